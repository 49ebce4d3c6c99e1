//! The ground truth of a simulated run, from the model itself: the critical speed (the
//! rightmost characteristic root crossing the axis, [`super::roots`]), the onset (the
//! ramp passing it) and developed chatter (an interstand tension swinging by more than
//! half its schedule value: the strip is then marked or goes slack).

use super::linear::TandemMill;
use super::roots::{critical_speed, CriticalSpeed, RootsError};
use super::simulate::{Record, SpeedRamp};

/// Fraction of the schedule tension a swing must exceed to count as developed chatter.
pub const DEVELOPED_TENSION_FRACTION: f64 = 0.5;

/// Speed factors searched for the critical speed.
pub const SEARCH_SPEEDS: (f64, f64) = (0.2, 4.0);

/// What the model says about one run.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GroundTruth {
    /// The mill's critical speed.
    pub(crate) critical: CriticalSpeed,
    /// When the ramp passes the critical speed, s (None: it never does).
    pub onset_s: Option<f64>,
    /// When an interstand tension first deviates by more than
    /// [`DEVELOPED_TENSION_FRACTION`] of its schedule value, s (None: never).
    pub developed_s: Option<f64>,
}

/// The critical speed of `mill` in [`SEARCH_SPEEDS`], to 1e-3.
pub fn mill_critical_speed(mill: &TandemMill) -> Result<CriticalSpeed, RootsError> {
    critical_speed(mill, SEARCH_SPEEDS.0, SEARCH_SPEEDS.1, 1e-3)
}

/// The ground truth of `record`, simulated on `mill` with `ramp`, given the mill's
/// `critical` speed.
pub fn ground_truth(
    mill: &TandemMill,
    ramp: &SpeedRamp,
    record: &Record,
    critical: CriticalSpeed,
) -> GroundTruth {
    let exit_speed = mill.exit_speed(mill.stands().len() - 1, 1.0);
    GroundTruth {
        critical,
        onset_s: ramp.time_at(critical.speed, exit_speed),
        developed_s: developed_time(mill, record),
    }
}

/// First time an interstand tension deviates by more than
/// [`DEVELOPED_TENSION_FRACTION`] of its schedule value, s.
pub fn developed_time(mill: &TandemMill, record: &Record) -> Option<f64> {
    first_developed(mill, record, 0..record.len()).map(|k| k as f64 / record.sample_rate_hz)
}

/// The first sample in `range` of `record` where an interstand tension deviates by
/// more than [`DEVELOPED_TENSION_FRACTION`] of its schedule value.
pub(crate) fn first_developed(
    mill: &TandemMill,
    record: &Record,
    range: std::ops::Range<usize>,
) -> Option<usize> {
    record
        .tension_pa
        .iter()
        .enumerate()
        .filter_map(|(j, tension)| {
            let limit = developed_limit_pa(mill, j);
            tension[range.clone()].iter().position(|d| d.abs() > limit)
        })
        .min()
        .map(|k| range.start + k)
}

/// The tension deviation between stands `j` and `j + 1` that counts as developed
/// chatter, Pa.
pub(crate) fn developed_limit_pa(mill: &TandemMill, interstand: usize) -> f64 {
    DEVELOPED_TENSION_FRACTION * mill.nominal_tension_pa(interstand)
}

/// The chatter amplitude of samples `range` of `record`: the largest interstand
/// tension deviation over its developed limit (above 1: developed chatter).
pub(crate) fn tension_swing(
    mill: &TandemMill,
    record: &Record,
    range: std::ops::Range<usize>,
) -> f64 {
    record
        .tension_pa
        .iter()
        .enumerate()
        .map(|(j, tension)| {
            let limit = developed_limit_pa(mill, j);
            tension[range.clone()]
                .iter()
                .fold(0.0_f64, |largest, d| largest.max(d.abs() / limit))
        })
        .fold(0.0, f64::max)
}
