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

mod delay;
mod excitation;
mod record;
mod settings;
mod simulation;

pub use record::Record;
pub use settings::{
    Accelerometer, Excitation, NoiseBurst, RunError, RunSettings, SimulationSetup, SpeedRamp,
    SpeedRange, TensionStep, MAX_DURATION_S,
};
pub use simulation::Simulation;

use super::linear::TandemMill;

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
