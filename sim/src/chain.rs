//! Time simulation of the torsional chain: couplings with stiffness, damping and a
//! symmetric dead zone, a PI speed-controlled motor on mass 0 and the rolling load on
//! the last mass.
//!
//! Conventions (shared with every tool that produces data under the same model):
//! - state starts at rest with zero twist: every gap is centred, so half its width must
//!   close before the coupling carries elastic torque;
//! - speeds are deviations from nominal; the PI reference is 0, so the motor torque is
//!   `kp (0 - w0) + ki * integral(0 - w0) = -kp w0 - ki theta0` (the integral of the
//!   speed deviation is the angle deviation, which starts at 0);
//! - twist of coupling i is `x = theta_i - theta_{i+1}`; with `g = backlash / 2` the
//!   elastic torque is `C (x - g)` for `x > g`, `0` for `|x| <= g`, `C (x + g)` for
//!   `x < -g`; damping `h (w_i - w_{i+1})` acts at all times;
//! - the load `M(t)` acts against the last mass; the measured channel is the torque
//!   (elastic + damping + friction) of the model's measured coupling, in kN*m, passed
//!   through the first-order lag `measurement.lag` when it is set (an extra state that
//!   starts at 0).
//!
//! Optional coupling extensions (all default 0): cubic hardening `k3 e^3` added to the
//! elastic torque, `e` being the deflection beyond the gap, and Coulomb-like friction
//! `F tanh(rate / FRICTION_SPEED)`. The tanh keeps the right-hand side smooth, so RK4
//! keeps its order; its slope `F / FRICTION_SPEED` counts in the step bound below.
//!
//! Integrator: classical fixed-step RK4 on `[theta, w]` with the contact regime of every
//! coupling frozen during a step, so each step integrates a smooth (piecewise linear)
//! system. When a twist leaves its regime inside a step, the crossing time is located
//! by the Illinois (modified regula falsi) method on the step length, the step is cut
//! there, the regime switches and the rest of the step follows. Steps are also cut at
//! the load onset, where the load's slope jumps. The step is
//! `sample_period / substeps` with `substeps = ceil(50 f_bound sample_period)`, where
//! `f_bound` (Hz) is a guaranteed upper bound on the linearised system's eigenvalue
//! magnitudes (stiffness, damping and PI gains all count).

use rand::{rngs::StdRng, Rng, SeedableRng};
use rand_distr::StandardNormal;

use crate::model::{Model, ModelError};

/// Twist rate at which a coupling's friction reaches tanh(1) = 76% of its full value,
/// rad/s. Well below the twist rates of bite transients (0.05-0.5 rad/s), so the
/// friction acts like Coulomb's, yet smooth enough for a fixed-step integrator.
pub const FRICTION_SPEED: f64 = 2.0e-3;

/// Integration steps per period of the fastest possible motion (h = 1 / (50 f_bound)).
pub(crate) const STEPS_PER_FASTEST_PERIOD: f64 = 50.0;

/// Largest number of RK4 steps per output sample the automatic choice may use.
const MAX_SUBSTEPS: usize = 1 << 20;

/// Event location stops when the bracket is this fraction of the step.
const EVENT_TOLERANCE: f64 = 1.0e-10;

/// Safety cap on Illinois iterations per event (each costs one RK4 step).
const MAX_EVENT_ITERATIONS: usize = 100;

/// A simulated record of the measured coupling torque.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Transient {
    /// Sample times, s: `k / sample_rate` for `k = 0 .. round(duration * sample_rate)`.
    pub t: Vec<f64>,
    /// Measured coupling torque (elastic + damping), kN*m, one per entry of `t`.
    pub torque_knm: Vec<f64>,
}

/// Contact regime of one coupling: which branch of the dead-zone law applies.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Regime {
    /// `x < -g`: torque `C (x + g)`.
    Negative,
    /// `|x| <= g`: no elastic torque.
    Open,
    /// `x > g` (or any `x` when the coupling has no gap): torque `C (x - g)`.
    Positive,
}

