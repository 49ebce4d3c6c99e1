//! The service: reader tasks -> analysis task -> output tasks, and their shutdown.
//!
//! Start-up fails loudly: [`Service::new`] refuses what cannot run (a model that does
//! not load, a register map past register 65535), [`Service::spawn`] what cannot bind,
//! and once running, an output task that ends (a listener that fails for good) or an
//! analysis that dies ends the service with the error, so `millgate run` exits
//! non-zero and its supervisor restarts it.

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use millgate_config::{Config, PlcOutput};
use tokio::net::TcpListener;
use tokio::sync::{broadcast, mpsc, oneshot, watch};

mod error;
mod outputs;
mod readers;
pub mod reload;
mod running;

pub use error::ServiceError;
pub use running::RunningService;

use outputs::{Kept, Listeners, Outputs, ReloadCounters, Wiring, WiringParts};
use reload::{Live, Reload};

use crate::analysis::driveline::BiteReport;
use crate::analysis::gap_estimate::GapObservation;
use crate::analysis::{AddedDrivelines, Analysis, DrivelineAddition, LiveSettings};
use crate::field::acquired::Acquired;
use crate::field::counters::Acquisition;
use crate::field::counters::{CanCounters, ChannelCounters};
use crate::field::modbus::NewChannels;
use crate::field::source_health::SourceHealth;
use crate::history::outages::{OutageMonitor, WatchedSource};
use crate::history::RunInfo;
use crate::outputs::modbus::hmi_server::{self, ServerCounters};
use crate::outputs::modbus::register_map::RegisterMap;
use crate::outputs::opcua::{self, OpcUaOutputTask};
use crate::outputs::web;
use crate::shutdown::{self, Shutdown};
use crate::state::board::Board;
use crate::state::commands::{self, CommandReceiver, CommandSender};
use crate::state::events::HistoryEvent;
use crate::state::history::History;
use crate::state::results::GatewayState;
use crate::state::time::UtcTime;
use crate::supervision::Liveness;

/// Samples in flight between readers and analysis. At 2 kHz and 100-sample blocks
/// this is seconds of data per channel: enough to ride out a slow analysis step.
const SAMPLE_QUEUE: usize = 1024;

/// A configured, not yet running gateway.
#[derive(Debug)]
pub struct Service {
    config: Config,
    map: Arc<RegisterMap>,
    board: Arc<Board>,
    commands: CommandSender,
    command_receiver: CommandReceiver,
    counters: Vec<Arc<ChannelCounters>>,
    health: Vec<Arc<SourceHealth>>,
    can_counters: Vec<Arc<CanCounters>>,
    bites: broadcast::Sender<BiteReport>,
    analysis: Analysis,
    history: History,
    server_listener: Option<TcpListener>,
    metrics_listener: Option<TcpListener>,
    web_listener: Option<TcpListener>,
    opcua_listener: Option<TcpListener>,
    /// The OPC UA server, made by [`Service::new`] (its address space and certificate
    /// store checked there, so `check` reports them).
    opcua: Option<OpcUaOutputTask>,
    liveness: Arc<Liveness>,
    server_counters: Arc<ServerCounters>,
    /// Set once the PLC writer attempted its first write (at once without a PLC).
    plc_attempted: watch::Sender<bool>,
    /// Reload requests ([`RunningService::reload`]), handled once the service runs.
    reloads: (mpsc::Sender<ReloadRequest>, mpsc::Receiver<ReloadRequest>),
    /// The configurations with drivelines added live, to the OPC UA server.
    added_configs: watch::Sender<Arc<Config>>,
    /// The thresholds of the drivelines and tandem mills, as a reload sends them to the
    /// analysis.
    thresholds: watch::Sender<LiveSettings>,
}

/// A reload of the configuration file at `path`, and where its outcome goes.
#[derive(Debug)]
pub(crate) struct ReloadRequest {
    path: PathBuf,
    reply: oneshot::Sender<Reload>,
}

