//! The chatter closed loop on the physical tandem model, offline and faster than real
//! time: the mill (`sim::tandem::online`, its speed set by the automation of
//! `sim::tandem::control` while it runs), the gateway's own monitor fed each DAQ block
//! as it is produced, and the monitor's slow-down request reaching the automation
//! [`LoopPlan::delay_cycles`] PLC cycles later (the latency measured through the
//! gateway over Modbus in `tests/tests/chatter_loop_e2e.rs`).
//!
//! **Mills.** Each mill is a pass schedule of `sim/schedules/` (Lu et al.'s 2.0 -> 0.2
//! mm, a heavy gauge 3.0 -> 0.8 mm, a tinplate 1.8 -> 0.18 mm) with its friction and
//! stack damping scaled ([`LoopPlan::mills`]), its critical speed from the characteristic roots, and
//! its own thresholds from `millgate chatter commission`'s code
//! ([`millgate::analysis::chatter::commission::commission`]) on recordings of its stable
//! rolling made for that only: accelerations from 60% of the critical speed to the
//! highest allowed speed ([`LoopPlan::top`] of the critical speed) and rolling there.
//!
//! **Detectors**, each with thresholds from those recordings:
//! - *band gain* (the gateway's default, `detector = "band_gain"`, 2 s gain window):
//!   the commissioned `gain_thresholds` and `slow_down_release`;
//! - *band RMS* (the mills' usual vibration alarm): chatter-band RMS per stand over
//!   0.5 s (the monitor with `gain_window_s = 0.5`) against the commissioned band-RMS
//!   levels, judged by the gateway's `SlowDown` (its release level commissioned the
//!   same way);
//! - *paper* (`detector = "paper"`): sigma_n <= sigma_min and K_mean >= the
//!   commissioned `k_max`.
//!
//! **Runs** ([`Scenario`]): *accelerated*: from 60-85% of the critical speed, held for
//! the settling time, the operator's setpoint then at 1.15-1.5 times the critical speed,
//! approached at 0.2-2 m/s^2, open loop (the request ignored) and closed loop;
//! *stable*: at the highest allowed speed, half reached by an acceleration from 60% at
//! 0.2-2 m/s^2 (the end of an acceleration raises the gain for a second or two), scored
//! after the settling time; *weld*: stable at the highest allowed speed with the force
//! noise 2-4 times louder for 2-5 s. Every run draws its mill, a noise factor (force
//! noise and incoming gauge, log-uniform 0.5-2), an eccentricity factor (0.5-2), a
//! deceleration (0.5-2 m/s^2, log-uniform) and a seed.

use std::collections::VecDeque;
use std::time::{Duration, Instant};

use millgate::analysis::chatter::commission::commission;
use millgate::analysis::chatter::{ChatterMonitor, ChatterUpdate, Recording};
use millgate_config::Config;
use millgate_sim::tandem::control::{SlowDownEvent, SlowDownPolicy, SpeedControl};
use millgate_sim::tandem::online::{OnlineError, OnlineMill};
use millgate_sim::tandem::roots::CriticalSpeed;
use millgate_sim::tandem::simulate::{
    simulate, Accelerometer, Excitation, NoiseBurst, RunError, RunSettings, SimulationSetup,
    SpeedRamp, SpeedRange,
};
use millgate_sim::tandem::truth::mill_critical_speed;
use millgate_sim::tandem::{PassSchedule, TandemMill};
use rand::rngs::SmallRng;
use rand::{Rng, SeedableRng};

use crate::chatter_eval::{monitor_config_with, parallel, quartiles, SAMPLE_RATE_HZ};

/// Samples per DAQ block and PLC cycle: 48 ms at 2500 Hz, the example configuration's
/// blocks; the automation reads the request once per cycle.
pub const CYCLE_SAMPLES: usize = 120;
/// Stands of the example schedule.
pub const STANDS: usize = 5;
/// Margin of the commissioned thresholds, percent (the command's default).
pub const MARGIN_PERCENT: f64 = 10.0;

