//! The analysis task: samples in, bite and chatter results out. Only synchronous
//! `dsp` code runs on the samples; this module routes each reader message to the
//! drivelines whose torque or trigger it is ([`driveline`]) and to the tandem mills
//! whose stand it is ([`chatter`]); process values that carry a rod mill's
//! operating point go to its span stability monitor ([`rod_monitor`]). The gap maps
//! of drivelines with a model are built elsewhere ([`gap_monitor::GapMapJob`], on
//! threads of their own) and installed when ready ([`Analysis::install_gap_maps`]).

pub(crate) mod bite_window;
pub mod chatter;
pub(crate) mod context;
pub mod driveline;
mod error;
mod extra_channels;
pub(crate) mod fatigue;
pub mod fatigue_ledger;
mod flight;
pub mod gap_estimate;
pub mod gap_map;
pub(crate) mod gap_map_cache;
pub mod gap_monitor;
pub mod gap_trend;
mod pool;
pub mod rod_monitor;
mod shares;
pub(crate) mod simulated_bite;
pub mod wear;

use std::sync::{Arc, MutexGuard};
use std::time::{Duration, Instant};

use millgate_config::{Config, DrivelineThresholds, TandemMill};
use tokio::sync::{broadcast, mpsc, oneshot, watch};

use crate::field::acquired::Acquired;
use crate::state::board::Board;
use crate::state::commands::{Command, CommandReceiver};
use crate::state::events::RestoredDriveline;
use crate::state::gap_maps::{GapMapState, GapMaps};
use crate::supervision::{Liveness, ANALYSIS_TICK};
use crate::warn_limit::{WarnLimit, WARN_PERIOD};
use driveline::{BiteReport, DrivelineAnalyzer};
pub use error::AnalysisError;
use gap_estimate::GapObservation;
use gap_map::GapMapError;
use gap_monitor::{GapMapJob, GapMapsReady};
use shares::Routes;

pub use flight::MAX_ROUND_MESSAGES;

/// The analysis task: consumes samples until every reader has hung up.
#[derive(Debug)]
pub struct Analysis {
    /// Per channel: the drivelines whose torque it is.
    by_torque: Vec<Vec<usize>>,
    /// Per channel: the drivelines it triggers.
    by_trigger: Vec<Vec<usize>>,
    /// Per channel: the drivelines whose context tag it is.
    by_context: Vec<Vec<usize>>,
    /// Per channel: the drivelines whose extra channel it is, with its position in
    /// their `extra_channels`.
    by_extra: Vec<Vec<(usize, usize)>>,
    /// The drivelines' analysers and the mills' monitors, their shares in flight on
    /// the pool and the bites held for extra channels.
    flight: flight::Flight,
    board: Arc<Board>,
    /// The commands' log lines, per kind (acknowledge, wear reset, capture of a
    /// driveline, of the stands): a client may send them in a loop (the web API, an
    /// HMI, OPC UA), so each kind logs its first, then one line per period with how
    /// many it stands for. The history records each with its origin.
    command_logs: [WarnLimit; 5],
}

impl Analysis {
    /// Analysers for every driveline and chatter monitors for every tandem mill of
    /// `config`. The gap maps of drivelines with a model are not built here: take
    /// their jobs with [`Self::take_gap_map_jobs`]. A model that does not load or fit
    /// is not an error (the driveline runs without wear diagnosis, see
    /// [`Self::wear_problems`]).
    pub fn new(
        config: &Config,
        board: Arc<Board>,
        bites: broadcast::Sender<BiteReport>,
    ) -> Result<Self, AnalysisError> {
        let built = built_drivelines(config, 0)?;
        for (index, (driveline, _)) in built.iter().enumerate() {
            if let Some(problem) = driveline.wear_problem() {
                board.set_gap_maps(index, GapMapState::Failed(problem.to_string()));
            }
        }
        let chatter = chatter::ChatterAnalysis::new(config, Arc::clone(&board))?;
        let rod_mills = rod_monitor::RodAnalysis::new(config, Arc::clone(&board))?;
        let channels = config.channels.len();
        let mut analysis = Self {
            by_torque: vec![Vec::new(); channels],
            by_trigger: vec![Vec::new(); channels],
            by_context: vec![Vec::new(); channels],
            by_extra: vec![Vec::new(); channels],
            flight: flight::Flight::new(
                pool::Pool::new(workers(config.analysis.workers)),
                Arc::clone(&board),
                bites,
                flight::Mills { chatter, rod_mills },
            ),
            board,
            command_logs: std::array::from_fn(|_| WarnLimit::new(WARN_PERIOD)),
        };
        for (analyzer, routes) in built {
            analysis.push_driveline(analyzer, routes);
        }
        Ok(analysis)
    }

