//! Time simulation of the linearised tandem mill: a speed ramp, excitation (force
//! noise, roll eccentricity, incoming gauge, reel-tension steps), the transport delays
//! and an accelerometer on every backup-roll chock.
//!
//! **Integrator.** Classical RK4 at an internal rate (a multiple of the output rate) of
//! at least 10 kHz and `|mu|_max / 0.8`, `mu` the eigenvalues of the undelayed system at
//! the run's top speed (RK4 is stable to 2.8; at 0.8 the 1 kHz work-roll modes lose
//! about 5% of their own damping to the method's, the 100-300 Hz band nothing
//! measurable), the speed factor evaluated at each stage. The delayed entry gauges are
//! read from a ring of every stand's exit-gauge deviation (`2 y_w + e`) kept at the
//! internal steps, by 4-point Lagrange interpolation at `t - L / v_out(t)` (the delay
//! follows the speed; over one delay the speed changes by less than 3% on the fastest
//! ramps, so the strip's true travel time differs from it by a fraction of that).
//! Before `t = 0` the mill was in its schedule's steady state (all deviations 0).
//!
//! **Excitation.** Force noise on each work roll: white, constant over an internal
//! step, with one-sided density `force_noise_density` (N/sqrt(Hz)). Eccentricity: the
//! gap of stand i varies by `e1 sin(phi_i + p1) + e2 sin(2 phi_i + p2)` with `phi_i`
//! the work roll's angle (speed / radius) and random phases. Incoming gauge: a
//! first-order low-pass of white noise (RMS and bandwidth). Tension steps: the payoff
//! and coiler tensions (stand 1's back and the last stand's front) jump by given
//! amounts at given times. Noise bursts: the force noise louder by a factor for a
//! while (a weld passing the stands), the mill's stability unchanged.
//!
//! **Stepping.** [`Simulation`] holds the whole state (rolls, tensions, the ring of
//! exit gauges, the roll angles, the anti-alias filters, the random sources) and
//! [`Simulation::advance`] appends the next samples with the speed the caller gives
//! for them, so a controller can change the speed while the mill runs; [`simulate`]
//! is one `advance` over a [`SpeedRamp`]. Advanced in pieces, a run is the same run
//! (`sim/tests/tandem.rs` compares them sample by sample). The speed must stay within
//! the [`SpeedRange`] the simulation was built for: the internal step is chosen for its
//! top, the ring of exit gauges sized for its bottom.
//!
//! **Accelerometer.** The backup roll's acceleration (the chock moves with it in the
//! lumped stack), optionally through a 4th-order Butterworth anti-alias low-pass at
//! 0.4x the output rate run at the internal rate, sampled at the output rate, plus
//! white sensor noise. All randomness is seeded (`SmallRng`: xoshiro, cheap enough not
//! to matter beside the integrator even in unoptimised builds).

use std::f64::consts::TAU;

use millgate_dsp::filter::{BiquadState, Cascade};
use rand::rngs::SmallRng;
use rand::{Rng, SeedableRng};
use rand_distr::StandardNormal;

use super::linear::{Inputs, TandemMill, MAX_STANDS};
use super::roots::Characteristic;

/// Lowest internal integration rate, Hz.
pub const MIN_INTERNAL_RATE_HZ: f64 = 10_000.0;
/// Longest run, s.
pub const MAX_DURATION_S: f64 = 3600.0;

/// Speed factor over time: `start` for `hold_s`, then a ramp of the last stand's exit
/// speed at `accel_m_s2` until `end` (every stand's speed scales with it).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SpeedRamp {
    /// Speed factor at the start (times the schedule's roll speeds), > 0.
    pub start: f64,
    /// Speed factor the ramp ends at, > 0 (below `start` for a slow-down).
    pub end: f64,
    /// Time at `start` before the ramp, s, >= 0.
    pub hold_s: f64,
    /// Acceleration of the last stand's exit strip speed, m/s^2, >= 0.
    pub accel_m_s2: f64,
}

impl SpeedRamp {
    /// A constant speed factor.
    pub fn constant(speed: f64) -> SpeedRamp {
        SpeedRamp {
            start: speed,
            end: speed,
            hold_s: 0.0,
            accel_m_s2: 0.0,
        }
    }

