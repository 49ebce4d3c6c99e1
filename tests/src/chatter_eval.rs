//! The race of chatter detectors on the physical tandem model (`sim::tandem`): stable
//! runs set each detector's threshold at zero false alarms, held-out stable runs count
//! false alarms per hour, speed ramps through the critical speed measure who warns
//! before chatter has developed, and by how much.
//!
//! **Runs.** Every run draws its mill from a grid of friction and stack-damping factors
//! (`EvalPlan::variations`, each critical speed from the characteristic roots), a
//! noise factor (force noise and incoming gauge, log-uniform 0.5-2), an eccentricity
//! factor (0.5-2) and a seed. The first `settle_s` of every run are not scored: the
//! delay roots near the axis need that long to reach their stationary level.
//! - *stable*: half at a constant speed, half ramping between two speeds, all within
//!   50-95% of the mill's critical speed; half of them with a reel-tension step of
//!   5-20 MPa; one calibration run per mill in the envelope's worst corner (95% of
//!   critical, noise 1.5-2), the held-out runs uniform over the envelope;
//! - *ramp*: from 60-85% of the critical speed (held for `settle_s`), up at 0.2-2
//!   m/s^2 (log-uniform, the last stand's exit speed) until well past developed
//!   chatter.
//!
//! **Detectors**, all on the same 0.5 s windows with 0.25 s hop at 2500 Hz:
//! - *band RMS*: 100-300 Hz RMS per stand ([`millgate_dsp::band_gain`]), one threshold
//!   per stand;
//! - *band gain*: 100-300 Hz RMS over 450-900 Hz RMS per stand, one threshold per stand;
//! - *paper, calibrated*: the gateway's monitor ([`millgate::analysis::chatter::ChatterMonitor`],
//!   its own windows, FFTs and `dsp::chatter`), alarm when `sigma_n <= sigma_min` and
//!   `K_mean` exceeds the largest `K_mean` of such windows in calibration;
//! - *paper, K_max 0.25*: the same with the example configuration's `k_max`, and the
//!   *paper warning* alone (`sigma_n <= sigma_min`): no threshold to set;
//! - *mode damping*: the least damped in-band matrix-pencil pole of each stand's
//!   chatter band ([`millgate_dsp::mode_damping`]), alarm below the smallest damping
//!   ratio seen in calibration.
//!
//! A threshold is the largest value of the detector's figure over every scored window
//! of the calibration runs (alarm strictly above it), so calibration has zero false
//! alarms by construction; the held-out runs tell whether that holds.

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;
use std::time::{Duration, Instant};

use millgate::analysis::chatter::commission::{commission, Commissioning};
use millgate::analysis::chatter::{windows, ChatterMonitor, ChatterUpdate, Recording, Window};
use millgate_config::Config;
use millgate_dsp::band_gain::{BandGain, BandGainSettings};
use millgate_dsp::mode_damping::least_damped;
use millgate_sim::tandem::roots::CriticalSpeed;
use millgate_sim::tandem::simulate::{
    simulate, Accelerometer, Excitation, Record, RunSettings, SpeedRamp, TensionStep,
};
use millgate_sim::tandem::truth::{ground_truth, mill_critical_speed, GroundTruth};
use millgate_sim::tandem::{PassSchedule, TandemMill};
use rand::rngs::SmallRng;
use rand::{Rng, SeedableRng};

/// Output rate of the simulated accelerometers, Hz (the example configuration's).
pub const SAMPLE_RATE_HZ: f64 = 2500.0;
/// Window of every detector, s; the hop is half of it.
pub const WINDOW_S: f64 = 0.5;
/// Chatter band, Hz.
pub const CHATTER_BAND_HZ: (f64, f64) = (100.0, 300.0);
/// Reference band of the band gain, Hz.
pub const REFERENCE_BAND_HZ: (f64, f64) = (450.0, 900.0);
/// The longer window of the band RMS and gain, s (a whole number of hops).
pub const LONG_WINDOW_S: f64 = 2.0;
/// How far beyond the calibration's largest figure the thresholds are set (10%; see
/// [`calibrate`]): with none, the held-out runs of the first evaluation raised false
/// alarms; the confirmation runs check the margin on fresh draws.
pub const MARGIN: f64 = 0.1;
/// `k_max` of the example configuration.
pub const CONFIGURED_K_MAX: f64 = 0.25;
/// Samples per message to the gateway's monitor (a 20th of a second at 2500 Hz; the
/// monitor's hop of 625 samples is 5 of them, so its windows end on message ends).
const BLOCK: usize = 125;
/// Decimation before the matrix pencil (2500 -> 833 Hz).
const PENCIL_DECIMATION: usize = 3;

