//! The live results board: the latest [`Results`] the analysis produced, joined with
//! the sources' health, for every output to read (each encodes them its own way: the
//! PLC writer and the HMI server through their register map, the others through the
//! [`super::catalogue`]). The analysis writes it; changes are recorded in the
//! history under the same lock.

use std::sync::{Arc, Mutex};

use millgate_config::Config;

use super::catalogue::{Subject, Value};
use super::changes::{Changes, Signal};
use super::events::{
    AlarmEvent, AlarmKind, AlarmRecord, HistoryEvent, StateRecord, SubjectResults,
};
use super::gap_maps::GapMapState;
use super::history::History;
use super::latency::Latencies;
use super::results::Results;
use super::time::UtcTime;
use crate::field::source_health::{SourceHealth, SourceStatus};
use crate::state::commands::CommandOrigin;

/// Shared between the analysis task (writes results) and the outputs (read them).
#[derive(Debug)]
pub struct Board {
    results: Mutex<Results>,
    /// The change signal every output waits on (its history's: [`Self::with_history`]).
    signal: Signal,
    health: Mutex<Vec<Arc<SourceHealth>>>,
    /// The source statuses of the final image, once the service stops.
    frozen_health: Mutex<Option<Vec<SourceStatus>>>,
    /// The drivelines' names, fatigue components and sources: a reload that adds
    /// drivelines grows them ([`Self::add_drivelines`]).
    drivelines: Mutex<DrivelineShape>,
    tandem_mill_names: Vec<String>,
    /// Indices of the sources of each tandem mill's stand channels.
    tandem_mill_sources: Vec<Vec<usize>>,
    /// Indices of the sources of each rod mill's input channels.
    rod_mill_sources: Vec<Vec<usize>>,
    /// Where changes are recorded (disabled without `[history]`).
    history: History,
    /// Each driveline's gap maps, for the outputs that draw them.
    gap_maps: Mutex<Vec<GapMapState>>,
    /// The block wait and bite -> PLC histograms, and the bites waiting for the PLC.
    latencies: Arc<Latencies>,
}

/// The results the PLC writer writes next ([`Board::results_for_plc`]).
#[derive(Debug)]
pub(crate) struct PlcImage {
    /// The results, source health applied.
    pub(crate) results: Results,
    /// The stamps of the bites these results show first (no write carried them yet).
    pub(crate) bites: Vec<crate::state::latency::BiteStamps>,
    /// History events recorded up to these results: a write of them waits until the
    /// history has settled this many ([`History::wait_settled`]).
    pub(crate) through: u64,
    /// The change signal's results version when they were taken.
    pub(crate) version: u64,
}

/// What the board knows of the drivelines besides their results, in config order.
#[derive(Debug)]
struct DrivelineShape {
    names: Arc<[String]>,
    /// Per driveline, its fatigue ledger's components (empty without a ledger).
    fatigue_components: Arc<[Vec<String>]>,
    /// Index in [`Config::sources`] of each driveline's torque channel's source.
    sources: Arc<[usize]>,
}

impl DrivelineShape {
    /// The drivelines of `config`.
    fn of(config: &Config) -> Self {
        let drivelines = &config.drivelines;
        Self {
            names: drivelines.iter().map(|d| d.name.clone()).collect(),
            fatigue_components: drivelines
                .iter()
                .map(|d| {
                    d.fatigue.as_ref().map_or_else(Vec::new, |f| {
                        f.components.iter().map(|c| c.name.clone()).collect()
                    })
                })
                .collect(),
            sources: drivelines
                .iter()
                .map(|d| config.source_of_channel(d.torque))
                .collect(),
        }
    }
}

/// The gap maps of `driveline` before any is built.
fn gap_maps_at_start(driveline: &millgate_config::Driveline) -> GapMapState {
    match driveline.model {
        Some(_) => GapMapState::Building { done: 0, total: 0 },
        None => GapMapState::NoModel,
    }
}

