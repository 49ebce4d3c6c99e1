//! What the data say on their own (noise level) and where and how a model's response
//! departs from them (disagreement windows and features).

use millgate_dsp::fit::{fit_eq1, FitOptions};
use millgate_dsp::transient::{analyze, TransientSettings};
use serde::Serialize;

use crate::wear_map::MAX_RECORD_SAMPLES;

/// A residual window counts as disagreement when its RMS exceeds the noise by this factor.
///
/// Over the [`WINDOW_S`] window (50 samples at 2 kHz) the RMS of pure white noise
/// scatters by about 1 / sqrt(2 * 50) = 10%, so 1.5x the noise is five of those
/// deviations away: noise alone does not reach it.
pub const DISAGREEMENT_FACTOR: f64 = 1.5;

/// Length of the moving-RMS window, s (at least 20 samples are used).
pub const WINDOW_S: f64 = 0.025;

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

/// One stretch of time where the model's residual exceeds the noise.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Disagreement {
    /// Start, s (the record's time base).
    pub t_start_s: f64,
    /// End, s.
    pub t_end_s: f64,
    /// What differs most there: `delay`, `peak`, `first_period`, `amplitude` or `phase`.
    pub feature: &'static str,
    /// RMS of the residual over the window, kN*m.
    pub residual_rms: f64,
}

/// One transient feature, measured and modelled.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Feature {
    /// `taf`, `peak_knm`, `first_period_s`, `second_period_s`, `frequency_drift_hz`,
    /// `f1_hz`, `f2_hz`, `decay1_per_s`, `decay2_per_s`, `asymmetry`, `delay_s`.
    pub name: &'static str,
    /// Value in the measured record.
    pub measured: Option<f64>,
    /// Value in the model's response.
    pub model: Option<f64>,
}

/// Windows where the moving RMS of `measured - model` exceeds
/// [`DISAGREEMENT_FACTOR`] times `noise` (windows closer than one window length are
/// merged), each labelled with the feature that differs there.
///
/// `onset_index` is the bite, `period_samples` the first oscillation period (samples).
pub fn disagreements(
    measured: &[f64],
    model: &[f64],
    noise: f64,
    t0_s: f64,
    sample_rate_hz: f64,
    onset_index: usize,
    period_samples: usize,
) -> Vec<Disagreement> {
    let n = measured.len().min(model.len());
    let width = ((WINDOW_S * sample_rate_hz).round() as usize)
        .max(20)
        .min(n.max(1));
    let residual: Vec<f64> = (0..n).map(|k| measured[k] - model[k]).collect();
    let threshold = (DISAGREEMENT_FACTOR * noise).powi(2);
    // Centred moving mean of the squared residual, by a running sum.
    let mut flagged = vec![false; n];
    let mut sum: f64 = residual[..width].iter().map(|r| r * r).sum();
    for start in 0..=n - width {
        if start > 0 {
            sum += residual[start + width - 1].powi(2) - residual[start - 1].powi(2);
        }
        if sum / width as f64 > threshold {
            flagged[start..start + width]
                .iter_mut()
                .for_each(|f| *f = true);
        }
    }
    let mut windows: Vec<(usize, usize)> = Vec::new();
    let mut k = 0;
    while k < n {
        if !flagged[k] {
            k += 1;
            continue;
        }
        let start = k;
        while k < n && flagged[k] {
            k += 1;
        }
        match windows.last_mut() {
            Some(last) if start - last.1 < width => last.1 = k,
            _ => windows.push((start, k)),
        }
    }
    let peak_index = onset_index
        + measured[onset_index.min(n)..n]
            .iter()
            .enumerate()
            .max_by(|a, b| a.1.total_cmp(b.1))
            .map_or(0, |(i, _)| i);
    windows
        .into_iter()
        .map(|(start, end)| {
            let rms = (residual[start..end].iter().map(|r| r * r).sum::<f64>()
                / (end - start) as f64)
                .sqrt();
            // Labelled where the residual is largest, not where the window starts: a
            // window from the load rise through the peak is about the peak when the
            // residual is largest there.
            let focus = start
                + residual[start..end]
                    .iter()
                    .enumerate()
                    .max_by(|a, b| a.1.abs().total_cmp(&b.1.abs()))
                    .map_or(0, |(i, _)| i);
            let feature = if focus < onset_index + period_samples / 8 {
                "delay"
            } else if focus.abs_diff(peak_index) <= period_samples / 8 {
                "peak"
            } else if focus < onset_index + period_samples * 2 {
                "first_period"
            } else if amplitude_explains(&measured[start..end], &model[start..end], period_samples)
            {
                "amplitude"
            } else {
                "phase"
            };
            Disagreement {
                t_start_s: t0_s + start as f64 / sample_rate_hz,
                t_end_s: t0_s + end as f64 / sample_rate_hz,
                feature,
                residual_rms: rms,
            }
        })
        .collect()
}