/// Coefficients of the chain, built once from a validated model.
#[derive(Debug, Clone)]
pub struct Simulator {
    inverse_inertia: Vec<f64>,
    stiffness: Vec<f64>,
    damping: Vec<f64>,
    /// Cubic hardening of each coupling, N*m/rad^3.
    hardening: Vec<f64>,
    /// Friction torque of each coupling, N*m.
    friction: Vec<f64>,
    /// Half the backlash of each coupling, rad.
    half_gap: Vec<f64>,
    /// `1 / lag` of the measured channel, 1/s; 0 when the channel has no lag.
    inverse_lag: f64,
    speed_kp: f64,
    speed_ki: f64,
    static_torque_nm: f64,
    rise_rate: f64,
    onset_s: f64,
    measured: usize,
    /// [`Simulator::run_into`] stops when |output| exceeds this, kN*m.
    divergence_limit_knm: f64,
    sample_period_s: f64,
    /// The sample rate, Hz: the record's times are `k / sample_rate_hz`, correctly
    /// rounded (`k * sample_period_s` would print `0.0045000000000000005`).
    sample_rate_hz: f64,
    samples: usize,
    substeps: usize,
}

/// Mutable integrator state and preallocated work buffers for one [`Simulator`].
#[derive(Debug, Clone)]
pub struct ChainState {
    /// `[theta_0 .. theta_{n-1}, w_0 .. w_{n-1}]`, rad and rad/s, then the lagged
    /// measured torque (N*m) when the channel has a lag.
    y: Vec<f64>,
    regime: Vec<Regime>,
    k1: Vec<f64>,
    k2: Vec<f64>,
    k3: Vec<f64>,
    k4: Vec<f64>,
    stage: Vec<f64>,
    trial: Vec<f64>,
    probe: Vec<f64>,
    /// Number of gap crossings located so far.
    events: usize,
}

/// A located regime change: coupling, its new regime, the step length to it and the
/// state just past it (in `ChainState::probe`).
#[derive(Debug, Clone, Copy)]
struct Crossing {
    coupling: usize,
    regime: Regime,
    step_s: f64,
}

impl Simulator {
    /// Validates the model and builds the simulator with the automatic step; a tree
    /// model (gear ratios, servo configurations) is refused: the simulation is of
    /// chains.
    pub fn new(model: &Model) -> Result<Simulator, ModelError> {
        model.validate("<model>")?;
        model.require_chain("<model>", "the time simulation")?;
        let inverse_inertia: Vec<f64> = model.masses.iter().map(|m| 1.0 / m.inertia).collect();
        let stiffness: Vec<f64> = model.couplings.iter().map(|c| c.stiffness).collect();
        let damping: Vec<f64> = model.couplings.iter().map(|c| c.damping).collect();
        let half_gap = model.couplings.iter().map(|c| 0.5 * c.backlash).collect();
        let hardening = model.couplings.iter().map(|c| c.hardening).collect();
        let friction = model.couplings.iter().map(|c| c.friction).collect();
        let lag = model.measurement.lag;
        let sample_period_s = 1.0 / model.measurement.sample_rate;
        let mut simulator = Simulator {
            inverse_inertia,
            stiffness,
            damping,
            hardening,
            friction,
            half_gap,
            inverse_lag: if lag > 0.0 { 1.0 / lag } else { 0.0 },
            speed_kp: model.motor.speed_kp,
            speed_ki: model.motor.speed_ki,
            static_torque_nm: model.load.static_torque * 1.0e3,
            rise_rate: model.load.rise_rate,
            onset_s: model.load.onset,
            measured: model.measurement.coupling,
            divergence_limit_knm: f64::INFINITY,
            sample_period_s,
            sample_rate_hz: model.measurement.sample_rate,
            samples: model.sample_count(),
            substeps: 1,
        };
        let steps = (STEPS_PER_FASTEST_PERIOD * simulator.frequency_bound_hz() * sample_period_s)
            .ceil()
            .clamp(1.0, MAX_SUBSTEPS as f64);
        simulator.substeps = steps as usize;
        Ok(simulator)
    }

