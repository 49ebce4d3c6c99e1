//! The simulation's state and its step: RK4 over the linearised mill with the
//! excitation's inputs, the exit gauges kept for the delays, the accelerometers read.

use millgate_dsp::filter::{BiquadState, Cascade};
use rand::rngs::SmallRng;
use rand::{Rng, SeedableRng};
use rand_distr::StandardNormal;

use super::delay::GaugeHistory;
use super::excitation::Sources;
use super::record::Record;
use super::settings::{Accelerometer, RunError, SimulationSetup, SpeedRange, MIN_INTERNAL_RATE_HZ};
use crate::tandem::linear::{Inputs, TandemMill, MAX_STANDS};
use crate::tandem::roots::Characteristic;

/// A tandem mill simulated step by step: [`Simulation::advance`] appends the next
/// samples to a record, its speed given by the caller for those samples, the state
/// (rolls, tensions, delayed gauges, filters, random sources) carried over. A run
/// advanced in pieces equals the run advanced at once with the same speeds.
pub struct Simulation {
    mill: TandemMill,
    speeds: SpeedRange,
    substeps: usize,
    /// Internal step, s.
    h: f64,
    /// Internal steps done.
    step: usize,
    /// Every random source in turn: the excitation's, then the sensors'.
    rng: SmallRng,
    sources: Sources,
    history: GaugeHistory,
    sensors: Sensors,
    rk4: Rk4,
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
        let (substeps, h) = internal_step(mill, setup)?;
        let tau_max = mill.delay_s(0, setup.speeds.lowest);
        let history = GaugeHistory::new((tau_max / h).ceil() as usize + 8, n);
        let mut rng = SmallRng::seed_from_u64(setup.seed);
        let sources = Sources::new(&setup.excitation, n, h, &mut rng);
        let sensors = Sensors::new(setup.sensor, n, substeps)?;
        Ok(Simulation {
            mill: mill.clone(),
            speeds: setup.speeds,
            substeps,
            h,
            step: 0,
            rng,
            sources,
            history,
            sensors,
            rk4: Rk4::new(mill.state_len()),
            carried: None,
        })
    }

    /// The simulated mill.
    pub(crate) fn mill(&self) -> &TandemMill {
        &self.mill
    }

    /// Time of the next sample, s.
    pub fn time_s(&self) -> f64 {
        self.samples() as f64 / self.sensors.sensor.sample_rate_hz
    }

    /// Samples produced so far (per stand).
    pub fn samples(&self) -> usize {
        self.step.div_ceil(self.substeps)
    }

    /// An empty record for this simulation's output, with room for `samples`.
    pub fn record(&self, samples: usize) -> Record {
        let n = self.mill.stands().len();
        Record {
            sample_rate_hz: self.sensors.sensor.sample_rate_hz,
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
        for step in self.step..self.step + samples * self.substeps {
            self.internal_step(step, &speed, record)?;
            self.step = step + 1;
        }
        Ok(())
    }

    /// Internal step `step`: the excitation over it, the inputs at its RK4 stages,
    /// the stages, the state at its start observed (exit gauges, accelerometers),
    /// the state moved on. On an error the step is not counted.
    fn internal_step(
        &mut self,
        step: usize,
        speed: &impl Fn(f64) -> f64,
        record: &mut Record,
    ) -> Result<(), RunError> {
        let (h, mill) = (self.h, &self.mill);
        let t = step as f64 * h;
        let force = self.sources.force(t, mill.stands().len(), &mut self.rng);
        let speeds = self.speeds_over(speed, t)?;
        let excitation = self
            .sources
            .step((t, h), force, speeds, mill, &mut self.rng);
        // Inputs at t, t + h/2 and t + h: the step's start reuses the last step's end
        // (the delayed gauges only read rows stored before), with this step's noise.
        let start = match self.carried.take() {
            Some(end) => excitation.carry(end),
            None => excitation.inputs_at(0.0, speed, mill, &self.history),
        };
        let middle = excitation.inputs_at(0.5, speed, mill, &self.history);
        let end = excitation.inputs_at(1.0, speed, mill, &self.history);
        self.rk4.stages(mill, h, [&start, &middle, &middle, &end]);
        self.observe(step, &start, record);
        if !self.rk4.finish(h) {
            return Err(RunError::Diverged { time_s: t + h });
        }
        self.sources.commit(&excitation);
        self.carried = Some(end);
        Ok(())
    }

    /// The speed factor at the start and the end of the step at `t`, both within the
    /// setup's range (else the error names the later one outside it).
    fn speeds_over(&self, speed: &impl Fn(f64) -> f64, t: f64) -> Result<(f64, f64), RunError> {
        let (lowest, highest) = (self.speeds.lowest, self.speeds.highest);
        let (speed_start, speed_end) = (speed(t), speed(t + self.h));
        let mut failed = None;
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
        failed.map_or(Ok((speed_start, speed_end)), Err)
    }

    /// The state at the start of internal step `step` (speed and inputs `start`):
    /// every stand's exit gauge into the delay ring, the accelerometers filtered and,
    /// at an output sample, the record's next sample.
    fn observe(&mut self, step: usize, (speed, inputs): &(f64, Inputs), record: &mut Record) {
        let (mill, x) = (&self.mill, &self.rk4.x);
        let n = mill.stands().len();
        let mut row = [0.0; MAX_STANDS];
        for (stand, slot) in row.iter_mut().enumerate().take(n) {
            *slot = mill.gap_deviation(x, inputs, stand);
        }
        self.history.push(&row);
        let sample_due = step.is_multiple_of(self.substeps);
        let accelerations = (0..n).map(|stand| self.rk4.k[0][TandemMill::work_roll(stand) + 3]);
        self.sensors
            .read(accelerations, sample_due, &mut self.rng, record);
        if sample_due {
            record.speed.push(*speed);
            for (j, tension) in record.tension_pa.iter_mut().enumerate() {
                tension.push(x[mill.tension(j)]);
            }
        }
    }
}

