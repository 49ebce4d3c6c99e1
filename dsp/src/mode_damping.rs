//! Output-only damping of the chatter mode in one window: the matrix-pencil poles
//! ([`crate::pencil::poles`]) of a stand's chatter-band signal, and the least damped
//! one inside the band.
//!
//! A mode's damping ratio falls to zero at the stability limit, so it is the textbook
//! early warning; what a window of a few tenths of a second can see is the damping of
//! the stand's structural mode, a few percent. (In `sim::tandem` the roots that cross
//! first form a chain spaced by the inverse transport delay, far narrower than a short
//! window resolves: the evaluation in `tests/tests/chatter_eval.rs` measures what this
//! estimate is worth there.)

use crate::pencil::{poles, PencilError, Pole};

/// The least damped pole of `band_signal` with a frequency in `band_hz`, and its damping
/// ratio `decay / sqrt(decay^2 + (2 pi f)^2)`; `None` if no pole is in the band.
///
/// `band_signal` is a stand's window after a band-pass (e.g. [`crate::band_gain`]'s
/// chatter band), uniform at `sample_rate_hz`; `decimation` >= 1 (boxcar averaging,
/// keep `sample_rate_hz / decimation` above 2.5x the band's upper edge).
pub fn least_damped(
    band_signal: &[f64],
    sample_rate_hz: f64,
    decimation: usize,
    band_hz: (f64, f64),
) -> Result<Option<(Pole, f64)>, PencilError> {
    let found = poles(band_signal, sample_rate_hz, decimation)?;
    Ok(found
        .iter()
        .filter(|p| (band_hz.0..=band_hz.1).contains(&p.frequency_hz))
        .map(|p| {
            let omega = core::f64::consts::TAU * p.frequency_hz;
            (
                *p,
                p.decay_per_s / libm::sqrt(p.decay_per_s * p.decay_per_s + omega * omega),
            )
        })
        .min_by(|a, b| a.1.total_cmp(&b.1)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_decaying_sine_gives_its_damping_ratio() {
        let fs = 2500.0;
        let (f, zeta) = (180.0, 0.02);
        let omega = core::f64::consts::TAU * f;
        let decay = zeta * omega / libm::sqrt(1.0 - zeta * zeta);
        let mut samples = [0.0; 1250];
        for (k, s) in samples.iter_mut().enumerate() {
            let t = k as f64 / fs;
            *s = libm::exp(-decay * t) * libm::sin(omega * libm::sqrt(1.0 - zeta * zeta) * t);
        }
        let (pole, ratio) = least_damped(&samples, fs, 1, (100.0, 300.0))
            .unwrap()
            .unwrap();
        assert!(
            (pole.frequency_hz - f * libm::sqrt(1.0 - zeta * zeta)).abs() < 0.05,
            "{pole:?}"
        );
        assert!((ratio - zeta).abs() < 1e-3, "{ratio}");
        assert_eq!(least_damped(&samples, fs, 1, (400.0, 600.0)).unwrap(), None);
    }
}