    /// The same simulator with `substeps` RK4 steps per output sample (at least 1).
    pub fn with_substeps_per_sample(mut self, substeps: usize) -> Simulator {
        self.substeps = substeps.max(1);
        self
    }

    /// The same simulator stopping as soon as |output| exceeds `limit_knm` (kN*m) or the
    /// gap crossings outnumber the output samples, the samples left unwritten set to
    /// NaN. For fits that try parameter values at which the fixed step is unstable or a
    /// gap chatters: such a run ends early instead of hunting crossings of an exploding
    /// state.
    pub(crate) fn with_divergence_limit(mut self, limit_knm: f64) -> Simulator {
        self.divergence_limit_knm = limit_knm;
        self
    }

    /// RK4 steps per output sample.
    pub fn substeps_per_sample(&self) -> usize {
        self.substeps
    }

    /// Integration step, s (gap crossings and the load onset cut it further).
    pub fn step_s(&self) -> f64 {
        self.sample_period_s / self.substeps as f64
    }

    /// Upper bound on |eigenvalue| / (2 pi) of the linearised chain, Hz.
    ///
    /// For `(l^2 M + l C + K) v = 0`, the infinity norms `k = |M^-1 K|` and
    /// `c = |M^-1 C|` (PI gains included) give `|l| <= (c + sqrt(c^2 + 4 k)) / 2`.
    /// Nonlinear couplings count with their largest slopes: friction adds
    /// `F / FRICTION_SPEED` to the damping; hardening adds `3 k3 e^2` to the stiffness
    /// at a deflection `e` of four times the static load's (a bound, not a guarantee,
    /// for transients with TAF up to 4). A lagged channel adds the eigenvalue `1 / lag`.
    pub(crate) fn frequency_bound_hz(&self) -> f64 {
        let n = self.inverse_inertia.len();
        let mut k_norm: f64 = 0.0;
        let mut c_norm: f64 = 0.0;
        for i in 0..n {
            let mut k_row = 0.0;
            let mut c_row = 0.0;
            if i > 0 {
                k_row += 2.0 * self.largest_stiffness(i - 1);
                c_row += 2.0 * self.largest_damping(i - 1);
            }
            if i + 1 < n {
                k_row += 2.0 * self.largest_stiffness(i);
                c_row += 2.0 * self.largest_damping(i);
            }
            if i == 0 {
                k_row += self.speed_ki;
                c_row += self.speed_kp;
            }
            k_norm = k_norm.max(k_row * self.inverse_inertia[i]);
            c_norm = c_norm.max(c_row * self.inverse_inertia[i]);
        }
        let chain = (c_norm + (c_norm * c_norm + 4.0 * k_norm).sqrt()) / 2.0;
        chain.max(self.inverse_lag) / std::f64::consts::TAU
    }

    /// Largest torque-per-twist slope of coupling `index`, N*m/rad (see
    /// [`Simulator::frequency_bound_hz`]).
    fn largest_stiffness(&self, index: usize) -> f64 {
        let stiffness = self.stiffness[index];
        let deflection = 4.0 * self.static_torque_nm / stiffness;
        stiffness + 3.0 * self.hardening[index] * deflection * deflection
    }

    /// Largest torque-per-twist-rate slope of coupling `index`, N*m*s/rad.
    fn largest_damping(&self, index: usize) -> f64 {
        self.damping[index] + self.friction[index] / FRICTION_SPEED
    }

    /// Number of output samples.
    pub fn sample_count(&self) -> usize {
        self.samples
    }

    /// A fresh state at rest: zero angles, zero speeds, every gap centred.
    pub fn initial_state(&self) -> ChainState {
        let regime = self
            .half_gap
            .iter()
            .map(|&g| {
                if g > 0.0 {
                    Regime::Open
                } else {
                    Regime::Positive
                }
            })
            .collect();
        let len = self.state_len();
        ChainState {
            y: vec![0.0; len],
            regime,
            k1: vec![0.0; len],
            k2: vec![0.0; len],
            k3: vec![0.0; len],
            k4: vec![0.0; len],
            stage: vec![0.0; len],
            trial: vec![0.0; len],
            probe: vec![0.0; len],
            events: 0,
        }
    }