/// How many runs of each kind, and how.
#[derive(Debug, Clone, PartialEq)]
pub struct LoopPlan {
    /// The mills: one each.
    pub mills: Vec<MillPlan>,
    /// Commissioning recordings per mill, each `commission_s` long after the settling.
    pub commission_recordings: usize,
    /// Length of a commissioning recording after the settling time, s.
    pub commission_s: f64,
    /// Accelerated runs (each open and closed loop).
    pub accelerated: usize,
    /// Stable runs at the highest allowed speed per detector.
    pub stable: usize,
    /// Scored time of a stable run at the top speed, s.
    pub stable_scored_s: f64,
    /// Weld runs per detector.
    pub welds: usize,
    /// Unscored start of every run, s (the delay roots near the axis need it).
    pub settle_s: f64,
    /// The highest allowed speed, a fraction of the critical speed.
    pub top: f64,
    /// Request delay, PLC cycles: the automation reads the verdict on the block of
    /// cycle `k` at the start of cycle `k + 1 + delay_cycles`. Through the gateway over
    /// Modbus the bit was in the PLC's register 21-27 ms after the DAQ published the
    /// block and the next scan read it: 1 (`tests/tests/chatter_loop_e2e.rs`).
    pub delay_cycles: usize,
    /// The automation's slow-down (its acceleration and deceleration are drawn per run).
    pub policy: SlowDownPolicy,
    /// Seed of the draws.
    pub seed: u64,
    /// Worker threads.
    pub threads: usize,
}

impl LoopPlan {
    /// The README's figures: seven mills on three schedules, 40 accelerated runs, an hour of stable rolling
    /// and 20 welds per detector.
    pub fn full() -> LoopPlan {
        LoopPlan {
            mills: vec![
                MillPlan::new("lu2019-5stand.toml", 1.0, 1.0),
                MillPlan::new("lu2019-5stand.toml", 0.9, 0.95),
                MillPlan::new("lu2019-5stand.toml", 1.1, 1.05),
                MillPlan::new("heavy-5stand.toml", 1.0, 1.0),
                MillPlan::new("heavy-5stand.toml", 0.95, 1.1),
                MillPlan::new("tinplate-5stand.toml", 1.0, 1.0),
                MillPlan::new("tinplate-5stand.toml", 1.05, 0.9),
            ],
            commission_recordings: 6,
            commission_s: 60.0,
            accelerated: 40,
            stable: 60,
            stable_scored_s: 60.0,
            welds: 20,
            settle_s: 20.0,
            top: 0.95,
            delay_cycles: 1,
            policy: SlowDownPolicy::default(),
            seed: 27,
            threads: std::thread::available_parallelism().map_or(2, |n| n.get()),
        }
    }

    /// The small deterministic version CI runs: the nominal mill, three accelerated
    /// runs, two stable runs and a weld, the band-gain detector.
    pub fn quick() -> LoopPlan {
        LoopPlan {
            mills: vec![MillPlan::new("lu2019-5stand.toml", 1.0, 1.0)],
            commission_recordings: 3,
            commission_s: 30.0,
            accelerated: 3,
            stable: 2,
            stable_scored_s: 30.0,
            welds: 1,
            settle_s: 12.0,
            threads: 2,
            ..LoopPlan::full()
        }
    }
}

/// A mill of the plan: a pass schedule of `sim/schedules/` with its friction and stack
/// damping scaled.
#[derive(Debug, Clone, PartialEq)]
pub struct MillPlan {
    /// The schedule's file name in `sim/schedules/`.
    pub schedule: &'static str,
    /// Friction factor.
    pub friction: f64,
    /// Stack damping factor.
    pub damping: f64,
}

impl MillPlan {
    /// The schedule `schedule` (a file name in `sim/schedules/`) scaled.
    pub fn new(schedule: &'static str, friction: f64, damping: f64) -> MillPlan {
        MillPlan {
            schedule,
            friction,
            damping,
        }
    }

    /// The scaled schedule.
    pub fn load(&self) -> anyhow::Result<PassSchedule> {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../sim/schedules")
            .join(self.schedule);
        Ok(PassSchedule::load(path)?.scaled(self.friction, self.damping))
    }
}

/// A detector the loop runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Detector {
    /// Chatter-band gain over 2 s against the commissioned `gain_thresholds`.
    BandGain,
    /// Chatter-band RMS over 0.5 s against the commissioned band-RMS levels.
    BandRms,
    /// The paper's conditions with the commissioned `k_max`.
    Paper,
}

impl Detector {
    /// Every detector, in table order.
    pub const ALL: [Detector; 3] = [Detector::BandGain, Detector::BandRms, Detector::Paper];

    /// Its name in the table.
    pub fn name(self) -> &'static str {
        match self {
            Detector::BandGain => "band gain 2 s (default)",
            Detector::BandRms => "band RMS 0.5 s",
            Detector::Paper => "paper (sigma_n, K_mean)",
        }
    }
}