/// Reload requests waiting for the service.
const RELOAD_QUEUE: usize = 4;

/// Addresses the service listens on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Bound {
    /// The Modbus server for HMIs.
    pub server: Option<SocketAddr>,
    /// The Prometheus endpoint.
    pub metrics: Option<SocketAddr>,
    /// The maintenance web page.
    pub web: Option<SocketAddr>,
    /// The OPC UA server.
    pub opcua: Option<SocketAddr>,
}

impl Service {
    /// Build every task's state from `config`; an error names the key of a setting
    /// the service cannot run with.
    pub fn new(config: Config) -> Result<Self, ServiceError> {
        let map = RegisterMap::try_new(&config)?;
        if let Some(plc) = &config.outputs.plc {
            check_register_base(&map, plc)?;
        }
        let counters = config
            .channels
            .iter()
            .map(|_| Arc::new(ChannelCounters::default()))
            .collect();
        let health = readers::source_health(&config);
        let history = History::new(config.history.as_ref());
        let board = Arc::new(Board::new(&config, health.clone()).with_history(history.clone()));
        let (bites, _) = broadcast::channel(64);
        let analysis = Analysis::new(&config, Arc::clone(&board), bites.clone())?;
        // A driveline model that does not load, or `wear` settings that do not fit it,
        // is a configuration error: `run` exits with it at once (and `check` names it)
        // rather than running on without the wear diagnosis the file asks for.
        let problems = analysis.wear_problems();
        if !problems.is_empty() {
            return Err(ServiceError::Wear(problems));
        }
        let (commands, command_receiver) = commands::channel();
        let (added_configs, added_configs_rx) = watch::channel(Arc::new(config.clone()));
        let opcua = OpcUaOutputTask::prepare(
            &config,
            &analysis.rod_mill_spans(),
            Arc::clone(&board),
            commands.clone(),
            added_configs_rx,
        )?;
        let can_counters = config.can_sources.iter().map(|_| Arc::default()).collect();
        let (plc_attempted, _) = watch::channel(config.outputs.plc.is_none());
        let (thresholds, _) = watch::channel(LiveSettings::of(&config));
        Ok(Self {
            config,
            map: Arc::new(map),
            board,
            commands,
            command_receiver,
            counters,
            health,
            can_counters,
            bites,
            analysis,
            history,
            server_listener: None,
            metrics_listener: None,
            web_listener: None,
            opcua_listener: None,
            opcua,
            liveness: Arc::default(),
            server_counters: Arc::default(),
            plc_attempted,
            reloads: mpsc::channel(RELOAD_QUEUE),
            added_configs,
            thresholds,
        })
    }

    /// What the configuration exposes that an operator should know: a Modbus server,
    /// `/metrics`, a web page or an OPC UA server reachable from other hosts. `millgate
    /// check` prints these; the service logs them as warnings at start.
    pub fn warnings(&self) -> Vec<String> {
        let outputs = &self.config.outputs;
        let opcua = outputs.opcua.as_ref().and_then(opcua::exposure_warning);
        outputs
            .server
            .as_ref()
            .and_then(hmi_server::exposure_warning)
            .into_iter()
            .chain(
                outputs
                    .metrics
                    .as_ref()
                    .and_then(crate::outputs::metrics::exposure_warning),
            )
            .chain(outputs.web.as_ref().and_then(web::exposure_warning))
            .chain(opcua)
            .collect()
    }

