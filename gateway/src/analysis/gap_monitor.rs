//! One driveline's gap diagnosis: its maps (built off the analysis task), the wear
//! trend of its bites, the published estimate and forecast, and the wear state.
//!
//! - **Maps** come from a [`GapMapJob`]: the cache when it holds maps for this model
//!   and these settings (`gap_map_cache`), else a build on its own threads
//!   ([`super::gap_map::build`]). Until they are installed the gap registers stay
//!   invalid; bites seen meanwhile are held (at most `MAX_PENDING`, 1000, the newest) and
//!   folded into the trend once the maps arrive. A build that fails leaves them invalid
//!   for good (the error is logged, naming the model file).
//! - **Trend** ([`super::gap_trend`]): every bite since the last wear reset, in time
//!   order: the gap at the last bite with its 90% interval, its growth, and the days
//!   until it reaches `thresholds.gap_alarm_mrad`.
//! - **Wear state**: warning while the estimated gap is at or above
//!   `thresholds.gap_warning_mrad`; alarm, latched until acknowledged
//!   (`command.acknowledge_alarms`), once the whole 90% interval is at or above
//!   `thresholds.gap_alarm_mrad` (the gap is that large with 95% confidence). The
//!   forecast says when the gap itself reaches the threshold: the alarm bit follows
//!   later, once the interval's low end is there too.
//! - **Reset** (`command.reset_wear_trend`, e.g. after a coupling was replaced): the
//!   trend starts again with the next bite; the estimate is invalid until then.

use std::collections::VecDeque;
use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use std::sync::Arc;
use std::time::Instant;

use millgate_config::{DrivelineThresholds, WearSettings};
use millgate_dsp::transient::{TransientResult, TransientSettings};
use millgate_dsp::wear_trend::TrendError;

use super::gap_estimate::{GapEstimate, GapObservation};
use super::gap_map::{build, GapMapError};
use super::gap_map_cache;
use super::gap_trend::{Folded, GapTrend};
use super::simulated_bite::BiteSimulator;
use crate::state::events::{AlarmEvent, AlarmKind, AlarmRecord, HistoryEvent, WearState};
use crate::state::gap_maps::{GapMapSpec, GapMaps};
use crate::state::results::{DrivelineResults, GapResults};
use crate::state::time::UtcTime;

/// What a bite adds to the gap diagnosis.
#[derive(Debug, Clone, PartialEq)]
pub struct GapBite {
    /// The bite's measures and their uncertainty (what a history stores to fold it
    /// in again).
    pub observation: GapObservation,
    /// The estimate from this bite alone, once the maps are ready.
    pub bite: Option<GapEstimate>,
    /// The trend's estimate and forecast after this bite, once the maps are ready.
    pub trend: Option<GapResults>,
    /// The trend's saved form after this bite (JSON), for the history.
    pub saved: Option<String>,
}

/// Where installed maps came from.
#[derive(Debug, Clone, PartialEq)]
pub enum MapsOrigin {
    /// Read from this cache file.
    Cache(PathBuf),
    /// Built in this many seconds and stored in the cache file, when it could be.
    Built {
        /// Wall time of the build, s.
        seconds: f64,
        /// The cache file written.
        saved: Option<PathBuf>,
    },
}

/// The gap maps of one driveline, to build (or read from the cache) off the analysis
/// task.
#[derive(Debug, Clone)]
pub struct GapMapJob {
    /// Index of the driveline in the configuration.
    pub driveline: usize,
    /// Name of the driveline.
    pub driveline_name: String,
    /// The model file.
    pub model_file: PathBuf,
    simulator: BiteSimulator,
    spec: GapMapSpec,
    cache_dir: PathBuf,
}

impl GapMapJob {
    /// The maps of `spec` for the bites `simulator` gives of the model in `model_file`,
    /// cached in `cache_dir`.
    pub fn new(
        driveline: usize,
        driveline_name: &str,
        model_file: &Path,
        simulator: BiteSimulator,
        spec: GapMapSpec,
        cache_dir: &Path,
    ) -> Self {
        Self {
            driveline,
            driveline_name: driveline_name.to_owned(),
            model_file: model_file.to_owned(),
            simulator,
            spec,
            cache_dir: cache_dir.to_owned(),
        }
    }

    /// The grid.
    pub fn spec(&self) -> &GapMapSpec {
        &self.spec
    }

    /// The cache file these maps are (or will be) stored in; `None` when the model
    /// cannot be keyed.
    pub fn cache_file(&self) -> Option<PathBuf> {
        let key = gap_map_cache::key(&self.simulator, &self.spec).ok()?;
        Some(gap_map_cache::path(&self.cache_dir, &key))
    }