    /// Speed factor at `t_s` for a mill whose last stand leaves at `exit_speed` m/s at
    /// speed factor 1.
    pub fn speed_at(&self, t_s: f64, exit_speed: f64) -> f64 {
        if t_s <= self.hold_s || self.accel_m_s2 == 0.0 {
            return self.start;
        }
        let change = self.accel_m_s2 / exit_speed * (t_s - self.hold_s);
        if self.end >= self.start {
            (self.start + change).min(self.end)
        } else {
            (self.start - change).max(self.end)
        }
    }

    /// When the ramp passes speed factor `speed`, s (None if it never does).
    pub fn time_at(&self, speed: f64, exit_speed: f64) -> Option<f64> {
        let (low, high) = (self.start.min(self.end), self.start.max(self.end));
        if self.accel_m_s2 <= 0.0 || !(low..=high).contains(&speed) {
            return (speed == self.start).then_some(0.0);
        }
        Some(self.hold_s + (speed - self.start).abs() * exit_speed / self.accel_m_s2)
    }

    fn lowest(&self) -> f64 {
        self.start.min(self.end)
    }

    fn highest(&self) -> f64 {
        self.start.max(self.end)
    }
}

/// A step of the reel tensions at one time.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TensionStep {
    /// When, s.
    pub time_s: f64,
    /// Change of the payoff (first stand's back) tension stress, MPa.
    pub entry_mpa: f64,
    /// Change of the coiler (last stand's front) tension stress, MPa.
    pub exit_mpa: f64,
}

/// What drives the mill besides its own dynamics.
#[derive(Debug, Clone, PartialEq)]
pub struct Excitation {
    /// One-sided density of the white force noise on each work roll, N/sqrt(Hz), >= 0.
    pub force_noise_density: f64,
    /// Roll-gap eccentricity amplitude at 1x and 2x the work roll's rotation, m, >= 0.
    pub eccentricity_m: [f64; 2],
    /// RMS of the incoming strip's thickness deviation, m, >= 0.
    pub entry_gauge_rms_m: f64,
    /// Bandwidth (first-order low-pass) of the incoming thickness deviation, Hz, > 0.
    pub entry_gauge_bandwidth_hz: f64,
    /// Reel-tension steps, any order.
    pub tension_steps: Vec<TensionStep>,
    /// Louder force noise for a while (a weld passing the stands), any order.
    pub noise_bursts: Vec<NoiseBurst>,
}

/// The force noise on every work roll `factor` times louder from `time_s` for
/// `duration_s`: an excitation step that leaves the mill's stability as it is (a weld
/// or a rougher strip section passing the stands, all stands at once).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NoiseBurst {
    /// Start, s, >= 0.
    pub time_s: f64,
    /// Length, s, > 0.
    pub duration_s: f64,
    /// Factor on the force-noise density, >= 1.
    pub factor: f64,
}

impl Excitation {
    /// The factor on the force noise at `t_s`: the largest of the bursts then, else 1.
    pub fn force_noise_factor(&self, t_s: f64) -> f64 {
        self.noise_bursts
            .iter()
            .filter(|b| t_s >= b.time_s && t_s < b.time_s + b.duration_s)
            .fold(1.0, |factor, b| factor.max(b.factor))
    }
}

impl Default for Excitation {
    /// Levels of a well-running mill: see `sim/README.md`.
    fn default() -> Self {
        Excitation {
            force_noise_density: 600.0,
            eccentricity_m: [4.0e-6, 1.5e-6],
            entry_gauge_rms_m: 4.0e-6,
            entry_gauge_bandwidth_hz: 2.0,
            tension_steps: Vec::new(),
            noise_bursts: Vec::new(),
        }
    }
}

/// The chock accelerometers and their acquisition.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Accelerometer {
    /// Output sample rate, Hz, in 500..=20000.
    pub sample_rate_hz: f64,
    /// RMS of white sensor noise, m/s^2, >= 0.
    pub noise_rms: f64,
    /// 4th-order Butterworth anti-alias low-pass at 0.4x the sample rate.
    pub anti_alias: bool,
}

impl Default for Accelerometer {
    fn default() -> Self {
        Accelerometer {
            sample_rate_hz: 2500.0,
            noise_rms: 0.02,
            anti_alias: true,
        }
    }
}