    /// Bind the listening outputs (Modbus server, metrics) now and return their
    /// addresses; `run` binds them otherwise. Lets callers learn ports chosen by
    /// the OS (`:0`).
    pub async fn bind(&mut self) -> Result<Bound, ServiceError> {
        async fn bind_once(
            output: &'static str,
            slot: &mut Option<TcpListener>,
            address: Option<SocketAddr>,
        ) -> Result<Option<SocketAddr>, ServiceError> {
            let Some(address) = address else {
                return Ok(None);
            };
            if slot.is_none() {
                let listener =
                    TcpListener::bind(address)
                        .await
                        .map_err(|source| ServiceError::Bind {
                            output,
                            address,
                            source,
                        })?;
                *slot = Some(listener);
            }
            Ok(slot.as_ref().and_then(|l| l.local_addr().ok()))
        }
        let outputs = &self.config.outputs;
        let server = outputs.server.as_ref().map(|s| s.bind);
        let metrics = outputs.metrics.as_ref().map(|m| m.bind);
        let web = outputs.web.as_ref().map(|w| w.bind);
        let opcua = outputs.opcua.as_ref().map(|o| o.bind);
        Ok(Bound {
            server: bind_once("Modbus server", &mut self.server_listener, server).await?,
            metrics: bind_once("metrics endpoint", &mut self.metrics_listener, metrics).await?,
            web: bind_once("maintenance page", &mut self.web_listener, web).await?,
            opcua: bind_once("OPC UA server", &mut self.opcua_listener, opcua).await?,
        })
    }

    /// Continue driveline `index`'s wear trend from its saved form, e.g. as a history
    /// kept it before a restart ([`RunningService`] bites carry each new one), or when
    /// there is none, from `bites` (time ms since the epoch, measures; oldest first)
    /// folded in again. The estimate is published as soon as the gap maps are ready.
    pub fn restore_gap_trend(
        &mut self,
        index: usize,
        saved: Option<&str>,
        bites: Vec<(i64, GapObservation)>,
    ) {
        self.analysis.restore_gap_trend(index, saved, bites);
    }

    /// Bites as they are analysed.
    pub(crate) fn subscribe_bites(&self) -> broadcast::Receiver<BiteReport> {
        self.bites.subscribe()
    }

    /// The published results.
    pub fn board(&self) -> Arc<Board> {
        Arc::clone(&self.board)
    }

    /// Where commands to the analysis go.
    pub fn commands(&self) -> CommandSender {
        self.commands.clone()
    }

    /// The register map the PLC writer and the HMI server encode the results with.
    pub fn register_map(&self) -> Arc<RegisterMap> {
        Arc::clone(&self.map)
    }

    /// Per-channel acquisition counters, indexed like `config.channels`.
    pub fn counters(&self) -> Vec<Arc<ChannelCounters>> {
        self.counters.clone()
    }

    /// The history file, `None` without `[history]`.
    pub fn history_path(&self) -> Option<&std::path::Path> {
        self.config
            .history
            .as_ref()
            .map(|history| history.path.as_path())
    }

    /// The event history (disabled without `[history]`).
    pub fn history(&self) -> History {
        self.history.clone()
    }

    /// Open the history and publish what it restores (before any reader starts, so
    /// the first bite continues the restored counter), and pool the bites last put
    /// into each driveline's gap pool again (the history is where the pool survives a
    /// restart). While the file exists but cannot be read (another process holds its
    /// lock, a file system error) this waits, retrying every
    /// [`crate::history::writer::REOPEN_PERIOD`], with no output running: no
    /// counter, bdSeq or replay cursor may start below what the file holds. `false`
    /// when `shutdown` came first (the history is closed then).
    async fn restore(&mut self, shutdown: &mut Shutdown) -> bool {
        let Some(opened) = crate::history::writer::spawn(&self.history, RunInfo::of(&self.config))
        else {
            return true;
        };
        let mut waiting = tokio::task::spawn_blocking(move || opened.recv());
        let restored = tokio::select! {
            restored = &mut waiting => restored,
            () = shutdown.recv() => {
                tracing::info!("stopped while waiting for the history file");
                let history = self.history.clone();
                if tokio::task::spawn_blocking(move || history.close()).await.is_err() {
                    tracing::error!("closing the history failed");
                }
                let _ = waiting.await;
                return false;
            }
        };
        let restored = match restored {
            Ok(Ok(restored)) => restored,
            Ok(Err(_)) => return true,
            Err(error) => {
                tracing::error!(%error, "opening the history failed");
                return true;
            }
        };
        let board = &self.board;
        board.update(|results| restored.apply_mills(results, board.tandem_mill_names()));
        let names = board.driveline_names();
        for driveline in &restored.drivelines {
            if let Some(index) = names.iter().position(|name| *name == driveline.name) {
                self.analysis.resume_driveline(index, driveline);
            }
        }
        true
    }

