//! Biquad (second-order IIR) sections and cascades: Butterworth low- and high-pass by
//! the bilinear transform with the cutoff prewarped, so the -3 dB point is exact.
//!
//! Coefficients (`Biquad`, [`Cascade`]) are built once and shared; the state
//! ([`BiquadState`], one per section) is what the hot path mutates. Direct form I:
//! `y = b0 x + b1 x1 + b2 x2 - a1 y1 - a2 y2`.

use core::f64::consts::PI;

/// Invalid filter settings; the variant names the field at fault.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FilterError {
    /// The sample rate is not finite and > 0.
    SampleRateHz,
    /// The cutoff is not finite, > 0 and below half the sample rate.
    CutoffHz,
    /// The quality factor is not finite and > 0.
    Q,
}

impl core::fmt::Display for FilterError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            FilterError::SampleRateHz => "sample_rate_hz must be finite and > 0",
            FilterError::CutoffHz => "cutoff_hz must be finite, > 0 and below half the sample rate",
            FilterError::Q => "q must be finite and > 0",
        })
    }
}

impl core::error::Error for FilterError {}

/// Coefficients of one second-order section (a0 normalised to 1).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Biquad {
    b0: f64,
    b1: f64,
    b2: f64,
    a1: f64,
    a2: f64,
}

/// State of one `Biquad`: the last two inputs and outputs.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct BiquadState {
    x1: f64,
    x2: f64,
    y1: f64,
    y2: f64,
}

/// Quality factor of section `k` (0-based) of a Butterworth filter of order
/// `2 * sections`: `1 / (2 cos((2k + 1) pi / (4 sections)))`.
pub(crate) fn butterworth_q(sections: usize, k: usize) -> f64 {
    let angle = (2 * k + 1) as f64 * PI / (4 * sections.max(1)) as f64;
    0.5 / libm::cos(angle)
}

impl Biquad {
    /// Low-pass with -3 dB at `cutoff_hz` for `q = 1 / sqrt(2)` (Butterworth section).
    pub(crate) fn lowpass(
        cutoff_hz: f64,
        sample_rate_hz: f64,
        q: f64,
    ) -> Result<Self, FilterError> {
        let k = prewarp(cutoff_hz, sample_rate_hz, q)?;
        let norm = 1.0 / (1.0 + k / q + k * k);
        let b0 = k * k * norm;
        Ok(Self {
            b0,
            b1: 2.0 * b0,
            b2: b0,
            a1: 2.0 * (k * k - 1.0) * norm,
            a2: (1.0 - k / q + k * k) * norm,
        })
    }

    /// High-pass with -3 dB at `cutoff_hz` for `q = 1 / sqrt(2)` (Butterworth section).
    pub(crate) fn highpass(
        cutoff_hz: f64,
        sample_rate_hz: f64,
        q: f64,
    ) -> Result<Self, FilterError> {
        let k = prewarp(cutoff_hz, sample_rate_hz, q)?;
        let norm = 1.0 / (1.0 + k / q + k * k);
        Ok(Self {
            b0: norm,
            b1: -2.0 * norm,
            b2: norm,
            a1: 2.0 * (k * k - 1.0) * norm,
            a2: (1.0 - k / q + k * k) * norm,
        })
    }

    /// One output sample.
    #[inline]
    pub(crate) fn process(&self, state: &mut BiquadState, x: f64) -> f64 {
        let y = self.b0 * x + self.b1 * state.x1 + self.b2 * state.x2
            - self.a1 * state.y1
            - self.a2 * state.y2;
        state.x2 = state.x1;
        state.x1 = x;
        state.y2 = state.y1;
        state.y1 = y;
        y
    }

    /// Zero-phase filtering in place: forward, then backward, each pass started in the
    /// steady state of its first sample (no start-up transient; unit DC gain kept).
    pub(crate) fn filtfilt(&self, data: &mut [f64]) {
        let pass = |samples: &mut dyn Iterator<Item = &mut f64>| {
            let mut state = None;
            for sample in samples {
                let state = state.get_or_insert_with(|| self.settled(*sample));
                *sample = self.process(state, *sample);
            }
        };
        pass(&mut data.iter_mut());
        pass(&mut data.iter_mut().rev());
    }

    /// The state of a filter that has seen the constant `x` forever (no start-up
    /// transient for a signal starting at `x`).
    pub(crate) fn settled(&self, x: f64) -> BiquadState {
        let gain = (self.b0 + self.b1 + self.b2) / (1.0 + self.a1 + self.a2);
        BiquadState {
            x1: x,
            x2: x,
            y1: gain * x,
            y2: gain * x,
        }
    }
}

fn prewarp(cutoff_hz: f64, sample_rate_hz: f64, q: f64) -> Result<f64, FilterError> {
    if !(sample_rate_hz.is_finite() && sample_rate_hz > 0.0) {
        return Err(FilterError::SampleRateHz);
    }
    if !(cutoff_hz.is_finite() && cutoff_hz > 0.0 && cutoff_hz < 0.5 * sample_rate_hz) {
        return Err(FilterError::CutoffHz);
    }
    if !(q.is_finite() && q > 0.0) {
        return Err(FilterError::Q);
    }
    Ok(libm::tan(PI * cutoff_hz / sample_rate_hz))
}

