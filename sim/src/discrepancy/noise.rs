//! The noise level of a record, from the data alone.

/// White-noise RMS of a record from its fourth differences.
///
/// The fourth difference `y[k] - 4 y[k+1] + 6 y[k+2] - 4 y[k+3] + y[k+4]` multiplies
/// white noise's variance by 70 and a sine of frequency f by `(2 sin(pi f / fs))^4`:
/// 2e-5 for a 21 Hz mode at 2 kHz, so even a 100 kN*m oscillation leaves only 2e-3 kN*m.
/// The median absolute value (1.4826 MAD for a Gaussian) ignores the few samples where a
/// fast transient or a spike dominates.
pub fn noise_rms(samples: &[f64]) -> f64 {
    if samples.len() < 5 {
        return 0.0;
    }
    let mut differences: Vec<f64> = samples
        .windows(5)
        .map(|w| (w[0] - 4.0 * w[1] + 6.0 * w[2] - 4.0 * w[3] + w[4]).abs())
        .collect();
    let middle = differences.len() / 2;
    let (_, median, _) = differences.select_nth_unstable_by(middle, f64::total_cmp);
    1.4826 * *median / 70.0_f64.sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{rngs::StdRng, Rng, SeedableRng};
    use rand_distr::StandardNormal;

    #[test]
    fn noise_estimate_ignores_the_driveline_modes() {
        let mut rng = StdRng::seed_from_u64(7);
        let fs = 2000.0;
        let series: Vec<f64> = (0..1200)
            .map(|k| {
                let t = k as f64 / fs;
                let clean =
                    112.0 + 80.0 * (-5.0 * t).exp() * (std::f64::consts::TAU * 21.0 * t).sin();
                let unit: f64 = rng.sample(StandardNormal);
                clean + 0.5 * unit
            })
            .collect();
        let estimate = noise_rms(&series);
        assert!((estimate / 0.5 - 1.0).abs() < 0.1, "estimate {estimate}");
    }
}