    /// Runs the whole record.
    pub fn run(&self) -> Transient {
        let mut state = self.initial_state();
        let mut torque_knm = vec![0.0; self.samples];
        self.run_into(&mut state, &mut torque_knm);
        let t = (0..self.samples)
            .map(|k| k as f64 / self.sample_rate_hz)
            .collect();
        Transient { t, torque_knm }
    }

    /// Runs from `state` (normally [`Simulator::initial_state`]) and writes the measured
    /// torque (kN*m) at `t = k / sample_rate` into `torque_knm[k]`; allocation-free.
    ///
    /// Writes `min(torque_knm.len(), sample_count)` samples and returns the number of
    /// gap crossings located.
    pub fn run_into(&self, state: &mut ChainState, torque_knm: &mut [f64]) -> usize {
        let count = torque_knm.len().min(self.samples);
        let step_s = self.step_s();
        for k in 0..count {
            let value = self.measured_nm(state) * 1.0e-3;
            torque_knm[k] = value;
            let diverged = value.is_nan()
                || value.abs() > self.divergence_limit_knm
                || (self.divergence_limit_knm.is_finite() && state.events > count);
            if diverged {
                torque_knm[k..count].fill(f64::NAN);
                break;
            }
            if k + 1 == count {
                break;
            }
            let sample_start = k as f64 * self.sample_period_s;
            for substep in 0..self.substeps {
                let t_start = sample_start + substep as f64 * step_s;
                let t_end = if substep + 1 == self.substeps {
                    (k + 1) as f64 * self.sample_period_s
                } else {
                    t_start + step_s
                };
                self.advance(state, t_start, t_end);
            }
        }
        state.events
    }

    /// Length of the state vector: angles, speeds and the lagged channel if any.
    fn state_len(&self) -> usize {
        2 * self.inverse_inertia.len() + usize::from(self.inverse_lag > 0.0)
    }

    /// The measured channel in state `y`, N*m: the lag state, or the measured
    /// coupling's torque when the channel has no lag.
    fn measured_nm(&self, state: &ChainState) -> f64 {
        let n = self.inverse_inertia.len();
        if self.inverse_lag > 0.0 {
            state.y[2 * n]
        } else {
            self.coupling_torque(self.measured, &state.y, &state.regime)
        }
    }

    /// Torque of coupling `index` (elastic + damping + friction) in state `y` under the
    /// frozen regimes, N*m.
    fn coupling_torque(&self, index: usize, y: &[f64], regime: &[Regime]) -> f64 {
        let n = self.inverse_inertia.len();
        let twist = y[index] - y[index + 1];
        let rate = y[n + index] - y[n + index + 1];
        let mut torque = self.elastic(index, twist, regime[index]) + self.damping[index] * rate;
        if self.friction[index] > 0.0 {
            torque += self.friction[index] * (rate / FRICTION_SPEED).tanh();
        }
        torque
    }

    /// Elastic torque of coupling `index` at twist `x` under a frozen regime, N*m.
    fn elastic(&self, index: usize, x: f64, regime: Regime) -> f64 {
        let g = self.half_gap[index];
        let deflection = match regime {
            Regime::Positive => x - g,
            Regime::Open => return 0.0,
            Regime::Negative => x + g,
        };
        let hardening = self.hardening[index];
        self.stiffness[index] * deflection + hardening * deflection * deflection * deflection
    }

    /// Rolling load at `t_s`, N*m.
    fn load_nm(&self, t_s: f64) -> f64 {
        if t_s <= self.onset_s {
            0.0
        } else {
            self.static_torque_nm * (1.0 - (-self.rise_rate * (t_s - self.onset_s)).exp())
        }
    }