/// `N` biquads in series.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Cascade<const N: usize> {
    sections: [Biquad; N],
}

impl<const N: usize> Cascade<N> {
    /// Butterworth low-pass of order `2 N`, -3 dB at `cutoff_hz`.
    pub fn butterworth_lowpass(cutoff_hz: f64, sample_rate_hz: f64) -> Result<Self, FilterError> {
        let mut sections = [Biquad::lowpass(cutoff_hz, sample_rate_hz, 0.5)?; N];
        for (k, section) in sections.iter_mut().enumerate() {
            *section = Biquad::lowpass(cutoff_hz, sample_rate_hz, butterworth_q(N, k))?;
        }
        Ok(Self { sections })
    }

    /// Butterworth high-pass of order `2 N`, -3 dB at `cutoff_hz`.
    pub(crate) fn butterworth_highpass(
        cutoff_hz: f64,
        sample_rate_hz: f64,
    ) -> Result<Self, FilterError> {
        let mut sections = [Biquad::highpass(cutoff_hz, sample_rate_hz, 0.5)?; N];
        for (k, section) in sections.iter_mut().enumerate() {
            *section = Biquad::highpass(cutoff_hz, sample_rate_hz, butterworth_q(N, k))?;
        }
        Ok(Self { sections })
    }

    /// One output sample through every section.
    #[inline]
    pub fn process(&self, state: &mut [BiquadState; N], x: f64) -> f64 {
        self.sections
            .iter()
            .zip(state.iter_mut())
            .fold(x, |value, (section, state)| section.process(state, value))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Gain of a cascade at `f_hz`, measured on a long sine after the transient.
    fn gain<const N: usize>(cascade: &Cascade<N>, f_hz: f64, fs: f64) -> f64 {
        let mut state = [BiquadState::default(); N];
        let (mut peak_in, mut peak_out) = (0.0_f64, 0.0_f64);
        for i in 0..20_000 {
            let x = libm::sin(2.0 * PI * f_hz * i as f64 / fs);
            let y = cascade.process(&mut state, x);
            if i > 10_000 {
                peak_in = peak_in.max(x.abs());
                peak_out = peak_out.max(y.abs());
            }
        }
        peak_out / peak_in
    }

    #[test]
    fn butterworth_magnitude_matches_the_analog_prototype_after_prewarping() {
        let fs = 2500.0;
        let low = Cascade::<2>::butterworth_lowpass(300.0, fs).unwrap();
        let high = Cascade::<2>::butterworth_highpass(100.0, fs).unwrap();
        // |H| of an order-4 Butterworth at the prewarped analog frequency.
        let analog = |f: f64, fc: f64| {
            let warp = |f: f64| libm::tan(PI * f / fs);
            let ratio = warp(f) / warp(fc);
            1.0 / libm::sqrt(1.0 + libm::pow(ratio, 8.0))
        };
        for f in [50.0, 150.0, 300.0, 450.0, 800.0] {
            let expected = analog(f, 300.0);
            assert!(
                (gain(&low, f, fs) - expected).abs() < 2e-3,
                "low-pass at {f}"
            );
        }
        for f in [30.0, 100.0, 200.0, 600.0] {
            let warp = |f: f64| libm::tan(PI * f / fs);
            let ratio = warp(100.0) / warp(f);
            let expected = 1.0 / libm::sqrt(1.0 + libm::pow(ratio, 8.0));
            assert!(
                (gain(&high, f, fs) - expected).abs() < 2e-3,
                "high-pass at {f}"
            );
        }
        assert!((butterworth_q(1, 0) - core::f64::consts::FRAC_1_SQRT_2).abs() < 1e-12);
    }

    #[test]
    fn settled_state_passes_a_constant_without_transient() {
        let section = Biquad::lowpass(10.0, 1000.0, 0.7).unwrap();
        let mut state = section.settled(3.0);
        for _ in 0..10 {
            assert!((section.process(&mut state, 3.0) - 3.0).abs() < 1e-12);
        }
    }

    #[test]
    fn filtfilt_keeps_a_constant_and_cuts_high_frequency() {
        let filter = Biquad::lowpass(10.0, 1000.0, core::f64::consts::FRAC_1_SQRT_2).unwrap();
        let mut constant = [5.0; 200];
        filter.filtfilt(&mut constant);
        assert!(constant.iter().all(|v| (v - 5.0).abs() < 1e-9));
        let mut fast = [0.0; 400];
        for (i, v) in fast.iter_mut().enumerate() {
            *v = libm::sin(2.0 * PI * 200.0 * i as f64 / 1000.0);
        }
        filter.filtfilt(&mut fast);
        assert!(fast[100..300].iter().all(|v| v.abs() < 0.01));
    }

    #[test]
    fn invalid_settings_are_named() {
        assert_eq!(
            Biquad::lowpass(1500.0, 2500.0, 0.7),
            Err(FilterError::CutoffHz)
        );
        assert_eq!(
            Biquad::lowpass(10.0, 0.0, 0.7),
            Err(FilterError::SampleRateHz)
        );
        assert_eq!(Biquad::highpass(10.0, 100.0, 0.0), Err(FilterError::Q));
    }
}
