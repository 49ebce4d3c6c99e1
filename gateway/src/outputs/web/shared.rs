//! What the page's handlers share: the configuration's parts they show, the board, the
//! history file, the live results and the kept gap trends.

use std::path::PathBuf;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Duration;

use millgate_config::{Identification, IdentificationValue};
use serde_json::{Map, Value as JsonValue};
use tokio::sync::{watch, OwnedSemaphorePermit, Semaphore};

use crate::state::board::Board;
use crate::state::captures::CaptureBandsFn;

/// What the configuration says about a driveline, for the pages.
#[derive(Debug, Clone)]
pub(crate) struct DrivelineInfo {
    /// Its name.
    pub name: String,
    /// TAF warning and alarm thresholds.
    pub taf_warning: f64,
    /// TAF alarm threshold.
    pub taf_alarm: f64,
    /// Gap warning threshold, mrad.
    pub gap_warning_mrad: f64,
    /// Gap alarm threshold, mrad.
    pub gap_alarm_mrad: f64,
    /// Whether it has a model (the gap diagnosis runs only with one).
    pub has_model: bool,
    /// The model, when it loads: the simulated response beside a bite's capture.
    pub model: Option<Arc<millgate_sim::model::Model>>,
    /// Its fatigue ledger's components (empty without `drivelines[].fatigue`).
    pub fatigue_components: Vec<String>,
    /// Its fatigue ledger's `life_limit` (none without `drivelines[].fatigue`).
    pub fatigue_life_limit: Option<f64>,
    /// Its nameplate (`drivelines[].identification`) as the API gives it: each key
    /// set, a text or (`year_of_construction`) a number.
    pub identification: Map<String, JsonValue>,
}

/// A nameplate as the API gives it: `{key: text or year}` of the keys set.
pub(crate) fn identification_json(identification: &Identification) -> Map<String, JsonValue> {
    identification
        .fields
        .iter()
        .map(|(field, value)| {
            let value = match value {
                IdentificationValue::Text(text) => text.as_str().into(),
                IdentificationValue::Year(year) => (*year).into(),
            };
            (field.key().to_owned(), value)
        })
        .collect()
}

/// Everything the handlers share.
#[derive(Debug)]
pub(crate) struct WebState {
    /// The configuration's name.
    pub(crate) config_name: String,
    pub(crate) drivelines: Vec<DrivelineInfo>,
    /// Tandem mills: name and stand channel names.
    pub(crate) tandem_mills: Vec<(String, Vec<String>)>,
    /// Rod mills by name.
    pub(crate) rod_mills: Vec<String>,
    /// Sources: name and kind (`modbus`, `can`), Modbus first as in the results.
    pub(crate) sources: Vec<(String, &'static str)>,
    pub(crate) board: Arc<Board>,
    /// The history file, `None` without `[history]`.
    pub(crate) history: Option<PathBuf>,
    /// Whether captures are kept (`[history]` with `history.captures = true`).
    pub(crate) captures_kept: bool,
    pub(crate) request_timeout: Duration,
    /// History queries running at once (`outputs.web.history_queries`): a slot is
    /// held until the query's thread has ended.
    pub(crate) query_slots: Arc<QuerySlots>,
    /// The threads the history queries run on, one per slot.
    pub(crate) queries: QueryThreads,
    /// Live-update streams open at once (`outputs.web.max_event_streams`).
    pub(crate) event_streams: Arc<Semaphore>,
    /// Host names answered besides addresses and `localhost`.
    pub(crate) allowed_hosts: Vec<String>,
    /// The live results as `/api/events` sends them (JSON), newest.
    pub(crate) live: watch::Receiver<Arc<String>>,
    /// Gap trends as last fitted, per driveline (the API's `gap_trend`).
    pub(crate) trends: TrendCache,
    /// The band analysis of a tandem mill's capture, once the service gave it.
    pub(crate) capture_bands: BandsHook,
    /// `outputs.web.allow_commands`: whether `POST /api/captures` is taken.
    pub(crate) allow_commands: bool,
    /// The analysis' command channel, once the service gave it.
    pub(crate) commands: std::sync::OnceLock<crate::state::commands::CommandSender>,
    /// The log line of `POST /api/captures`: the first, then one per period with how
    /// many it stands for (a client may post in a loop).
    pub(crate) command_log: std::sync::Mutex<crate::warn_limit::WarnLimit>,
}

/// The band analysis of a tandem mill's capture (`analysis::chatter::episode_bands`,
/// given by the service), set once.
#[derive(Default)]
pub(crate) struct BandsHook(pub(crate) std::sync::OnceLock<CaptureBandsFn>);

// By hand: a function has no Debug.
impl std::fmt::Debug for BandsHook {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_tuple("BandsHook")
            .field(&self.0.get().is_some())
            .finish()
    }
}

