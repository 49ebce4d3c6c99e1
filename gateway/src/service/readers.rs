//! The service's input side: the sources' health, the reader tasks (one per Modbus
//! source, one supervised reader per CAN source) and the analysis task with the gap map
//! builds it installs.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

use millgate_config::{Config, SourceRef};
use tokio::sync::{mpsc, watch};
use tokio::task::{JoinHandle, JoinSet};

use crate::analysis::gap_monitor::{spawn_job, GapMapJob, GapMapsReady};
use crate::analysis::{Analysis, DrivelineAddition, LiveSettings};
use crate::field::acquired::Acquired;
use crate::field::can::supervisor::supervise_can;
use crate::field::counters::Acquisition;
use crate::field::modbus::{DaqReader, NewChannels};
use crate::field::source_health::SourceHealth;
use crate::shutdown::Shutdown;
use crate::state::board::Board;
use crate::state::commands::CommandReceiver;
use crate::state::gap_maps::GapMapState;
use crate::supervision::Liveness;

/// The health of Modbus source `index` of `config`: stale after three poll periods,
/// two timeouts or two periods of its slowest full block (new data is what keeps a
/// source fresh), whichever is longest; lost after five times that or 5 s.
fn modbus_health(config: &Config, index: usize) -> SourceHealth {
    let source = &config.modbus_sources[index];
    let slowest_block = config
        .channels
        .iter()
        .filter_map(|channel| match channel.source {
            millgate_config::ChannelSource::ModbusBlock { source, .. } if source == index => {
                Some(Duration::from_secs_f64(
                    f64::from(millgate_config::layout::MAX_BLOCK_SAMPLES) / channel.sample_rate_hz,
                ))
            }
            _ => None,
        })
        .max()
        .unwrap_or_default();
    let stale_after = (source.poll_period * 3)
        .max(source.timeout * 2)
        .max(slowest_block * 2);
    SourceHealth::new(stale_after, (stale_after * 5).max(Duration::from_secs(5)))
}

/// A health record per source of `config`, in the order of [`Config::sources`]: a CAN
/// source is stale after 1 s without a frame, lost after 5 s.
pub(super) fn source_health(config: &Config) -> Vec<Arc<SourceHealth>> {
    let mut modbus = 0;
    config
        .sources()
        .map(|source| match source {
            SourceRef::Modbus(_) => {
                modbus += 1;
                Arc::new(modbus_health(config, modbus - 1))
            }
            SourceRef::Can(_) => Arc::new(SourceHealth::new(
                Duration::from_secs(1),
                Duration::from_secs(5),
            )),
        })
        .collect()
}

/// Where the running Modbus readers take the channels a reload appends on their
/// sources: per source in the order of [`Config::sources`], `None` for a CAN source.
pub(super) type ChannelFeeds = Vec<Option<watch::Sender<NewChannels>>>;

/// Start a reader per source, sending on `samples`, until `shutdown`; with the feeds
/// of their new channels.
pub(super) fn spawn(
    config: &Config,
    acquisition: &Acquisition,
    samples: &mpsc::Sender<Acquired>,
    shutdown: &Shutdown,
) -> (JoinSet<()>, ChannelFeeds) {
    let mut readers = JoinSet::new();
    let shared = Arc::new(config.clone());
    let feeds = (0..config.sources().count())
        .map(|index| {
            spawn_source(
                &shared,
                index,
                acquisition,
                (samples, shutdown),
                &mut readers,
            )
        })
        .collect();
    (readers, feeds)
}

/// Into `readers`, the reader of source `index` of `config` (in the order of
/// [`Config::sources`]), counting into `acquisition` (which has its health record and
/// its channels' counters, and its CAN counters for a CAN source), sending on
/// `samples` until `shutdown`. A Modbus reader's feed of new channels
/// ([`DaqReader::with_new_channels`]).
pub(super) fn spawn_source(
    config: &Arc<Config>,
    index: usize,
    acquisition: &Acquisition,
    (samples, shutdown): (&mpsc::Sender<Acquired>, &Shutdown),
    readers: &mut JoinSet<()>,
) -> Option<watch::Sender<NewChannels>> {
    let health = Arc::clone(&acquisition.health[index]);
    let modbus = config.modbus_sources.len();
    match config.sources().nth(index) {
        Some(SourceRef::Modbus(source)) => {
            let (feed, new_channels) = watch::channel(NewChannels {
                config: Arc::clone(config),
                counters: acquisition.counters.clone(),
            });
            let reader = DaqReader::new(config, index, &acquisition.counters, health)
                .with_new_channels(new_channels);
            tracing::info!(source = %source.name, address = %source.address, "starting DaqReader");
            readers.spawn(reader.run(samples.clone(), shutdown.clone()));
            Some(feed)
        }
        Some(SourceRef::Can(source)) => {
            let can = index - modbus;
            tracing::info!(source = %source.name, interface = %source.interface, "starting CanReader");
            readers.spawn(supervise_can(
                Arc::clone(config),
                can,
                health,
                (
                    Arc::clone(&acquisition.can[can]),
                    acquisition.counters.clone(),
                ),
                samples.clone(),
                shutdown.clone(),
            ));
            None
        }
        None => None,
    }
}

