//! Where a model's response departs from the record: windows of the residual above the
//! noise, each labelled with what differs there.

use serde::Serialize;

/// A residual window counts as disagreement when its RMS exceeds the noise by this factor.
///
/// Over the [`WINDOW_S`] window (50 samples at 2 kHz) the RMS of pure white noise
/// scatters by about 1 / sqrt(2 * 50) = 10%, so 1.5x the noise is five of those
/// deviations away: noise alone does not reach it.
pub(crate) const DISAGREEMENT_FACTOR: f64 = 1.5;

/// Length of the moving-RMS window, s (at least 20 samples are used).
pub(crate) const WINDOW_S: f64 = 0.025;

/// What differs most in a disagreement window.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Label {
    /// The load rise: the record starts rising earlier or later than the model.
    Delay,
    /// The first peak.
    Peak,
    /// The first two oscillation periods after the bite.
    FirstPeriod,
    /// Later: the oscillation is larger or smaller (scaling explains more than shifting).
    Amplitude,
    /// Later: the oscillation is early or late (shifting explains more than scaling).
    Phase,
}

keyed!(Label);

impl Label {
    /// The name used in JSON and reports.
    pub(crate) fn key(self) -> &'static str {
        match self {
            Label::Delay => "delay",
            Label::Peak => "peak",
            Label::FirstPeriod => "first_period",
            Label::Amplitude => "amplitude",
            Label::Phase => "phase",
        }
    }
}

/// One stretch of time where the model's residual exceeds the noise.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub(crate) struct Disagreement {
    /// The bite, 0-based in the order given.
    pub(crate) bite: usize,
    /// Start, s (the bite record's time base).
    pub(crate) t_start_s: f64,
    /// End, s.
    pub(crate) t_end_s: f64,
    /// What differs most there.
    pub(crate) feature: Label,
    /// RMS of the residual over the window, kN*m.
    pub(crate) residual_rms: f64,
}

/// Where a bite is on its record's time grid.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct BiteTiming {
    /// The bite, 0-based in the order given.
    pub(crate) bite: usize,
    /// Time of the record's first sample, s.
    pub(crate) t0_s: f64,
    /// Sample rate, Hz.
    pub(crate) sample_rate_hz: f64,
    /// Sample of the load onset.
    pub(crate) onset_index: usize,
    /// The first oscillation period, samples.
    pub(crate) period_samples: usize,
}

/// Windows where the moving RMS of `measured - model` exceeds
/// [`DISAGREEMENT_FACTOR`] times `noise` (windows closer than one window length are
/// merged), each labelled with the feature that differs there.
pub(crate) fn disagreements(
    measured: &[f64],
    model: &[f64],
    noise: f64,
    timing: &BiteTiming,
) -> Vec<Disagreement> {
    let BiteTiming {
        bite,
        t0_s,
        sample_rate_hz,
        onset_index,
        period_samples,
    } = *timing;
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
                Label::Delay
            } else if focus.abs_diff(peak_index) <= period_samples / 8 {
                Label::Peak
            } else if focus < onset_index + period_samples * 2 {
                Label::FirstPeriod
            } else if amplitude_explains(&measured[start..end], &model[start..end], period_samples)
            {
                Label::Amplitude
            } else {
                Label::Phase
            };
            Disagreement {
                bite,
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

#[cfg(test)]
mod tests {
    use super::*;

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
        let timing = BiteTiming {
            bite: 0,
            t0_s: 0.0,
            sample_rate_hz: fs,
            onset_index: 100,
            period_samples: 200,
        };
        let windows = disagreements(&measured, &model, 0.1, &timing);
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

    const TIMING: BiteTiming = BiteTiming {
        bite: 0,
        t0_s: 0.0,
        sample_rate_hz: 2000.0,
        onset_index: 200,
        period_samples: 95,
    };

    fn label_of(measured: &[f64], model: &[f64]) -> Vec<&'static str> {
        disagreements(measured, model, 0.1, &TIMING)
            .iter()
            .map(|d| d.feature.key())
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
        let windows = disagreements(&rise_and_peak, &model, 0.1, &TIMING);
        assert_eq!(windows.len(), 1, "{windows:?}");
        assert!(
            windows[0].t_start_s < 0.1 + 95.0 / 4.0 / 2000.0,
            "{windows:?}"
        );
        assert_eq!(windows[0].feature, Label::Peak);

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