/// How many runs of each kind, how long, and over which mills.
#[derive(Debug, Clone, PartialEq)]
pub struct EvalPlan {
    /// Stable runs that set the thresholds.
    pub calibration: usize,
    /// Stable runs that count false alarms.
    pub held_out: usize,
    /// Further stable runs that count false alarms (a second, independent draw).
    pub confirmation: usize,
    /// Ramps through the critical speed.
    pub ramps: usize,
    /// Unscored start of every run (and the hold before a ramp), s.
    pub settle_s: f64,
    /// Scored length of a stable run, s.
    pub stable_scored_s: f64,
    /// Friction and damping factors: every pair is a mill.
    pub variations: Vec<f64>,
    /// Slowest and fastest ramp, m/s^2.
    pub accel_m_s2: (f64, f64),
    /// Seed of the plan's draws.
    pub seed: u64,
    /// Worker threads.
    pub threads: usize,
    /// Run the gateway's monitor (the paper's conditions) too.
    pub paper: bool,
}

impl EvalPlan {
    /// The evaluation: 60 calibration, 60 held-out and 60 confirmation stable
    /// runs, 60 ramps, friction and damping +-10% in steps of 5%.
    pub fn full() -> EvalPlan {
        EvalPlan {
            calibration: 60,
            held_out: 60,
            confirmation: 60,
            ramps: 60,
            settle_s: 20.0,
            stable_scored_s: 40.0,
            variations: vec![0.9, 0.95, 1.0, 1.05, 1.1],
            accel_m_s2: (0.2, 2.0),
            seed: 16,
            threads: std::thread::available_parallelism().map_or(2, |n| n.get()),
            paper: true,
        }
    }

    /// A small version for CI: the nominal mill, short runs, fast ramps, no gateway
    /// monitor (its FFTs are slow unoptimised; `chatter_e2e` runs it on the model).
    pub fn quick() -> EvalPlan {
        EvalPlan {
            calibration: 8,
            held_out: 4,
            confirmation: 0,
            ramps: 4,
            settle_s: 12.0,
            stable_scored_s: 16.0,
            variations: vec![1.0],
            accel_m_s2: (1.0, 2.0),
            seed: 61,
            threads: 2,
            paper: false,
        }
    }
}

/// What a run is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RunKind {
    /// Calibration: sets the thresholds.
    Calibration,
    /// Held out: counts false alarms.
    HeldOut,
    /// A second held-out set.
    Confirmation,
    /// A ramp through the critical speed.
    Ramp,
}

/// One run's drawn conditions.
#[derive(Debug, Clone, PartialEq)]
pub struct Scenario {
    /// Its role.
    pub kind: RunKind,
    /// Friction factor of the mill.
    pub friction: f64,
    /// Stack damping factor of the mill.
    pub damping: f64,
    /// The mill's critical speed factor.
    pub critical: CriticalSpeed,
    /// Force-noise and gauge factor.
    pub noise: f64,
    /// Eccentricity factor.
    pub eccentricity: f64,
    /// The simulated run.
    pub settings: RunSettings,
}

/// Every detector's figure in one window.
#[derive(Debug, Clone, PartialEq)]
pub struct Figures {
    /// End of the window, s.
    pub end_s: f64,
    /// Chatter-band RMS per stand over the last 0.5 s, m/s^2.
    pub band_rms: Vec<f64>,
    /// Chatter-band gain per stand over the last 0.5 s.
    pub gain: Vec<f64>,
    /// Chatter-band RMS per stand over the last [`LONG_WINDOW_S`], m/s^2 (empty until
    /// that much is in).
    pub band_rms_long: Vec<f64>,
    /// Chatter-band gain per stand over the last [`LONG_WINDOW_S`].
    pub gain_long: Vec<f64>,
    /// Smallest in-band damping ratio over the stands in the last 0.5 s (infinity
    /// without a pole).
    pub damping: f64,
}

/// The gateway monitor's result in one window.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PaperFigures {
    /// End of the window, s.
    pub end_s: f64,
    /// RMS difference of adjacent principal frequencies, Hz.
    pub sigma_n_hz: f64,
    /// Spectrum step, Hz.
    pub sigma_min_hz: f64,
    /// Mean adjacent correlation.
    pub k_mean: f64,
}

/// A run, its truth and every window's figures.
#[derive(Debug, Clone, PartialEq)]
pub struct RunResult {
    /// The conditions.
    pub scenario: Scenario,
    /// The model's truth.
    pub truth: GroundTruth,
    /// dsp detectors' windows.
    pub windows: Vec<Figures>,
    /// The gateway monitor's windows.
    pub paper: Vec<PaperFigures>,
}