    /// Start analysing the drivelines `added` (built by [`AddedDrivelines::build`]
    /// off this task) after those analysed (a reload that adds drivelines after the
    /// others; `config` is the running configuration with them, its channels the ones
    /// read): each from the next block of its torque channel on, as a driveline does
    /// at a start, its results on the board, resumed from the state a history kept
    /// under its name when `added` carries one ([`AddedDrivelines::resume`]), as a
    /// start resumes it ([`Self::resume_driveline`]), before its first bite. Returns
    /// the names of the drivelines added; an error (nothing added) when `added` was
    /// built for another count of drivelines than the analysis has.
    ///
    /// The gap maps of an added driveline with a model build as at a start: take
    /// their jobs from `added` ([`AddedDrivelines::take_gap_map_jobs`]) and run them
    /// off this task once it has the drivelines; the board shows them building.
    pub fn add_drivelines(
        &mut self,
        config: &Config,
        added: AddedDrivelines,
    ) -> Result<Vec<String>, String> {
        self.flight.settle();
        let from = self.flight.drivelines.len();
        if added.from != from {
            return Err(format!(
                "drivelines built from index {} for an analysis of {from} drivelines",
                added.from
            ));
        }
        // Channels a reload appended (on a source added live): routed from now on,
        // before their reader starts.
        let channels = config.channels.len().max(self.by_torque.len());
        self.by_torque.resize(channels, Vec::new());
        self.by_trigger.resize(channels, Vec::new());
        self.by_context.resize(channels, Vec::new());
        self.by_extra.resize(channels, Vec::new());
        if added.built.is_empty() {
            return Ok(Vec::new());
        }
        self.board.add_drivelines(config);
        let names: Vec<String> = config.drivelines[from..]
            .iter()
            .map(|driveline| driveline.name.clone())
            .collect();
        for (analyzer, routes) in added.built {
            self.push_driveline(analyzer, routes);
        }
        // Before their first block: their first bite continues the counter resumed.
        for restored in &added.resumed {
            if let Some(k) = names.iter().position(|name| *name == restored.name) {
                self.resume_driveline(from + k, restored);
            }
        }
        Ok(names)
    }

    /// Analyse `analyzer` (the next driveline) on the channels of `routes`.
    fn push_driveline(&mut self, analyzer: DrivelineAnalyzer, routes: DrivelineRoutes) {
        let index = self.flight.drivelines.len();
        self.by_torque[routes.torque].push(index);
        if let Some(trigger) = routes.trigger {
            self.by_trigger[trigger].push(index);
        }
        for channel in routes.context {
            self.by_context[channel].push(index);
        }
        for (position, channel) in routes.extra.into_iter().enumerate() {
            self.by_extra[channel].push((index, position));
        }
        self.flight.add_driveline(analyzer, routes.hold);
    }

    /// Each rod mill's span count (from its mill file), in config order.
    pub fn rod_mill_spans(&self) -> Vec<usize> {
        self.flight
            .mills()
            .rod_mills
            .monitors()
            .iter()
            .map(|monitor| monitor.span_names().len())
            .collect()
    }

    /// Why drivelines that name a model run without wear diagnosis (a model that does
    /// not load, `wear` settings that do not fit it); each message names the key.
    pub fn wear_problems(&self) -> Vec<String> {
        self.flight
            .drivelines
            .iter()
            .filter_map(|driveline| {
                crate::lock(driveline)
                    .wear_problem()
                    .map(ToString::to_string)
            })
            .collect()
    }

    /// The gap map builds of the drivelines with a model (each once; later calls give
    /// none). Run each off the analysis task and hand the result to
    /// [`Self::install_gap_maps`] (or through the `maps` channel of [`Self::run`]).
    pub fn take_gap_map_jobs(&mut self) -> Vec<GapMapJob> {
        self.flight
            .drivelines
            .iter()
            .filter_map(|driveline| crate::lock(driveline).take_gap_map_job())
            .collect()
    }

