//! Vertical vibration of the stands of a tandem cold mill, with and without chatter
//! synchronization (domain notes 2), for the virtual DAQ and the chatter tests.
//!
//! Each stand's signal is a narrow-band process plus white measurement noise:
//!
//! ```text
//! x_i(t) = amplitude * sin(phi_i(t)) + noise
//! dphi_i = 2 pi f_i(t) dt + coupling_i(t) dt + sqrt(2 pi linewidth dt) * N(0, 1)
//! ```
//!
//! The random phase walk gives each stand a Lorentzian line `linewidth_hz` wide
//! (full width at half maximum) around its own natural frequency in the chatter band.
//!
//! In the [`Regime::Synchronized`] regime the strip couples the stands from
//! `start_s` on: each stand's frequency is pulled from its own value to the common
//! one with time constant `pull_time_s`,
//! `f_i(t) = common + (natural_i - common) exp(-(t - start) / pull_time)`,
//! and its phase is drawn to a common reference oscillator (at `common_hz`, with the
//! same phase walk) by a coupling that grows with time constant `lock_time_s`:
//! `coupling_i = 2 pi coupling_hz (1 - exp(-(t - start) / lock_time)) sin(phi_c - phi_i)`.
//! With `lock_time_s` longer than `pull_time_s` the frequencies meet before the
//! phases lock, as the paper describes for the onset of chatter.

use std::f64::consts::TAU;

use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use rand_distr::StandardNormal;

/// Invalid stand settings; the variant names the field at fault.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum StandsError {
    #[error("sample_rate_hz must be finite and > 0")]
    SampleRateHz,
    #[error("natural_hz must hold 1 or more frequencies, each finite, > 0 and below half the sample rate")]
    NaturalHz,
    #[error("amplitude must be finite and >= 0")]
    Amplitude,
    #[error("linewidth_hz must be finite and >= 0")]
    LinewidthHz,
    #[error("noise_rms must be finite and >= 0")]
    NoiseRms,
    #[error("start_s must be finite and >= 0")]
    StartS,
    #[error("common_hz must be finite, > 0 and below half the sample rate")]
    CommonHz,
    #[error("pull_time_s must be finite and > 0")]
    PullTimeS,
    #[error("lock_time_s must be finite and > 0")]
    LockTimeS,
    #[error("coupling_hz must be finite and >= 0")]
    CouplingHz,
    #[error("duration_s must be finite, >= 0 and at most 1e8 samples long")]
    DurationS,
}

/// The stands and their measurement.
#[derive(Debug, Clone, PartialEq)]
pub struct StandsSettings {
    /// Sample rate of every stand's signal, Hz, > 0.
    pub sample_rate_hz: f64,
    /// Each stand's own principal (natural) frequency, Hz, in rolling order;
    /// each > 0 and below half the sample rate.
    pub natural_hz: Vec<f64>,
    /// Peak of each stand's narrow-band vibration, in signal units (e.g. m/s^2), >= 0.
    pub amplitude: f64,
    /// Width of each stand's spectral line (phase random walk), Hz, >= 0.
    pub linewidth_hz: f64,
    /// White measurement noise, RMS in signal units, >= 0.
    pub noise_rms: f64,
}

/// Onset of chatter: the stands' frequencies pull together and their phases lock.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Synchronization {
    /// When the coupling starts, s from the start of the record, >= 0.
    pub start_s: f64,
    /// The common frequency the stands are pulled to, Hz, > 0, below half the sample rate.
    pub common_hz: f64,
    /// Time constant of the frequency pull, s, > 0.
    pub pull_time_s: f64,
    /// Time constant of the growth of the phase coupling, s, > 0.
    pub lock_time_s: f64,
    /// Strength of the full phase coupling, Hz (rad/s over 2 pi), >= 0: phase
    /// errors decay at this rate once locked.
    pub coupling_hz: f64,
}

impl Synchronization {
    /// Synchronization from `start_s` to `common_hz` with the defaults: frequencies
    /// pull in with a 0.3 s time constant, the phase coupling grows with 1 s to 10 Hz.
    pub fn new(start_s: f64, common_hz: f64) -> Self {
        Self {
            start_s,
            common_hz,
            pull_time_s: 0.3,
            lock_time_s: 1.0,
            coupling_hz: 10.0,
        }
    }
}

/// How the stands vibrate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Regime {
    /// Steady rolling: every stand at its own frequency, independent phases.
    Independent,
    /// Steady rolling until the synchronization starts, then chatter builds up.
    Synchronized(Synchronization),
}

impl Regime {
    /// [`Regime::Synchronized`] from `start_s` to `common_hz` with the default
    /// time constants of [`Synchronization::new`].
    pub fn synchronized(start_s: f64, common_hz: f64) -> Self {
        Self::Synchronized(Synchronization::new(start_s, common_hz))
    }
}