/// Draws the plan's scenarios (critical speeds computed once per mill).
pub fn scenarios(plan: &EvalPlan) -> anyhow::Result<Vec<Scenario>> {
    let base = PassSchedule::example()?;
    let mut mills = Vec::new();
    for &friction in &plan.variations {
        for &damping in &plan.variations {
            mills.push((friction, damping));
        }
    }
    let critical: Vec<CriticalSpeed> = parallel(plan.threads, &mills, |&(f, d)| {
        mill_critical_speed(&TandemMill::new(&base.scaled(f, d))?).map_err(anyhow::Error::from)
    })?;
    let exit_speed = TandemMill::new(&base)?.exit_speed(base.stands.len() - 1, 1.0);
    let mut rng = SmallRng::seed_from_u64(plan.seed);
    let mut out = Vec::new();
    let kinds = std::iter::repeat_n(RunKind::Calibration, plan.calibration)
        .chain(std::iter::repeat_n(RunKind::HeldOut, plan.held_out))
        .chain(std::iter::repeat_n(
            RunKind::Confirmation,
            plan.confirmation,
        ))
        .chain(std::iter::repeat_n(RunKind::Ramp, plan.ramps));
    for (index, kind) in kinds.enumerate() {
        // The first calibration runs, one per mill (at least a third), sit in the
        // envelope's worst corner
        // (95% of critical, noise 1.5-2), where every detector's figure is largest:
        // thresholds are set where they matter. The held-out runs stay uniform.
        let corner = kind == RunKind::Calibration && index < mills.len().max(plan.calibration / 3);
        let mill = if corner {
            index % mills.len()
        } else {
            rng.random_range(0..mills.len())
        };
        let (friction, damping) = mills[mill];
        let critical = critical[mill];
        let noise = if corner {
            rng.random_range(1.5..2.0)
        } else {
            (rng.random_range((0.5f64).ln()..(2.0f64).ln())).exp()
        };
        let speeds = if corner { 0.949..0.95 } else { 0.5..0.95 };
        let eccentricity = rng.random_range(0.5..2.0);
        let mut excitation = Excitation::default();
        excitation.force_noise_density *= noise;
        excitation.entry_gauge_rms_m *= noise;
        excitation.eccentricity_m = excitation.eccentricity_m.map(|e| e * eccentricity);
        let accel = (rng.random_range(plan.accel_m_s2.0.ln()..=plan.accel_m_s2.1.ln())).exp();
        let sc = critical.speed;
        let (ramp, duration_s) = match kind {
            RunKind::Ramp => {
                let start = rng.random_range(0.6..0.85) * sc;
                let ramp = SpeedRamp {
                    start,
                    end: 3.0 * sc,
                    hold_s: plan.settle_s,
                    accel_m_s2: accel,
                };
                let onset = ramp.time_at(sc, exit_speed).unwrap_or(plan.settle_s);
                (ramp, onset + 10.0 + 40.0 * (0.2 / accel).sqrt())
            }
            _ => {
                let duration = plan.settle_s + plan.stable_scored_s;
                let (a, b) = (
                    rng.random_range(speeds.clone()) * sc,
                    rng.random_range(speeds) * sc,
                );
                let ramp = if rng.random_bool(0.5) {
                    SpeedRamp::constant(a)
                } else {
                    SpeedRamp {
                        start: a,
                        end: b,
                        hold_s: rng.random_range(0.0..plan.settle_s + 0.5 * plan.stable_scored_s),
                        accel_m_s2: accel,
                    }
                };
                if rng.random_bool(0.5) {
                    let size =
                        rng.random_range(5.0..20.0) * if rng.random_bool(0.5) { 1.0 } else { -1.0 };
                    let on_entry = rng.random_bool(0.5);
                    excitation.tension_steps.push(TensionStep {
                        time_s: rng.random_range(plan.settle_s..duration - 2.0),
                        entry_mpa: if on_entry { size } else { 0.0 },
                        exit_mpa: if on_entry { 0.0 } else { size },
                    });
                }
                (ramp, duration)
            }
        };
        out.push(Scenario {
            kind,
            friction,
            damping,
            critical,
            noise,
            eccentricity,
            settings: RunSettings {
                ramp,
                excitation,
                sensor: Accelerometer {
                    sample_rate_hz: SAMPLE_RATE_HZ,
                    ..Accelerometer::default()
                },
                duration_s,
                seed: plan.seed.wrapping_mul(1000).wrapping_add(index as u64),
                internal_rate_hz: None,
            },
        });
    }
    Ok(out)
}

/// `f` over `items` on `threads` workers, results in order; the first error wins.
pub fn parallel<T: Sync, R: Send>(
    threads: usize,
    items: &[T],
    f: impl Fn(&T) -> anyhow::Result<R> + Sync,
) -> anyhow::Result<Vec<R>> {
    let next = AtomicUsize::new(0);
    let results: Mutex<Vec<Option<anyhow::Result<R>>>> =
        Mutex::new((0..items.len()).map(|_| None).collect());
    std::thread::scope(|scope| {
        for _ in 0..threads.max(1) {
            scope.spawn(|| loop {
                let index = next.fetch_add(1, Ordering::Relaxed);
                let Some(item) = items.get(index) else {
                    break;
                };
                let result = f(item);
                if let Ok(mut slots) = results.lock() {
                    slots[index] = Some(result);
                }
            });
        }
    });
    results
        .into_inner()
        .map_err(|_| anyhow::anyhow!("a worker panicked"))?
        .into_iter()
        .map(|r| r.unwrap_or_else(|| Err(anyhow::anyhow!("a run was not done"))))
        .collect()
}

/// The gateway configuration the monitor is built from: one mill of `stands` stands,
/// the paper's detector with the example's `k_max`.
pub fn monitor_config(stands: usize) -> anyhow::Result<Config> {
    monitor_config_with(
        stands,
        &format!("k_max = {CONFIGURED_K_MAX}\ndetector = \"paper\"\n"),
    )
}