    /// Driveline `index`'s analyser once its shares in flight (all of them) are
    /// done; `None` when there is no such driveline.
    fn settled_driveline(&mut self, index: usize) -> Option<MutexGuard<'_, DrivelineAnalyzer>> {
        self.flight.settle();
        self.flight.driveline(index)
    }

    /// Install driveline `index`'s gap maps, or note that they failed (logged with
    /// the error, the gap registers stay invalid); publishes the trend's estimate of
    /// the bites seen meanwhile.
    pub fn install_gap_maps(&mut self, index: usize, maps: Result<GapMaps, GapMapError>) {
        let board = Arc::clone(&self.board);
        let Some(mut driveline) = self.settled_driveline(index) else {
            return;
        };
        let maps = match maps {
            Ok(maps) => {
                let maps = Arc::new(maps);
                board.set_gap_maps(index, GapMapState::Ready(Arc::clone(&maps)));
                Some(maps)
            }
            Err(error) => {
                tracing::error!(driveline = index, %error, "no gap maps: the gap registers stay invalid");
                board.set_gap_maps(index, GapMapState::Failed(error.to_string()));
                None
            }
        };
        if let Some(estimate) = driveline.set_gap_maps(maps) {
            driveline.publish_gap(&board, &estimate);
        }
    }

    /// Continue driveline `index`'s wear trend as a history restores it at start: its
    /// saved form, or when there is none or it does not fit, `bites` folded in again
    /// (time ms since the epoch, measures; oldest first); publishes the estimate once
    /// the maps are ready.
    pub fn restore_gap_trend(
        &mut self,
        index: usize,
        saved: Option<&str>,
        bites: Vec<(i64, GapObservation)>,
    ) {
        let board = Arc::clone(&self.board);
        let Some(mut driveline) = self.settled_driveline(index) else {
            return;
        };
        if let Some(estimate) = driveline.restore_gap_trend(saved, bites) {
            driveline.publish_gap(&board, &estimate);
        }
    }

    /// Resume driveline `index` from the state a history kept of it (`restored`, under
    /// its name): its published results (bite counter, last bite's values and time,
    /// wear index and trend, gap estimate, warnings, latched alarms, flagged
    /// `restored` until its next bite), its gap's wear trend (continued from its saved
    /// form, or its bites folded in again) and its fatigue ledger (a form that is not
    /// usable is logged and the ledger starts at 0). What a start restores, and what a
    /// driveline a reload adds under a name the history knows resumes before its
    /// first bite ([`Self::add_drivelines`]).
    pub fn resume_driveline(&mut self, index: usize, restored: &RestoredDriveline) {
        let board = Arc::clone(&self.board);
        let Some(mut driveline) = self.settled_driveline(index) else {
            return;
        };
        // A driveline whose `fatigue` section was removed publishes no fatigue
        // figures: its state row still holds the last ledger's (the saved ledger stays
        // in the history, so that adding the section again resumes it).
        let no_ledger = board
            .fatigue_components()
            .get(index)
            .is_none_or(Vec::is_empty);
        board.update(|results| {
            let results = &mut results.drivelines[index];
            *results = restored.results.clone();
            if no_ledger {
                results.fatigue = None;
                results.fatigue_components.clear();
            }
        });
        let saved = restored.gap_trend.as_deref();
        if saved.is_some() || !restored.gap_bites.is_empty() {
            let bites = restored.gap_bites.iter().map(|(time, bite)| {
                let observation = GapObservation {
                    static_torque_knm: bite.static_torque_knm,
                    taf: bite.taf,
                    taf_sigma: bite.taf_sigma,
                    period_shift_s: bite.period_shift_s,
                    period_shift_sigma_s: bite.period_shift_sigma_s,
                };
                (*time, observation)
            });
            if let Some(estimate) = driveline.restore_gap_trend(saved, bites.collect()) {
                driveline.publish_gap(&board, &estimate);
            }
        }
        if let Some(ledger) = restored
            .fatigue_ledger
            .as_deref()
            .and_then(|saved| driveline.restore_fatigue(saved))
        {
            driveline.publish_fatigue(&board, &ledger, None);
        }
        tracing::info!(
            driveline = %restored.name,
            bite_counter = restored.results.bite_counter,
            wear_trend = ?restored.results.wear_trend,
            alarm_latched = restored.results.taf_alarm,
            last_bite_ms = ?restored.results.last_bite_unix_ms,
            gap_alarm_latched = restored.results.gap_alarm,
            gap_trend_saved = restored.gap_trend.is_some(),
            gap_bites = restored.gap_bites.len(),
            fatigue_ledger_saved = restored.fatigue_ledger.is_some(),
            "state restored from the history"
        );
    }

    /// Driveline `index`'s wear trend in its saved form; `None` without a model.
    pub fn gap_trend(&self, index: usize) -> Option<String> {
        self.flight.driveline(index)?.gap_trend()
    }

    /// Warn and alarm at `settings` (a reload): each driveline at its thresholds from
    /// its next bite on, each tandem mill at its chatter thresholds from its next
    /// window on. Latched alarms stay latched until acknowledged.
    pub fn set_thresholds(&mut self, settings: &LiveSettings) {
        self.flight.settle();
        for (driveline, (thresholds, horizon_days)) in
            self.flight.drivelines.iter().zip(&settings.drivelines)
        {
            crate::lock(driveline).set_thresholds((thresholds, *horizon_days));
        }
        self.flight
            .mills()
            .chatter
            .set_thresholds(&settings.tandem_mills);
    }

    /// Apply a command: acknowledge the latched alarms, or reset a driveline's wear
    /// (its TAF-ratio trend, its gap estimate and the gap's wear trend behind it).
    /// Waits for the shares in flight first (their bites are published as they end),
    /// so the command is in effect after the samples taken up before it.
    pub fn command(&mut self, command: Command) {
        // In order with the samples taken up before it.
        self.flight.settle();
        let kind = match &command {
            Command::AcknowledgeAlarms { .. } => 0,
            Command::ResetWear { .. } => 1,
            Command::CaptureTorque { .. } => 2,
            Command::CaptureStands { .. } => 3,
            Command::ResetFatigue { .. } => 4,
        };
        // `None`: this line is left out (counted in the next one logged).
        let log = self.command_logs[kind].occurred(tokio::time::Instant::now());
        match command {
            Command::AcknowledgeAlarms { origin } => {
                if let Some(suppressed) = log {
                    tracing::info!(by = origin.name(), peer = ?origin.peer(), suppressed, "alarms acknowledged");
                }
                self.board.acknowledge_alarms(origin);
            }
            Command::ResetWear { driveline, origin } => {
                let Some(mut analyzer) = self.flight.driveline(driveline) else {
                    tracing::warn!(driveline, "wear reset of a driveline that does not exist");
                    return;
                };
                if let Some(suppressed) = log {
                    tracing::info!(driveline = %self.board.driveline_names()[driveline], by = origin.name(), peer = ?origin.peer(), suppressed, "wear reset");
                }
                analyzer.reset_gap_trend();
                self.board.reset_wear(driveline, origin);
            }
            Command::ResetFatigue {
                driveline,
                component,
                origin,
            } => {
                let Some(mut analyzer) = self.flight.driveline(driveline) else {
                    tracing::warn!(
                        driveline,
                        "fatigue reset of a driveline that does not exist"
                    );
                    return;
                };
                match analyzer.reset_fatigue(component) {
                    Some((name, life_used, ledger)) => {
                        if let Some(suppressed) = log {
                            tracing::info!(driveline = %self.board.driveline_names()[driveline], component = %name, life_used, by = origin.name(), peer = ?origin.peer(), suppressed, "fatigue reset");
                        }
                        analyzer.publish_fatigue(
                            &self.board,
                            &ledger,
                            Some((component, name, life_used, origin)),
                        );
                    }
                    None => {
                        tracing::warn!(driveline = %self.board.driveline_names()[driveline], component, by = origin.name(), "fatigue reset refused: the driveline has no such fatigue component")
                    }
                }
            }
            Command::CaptureTorque {
                driveline,
                seconds,
                origin,
            } => {
                let Some(mut analyzer) = self.flight.driveline(driveline) else {
                    tracing::warn!(
                        driveline,
                        "manual capture of a driveline that does not exist"
                    );
                    return;
                };
                let names = self.board.driveline_names();
                let name = &names[driveline];
                let started = analyzer.start_manual_capture(f64::from(seconds));
                match (log, started) {
                    (None, _) => {}
                    (Some(suppressed), true) => {
                        tracing::info!(driveline = %name, seconds, by = origin.name(), peer = ?origin.peer(), suppressed, "manual capture started")
                    }
                    (Some(suppressed), false) => {
                        tracing::warn!(driveline = %name, by = origin.name(), suppressed, "manual capture refused: captures are not kept (no [history], or history.captures = false)")
                    }
                }
            }
            Command::CaptureStands {
                mill,
                seconds,
                origin,
            } => {
                let started = self
                    .flight
                    .mills()
                    .chatter
                    .start_manual_capture(mill, f64::from(seconds));
                match (log, started) {
                    (None, _) => {}
                    (Some(suppressed), true) => tracing::info!(mill, seconds, by = origin.name(), peer = ?origin.peer(), suppressed, "manual capture of the stands started"),
                    (Some(suppressed), false) => tracing::warn!(mill, by = origin.name(), suppressed, "manual capture of the stands refused: no such tandem mill, or captures are not kept (no [history], or history.captures = false)"),
                }
            }
        }
    }

    /// Handle one message from a reader; returns the bites it released (see
    /// [`Self::handle_all`]).
    pub fn handle(&mut self, message: Acquired) -> Vec<BiteReport> {
        self.handle_all(vec![message])
    }

    /// Handle the messages from the readers that are ready together, in their order,
    /// and wait until every driveline's share of them is done; returns the bites they
    /// released: published and recorded. What [`Self::run`] does without the wait
    /// ([`Self::take_up`]).
    pub fn handle_all(&mut self, messages: Vec<Acquired>) -> Vec<BiteReport> {
        let mut released = self.take_up(messages);
        released.extend(self.flight.settle());
        released
    }

    /// Take `messages` up, in their order: each driveline's share of them starts now
    /// (or after its share in flight), and so does the mills' (every message). Does
    /// not wait for the shares on the pool; returns the bites released meanwhile
    /// (published and recorded): those of the shares that ran on this thread and of
    /// those that ended on the pool. A bite of a
    /// driveline with extra channels is held until every one has samples up to the
    /// end of its window, or its hold bound passes ([`Self::release_held`]); any
    /// other bite is released as soon as its share ends.
    pub fn take_up(&mut self, messages: Vec<Acquired>) -> Vec<BiteReport> {
        let latencies = self.board.latencies();
        for message in &messages {
            if let Acquired::Samples { handed, .. } = message {
                latencies.block_taken(handed.elapsed());
            }
        }
        let messages: Vec<Arc<Acquired>> = messages.into_iter().map(Arc::new).collect();
        let routes = Routes {
            by_torque: &self.by_torque,
            by_trigger: &self.by_trigger,
            by_context: &self.by_context,
            by_extra: &self.by_extra,
        };
        let shares = routes.steps(&messages, self.flight.drivelines.len());
        self.flight.take_up(messages, shares)
    }

    /// Release the held bites (in the order they completed, per driveline) whose
    /// extra channels reach the end of their window, whose bound has passed at `now`,
    /// or all when `all` (once the shares in flight ended): their captures take what
    /// the rings hold, and they are published and recorded together. Returns them.
    pub fn release_held(&mut self, now: Instant, all: bool) -> Vec<BiteReport> {
        self.flight.release_held(now, all)
    }

    /// Run until every sender of `samples` is dropped, installing gap maps as they
    /// arrive on `maps`, applying commands as they arrive on `commands` (in order with
    /// the samples: a command given before a bite is in effect at that bite), and
    /// counting each turn of the loop (a message handled, or [`ANALYSIS_TICK`] without
    /// one) in `liveness`: a watchdog sees a stuck analysis as turns that stop. New
    /// `thresholds` (a reload) take effect in order with the samples, like commands,
    /// and so do drivelines a reload adds (`additions`), once the shares in flight
    /// ended.
    pub async fn run(
        mut self,
        mut samples: mpsc::Receiver<Acquired>,
        mut maps: mpsc::Receiver<GapMapsReady>,
        (mut commands, mut thresholds, mut additions): (
            CommandReceiver,
            watch::Receiver<LiveSettings>,
            mpsc::Receiver<DrivelineAddition>,
        ),
        liveness: Arc<Liveness>,
    ) {
        let mut idle = tokio::time::interval(ANALYSIS_TICK);
        idle.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        let mut maps_open = true;
        let mut commands_open = true;
        let mut thresholds_open = true;
        let mut additions_open = true;
        let ended = self.flight.woken();
        loop {
            tokio::select! {
                biased;
                command = commands.recv(), if commands_open => match command {
                    Some(command) => self.command(command),
                    None => commands_open = false,
                },
                changed = thresholds.changed(), if thresholds_open => match changed {
                    Ok(()) => {
                        let settings = thresholds.borrow_and_update().clone();
                        self.set_thresholds(&settings);
                    }
                    Err(_) => thresholds_open = false,
                },
                addition = additions.recv(), if additions_open => match addition {
                    Some(DrivelineAddition { config, drivelines, done }) => {
                        let _ = done.send(self.add_drivelines(&config, drivelines));
                    }
                    None => additions_open = false,
                },
                () = ended.notified(), if self.flight.any() => {
                    self.flight.finished();
                }
                message = samples.recv() => match message {
                    Some(message) => {
                        // With it, whatever else is ready.
                        let mut ready = vec![message];
                        while ready.len() < MAX_ROUND_MESSAGES {
                            match samples.try_recv() {
                                Ok(message) => ready.push(message),
                                Err(_) => break,
                            }
                        }
                        self.take_up(ready);
                    }
                    None => break,
                },
                ready = maps.recv(), if maps_open => match ready {
                    Some((index, result)) => self.install_gap_maps(index, result),
                    None => maps_open = false,
                },
                _ = idle.tick() => {
                    self.release_held(Instant::now(), false);
                }
            }
            liveness.analysis_turned();
        }
        // The readers are gone: no more extra samples will come.
        self.release_held(Instant::now(), true);
    }
}