/// One simulated run.
#[derive(Debug, Clone, PartialEq)]
pub struct RunSettings {
    /// Speed over time.
    pub ramp: SpeedRamp,
    /// Excitation.
    pub excitation: Excitation,
    /// Measurement.
    pub sensor: Accelerometer,
    /// Length, s, > 0 and at most [`MAX_DURATION_S`].
    pub duration_s: f64,
    /// Seed of every random source.
    pub seed: u64,
    /// Internal integration rate, Hz; `None` chooses it (see the module docs).
    pub internal_rate_hz: Option<f64>,
}

/// Why a run could not be simulated; names the setting at fault.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RunError {
    /// A setting is outside its range.
    #[error("{key}: {value} is not allowed (must be {allowed})")]
    Setting {
        /// The setting, e.g. `ramp.start`.
        key: &'static str,
        /// Its value.
        value: f64,
        /// The allowed range with its unit.
        allowed: &'static str,
    },
    /// The system's eigenvalues could not be computed (to choose the step).
    #[error("the linearised mill's eigenvalues could not be computed at speed factor {speed}")]
    Eigenvalues {
        /// The speed factor.
        speed: f64,
    },
    /// A speed given to [`Simulation::advance`] left the setup's [`SpeedRange`].
    #[error(
        "speed factor {speed} at t = {time_s:.3} s is outside the simulation's speed range \
         {lowest} ..= {highest}"
    )]
    Speed {
        /// When, s.
        time_s: f64,
        /// The speed factor asked for.
        speed: f64,
        /// Lowest speed factor of the setup.
        lowest: f64,
        /// Highest speed factor of the setup.
        highest: f64,
    },
    /// The state left the finite numbers (a far unstable run).
    #[error(
        "the simulation diverged at t = {time_s:.3} s (the mill is far beyond its critical speed)"
    )]
    Diverged {
        /// When, s.
        time_s: f64,
    },
}

/// A simulated record.
#[derive(Debug, Clone, PartialEq)]
pub struct Record {
    /// Output sample rate, Hz; sample k is at `k / sample_rate_hz` s.
    pub sample_rate_hz: f64,
    /// Chock acceleration per stand, m/s^2 (sensor noise included).
    pub acceleration: Vec<Vec<f64>>,
    /// Speed factor per sample.
    pub speed: Vec<f64>,
    /// Interstand tension deviation per interstand, Pa (noise-free truth).
    pub tension_pa: Vec<Vec<f64>>,
}

impl Record {
    /// Number of samples.
    pub fn len(&self) -> usize {
        self.speed.len()
    }

    /// True when the record holds no sample.
    pub fn is_empty(&self) -> bool {
        self.speed.is_empty()
    }

    /// CSV: `t` (s), then `s1_vib .. sN_vib` (chock acceleration, m/s^2; the channel
    /// names of `config/examples/tandem-5stand.toml`); with `truth` also
    /// `speed_factor` and the interstand tension deviations `tension_1_2_mpa` ...
    pub fn to_csv(&self, truth: bool) -> String {
        use std::fmt::Write as _;
        let stands = self.acceleration.len();
        let mut header: Vec<String> = std::iter::once("t".to_owned())
            .chain((1..=stands).map(|s| format!("s{s}_vib")))
            .collect();
        if truth {
            header.push("speed_factor".to_owned());
            header.extend((1..stands).map(|j| format!("tension_{j}_{}_mpa", j + 1)));
        }
        let mut csv = header.join(",");
        csv.push('\n');
        for k in 0..self.len() {
            let _ = write!(csv, "{}", k as f64 / self.sample_rate_hz);
            for stand in &self.acceleration {
                let _ = write!(csv, ",{:.6}", stand[k]);
            }
            if truth {
                let _ = write!(csv, ",{:.6}", self.speed[k]);
                for tension in &self.tension_pa {
                    let _ = write!(csv, ",{:.6}", tension[k] * 1e-6);
                }
            }
            csv.push('\n');
        }
        csv
    }
}

fn check(key: &'static str, value: f64, ok: bool, allowed: &'static str) -> Result<(), RunError> {
    if ok && value.is_finite() {
        Ok(())
    } else {
        Err(RunError::Setting {
            key,
            value,
            allowed,
        })
    }
}