/// The output sample rate's divisor and the internal step (s) of `mill` run under
/// `setup`: >= 10 kHz and `h |mu|_max <= 0.8` at the top speed (RK4 is stable to 2.8),
/// or the setup's internal rate.
fn internal_step(mill: &TandemMill, setup: &SimulationSetup) -> Result<(usize, f64), RunError> {
    let fs = setup.sensor.sample_rate_hz;
    let spectral = spectral_radius(mill, setup.speeds.highest)?;
    let wanted = setup
        .internal_rate_hz
        .unwrap_or(MIN_INTERNAL_RATE_HZ.max(spectral / 0.8));
    let substeps = (wanted / fs).ceil().max(1.0) as usize;
    Ok((substeps, 1.0 / (fs * substeps as f64)))
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

/// The accelerometers: the optional anti-alias low-pass run at the internal rate,
/// sampled at the output rate with white sensor noise.
struct Sensors {
    sensor: Accelerometer,
    anti_alias: Cascade<2>,
    filter_state: Vec<[BiquadState; 2]>,
}

impl Sensors {
    /// `stands` accelerometers read every `substeps` internal steps.
    fn new(sensor: Accelerometer, stands: usize, substeps: usize) -> Result<Sensors, RunError> {
        let fs = sensor.sample_rate_hz;
        let anti_alias = Cascade::<2>::butterworth_lowpass(0.4 * fs, fs * substeps as f64)
            .map_err(|_| RunError::Setting {
                key: "sensor.sample_rate_hz",
                value: fs,
                allowed: "500 ..= 20000 Hz",
            })?;
        Ok(Sensors {
            sensor,
            anti_alias,
            filter_state: vec![[BiquadState::default(); 2]; stands],
        })
    }

    /// Filters every stand's acceleration (m/s^2) of one internal step; at an output
    /// sample (`sample_due`) appends them, with sensor noise from `rng`, to `record`.
    fn read(
        &mut self,
        accelerations: impl Iterator<Item = f64>,
        sample_due: bool,
        rng: &mut SmallRng,
        record: &mut Record,
    ) {
        for (stand, acceleration) in accelerations.enumerate() {
            let filtered = if self.sensor.anti_alias {
                self.anti_alias
                    .process(&mut self.filter_state[stand], acceleration)
            } else {
                acceleration
            };
            if sample_due {
                let noise = self.sensor.noise_rms * rng.sample::<f64, _>(StandardNormal);
                record.acceleration[stand].push(filtered + noise);
            }
        }
    }
}

/// Classical fourth-order Runge-Kutta over the mill's state.
struct Rk4 {
    /// The state at the step's start.
    x: Vec<f64>,
    /// The state a stage evaluates at.
    stage: Vec<f64>,
    /// The four stages' derivatives.
    k: [Vec<f64>; 4],
}

impl Rk4 {
    fn new(len: usize) -> Rk4 {
        Rk4 {
            x: vec![0.0; len],
            stage: vec![0.0; len],
            k: [
                vec![0.0; len],
                vec![0.0; len],
                vec![0.0; len],
                vec![0.0; len],
            ],
        }
    }

    /// The four stages' derivatives over a step of `h` s, with the speed factor and
    /// inputs at its start, middle (twice) and end.
    fn stages(&mut self, mill: &TandemMill, h: f64, inputs: [&(f64, Inputs); 4]) {
        for (s, (weight, &(speed, ref inputs))) in
            [0.0, 0.5, 0.5, 1.0].into_iter().zip(inputs).enumerate()
        {
            if s == 0 {
                self.stage.copy_from_slice(&self.x);
            } else {
                for ((value, x0), previous) in
                    self.stage.iter_mut().zip(self.x.iter()).zip(&self.k[s - 1])
                {
                    *value = x0 + weight * h * previous;
                }
            }
            mill.derivative(speed, &self.stage, inputs, &mut self.k[s]);
        }
    }

    /// Moves the state over the step of `h` s; false when it left the finite numbers.
    fn finish(&mut self, h: f64) -> bool {
        let [k0, k1, k2, k3] = &self.k;
        for ((((value, a), b), c), d) in self.x.iter_mut().zip(k0).zip(k1).zip(k2).zip(k3) {
            *value += h / 6.0 * (a + 2.0 * b + 2.0 * c + d);
        }
        self.x.iter().all(|v| v.is_finite())
    }
}
