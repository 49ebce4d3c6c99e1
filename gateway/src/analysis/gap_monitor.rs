//! One driveline's gap diagnosis: its maps (built off the analysis task), the pool of
//! its last bites, the published estimate and the wear state.
//!
//! - **Maps** come from a [`GapMapJob`]: the cache when it holds maps for this model
//!   and these settings (`gap_map_cache`), else a build on its own threads
//!   ([`super::gap_map::build`]). Until they are installed the gap registers stay
//!   invalid; bites seen meanwhile are pooled and estimated once the maps arrive. A
//!   build that fails leaves them invalid for good (the error is logged, naming the
//!   model file).
//! - **Wear state**: warning while the estimated gap (maximum likelihood) is at or
//!   above `thresholds.gap_warning_mrad`; alarm, latched until acknowledged
//!   (`command.acknowledge_alarms`), once the whole 90% interval is at or above
//!   `thresholds.gap_alarm_mrad` (the gap is that large with 95% confidence).
//! - **Reset** (`command.reset_wear_trend`, e.g. after a coupling was replaced): the
//!   pool is emptied and the estimate invalid until the next bite.

use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use std::sync::Arc;
use std::time::Instant;

use millgate_config::DrivelineThresholds;
use millgate_dsp::transient::{TransientResult, TransientSettings};

use super::gap_estimate::{GapEstimate, GapObservation, GapPool};
use super::gap_map::{build, GapMapError};
use super::gap_map_cache;
use super::simulated_bite::BiteSimulator;
use crate::state::events::{AlarmEvent, AlarmKind, AlarmRecord, HistoryEvent, WearState};
use crate::state::gap_maps::{GapMapSpec, GapMaps};
use crate::state::results::{DrivelineResults, GapResults};
use crate::state::time::UtcTime;

/// What a bite adds to the gap diagnosis.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GapBite {
    /// The bite's measures and their uncertainty (what a history stores to restore the
    /// pool).
    pub observation: GapObservation,
    /// The estimate from this bite alone, once the maps are ready.
    pub bite: Option<GapEstimate>,
    /// The pooled estimate after this bite, once the maps are ready.
    pub pooled: Option<GapEstimate>,
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

/// The gap diagnosis state of one driveline in the analysis task.
#[derive(Debug)]
pub(super) struct GapMonitor {
    maps: Option<Arc<GapMaps>>,
    pool: GapPool,
    warning_mrad: f64,
    alarm_mrad: f64,
}

impl GapMonitor {
    /// A monitor pooling the last `pool_bites` bites, with the driveline's thresholds.
    pub(super) fn new(thresholds: &DrivelineThresholds, pool_bites: usize) -> Self {
        Self {
            maps: None,
            pool: GapPool::new(pool_bites),
            warning_mrad: thresholds.gap_warning_mrad,
            alarm_mrad: thresholds.gap_alarm_mrad,
        }
    }

    /// Install the maps (`None`: they failed and will not come); the pooled estimate
    /// of the bites held.
    pub(super) fn set_maps(&mut self, maps: Option<Arc<GapMaps>>) -> Option<GapEstimate> {
        self.maps = maps;
        self.estimate()
    }

    fn estimate(&self) -> Option<GapEstimate> {
        self.pool.estimate(self.maps.as_deref()?)
    }

    /// Replace the pool by `observations`; the estimate, when the maps are ready.
    pub(super) fn restore(&mut self, observations: Vec<GapObservation>) -> Option<GapEstimate> {
        self.pool = GapPool::from_observations(self.pool.capacity(), observations);
        self.estimate()
    }

    /// The pool's saved form.
    pub(super) fn observations(&self) -> Vec<GapObservation> {
        self.pool.observations()
    }

    /// Empty the pool.
    pub(super) fn reset(&mut self) {
        self.pool.clear();
    }

    /// Pool a bite whose window (kN*m) gave `transient` with `settings`.
    pub(super) fn observe(
        &mut self,
        window: &[f64],
        transient: &TransientResult,
        settings: &TransientSettings,
    ) -> Option<GapBite> {
        let observation = GapObservation::from_window(window, transient, settings)?;
        self.pool.push(observation);
        let maps = self.maps.as_deref();
        Some(GapBite {
            observation,
            bite: maps.and_then(|maps| super::gap_estimate::estimate(maps, &[observation])),
            pooled: maps.and_then(|maps| self.pool.estimate(maps)),
        })
    }

    /// Record `estimate` in the results of driveline `subject`: the values, the
    /// warning, the latched alarm; and, dated `time`, the alarm events of the warning's
    /// and the alarm's changes.
    pub(super) fn publish(
        &self,
        results: &mut DrivelineResults,
        estimate: &GapEstimate,
        (subject, time): (&str, UtcTime),
        events: &mut Vec<HistoryEvent>,
    ) {
        let (was_warning, was_alarm) = (results.gap_warning, results.gap_alarm);
        results.gap = Some(GapResults {
            gap_mrad: estimate.gap_mrad,
            low_mrad: estimate.gap_low_mrad,
            high_mrad: estimate.gap_high_mrad,
            coupling: estimate.coupling,
            likeliest_coupling: Some(estimate.likeliest_coupling),
            bites_pooled: estimate.bites_pooled,
        });
        results.gap_warning = estimate.gap_mrad >= self.warning_mrad;
        results.gap_alarm |= estimate.gap_low_mrad >= self.alarm_mrad;
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
                estimate.gap_low_mrad,
                self.alarm_mrad,
            ));
        }
    }

    /// `estimate` against the thresholds, as the history records it.
    pub(super) fn verdict(&self, estimate: &GapEstimate) -> WearState {
        if estimate.gap_low_mrad >= self.alarm_mrad {
            WearState::Alarm
        } else if estimate.gap_mrad >= self.warning_mrad {
            WearState::Warning
        } else {
            WearState::Ok
        }
    }
}