impl RunSettings {
    /// Checks every setting against its range.
    pub fn validate(&self) -> Result<(), RunError> {
        let r = &self.ramp;
        check("ramp.start", r.start, r.start > 0.0, "> 0")?;
        check("ramp.end", r.end, r.end > 0.0, "> 0")?;
        check("ramp.hold_s", r.hold_s, r.hold_s >= 0.0, ">= 0 s")?;
        check(
            "ramp.accel_m_s2",
            r.accel_m_s2,
            r.accel_m_s2 >= 0.0,
            ">= 0 m/s^2",
        )?;
        self.setup().validate()?;
        check(
            "duration_s",
            self.duration_s,
            self.duration_s > 0.0 && self.duration_s <= MAX_DURATION_S,
            "> 0 and <= 3600 s",
        )?;
        Ok(())
    }

    /// The setup of this run: its speed range is the ramp's.
    pub fn setup(&self) -> SimulationSetup {
        SimulationSetup {
            excitation: self.excitation.clone(),
            sensor: self.sensor,
            seed: self.seed,
            internal_rate_hz: self.internal_rate_hz,
            speeds: SpeedRange {
                lowest: self.ramp.lowest(),
                highest: self.ramp.highest(),
            },
        }
    }
}

/// Checks the excitation's settings against their ranges.
fn validate_excitation(e: &Excitation) -> Result<(), RunError> {
    check(
        "excitation.force_noise_density",
        e.force_noise_density,
        e.force_noise_density >= 0.0,
        ">= 0 N/sqrt(Hz)",
    )?;
    for value in e.eccentricity_m {
        check("excitation.eccentricity_m", value, value >= 0.0, ">= 0 m")?;
    }
    check(
        "excitation.entry_gauge_rms_m",
        e.entry_gauge_rms_m,
        e.entry_gauge_rms_m >= 0.0,
        ">= 0 m",
    )?;
    check(
        "excitation.entry_gauge_bandwidth_hz",
        e.entry_gauge_bandwidth_hz,
        e.entry_gauge_bandwidth_hz > 0.0,
        "> 0 Hz",
    )?;
    for step in &e.tension_steps {
        check(
            "tension_steps.time_s",
            step.time_s,
            step.time_s >= 0.0,
            ">= 0 s",
        )?;
        check("tension_steps.entry_mpa", step.entry_mpa, true, "finite")?;
        check("tension_steps.exit_mpa", step.exit_mpa, true, "finite")?;
    }
    for burst in &e.noise_bursts {
        check(
            "noise_bursts.time_s",
            burst.time_s,
            burst.time_s >= 0.0,
            ">= 0 s",
        )?;
        check(
            "noise_bursts.duration_s",
            burst.duration_s,
            burst.duration_s > 0.0,
            "> 0 s",
        )?;
        check(
            "noise_bursts.factor",
            burst.factor,
            burst.factor >= 1.0,
            ">= 1",
        )?;
    }
    Ok(())
}

/// The ring of exit-gauge deviations, one row of `stands` values per internal step;
/// a power-of-two number of rows, so the ring index is a mask.
struct GaugeHistory {
    values: Vec<f64>,
    mask: usize,
    stands: usize,
    /// Steps stored so far (the newest is step `stored - 1`).
    stored: usize,
}

impl GaugeHistory {
    fn new(steps: usize, stands: usize) -> GaugeHistory {
        let rows = steps.next_power_of_two();
        GaugeHistory {
            values: vec![0.0; rows * stands],
            mask: rows - 1,
            stands,
            stored: 0,
        }
    }

    fn push(&mut self, row: &[f64]) {
        let at = (self.stored & self.mask) * self.stands;
        self.values[at..at + self.stands].copy_from_slice(&row[..self.stands]);
        self.stored += 1;
    }

    /// Stand `stand`'s deviation at step position `position` (fractional), by 4-point
    /// Lagrange interpolation; 0 before the first step. The caller keeps `position`
    /// at least two steps behind the newest.
    fn at(&self, stand: usize, position: f64) -> f64 {
        if position < 0.0 {
            return 0.0;
        }
        let base = position as usize;
        let frac = position - base as f64;
        let value = |step: usize| self.values[(step & self.mask) * self.stands + stand];
        let p0 = if base == 0 { 0.0 } else { value(base - 1) };
        let (p1, p2, p3) = (value(base), value(base + 1), value(base + 2));
        let (u, v, w, x) = (frac + 1.0, frac, frac - 1.0, frac - 2.0);
        -p0 * v * w * x / 6.0 + p1 * u * w * x / 2.0 - p2 * u * v * x / 2.0 + p3 * u * v * w / 6.0
    }
}