impl Board {
    /// A board for `config` with one health record per source, in the order of
    /// [`Config::sources`].
    pub fn new(config: &Config, health: Vec<Arc<SourceHealth>>) -> Self {
        let mut results = Results::new(
            health.len(),
            config.drivelines.len(),
            config.tandem_mills.len(),
        );
        results.rod_mills = vec![Default::default(); config.rod_mills.len()];
        let sources_of = |channels: &mut dyn Iterator<Item = usize>| -> Vec<usize> {
            channels.map(|c| config.source_of_channel(c)).collect()
        };
        Self {
            results: Mutex::new(results),
            signal: Signal::default(),
            health: Mutex::new(health),
            frozen_health: Mutex::new(None),
            drivelines: Mutex::new(DrivelineShape::of(config)),
            tandem_mill_names: config.tandem_mills.iter().map(|m| m.name.clone()).collect(),
            tandem_mill_sources: config
                .tandem_mills
                .iter()
                .map(|m| sources_of(&mut m.stands.iter().copied()))
                .collect(),
            rod_mill_sources: config
                .rod_mills
                .iter()
                .map(|m| {
                    let inputs = [m.configuration, m.pass, m.finishing_speed];
                    sources_of(&mut inputs.into_iter().chain(m.temperature))
                })
                .collect(),
            history: History::disabled(),
            gap_maps: Mutex::new(config.drivelines.iter().map(gap_maps_at_start).collect()),
            latencies: Arc::default(),
        }
    }

    /// The latency histograms (for `/metrics`, the analysis and the PLC writer).
    pub fn latencies(&self) -> &Arc<Latencies> {
        &self.latencies
    }

    /// Driveline `index`'s gap maps.
    pub fn gap_maps(&self, index: usize) -> Option<GapMapState> {
        crate::lock(&self.gap_maps).get(index).cloned()
    }

    /// Set driveline `index`'s gap maps (a progress report of a build that has
    /// finished or failed is ignored).
    pub fn set_gap_maps(&self, index: usize, state: GapMapState) {
        let mut maps = crate::lock(&self.gap_maps);
        if let Some(slot) = maps.get_mut(index) {
            let late = matches!(state, GapMapState::Building { .. })
                && !matches!(slot, GapMapState::Building { .. });
            if !late {
                *slot = state;
            }
        }
    }

    /// This board recording into `history`, signalling its changes on the history's
    /// signal (so one `Changes` sees the results and what the history stored).
    pub fn with_history(mut self, history: History) -> Self {
        self.signal = history.signal();
        self.history = history;
        self
    }

    /// The history changes are recorded into.
    pub fn history(&self) -> &History {
        &self.history
    }

    /// Driveline names, in config order (a reload may add some at the end).
    pub(crate) fn driveline_names(&self) -> Arc<[String]> {
        Arc::clone(&crate::lock(&self.drivelines).names)
    }

    /// Per driveline (config order), its fatigue ledger's component names (empty
    /// without `drivelines[].fatigue`).
    pub(crate) fn fatigue_components(&self) -> Arc<[Vec<String>]> {
        Arc::clone(&crate::lock(&self.drivelines).fatigue_components)
    }

    /// Add the drivelines of `config` after those the board has (a reload that adds
    /// drivelines after the others, `config` being the running one with them): their
    /// results start empty, as at a start, and the outputs are woken. Returns how many
    /// were added. The drivelines the board has are `config`'s first ones.
    pub(crate) fn add_drivelines(&self, config: &Config) -> usize {
        let mut results = crate::lock(&self.results);
        let mut shape = crate::lock(&self.drivelines);
        let Some(added) = config.drivelines.get(shape.names.len()..) else {
            return 0;
        };
        if added.is_empty() {
            return 0;
        }
        results
            .drivelines
            .resize(config.drivelines.len(), Default::default());
        *shape = DrivelineShape::of(config);
        crate::lock(&self.gap_maps).extend(added.iter().map(gap_maps_at_start));
        drop((shape, results));
        self.signal.results_changed();
        added.len()
    }

    /// Tandem mill names, in config order.
    pub(crate) fn tandem_mill_names(&self) -> &[String] {
        &self.tandem_mill_names
    }

    /// Change the results.
    pub fn update<T>(&self, change: impl FnOnce(&mut Results) -> T) -> T {
        self.update_recorded(|results, _| change(results))
    }

    /// Change the results and record what happened (the events `change` pushes) in
    /// the history, under one lock: whoever reads the results after this call finds
    /// the events already counted in [`History::enqueued`], which is what lets the
    /// PLC writer wait until a bite it writes is stored.
    pub(crate) fn update_recorded<T>(
        &self,
        change: impl FnOnce(&mut Results, &mut Vec<HistoryEvent>) -> T,
    ) -> T {
        self.update_recorded_if(|results, events| (change(results, events), true))
    }