/// A mill and its commissioned thresholds.
#[derive(Debug, Clone)]
pub struct Mill {
    /// Its schedule and factors.
    pub plan: MillPlan,
    /// The linearised mill.
    pub mill: TandemMill,
    /// Its critical speed.
    pub critical: CriticalSpeed,
    /// Exit speed at speed factor 1, m/s.
    pub unit_m_s: f64,
    /// Commissioned per-stand gain thresholds (2 s).
    pub gain_thresholds: Vec<f64>,
    /// Commissioned per-stand band-RMS levels (0.5 s), m/s^2.
    pub rms_thresholds: Vec<f64>,
    /// Commissioned `slow_down_release` for the gain thresholds.
    pub gain_release: f64,
    /// The same for the band-RMS levels.
    pub rms_release: f64,
    /// Commissioned `k_max`.
    pub k_max: f64,
}

impl Mill {
    /// The critical speed as the last stand's exit speed, m/s.
    pub fn critical_m_s(&self) -> f64 {
        self.critical.speed * self.unit_m_s
    }

    /// The monitor configuration of `detector` with this mill's thresholds.
    pub fn config(&self, detector: Detector) -> anyhow::Result<Config> {
        let list = |values: &[f64]| {
            let items: Vec<String> = values.iter().map(|v| format!("{v}")).collect();
            format!("[{}]", items.join(", "))
        };
        match detector {
            Detector::BandGain => monitor_config_with(
                STANDS,
                &format!(
                    "k_max = 0.25\ndetector = \"band_gain\"\ngain_thresholds = {}\n\
                     slow_down_release = {}\n",
                    list(&self.gain_thresholds),
                    self.gain_release
                ),
            ),
            Detector::BandRms => monitor_config_with(
                STANDS,
                &format!(
                    "k_max = 0.25\ndetector = \"paper\"\ngain_window_s = 0.5\n\
                     slow_down_release = {}\n",
                    self.rms_release
                ),
            ),
            Detector::Paper => monitor_config_with(
                STANDS,
                &format!("k_max = {}\ndetector = \"paper\"\n", self.k_max),
            ),
        }
    }
}

/// What a run does.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Scenario {
    /// Held at `start_m_s` for the settling time, then the operator's setpoint
    /// `setpoint_m_s` approached at `accel_m_s2`.
    Accelerated {
        /// Speed at the start, m/s.
        start_m_s: f64,
        /// The operator's setpoint after the settling time, m/s.
        setpoint_m_s: f64,
        /// The operator's acceleration, m/s^2.
        accel_m_s2: f64,
    },
    /// Stable rolling at the highest allowed speed; with `accel_m_s2`, reached from 60%
    /// of the critical speed after the settling time.
    Stable {
        /// The acceleration to the top speed, m/s^2, if any.
        accel_m_s2: Option<f64>,
    },
    /// Stable at the highest allowed speed with a louder force noise for a while.
    Weld {
        /// The burst.
        burst: NoiseBurst,
    },
}

/// One drawn run.
#[derive(Debug, Clone, PartialEq)]
pub struct Run {
    /// Index of the mill in [`LoopPlan::mills`].
    pub mill: usize,
    /// What it does.
    pub scenario: Scenario,
    /// Force-noise and gauge factor.
    pub noise: f64,
    /// Eccentricity factor.
    pub eccentricity: f64,
    /// The automation's deceleration on a request, m/s^2.
    pub decel_m_s2: f64,
    /// Seed of the simulation.
    pub seed: u64,
    /// Length, s.
    pub duration_s: f64,
}

/// One cycle of a traced run (for the plot).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TraceRow {
    /// Time at the cycle's end, s.
    pub t_s: f64,
    /// Exit speed, m/min.
    pub speed_m_min: f64,
    /// The detector's figure relative to its alarm level (1 = alarm), when evaluated.
    pub level: Option<f64>,
    /// The request as the automation read it this cycle.
    pub request: bool,
    /// Chatter amplitude: the largest tension swing over its developed limit.
    pub swing: f64,
}

/// How a run ended.
#[derive(Debug, Clone, PartialEq)]
pub struct Outcome {
    /// When chatter developed, s (None: never).
    pub developed_s: Option<f64>,
    /// When the speed first passed the critical speed, s.
    pub onset_s: Option<f64>,
    /// The slow-downs.
    pub events: Vec<SlowDownEvent>,
    /// Simulated, s (shorter than planned when the simulation diverged past developed
    /// chatter).
    pub duration_s: f64,
    /// Every cycle, when traced.
    pub trace: Vec<TraceRow>,
}

