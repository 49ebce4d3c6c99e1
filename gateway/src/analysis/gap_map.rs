//! Gap maps: what a driveline's torque channel shows at a bite, over static torque x
//! opened gap, for every coupling that may carry the gap.
//!
//! Each grid point is one bite of the driveline model simulated and analysed as a
//! measured bite ([`BiteSimulator`]: the model's physics, then the driveline's own bite
//! detector and transient analysis with the same settings). A point keeps the static
//! torque the analysis *measured* (not the simulated load: the estimator looks maps up
//! by the measured value, as bites give it), the TAF and the first-period shift
//! (first minus second period).
//!
//! - **Grid**: static torques geometric over the driveline's range (denser where the
//!   gap weighs most), gaps uniform from 0 (the linear row, shared by every coupling).
//! - **Interpolation**: linear in log static torque along a row, then linear in the gap
//!   ([`GapMaps::cells`], [`Cell`]).
//! - **Interpolation error**: per point, from leave-one-out: the value each inner point
//!   takes when interpolated from its two neighbours, a quarter of the difference
//!   (linear interpolation over twice the step errs four times as much where the
//!   curvature is smooth), along the torque and the gap; the estimator adds it to the
//!   measurement noise, so where the map bends sharply a bite weighs less.
//! - **Cost**: (torque points) x (1 + couplings x gaps) simulations, shared among
//!   `threads` threads; cancelled between points through an [`AtomicBool`].

use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::Mutex;

use millgate_config::WearSettings;
use millgate_sim::model::Model;
use serde::{Deserialize, Serialize};

use super::simulated_bite::{BiteSimulator, Gap, SimulatedBiteError};

/// Default static torque range as fractions of the model's load.
const DEFAULT_RANGE: (f64, f64) = (0.25, 2.0);
/// Lowest default static torque as a multiple of the bite threshold: below it a bite
/// barely rises above the threshold.
const MIN_THRESHOLD_MULTIPLE: f64 = 1.25;
/// How far past its end points a row is used unchanged, as a fraction of the static
/// torque (the measured static torque of a row's end points varies a little with the
/// gap).
const EDGE_TOLERANCE: f64 = 0.02;

/// The grid of a driveline's gap maps.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GapMapSpec {
    /// Couplings that may carry the gap, model indices.
    pub couplings: Vec<usize>,
    /// Opened gaps, rad, ascending and uniform from 0.
    pub gaps_rad: Vec<f64>,
    /// Simulated static torques, kN*m, ascending.
    pub static_torques_knm: Vec<f64>,
}

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

    /// Simulations a build runs.
    pub fn simulations(&self) -> usize {
        self.static_torques_knm.len() * (1 + self.couplings.len() * (self.gaps_rad.len() - 1))
    }
}

/// One grid point: what the analysis measured on the simulated bite.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct MapPoint {
    /// Static torque as measured, kN*m.
    pub static_knm: f64,
    /// Torque amplification factor.
    pub taf: f64,
    /// First minus second period, s, when three up-crossings were found.
    pub period_shift_s: Option<f64>,
}

/// The map of one coupling: `rows[gap][torque]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CouplingMap {
    /// Coupling index in the model.
    pub coupling: usize,
    /// The coupling's name in the model.
    pub name: String,
    /// Per gap of [`GapMapSpec::gaps_rad`], per static torque of the spec.
    pub rows: Vec<Vec<MapPoint>>,
}

/// The computed maps as stored in the cache.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GapMapData {
    /// The model's name.
    pub model_name: String,
    /// The grid.
    pub spec: GapMapSpec,
    /// One map per coupling of the spec, in its order.
    pub maps: Vec<CouplingMap>,
}

/// Interpolation error estimates of one point: TAF and shift (s).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
struct Floor {
    taf: f64,
    shift_s: f64,
}

/// A coupling's map at one static torque, between two grid torques: per gap row the
/// values at both neighbours and the weight of the upper one.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Cell {
    /// The two neighbours (lower, upper torque).
    pub points: [MapPoint; 2],
    /// Their interpolation error estimates: TAF.
    pub taf_floor: [f64; 2],
    /// Their interpolation error estimates: shift, s.
    pub shift_floor_s: [f64; 2],
    /// Weight of the upper neighbour, 0..=1.
    pub weight: f64,
}

