//! The noise level of a record (`millgate_dsp::noise::noise_rms`) against independent
//! computations: numpy on a fixed record, closed forms on known signals, a sorted
//! copy's median on random records, and the RMS of seeded Gaussian noise.

use millgate_dsp::noise::noise_rms;
use millgate_dsp::testing::assert_isclose;
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use rand_distr::StandardNormal;

/// 1.4826 / sqrt(70): the estimate per unit median absolute fourth difference.
fn per_median() -> f64 {
    1.4826 / 70.0_f64.sqrt()
}

/// A decaying 21 Hz-like oscillation on a static level, hashed uniform noise of
/// +-0.4 and a 50-unit spike every 97 samples; the same formula as in `numpy_record`.
fn spiky_record(n: usize) -> Vec<f64> {
    (0..n)
        .map(|k| {
            let t = k as f64;
            let hashed = ((k as u64 * 2_654_435_761) % (1 << 32)) as f64 / 4_294_967_296.0 - 0.5;
            let spike = if k % 97 == 0 { 50.0 } else { 0.0 };
            120.0 + 40.0 * (-t / 300.0).exp() * (0.066 * t).sin() + 0.8 * hashed + spike
        })
        .collect()
}

#[test]
fn matches_numpy_on_a_record_with_spikes() {
    // numpy 2.4: n = 1001; k = np.arange(n);
    // hashed = np.array([(i * 2654435761) % 2**32 for i in range(n)]) / 2**32 - 0.5
    // x = 120 + 40 * np.exp(-k / 300) * np.sin(0.066 * k) + 0.8 * hashed
    //     + np.where(k % 97 == 0, 50.0, 0.0)
    // 1.4826 * np.median(np.abs(np.diff(x, 4))) / np.sqrt(70)
    // (997 differences, an odd count: the median is the middle one either way.)
    const NUMPY: f64 = 0.425_296_300_854_253_85;
    assert_isclose(
        noise_rms(&spiky_record(1001)),
        NUMPY,
        1e-9,
        0.0,
        "noise_rms",
    );
}

#[test]
fn alternating_signal_on_a_cubic_trend_is_the_closed_form() {
    // The fourth difference of a (-1)^k is +-16 a; of a cubic, 0.
    for (a, n) in [(0.5, 5), (0.5, 6), (2.0, 101), (1e-3, 1000)] {
        let record: Vec<f64> = (0..n)
            .map(|k| {
                let t = k as f64;
                let alternating = if k % 2 == 0 { a } else { -a };
                0.002 * t * t * t - 0.3 * t * t + 7.0 + alternating
            })
            .collect();
        let expected = 16.0 * a * per_median();
        assert_isclose(noise_rms(&record), expected, 1e-8, 0.0, "alternating");
    }
}

#[test]
fn sine_is_its_fourth_difference_gain_times_the_median_of_a_sine() {
    // Delta^4 sin(w k) = (2 sin(w / 2))^4 sin(w (k + 2)); the median of |sin| over
    // equidistributed phases is sin(pi / 4).
    let (amplitude, w) = (3.0, 0.9);
    let record: Vec<f64> = (0..20_000)
        .map(|k| amplitude * (w * k as f64).sin())
        .collect();
    let gain = (2.0 * (w / 2.0).sin()).powi(4);
    let expected = amplitude * gain * std::f64::consts::FRAC_1_SQRT_2 * per_median();
    assert_isclose(noise_rms(&record), expected, 1e-3, 0.0, "sine");
}

#[test]
fn is_the_median_of_a_sorted_copy_bit_for_bit() {
    let mut rng = StdRng::seed_from_u64(36);
    for case in 0..200 {
        // Short records, and some of a bite window's length (the selection then
        // gathers a few candidates after the top bytes).
        let n = 5 + case * 7 % 400 + if case % 4 == 0 { 1500 } else { 0 };
        let mut record: Vec<f64> = (0..n)
            .map(|_| {
                let value: f64 = rng.sample(StandardNormal);
                // Ties and exact zeros as well as spread values.
                if rng.random_bool(0.2) {
                    (value * 4.0).round()
                } else {
                    value * 10f64.powi(rng.random_range(-6..6))
                }
            })
            .collect();
        if case % 5 == 0 {
            let at = rng.random_range(0..n);
            record[at] = [f64::INFINITY, f64::NEG_INFINITY, f64::NAN][case % 3];
        }
        let mut magnitudes: Vec<f64> = record
            .windows(5)
            .map(|w| (w[0] - 4.0 * w[1] + 6.0 * w[2] - 4.0 * w[3] + w[4]).abs())
            .collect();
        magnitudes.sort_by(f64::total_cmp);
        let expected = 1.4826 * magnitudes[magnitudes.len() / 2] / 70.0_f64.sqrt();
        let estimate = noise_rms(&record);
        assert_eq!(
            estimate.to_bits(),
            expected.to_bits(),
            "case {case}: {estimate} != {expected}"
        );
    }
}

#[test]
fn estimate_of_gaussian_noise_ignores_the_driveline_modes() {
    let mut rng = StdRng::seed_from_u64(7);
    let fs = 2000.0;
    let series: Vec<f64> = (0..1200)
        .map(|k| {
            let t = k as f64 / fs;
            let clean = 112.0 + 80.0 * (-5.0 * t).exp() * (std::f64::consts::TAU * 21.0 * t).sin();
            let unit: f64 = rng.sample(StandardNormal);
            clean + 0.5 * unit
        })
        .collect();
    let estimate = noise_rms(&series);
    assert!((estimate / 0.5 - 1.0).abs() < 0.1, "estimate {estimate}");
}

#[test]
fn fewer_than_five_samples_give_zero() {
    for n in 0..5 {
        assert_eq!(noise_rms(&vec![1.0; n]), 0.0);
    }
    // One difference, 6.
    let single = noise_rms(&[0.0, 0.0, 1.0, 0.0, 0.0]);
    assert_isclose(single, 6.0 * per_median(), 1e-15, 0.0, "one difference");
}