/// A work roll's angle as (cos, sin), advanced by small rotations (no sine call per
/// step) and renormalised, with the 1x and 2x eccentricity read from it.
#[derive(Clone, Copy)]
struct RollAngle {
    cos: f64,
    sin: f64,
    /// (cos, sin) of the random phases of the 1x and 2x components.
    phases: [(f64, f64); 2],
}

impl RollAngle {
    /// Turn by `delta` rad (|delta| << 1: Taylor to 4th order).
    fn turn(&mut self, delta: f64) {
        let d2 = delta * delta;
        let (c, s) = (1.0 - d2 / 2.0 + d2 * d2 / 24.0, delta * (1.0 - d2 / 6.0));
        let (cos, sin) = (self.cos * c - self.sin * s, self.sin * c + self.cos * s);
        let norm = 1.0 / (cos * cos + sin * sin).sqrt();
        self.cos = cos * norm;
        self.sin = sin * norm;
    }

    /// `e1 sin(phi + p1) + e2 sin(2 phi + p2)`.
    fn eccentricity(&self, amplitudes: [f64; 2]) -> f64 {
        let (c2, s2) = (
            self.cos * self.cos - self.sin * self.sin,
            2.0 * self.sin * self.cos,
        );
        let [(pc1, ps1), (pc2, ps2)] = self.phases;
        amplitudes[0] * (self.sin * pc1 + self.cos * ps1) + amplitudes[1] * (s2 * pc2 + c2 * ps2)
    }
}

/// A run's speeds: the range every speed factor it is driven at stays within. The
/// internal step is chosen for the highest (the fastest dynamics), the ring of exit
/// gauges sized for the lowest (the longest transport delay).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SpeedRange {
    /// Lowest speed factor, > 0.
    pub lowest: f64,
    /// Highest speed factor, >= `lowest`.
    pub highest: f64,
}

/// What a simulation is built with, whatever drives its speed: a [`SpeedRamp`]
/// ([`simulate`]) or a controller acting while it runs ([`Simulation::advance`]).
#[derive(Debug, Clone, PartialEq)]
pub struct SimulationSetup {
    /// Excitation.
    pub excitation: Excitation,
    /// Measurement.
    pub sensor: Accelerometer,
    /// Seed of every random source.
    pub seed: u64,
    /// Internal integration rate, Hz; `None` chooses it (see the module docs).
    pub internal_rate_hz: Option<f64>,
    /// The speeds the run stays within.
    pub speeds: SpeedRange,
}

impl SimulationSetup {
    /// Checks every setting against its range.
    pub fn validate(&self) -> Result<(), RunError> {
        let speeds = &self.speeds;
        check("speeds.lowest", speeds.lowest, speeds.lowest > 0.0, "> 0")?;
        check(
            "speeds.highest",
            speeds.highest,
            speeds.highest >= speeds.lowest,
            ">= speeds.lowest",
        )?;
        validate_excitation(&self.excitation)?;
        let s = &self.sensor;
        check(
            "sensor.sample_rate_hz",
            s.sample_rate_hz,
            (500.0..=20_000.0).contains(&s.sample_rate_hz),
            "500 ..= 20000 Hz",
        )?;
        check(
            "sensor.noise_rms",
            s.noise_rms,
            s.noise_rms >= 0.0,
            ">= 0 m/s^2",
        )?;
        if let Some(rate) = self.internal_rate_hz {
            check(
                "internal_rate_hz",
                rate,
                (1000.0..=1.0e6).contains(&rate),
                "1000 ..= 1e6 Hz",
            )?;
        }
        Ok(())
    }
}