/// Drivelines a reload adds after the others ([`Analysis::add_drivelines`]).
#[derive(Debug)]
pub struct DrivelineAddition {
    /// The running configuration with them (its channels the ones read).
    pub config: Arc<Config>,
    /// Their analysers, built off the analysis task.
    pub drivelines: AddedDrivelines,
    /// Told the names of the drivelines the analysis added, or why it added none.
    pub done: oneshot::Sender<Result<Vec<String>, String>>,
}

/// The analysers of drivelines a reload adds after the others, built (their models
/// loaded, their linear wear references simulated) before the analysis takes them,
/// so it does not stop for that.
#[derive(Debug)]
pub struct AddedDrivelines {
    /// Index of the first in the configuration.
    from: usize,
    built: Vec<(DrivelineAnalyzer, DrivelineRoutes)>,
    /// The state a history kept of those it knows by name, read off the analysis.
    resumed: Vec<RestoredDriveline>,
}

impl AddedDrivelines {
    /// The analysers of `config`'s drivelines from index `from` on (none when `from`
    /// is their count). An error names the first driveline the analysis cannot be
    /// built for, or whose model does not load or fit its `wear` settings (a start
    /// refuses such a file too).
    pub fn build(config: &Config, from: usize) -> Result<Self, AnalysisError> {
        let mut built = built_drivelines(config, from)?;
        if let Some(problem) = built
            .iter_mut()
            .find_map(|(analyzer, _)| analyzer.take_wear_problem())
        {
            return Err(problem);
        }
        Ok(Self {
            from,
            built,
            resumed: Vec::new(),
        })
    }