/// One mill of `stands` stands (channels `s0`, `s1`, ... at [`SAMPLE_RATE_HZ`]) with the
/// race's chatter band and window; `keys` are the rest of its `[[tandem_mills]]` entry
/// (`k_max` at least).
pub fn monitor_config_with(stands: usize, keys: &str) -> anyhow::Result<Config> {
    let mut text = String::from(
        "name = \"chatter eval\"\n[[sources.modbus]]\nname = \"daq\"\naddress = \"127.0.0.1:1\"\npoll_period_ms = 20\n",
    );
    for s in 0..stands {
        text += &format!(
            "[[channels]]\nname = \"s{s}\"\nkind = \"acceleration\"\nunit = \"m/s^2\"\n\
             sample_rate_hz = {SAMPLE_RATE_HZ}\nsource = {{ modbus = \"daq\", table = \"input\", block = {} }}\n",
            s * 122
        );
    }
    let names: Vec<String> = (0..stands).map(|s| format!("\"s{s}\"")).collect();
    text += &format!(
        "[[tandem_mills]]\nname = \"TCM\"\nstands = [{}]\nchatter_band_hz = [{}, {}]\n\
         window_s = {WINDOW_S}\n{keys}",
        names.join(", "),
        CHATTER_BAND_HZ.0,
        CHATTER_BAND_HZ.1
    );
    millgate_config::from_toml_str(&text, "chatter-eval.toml", std::path::Path::new("."))
        .map_err(|e| anyhow::anyhow!("{e}"))
}

/// The scenario's mill and its simulated record.
pub fn simulated(scenario: &Scenario) -> anyhow::Result<(TandemMill, Record)> {
    let base = PassSchedule::example()?.scaled(scenario.friction, scenario.damping);
    let mill = TandemMill::new(&base)?;
    let record = simulate(&mill, &scenario.settings)?;
    Ok((mill, record))
}

/// What `millgate chatter commission` makes of the race's calibration runs, and what
/// the gateway's monitor with its thresholds does in the held-out runs.
#[derive(Debug, Clone, PartialEq)]
pub struct CommissionedRace {
    /// The commissioning (thresholds, release, windows) from the calibration runs'
    /// records after the settling time.
    pub commissioning: Commissioning,
    /// Windows of the held-out and confirmation runs after the settling time in which
    /// the monitor (`detector = "band_gain"`, those thresholds and release) raised its
    /// alarm: (run index, window end s).
    pub alarms: Vec<(usize, f64)>,
    /// Scored hours of those runs.
    pub hours: f64,
}

/// Commission the band gain from the calibration runs of `scenarios` with the
/// command's code (`millgate chatter commission`, margin 10%), then run the gateway's
/// monitor with the result over every held-out and confirmation run.
pub fn commissioned_race(
    plan: &EvalPlan,
    scenarios: &[Scenario],
) -> anyhow::Result<CommissionedRace> {
    let from = (plan.settle_s * SAMPLE_RATE_HZ) as usize;
    let calibration: Vec<&Scenario> = scenarios
        .iter()
        .filter(|s| s.kind == RunKind::Calibration)
        .collect();
    let recordings = parallel(plan.threads, &calibration, |scenario| {
        let (_, record) = simulated(scenario)?;
        Ok(Recording {
            name: format!("calibration seed {}", scenario.settings.seed),
            time_s: (from..record.len())
                .map(|k| k as f64 / SAMPLE_RATE_HZ)
                .collect(),
            stands: record
                .acceleration
                .iter()
                .map(|a| a[from..].to_vec())
                .collect(),
            speed: None,
        })
    })?;
    let stands = recordings.first().map_or(0, |r| r.stands.len());
    let commissioning = commission(
        &monitor_config_with(
            stands,
            &format!("k_max = {CONFIGURED_K_MAX}\ndetector = \"paper\"\n"),
        )?,
        0,
        &recordings,
        MARGIN * 100.0,
    )?;
    let list: Vec<String> = commissioning
        .gain_thresholds
        .iter()
        .map(|t| t.to_string())
        .collect();
    let config = monitor_config_with(
        stands,
        &format!(
            "k_max = {CONFIGURED_K_MAX}\ngain_thresholds = [{}]\nslow_down_release = {}\n",
            list.join(", "),
            commissioning.slow_down_release
        ),
    )?;
    let held_out: Vec<(usize, &Scenario)> = scenarios
        .iter()
        .enumerate()
        .filter(|(_, s)| matches!(s.kind, RunKind::HeldOut | RunKind::Confirmation))
        .collect();
    let alarms = parallel(plan.threads, &held_out, |&(index, scenario)| {
        let (_, record) = simulated(scenario)?;
        let windows = monitored_windows(&config, &record)?;
        Ok(windows
            .into_iter()
            .filter(|w| w.t_s >= plan.settle_s && w.verdict.alarm)
            .map(|w| (index, w.t_s))
            .collect::<Vec<_>>())
    })?;
    Ok(CommissionedRace {
        commissioning,
        alarms: alarms.into_iter().flatten().collect(),
        hours: held_out
            .iter()
            .map(|(_, s)| (s.settings.duration_s - plan.settle_s) / 3600.0)
            .sum(),
    })
}