impl Cell {
    /// The TAF interpolated in log static torque.
    pub fn taf(&self) -> f64 {
        lerp(self.points[0].taf, self.points[1].taf, self.weight)
    }
}

fn lerp(a: f64, b: f64, weight: f64) -> f64 {
    a + (b - a) * weight
}

/// Gap maps of a driveline, ready for look-ups.
#[derive(Debug, Clone, PartialEq)]
pub struct GapMaps {
    data: GapMapData,
    /// Per coupling, per gap, per torque.
    floors: Vec<Vec<Vec<Floor>>>,
}

impl GapMaps {
    /// Maps from computed or cached data; the interpolation error estimates are
    /// computed here.
    pub fn new(data: GapMapData) -> Self {
        let floors = data.maps.iter().map(|map| floors(&map.rows)).collect();
        Self { data, floors }
    }

    /// The maps as computed (what the cache stores).
    pub fn data(&self) -> &GapMapData {
        &self.data
    }

    /// The opened gaps of the rows, rad.
    pub fn gaps_rad(&self) -> &[f64] {
        &self.data.spec.gaps_rad
    }

    /// The couplings' maps.
    pub fn maps(&self) -> &[CouplingMap] {
        &self.data.maps
    }

    /// The static torque range every row covers, kN*m (measured values).
    pub fn static_range_knm(&self) -> (f64, f64) {
        let mut range = (f64::NEG_INFINITY, f64::INFINITY);
        for map in &self.data.maps {
            for row in &map.rows {
                if let (Some(first), Some(last)) = (row.first(), row.last()) {
                    range.0 = range.0.max(first.static_knm);
                    range.1 = range.1.min(last.static_knm);
                }
            }
        }
        range
    }

    /// Map `index` (in spec order) at static torque `static_knm`: one [`Cell`] per gap
    /// row, or `None` outside the map.
    pub fn cells(&self, index: usize, static_knm: f64) -> Option<Vec<Cell>> {
        let map = self.data.maps.get(index)?;
        let floors = &self.floors[index];
        map.rows
            .iter()
            .zip(floors)
            .map(|(row, floors)| cell(row, floors, static_knm))
            .collect()
    }
}

impl GapMaps {
    /// The linear driveline (gap 0) at static torque `static_knm`: TAF and first-period
    /// shift (s, when the map has it); `None` outside the map.
    pub fn linear_at(&self, static_knm: f64) -> Option<(f64, Option<f64>)> {
        let cell = self.cells(0, static_knm)?.into_iter().next()?;
        let [a, b] = cell.points;
        let shift = a
            .period_shift_s
            .zip(b.period_shift_s)
            .map(|(a, b)| lerp(a, b, cell.weight));
        Some((cell.taf(), shift))
    }

    /// The index (in spec order) of coupling `coupling`'s map.
    pub fn index_of(&self, coupling: usize) -> Option<usize> {
        self.data
            .maps
            .iter()
            .position(|map| map.coupling == coupling)
    }

    /// [`Self::taf_curve`]s of map `index` at every whole mrad up to the largest gap
    /// row: (gap in mrad, curve), gap 0 first.
    pub fn whole_mrad_curves(&self, index: usize) -> Vec<(u32, Vec<(f64, f64)>)> {
        let max_mrad = self.gaps_rad().last().copied().unwrap_or(0.0) * 1e3;
        // Rows are exact multiples of the step: 8 mrad may come out as 7.999...
        let whole = (max_mrad + 1e-9).floor() as u32;
        (0..=whole)
            .map(|mrad| (mrad, self.taf_curve(index, f64::from(mrad) * 1e-3)))
            .collect()
    }

    /// TAF over measured static torque (kN*m) of map `index` at gap `gap_rad`
    /// (between rows: interpolated), one point per grid torque.
    pub fn taf_curve(&self, index: usize, gap_rad: f64) -> Vec<(f64, f64)> {
        let Some(map) = self.data.maps.get(index) else {
            return Vec::new();
        };
        let gaps = &self.data.spec.gaps_rad;
        let upper = gaps
            .partition_point(|&g| g <= gap_rad)
            .clamp(1, gaps.len() - 1);
        let lower = upper - 1;
        let weight = ((gap_rad - gaps[lower]) / (gaps[upper] - gaps[lower])).clamp(0.0, 1.0);
        map.rows[lower]
            .iter()
            .zip(&map.rows[upper])
            .map(|(a, b)| {
                (
                    lerp(a.static_knm, b.static_knm, weight),
                    lerp(a.taf, b.taf, weight),
                )
            })
            .collect()
    }
}