    /// As [`Self::update_recorded`], for bites whose windows blocks handed over at
    /// `handed` completed: their stamps wait, with the results, for the PLC writer
    /// ([`Self::results_for_plc`]). The bites of the analysis' shares that ended
    /// together go in one call: one change for the outputs, the PLC write and the
    /// history commit that follow carry them all.
    pub(crate) fn update_bites_recorded<T>(
        &self,
        handed: impl IntoIterator<Item = std::time::Instant>,
        change: impl FnOnce(&mut Results, &mut Vec<HistoryEvent>) -> T,
    ) -> T {
        self.update_recorded(|results, events| {
            for handed in handed {
                self.latencies.published(handed);
            }
            change(results, events)
        })
    }

    /// As [`Self::update_recorded`], waking the outputs only when `change` says it
    /// changed the results (the `bool` it returns).
    fn update_recorded_if<T>(
        &self,
        change: impl FnOnce(&mut Results, &mut Vec<HistoryEvent>) -> (T, bool),
    ) -> T {
        let mut results = crate::lock(&self.results);
        let mut events = Vec::new();
        let (value, changed) = change(&mut results, &mut events);
        for event in events {
            self.history.record(event);
        }
        drop(results);
        if changed {
            self.signal.results_changed();
        }
        value
    }

    /// A waiter on the change signal that has seen everything up to now: what every
    /// output waits on (see `super::changes`).
    pub fn changes(&self) -> Changes {
        self.signal.subscribe()
    }

    /// A copy of the results with current source health applied.
    pub fn results(&self) -> Results {
        let mut results = crate::lock(&self.results).clone();
        self.apply_health(&mut results);
        results
    }

    /// What the PLC writer writes next: a copy of the results (as [`Self::results`])
    /// and, taken under the same lock, the stamps of the bites published in them that
    /// no PLC write carried yet (observed once the PLC acknowledged the write:
    /// [`Latencies::written`]) and the count of history events recorded with them
    /// (the write waits until the history has settled exactly those).
    pub(crate) fn results_for_plc(&self) -> PlcImage {
        let locked = crate::lock(&self.results);
        let image = self.image_locked(&locked, Vec::new());
        drop(locked);
        self.with_health(image)
    }

    /// `image` brought up to the results now when the history has already settled
    /// every event recorded with them (a bite published while the writer waited for
    /// the commit of `image`'s, and committed with them or since): the write then
    /// carries it too, instead of the next write after this one. Returns whether it
    /// moved; `image` is left as it is otherwise.
    pub(crate) fn newer_settled_for_plc(&self, image: &mut PlcImage) -> bool {
        let locked = crate::lock(&self.results);
        let version = self.signal.now().results;
        let through = self.history.enqueued();
        if version == image.version || !self.history.settled_now(through) {
            return false;
        }
        let newer = self.image_locked(&locked, std::mem::take(&mut image.bites));
        drop(locked);
        *image = self.with_health(newer);
        true
    }

    /// A [`PlcImage`] of `locked` (the results under their lock), its stamps after
    /// `carried`, health not applied yet.
    fn image_locked(
        &self,
        locked: &Results,
        mut carried: Vec<crate::state::latency::BiteStamps>,
    ) -> PlcImage {
        carried.extend(self.latencies.take_waiting());
        PlcImage {
            results: locked.clone(),
            bites: carried,
            through: self.history.enqueued(),
            version: self.signal.now().results,
        }
    }

    fn with_health(&self, mut image: PlcImage) -> PlcImage {
        self.apply_health(&mut image.results);
        image
    }

    /// Keep the source statuses as they are now in every later image: the readers are
    /// about to stop, and a source they stop reading is not a source gone stale. The
    /// final image of an orderly stop shows the sources as they were while running.
    pub(crate) fn freeze_health(&self) {
        let statuses = self.statuses();
        *crate::lock(&self.frozen_health) = Some(statuses);
    }

    /// Each source's status now, in the order of [`Config::sources`].
    fn statuses(&self) -> Vec<SourceStatus> {
        crate::lock(&self.health)
            .iter()
            .map(|h| h.status())
            .collect()
    }

    /// Show the sources a reload added (after the others, in the order of
    /// [`Config::sources`]) by their `health`.
    pub(crate) fn add_sources(&self, health: &[Arc<SourceHealth>]) {
        crate::lock(&self.health).extend(health.iter().cloned());
        self.signal.results_changed();
    }