/// A validated stand vibration generator.
#[derive(Debug, Clone, PartialEq)]
pub struct Stands {
    settings: StandsSettings,
    regime: Regime,
}

/// Largest record generated, samples per stand.
const MAX_SAMPLES: f64 = 1e8;

fn finite_at_least(value: f64, low: f64) -> bool {
    value.is_finite() && value >= low
}

impl Stands {
    /// Validates `settings` and `regime`.
    pub fn new(settings: StandsSettings, regime: Regime) -> Result<Self, StandsError> {
        let fs = settings.sample_rate_hz;
        if !(fs.is_finite() && fs > 0.0) {
            return Err(StandsError::SampleRateHz);
        }
        let audible = |f: f64| f.is_finite() && f > 0.0 && f < fs / 2.0;
        if settings.natural_hz.is_empty() || !settings.natural_hz.iter().all(|&f| audible(f)) {
            return Err(StandsError::NaturalHz);
        }
        if !finite_at_least(settings.amplitude, 0.0) {
            return Err(StandsError::Amplitude);
        }
        if !finite_at_least(settings.linewidth_hz, 0.0) {
            return Err(StandsError::LinewidthHz);
        }
        if !finite_at_least(settings.noise_rms, 0.0) {
            return Err(StandsError::NoiseRms);
        }
        if let Regime::Synchronized(sync) = regime {
            if !finite_at_least(sync.start_s, 0.0) {
                return Err(StandsError::StartS);
            }
            if !audible(sync.common_hz) {
                return Err(StandsError::CommonHz);
            }
            if !(sync.pull_time_s.is_finite() && sync.pull_time_s > 0.0) {
                return Err(StandsError::PullTimeS);
            }
            if !(sync.lock_time_s.is_finite() && sync.lock_time_s > 0.0) {
                return Err(StandsError::LockTimeS);
            }
            if !finite_at_least(sync.coupling_hz, 0.0) {
                return Err(StandsError::CouplingHz);
            }
        }
        Ok(Self { settings, regime })
    }

    /// The validated settings.
    pub fn settings(&self) -> &StandsSettings {
        &self.settings
    }

    /// Number of stands.
    pub fn len(&self) -> usize {
        self.settings.natural_hz.len()
    }

    /// Whether there are no stands (never: [`Stands::new`] requires one).
    pub fn is_empty(&self) -> bool {
        self.settings.natural_hz.is_empty()
    }

    /// The frequency law of `stand` at `t_s` (s from the start), Hz, without the
    /// phase walk and coupling: its natural frequency, pulled towards the common one
    /// once synchronization has started. `None` for a stand index out of range.
    pub fn frequency_hz(&self, stand: usize, t_s: f64) -> Option<f64> {
        let natural = *self.settings.natural_hz.get(stand)?;
        Some(match self.regime {
            Regime::Synchronized(sync) if t_s >= sync.start_s => {
                let pulled = (-(t_s - sync.start_s) / sync.pull_time_s).exp();
                sync.common_hz + (natural - sync.common_hz) * pulled
            }
            _ => natural,
        })
    }

    /// Phase coupling gain at `t_s`, rad/s.
    fn coupling_gain(&self, t_s: f64) -> f64 {
        match self.regime {
            Regime::Synchronized(sync) if t_s >= sync.start_s => {
                let grown = 1.0 - (-(t_s - sync.start_s) / sync.lock_time_s).exp();
                TAU * sync.coupling_hz * grown
            }
            _ => 0.0,
        }
    }

