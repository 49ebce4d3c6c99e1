//! A driveline's gap maps, as data: what its torque channel shows at a bite, over
//! static torque x opened gap, for every coupling that may carry the gap, and the
//! look-ups the estimator and the pages make on them. The analysis builds them
//! ([`crate::analysis::gap_map`]) and installs them; the outputs draw them.
//!
//! - **Interpolation**: linear in log static torque along a row, then linear in the gap
//!   ([`GapMaps::cells`], [`Cell`]).
//! - **Interpolation error**: per point, from leave-one-out: the value each inner point
//!   takes when interpolated from its two neighbours, a quarter of the difference
//!   (linear interpolation over twice the step errs four times as much where the
//!   curvature is smooth), along the torque and the gap; the estimator adds it to the
//!   measurement noise, so where the map bends sharply a bite weighs less.

use std::sync::Arc;

use serde::{Deserialize, Serialize};

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

impl GapMapSpec {
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

/// What a look-up needs of one point beyond its values: its interpolation error
/// estimates, TAF and shift (s), and the logarithm of its static torque (a bite's
/// look-up interpolates in log torque on every gap row of every coupling, more than
/// once: taken once here).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
struct Floor {
    taf: f64,
    shift_s: f64,
    ln_static_knm: f64,
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
    /// A hash of `data`: which maps a wear trend's bites were folded against.
    fingerprint: u64,
}

/// FNV-1a, 64 bits: a hash that stays the same across Rust releases (std's
/// `DefaultHasher` does not promise to), for cache file names and the maps'
/// fingerprint. Hand-rolled: six lines against a new dependency.
pub(crate) fn fnv1a(text: &str) -> u64 {
    text.bytes().fold(0xcbf2_9ce4_8422_2325, |hash, byte| {
        (hash ^ u64::from(byte)).wrapping_mul(0x0000_0100_0000_01b3)
    })
}

impl GapMaps {
    /// Maps from computed or cached data; the interpolation error estimates are
    /// computed here.
    pub fn new(data: GapMapData) -> Self {
        let floors = data.maps.iter().map(|map| floors(&map.rows)).collect();
        // Serializing plain numbers and names cannot fail.
        let fingerprint = fnv1a(&serde_json::to_string(&data).unwrap_or_default());
        Self {
            data,
            floors,
            fingerprint,
        }
    }

    /// A hash of the maps' values: equal maps, equal fingerprints (another model or
    /// other settings: almost surely another one).
    pub fn fingerprint(&self) -> u64 {
        self.fingerprint
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
    pub(crate) fn static_range_knm(&self) -> (f64, f64) {
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
        let ln_static_knm = static_knm.ln();
        map.rows
            .iter()
            .zip(floors)
            .map(|(row, floors)| cell(row, floors, (static_knm, ln_static_knm)))
            .collect()
    }
}

impl GapMaps {
    /// The linear driveline (gap 0) at static torque `static_knm`: TAF and first-period
    /// shift (s, when the map has it); `None` outside the map.
    pub(crate) fn linear_at(&self, static_knm: f64) -> Option<(f64, Option<f64>)> {
        let cell = self.cells(0, static_knm)?.into_iter().next()?;
        let [a, b] = cell.points;
        let shift = a
            .period_shift_s
            .zip(b.period_shift_s)
            .map(|(a, b)| lerp(a, b, cell.weight));
        Some((cell.taf(), shift))
    }

    /// The index (in spec order) of coupling `coupling`'s map.
    pub(crate) fn index_of(&self, coupling: usize) -> Option<usize> {
        self.data
            .maps
            .iter()
            .position(|map| map.coupling == coupling)
    }

    /// [`Self::taf_curve`]s of map `index` at every whole mrad up to the largest gap
    /// row: (gap in mrad, curve), gap 0 first.
    pub(crate) fn whole_mrad_curves(&self, index: usize) -> Vec<(u32, Vec<(f64, f64)>)> {
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

/// The cell of `row` around `static_knm` (with its logarithm).
fn cell(
    row: &[MapPoint],
    floors: &[Floor],
    (static_knm, ln_static_knm): (f64, f64),
) -> Option<Cell> {
    let (first, last) = (row.first()?, row.last()?);
    let tolerance = 1.0 + EDGE_TOLERANCE;
    if !(static_knm * tolerance >= first.static_knm && static_knm <= last.static_knm * tolerance) {
        return None;
    }
    let upper = row
        .partition_point(|p| p.static_knm <= static_knm)
        .clamp(1, row.len() - 1);
    let lower = upper - 1;
    let (a, b) = (floors[lower].ln_static_knm, floors[upper].ln_static_knm);
    let weight = ((ln_static_knm - a) / (b - a)).clamp(0.0, 1.0);
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
                    ln_static_knm: rows[j][i].static_knm.ln(),
                })
                .collect()
        })
        .collect()
}

/// Where a driveline's gap maps are: the analysis installs them, the outputs that draw
/// them read them from the board.
#[derive(Debug, Clone)]
pub enum GapMapState {
    /// The driveline has no model: no maps.
    NoModel,
    /// Read from the cache or being built: `done` of `total` simulations.
    Building {
        /// Simulations done.
        done: usize,
        /// Simulations the build runs (0 until the build reports).
        total: usize,
    },
    /// Ready.
    Ready(Arc<GapMaps>),
    /// Will not come: why (the model does not load or fit, the build failed).
    Failed(String),
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng as _, SeedableRng as _};

    /// A cell's weight is the static torque's place between its neighbours in log
    /// torque, bit for bit as each logarithm taken at the look-up gives it (the maps
    /// keep their points' logarithms): seeded rows whose measured torques differ a
    /// little from row to row, torques anywhere in and just outside the maps.
    #[test]
    fn a_cells_weight_is_its_place_in_log_torque() {
        let mut rng = rand::rngs::StdRng::seed_from_u64(5);
        let torques = [40.0, 55.0, 75.0, 100.0, 130.0, 170.0];
        let rows: Vec<Vec<MapPoint>> = (0..5)
            .map(|_| {
                torques
                    .iter()
                    .map(|&t| MapPoint {
                        static_knm: t * rng.random_range(0.99..1.01),
                        taf: rng.random_range(1.0..2.0),
                        period_shift_s: None,
                    })
                    .collect()
            })
            .collect();
        let maps = GapMaps::new(GapMapData {
            model_name: "test".into(),
            spec: GapMapSpec {
                couplings: vec![0],
                gaps_rad: (0..5).map(|g| f64::from(g) * 1e-3).collect(),
                static_torques_knm: torques.to_vec(),
            },
            maps: vec![CouplingMap {
                coupling: 0,
                name: "spindle".into(),
                rows: rows.clone(),
            }],
        });
        let mut looked = 0;
        for _ in 0..2_000 {
            let static_knm = rng.random_range(35.0..180.0);
            let Some(cells) = maps.cells(0, static_knm) else {
                continue;
            };
            looked += 1;
            for (cell, row) in cells.iter().zip(&rows) {
                let upper = row
                    .partition_point(|p| p.static_knm <= static_knm)
                    .clamp(1, row.len() - 1);
                let (a, b) = (row[upper - 1].static_knm, row[upper].static_knm);
                let weight = ((static_knm.ln() - a.ln()) / (b.ln() - a.ln())).clamp(0.0, 1.0);
                assert_eq!(cell.weight.to_bits(), weight.to_bits(), "{static_knm} kN*m");
                assert_eq!(cell.points, [row[upper - 1], row[upper]]);
            }
        }
        assert!(looked > 1_500, "{looked} look-ups inside the maps");
    }
}