    /// The maps from the cache, else built on `threads` threads (`progress(done,
    /// total)` per simulation; cancelled through `cancel`) and stored in the cache. A
    /// cache that cannot be read or written is logged, not an error.
    pub fn run(
        &self,
        threads: usize,
        cancel: &AtomicBool,
        progress: &(dyn Fn(usize, usize) + Sync),
    ) -> Result<(GapMaps, MapsOrigin), GapMapError> {
        let model = self.model_file.display().to_string();
        let key = match gap_map_cache::key(&self.simulator, &self.spec) {
            Ok(key) => Some(key),
            Err(error) => {
                tracing::warn!(%model, %error, "gap maps not cached");
                None
            }
        };
        if let Some(key) = &key {
            match gap_map_cache::load(&self.cache_dir, key) {
                Ok(Some(maps)) => {
                    let file = gap_map_cache::path(&self.cache_dir, key);
                    return Ok((maps, MapsOrigin::Cache(file)));
                }
                Ok(None) => {}
                Err(error) => {
                    tracing::warn!(%model, %error, "cached gap maps not usable: rebuilding")
                }
            }
        }
        let started = Instant::now();
        let maps = build(
            &self.simulator,
            &self.spec,
            &model,
            threads,
            cancel,
            progress,
        )?;
        let seconds = started.elapsed().as_secs_f64();
        let saved = key.and_then(
            |key| match gap_map_cache::save(&self.cache_dir, &key, &maps) {
                Ok(file) => Some(file),
                Err(error) => {
                    tracing::warn!(%model, %error, "gap maps not cached");
                    None
                }
            },
        );
        Ok((maps, MapsOrigin::Built { seconds, saved }))
    }
}

/// Run `job` on a thread of its own (and `threads` workers: the build uses the
/// machine while the service already runs), reporting `progress(done, total)` per
/// simulation and sending the outcome on `ready`; the build stops early once
/// `cancel` is set.
pub(crate) fn spawn_job(
    job: GapMapJob,
    threads: usize,
    ready: tokio::sync::mpsc::Sender<GapMapsReady>,
    cancel: Arc<AtomicBool>,
    progress: impl Fn(usize, usize) + Send + Sync + 'static,
) -> std::io::Result<std::thread::JoinHandle<()>> {
    std::thread::Builder::new()
        .name(format!("gap-maps-{}", job.driveline))
        .spawn(move || {
            tracing::info!(
                driveline = %job.driveline_name,
                model = %job.model_file.display(),
                simulations = job.spec().simulations(),
                "gap maps: reading the cache or building"
            );
            let outcome = job.run(threads, &cancel, &progress);
            match &outcome {
                Ok((_, origin)) => tracing::info!(
                    driveline = %job.driveline_name,
                    origin = ?origin,
                    "gap maps ready"
                ),
                Err(GapMapError::Cancelled) => return,
                Err(_) => {} // logged where it is installed
            }
            // The analysis may have stopped: nobody to tell.
            let _ = ready.blocking_send((job.driveline, outcome.map(|(maps, _)| maps)));
        })
}

/// The outcome of a driveline's gap map job, for [`super::Analysis::run`]: the
/// driveline index and the maps or why there are none.
pub(crate) type GapMapsReady = (usize, Result<GapMaps, GapMapError>);

/// The most bites held while the maps are not ready (the newest are kept).
pub(crate) const MAX_PENDING: usize = 1000;

/// The gap diagnosis state of one driveline in the analysis task.
#[derive(Debug)]
pub(super) struct GapMonitor {
    maps: Option<Arc<GapMaps>>,
    trend: GapTrend,
    /// Bites seen before the maps, oldest first: (time ms since the epoch, measures).
    pending: VecDeque<(i64, GapObservation)>,
    name: String,
    warning_mrad: f64,
    alarm_mrad: f64,
}

impl GapMonitor {
    /// The monitor of driveline `name` with its thresholds, its trend as `wear` says
    /// (forecasting up to `horizon_days`, the growth over `growth_span_s`).
    pub(super) fn new(
        name: &str,
        thresholds: &DrivelineThresholds,
        wear: &WearSettings,
    ) -> Result<Self, TrendError> {
        let mut trend = GapTrend::new(wear.horizon_days)?;
        trend.set_growth_span_s(wear.growth_span_s)?;
        Ok(Self {
            maps: None,
            trend,
            pending: VecDeque::new(),
            name: name.to_owned(),
            warning_mrad: thresholds.gap_warning_mrad,
            alarm_mrad: thresholds.gap_alarm_mrad,
        })
    }

    /// Warn and alarm at `thresholds`, and forecast up to `horizon_days`, from the
    /// next bite on (a reload).
    pub(super) fn set_thresholds(
        &mut self,
        thresholds: &DrivelineThresholds,
        horizon_days: f64,
    ) -> Result<(), TrendError> {
        self.warning_mrad = thresholds.gap_warning_mrad;
        self.alarm_mrad = thresholds.gap_alarm_mrad;
        self.trend.set_horizon_days(horizon_days)
    }

    /// Install the maps (`None`: they failed and will not come); the trend's estimate
    /// after folding in the bites held meanwhile.
    pub(super) fn set_maps(&mut self, maps: Option<Arc<GapMaps>>) -> Option<GapResults> {
        self.maps = maps;
        let maps = self.maps.clone()?;
        while let Some((time, observation)) = self.pending.pop_front() {
            self.fold(&maps, &observation, time);
        }
        self.results()
    }