/// `record` through the gateway's monitor of `config` as `millgate chatter` runs it.
fn monitored_windows(config: &Config, record: &Record) -> anyhow::Result<Vec<Window>> {
    let time_s: Vec<f64> = (0..record.len())
        .map(|k| k as f64 / SAMPLE_RATE_HZ)
        .collect();
    Ok(windows(config, 0, &time_s, &record.acceleration)?)
}

/// Simulates one scenario and runs every detector over it (the gateway's monitor only
/// with `paper`).
pub fn run(scenario: &Scenario, paper: bool) -> anyhow::Result<RunResult> {
    let (mill, record) = simulated(scenario)?;
    let truth = ground_truth(&mill, &scenario.settings.ramp, &record, scenario.critical);
    // Nothing after developed chatter (+ 2 s) is scored.
    let last = truth
        .developed_s
        .map_or(record.len(), |t| ((t + 2.0) * SAMPLE_RATE_HZ) as usize)
        .min(record.len());
    let stands = record.acceleration.len();
    let window = (WINDOW_S * SAMPLE_RATE_HZ).round() as usize;

    let hop = window / 2;
    let detector = |window_hops: usize| {
        BandGain::new(BandGainSettings {
            sample_rate_hz: SAMPLE_RATE_HZ,
            chatter_band_hz: CHATTER_BAND_HZ,
            reference_band_hz: REFERENCE_BAND_HZ,
            hop_samples: hop,
            window_hops,
            stands,
        })
        .map_err(|e| anyhow::anyhow!("{e}"))
    };
    let short = detector(2)?;
    let long = detector((LONG_WINDOW_S * SAMPLE_RATE_HZ / hop as f64).round() as usize)?;
    let (mut short_state, mut long_state) = (short.state(), long.state());
    let mut rings = vec![vec![0.0; window]; stands];
    let mut linear = vec![0.0; window];
    let mut frame = vec![0.0; stands];
    let mut windows = Vec::new();
    for k in 0..last {
        for (slot, signal) in frame.iter_mut().zip(&record.acceleration) {
            *slot = signal[k];
        }
        let done = short
            .process(&mut short_state, &frame)
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        let done_long = long
            .process(&mut long_state, &frame)
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        for (s, ring) in rings.iter_mut().enumerate() {
            ring[k % window] = short.band_sample(&short_state, s);
        }
        if let Some(result) = done {
            let mut damping = f64::INFINITY;
            for ring in &rings {
                for (i, slot) in linear.iter_mut().enumerate() {
                    *slot = ring[(k + 1 + i) % window];
                }
                if let Ok(Some((_, ratio))) =
                    least_damped(&linear, SAMPLE_RATE_HZ, PENCIL_DECIMATION, CHATTER_BAND_HZ)
                {
                    damping = damping.min(ratio);
                }
            }
            let (band_rms_long, gain_long) = done_long
                .map(|w| (w.band_rms.to_vec(), w.gain.to_vec()))
                .unwrap_or_default();
            windows.push(Figures {
                end_s: (k + 1) as f64 / SAMPLE_RATE_HZ,
                band_rms: result.band_rms.to_vec(),
                gain: result.gain.to_vec(),
                band_rms_long,
                gain_long,
                damping,
            });
        }
    }

    let config = monitor_config(stands)?;
    let mut monitor = ChatterMonitor::new(&config, 0)?;
    let t0 = Instant::now();
    let period = Duration::from_secs_f64(BLOCK as f64 / SAMPLE_RATE_HZ);
    let blocks = if paper { last.saturating_sub(BLOCK) } else { 0 };
    let mut paper = Vec::new();
    for (b, start) in (0..blocks).step_by(BLOCK).enumerate() {
        let arrival = t0 + period * b as u32;
        for (s, signal) in record.acceleration.iter().enumerate() {
            if let Some(ChatterUpdate::Evaluated(result)) =
                monitor.samples(s, &signal[start..start + BLOCK], arrival)
            {
                paper.push(PaperFigures {
                    end_s: (start + BLOCK) as f64 / SAMPLE_RATE_HZ,
                    sigma_n_hz: result.sigma_n_hz,
                    sigma_min_hz: result.sigma_min_hz,
                    k_mean: result.k_mean,
                });
            }
        }
    }
    Ok(RunResult {
        scenario: scenario.clone(),
        truth,
        windows,
        paper,
    })
}

/// A detector's figure: what it reads from each window.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Figure {
    /// Chatter-band RMS, one per stand.
    BandRms,
    /// The same over [`LONG_WINDOW_S`].
    BandRmsLong,
    /// Chatter-band gain, one per stand.
    BandGain,
    /// The same over [`LONG_WINDOW_S`].
    BandGainLong,
    /// The paper's two conditions, K_max calibrated: K_mean where sigma_n <= sigma_min.
    PaperCalibrated,
    /// The paper's two conditions with the configured K_max (1 alarm, 0 none).
    PaperConfigured,
    /// The paper's warning alone, frequencies locked (1 alarm, 0 none).
    PaperWarning,
    /// Minus the least damping ratio of an in-band pole over the stands.
    ModeDamping,
}

/// A detector: a figure, and how many consecutive windows it must exceed its
/// threshold (1: the first window alarms; more is an on-delay that rides out
/// transients such as a reel-tension step).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Detector {
    /// What it reads.
    pub figure: Figure,
    /// Consecutive windows over the threshold to alarm, >= 1.
    pub windows: usize,
}

