//! The transient features of the domain notes (TAF, periods, frequencies, decays,
//! asymmetry, delay), measured on the record and on a model's response.

use millgate_dsp::fit::{fit_eq1, FitOptions};
use millgate_dsp::transient::{analyze, TransientSettings};
use serde::Serialize;

use crate::wear_map::MAX_RECORD_SAMPLES;

/// Which transient feature (its unit is in its name).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum FeatureName {
    /// Torque amplification factor: peak / static torque.
    Taf,
    /// Peak torque, kN*m.
    PeakKnm,
    /// First oscillation period after the bite, s.
    FirstPeriodS,
    /// Second oscillation period, s.
    SecondPeriodS,
    /// Frequency of the second period minus that of the first, Hz.
    FrequencyDriftHz,
    /// First frequency of the eq. (1) fit, Hz.
    F1Hz,
    /// Second frequency of the eq. (1) fit, Hz.
    F2Hz,
    /// First decay rate of the eq. (1) fit, 1/s.
    Decay1PerS,
    /// Second decay rate of the eq. (1) fit, 1/s.
    Decay2PerS,
    /// Largest positive over largest negative excursion about the load rise.
    Asymmetry,
    /// Lag of the record behind the model over the load rise, s.
    DelayS,
}

keyed!(FeatureName);

impl FeatureName {
    /// The name used in JSON and reports.
    pub(crate) fn key(self) -> &'static str {
        match self {
            FeatureName::Taf => "taf",
            FeatureName::PeakKnm => "peak_knm",
            FeatureName::FirstPeriodS => "first_period_s",
            FeatureName::SecondPeriodS => "second_period_s",
            FeatureName::FrequencyDriftHz => "frequency_drift_hz",
            FeatureName::F1Hz => "f1_hz",
            FeatureName::F2Hz => "f2_hz",
            FeatureName::Decay1PerS => "decay1_per_s",
            FeatureName::Decay2PerS => "decay2_per_s",
            FeatureName::Asymmetry => "asymmetry",
            FeatureName::DelayS => "delay_s",
        }
    }
}

/// One transient feature of one bite, measured and modelled.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub(crate) struct Feature {
    /// The bite, 0-based in the order given.
    pub(crate) bite: usize,
    /// Which feature.
    pub(crate) name: FeatureName,
    /// Value in the measured record.
    pub(crate) measured: Option<f64>,
    /// Value in the model's response.
    pub(crate) model: Option<f64>,
}

/// The features of the domain notes for a measured record and a model response.
///
/// TAF and periods come from [`millgate_dsp::transient::analyze`] (periods low-passed at
/// `period_lowpass_hz`; the drift is the change of 1 / period from the first to the
/// second), frequencies and decays from the eq. (1) fit of
/// [`millgate_dsp::fit::fit_eq1`] on the record from the bite, asymmetry is the largest
/// positive excursion about the fitted load rise divided by the largest negative one,
/// and the delay is the lag (s) of the record behind the model that best aligns the
/// rise from the bite to the first peak.
pub(crate) fn compare(
    bite: usize,
    measured: &[f64],
    model: &[f64],
    sample_rate_hz: f64,
    onset_index: usize,
    period_lowpass_hz: f64,
) -> Vec<Feature> {
    let a = Features::of(measured, sample_rate_hz, onset_index, period_lowpass_hz);
    let b = Features::of(model, sample_rate_hz, onset_index, period_lowpass_hz);
    let delay = delay_s(measured, model, sample_rate_hz, onset_index);
    let pair = |name, x: Option<f64>, y: Option<f64>| Feature {
        bite,
        name,
        measured: x,
        model: y,
    };
    vec![
        pair(FeatureName::Taf, a.taf, b.taf),
        pair(FeatureName::PeakKnm, a.peak, b.peak),
        pair(FeatureName::FirstPeriodS, a.first_period, b.first_period),
        pair(FeatureName::SecondPeriodS, a.second_period, b.second_period),
        pair(
            FeatureName::FrequencyDriftHz,
            a.frequency_drift(),
            b.frequency_drift(),
        ),
        pair(FeatureName::F1Hz, a.f1, b.f1),
        pair(FeatureName::F2Hz, a.f2, b.f2),
        pair(FeatureName::Decay1PerS, a.decay1, b.decay1),
        pair(FeatureName::Decay2PerS, a.decay2, b.decay2),
        pair(FeatureName::Asymmetry, a.asymmetry, b.asymmetry),
        pair(FeatureName::DelayS, delay, Some(0.0)),
    ]
}