    /// Resume those of them a history knows by name from the state it kept
    /// (`restored`, read off the analysis task: the analysis only applies it).
    pub fn resume(&mut self, restored: Vec<RestoredDriveline>) {
        self.resumed = restored;
    }

    /// No driveline added after the first `from` (a reload that adds sources only:
    /// the analysis routes their channels).
    pub fn none(from: usize) -> Self {
        Self {
            from,
            built: Vec::new(),
            resumed: Vec::new(),
        }
    }

    /// Their gap map builds, as [`Analysis::take_gap_map_jobs`] gives a start's (each
    /// once).
    pub fn take_gap_map_jobs(&mut self) -> Vec<GapMapJob> {
        self.built
            .iter_mut()
            .filter_map(|(analyzer, _)| analyzer.take_gap_map_job())
            .collect()
    }
}

/// The settings a reload changes in the running analysis (`service::reload`), in
/// config order.
#[derive(Debug, Clone, PartialEq)]
pub struct LiveSettings {
    /// Each driveline's TAF and gap thresholds and its forecasts' horizon
    /// (`wear.horizon_days`).
    pub drivelines: Vec<(DrivelineThresholds, f64)>,
    /// Each tandem mill: its chatter thresholds apply (`gain_thresholds`, the
    /// slow-down's release and hold, the weld hold), the rest runs as it started.
    pub tandem_mills: Vec<TandemMill>,
}

