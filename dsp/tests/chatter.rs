//! Chatter conditions on synthetic stands: a shared frequency locks them, independent
//! frequencies do not.

use millgate_dsp::chatter::{ChatterDetector, ChatterSettings, StandWindow};
use rand::rngs::StdRng;
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};
use rustfft::num_complex::Complex;
use rustfft::FftPlanner;
use std::f64::consts::PI;

const FS: f64 = 2048.0;
const LEN: usize = 2048;
const STANDS: usize = 5;

/// Hann-windowed magnitude spectrum (bins 0..LEN/2).
fn magnitude(signal: &[f64]) -> Vec<f64> {
    let mut buffer: Vec<Complex<f64>> = signal
        .iter()
        .enumerate()
        .map(|(i, &v)| {
            let w = 0.5 - 0.5 * (2.0 * PI * i as f64 / LEN as f64).cos();
            Complex::new(v * w, 0.0)
        })
        .collect();
    FftPlanner::new().plan_fft_forward(LEN).process(&mut buffer);
    buffer[..LEN / 2].iter().map(|c| c.norm()).collect()
}

/// Stand signals: sine at `frequencies[i]` with phase `phases[i]` plus noise.
fn stands(frequencies: &[f64], phases: &[f64], seed: u64) -> Vec<Vec<f64>> {
    let mut rng = StdRng::seed_from_u64(seed);
    let noise = Normal::new(0.0, 0.5).unwrap();
    frequencies
        .iter()
        .zip(phases)
        .map(|(&f, &p)| {
            (0..LEN)
                .map(|i| (2.0 * PI * f * i as f64 / FS + p).sin() + noise.sample(&mut rng))
                .collect()
        })
        .collect()
}

fn evaluate(signals: &[Vec<f64>]) -> millgate_dsp::chatter::ChatterResult {
    let detector = ChatterDetector::new(ChatterSettings {
        band_low_hz: 100.0,
        band_high_hz: 300.0,
        k_max: 0.3,
    })
    .unwrap();
    let spectra: Vec<Vec<f64>> = signals.iter().map(|s| magnitude(s)).collect();
    let windows: Vec<StandWindow<'_>> = spectra
        .iter()
        .zip(signals)
        .map(|(m, s)| StandWindow {
            magnitude: m,
            signal: s,
        })
        .collect();
    detector.evaluate(&windows, FS / LEN as f64).unwrap()
}

#[test]
fn shared_frequency_in_phase_is_synchronized() {
    let result = evaluate(&stands(&[180.3; STANDS], &[0.1; STANDS], 3));
    println!(
        "shared: sigma_n {:.3} Hz (min {:.3}), K_mean {:.3}",
        result.sigma_n_hz, result.sigma_min_hz, result.k_mean
    );
    for stand in &result.stands {
        assert!((stand.principal_hz - 180.3).abs() < 0.2, "{stand:?}");
    }
    assert!(result.frequencies_locked && result.correlated && result.synchronized);
}

#[test]
fn independent_frequencies_are_not_synchronized() {
    let frequencies = [150.0, 172.5, 195.0, 221.0, 260.0];
    let phases = [0.0, 1.0, 2.0, 3.0, 4.0];
    let result = evaluate(&stands(&frequencies, &phases, 4));
    println!(
        "independent: sigma_n {:.3} Hz, K_mean {:.3}",
        result.sigma_n_hz, result.k_mean
    );
    for (stand, f) in result.stands.iter().zip(frequencies) {
        assert!((stand.principal_hz - f).abs() < 0.2, "{stand:?}");
    }
    assert!(!result.frequencies_locked && !result.correlated && !result.synchronized);
}

#[test]
fn shared_frequency_with_random_phases_locks_frequency_only() {
    // Same frequency, phases in quadrature or opposite: correlation averages low.
    let phases = [0.0, PI / 2.0, PI, 3.0 * PI / 2.0, 2.0 * PI];
    let result = evaluate(&stands(&[180.3; STANDS], &phases, 5));
    assert!(result.frequencies_locked);
    assert!(!result.correlated && !result.synchronized, "{result:?}");
}