/// Windows of a 1 s on-delay at the 0.25 s hop.
pub const ON_DELAY_WINDOWS: usize = 4;

impl Detector {
    /// Every detector, in table order.
    pub const ALL: [Detector; 10] = [
        Detector {
            figure: Figure::BandRms,
            windows: 1,
        },
        Detector {
            figure: Figure::BandRms,
            windows: ON_DELAY_WINDOWS,
        },
        Detector {
            figure: Figure::BandRmsLong,
            windows: 1,
        },
        Detector {
            figure: Figure::BandGain,
            windows: 1,
        },
        Detector {
            figure: Figure::BandGain,
            windows: ON_DELAY_WINDOWS,
        },
        Detector {
            figure: Figure::BandGainLong,
            windows: 1,
        },
        Detector {
            figure: Figure::PaperCalibrated,
            windows: 1,
        },
        Detector {
            figure: Figure::PaperConfigured,
            windows: 1,
        },
        Detector {
            figure: Figure::PaperWarning,
            windows: 1,
        },
        Detector {
            figure: Figure::ModeDamping,
            windows: 1,
        },
    ];

    /// The band-RMS detector the others are compared with (what mills use).
    pub const RMS: Detector = Detector {
        figure: Figure::BandRms,
        windows: 1,
    };

    /// Its name in the table.
    pub fn name(self) -> String {
        let figure = match self.figure {
            Figure::BandRms => "band RMS (100-300 Hz) per stand, 0.5 s",
            Figure::BandRmsLong => "band RMS (100-300 Hz) per stand, 2 s",
            Figure::BandGain => "band gain (100-300 / 450-900 Hz RMS) per stand, 0.5 s",
            Figure::BandGainLong => "band gain (100-300 / 450-900 Hz RMS) per stand, 2 s",
            Figure::PaperCalibrated => {
                "paper: sigma_n <= sigma_min and K_mean > K_max (calibrated)"
            }
            Figure::PaperConfigured => {
                "paper: sigma_n <= sigma_min and K_mean >= 0.25 (as configured)"
            }
            Figure::PaperWarning => "paper warning: sigma_n <= sigma_min",
            Figure::ModeDamping => "mode damping ratio (matrix pencil) per stand, 0.5 s",
        };
        if self.windows > 1 {
            format!(
                "{figure}, {:.2} s on-delay",
                (self.windows - 1) as f64 * WINDOW_S / 2.0
            )
        } else {
            figure.to_owned()
        }
    }

    /// `(end time, figure per channel)` of every window: higher is more alarming; a
    /// detector without a threshold gives 1 for alarm and 0 for none (threshold 0.5).
    /// With an on-delay, each channel's value is its smallest over the last `windows`.
    fn figures(self, run: &RunResult) -> Vec<(f64, Vec<f64>)> {
        let locked = |p: &PaperFigures| p.sigma_n_hz <= p.sigma_min_hz;
        let raw: Vec<(f64, Vec<f64>)> = match self.figure {
            Figure::BandRms => run
                .windows
                .iter()
                .map(|w| (w.end_s, w.band_rms.clone()))
                .collect(),
            Figure::BandGain => run
                .windows
                .iter()
                .map(|w| (w.end_s, w.gain.clone()))
                .collect(),
            Figure::BandRmsLong => run
                .windows
                .iter()
                .filter(|w| !w.band_rms_long.is_empty())
                .map(|w| (w.end_s, w.band_rms_long.clone()))
                .collect(),
            Figure::BandGainLong => run
                .windows
                .iter()
                .filter(|w| !w.gain_long.is_empty())
                .map(|w| (w.end_s, w.gain_long.clone()))
                .collect(),
            Figure::ModeDamping => run
                .windows
                .iter()
                .map(|w| (w.end_s, vec![-w.damping]))
                .collect(),
            Figure::PaperCalibrated => run
                .paper
                .iter()
                .map(|p| (p.end_s, vec![if locked(p) { p.k_mean } else { -1.0 }]))
                .collect(),
            Figure::PaperConfigured => run
                .paper
                .iter()
                .map(|p| {
                    let alarm = locked(p) && p.k_mean >= CONFIGURED_K_MAX;
                    (p.end_s, vec![if alarm { 1.0 } else { 0.0 }])
                })
                .collect(),
            Figure::PaperWarning => run
                .paper
                .iter()
                .map(|p| (p.end_s, vec![if locked(p) { 1.0 } else { 0.0 }]))
                .collect(),
        };
        (0..raw.len())
            .filter(|&k| k + 1 >= self.windows)
            .map(|k| {
                let held = &raw[k + 1 - self.windows..=k];
                let channels = raw[k].1.len();
                let smallest = (0..channels)
                    .map(|c| held.iter().map(|(_, f)| f[c]).fold(f64::INFINITY, f64::min))
                    .collect();
                (raw[k].0, smallest)
            })
            .collect()
    }

    /// Whether its figure comes from the gateway's monitor.
    pub fn from_monitor(self) -> bool {
        matches!(
            self.figure,
            Figure::PaperCalibrated | Figure::PaperConfigured | Figure::PaperWarning
        )
    }