    /// Time derivative of `y` at `t_s` with the regimes frozen, written into `dy`.
    fn derivative(&self, t_s: f64, y: &[f64], regime: &[Regime], dy: &mut [f64]) {
        let n = self.inverse_inertia.len();
        dy[..n].copy_from_slice(&y[n..2 * n]);
        // Torque flowing into mass i from its left neighbour (the motor for mass 0).
        let mut from_left = -self.speed_kp * y[n] - self.speed_ki * y[0];
        for i in 0..n - 1 {
            let coupling = self.coupling_torque(i, y, regime);
            dy[n + i] = (from_left - coupling) * self.inverse_inertia[i];
            if i == self.measured && self.inverse_lag > 0.0 {
                dy[2 * n] = (coupling - y[2 * n]) * self.inverse_lag;
            }
            from_left = coupling;
        }
        dy[2 * n - 1] = (from_left - self.load_nm(t_s)) * self.inverse_inertia[n - 1];
    }

    /// One RK4 step of length `h` from `(t_s, state.y)` under the frozen regimes; the
    /// result goes to `out` (either `state.trial` or `state.probe`).
    fn rk4(&self, state: &mut ChainState, t_s: f64, h: f64, into_probe: bool) {
        let ChainState {
            y,
            regime,
            k1,
            k2,
            k3,
            k4,
            stage,
            trial,
            probe,
            ..
        } = state;
        self.derivative(t_s, y, regime, k1);
        for ((s, &y), &k) in stage.iter_mut().zip(y.iter()).zip(k1.iter()) {
            *s = y + 0.5 * h * k;
        }
        self.derivative(t_s + 0.5 * h, stage, regime, k2);
        for ((s, &y), &k) in stage.iter_mut().zip(y.iter()).zip(k2.iter()) {
            *s = y + 0.5 * h * k;
        }
        self.derivative(t_s + 0.5 * h, stage, regime, k3);
        for ((s, &y), &k) in stage.iter_mut().zip(y.iter()).zip(k3.iter()) {
            *s = y + h * k;
        }
        self.derivative(t_s + h, stage, regime, k4);
        let out = if into_probe { probe } else { trial };
        for (i, o) in out.iter_mut().enumerate() {
            *o = y[i] + h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]);
        }
    }

    /// Advances `state` from `t_start` to `t_end`, cutting at the load onset and at
    /// every gap crossing.
    fn advance(&self, state: &mut ChainState, t_start: f64, t_end: f64) {
        let mut t = t_start;
        while t < t_end {
            let target = if t < self.onset_s && self.onset_s < t_end {
                self.onset_s
            } else {
                t_end
            };
            let h = target - t;
            self.rk4(state, t, h, false);
            match self.earliest_crossing(state, t, h) {
                None => {
                    std::mem::swap(&mut state.y, &mut state.trial);
                    t = target;
                }
                Some(crossing) => {
                    // Recompute the state just past the crossing into `probe`.
                    self.rk4(state, t, crossing.step_s, true);
                    std::mem::swap(&mut state.y, &mut state.probe);
                    state.regime[crossing.coupling] = crossing.regime;
                    state.events += 1;
                    t += crossing.step_s;
                }
            }
        }
    }

    /// The regime a coupling leaves for, if its twist `x` has left `regime`.
    fn departure(&self, index: usize, x: f64, regime: Regime) -> Option<(Regime, f64)> {
        let g = self.half_gap[index];
        if g <= 0.0 {
            return None;
        }
        match regime {
            Regime::Positive if x <= g => Some((Regime::Open, g)),
            Regime::Open if x > g => Some((Regime::Positive, g)),
            Regime::Open if x < -g => Some((Regime::Negative, -g)),
            Regime::Negative if x >= -g => Some((Regime::Open, -g)),
            _ => None,
        }
    }

    /// Earliest regime change within the trial step of length `h` (in `state.trial`).
    fn earliest_crossing(&self, state: &mut ChainState, t_s: f64, h: f64) -> Option<Crossing> {
        let mut earliest: Option<Crossing> = None;
        for index in 0..self.half_gap.len() {
            let x_end = state.trial[index] - state.trial[index + 1];
            let Some((next, boundary)) = self.departure(index, x_end, state.regime[index]) else {
                continue;
            };
            let limit = earliest.map_or(h, |c| c.step_s);
            let step_s = self.locate(state, t_s, h, index, boundary, limit);
            if earliest.is_none_or(|c| step_s < c.step_s) {
                earliest = Some(Crossing {
                    coupling: index,
                    regime: next,
                    step_s,
                });
            }
        }
        earliest
    }

    /// Step length in `(0, h]` just past which coupling `index` crosses `boundary`.
    ///
    /// Illinois iteration on `f(s) = x(s) - boundary`, where `x(s)` is the twist after
    /// one frozen-regime RK4 step of length `s`; the bracket `[lo, hi]` always has `lo`
    /// before the crossing and `hi` after it. `limit` (<= h) is an earlier crossing of
    /// another coupling already found; the search gives up past it.
    fn locate(
        &self,
        state: &mut ChainState,
        t_s: f64,
        h: f64,
        index: usize,
        boundary: f64,
        limit: f64,
    ) -> f64 {
        let regime = state.regime[index];
        let twist = |y: &[f64]| y[index] - y[index + 1];
        let mut lo = 0.0;
        let mut f_lo = twist(&state.y) - boundary;
        let mut hi = h;
        let mut f_hi = twist(&state.trial) - boundary;
        if limit < h {
            self.rk4(state, t_s, limit, true);
            let x = twist(&state.probe);
            if self.departure(index, x, regime).is_none() {
                return h;
            }
            hi = limit;
            f_hi = x - boundary;
        }
        // Which end was moved last, for the Illinois halving.
        let mut last_side = 0_i8;
        for _ in 0..MAX_EVENT_ITERATIONS {
            if hi - lo <= EVENT_TOLERANCE * h {
                break;
            }
            let secant = if f_hi != f_lo {
                lo - f_lo * (hi - lo) / (f_hi - f_lo)
            } else {
                f64::NAN
            };
            let s = if secant > lo && secant < hi {
                secant
            } else {
                0.5 * (lo + hi)
            };
            self.rk4(state, t_s, s, true);
            let x = twist(&state.probe);
            let f = x - boundary;
            if self.departure(index, x, regime).is_some() {
                hi = s;
                f_hi = f;
                if last_side == 1 {
                    f_lo *= 0.5;
                }
                last_side = 1;
            } else {
                lo = s;
                f_lo = f;
                if last_side == -1 {
                    f_hi *= 0.5;
                }
                last_side = -1;
            }
        }
        hi
    }
}