impl LiveSettings {
    /// The settings of `config`.
    pub fn of(config: &Config) -> Self {
        Self {
            drivelines: config
                .drivelines
                .iter()
                .map(|driveline| (driveline.thresholds, driveline.wear.horizon_days))
                .collect(),
            tandem_mills: config.tandem_mills.clone(),
        }
    }
}

/// The channels (indices in `config.channels`) whose messages go to a driveline's
/// analyser, and how long its bites wait for its extra channels.
#[derive(Debug)]
struct DrivelineRoutes {
    torque: usize,
    trigger: Option<usize>,
    context: Vec<usize>,
    /// Its extra channels, in order, when captures are kept.
    extra: Vec<usize>,
    hold: Duration,
}

/// The analysers of `config`'s drivelines from index `from` on, with their routes; the
/// first error when one cannot be built.
fn built_drivelines(
    config: &Config,
    from: usize,
) -> Result<Vec<(DrivelineAnalyzer, DrivelineRoutes)>, AnalysisError> {
    let cache_dir = config
        .cache_dir
        .clone()
        .unwrap_or_else(gap_map_cache::default_dir);
    let captures = config
        .history
        .as_ref()
        .is_some_and(|history| history.captures.enabled);
    let drivelines = config.drivelines.get(from..).unwrap_or_default();
    let mut built = Vec::with_capacity(drivelines.len());
    for (index, driveline) in (from..).zip(drivelines) {
        let torque = &config.channels[driveline.torque];
        let mut analyzer = DrivelineAnalyzer::new(index, driveline, torque, &cache_dir)?;
        let context = analyzer.track_context(driveline, config);
        let hold = extra_channel_hold(config, &driveline.extra_channels);
        let mut extra = Vec::new();
        if captures {
            let extra_channels: Vec<_> = driveline
                .extra_channels
                .iter()
                .map(|&channel| &config.channels[channel])
                .collect();
            let window_s = driveline.bite.pre_trigger_s + driveline.bite.post_trigger_s;
            // The window, the hold, and as much again for a channel ahead of the
            // torque by up to the hold.
            let ring =
                ((window_s + 2.0 * hold.as_secs_f64()) * torque.sample_rate_hz).ceil() as usize + 1;
            analyzer.keep_captures(torque, &extra_channels, ring);
            extra.clone_from(&driveline.extra_channels);
        }
        let routes = DrivelineRoutes {
            torque: driveline.torque,
            trigger: driveline.metal_in_stand,
            context,
            extra,
            hold,
        };
        built.push((analyzer, routes));
    }
    Ok(built)
}