    /// The outage monitor of every source.
    fn outage_monitor(&self) -> OutageMonitor {
        let sources = 0..self.health.len();
        outage_monitor(
            &self.config,
            (&self.health[..], &self.counters[..]),
            sources,
            &self.history,
        )
    }

    /// Run until `shutdown` fires; then stop the readers, let analysis drain what
    /// they read, and write the final registers with status "stopped" (the source
    /// statuses as they were while running: an orderly stop is not a fault).
    ///
    /// Ends early with an error when an output task or the analysis fails.
    pub async fn run(mut self, mut shutdown: Shutdown) -> Result<(), ServiceError> {
        self.bind().await?;
        for warning in self.warnings() {
            tracing::warn!("{warning}");
        }
        if !self.restore(&mut shutdown).await {
            return Ok(());
        }
        let mut started = self.start()?;
        let failure = started.until_failure(&mut shutdown).await;
        if let Some(failure) = &failure {
            tracing::error!(%failure, "stopping the service");
        }
        started.stop().await;
        failure.map_or(Ok(()), Err)
    }

    /// Spawn the readers, the analysis and every output; the gateway is running.
    fn start(self) -> Result<Started, ServiceError> {
        let outage_monitor = Some(self.outage_monitor());
        let Service {
            config,
            map,
            board,
            commands,
            command_receiver,
            counters,
            health,
            can_counters,
            analysis,
            history,
            server_listener,
            metrics_listener,
            web_listener,
            opcua_listener,
            opcua,
            liveness,
            server_counters,
            plc_attempted,
            reloads,
            added_configs,
            thresholds,
            ..
        } = self;
        let rod_mill_spans = analysis.rod_mill_spans();
        // Readers stop on their own signal, after the final source statuses are kept.
        let (readers_stop, readers_shutdown) = shutdown::channel();
        let (samples, samples_rx) = mpsc::channel(SAMPLE_QUEUE);
        // One addition at a time: a reload waits for the analysis to take it.
        let (additions, additions_rx) = mpsc::channel(1);
        let acquisition = Acquisition {
            counters,
            health,
            can: can_counters,
        };
        let (readers, feeds) = readers::spawn(&config, &acquisition, &samples, &readers_shutdown);
        let inputs = Inputs {
            acquisition: acquisition.clone(),
            feeds,
            samples: Some(samples),
            shutdown: readers_shutdown,
        };
        let analysis_task = readers::spawn_analysis(
            analysis,
            (
                samples_rx,
                command_receiver,
                thresholds.subscribe(),
                additions_rx,
            ),
            &board,
            Arc::clone(&liveness),
        );
        // Outputs stop only after analysis has drained, so the last bite is published.
        // Each returns what ended it; before the stop, any end is a failure.
        let keep = |listener: Option<TcpListener>, configured: Option<SocketAddr>| {
            listener
                .zip(configured)
                .map(|(listener, configured)| {
                    Kept::new(configured, listener).map_err(|source| (configured, source))
                })
                .transpose()
        };
        let bind_error = |output| {
            move |(address, source)| ServiceError::Bind {
                output,
                address,
                source,
            }
        };
        let configured = &config.outputs;
        let listeners = Listeners {
            server: keep(server_listener, configured.server.as_ref().map(|s| s.bind))
                .map_err(bind_error("Modbus server"))?,
            metrics: keep(
                metrics_listener,
                configured.metrics.as_ref().map(|m| m.bind),
            )
            .map_err(bind_error("metrics endpoint"))?,
            web: keep(web_listener, configured.web.as_ref().map(|w| w.bind))
                .map_err(bind_error("maintenance page"))?,
            opcua: opcua_listener,
        };
        let reload_counters = Arc::new(ReloadCounters::default());
        let wiring = Wiring::new(
            config.clone(),
            WiringParts {
                map: Arc::clone(&map),
                board: Arc::clone(&board),
                commands,
                acquisition,
                server_counters,
                plc_attempted: Some(plc_attempted),
                listeners,
                outage_monitor,
                rod_mill_spans,
                opcua,
                reloads: Arc::clone(&reload_counters),
            },
        );
        let outputs = Outputs::start(wiring)?;
        board.update(|results| results.state = GatewayState::Running);
        Ok(Started {
            config,
            map,
            board,
            history,
            readers,
            readers_stop,
            inputs,
            analysis_maps: analysis_task.maps,
            analysis: analysis_task.task,
            analysis_ended: None,
            outputs,
            reloads: reloads.1,
            reload_counters,
            thresholds,
            additions,
            added_configs,
        })
    }
}

