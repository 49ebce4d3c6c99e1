//! What a run is built with: the speed ramp or range, the excitation, the
//! accelerometers, the seed; their ranges and the errors of a run.

/// Lowest internal integration rate, Hz.
pub(super) const MIN_INTERNAL_RATE_HZ: f64 = 10_000.0;
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

/// The force noise on every work roll (or on one stand's, `stand`) `factor` times
/// louder from `time_s` for `duration_s`: an excitation step that leaves the mill's
/// stability as it is (a weld or a rougher strip section passing the stands, all
/// stands at once; a weld passing stand by stand is a burst per stand, one after the
/// other).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NoiseBurst {
    /// Start, s, >= 0.
    pub time_s: f64,
    /// Length, s, > 0.
    pub duration_s: f64,
    /// Factor on the force-noise density, >= 1.
    pub factor: f64,
    /// The stand (index from the entry) whose work roll it excites; `None`: every
    /// stand.
    pub stand: Option<usize>,
}

impl Excitation {
    /// The factor on stand `stand`'s force noise at `t_s`: the largest of the bursts
    /// on it then, else 1.
    pub(crate) fn force_noise_factor(&self, t_s: f64, stand: usize) -> f64 {
        self.noise_bursts
            .iter()
            .filter(|b| t_s >= b.time_s && t_s < b.time_s + b.duration_s)
            .filter(|b| b.stand.is_none_or(|s| s == stand))
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
    /// A speed given to [`Simulation::advance`](super::Simulation::advance) left the
    /// setup's [`SpeedRange`].
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
    /// The chatter tests' reference ramp on a mill whose critical speed factor is
    /// `critical`: `hold_s` at `start` times it, then 2 m/s^2 up to 1.5 times it, the
    /// default excitation, an accelerometer at `sample_rate_hz`, `duration_s` long,
    /// seeded with `seed`.
    pub fn reference_ramp(
        critical: f64,
        start: f64,
        hold_s: f64,
        duration_s: f64,
        sample_rate_hz: f64,
        seed: u64,
    ) -> RunSettings {
        RunSettings {
            ramp: SpeedRamp {
                start: start * critical,
                end: 1.5 * critical,
                hold_s,
                accel_m_s2: 2.0,
            },
            excitation: Excitation::default(),
            sensor: Accelerometer {
                sample_rate_hz,
                ..Accelerometer::default()
            },
            duration_s,
            seed,
            internal_rate_hz: None,
        }
    }

    /// Checks every setting against its range.
    pub(crate) fn validate(&self) -> Result<(), RunError> {
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
/// ([`simulate`](super::simulate)) or a controller acting while it runs
/// ([`Simulation::advance`](super::Simulation::advance)).
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
    pub(crate) fn validate(&self) -> Result<(), RunError> {
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