/// The analysis pool's threads for `analysis.workers` = `configured`: as many when
/// not 0, else one per core the machine offers (1 when it does not say).
fn workers(configured: usize) -> usize {
    match configured {
        0 => std::thread::available_parallelism().map_or(1, std::num::NonZeroUsize::get),
        workers => workers,
    }
}

/// Least time a bite waits for its extra channels.
const MIN_EXTRA_HOLD: Duration = Duration::from_millis(200);

/// How long a bite of a driveline with `extra_channels` (indices into
/// `config.channels`) waits for them: for each, the larger of [`MIN_EXTRA_HOLD`] and
/// two poll periods of its Modbus source (a block that was not ready at one poll is
/// read at the next); the largest over the channels; zero without any.
fn extra_channel_hold(config: &Config, extra_channels: &[usize]) -> Duration {
    extra_channels
        .iter()
        .map(|&channel| match config.channels[channel].source {
            millgate_config::ChannelSource::ModbusBlock { source, .. }
            | millgate_config::ChannelSource::ModbusValue { source, .. } => {
                (2 * config.modbus_sources[source].poll_period).max(MIN_EXTRA_HOLD)
            }
            _ => MIN_EXTRA_HOLD,
        })
        .max()
        .unwrap_or(Duration::ZERO)
}