    /// Whether the threshold is calibrated (false: fixed at 0.5 on a 0/1 figure).
    pub fn calibrated(self) -> bool {
        !matches!(self.figure, Figure::PaperConfigured | Figure::PaperWarning)
    }
}

/// The scored windows of a run: after the settling time.
fn scored(run: &RunResult, settle_s: f64, figures: Vec<(f64, Vec<f64>)>) -> Vec<(f64, Vec<f64>)> {
    let from = match run.scenario.kind {
        RunKind::Ramp => run.scenario.settings.ramp.hold_s,
        _ => settle_s,
    };
    figures.into_iter().filter(|(t, _)| *t >= from).collect()
}

/// Per-channel thresholds: the largest figure of each channel over the calibration
/// runs' scored windows (alarm strictly above), moved by `margin` away from the alarm
/// side: times `1 + margin` for the amplitude figures (RMS, gain), a damping ratio
/// `margin` lower, `margin` of the way from K_max to 1.
pub fn calibrate(detector: Detector, runs: &[RunResult], settle_s: f64, margin: f64) -> Vec<f64> {
    if !detector.calibrated() {
        return vec![0.5];
    }
    let mut thresholds: Vec<f64> = Vec::new();
    for run in runs
        .iter()
        .filter(|r| r.scenario.kind == RunKind::Calibration)
    {
        for (_, figures) in scored(run, settle_s, detector.figures(run)) {
            if thresholds.is_empty() {
                thresholds = vec![f64::NEG_INFINITY; figures.len()];
            }
            for (t, f) in thresholds.iter_mut().zip(&figures) {
                *t = t.max(*f);
            }
        }
    }
    for t in &mut thresholds {
        *t = match detector.figure {
            Figure::ModeDamping => *t * (1.0 - margin),
            Figure::PaperCalibrated => *t + margin * (1.0 - *t),
            _ => *t * (1.0 + margin),
        };
    }
    thresholds
}

/// Times of the scored windows where `detector` alarms.
fn alarms(detector: Detector, run: &RunResult, thresholds: &[f64], settle_s: f64) -> Vec<f64> {
    scored(run, settle_s, detector.figures(run))
        .into_iter()
        .filter(|(_, figures)| figures.iter().zip(thresholds).any(|(f, t)| f > t))
        .map(|(t, _)| t)
        .collect()
}

/// False alarms in one set of stable runs.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct FalseAlarms {
    /// Alarm episodes (a window alarming after one that did not).
    pub episodes: usize,
    /// Scored hours of rolling.
    pub hours: f64,
    /// (index of the run, time s) of each episode's start.
    pub at: Vec<(usize, f64)>,
    /// Largest figure / threshold over the set's windows (amplitude figures only).
    pub peak_ratio: f64,
}

impl FalseAlarms {
    /// Episodes per hour.
    pub fn per_hour(&self) -> f64 {
        self.episodes as f64 / self.hours.max(1e-9)
    }
}

/// One detector's line of the table.
#[derive(Debug, Clone, PartialEq)]
pub struct Score {
    /// The detector.
    pub detector: Detector,
    /// Its thresholds (per stand where it has one per stand).
    pub thresholds: Vec<f64>,
    /// In the held-out runs.
    pub held_out: FalseAlarms,
    /// In the confirmation runs.
    pub confirmation: FalseAlarms,
    /// Ramps that developed chatter.
    pub developed: usize,
    /// Of those, alarmed before developed.
    pub detected: usize,
    /// Developed minus alarm time per detected ramp, s.
    pub lead_s: Vec<f64>,
    /// Alarm minus onset time per detected ramp, s.
    pub after_onset_s: Vec<f64>,
    /// First alarm per ramp (None: none before developed), in ramp order.
    pub first_alarm_s: Vec<Option<f64>>,
}

/// Scores every detector with thresholds `margin` beyond calibration (see
/// [`calibrate`]).
pub fn score(runs: &[RunResult], settle_s: f64, margin: f64) -> Vec<Score> {
    let monitored = runs.iter().any(|r| !r.paper.is_empty());
    Detector::ALL
        .iter()
        .filter(|d| monitored || !d.from_monitor())
        .map(|&detector| {
            let thresholds = calibrate(detector, runs, settle_s, margin);
            let mut score = Score {
                detector,
                thresholds: thresholds.clone(),
                held_out: FalseAlarms::default(),
                confirmation: FalseAlarms::default(),
                developed: 0,
                detected: 0,
                lead_s: Vec::new(),
                after_onset_s: Vec::new(),
                first_alarm_s: Vec::new(),
            };
            let amplitude = matches!(
                detector.figure,
                Figure::BandRms | Figure::BandRmsLong | Figure::BandGain | Figure::BandGainLong
            );
            for (index, run) in runs.iter().enumerate() {
                let times = alarms(detector, run, &thresholds, settle_s);
                let set = match run.scenario.kind {
                    RunKind::Calibration => continue,
                    RunKind::HeldOut => &mut score.held_out,
                    RunKind::Confirmation => &mut score.confirmation,
                    RunKind::Ramp => {
                        let Some(developed) = run.truth.developed_s else {
                            score.first_alarm_s.push(None);
                            continue;
                        };
                        score.developed += 1;
                        let first = times.first().copied().filter(|t| *t <= developed);
                        score.first_alarm_s.push(first);
                        if let Some(alarm) = first {
                            score.detected += 1;
                            score.lead_s.push(developed - alarm);
                            if let Some(onset) = run.truth.onset_s {
                                score.after_onset_s.push(alarm - onset);
                            }
                        }
                        continue;
                    }
                };
                let hop = WINDOW_S / 2.0;
                set.at.extend(
                    times
                        .iter()
                        .enumerate()
                        .filter(|(i, t)| *i == 0 || **t - times[i - 1] > 1.5 * hop)
                        .map(|(_, t)| (index, *t)),
                );
                set.episodes = set.at.len();
                set.hours += (run.scenario.settings.duration_s - settle_s) / 3600.0;
                if amplitude {
                    for (_, figures) in scored(run, settle_s, detector.figures(run)) {
                        for (f, t) in figures.iter().zip(&thresholds) {
                            set.peak_ratio = set.peak_ratio.max(f / t);
                        }
                    }
                }
            }
            score
        })
        .collect()
}

