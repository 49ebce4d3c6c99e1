//! A rolling schedule: a torque record with one metal biting per bar, for the
//! virtual DAQ, the demo and end-to-end tests.
//!
//! Each bar is simulated from rest with the driveline model and its own static
//! torque: idle, the bite (the model's load rise), rolling. When the bar leaves
//! the stand the record is tapered to zero over [`TAIL_OUT_S`] (a raised-cosine
//! taper: the model has no unloading law, and a smooth tail-out keeps the next idle
//! period quiet) and the next bar follows. [`rolling_schedule_with_gap`] opens a gap
//! per bar (wear growing over the schedule).

use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use rand_distr::StandardNormal;

use crate::chain::simulate;
use crate::model::{Model, ModelError};

/// Length of the tail-out taper, s.
pub const TAIL_OUT_S: f64 = 0.2;

/// The truth of one simulated bite, from the noise-free record.
#[derive(Debug, Clone, PartialEq)]
pub struct BiteTruth {
    /// Sample index of the load onset in the whole record.
    pub onset_sample: usize,
    /// Static rolling torque of this bar, kN*m.
    pub static_torque_knm: f64,
    /// Largest measured torque during the bar, kN*m.
    pub peak_torque_knm: f64,
    /// peak / static.
    pub taf: f64,
    /// Opened gap (backlash) of every coupling during this bar, rad.
    pub backlash_rad: Vec<f64>,
}

/// A whole schedule: the measured torque and the truth of each bite.
#[derive(Debug, Clone, PartialEq)]
pub struct Schedule {
    /// Sample rate of `torque_knm`, Hz.
    pub sample_rate_hz: f64,
    /// Measured torque, kN*m, with noise when asked for.
    pub torque_knm: Vec<f64>,
    /// The truth of each bar's bite, in order.
    pub bites: Vec<BiteTruth>,
}

impl Schedule {
    /// The truth of the bar whose static torque is nearest `static_knm` (kN*m): the
    /// bite a measured one most likely is. `None` for a schedule without bars.
    pub fn nearest_truth(&self, static_knm: f64) -> Option<&BiteTruth> {
        self.next_truth(0, self.bites.len(), static_knm)
            .map(|(_, truth)| truth)
    }

    /// The bar among the `count` from index `from` on whose static torque is nearest
    /// `static_knm` (kN*m), with its index: the next bite of a schedule whose bars
    /// repeat their torques but not their gap. `None` when there is no such bar.
    pub fn next_truth(
        &self,
        from: usize,
        count: usize,
        static_knm: f64,
    ) -> Option<(usize, &BiteTruth)> {
        self.bites
            .iter()
            .enumerate()
            .skip(from)
            .take(count)
            .min_by(|(_, a), (_, b)| {
                let da = (a.static_torque_knm - static_knm).abs();
                let db = (b.static_torque_knm - static_knm).abs();
                da.total_cmp(&db)
            })
    }
}

/// Timing of each bar.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BarTiming {
    /// Quiet time before the bite, s (> 0).
    pub idle_s: f64,
    /// Rolling time from the bite until tail-out, s (> 0).
    pub rolling_s: f64,
}

/// Simulate one bar per entry of `static_torques_knm` with `model` (its own load
/// static torque is replaced), adding white Gaussian noise of `noise_rms_knm`
/// from a generator seeded with `seed`.
pub fn rolling_schedule(
    model: &Model,
    static_torques_knm: &[f64],
    timing: BarTiming,
    noise_rms_knm: f64,
    seed: u64,
) -> Result<Schedule, ModelError> {
    bars(
        model,
        static_torques_knm,
        timing,
        noise_rms_knm,
        seed,
        |_, _| {},
    )
}

/// As [`rolling_schedule`], with the backlash of coupling `coupling` set for bar k to
/// `gaps_rad[k]` (rad, >= 0; the last value for bars beyond the list): an opened gap
/// that grows (or is repaired) during the schedule.
pub fn rolling_schedule_with_gap(
    model: &Model,
    static_torques_knm: &[f64],
    timing: BarTiming,
    noise_rms_knm: f64,
    seed: u64,
    coupling: usize,
    gaps_rad: &[f64],
) -> Result<Schedule, ModelError> {
    let couplings = model.couplings.len();
    if coupling >= couplings {
        return Err(ModelError::Value {
            file: "<schedule>".into(),
            key: "coupling".into(),
            value: coupling.to_string(),
            allowed: format!("a coupling index, 0 ..= {}", couplings.saturating_sub(1)),
        });
    }
    bars(
        model,
        static_torques_knm,
        timing,
        noise_rms_knm,
        seed,
        |k, bar| {
            if let Some(&gap) = gaps_rad.get(k).or(gaps_rad.last()) {
                bar.couplings[coupling].backlash = gap;
            }
        },
    )
}