/// The cell of `row` around `static_knm`.
fn cell(row: &[MapPoint], floors: &[Floor], static_knm: f64) -> Option<Cell> {
    let (first, last) = (row.first()?, row.last()?);
    let tolerance = 1.0 + EDGE_TOLERANCE;
    if !(static_knm * tolerance >= first.static_knm && static_knm <= last.static_knm * tolerance) {
        return None;
    }
    let upper = row
        .partition_point(|p| p.static_knm <= static_knm)
        .clamp(1, row.len() - 1);
    let lower = upper - 1;
    let (a, b) = (row[lower].static_knm, row[upper].static_knm);
    let weight = ((static_knm.ln() - a.ln()) / (b.ln() - a.ln())).clamp(0.0, 1.0);
    Some(Cell {
        points: [row[lower], row[upper]],
        taf_floor: [floors[lower].taf, floors[upper].taf],
        shift_floor_s: [floors[lower].shift_s, floors[upper].shift_s],
        weight,
    })
}

/// Leave-one-out interpolation error estimates of every point of `rows[gap][torque]`.
fn floors(rows: &[Vec<MapPoint>]) -> Vec<Vec<Floor>> {
    let gaps = rows.len();
    let torques = rows.first().map_or(0, Vec::len);
    // Along the torque: the point against its neighbours interpolated in log torque.
    let along_torque = |j: usize, i: usize, value: fn(&MapPoint) -> Option<f64>| {
        let row = &rows[j];
        let i = i.clamp(1, torques.saturating_sub(2).max(1));
        if torques < 3 {
            return 0.0;
        }
        let (a, p, b) = (&row[i - 1], &row[i], &row[i + 1]);
        let weight =
            (p.static_knm.ln() - a.static_knm.ln()) / (b.static_knm.ln() - a.static_knm.ln());
        match (value(a), value(p), value(b)) {
            (Some(a), Some(p), Some(b)) => (p - lerp(a, b, weight)).abs() / 4.0,
            _ => 0.0,
        }
    };
    // Along the gap (uniform steps): the point against the mean of its neighbours.
    let along_gap = |j: usize, i: usize, value: fn(&MapPoint) -> Option<f64>| {
        if gaps < 3 {
            return 0.0;
        }
        let j = j.clamp(1, gaps - 2);
        match (
            value(&rows[j - 1][i]),
            value(&rows[j][i]),
            value(&rows[j + 1][i]),
        ) {
            (Some(a), Some(p), Some(b)) => (p - 0.5 * (a + b)).abs() / 4.0,
            _ => 0.0,
        }
    };
    let taf: fn(&MapPoint) -> Option<f64> = |p| Some(p.taf);
    let shift: fn(&MapPoint) -> Option<f64> = |p| p.period_shift_s;
    (0..gaps)
        .map(|j| {
            (0..torques)
                .map(|i| Floor {
                    taf: along_torque(j, i, taf).hypot(along_gap(j, i, taf)),
                    shift_s: along_torque(j, i, shift).hypot(along_gap(j, i, shift)),
                })
                .collect()
        })
        .collect()
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
    let torques = spec.static_torques_knm.len();
    // Item k: torque k % torques; row k / torques: 0 the linear row, then per
    // coupling its gaps from the second on.
    let gaps_per_coupling = spec.gaps_rad.len() - 1;
    let total = spec.simulations();
    let gap_of = |row: usize| -> Option<Gap> {
        (row > 0).then(|| {
            let coupling = spec.couplings[(row - 1) / gaps_per_coupling];
            let width_rad = spec.gaps_rad[1 + (row - 1) % gaps_per_coupling];
            Gap {
                coupling,
                width_rad,
            }
        })
    };
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
        match simulator.bite(static_knm, gap_of(item / torques)) {
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
    let points: Vec<MapPoint> = results
        .into_iter()
        .map(|slot| slot.into_inner().unwrap_or_else(|e| e.into_inner()))
        .collect::<Option<_>>()
        .ok_or(GapMapError::Cancelled)?;
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
    Ok(GapMaps::new(GapMapData {
        model_name: simulator.linear_model().name.clone(),
        spec: spec.clone(),
        maps,
    }))
}