impl Outcome {
    /// Slow-downs requested at or after `from_s`.
    pub fn events_from(&self, from_s: f64) -> usize {
        self.events
            .iter()
            .filter(|e| e.requested_s >= from_s)
            .count()
    }
}

/// The excitation of a run.
fn excitation(run: &Run) -> Excitation {
    let mut excitation = Excitation::default();
    excitation.force_noise_density *= run.noise;
    excitation.entry_gauge_rms_m *= run.noise;
    excitation.eccentricity_m = excitation.eccentricity_m.map(|e| e * run.eccentricity);
    if let Scenario::Weld { burst } = run.scenario {
        excitation.noise_bursts.push(burst);
    }
    excitation
}

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
                let mut excitation = Excitation::default();
                excitation.force_noise_density *= noise;
                excitation.entry_gauge_rms_m *= noise;
                let record = simulate(
                    &mill,
                    &RunSettings {
                        ramp,
                        excitation,
                        sensor: Accelerometer {
                            sample_rate_hz: SAMPLE_RATE_HZ,
                            ..Accelerometer::default()
                        },
                        duration_s,
                        seed: rng.random(),
                        internal_rate_hz: None,
                    },
                )?;
                // The settling time is not part of the recording.
                let from = (plan.settle_s * SAMPLE_RATE_HZ) as usize;
                Ok(Recording {
                    name: format!("commissioning {k}"),
                    time_s: (from..record.len())
                        .map(|i| i as f64 / SAMPLE_RATE_HZ)
                        .collect(),
                    stands: record
                        .acceleration
                        .iter()
                        .map(|a| a[from..].to_vec())
                        .collect(),
                    speed: None,
                })
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
        .chain(std::iter::repeat_n(2, plan.welds));
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
            _ => (
                Scenario::Weld {
                    burst: NoiseBurst {
                        time_s: plan.settle_s + 10.0,
                        duration_s: rng.random_range(2.0..5.0),
                        factor: rng.random_range(2.0..4.0),
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
        excitation: excitation(run),
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
    let mut monitor = ChatterMonitor::new(&mill.config(judged)?, 0)?;
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

/// One detector's closed-loop figures.
#[derive(Debug, Clone, PartialEq)]
pub struct LoopScore {
    /// The detector.
    pub detector: Detector,
    /// Accelerated runs that developed chatter with the loop closed.
    pub developed: usize,
    /// Accelerated runs.
    pub accelerated: usize,
    /// Slow-downs in the accelerated runs that did not develop chatter.
    pub events: Vec<SlowDownEvent>,
    /// Per event, the time below the speed at the request, s: until it was back, or
    /// the next request, or the run's end.
    pub reduced_s: Vec<f64>,
    /// False slow-downs in the stable runs' scored time, and those hours.
    pub false_stable: (usize, f64),
    /// Weld runs with a slow-down in their scored time, and weld runs.
    pub false_welds: (usize, usize),
}

/// The time each event of `outcome` spent below its speed at the request, s.
pub fn reduced_times(outcome: &Outcome) -> Vec<f64> {
    outcome
        .events
        .iter()
        .enumerate()
        .map(|(k, event)| {
            let end = outcome
                .events
                .get(k + 1)
                .map_or(outcome.duration_s, |next| next.requested_s);
            event.recovered_s.unwrap_or(end).min(end) - event.requested_s
        })
        .collect()
}

/// Every closed-loop figure of `detector` over `runs` (the open loop's in
/// [`open_loop_developed`]).
pub fn score(
    plan: &LoopPlan,
    mills: &[Mill],
    runs: &[Run],
    detector: Detector,
) -> anyhow::Result<(LoopScore, Vec<Outcome>)> {
    let outcomes = parallel(plan.threads, runs, |run| {
        run_loop(plan, &mills[run.mill], run, Some(detector), false)
    })?;
    let mut score = LoopScore {
        detector,
        developed: 0,
        accelerated: 0,
        events: Vec::new(),
        reduced_s: Vec::new(),
        false_stable: (0, 0.0),
        false_welds: (0, 0),
    };
    for (run, outcome) in runs.iter().zip(&outcomes) {
        match run.scenario {
            Scenario::Accelerated { .. } => {
                score.accelerated += 1;
                if outcome.developed_s.is_some() {
                    score.developed += 1;
                } else {
                    score.events.extend_from_slice(&outcome.events);
                    score.reduced_s.extend(reduced_times(outcome));
                }
            }
            Scenario::Stable { .. } => {
                score.false_stable.0 += outcome.events_from(plan.settle_s);
                score.false_stable.1 += (outcome.duration_s - plan.settle_s) / 3600.0;
            }
            Scenario::Weld { .. } => {
                score.false_welds.0 += usize::from(outcome.events_from(plan.settle_s) > 0);
                score.false_welds.1 += 1;
            }
        }
    }
    Ok((score, outcomes))
}

/// Accelerated runs of `runs` that develop chatter with the request ignored, and how
/// many accelerated runs there are.
pub fn open_loop_developed(
    plan: &LoopPlan,
    mills: &[Mill],
    runs: &[Run],
) -> anyhow::Result<(usize, usize)> {
    let accelerated: Vec<&Run> = runs
        .iter()
        .filter(|r| matches!(r.scenario, Scenario::Accelerated { .. }))
        .collect();
    let outcomes = parallel(plan.threads, &accelerated, |run| {
        run_loop(plan, &mills[run.mill], run, None, false)
    })?;
    Ok((
        outcomes.iter().filter(|o| o.developed_s.is_some()).count(),
        outcomes.len(),
    ))
}

/// The README's table row of `score` (open loop: `open` developed of `of`).
pub fn table_row(score: &LoopScore, open: (usize, usize)) -> String {
    let shed: Vec<f64> = score.events.iter().map(|e| e.shed_m_s() * 60.0).collect();
    let (s1, s2, s3) = quartiles(&shed);
    let (r1, r2, r3) = quartiles(&score.reduced_s);
    let per_run = score.events.len() as f64 / (score.accelerated - score.developed).max(1) as f64;
    let max_shed = shed.iter().copied().fold(0.0, f64::max);
    format!(
        "| {} | {}/{} | {}/{} | {} ({per_run:.1} per run) | {s2:.0} [{s1:.0}, {s3:.0}], max {max_shed:.0} | {r2:.1} [{r1:.1}, {r3:.1}] | {:.1} ({} in {:.2} h) | {}/{} |",
        score.detector.name(),
        score.developed,
        score.accelerated,
        open.0,
        open.1,
        score.events.len(),
        score.false_stable.0 as f64 / score.false_stable.1.max(1e-9),
        score.false_stable.0,
        score.false_stable.1,
        score.false_welds.0,
        score.false_welds.1,
    )
}

/// The table's header.
pub const TABLE_HEADER: &str = "| detector | developed, closed loop | developed, open loop | slow-downs in runs kept below developed | speed shed per slow-down, m/min: median [IQR] | time below the speed at the request, s: median [IQR] | false slow-downs / h at the top speed | welds with a slow-down |\n|---|---|---|---|---|---|---|---|";

/// The SVG of a traced closed-loop run: speed (m/min, the critical speed dashed as a
/// flat line), the detector's figure over its alarm level, the request, and the
/// chatter amplitude (tension swing over its developed limit; 1 = developed).
pub fn plot(outcome: &Outcome, critical_m_min: f64, title: &str) -> anyhow::Result<String> {
    use millgate_sim::plot::time_series_svg;
    let time_s: Vec<f64> = outcome.trace.iter().map(|r| r.t_s).collect();
    let speed = vec![
        (
            "exit speed".to_owned(),
            outcome.trace.iter().map(|r| Some(r.speed_m_min)).collect(),
        ),
        (
            "critical speed".to_owned(),
            outcome.trace.iter().map(|_| Some(critical_m_min)).collect(),
        ),
    ];
    let level = vec![(
        "gain ratio (1 = alarm)".to_owned(),
        outcome.trace.iter().map(|r| r.level).collect(),
    )];
    let request = vec![(
        "slow-down request seen by the PLC".to_owned(),
        outcome
            .trace
            .iter()
            .map(|r| Some(if r.request { 1.0 } else { 0.0 }))
            .collect(),
    )];
    let swing = vec![(
        "tension swing / developed limit".to_owned(),
        outcome.trace.iter().map(|r| Some(r.swing)).collect(),
    )];
    Ok(time_series_svg(
        title,
        &time_s,
        &[
            ("speed, m/min", speed),
            ("gain ratio", level),
            ("request", request),
            ("chatter amplitude", swing),
        ],
    )?)
}