/// A tandem mill simulated step by step: [`Simulation::advance`] appends the next
/// samples to a record, its speed given by the caller for those samples, the state
/// (rolls, tensions, delayed gauges, filters, random sources) carried over. A run
/// advanced in pieces equals the run advanced at once with the same speeds.
pub struct Simulation {
    mill: TandemMill,
    excitation: Excitation,
    sensor: Accelerometer,
    speeds: SpeedRange,
    substeps: usize,
    /// Internal step, s.
    h: f64,
    /// Internal steps done.
    step: usize,
    history: GaugeHistory,
    rng: SmallRng,
    angles: Vec<RollAngle>,
    force_sigma: f64,
    gauge_decay: f64,
    gauge_kick: f64,
    gauge: f64,
    /// The reel-tension steps in time order.
    tension_steps: Vec<TensionStep>,
    anti_alias: Cascade<2>,
    filter_state: Vec<[BiquadState; 2]>,
    x: Vec<f64>,
    stage: Vec<f64>,
    k: [Vec<f64>; 4],
    gap_now: [f64; MAX_STANDS],
    /// The last step's end inputs, reused as the next step's start.
    carried: Option<(f64, Inputs)>,
}

// By hand: the state vectors and filters are not worth printing.
impl std::fmt::Debug for Simulation {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Simulation")
            .field("stands", &self.mill.stands().len())
            .field("time_s", &self.time_s())
            .field("substeps", &self.substeps)
            .finish_non_exhaustive()
    }
}

impl Simulation {
    /// `mill` in its schedule's steady state at t = 0 (all deviations 0), to be run
    /// under `setup`.
    pub fn new(mill: &TandemMill, setup: &SimulationSetup) -> Result<Simulation, RunError> {
        setup.validate()?;
        let n = mill.stands().len();
        let len = mill.state_len();
        let fs = setup.sensor.sample_rate_hz;

        // Internal rate: >= 10 kHz and h |mu|_max <= 0.8 (RK4 is stable to 2.8).
        let spectral = spectral_radius(mill, setup.speeds.highest)?;
        let wanted = setup
            .internal_rate_hz
            .unwrap_or(MIN_INTERNAL_RATE_HZ.max(spectral / 0.8));
        let substeps = (wanted / fs).ceil().max(1.0) as usize;
        let h = 1.0 / (fs * substeps as f64);

        let tau_max = mill.delay_s(0, setup.speeds.lowest);
        let history = GaugeHistory::new((tau_max / h).ceil() as usize + 8, n);

        let mut rng = SmallRng::seed_from_u64(setup.seed);
        let excitation = setup.excitation.clone();
        let angles: Vec<RollAngle> = (0..n)
            .map(|_| {
                let [p1, p2] = [rng.random::<f64>() * TAU, rng.random::<f64>() * TAU];
                RollAngle {
                    cos: 1.0,
                    sin: 0.0,
                    phases: [(p1.cos(), p1.sin()), (p2.cos(), p2.sin())],
                }
            })
            .collect();
        let force_sigma = excitation.force_noise_density * (0.5 / h).sqrt();
        let gauge_decay = (-TAU * excitation.entry_gauge_bandwidth_hz * h).exp();
        let gauge_kick = excitation.entry_gauge_rms_m * (1.0 - gauge_decay * gauge_decay).sqrt();
        let gauge = excitation.entry_gauge_rms_m * rng.sample::<f64, _>(StandardNormal);
        let mut tension_steps = excitation.tension_steps.clone();
        tension_steps.sort_by(|a, b| a.time_s.total_cmp(&b.time_s));

        let anti_alias = Cascade::<2>::butterworth_lowpass(0.4 * fs, fs * substeps as f64)
            .map_err(|_| RunError::Setting {
                key: "sensor.sample_rate_hz",
                value: fs,
                allowed: "500 ..= 20000 Hz",
            })?;
        let mut gap_now = [0.0; MAX_STANDS];
        for (slot, angle) in gap_now.iter_mut().zip(&angles) {
            *slot = angle.eccentricity(excitation.eccentricity_m);
        }
        Ok(Simulation {
            mill: mill.clone(),
            excitation,
            sensor: setup.sensor,
            speeds: setup.speeds,
            substeps,
            h,
            step: 0,
            history,
            rng,
            angles,
            force_sigma,
            gauge_decay,
            gauge_kick,
            gauge,
            tension_steps,
            anti_alias,
            filter_state: vec![[BiquadState::default(); 2]; n],
            x: vec![0.0; len],
            stage: vec![0.0; len],
            k: [
                vec![0.0; len],
                vec![0.0; len],
                vec![0.0; len],
                vec![0.0; len],
            ],
            gap_now,
            carried: None,
        })
    }