/// The features of one series.
#[derive(Debug, Default)]
struct Features {
    taf: Option<f64>,
    peak: Option<f64>,
    first_period: Option<f64>,
    second_period: Option<f64>,
    f1: Option<f64>,
    f2: Option<f64>,
    decay1: Option<f64>,
    decay2: Option<f64>,
    asymmetry: Option<f64>,
}

impl Features {
    /// Frequency drift with amplitude, Hz: the frequency of the second oscillation
    /// period (smaller amplitude) minus that of the first (larger). A softening gap
    /// gives a positive drift, hardening a negative one, a linear chain about 0.
    fn frequency_drift(&self) -> Option<f64> {
        Some(1.0 / self.second_period? - 1.0 / self.first_period?)
    }

    fn of(
        series: &[f64],
        sample_rate_hz: f64,
        onset_index: usize,
        period_lowpass_hz: f64,
    ) -> Features {
        let mut features = Features::default();
        let window = &series[..series.len().min(MAX_RECORD_SAMPLES)];
        let settings = TransientSettings {
            sample_rate_hz,
            period_lowpass_hz,
            peak_lowpass_hz: None,
            settled_fraction: 0.3,
            min_static_knm: f64::MIN_POSITIVE,
            reference_shift_s: None,
        };
        if let Ok(result) = analyze::<MAX_RECORD_SAMPLES>(window, onset_index, 0.0, &settings) {
            features.taf = result.taf;
            features.peak = Some(result.peak_torque_knm);
            features.first_period = result.first_period_s;
            features.second_period = result.second_period_s;
        }
        let after = &series[onset_index.min(series.len())..];
        if let Ok(fit) = fit_eq1(after, &FitOptions::new(sample_rate_hz)) {
            features.f1 = Some(fit.f1_hz);
            features.f2 = Some(fit.f2_hz);
            features.decay1 = Some(fit.decay1_per_s);
            features.decay2 = Some(fit.decay2_per_s);
            let (a9, a10) = (fit.params[8], fit.params[9]);
            let (high, low) =
                after
                    .iter()
                    .enumerate()
                    .fold((0.0_f64, 0.0_f64), |(hi, lo), (k, v)| {
                        let trend = a9 * (1.0 - (-a10 * k as f64 / sample_rate_hz).exp());
                        (hi.max(v - trend), lo.min(v - trend))
                    });
            if low < 0.0 {
                features.asymmetry = Some(high / -low);
            }
        }
        features
    }
}

/// Lag of `measured` behind `model` (s) over the rise from the bite to the model's first
/// peak: the integer lag with the least squared difference, refined by a parabola.
fn delay_s(
    measured: &[f64],
    model: &[f64],
    sample_rate_hz: f64,
    onset_index: usize,
) -> Option<f64> {
    let n = measured.len().min(model.len());
    let rise = &model[onset_index.min(n)..n];
    let peak = rise.iter().enumerate().max_by(|a, b| a.1.total_cmp(b.1))?.0;
    let end = onset_index + peak.max(4);
    let max_lag = (end - onset_index) / 2;
    let cost = |lag: isize| -> f64 {
        (onset_index..end)
            .map(|k| {
                let j = (k as isize + lag).clamp(0, n as isize - 1) as usize;
                (measured[j] - model[k]).powi(2)
            })
            .sum()
    };
    let lags: Vec<isize> = (-(max_lag as isize)..=max_lag as isize).collect();
    let (best, _) = lags
        .iter()
        .map(|&l| (l, cost(l)))
        .min_by(|a, b| a.1.total_cmp(&b.1))?;
    let (left, mid, right) = (cost(best - 1), cost(best), cost(best + 1));
    let curvature = left - 2.0 * mid + right;
    let offset = if curvature > 0.0 {
        (0.5 * (left - right) / curvature).clamp(-0.5, 0.5)
    } else {
        0.0
    };
    Some((best as f64 + offset) / sample_rate_hz)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn delay_of_a_shifted_rise_is_found_to_a_fraction_of_a_sample() {
        let fs = 2000.0;
        let curve = |t: f64| {
            if t > 0.05 {
                100.0 * (1.0 - (-(t - 0.05) * 30.0).exp()) * (1.0 + 0.5 * ((t - 0.05) * 60.0).sin())
            } else {
                0.0
            }
        };
        let model: Vec<f64> = (0..1000).map(|k| curve(k as f64 / fs)).collect();
        let measured: Vec<f64> = (0..1000).map(|k| curve(k as f64 / fs - 0.0042)).collect();
        let delay = delay_s(&measured, &model, fs, 100).unwrap();
        assert!((delay - 0.0042).abs() < 2.5e-4, "delay {delay}");
    }
}
