//! Wear index of a driveline: the measured bite against its linear reference.
//!
//! When a driveline names a model file (`drivelines[i].model`, a `millgate-sim`
//! model TOML), the gateway simulates the **linear reference**: the same model with
//! every coupling's backlash forced to 0 (its other properties, damping, motor
//! controller, load rise, stay as in the file), loaded to the static torque the bite
//! measured. The simulated torque goes through the same bite detector and the same
//! `dsp` transient analysis as the measured samples, which gives the reference TAF and
//! the reference first-period shift (domain notes, section 1.3: the linear model's
//! response is the reference, wear is the departure from it).
//!
//! - **Wear index** = measured TAF / reference TAF - 1. It is about 0 for a driveline
//!   without opened backlash and grows with the gap. The period-shift excess
//!   (measured minus reference first-period shift, s) is reported beside it in
//!   [`WearEstimate`] but not folded into the index: it needs three clean
//!   up-crossings, which a short or noisy bite may not give.
//! - **Reference cache**: references are cached by the static torque rounded to
//!   [`STATIC_TORQUE_STEP_KNM`]; a bite at a new level simulates once (a few ms), later
//!   bites at that level reuse it. The level, not the exact measured value, is what is
//!   simulated. For a linear driveline the response scales with the load, so TAF
//!   hardly depends on the level; what changes with it is where the fixed bite
//!   threshold cuts the load rise, and the cache step is far finer than that matters.
//! - **Wear trend**: an exponentially weighted mean of the wear index over bites,
//!   weight [`WEAR_TREND_WEIGHT`] for the newest (a time constant of about 10 bites),
//!   seeded by the first index after start or after the maintenance engineer resets it
//!   (command register `command.reset_wear_trend`). Degraded windows (gaps, NaN,
//!   saturation) do not move it.

use std::collections::BTreeMap;

use super::simulated_bite::{BiteSimulator, SimulatedBiteError};

/// Grid of the reference cache, kN*m: references are simulated at static torques
/// that are multiples of this step.
pub const STATIC_TORQUE_STEP_KNM: f64 = 5.0;
/// Most cached reference levels; the cache is emptied when a new level would pass it
/// (at 5 kN*m steps, 0 to 640 kN*m fits, far beyond any rolling torque).
const MAX_CACHED_LEVELS: usize = 128;
/// Weight of the newest wear index in the wear trend (EWMA), in (0, 1].
pub const WEAR_TREND_WEIGHT: f64 = 0.1;

/// The linear reference at one static torque level.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Reference {
    /// Static torque the reference was simulated at (a cache level), kN*m.
    pub level_knm: f64,
    /// TAF of the simulated linear bite.
    pub taf: f64,
    /// First minus second period of the simulated linear bite, s, when measured.
    pub period_shift_s: Option<f64>,
}

/// A bite's wear measures against its reference.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WearEstimate {
    /// Measured TAF / reference TAF - 1 (dimensionless; 0 = like the linear driveline).
    pub index: f64,
    /// The reference it was computed against.
    pub reference: Reference,
    /// Measured minus reference first-period shift, s, when both were measured.
    pub shift_excess_s: Option<f64>,
}

/// Wear index of a bite of TAF `measured_taf` against `reference_taf`:
/// `measured / reference - 1`; `None` unless both are finite and the reference > 0.
///
/// ```
/// let index = millgate::analysis::wear::wear_index(2.2, 2.0).unwrap();
/// assert!((index - 0.1).abs() < 1e-12);
/// assert_eq!(millgate::analysis::wear::wear_index(2.2, 0.0), None);
/// ```
pub fn wear_index(measured_taf: f64, reference_taf: f64) -> Option<f64> {
    let index = measured_taf / reference_taf - 1.0;
    (measured_taf.is_finite() && reference_taf.is_finite() && reference_taf > 0.0).then_some(index)
}

/// The wear trend after one more `index`: EWMA with weight [`WEAR_TREND_WEIGHT`],
/// seeded by `index` when there is no trend yet (start, or after a reset).
pub fn next_trend(trend: Option<f64>, index: f64) -> f64 {
    match trend.filter(|t| t.is_finite()) {
        Some(trend) => trend + WEAR_TREND_WEIGHT * (index - trend),
        None => index,
    }
}

/// Linear references of one driveline, cached by static torque level.
#[derive(Debug, Clone)]
pub(crate) struct WearReference {
    simulator: BiteSimulator,
    cache: BTreeMap<i64, Reference>,
}

impl WearReference {
    /// References for a driveline whose bites `simulator` simulates and analyses like
    /// its measured ones (the linear model: no gap).
    pub(crate) fn new(simulator: BiteSimulator) -> Self {
        Self {
            simulator,
            cache: BTreeMap::new(),
        }
    }

    /// The cache level of `static_knm`: the nearest multiple of
    /// [`STATIC_TORQUE_STEP_KNM`], at least one step.
    pub(crate) fn level_of(static_knm: f64) -> i64 {
        ((static_knm / STATIC_TORQUE_STEP_KNM).round() as i64).max(1)
    }

    /// The reference for a bite of static torque `static_knm`, kN*m: from the cache,
    /// or simulated at its level and cached.
    pub(crate) fn reference(&mut self, static_knm: f64) -> Result<Reference, SimulatedBiteError> {
        let level = Self::level_of(static_knm);
        if let Some(reference) = self.cache.get(&level) {
            return Ok(*reference);
        }
        let reference = self.simulate(level as f64 * STATIC_TORQUE_STEP_KNM)?;
        if self.cache.len() >= MAX_CACHED_LEVELS {
            self.cache.clear();
        }
        self.cache.insert(level, reference);
        Ok(reference)
    }

    /// The wear measures of a bite of static torque `static_knm` (kN*m), TAF `taf`
    /// and first-period shift `period_shift_s` (s).
    pub(crate) fn estimate(
        &mut self,
        static_knm: f64,
        taf: f64,
        period_shift_s: Option<f64>,
    ) -> Result<Option<WearEstimate>, SimulatedBiteError> {
        let reference = self.reference(static_knm)?;
        Ok(wear_index(taf, reference.taf).map(|index| WearEstimate {
            index,
            reference,
            shift_excess_s: period_shift_s
                .zip(reference.period_shift_s)
                .map(|(measured, linear)| measured - linear),
        }))
    }

    /// Simulate and analyse the linear reference at `level_knm`.
    fn simulate(&self, level_knm: f64) -> Result<Reference, SimulatedBiteError> {
        let bite = self.simulator.bite(level_knm, None)?;
        Ok(Reference {
            level_knm,
            taf: bite.taf,
            period_shift_s: bite.transient.period_shift_s,
        })
    }
}