/// One detector's first alarms against another's, ramp by ramp.
#[derive(Debug, Clone, PartialEq)]
pub struct Versus {
    /// Ramps where it alarmed first (or only it did).
    pub earlier: usize,
    /// Same window, or neither alarmed.
    pub same: usize,
    /// Ramps where the other alarmed first (or only the other did).
    pub later: usize,
    /// The other's alarm minus its own, s, where both alarmed.
    pub gained_s: Vec<f64>,
}

impl Versus {
    /// A Markdown row: name, earlier, same, later, median gain.
    pub fn row(&self, name: &str) -> String {
        let (_, median, _) = quartiles(&self.gained_s);
        format!(
            "| {name} | {} | {} | {} | {median:+.2} |",
            self.earlier, self.same, self.later
        )
    }
}

/// `a`'s first alarms against `b`'s, ramp by ramp.
pub fn versus(a: &Score, b: &Score) -> Versus {
    let mut result = Versus {
        earlier: 0,
        same: 0,
        later: 0,
        gained_s: Vec::new(),
    };
    for (a, b) in a.first_alarm_s.iter().zip(&b.first_alarm_s) {
        match (a, b) {
            (Some(a), Some(b)) => {
                result.gained_s.push(b - a);
                if (a - b).abs() < 1e-9 {
                    result.same += 1;
                } else if a < b {
                    result.earlier += 1;
                } else {
                    result.later += 1;
                }
            }
            (Some(_), None) => result.earlier += 1,
            (None, Some(_)) => result.later += 1,
            (None, None) => result.same += 1,
        }
    }
    result
}

/// Median and quartiles (linear interpolation); NaN for no values.
pub fn quartiles(values: &[f64]) -> (f64, f64, f64) {
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    let at = |q: f64| {
        if v.is_empty() {
            return f64::NAN;
        }
        let x = q * (v.len() - 1) as f64;
        let (i, frac) = (x.floor() as usize, x - x.floor());
        v[i] + frac * (v[(i + 1).min(v.len() - 1)] - v[i])
    };
    (at(0.25), at(0.5), at(0.75))
}

/// The table (Markdown) and the comparison of each detector against band RMS.
pub fn table(scores: &[Score]) -> String {
    use std::fmt::Write as _;
    let mut out = String::from(
        "| detector | false alarms / h: held-out, confirmation (largest figure / threshold) | detected before developed | lead before developed, s: median [IQR] | alarm - onset, s: median [IQR] |\n|---|---|---|---|---|\n",
    );
    let ratio = |f: &FalseAlarms| {
        if f.peak_ratio > 0.0 {
            format!(" ({:.2})", f.peak_ratio)
        } else {
            String::new()
        }
    };
    for s in scores {
        let (l1, l2, l3) = quartiles(&s.lead_s);
        let (o1, o2, o3) = quartiles(&s.after_onset_s);
        let _ = writeln!(
            out,
            "| {} | {:.1}{}, {:.1}{} | {}/{} | {l2:.2} [{l1:.2}, {l3:.2}] | {o2:+.2} [{o1:+.2}, {o3:+.2}] |",
            s.detector.name(),
            s.held_out.per_hour(),
            ratio(&s.held_out),
            s.confirmation.per_hour(),
            ratio(&s.confirmation),
            s.detected,
            s.developed,
        );
    }
    if let Some(rms) = scores.iter().find(|s| s.detector == Detector::RMS) {
        let _ = writeln!(
            out,
            "\nAgainst band RMS (0.5 s), ramp by ramp (earlier: alarm before RMS's; a miss counts as never):\n"
        );
        let _ = writeln!(
            out,
            "| detector | earlier | same window | later | median lead gained, s |\n|---|---|---|---|---|"
        );
        for s in scores.iter().filter(|s| s.detector != Detector::RMS) {
            let _ = writeln!(out, "{}", versus(s, rms).row(&s.detector.name()));
        }
    }
    out
}
