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
//! noise 2-4 times louder for 2-5 s; *weld ramp*: an accelerated run whose weld (the
//! same burst) ends 0-3 s before the speed reaches the critical speed. With
//! [`LoopPlan::weld_bit`] the monitor's slow-down request is told of each weld by the
//! PLC's weld bit (set for the burst, as the weld tracking sets it from the weld at the
//! first stand until it has left the last) and holds the request off by the mill's weld
//! hold ([`millgate::analysis::chatter::WeldHold`]). With [`LoopPlan::weld_passes`]
//! the weld passes the stands one after the other (its burst split into one per stand,
//! each a stand's share of the time in the mill, at that stand only), and with
//! [`WeldBits::Stands`] the monitor reads a bit per stand (set while the weld is in
//! that stand: [`millgate::analysis::chatter::SlowDown::weld_at`]) instead of the
//! mill's. Every run draws its mill, a noise factor (force
//! noise and incoming gauge, log-uniform 0.5-2), an eccentricity factor (0.5-2), a
//! deceleration (0.5-2 m/s^2, log-uniform) and a seed.

use millgate::analysis::chatter::WeldHold;
use millgate_config::Config;
use millgate_sim::tandem::control::{SlowDownEvent, SlowDownPolicy};
use millgate_sim::tandem::roots::CriticalSpeed;
use millgate_sim::tandem::simulate::NoiseBurst;
use millgate_sim::tandem::{PassSchedule, TandemMill};

use crate::experiments::chatter_eval::monitor_config_with;

mod mills;
mod run;
mod score;

pub use mills::{mills, runs};
pub use run::run_loop;
pub use score::{
    open_loop_developed, open_loop_weld_ramps, plot, reduced_times, score, table_row,
    weld_bits_row, weld_bits_table, weld_transients, LoopScore, WeldBitsRow, WeldTransient,
    TABLE_HEADER,
};

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
    /// Accelerated runs with a weld ending 0-3 s before the critical speed.
    pub weld_ramps: usize,
    /// The weld bit and the mill's weld hold: `None`, the monitor is not told of welds
    /// (as before the weld bit).
    pub weld_bit: Option<WeldHold>,
    /// Which weld bits the monitor reads (with [`Self::weld_bit`]).
    pub weld_bits: WeldBits,
    /// The weld passes the stands one after the other (a burst per stand); `false`:
    /// it excites every stand at once for its whole time in the mill.
    pub weld_passes: bool,
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
            weld_ramps: 20,
            weld_bit: None,
            weld_bits: WeldBits::Mill,
            weld_passes: false,
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
            weld_ramps: 0,
            settle_s: 12.0,
            threads: 2,
            ..LoopPlan::full()
        }
    }
}

/// The PLC's weld tracking the monitor reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WeldBits {
    /// One bit for the mill: 1 from the weld reaching the first stand until it has
    /// left the last (`context.weld`).
    Mill,
    /// A bit per stand: 1 while the weld is in that stand (`context.weld_stands`).
    Stands,
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

    /// The monitor configuration of `detector` with this mill's thresholds and the
    /// weld hold `weld` (the configuration's default without).
    pub fn config(&self, detector: Detector, weld: Option<WeldHold>) -> anyhow::Result<Config> {
        let hold = weld.map_or(String::new(), |hold| {
            format!(
                "weld_settle_s = {}\nweld_alarm_factor = {}\n",
                hold.settle_s, hold.alarm_factor
            )
        });
        let list = |values: &[f64]| {
            let items: Vec<String> = values.iter().map(|v| format!("{v}")).collect();
            format!("[{}]", items.join(", "))
        };
        match detector {
            Detector::BandGain => monitor_config_with(
                STANDS,
                &format!(
                    "k_max = 0.25\ndetector = \"band_gain\"\ngain_thresholds = {}\n\
                     slow_down_release = {}\n{hold}",
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
    /// As `Accelerated`, with a weld (`burst`) shortly before the critical speed.
    WeldRamp {
        /// Speed at the start, m/s.
        start_m_s: f64,
        /// The operator's setpoint after the settling time, m/s.
        setpoint_m_s: f64,
        /// The operator's acceleration, m/s^2.
        accel_m_s2: f64,
        /// The weld.
        burst: NoiseBurst,
    },
}

impl Scenario {
    /// The weld of the run, if any.
    pub fn weld(&self) -> Option<NoiseBurst> {
        match *self {
            Scenario::Weld { burst } | Scenario::WeldRamp { burst, .. } => Some(burst),
            Scenario::Accelerated { .. } | Scenario::Stable { .. } => None,
        }
    }

    /// The weld's bursts: the whole weld at every stand, or with `passes` one per
    /// stand of [`STANDS`], stand `s` excited for the `s`-th share of its time in the
    /// mill (the weld in that stand).
    pub fn weld_bursts(&self, passes: bool) -> Vec<NoiseBurst> {
        let Some(weld) = self.weld() else {
            return Vec::new();
        };
        if !passes {
            return vec![weld];
        }
        let share_s = weld.duration_s / STANDS as f64;
        (0..STANDS)
            .map(|stand| NoiseBurst {
                time_s: weld.time_s + stand as f64 * share_s,
                duration_s: share_s,
                stand: Some(stand),
                ..weld
            })
            .collect()
    }
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