    /// `duration_s` seconds of every stand's signal (one `Vec` per stand, in stand
    /// order, sample k at `k / sample_rate_hz`), from a generator seeded with `seed`.
    pub fn generate(&self, duration_s: f64, seed: u64) -> Result<Vec<Vec<f64>>, StandsError> {
        let fs = self.settings.sample_rate_hz;
        let samples = duration_s * fs;
        if !(duration_s.is_finite() && duration_s >= 0.0 && samples <= MAX_SAMPLES) {
            return Err(StandsError::DurationS);
        }
        let samples = samples.round() as usize;
        let mut rng = StdRng::seed_from_u64(seed);
        let dt = 1.0 / fs;
        let walk = (TAU * self.settings.linewidth_hz * dt).sqrt();
        let common_hz = match self.regime {
            Regime::Synchronized(sync) => sync.common_hz,
            Regime::Independent => 0.0,
        };
        let stands = self.len();
        // Random initial phases: independent stands share nothing.
        let mut phases: Vec<f64> = (0..stands).map(|_| TAU * rng.random::<f64>()).collect();
        let mut reference_phase = TAU * rng.random::<f64>();
        let mut signals: Vec<Vec<f64>> = (0..stands).map(|_| Vec::with_capacity(samples)).collect();
        for k in 0..samples {
            let t_s = k as f64 * dt;
            let gain = self.coupling_gain(t_s);
            for (stand, (phase, signal)) in phases.iter_mut().zip(&mut signals).enumerate() {
                let noise: f64 = rng.sample(StandardNormal);
                signal
                    .push(self.settings.amplitude * phase.sin() + self.settings.noise_rms * noise);
                let frequency = self.frequency_hz(stand, t_s).unwrap_or(common_hz);
                let step: f64 = rng.sample(StandardNormal);
                let pull = gain * (reference_phase - *phase).sin();
                *phase = (*phase + (TAU * frequency + pull) * dt + walk * step).rem_euclid(TAU);
            }
            let step: f64 = rng.sample(StandardNormal);
            reference_phase =
                (reference_phase + TAU * common_hz * dt + walk * step).rem_euclid(TAU);
        }
        Ok(signals)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use millgate_dsp::chatter::pearson;

    const FS: f64 = 2500.0;
    const NATURAL_HZ: [f64; 5] = [150.0, 172.0, 196.0, 221.0, 248.0];

    fn settings() -> StandsSettings {
        StandsSettings {
            sample_rate_hz: FS,
            natural_hz: NATURAL_HZ.to_vec(),
            amplitude: 1.0,
            linewidth_hz: 0.5,
            noise_rms: 0.3,
        }
    }

    /// Magnitude of the mean of `signal * exp(-j 2 pi f t)`: about amplitude / 2 for
    /// a sine at `f`, near 0 for one far from it.
    fn dft_magnitude(signal: &[f64], f_hz: f64) -> f64 {
        let (mut re, mut im) = (0.0, 0.0);
        for (k, v) in signal.iter().enumerate() {
            let angle = TAU * f_hz * k as f64 / FS;
            re += v * angle.cos();
            im -= v * angle.sin();
        }
        re.hypot(im) / signal.len() as f64
    }

    fn mean_adjacent_correlation(signals: &[Vec<f64>], range: std::ops::Range<usize>) -> f64 {
        let pairs = signals.windows(2);
        let count = pairs.len() as f64;
        pairs
            .map(|pair| pearson(&pair[0][range.clone()], &pair[1][range.clone()]))
            .sum::<f64>()
            / count
    }

    #[test]
    fn independent_stands_sit_at_their_own_frequencies_uncorrelated() {
        let stands = Stands::new(settings(), Regime::Independent).unwrap();
        let signals = stands.generate(1.0, 11).unwrap();
        assert_eq!(signals.len(), 5);
        assert!(signals.iter().all(|s| s.len() == 2500));
        for (signal, own) in signals.iter().zip(NATURAL_HZ) {
            let at_own = dft_magnitude(&signal[..1250], own);
            let at_neighbour = dft_magnitude(&signal[..1250], own + 12.0);
            assert!(
                at_own > 0.3 && at_neighbour < 0.1,
                "{own} Hz: {at_own} vs {at_neighbour}"
            );
        }
        let k_mean = mean_adjacent_correlation(&signals, 0..2500);
        assert!(k_mean.abs() < 0.1, "K_mean {k_mean}");
    }

    #[test]
    fn synchronized_stands_pull_to_the_common_frequency_and_lock_phase() {
        let common = 187.0;
        let stands = Stands::new(settings(), Regime::synchronized(1.0, common)).unwrap();
        assert_eq!(stands.frequency_hz(0, 0.5), Some(150.0));
        let late = stands.frequency_hz(0, 4.0).unwrap();
        assert!((late - common).abs() < 0.01, "{late}");
        let signals = stands.generate(6.0, 12).unwrap();
        let before = mean_adjacent_correlation(&signals, 0..2500);
        let after = mean_adjacent_correlation(&signals, 12500..15000);
        assert!(before.abs() < 0.1, "before sync K_mean {before}");
        assert!(after > 0.6, "after sync K_mean {after}");
        for signal in &signals {
            let at_common = dft_magnitude(&signal[12500..15000], common);
            assert!(at_common > 0.3, "{at_common}");
        }
    }

    #[test]
    fn same_seed_same_record() {
        let stands = Stands::new(settings(), Regime::synchronized(0.1, 200.0)).unwrap();
        assert_eq!(stands.generate(0.2, 5), stands.generate(0.2, 5));
        assert_ne!(stands.generate(0.2, 5), stands.generate(0.2, 6));
    }

    #[test]
    fn invalid_settings_are_named() {
        let too_high = StandsSettings {
            natural_hz: vec![150.0, 1300.0],
            ..settings()
        };
        assert_eq!(
            Stands::new(too_high, Regime::Independent),
            Err(StandsError::NaturalHz)
        );
        let mut sync = Synchronization::new(1.0, 180.0);
        sync.pull_time_s = 0.0;
        assert_eq!(
            Stands::new(settings(), Regime::Synchronized(sync)),
            Err(StandsError::PullTimeS)
        );
        let stands = Stands::new(settings(), Regime::Independent).unwrap();
        assert_eq!(stands.generate(f64::NAN, 1), Err(StandsError::DurationS));
    }
}
