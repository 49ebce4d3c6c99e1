//! Building a driveline's gap maps ([`GapMaps`], the data and its look-ups, are the
//! state layer's: [`crate::state::gap_maps`]): what its torque channel shows at a
//! bite, over static torque x opened gap, for every coupling that may carry the gap.
//!
//! Each grid point is one bite of the driveline model simulated and analysed as a
//! measured bite (`BiteSimulator`: the model's physics, then the driveline's own bite
//! detector and transient analysis with the same settings). A point keeps the static
//! torque the analysis *measured* (not the simulated load: the estimator looks maps up
//! by the measured value, as bites give it), the TAF and the first-period shift
//! (first minus second period).
//!
//! - **Grid**: static torques geometric over the driveline's range (denser where the
//!   gap weighs most), gaps uniform from 0 (the linear row, shared by every coupling).
//! - **Cost**: (torque points) x (1 + couplings x gaps) simulations, shared among
//!   `threads` threads; cancelled between points through an [`AtomicBool`].

use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::Mutex;

use millgate_config::WearSettings;
use millgate_sim::model::Model;

use super::simulated_bite::{BiteSimulator, Gap, SimulatedBiteError};
use crate::state::gap_maps::{CouplingMap, GapMapData, GapMapSpec, GapMaps, MapPoint};

/// Default static torque range as fractions of the model's load.
const DEFAULT_RANGE: (f64, f64) = (0.25, 2.0);
/// Lowest default static torque as a multiple of the bite threshold: below it a bite
/// barely rises above the threshold.
const MIN_THRESHOLD_MULTIPLE: f64 = 1.25;

/// Why a driveline's gap maps cannot be specified or built.
#[derive(Debug, thiserror::Error)]
pub enum GapMapError {
    /// A `wear` setting does not fit the model; `key` is the configuration key.
    #[error("{key}: {message}")]
    Setting {
        /// Configuration key, e.g. `drivelines[0].wear.couplings[1]`.
        key: String,
        /// What is wrong, with the allowed range.
        message: String,
    },
    /// A grid point could not be simulated or analysed.
    #[error("{model}: wear map point: {source}")]
    Point {
        /// The model file.
        model: String,
        /// Why (boxed: the error stays small on the `Ok` path).
        #[source]
        source: Box<SimulatedBiteError>,
    },
    /// A row's measured static torques do not rise with the simulated ones.
    #[error(
        "{model}: wear map of coupling {coupling}: at a {gap_mrad} mrad gap the measured \
         static torque does not rise with the load ({low_knm} kN*m after {high_knm} kN*m)"
    )]
    NotMonotonic {
        /// The model file.
        model: String,
        /// Coupling of the row.
        coupling: usize,
        /// Gap of the row, mrad.
        gap_mrad: f64,
        /// The later, lower value, kN*m.
        low_knm: f64,
        /// The earlier, higher value, kN*m.
        high_knm: f64,
    },
    /// The build was cancelled (the service is stopping).
    #[error("wear map build cancelled")]
    Cancelled,
}

impl GapMapSpec {
    /// The grid for `settings` of driveline `index` and its `model`, whose bites are
    /// detected at `threshold_knm` (kN*m); errors name the key at fault.
    pub fn new(
        index: usize,
        settings: &WearSettings,
        model: &Model,
        threshold_knm: f64,
    ) -> Result<Self, GapMapError> {
        let key = |name: &str| format!("drivelines[{index}].wear.{name}");
        let count = model.couplings.len();
        let couplings = match &settings.couplings {
            None => (0..count).collect(),
            Some(list) => {
                if let Some(position) = list.iter().position(|&c| c >= count) {
                    return Err(GapMapError::Setting {
                        key: key(&format!("couplings[{position}]")),
                        message: format!(
                            "{} is not allowed (must be a coupling of the model \"{}\": 0 ..= {})",
                            list[position],
                            model.name,
                            count.saturating_sub(1)
                        ),
                    });
                }
                list.clone()
            }
        };
        let (low, high) = match settings.static_torque_knm {
            Some(range) => range,
            None => {
                let nominal = model.load.static_torque;
                let low = (DEFAULT_RANGE.0 * nominal).max(MIN_THRESHOLD_MULTIPLE * threshold_knm);
                let high = DEFAULT_RANGE.1 * nominal;
                if low.partial_cmp(&high) != Some(std::cmp::Ordering::Less) {
                    return Err(GapMapError::Setting {
                        key: key("static_torque_knm"),
                        message: format!(
                            "missing: the model's static torque {nominal} kN*m gives no default \
                             range above {MIN_THRESHOLD_MULTIPLE} x the bite threshold \
                             ({threshold_knm} kN*m); give [low, high] in kN*m"
                        ),
                    });
                }
                (low, high)
            }
        };
        let points = settings.torque_points.max(2);
        let ratio = (high / low).powf(1.0 / (points - 1) as f64);
        let static_torques_knm = (0..points).map(|i| low * ratio.powi(i as i32)).collect();
        let steps = (settings.max_gap_mrad / settings.gap_step_mrad)
            .round()
            .max(1.0) as usize;
        let gaps_rad = (0..=steps)
            .map(|i| i as f64 * settings.gap_step_mrad * 1e-3)
            .collect();
        Ok(Self {
            couplings,
            gaps_rad,
            static_torques_knm,
        })
    }
}

