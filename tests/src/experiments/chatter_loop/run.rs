//! One run of the loop: the online mill, its automation and the gateway's monitor fed
//! each block ([`run_loop`]).

use std::collections::VecDeque;
use std::time::{Duration, Instant};

use millgate::analysis::chatter::{ChatterMonitor, ChatterUpdate};
use millgate_sim::tandem::control::{SlowDownPolicy, SpeedControl};
use millgate_sim::tandem::online::{OnlineError, OnlineMill};
use millgate_sim::tandem::simulate::{
    Accelerometer, Excitation, NoiseBurst, RunError, SimulationSetup, SpeedRange,
};

use super::{Detector, LoopPlan, Mill, Outcome, Run, Scenario, TraceRow, WeldBits, CYCLE_SAMPLES};
use crate::experiments::chatter_eval::SAMPLE_RATE_HZ;

/// `run` on `mill`, with `detector` acting on the automation (closed loop) or with the
/// request ignored (`None`: open loop); every cycle in the outcome's trace with
/// `trace` (the figure is `detector`'s, or the band gain's in the open loop).
pub fn run_loop(
    plan: &LoopPlan,
    mill: &Mill,
    run: &Run,
    detector: Option<Detector>,
    trace: bool,
) -> anyhow::Result<Outcome> {
    let critical = mill.critical_m_s();
    let top = plan.top * critical;
    let (start, operator, accel) = match run.scenario {
        Scenario::Accelerated {
            start_m_s,
            setpoint_m_s,
            accel_m_s2,
        }
        | Scenario::WeldRamp {
            start_m_s,
            setpoint_m_s,
            accel_m_s2,
            ..
        } => (start_m_s, setpoint_m_s, accel_m_s2),
        Scenario::Stable {
            accel_m_s2: Some(accel),
        } => (0.6 * critical, top, accel),
        Scenario::Stable { accel_m_s2: None } | Scenario::Weld { .. } => (top, top, 1.0),
    };
    let policy = SlowDownPolicy {
        accel_m_s2: accel,
        decel_m_s2: run.decel_m_s2,
        ..plan.policy
    };
    let control = SpeedControl::new(policy, start, start)?;
    let setup = SimulationSetup {
        excitation: excitation(plan, run),
        sensor: Accelerometer {
            sample_rate_hz: SAMPLE_RATE_HZ,
            ..Accelerometer::default()
        },
        seed: run.seed,
        internal_rate_hz: None,
        speeds: SpeedRange {
            lowest: 1.0,
            highest: 1.0,
        },
    };
    let mut online = OnlineMill::new(&mill.mill, &setup, control, CYCLE_SAMPLES, operator)?;
    let judged = detector.unwrap_or(Detector::BandGain);
    let mut monitor = ChatterMonitor::new(&mill.config(judged, plan.weld_bit)?, 0)?;
    // The PLC's weld bits, when the plan reads them: the mill's set for the whole
    // weld, a stand's for its burst.
    let weld = run.scenario.weld().filter(|_| plan.weld_bit.is_some());
    let stand_welds = match weld {
        Some(_) if plan.weld_bits == WeldBits::Stands => run.scenario.weld_bursts(plan.weld_passes),
        _ => Vec::new(),
    };
    let mut slow_down = monitor.slow_down();
    let hop_s = monitor.hop_s();
    let mut requested = VecDeque::from(vec![false; plan.delay_cycles]);
    let mut record = online.record(CYCLE_SAMPLES);
    let cycles = (run.duration_s / online.cycle_s()).round() as usize;
    let t0 = Instant::now();
    let mut outcome = Outcome {
        developed_s: None,
        onset_s: None,
        events: Vec::new(),
        duration_s: 0.0,
        trace: Vec::new(),
    };
    let mut level = None;
    for _ in 0..cycles {
        if online.time_s() >= plan.settle_s {
            online.control_mut().set_setpoint(operator);
        }
        let seen = requested.pop_front().unwrap_or(false) && detector.is_some();
        for values in record.acceleration.iter_mut() {
            values.clear();
        }
        record.speed.clear();
        for tension in record.tension_pa.iter_mut() {
            tension.clear();
        }
        let truth = match online.cycle(seen, &mut record) {
            Ok(truth) => truth,
            // Far past developed chatter the linear model leaves the numbers: the run
            // ends there (developed was recorded before).
            Err(OnlineError::Run(RunError::Diverged { .. })) => break,
            Err(error) => return Err(error.into()),
        };
        if truth.speed_m_s >= critical && outcome.onset_s.is_none() {
            outcome.onset_s = Some(truth.time_s);
        }
        let arrival = t0 + Duration::from_secs_f64(truth.time_s);
        let cycle_start_s = truth.time_s - online.cycle_s();
        let in_cycle =
            |b: &NoiseBurst| cycle_start_s < b.time_s + b.duration_s && truth.time_s > b.time_s;
        if plan.weld_bits == WeldBits::Mill && weld.as_ref().is_some_and(in_cycle) {
            slow_down.weld();
        }
        for burst in stand_welds.iter().filter(|&b| in_cycle(b)) {
            match burst.stand {
                Some(stand) => slow_down.weld_at(stand),
                None => slow_down.weld(),
            }
        }
        for (stand, values) in record.acceleration.iter().enumerate() {
            let Some(change) = monitor.samples(stand, values, arrival) else {
                continue;
            };
            level = None;
            match judged {
                Detector::BandRms => {
                    let rms_level = monitor.gain_window().map(|window| {
                        window
                            .band_rms
                            .iter()
                            .zip(&mill.rms_thresholds)
                            .map(|(rms, threshold)| rms / threshold)
                            .fold(0.0, f64::max)
                    });
                    match (&change, rms_level) {
                        (ChatterUpdate::Evaluated(_), Some(l)) => {
                            level = Some(l);
                            slow_down.window(l, hop_s);
                        }
                        _ => slow_down.untrusted(),
                    }
                }
                Detector::BandGain | Detector::Paper => {
                    monitor.judge(&change, &mut slow_down);
                    if let ChatterUpdate::Evaluated(result) = &change {
                        level = monitor.alarm_level(result);
                    }
                }
            }
        }
        requested.push_back(slow_down.requested());
        if trace {
            outcome.trace.push(TraceRow {
                t_s: truth.time_s,
                speed_m_min: truth.speed_m_s * 60.0,
                level,
                request: seen,
                swing: truth.swing,
            });
        }
        if online.developed_s().is_some() && detector.is_none() {
            // The open loop: chatter has developed, nothing more to learn.
            break;
        }
    }
    outcome.developed_s = online.developed_s();
    outcome.events = online.control().events().to_vec();
    outcome.duration_s = online.time_s();
    Ok(outcome)
}

/// The excitation of a run of `plan`.
fn excitation(plan: &LoopPlan, run: &Run) -> Excitation {
    let mut excitation = Excitation::default();
    excitation.force_noise_density *= run.noise;
    excitation.entry_gauge_rms_m *= run.noise;
    excitation.eccentricity_m = excitation.eccentricity_m.map(|e| e * run.eccentricity);
    excitation
        .noise_bursts
        .extend(run.scenario.weld_bursts(plan.weld_passes));
    excitation
}