    fn apply_health(&self, results: &mut Results) {
        let frozen = crate::lock(&self.frozen_health).clone();
        let statuses: Vec<SourceStatus> = frozen.unwrap_or_else(|| self.statuses());
        results.sources = statuses.iter().copied().map(Some).collect();
        let bad = |source: &usize| {
            statuses
                .get(*source)
                .is_some_and(|s| *s != SourceStatus::Ok)
        };
        let sources = Arc::clone(&crate::lock(&self.drivelines).sources);
        for (driveline, source) in results.drivelines.iter_mut().zip(sources.iter()) {
            driveline.source_stale = bad(source);
        }
        // A mill is also flagged by its analysis (a gap restarted its window).
        for (mill, sources) in results
            .tandem_mills
            .iter_mut()
            .zip(&self.tandem_mill_sources)
        {
            mill.source_stale |= sources.iter().any(bad);
        }
        for (mill, sources) in results.rod_mills.iter_mut().zip(&self.rod_mill_sources) {
            mill.source_stale = sources.iter().any(bad);
        }
    }

    /// Increment the heartbeat counter (each PLC write period, or each second
    /// without a PLC output), so a watchdog sees the gateway alive.
    /// Not a change of the results: waiters on [`Self::changes`] are not woken (the
    /// PLC writer beats on each write and would wake itself).
    pub fn beat(&self) {
        let mut results = crate::lock(&self.results);
        results.heartbeat = results.heartbeat.wrapping_add(1);
    }

    /// Forget driveline `index`'s wear trend and gap estimate (the analysis applies a
    /// [`super::commands::Command::ResetWear`] through this and empties the gap pool it
    /// holds); `origin` says who, for the history.
    pub fn reset_wear(&self, index: usize, origin: CommandOrigin) {
        let time = UtcTime::now();
        let names = self.driveline_names();
        self.update_recorded(|results, events| {
            if let Some(driveline) = results.drivelines.get_mut(index) {
                driveline.wear_trend = None;
                driveline.gap = None;
                if driveline.gap_warning {
                    driveline.gap_warning = false;
                    events.push(HistoryEvent::Alarm(AlarmRecord {
                        time,
                        subject: names[index].clone(),
                        kind: AlarmKind::GapWarning,
                        event: AlarmEvent::Cleared,
                        origin: Some(origin),
                        value: None,
                        threshold: None,
                    }));
                }
                events.push(HistoryEvent::WearReset {
                    time,
                    driveline: names[index].clone(),
                    origin,
                });
                events.push(state_record(
                    time,
                    &names[index],
                    SubjectResults::Driveline(Box::new(driveline.clone())),
                ));
            }
        });
    }

    /// Clear latched alarms (the analysis applies a
    /// [`super::commands::Command::AcknowledgeAlarms`] through this); `origin` says who,
    /// for the history, which records each alarm that was latched and the state of
    /// each subject after it.
    pub fn acknowledge_alarms(&self, origin: CommandOrigin) {
        let time = UtcTime::now();
        let names = self.driveline_names();
        // Nothing latched, nothing changes: the outputs are not woken (an acknowledge
        // sent in a loop made a PLC write each).
        self.update_recorded_if(|results, events| {
            for (driveline, name) in results.drivelines.iter_mut().zip(names.iter()) {
                if acknowledge(driveline, name, (time, origin), events) {
                    events.push(state_record(
                        time,
                        name,
                        SubjectResults::Driveline(Box::new(driveline.clone())),
                    ));
                }
            }
            for (mill, name) in results.tandem_mills.iter_mut().zip(&self.tandem_mill_names) {
                if acknowledge(mill, name, (time, origin), events) {
                    events.push(state_record(
                        time,
                        name,
                        SubjectResults::TandemMill(Box::new(mill.clone())),
                    ));
                }
            }
            ((), !events.is_empty())
        });
    }
}

fn state_record(time: UtcTime, subject: &str, results: SubjectResults) -> HistoryEvent {
    HistoryEvent::State(StateRecord {
        time,
        subject: subject.to_owned(),
        results,
    })
}

/// Clear the latched alarms of `subject` (its catalogue flags that latch), recording
/// each one that was set as acknowledged by `origin` at `time`; whether any was.
fn acknowledge<R: Subject>(
    subject: &mut R,
    name: &str,
    (time, origin): (UtcTime, CommandOrigin),
    events: &mut Vec<HistoryEvent>,
) -> bool {
    let mut any = false;
    for figure in R::FIGURES.iter().filter(|figure| figure.latched) {
        let Some(kind) = figure.alarm else { continue };
        if figure.value(subject) == Some(Value::Bool(true)) {
            let cleared = figure.set(subject, Some(Value::Bool(false)));
            debug_assert!(cleared, "{}: a latched flag needs its setter", figure.key);
            events.push(HistoryEvent::Alarm(AlarmRecord {
                time,
                subject: name.to_owned(),
                kind,
                event: AlarmEvent::Acknowledged,
                origin: Some(origin),
                value: None,
                threshold: None,
            }));
            any = true;
        }
    }
    any
}