/// Whether scaling the model's oscillation about its mean explains more of the window's
/// residual than shifting it does, by up to half an oscillation period
/// (`period_samples`; a longer shift would match a decaying oscillation to an earlier,
/// larger cycle) and a quarter of the window.
fn amplitude_explains(measured: &[f64], model: &[f64], period_samples: usize) -> bool {
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    let (mm, ml) = (mean(measured), mean(model));
    let a: Vec<f64> = measured.iter().map(|v| v - mm).collect();
    let b: Vec<f64> = model.iter().map(|v| v - ml).collect();
    let bb: f64 = b.iter().map(|v| v * v).sum();
    if bb <= 0.0 {
        return true;
    }
    let scale = a.iter().zip(&b).map(|(x, y)| x * y).sum::<f64>() / bb;
    let scaled: f64 = a.iter().zip(&b).map(|(x, y)| (x - scale * y).powi(2)).sum();
    let max_shift = (b.len() / 4).min(period_samples / 2);
    let shifted = (1..=max_shift)
        .flat_map(|s| [s as isize, -(s as isize)])
        .map(|s| {
            let pairs = (0..a.len()).filter_map(|i| {
                let j = i as isize + s;
                (j >= 0 && (j as usize) < b.len()).then(|| (a[i], b[j as usize]))
            });
            let (sum, count) =
                pairs.fold((0.0, 0), |(sum, c), (x, y)| (sum + (x - y).powi(2), c + 1));
            sum / count.max(1) as f64 * a.len() as f64
        })
        .fold(f64::INFINITY, f64::min);
    scaled <= shifted
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
pub fn compare(
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
        name,
        measured: x,
        model: y,
    };
    vec![
        pair("taf", a.taf, b.taf),
        pair("peak_knm", a.peak, b.peak),
        pair("first_period_s", a.first_period, b.first_period),
        pair("second_period_s", a.second_period, b.second_period),
        pair(
            "frequency_drift_hz",
            a.frequency_drift(),
            b.frequency_drift(),
        ),
        pair("f1_hz", a.f1, b.f1),
        pair("f2_hz", a.f2, b.f2),
        pair("decay1_per_s", a.decay1, b.decay1),
        pair("decay2_per_s", a.decay2, b.decay2),
        pair("asymmetry", a.asymmetry, b.asymmetry),
        pair("delay_s", delay, Some(0.0)),
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

    #[test]
    fn a_local_departure_is_one_window_at_its_place() {
        let fs = 2000.0;
        let model = vec![0.0; 1000];
        let mut measured = vec![0.0; 1000];
        for (k, value) in measured.iter_mut().enumerate() {
            // +-0.1 alternating "noise", and a 5 kN*m bump between samples 600 and 650.
            *value = if k % 2 == 0 { 0.1 } else { -0.1 }
                + if (600..650).contains(&k) { 5.0 } else { 0.0 };
        }
        let windows = disagreements(&measured, &model, 0.1, 0.0, fs, 100, 200);
        assert_eq!(windows.len(), 1, "{windows:?}");
        assert!(
            windows[0].t_start_s > 0.27 && windows[0].t_start_s < 0.30,
            "{windows:?}"
        );
        assert!(
            windows[0].t_end_s > 0.325 && windows[0].t_end_s < 0.355,
            "{windows:?}"
        );
    }

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

    /// A bite at sample 200 (2 kHz): a 5 ms load rise to 100 kN*m with a decaying
    /// 21 Hz oscillation (first period 95 samples), delayed by `delay_s`.
    fn bite(k: usize, delay_s: f64) -> f64 {
        let t = k as f64 / 2000.0 - 0.1 - delay_s;
        if t <= 0.0 {
            return 0.0;
        }
        100.0 * (1.0 - (-t / 0.005).exp())
            + 60.0 * (-4.0 * t).exp() * (std::f64::consts::TAU * 21.0 * t).sin()
    }

    fn label_of(measured: &[f64], model: &[f64]) -> Vec<&'static str> {
        disagreements(measured, model, 0.1, 0.0, 2000.0, 200, 95)
            .iter()
            .map(|d| d.feature)
            .collect()
    }

    #[test]
    fn windows_are_labelled_where_their_residual_is_largest() {
        let model: Vec<f64> = (0..1200).map(|k| bite(k, 0.0)).collect();
        let peak = 200
            + model[200..]
                .iter()
                .enumerate()
                .max_by(|a, b| a.1.total_cmp(b.1))
                .unwrap()
                .0;
        let bump =
            |centre: usize, k: usize| 6.0 * (-((k as f64 - centre as f64) / 8.0).powi(2)).exp();

        let delayed: Vec<f64> = (0..1200).map(|k| bite(k, 0.002)).collect();
        assert_eq!(label_of(&delayed, &model).first(), Some(&"delay"));

        let at_peak: Vec<f64> = (0..1200).map(|k| model[k] + bump(peak, k)).collect();
        assert_eq!(label_of(&at_peak, &model), ["peak"]);

        // One window from the load rise through the peak, largest at the peak: the peak
        // (labelled by its start it would be called a delay).
        let rise_and_peak: Vec<f64> = (0..1200)
            .map(|k| model[k] + 0.4 * bump(200 + 4, k) + bump(peak, k))
            .collect();
        let windows = disagreements(&rise_and_peak, &model, 0.1, 0.0, 2000.0, 200, 95);
        assert_eq!(windows.len(), 1, "{windows:?}");
        assert!(
            windows[0].t_start_s < 0.1 + 95.0 / 4.0 / 2000.0,
            "{windows:?}"
        );
        assert_eq!(windows[0].feature, "peak");

        let in_first_period: Vec<f64> = (0..1200).map(|k| model[k] + bump(200 + 150, k)).collect();
        assert_eq!(label_of(&in_first_period, &model), ["first_period"]);

        // Late: the oscillation 30% larger, or 3 ms later, from the fifth period on.
        let late = 200 + 5 * 95;
        let oscillation = |k: usize| model[k] - 100.0;
        let larger: Vec<f64> = (0..1200)
            .map(|k| {
                if k < late {
                    model[k]
                } else {
                    model[k] + 0.3 * oscillation(k)
                }
            })
            .collect();
        assert_eq!(label_of(&larger, &model), ["amplitude"]);
        let later: Vec<f64> = (0..1200)
            .map(|k| if k < late { model[k] } else { bite(k, 0.003) })
            .collect();
        assert_eq!(label_of(&later, &model), ["phase"]);
    }
}