impl BandsHook {
    pub(crate) fn get(&self) -> Option<&CaptureBandsFn> {
        self.0.get()
    }
}

/// Gap trends as last fitted, per driveline: the time of the last bite (Unix ms) they
/// were fitted up to, and the trend. A trend changes only with a new bite (a later
/// wear reset counts from the next bite on), so an overview load looks up one index
/// entry per driveline instead of fitting four weeks of bites again (about 70 ms per
/// driveline on a year of bites, one every 30 s). Retention that deletes bites inside
/// the window leaves the trend as fitted until the next bite.
#[derive(Debug, Default)]
pub(crate) struct TrendCache(
    pub(crate) std::sync::Mutex<std::collections::HashMap<String, (i64, Option<f64>)>>,
);

/// The page's history query slots (`outputs.web.history_queries`) and the requests
/// that found none free, for `/metrics`.
#[derive(Debug)]
pub(crate) struct QuerySlots {
    free: Arc<Semaphore>,
    limit: usize,
    refused: AtomicU64,
}

impl QuerySlots {
    /// `limit` slots, all free.
    pub(crate) fn new(limit: usize) -> Self {
        Self {
            free: Arc::new(Semaphore::new(limit)),
            limit,
            refused: AtomicU64::new(0),
        }
    }

    /// A free slot, waiting at most `wait` for one; `None` (counted as refused) when
    /// none frees in time. The slot is free again when the permit is dropped.
    pub(crate) async fn acquire(&self, wait: Duration) -> Option<OwnedSemaphorePermit> {
        match tokio::time::timeout(wait, Arc::clone(&self.free).acquire_owned()).await {
            Ok(Ok(permit)) => Some(permit),
            _ => {
                self.refused.fetch_add(1, Ordering::Relaxed);
                None
            }
        }
    }

    /// How many slots there are.
    pub(crate) fn limit(&self) -> usize {
        self.limit
    }

    /// Slots held by a query now.
    pub(crate) fn in_use(&self) -> usize {
        self.limit.saturating_sub(self.free.available_permits())
    }

    /// Requests answered 503 because no slot freed in time, since start.
    pub(crate) fn refused(&self) -> u64 {
        self.refused.load(Ordering::Relaxed)
    }
}

/// A history query's work, run on a [`QueryThreads`] thread.
pub(crate) type QueryJob = Box<dyn FnOnce() + Send>;

/// Nice value of the query threads: the lowest priority, so the page's work never
/// takes the CPU from the readers and the analysis.
const QUERY_NICE: i32 = 19;

/// The threads the page's history queries run on: a fixed number, started with the
/// server at the lowest CPU priority; they end when the server's state is dropped.
#[derive(Debug)]
pub(crate) struct QueryThreads(std::sync::mpsc::Sender<QueryJob>);

impl QueryThreads {
    /// `count` threads named `WebHistoryQuery`.
    pub(crate) fn start(count: usize) -> std::io::Result<Self> {
        let (jobs, queue) = std::sync::mpsc::channel::<QueryJob>();
        let queue = Arc::new(std::sync::Mutex::new(queue));
        for _ in 0..count {
            let queue = Arc::clone(&queue);
            std::thread::Builder::new()
                .name("WebHistoryQuery".into())
                .spawn(move || {
                    if let Err(error) = rustix::process::setpriority_process(None, QUERY_NICE) {
                        tracing::debug!(%error, "history query thread: priority not lowered");
                    }
                    loop {
                        let job = crate::lock(&queue).recv();
                        match job {
                            // A job that panics (a bug) ends its request, not the
                            // thread: the slots keep their threads.
                            Ok(job) => {
                                if std::panic::catch_unwind(std::panic::AssertUnwindSafe(job))
                                    .is_err()
                                {
                                    tracing::error!("a history query panicked");
                                }
                            }
                            Err(_) => break,
                        }
                    }
                })?;
        }
        Ok(Self(jobs))
    }

    /// Run `job` on the next free thread; `Err` when the threads have ended.
    pub(crate) fn run(&self, job: QueryJob) -> Result<(), QueryJob> {
        self.0.send(job).map_err(|refused| refused.0)
    }
}