/// One bar per model of `models`, each its own driveline and load (static torque, rise
/// rate; onset and duration come from `timing`), at the first model's sample rate, noise
/// as [`rolling_schedule`]: bites of a driveline whose effect or load differs per bar.
/// At least one model.
pub(crate) fn rolling_schedule_of(
    models: &[Model],
    timing: BarTiming,
    noise_rms_knm: f64,
    seed: u64,
) -> Result<Schedule, ModelError> {
    let Some(first) = models.first() else {
        return Err(ModelError::Value {
            file: "<schedule>".into(),
            key: "models".into(),
            value: "0".into(),
            allowed: "at least one bar".into(),
        });
    };
    let torques: Vec<f64> = models.iter().map(|m| m.load.static_torque).collect();
    bars(first, &torques, timing, noise_rms_knm, seed, |k, bar| {
        *bar = models[k].clone();
    })
}

/// The schedule of one bar per static torque, bar k's model changed by `change(k, bar)`.
fn bars(
    model: &Model,
    static_torques_knm: &[f64],
    timing: BarTiming,
    noise_rms_knm: f64,
    seed: u64,
    change: impl Fn(usize, &mut Model),
) -> Result<Schedule, ModelError> {
    let sample_rate_hz = model.measurement.sample_rate;
    let mut torque_knm = Vec::new();
    let mut bites = Vec::new();
    for (k, &static_torque_knm) in static_torques_knm.iter().enumerate() {
        let mut bar = model.clone();
        change(k, &mut bar);
        bar.load.static_torque = static_torque_knm;
        bar.load.onset = timing.idle_s;
        bar.measurement.duration = timing.idle_s + timing.rolling_s;
        let mut record = simulate(&bar)?.torque_knm;
        let onset_in_bar = (timing.idle_s * sample_rate_hz).round() as usize;
        let peak_torque_knm = record[onset_in_bar..]
            .iter()
            .copied()
            .fold(f64::NEG_INFINITY, f64::max);
        let tail = (TAIL_OUT_S * sample_rate_hz).round() as usize;
        let last = *record.last().unwrap_or(&0.0);
        record.extend((1..=tail).map(|i| {
            let x = i as f64 / tail as f64;
            last * 0.5 * (1.0 + (std::f64::consts::PI * x).cos())
        }));
        bites.push(BiteTruth {
            onset_sample: torque_knm.len() + onset_in_bar,
            static_torque_knm,
            peak_torque_knm,
            taf: peak_torque_knm / static_torque_knm,
            backlash_rad: bar.couplings.iter().map(|c| c.backlash).collect(),
        });
        torque_knm.extend(record);
    }
    let mut rng = StdRng::seed_from_u64(seed);
    for value in &mut torque_knm {
        let unit: f64 = rng.sample(StandardNormal);
        *value += noise_rms_knm * unit;
    }
    Ok(Schedule {
        sample_rate_hz,
        torque_knm,
        bites,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bites_sit_at_their_onsets_with_their_static_torque() {
        let model = Model::from_toml_str(
            include_str!("../models/table2-adjusted.toml"),
            "table2-adjusted.toml",
        )
        .unwrap();
        let timing = BarTiming {
            idle_s: 0.3,
            rolling_s: 1.0,
        };
        let schedule = rolling_schedule(&model, &[112.0, 60.0], timing, 0.0, 1).unwrap();
        let per_bar = ((0.3 + 1.0 + TAIL_OUT_S) * 2000.0).round() as usize;
        assert_eq!(schedule.torque_knm.len(), 2 * per_bar);
        assert_eq!(schedule.bites[0].onset_sample, 600);
        assert_eq!(schedule.bites[1].onset_sample, per_bar + 600);
        for bite in &schedule.bites {
            assert!(
                schedule.torque_knm[bite.onset_sample - 1].abs() < 1e-9,
                "quiet before onset"
            );
            // A linear driveline under a load rise: overshoot, but TAF at most ~2.
            assert!(bite.taf > 1.05 && bite.taf <= 2.0, "taf {}", bite.taf);
        }
        assert_eq!(schedule.bites[0].backlash_rad, [0.0, 0.0]);
        // Rolling: the record settles near the static torque before tail-out.
        let settled = schedule.torque_knm[per_bar - 450];
        assert!((settled - 112.0).abs() < 0.1 * 112.0, "settled {settled}");
        assert!(
            schedule.torque_knm[per_bar - 1].abs() < 1e-9,
            "tapered to zero"
        );
    }

    #[test]
    fn a_growing_gap_is_set_per_bar_and_raises_the_taf() {
        let model = Model::from_toml_str(
            include_str!("../models/table2-adjusted.toml"),
            "table2-adjusted.toml",
        )
        .unwrap();
        let timing = BarTiming {
            idle_s: 0.3,
            rolling_s: 1.0,
        };
        let gaps = [0.0, 2e-3];
        let schedule =
            rolling_schedule_with_gap(&model, &[80.0; 3], timing, 0.0, 1, 1, &gaps).unwrap();
        let backlash: Vec<f64> = schedule.bites.iter().map(|b| b.backlash_rad[1]).collect();
        assert_eq!(backlash, [0.0, 2e-3, 2e-3], "the last gap holds on");
        assert!(schedule.bites[1].taf > schedule.bites[0].taf + 0.1);
        assert_eq!(schedule.next_truth(1, 2, 80.0).map(|(k, _)| k), Some(1));
        let error = rolling_schedule_with_gap(&model, &[80.0], timing, 0.0, 1, 2, &gaps)
            .expect_err("no coupling 2");
        assert!(error.to_string().contains("0 ..= 1"), "{error}");
    }
}