/// The analysis task and the gap map builds it waits for.
pub(super) struct AnalysisTask {
    /// The task: it ends once every reader has hung up.
    pub(super) task: JoinHandle<()>,
    /// The builds.
    pub(super) maps: MapBuilds,
}

/// The gap map builds, each on a thread of its own: a start's, and those of
/// drivelines a reload adds (the same way); the analysis installs what they give.
pub(super) struct MapBuilds {
    /// Where the builds send their maps, to the analysis.
    ready: mpsc::Sender<GapMapsReady>,
    /// Set at the stop: the builds still running end early.
    cancel: Arc<AtomicBool>,
    /// Where their progress shows.
    board: Arc<Board>,
    /// The machine's cores: a start's builds take one worker per core, a reload's one
    /// fewer ([`MapBuilds::spawn_live`]).
    threads: usize,
}

impl MapBuilds {
    /// Builds of `jobs` (read from the cache or simulated), `board` showing their
    /// progress, and the receiver of their outcome for the analysis.
    fn start(jobs: Vec<GapMapJob>, board: &Arc<Board>) -> (Self, mpsc::Receiver<GapMapsReady>) {
        let (ready, ready_rx) = mpsc::channel(jobs.len().max(1));
        let builds = Self {
            ready,
            cancel: Arc::new(AtomicBool::new(false)),
            board: Arc::clone(board),
            threads: std::thread::available_parallelism().map_or(1, |n| n.get()),
        };
        builds.spawn(jobs, builds.threads);
        (builds, ready_rx)
    }

    /// Start the builds of `jobs` of drivelines a reload added, on one worker fewer
    /// than the cores (at least one): the running drivelines' analysis keeps a core
    /// while the maps build (with every core, a live build of 20 600 simulated bites
    /// doubled their bite -> PLC latency in `reload.rs`' measurement).
    pub(super) fn spawn_live(&self, jobs: Vec<GapMapJob>) {
        self.spawn(jobs, self.threads.saturating_sub(1).max(1));
    }

    /// Start the builds of `jobs`, each on a thread of its own with `threads` workers
    /// (drivelines the analysis already has: their progress and their maps find them);
    /// one that cannot start is a failed build on the board.
    fn spawn(&self, jobs: Vec<GapMapJob>, threads: usize) {
        for job in jobs {
            let driveline = job.driveline_name.clone();
            let index = job.driveline;
            let progress = {
                let board = Arc::clone(&self.board);
                move |done, total| board.set_gap_maps(index, GapMapState::Building { done, total })
            };
            let spawned = spawn_job(
                job,
                threads,
                self.ready.clone(),
                Arc::clone(&self.cancel),
                progress,
            );
            if let Err(error) = spawned {
                tracing::error!(%driveline, %error, "cannot start the gap map build");
                self.board.set_gap_maps(
                    index,
                    GapMapState::Failed(format!("cannot start the gap map build: {error}")),
                );
            }
        }
    }

    /// Stop the builds still running.
    pub(super) fn cancel(&self) {
        self.cancel.store(true, Ordering::Relaxed);
    }
}

/// Start `analysis` on the readers' `samples`, the `commands`, and the `thresholds`
/// and driveline `additions` a reload sends, and the gap map builds of its drivelines
/// on threads of their own (read from the cache or built while the service runs; the
/// analysis installs them as they come, `board` shows their progress).
pub(super) fn spawn_analysis(
    mut analysis: Analysis,
    (samples, commands, thresholds, additions): (
        mpsc::Receiver<Acquired>,
        CommandReceiver,
        watch::Receiver<LiveSettings>,
        mpsc::Receiver<DrivelineAddition>,
    ),
    board: &Arc<Board>,
    liveness: Arc<Liveness>,
) -> AnalysisTask {
    let (maps, maps_rx) = MapBuilds::start(analysis.take_gap_map_jobs(), board);
    let run = analysis.run(
        samples,
        maps_rx,
        (commands, thresholds, additions),
        liveness,
    );
    // On a thread of its own, not on a runtime worker: the analysis blocks its
    // thread while it runs a share (or, one worker configured, a bite's analysis) or
    // waits for the shares in flight, and a task a worker wakes goes to that worker's
    // LIFO slot, which no other worker can take. On a worker, the PLC writer woken by
    // a bite's publication (and the Sparkplug node, the web's streams) waited there
    // until the analysis let go, and a busy analysis left one worker for every reader
    // and output. Woken from this thread, they go to the runtime's shared
    // queue, which any worker takes at once.
    let runtime = tokio::runtime::Handle::current();
    AnalysisTask {
        task: tokio::task::spawn_blocking(move || runtime.block_on(run)),
        maps,
    }
}