    /// The trend's estimate and forecast; `None` before a bite was folded in.
    pub(super) fn results(&self) -> Option<GapResults> {
        self.trend.results(self.alarm_mrad)
    }

    /// Continue the trend `saved` (a restart), when it fits; `false` when it does not
    /// (another format, or unreadable: the caller folds the bites in again).
    pub(super) fn restore_trend(&mut self, saved: &str) -> bool {
        match self.trend.restore(saved) {
            Ok(()) => true,
            Err(error) => {
                tracing::warn!(driveline = %self.name, %error, "saved wear trend not usable: folding the last bites in again");
                false
            }
        }
    }

    /// Fold in `bites` (time ms since the epoch, measures; oldest first) as a restart
    /// does without a saved trend; held until the maps are ready.
    pub(super) fn restore_bites(&mut self, bites: Vec<(i64, GapObservation)>) {
        self.trend.reset();
        self.pending.clear();
        for (time, observation) in bites {
            self.hold_or_fold(time, observation);
        }
    }

    /// Forget every bite (the wear reset).
    pub(super) fn reset(&mut self) {
        self.trend.reset();
        self.pending.clear();
    }

    /// The trend's saved form (JSON).
    pub(super) fn saved(&self) -> String {
        self.trend.saved()
    }

    /// Fold in a bite at `time` (ms since the epoch) whose window (kN*m) gave
    /// `transient` with `settings`.
    pub(super) fn observe(
        &mut self,
        window: &[f64],
        transient: &TransientResult,
        settings: &TransientSettings,
        time: i64,
    ) -> Option<GapBite> {
        let observation = GapObservation::from_window(window, transient, settings)?;
        let bite = self.hold_or_fold(time, observation);
        let trend = self.maps.as_ref().and_then(|_| self.results());
        Some(GapBite {
            observation,
            bite,
            saved: trend.map(|_| self.saved()),
            trend,
        })
    }

    /// Fold `observation` in when the maps are ready (the bite's own estimate), else
    /// hold it.
    fn hold_or_fold(&mut self, time: i64, observation: GapObservation) -> Option<GapEstimate> {
        match self.maps.clone() {
            Some(maps) => self.fold(&maps, &observation, time),
            None => {
                if self.pending.len() == MAX_PENDING {
                    self.pending.pop_front();
                }
                self.pending.push_back((time, observation));
                None
            }
        }
    }

    /// Fold one bite into the trend; what it refuses is logged. The bite's own
    /// estimate, when it was folded in.
    fn fold(
        &mut self,
        maps: &GapMaps,
        observation: &GapObservation,
        time: i64,
    ) -> Option<GapEstimate> {
        match self.trend.fold(maps, observation, time) {
            Ok(Folded::Folded { jumped, bite }) => {
                if jumped {
                    tracing::warn!(
                        driveline = %self.name,
                        "the gap stepped: the wear trend reopened (a coupling changed without a wear reset? reset the wear trend)"
                    );
                }
                bite
            }
            Ok(Folded::OutsideMaps) => None,
            Err(error) => {
                tracing::warn!(driveline = %self.name, %error, "bite not folded into the wear trend");
                None
            }
        }
    }

    /// Record `estimate` in the results of driveline `subject`: the values, the
    /// warning, the latched alarm; and, dated `time`, the alarm events of the warning's
    /// and the alarm's changes.
    pub(super) fn publish(
        &self,
        results: &mut DrivelineResults,
        estimate: &GapResults,
        (subject, time): (&str, UtcTime),
        events: &mut Vec<HistoryEvent>,
    ) {
        let (was_warning, was_alarm) = (results.gap_warning, results.gap_alarm);
        results.gap = Some(*estimate);
        results.gap_warning = estimate.gap_mrad >= self.warning_mrad;
        results.gap_alarm |= estimate.low_mrad >= self.alarm_mrad;
        let alarm = |kind, event, value, threshold| {
            HistoryEvent::Alarm(AlarmRecord {
                time,
                subject: subject.to_owned(),
                kind,
                event,
                origin: None,
                value: Some(value),
                threshold: Some(threshold),
            })
        };
        if results.gap_warning != was_warning {
            let event = if results.gap_warning {
                AlarmEvent::Raised
            } else {
                AlarmEvent::Cleared
            };
            events.push(alarm(
                AlarmKind::GapWarning,
                event,
                estimate.gap_mrad,
                self.warning_mrad,
            ));
        }
        if results.gap_alarm && !was_alarm {
            events.push(alarm(
                AlarmKind::GapAlarm,
                AlarmEvent::Raised,
                estimate.low_mrad,
                self.alarm_mrad,
            ));
        }
    }

    /// `estimate` against the thresholds, as the history records it.
    pub(super) fn verdict(&self, estimate: &GapResults) -> WearState {
        if estimate.low_mrad >= self.alarm_mrad {
            WearState::Alarm
        } else if estimate.gap_mrad >= self.warning_mrad {
            WearState::Warning
        } else {
            WearState::Ok
        }
    }
}