/// The outage monitor of `config`'s `sources` (indices in the order of
/// [`Config::sources`]), by their `health` and their channels' `counters`.
fn outage_monitor(
    config: &Config,
    (health, counters): (&[Arc<SourceHealth>], &[Arc<ChannelCounters>]),
    sources: std::ops::Range<usize>,
    history: &History,
) -> OutageMonitor {
    let watched = config
        .sources()
        .zip(health)
        .enumerate()
        .filter(|(index, _)| sources.contains(index))
        .map(|(index, (source, health))| WatchedSource {
            name: source.name().to_owned(),
            health: Arc::clone(health),
            channels: (0..config.channels.len())
                .filter(|&c| config.source_of_channel(c) == index)
                .map(|c| Arc::clone(&counters[c]))
                .collect(),
        })
        .collect();
    OutageMonitor::new(watched, history.clone())
}

/// Whether the register map `map` written at `plc`'s base fits below register 65536.
fn check_register_base(map: &RegisterMap, plc: &PlcOutput) -> Result<(), ServiceError> {
    let span = map.plc_span(plc.extension_blocks);
    let end = u32::from(plc.register_base) + u32::from(span) - 1;
    if end > u32::from(u16::MAX) {
        return Err(ServiceError::RegisterBase {
            base: plc.register_base,
            span,
            end,
            max: u32::from(u16::MAX) + 1 - u32::from(span),
        });
    }
    Ok(())
}

/// What the readers run with, kept for the sources a reload adds.
struct Inputs {
    /// The counters and health records, grown by the sources and channels added.
    acquisition: Acquisition,
    /// Where the running Modbus readers take the channels added on their sources.
    feeds: readers::ChannelFeeds,
    /// Where readers send, dropped at the stop (the analysis ends once every reader
    /// has hung up).
    samples: Option<mpsc::Sender<Acquired>>,
    /// The readers' stop.
    shutdown: Shutdown,
}

/// A started service's tasks, in the order they stop.
struct Started {
    /// The configuration it runs (the file's at start, with what reloads applied).
    config: Config,
    map: Arc<RegisterMap>,
    board: Arc<Board>,
    history: History,
    /// The readers, and the outage monitors of sources a reload added.
    readers: tokio::task::JoinSet<()>,
    readers_stop: shutdown::ShutdownTrigger,
    /// What a reader a reload adds starts with.
    inputs: Inputs,
    analysis_maps: readers::MapBuilds,
    analysis: tokio::task::JoinHandle<()>,
    /// How the analysis ended, when it ended before the stop.
    analysis_ended: Option<Result<(), tokio::task::JoinError>>,
    outputs: Outputs,
    reloads: mpsc::Receiver<ReloadRequest>,
    reload_counters: Arc<ReloadCounters>,
    thresholds: watch::Sender<LiveSettings>,
    /// Drivelines a reload adds, to the analysis.
    additions: mpsc::Sender<DrivelineAddition>,
    /// The configurations with drivelines added live, to the OPC UA server (which
    /// adds their nodes as it runs), sent once the board has them.
    added_configs: watch::Sender<Arc<Config>>,
}