    /// The simulated mill.
    pub fn mill(&self) -> &TandemMill {
        &self.mill
    }

    /// Time of the next sample, s.
    pub fn time_s(&self) -> f64 {
        self.samples() as f64 / self.sensor.sample_rate_hz
    }

    /// Samples produced so far (per stand).
    pub fn samples(&self) -> usize {
        self.step.div_ceil(self.substeps)
    }

    /// An empty record for this simulation's output, with room for `samples`.
    pub fn record(&self, samples: usize) -> Record {
        let n = self.mill.stands().len();
        Record {
            sample_rate_hz: self.sensor.sample_rate_hz,
            acceleration: vec![Vec::with_capacity(samples); n],
            speed: Vec::with_capacity(samples),
            tension_pa: vec![Vec::with_capacity(samples); n - 1],
        }
    }

    /// Simulate the next `samples` output samples, appending them to `record`;
    /// `speed(t)` is the speed factor at time `t` (s since the run's start) over
    /// them, within the setup's [`SpeedRange`].
    pub fn advance(
        &mut self,
        samples: usize,
        speed: impl Fn(f64) -> f64,
        record: &mut Record,
    ) -> Result<(), RunError> {
        // Disjoint borrows of the state for the hot loop.
        let Simulation {
            mill,
            excitation,
            sensor,
            speeds,
            substeps,
            h,
            step: done,
            history,
            rng,
            angles,
            force_sigma,
            gauge_decay,
            gauge_kick,
            gauge: gauge_state,
            tension_steps,
            anti_alias,
            filter_state,
            x,
            stage,
            k,
            gap_now: gap_state,
            carried,
        } = self;
        let (substeps, h) = (*substeps, *h);
        let n = mill.stands().len();
        let radius = mill.roll_radius_m();
        let amplitudes = excitation.eccentricity_m;
        let (lowest, highest) = (speeds.lowest, speeds.highest);
        let mut row = [0.0; MAX_STANDS];
        let mut gap_now = *gap_state;
        let mut gauge = *gauge_state;
        let first = *done;
        let mut next = first;
        let mut failed = None;
        for step in first..first + samples * substeps {
            let t = step as f64 * h;
            // Excitation over this step: noise held, eccentricity and gauge interpolated.
            let sigma = *force_sigma * excitation.force_noise_factor(t);
            let mut force = [0.0; MAX_STANDS];
            for value in force.iter_mut().take(n) {
                *value = sigma * rng.sample::<f64, _>(StandardNormal);
            }
            let speed_start = speed(t);
            let speed_end = speed(t + h);
            for value in [speed_start, speed_end] {
                if !(value >= lowest && value <= highest) {
                    failed = Some(RunError::Speed {
                        time_s: t,
                        speed: value,
                        lowest,
                        highest,
                    });
                }
            }
            if failed.is_some() {
                break;
            }
            let mut gap_next = [0.0; MAX_STANDS];
            for ((slot, angle), model) in gap_next
                .iter_mut()
                .zip(angles.iter_mut())
                .zip(mill.stands())
            {
                angle.turn(0.5 * (speed_start + speed_end) * model.roll_speed / radius * h);
                *slot = angle.eccentricity(amplitudes);
            }
            let gauge_next =
                gauge * *gauge_decay + *gauge_kick * rng.sample::<f64, _>(StandardNormal);
            let (entry_tension, exit_tension) = tension_steps
                .iter()
                .take_while(|s| s.time_s <= t)
                .fold((0.0, 0.0), |(a, b), s| {
                    (a + s.entry_mpa * 1e6, b + s.exit_mpa * 1e6)
                });

            // Inputs at t, t + h/2 and t + h: the step's start reuses the last step's
            // end (the delayed gauges only read rows stored before), with this step's
            // noise.
            let inputs_at = |weight: f64| {
                let t_stage = t + weight * h;
                let speed = speed(t_stage);
                let mut inputs = Inputs {
                    entry_tension_pa: entry_tension,
                    exit_tension_pa: exit_tension,
                    force_n: force,
                    ..Inputs::default()
                };
                inputs.entry_thickness_m[0] = gauge + weight * (gauge_next - gauge);
                for stand in 0..n {
                    inputs.gap_offset_m[stand] =
                        gap_now[stand] + weight * (gap_next[stand] - gap_now[stand]);
                    if stand + 1 < n {
                        let delay = mill.delay_s(stand, speed);
                        inputs.entry_thickness_m[stand + 1] =
                            history.at(stand, (t_stage - delay) / h);
                    }
                }
                (speed, inputs)
            };
            let start = match carried.take() {
                Some((speed, inputs)) => (
                    speed,
                    Inputs {
                        force_n: force,
                        entry_tension_pa: entry_tension,
                        exit_tension_pa: exit_tension,
                        ..inputs
                    },
                ),
                None => inputs_at(0.0),
            };
            let middle = inputs_at(0.5);
            let end = inputs_at(1.0);
            for (s, (weight, &(speed, ref inputs))) in
                [(0.0, &start), (0.5, &middle), (0.5, &middle), (1.0, &end)]
                    .into_iter()
                    .enumerate()
            {
                if s == 0 {
                    stage.copy_from_slice(x);
                } else {
                    for ((value, x0), previous) in stage.iter_mut().zip(x.iter()).zip(&k[s - 1]) {
                        *value = x0 + weight * h * previous;
                    }
                }
                mill.derivative(speed, stage, inputs, &mut k[s]);
                if s == 0 {
                    // The state at t: keep the exit gauges, feed the accelerometers.
                    for (stand, slot) in row.iter_mut().enumerate().take(n) {
                        *slot = mill.gap_deviation(x, inputs, stand);
                    }
                    history.push(&row);
                    let sample_due = step.is_multiple_of(substeps);
                    for stand in 0..n {
                        let acceleration = k[0][TandemMill::work_roll(stand) + 3];
                        let filtered = if sensor.anti_alias {
                            anti_alias.process(&mut filter_state[stand], acceleration)
                        } else {
                            acceleration
                        };
                        if sample_due {
                            let noise = sensor.noise_rms * rng.sample::<f64, _>(StandardNormal);
                            record.acceleration[stand].push(filtered + noise);
                        }
                    }
                    if sample_due {
                        record.speed.push(speed);
                        for (j, tension) in record.tension_pa.iter_mut().enumerate() {
                            tension.push(x[mill.tension(j)]);
                        }
                    }
                }
            }
            let [k0, k1, k2, k3] = &*k;
            for ((((value, a), b), c), d) in x.iter_mut().zip(k0).zip(k1).zip(k2).zip(k3) {
                *value += h / 6.0 * (a + 2.0 * b + 2.0 * c + d);
            }
            if !x.iter().all(|v| v.is_finite()) {
                failed = Some(RunError::Diverged { time_s: t + h });
                break;
            }
            gap_now = gap_next;
            gauge = gauge_next;
            *carried = Some(end);
            next = step + 1;
        }
        *done = next;
        *gap_state = gap_now;
        *gauge_state = gauge;
        failed.map_or(Ok(()), Err)
    }
}

/// Simulates `mill` under `settings` (see the module docs).
pub fn simulate(mill: &TandemMill, settings: &RunSettings) -> Result<Record, RunError> {
    settings.validate()?;
    let ramp = settings.ramp;
    let mut simulation = Simulation::new(mill, &settings.setup())?;
    let exit_speed = mill.exit_speed(mill.stands().len() - 1, 1.0);
    let samples = (settings.duration_s * settings.sensor.sample_rate_hz).round() as usize;
    let mut record = simulation.record(samples);
    simulation.advance(samples, |t| ramp.speed_at(t, exit_speed), &mut record)?;
    Ok(record)
}

/// Largest eigenvalue magnitude of the undelayed system at speed factor `speed`, 1/s.
fn spectral_radius(mill: &TandemMill, speed: f64) -> Result<f64, RunError> {
    let characteristic = Characteristic::new(&mill.linear_system(speed))
        .map_err(|_| RunError::Eigenvalues { speed })?;
    Ok(characteristic
        .eigenvalues()
        .iter()
        .fold(0.0_f64, |m, mu| m.max(mu.norm())))
}