/// Builds the maps of `spec` for the bites `simulator` simulates (`model_file` names
/// the model in errors), on `threads` threads (at least 1); `progress(done, total)`
/// after each simulation (from any of the threads); stops with
/// [`GapMapError::Cancelled`] once `cancel` is set.
pub fn build(
    simulator: &BiteSimulator,
    spec: &GapMapSpec,
    model_file: &str,
    threads: usize,
    cancel: &AtomicBool,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<GapMaps, GapMapError> {
    let points = simulate(simulator, spec, model_file, threads, cancel, progress)?;
    let maps = coupling_maps(simulator, spec, model_file, &points)?;
    Ok(GapMaps::new(GapMapData {
        model_name: simulator.linear_model().name.clone(),
        spec: spec.clone(),
        maps,
    }))
}

/// The gap of row `row` of `spec`'s grid: none for 0 (the linear row), then per
/// coupling its gaps from the second on.
fn grid_gap(spec: &GapMapSpec, row: usize) -> Option<Gap> {
    let gaps_per_coupling = spec.gaps_rad.len() - 1;
    (row > 0).then(|| {
        let coupling = spec.couplings[(row - 1) / gaps_per_coupling];
        let width_rad = spec.gaps_rad[1 + (row - 1) % gaps_per_coupling];
        Gap {
            coupling,
            width_rad,
        }
    })
}

/// Every point of `spec`'s grid simulated (see [`build`]), in grid order: item k at
/// torque k % torques of row k / torques ([`grid_gap`]).
fn simulate(
    simulator: &BiteSimulator,
    spec: &GapMapSpec,
    model_file: &str,
    threads: usize,
    cancel: &AtomicBool,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<Vec<MapPoint>, GapMapError> {
    let torques = spec.static_torques_knm.len();
    let total = spec.simulations();
    let results: Vec<Mutex<Option<MapPoint>>> = (0..total).map(|_| Mutex::new(None)).collect();
    let next = AtomicUsize::new(0);
    let done = AtomicUsize::new(0);
    let failed: Mutex<Option<(usize, GapMapError)>> = Mutex::new(None);
    let stop = AtomicBool::new(false);
    let work = || loop {
        if stop.load(Ordering::Relaxed) || cancel.load(Ordering::Relaxed) {
            return;
        }
        let item = next.fetch_add(1, Ordering::Relaxed);
        if item >= total {
            return;
        }
        let static_knm = spec.static_torques_knm[item % torques];
        match simulator.bite(static_knm, grid_gap(spec, item / torques)) {
            Ok(bite) => {
                *crate::lock(&results[item]) = Some(MapPoint {
                    static_knm: bite.transient.static_torque_knm,
                    taf: bite.taf,
                    period_shift_s: bite.transient.period_shift_s,
                });
                progress(done.fetch_add(1, Ordering::Relaxed) + 1, total);
            }
            Err(source) => {
                let mut failed = crate::lock(&failed);
                // Keep the first point in grid order, whichever thread got there first.
                if failed.as_ref().is_none_or(|(first, _)| item < *first) {
                    let error = GapMapError::Point {
                        model: model_file.to_owned(),
                        source: Box::new(source),
                    };
                    *failed = Some((item, error));
                }
                stop.store(true, Ordering::Relaxed);
                return;
            }
        }
    };
    std::thread::scope(|scope| {
        for _ in 1..threads.max(1) {
            scope.spawn(work);
        }
        work();
    });
    if let Some((_, error)) = failed.into_inner().unwrap_or_else(|e| e.into_inner()) {
        return Err(error);
    }
    if cancel.load(Ordering::Relaxed) {
        return Err(GapMapError::Cancelled);
    }
    results
        .into_iter()
        .map(|slot| slot.into_inner().unwrap_or_else(|e| e.into_inner()))
        .collect::<Option<_>>()
        .ok_or(GapMapError::Cancelled)
}

/// Per coupling of `spec`, its map from the grid's `points` (the linear row, then its
/// gaps' rows); every row's measured static torques must rise.
fn coupling_maps(
    simulator: &BiteSimulator,
    spec: &GapMapSpec,
    model_file: &str,
    points: &[MapPoint],
) -> Result<Vec<CouplingMap>, GapMapError> {
    let torques = spec.static_torques_knm.len();
    let gaps_per_coupling = spec.gaps_rad.len() - 1;
    let row = |index: usize| points[index * torques..(index + 1) * torques].to_vec();
    let linear = row(0);
    let mut maps = Vec::with_capacity(spec.couplings.len());
    for (position, &coupling) in spec.couplings.iter().enumerate() {
        let mut rows = vec![linear.clone()];
        rows.extend((0..gaps_per_coupling).map(|g| row(1 + position * gaps_per_coupling + g)));
        for (j, row) in rows.iter().enumerate() {
            if let Some(pair) = row.windows(2).find(|p| p[1].static_knm <= p[0].static_knm) {
                return Err(GapMapError::NotMonotonic {
                    model: model_file.to_owned(),
                    coupling,
                    gap_mrad: spec.gaps_rad[j] * 1e3,
                    low_knm: pair[1].static_knm,
                    high_knm: pair[0].static_knm,
                });
            }
        }
        maps.push(CouplingMap {
            coupling,
            name: simulator.linear_model().couplings[coupling].name.clone(),
            rows,
        });
    }
    Ok(maps)
}