/// Simulates the model's measured torque from rest over its duration.
///
/// # Example
/// ```
/// let model = millgate_sim::model::Model::load(concat!(
///     env!("CARGO_MANIFEST_DIR"),
///     "/models/table2-adjusted.toml"
/// ))?;
/// let transient = millgate_sim::chain::simulate(&model)?;
/// assert_eq!(transient.t.len(), model.sample_count());
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub fn simulate(model: &Model) -> Result<Transient, ModelError> {
    Ok(Simulator::new(model)?.run())
}

/// Like [`simulate`], plus white Gaussian noise of RMS `noise_rms_knm` (kN*m, >= 0)
/// from a [`StdRng`] seeded with `seed` (same seed, same noise).
pub fn simulate_with_noise(
    model: &Model,
    noise_rms_knm: f64,
    seed: u64,
) -> Result<Transient, ModelError> {
    if !(noise_rms_knm.is_finite() && noise_rms_knm >= 0.0) {
        return Err(ModelError::Value {
            file: "<arguments>".to_owned(),
            key: "noise_rms".to_owned(),
            value: noise_rms_knm.to_string(),
            allowed: ">= 0 kN*m".to_owned(),
        });
    }
    let mut transient = simulate(model)?;
    let mut rng = StdRng::seed_from_u64(seed);
    for value in &mut transient.torque_knm {
        let unit: f64 = rng.sample(StandardNormal);
        *value += noise_rms_knm * unit;
    }
    Ok(transient)
}