#[cfg(test)]
mod tests {
    use std::time::Duration;

    use super::*;

    /// Whether the results changed within a second.
    async fn woken(changes: &mut Changes) -> bool {
        tokio::time::timeout(Duration::from_secs(1), changes.results())
            .await
            .is_ok()
    }

    /// An acknowledge with no alarm latched changes nothing and wakes no output (the
    /// round-4 audit's acknowledges in a loop made 2 300 PLC writes a second); one
    /// with an alarm latched clears it and wakes them.
    #[tokio::test(start_paused = true)]
    async fn an_acknowledge_wakes_the_outputs_only_when_it_clears_an_alarm() {
        let config = crate::testing::example_config("demo.toml");
        let board = Board::new(&config, Vec::new());
        let mut changes = board.changes();
        board.acknowledge_alarms(CommandOrigin::Local);
        assert!(!woken(&mut changes).await, "nothing latched: no change");
        board.update(|results| results.drivelines[0].taf_alarm = true);
        assert!(woken(&mut changes).await);
        board.acknowledge_alarms(CommandOrigin::Local);
        assert!(woken(&mut changes).await, "an alarm cleared: a change");
        assert!(!board.results().drivelines[0].taf_alarm);
    }

    /// Publish a bite of driveline 0 handed over at `handed`, counted `counter`, with
    /// one history event.
    fn bite(board: &Board, handed: std::time::Instant, counter: u32) {
        board.update_bites_recorded([handed], |results, events| {
            results.drivelines[0].bite_counter = counter;
            events.push(HistoryEvent::WearReset {
                time: UtcTime::now(),
                driveline: "F1".into(),
                origin: CommandOrigin::Local,
            });
        });
    }

    /// The PLC writer's copy waits for exactly the history events recorded with its
    /// results; newer results replace it only once their own events are settled, and
    /// then carry the bites of both; a writer that took them is not woken for them
    /// again.
    #[tokio::test(start_paused = true)]
    async fn the_plc_image_waits_for_its_own_events_and_takes_newer_settled_ones() {
        let config = crate::testing::example_config("demo.toml");
        let settings = millgate_config::History {
            // Never opened: no writer runs, the test settles events itself.
            path: std::env::temp_dir().join("millgate-board-plc-image-unused.db"),
            retention_days: 1,
            max_size_mb: 16,
            captures: millgate_config::CaptureSettings::defaults(16),
            synchronous: millgate_config::Synchronous::default(),
        };
        let history = History::new(Some(&settings));
        let board = Board::new(&config, Vec::new()).with_history(history.clone());
        let _writer = board.latencies().plc_writer();
        let mut changes = board.changes();
        let (first, second) = (
            std::time::Instant::now(),
            std::time::Instant::now() + Duration::from_millis(1),
        );
        bite(&board, first, 1);
        let mut image = board.results_for_plc();
        let handed = |image: &PlcImage| image.bites.iter().map(|b| b.handed).collect::<Vec<_>>();
        assert_eq!((image.through, handed(&image)), (1, vec![first]));
        bite(&board, second, 2);
        assert_eq!(history.enqueued(), 2);
        assert_eq!(image.through, 1, "the later bite's event is not waited for");
        assert!(!history.settled_now(image.through));
        history.signal().settled(1);
        assert!(history.settled_now(image.through));
        assert!(
            !board.newer_settled_for_plc(&mut image),
            "the newer results' event is not committed yet"
        );
        assert_eq!(image.results.drivelines[0].bite_counter, 1);
        history.signal().settled(2);
        assert!(board.newer_settled_for_plc(&mut image));
        assert_eq!(image.results.drivelines[0].bite_counter, 2);
        assert_eq!((image.through, handed(&image)), (2, vec![first, second]));
        assert!(
            image.bites[1].taken >= image.bites[0].taken,
            "the bite taken after the wait was taken then"
        );
        assert!(!board.newer_settled_for_plc(&mut image), "nothing newer");
        changes.saw_results(image.version);
        assert!(!woken(&mut changes).await, "the image showed it all");
        bite(&board, second, 3);
        assert!(woken(&mut changes).await);
    }
}