impl Started {
    /// Run until `shutdown` fires (`None`) or an output or the analysis ends (the
    /// failure: before the stop, any end is one), applying reloads meanwhile.
    async fn until_failure(&mut self, shutdown: &mut Shutdown) -> Option<ServiceError> {
        loop {
            tokio::select! {
                () = shutdown.recv() => return None,
                failure = self.outputs.failure() => return Some(failure),
                ended = &mut self.analysis => {
                    let failure = match &ended {
                        Ok(()) => ServiceError::Ended,
                        Err(error) => ServiceError::Output {
                            output: "analysis",
                            reason: error.to_string(),
                        },
                    };
                    self.analysis_ended = Some(ended);
                    return Some(failure);
                }
                Some(request) = self.reloads.recv() => {
                    match self.reload(&request.path).await {
                        Ok(outcome) => {
                            let _ = request.reply.send(outcome);
                        }
                        Err(failure) => return Some(failure),
                    }
                }
            }
        }
    }

    /// Reload the configuration file at `path`: apply what can be applied, log the
    /// outcome, count it and return it. An error when an output cannot be started
    /// again with settings that passed the checks (the service then ends with it, and
    /// its supervisor starts it anew with the new file).
    async fn reload(&mut self, path: &Path) -> Result<Reload, ServiceError> {
        let outcome = match millgate_config::load(path) {
            Err(errors) => Reload::Refused(errors.to_string()),
            Ok(new) => match reload::compare(&self.config, &new) {
                Reload::Changed(plan) => self.apply(plan, &new).await?,
                other => other,
            },
        };
        match &outcome {
            Reload::Unchanged => tracing::info!(outcome = outcome.outcome(), "{outcome}"),
            Reload::Changed(plan) if plan.needs_restart.is_empty() => {
                tracing::info!(outcome = outcome.outcome(), "{outcome}");
            }
            _ => tracing::warn!(outcome = outcome.outcome(), "{outcome}"),
        }
        self.reload_counters.count(outcome.outcome());
        Ok(outcome)
    }

    /// Apply the parts of `plan` that run live (`new`'s): check them, bind the new
    /// addresses, then send the thresholds to the analysis and restart the outputs
    /// they touch. A check or bind that fails refuses the whole reload.
    async fn apply(
        &mut self,
        mut plan: reload::Plan,
        new: &Config,
    ) -> Result<Reload, ServiceError> {
        let config = plan.applied_to(&self.config, new);
        if let Some(plc) = &config.outputs.plc {
            if let Err(error) = check_register_base(&self.map, plc) {
                return Ok(Reload::Refused(error.to_string()));
            }
        }
        let added = match plan.live.contains(&Live::Drivelines) {
            true => match self.map_with_added(&config).await {
                Ok((map, drivelines, resumed)) => {
                    plan.note_resumed(&resumed);
                    Some((map, drivelines))
                }
                Err(refused) => return Ok(Reload::Refused(refused)),
            },
            false => None,
        };
        let listeners = match self.outputs.bind_new(&config).await {
            Ok(listeners) => listeners,
            Err(error) => return Ok(Reload::Refused(error.to_string())),
        };
        let analysis = [Live::Thresholds, Live::Horizon, Live::Chatter];
        if analysis.iter().any(|part| plan.live.contains(part)) {
            self.thresholds.send_replace(LiveSettings::of(&config));
        }
        if plan.live.contains(&Live::Thresholds) || added.is_some() {
            self.history.record(HistoryEvent::Settings {
                time: UtcTime::now(),
                drivelines: config.drivelines.clone(),
            });
        }
        // The outputs that show drivelines stop before the board grows: an output
        // built for the drivelines it had never meets one it does not know.
        let restart = self.outputs.stop_touched(&config, &plan.live).await;
        let sources = plan.live.contains(&Live::Sources);
        if added.is_some() || sources {
            self.add_drivelines(&config, added).await?;
        }
        if sources {
            self.start_sources(&config);
        }
        self.outputs
            .start_touched(config.clone(), &plan.live, &restart, listeners)?;
        self.config = config;
        Ok(Reload::Changed(plan))
    }

