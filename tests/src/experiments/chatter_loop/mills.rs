//! The loop's mills, commissioned on recordings of their stable rolling ([`mills`]),
//! and the runs drawn over them ([`runs`]).

use millgate::analysis::chatter::commission::commission;
use millgate_sim::tandem::simulate::{NoiseBurst, SpeedRamp};
use millgate_sim::tandem::truth::mill_critical_speed;
use millgate_sim::tandem::TandemMill;
use rand::rngs::SmallRng;
use rand::{Rng, SeedableRng};

use super::{LoopPlan, Mill, Run, Scenario, MARGIN_PERCENT, STANDS};
use crate::experiments::chatter_eval::{
    monitor_config_with, noisy_run, parallel, recording_from, SAMPLE_RATE_HZ,
};

/// The mills of `plan` with their critical speeds and commissioned thresholds.
pub fn mills(plan: &LoopPlan) -> anyhow::Result<Vec<Mill>> {
    parallel(plan.threads, &plan.mills, |mill_plan| {
        let mill = TandemMill::new(&mill_plan.load()?)?;
        let critical = mill_critical_speed(&mill)?;
        let unit_m_s = mill.exit_speed(mill.stands().len() - 1, 1.0);
        let schedule_seed = mill_plan
            .schedule
            .bytes()
            .fold(0u64, |h, b| h.wrapping_mul(31).wrapping_add(u64::from(b)));
        let mill_seed = (((mill_plan.friction * 1000.0) as u64) << 20)
            | ((mill_plan.damping * 1000.0) as u64)
            | (schedule_seed << 40);
        let seed = plan.seed ^ mill_seed;
        let mut rng = SmallRng::seed_from_u64(seed);
        let top = plan.top * critical.speed;
        let ramps = plan.commission_recordings - plan.commission_recordings / 3;
        let recordings = (0..plan.commission_recordings)
            .map(|k| {
                // Accelerations to the top speed, one in each of `ramps` equal steps of
                // log(0.2..2 m/s^2) (the rates the runs use: the end of an acceleration
                // raises the gain for a second or two), then a third of the recordings
                // rolling there; each at its own noise level.
                let (low, high): (f64, f64) = (0.2_f64.ln(), 2.0_f64.ln());
                let step = (high - low) / ramps as f64;
                let accel = rng
                    .random_range(low + step * k as f64..low + step * (k as f64 + 1.0))
                    .exp();
                let noise = log_uniform(&mut rng, 0.5, 2.0);
                let (ramp, duration_s) = if k < ramps {
                    let start = 0.6 * critical.speed;
                    let ramp = SpeedRamp {
                        start,
                        end: top,
                        hold_s: plan.settle_s,
                        accel_m_s2: accel,
                    };
                    let reach = ramp.time_at(top, unit_m_s).unwrap_or(0.0);
                    (ramp, reach + plan.commission_s)
                } else {
                    (SpeedRamp::constant(top), plan.settle_s + plan.commission_s)
                };
                let record = noisy_run(&mill, ramp, duration_s, noise, rng.random())?;
                // The settling time is not part of the recording.
                let from = (plan.settle_s * SAMPLE_RATE_HZ) as usize;
                Ok(recording_from(format!("commissioning {k}"), &record, from))
            })
            .collect::<anyhow::Result<Vec<_>>>()?;
        let gain = commission(
            &monitor_config_with(STANDS, "k_max = 0.25\ndetector = \"paper\"\n")?,
            0,
            &recordings,
            MARGIN_PERCENT,
        )?;
        let rms = commission(
            &monitor_config_with(
                STANDS,
                "k_max = 0.25\ndetector = \"paper\"\ngain_window_s = 0.5\n",
            )?,
            0,
            &recordings,
            MARGIN_PERCENT,
        )?;
        Ok(Mill {
            plan: mill_plan.clone(),
            mill,
            critical,
            unit_m_s,
            gain_thresholds: gain.gain_thresholds,
            rms_thresholds: rms.band_rms_thresholds,
            gain_release: gain.slow_down_release,
            rms_release: rms.band_rms_release,
            k_max: gain.k_max,
        })
    })
}

fn log_uniform(rng: &mut SmallRng, low: f64, high: f64) -> f64 {
    rng.random_range(low.ln()..=high.ln()).exp()
}

/// The runs of `plan` over `mills`: the accelerated ones, then the stable ones, then
/// the welds.
pub fn runs(plan: &LoopPlan, mills: &[Mill]) -> Vec<Run> {
    let mut rng = SmallRng::seed_from_u64(plan.seed.wrapping_mul(7919));
    let mut runs = Vec::new();
    let kinds = std::iter::repeat_n(0, plan.accelerated)
        .chain(std::iter::repeat_n(1, plan.stable))
        .chain(std::iter::repeat_n(2, plan.welds))
        .chain(std::iter::repeat_n(3, plan.weld_ramps));
    for (index, kind) in kinds.enumerate() {
        let mill = index % mills.len();
        let m = &mills[mill];
        let critical = m.critical_m_s();
        let noise = log_uniform(&mut rng, 0.5, 2.0);
        let eccentricity = rng.random_range(0.5..2.0);
        let decel_m_s2 = log_uniform(&mut rng, 0.5, 2.0);
        let accel = log_uniform(&mut rng, 0.2, 2.0);
        let top = plan.top * critical;
        let (scenario, duration_s) = match kind {
            0 => {
                let start_m_s = rng.random_range(0.6..0.85) * critical;
                let setpoint_m_s = rng.random_range(1.15..1.5) * critical;
                let reach = (setpoint_m_s - start_m_s) / accel;
                (
                    Scenario::Accelerated {
                        start_m_s,
                        setpoint_m_s,
                        accel_m_s2: accel,
                    },
                    plan.settle_s + reach + 40.0,
                )
            }
            1 if rng.random_bool(0.5) => {
                let reach = (top - 0.6 * critical) / accel;
                (
                    Scenario::Stable {
                        accel_m_s2: Some(accel),
                    },
                    plan.settle_s + reach + plan.stable_scored_s,
                )
            }
            1 => (
                Scenario::Stable { accel_m_s2: None },
                plan.settle_s + plan.stable_scored_s,
            ),
            3 => {
                let start_m_s = rng.random_range(0.6..0.85) * critical;
                let setpoint_m_s = rng.random_range(1.15..1.5) * critical;
                let reach = (setpoint_m_s - start_m_s) / accel;
                let at_critical_s = plan.settle_s + (critical - start_m_s) / accel;
                let duration_s = rng.random_range(2.0..5.0);
                let ends_before_s = rng.random_range(0.0..3.0);
                (
                    Scenario::WeldRamp {
                        start_m_s,
                        setpoint_m_s,
                        accel_m_s2: accel,
                        burst: NoiseBurst {
                            time_s: (at_critical_s - ends_before_s - duration_s).max(0.0),
                            duration_s,
                            factor: rng.random_range(2.0..4.0),
                            stand: None,
                        },
                    },
                    plan.settle_s + reach + 40.0,
                )
            }
            _ => (
                Scenario::Weld {
                    burst: NoiseBurst {
                        time_s: plan.settle_s + 10.0,
                        duration_s: rng.random_range(2.0..5.0),
                        factor: rng.random_range(2.0..4.0),
                        stand: None,
                    },
                },
                plan.settle_s + 30.0,
            ),
        };
        runs.push(Run {
            mill,
            scenario,
            noise,
            eccentricity,
            decel_m_s2,
            seed: plan.seed.wrapping_mul(1000).wrapping_add(index as u64),
            duration_s,
        });
    }
    runs
}