    /// The register map of `config` (the running configuration with drivelines added
    /// after the others), the analysers of the drivelines added, and what the history
    /// holds of them, once checked: the map it grows into has every register where it
    /// was (the added drivelines take blocks `outputs.driveline_slots` reserves), the
    /// analysis can be built for the added drivelines, their models loaded, and the
    /// history read for the state it kept under their names ([`reload::resumed_from`];
    /// the analysers resume it). Built and read on a blocking thread (a model is
    /// loaded and its linear wear reference simulated; the history file is read): the
    /// analysis runs on meanwhile. `Err` says why not.
    async fn map_with_added(
        &self,
        config: &Config,
    ) -> Result<(RegisterMap, AddedDrivelines, reload::Resumed), String> {
        let map = RegisterMap::try_new(config).map_err(|error| error.to_string())?;
        if map.len() != self.map.len() {
            return Err(format!(
                "the register map would grow from {} to {} registers: a driveline added \
                 live takes a block outputs.driveline_slots reserves",
                self.map.len(),
                map.len()
            ));
        }
        let (config, from) = (config.clone(), self.config.drivelines.len());
        let history = self.config.history.as_ref().map(|h| h.path.clone());
        let built = tokio::task::spawn_blocking(move || {
            let mut drivelines =
                AddedDrivelines::build(&config, from).map_err(|error| error.to_string())?;
            let names: Vec<String> = config.drivelines[from..]
                .iter()
                .map(|driveline| driveline.name.clone())
                .collect();
            let resumed = reload::resumed_from(history.as_deref(), &names)?;
            drivelines.resume(resumed.drivelines.clone());
            Ok::<_, String>((drivelines, resumed))
        })
        .await
        .map_err(|error| format!("building the added drivelines' analysis failed: {error}"))?;
        let (drivelines, resumed) = built?;
        Ok((map, drivelines, resumed))
    }

    /// Start analysing the drivelines `config` (the running configuration with them)
    /// adds after the others, `added` as [`Self::map_with_added`] checked them (the
    /// map and their analysers with the state the history kept of them; `None` when a
    /// reload adds sources only, whose channels the analysis then routes): the
    /// analysis takes them once its shares in flight ended, grows the board and resumes that state
    /// before their first bite, then their gap maps build as a start's do; the outputs
    /// restarted for [`Live::Drivelines`] then run on the map. An error when the
    /// analysis has ended or refuses them after all (the service ends with it, and
    /// its supervisor starts it anew with the file).
    async fn add_drivelines(
        &mut self,
        config: &Config,
        added: Option<(RegisterMap, AddedDrivelines)>,
    ) -> Result<(), ServiceError> {
        let (map, mut drivelines) = match added {
            Some((map, drivelines)) => (Some(map), drivelines),
            None => (None, AddedDrivelines::none(self.config.drivelines.len())),
        };
        let gap_maps = drivelines.take_gap_map_jobs();
        let (done, answer) = oneshot::channel();
        let config = Arc::new(config.clone());
        let addition = DrivelineAddition {
            config: Arc::clone(&config),
            drivelines,
            done,
        };
        if self.additions.send(addition).await.is_err() {
            return Err(ServiceError::Ended);
        }
        let names = match answer.await {
            Ok(Ok(names)) => names,
            Ok(Err(reason)) => {
                return Err(ServiceError::Output {
                    output: "analysis",
                    reason,
                })
            }
            Err(_) => return Err(ServiceError::Ended),
        };
        // The analysis and the board have them now: the maps' progress and outcome
        // find their driveline.
        self.analysis_maps.spawn_live(gap_maps);
        let Some(map) = map else {
            return Ok(());
        };
        tracing::info!(drivelines = ?names, "reload: drivelines added, analysed from their next block on");
        self.added_configs.send_replace(config);
        self.map = Arc::new(map);
        self.outputs.use_map(Arc::clone(&self.map));
        Ok(())
    }

    /// Start reading the sources and channels `config` (the running configuration
    /// with them, [`Live::Sources`]) adds after the others, once the analysis routes
    /// their channels: their health records join the board's, their counters the
    /// acquisition's (the outputs restarted for them show both), a reader per source
    /// added, with an outage monitor of their own, and the channels added on a running
    /// Modbus source to its reader, which takes them between two polls. The running
    /// sources' readers and their channels are not touched otherwise.
    fn start_sources(&mut self, config: &Config) {
        let Some(samples) = &self.inputs.samples else {
            return;
        };
        let acquisition = &mut self.inputs.acquisition;
        let from = acquisition.health.len();
        let added = readers::source_health(config).split_off(from);
        let channels = acquisition.counters.len();
        acquisition.counters.extend(
            (channels..config.channels.len()).map(|_| Arc::new(ChannelCounters::default())),
        );
        let can = acquisition.can.len()..config.can_sources.len();
        acquisition.can.extend(can.map(|_| Arc::default()));
        acquisition.health.extend(added.iter().cloned());
        self.board.add_sources(&added);
        self.outputs.use_acquisition(acquisition.clone());
        let shared = Arc::new(config.clone());
        let mut grown: Vec<usize> = (channels..config.channels.len())
            .map(|channel| config.source_of_channel(channel))
            .filter(|&source| source < from)
            .collect();
        grown.dedup();
        for feed in grown
            .iter()
            .filter_map(|&source| self.inputs.feeds[source].as_ref())
        {
            feed.send_replace(NewChannels {
                config: Arc::clone(&shared),
                counters: acquisition.counters.clone(),
            });
        }
        let sources = from..from + added.len();
        for index in sources.clone() {
            let inputs = (samples, &self.inputs.shutdown);
            let feed =
                readers::spawn_source(&shared, index, acquisition, inputs, &mut self.readers);
            self.inputs.feeds.push(feed);
        }
        if sources.is_empty() {
            return;
        }
        let watched = (&acquisition.health[..], &acquisition.counters[..]);
        let monitor = outage_monitor(config, watched, sources, &self.history);
        self.readers
            .spawn(monitor.run(self.inputs.shutdown.clone()));
    }

    /// Stop the readers (the source statuses kept as they were), let the analysis
    /// drain what they read, stop the outputs (the PLC gets its last write) and close
    /// the history last, so it commits what analysis and the outputs recorded.
    async fn stop(self) {
        let Started {
            board,
            history,
            mut readers,
            readers_stop,
            inputs,
            analysis_maps,
            analysis,
            analysis_ended,
            outputs,
            ..
        } = self;
        board.freeze_health();
        readers_stop.trigger();
        while readers.join_next().await.is_some() {}
        // The last sender: the analysis drains what was read, then ends.
        drop(inputs);
        analysis_maps.cancel();
        let analysis_ended = match analysis_ended {
            Some(ended) => ended,
            None => analysis.await,
        };
        if let Err(error) = analysis_ended {
            tracing::error!(%error, "analysis task failed");
        }
        outputs.stop().await;
        board.update(|results| results.state = GatewayState::Stopped);
        if tokio::task::spawn_blocking(move || history.close())
            .await
            .is_err()
        {
            tracing::error!("closing the history failed");
        }
        tracing::info!("stopped");
    }
}

/// Run the gateway for `config` until `shutdown` fires.
pub async fn run(config: Config, shutdown: Shutdown) -> Result<(), ServiceError> {
    Service::new(config)?.run(shutdown).await
}
