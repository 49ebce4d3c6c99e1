//! Natural frequencies from the part of a bite where the couplings stay loaded.
//!
//! A gap in a coupling opens only while the coupling's torque passes through zero. Once
//! the load has risen and the oscillation about it is smaller than the load, every
//! coupling stays loaded past its gap and the driveline is linear again: what the record
//! shows there is the chain's own stiffness, whatever the gap did during the rise. That
//! stretch is fitted by a sum of two damped modes, a constant and the decaying rest of
//! the load rise,
//!
//! ```text
//! y(t) = c0 + c1 exp(-r t) + sum_j exp(-d_j t) (a_j cos(2 pi f_j t) + b_j sin(2 pi f_j t))
//! ```
//!
//! (paper eq. (1) with the offset a window that starts after the bite needs), by
//! variable projection: Levenberg-Marquardt over `f_j, d_j, r`, the six amplitudes
//! solved by least squares at every point. The poles of dsp's matrix pencil start it.
//! Where the stretch begins is chosen by measurement: the earliest start after which the
//! record stays above a quarter of its static level and the fit leaves no more than
//! [`LINEAR_RESIDUAL_FACTOR`] times the noise (a gap still crossing there, in a coupling
//! the record does not measure, leaves more).

use millgate_dsp::pencil;
use nalgebra::{DMatrix, DVector};

use super::levenberg_marquardt::{minimise, FnResiduals, LmSettings};

/// The loaded part starts after the last sample below this fraction of the static level.
pub(crate) const LOADED_FRACTION: f64 = 0.25;

/// A start is accepted when the fit's RMS residual is at most this multiple of the noise.
pub(crate) const LINEAR_RESIDUAL_FACTOR: f64 = 1.25;

/// Shortest loaded part fitted, s (about three periods of a 12 Hz mode).
pub(crate) const MIN_LOADED_S: f64 = 0.25;

/// Later starts are tried in steps of this length, s.
const START_STEP_S: f64 = 0.025;

/// Half-width of the moving mean that decides where the record is loaded, s.
const SMOOTHING_S: f64 = 0.005;

/// Highest mode frequency the pencil must resolve, Hz (as dsp's eq. (1) fit).
const MAX_MODE_HZ: f64 = 60.0;

/// Damping rates the fit may reach, 1/s: from almost undamped to critically fast.
const DECAY_RANGE: (f64, f64) = (0.05, 500.0);

/// Two damped modes fitted to a stretch of record.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct ModeFit {
    /// Undamped natural frequencies `sqrt(f_d^2 + (d / 2 pi)^2)`, Hz, ascending.
    pub(crate) natural_hz: [f64; 2],
    /// Decay rates of the two modes, 1/s.
    pub(crate) decay_per_s: [f64; 2],
    /// RMS residual of the fit, kN*m.
    pub(crate) rms_residual: f64,
}

/// Fits the loaded part of one bite: `samples` from the record's first sample at
/// `sample_rate_hz` (Hz), the bite at `onset_index`, white noise `noise_rms` (kN*m).
///
/// Returns the start index of the fitted stretch and the fit, or `None` when the record
/// never stays loaded for [`MIN_LOADED_S`] or no fit converges.
pub(crate) fn loaded_modes(
    samples: &[f64],
    sample_rate_hz: f64,
    onset_index: usize,
    noise_rms: f64,
) -> Option<(usize, ModeFit)> {
    let m = samples.len();
    let level = static_level(samples)?;
    let half = ((SMOOTHING_S * sample_rate_hz).round() as usize).max(1);
    let smooth = |k: usize| {
        let window = &samples[k.saturating_sub(half)..(k + half + 1).min(m)];
        window.iter().sum::<f64>() / window.len() as f64
    };
    let first = (onset_index..m)
        .rev()
        .find(|&k| smooth(k) < LOADED_FRACTION * level)
        .map_or(onset_index, |k| k + 1);
    let shortest = (MIN_LOADED_S * sample_rate_hz).ceil() as usize;
    let step = ((START_STEP_S * sample_rate_hz).round() as usize).max(1);
    let mut best: Option<(usize, ModeFit)> = None;
    let mut start = first;
    while start + shortest <= m {
        if let Some(fit) = fit_modes(&samples[start..], sample_rate_hz) {
            if fit.rms_residual <= LINEAR_RESIDUAL_FACTOR * noise_rms {
                return Some((start, fit));
            }
            let ratio = |f: &ModeFit| f.rms_residual / noise_rms.max(f64::MIN_POSITIVE);
            if best.as_ref().is_none_or(|(_, b)| ratio(&fit) < ratio(b)) {
                best = Some((start, fit));
            }
        }
        start += step;
    }
    best
}

/// The static level of a bite: the median of its last 30%.
fn static_level(samples: &[f64]) -> Option<f64> {
    let tail_start = samples.len() * 7 / 10;
    let mut tail = samples[tail_start..].to_vec();
    if tail.is_empty() {
        return None;
    }
    let middle = tail.len() / 2;
    let (_, median, _) = tail.select_nth_unstable_by(middle, f64::total_cmp);
    (*median > 0.0).then_some(*median)
}

/// Fits two damped modes, a constant and a decaying exponential to `samples` (t = 0 at
/// the first), started from the matrix pencil's poles; the best fit over the pairs of
/// oscillating poles it finds.
pub(crate) fn fit_modes(samples: &[f64], sample_rate_hz: f64) -> Option<ModeFit> {
    let decimation = ((sample_rate_hz / (4.0 * MAX_MODE_HZ)).floor() as usize).max(1);
    let poles = pencil::poles(samples, sample_rate_hz, decimation).ok()?;
    let oscillating: Vec<(f64, f64)> = poles
        .iter()
        .filter(|p| p.frequency_hz > 0.5 && p.frequency_hz < MAX_MODE_HZ)
        .map(|p| {
            (
                p.frequency_hz,
                p.decay_per_s.clamp(DECAY_RANGE.0, DECAY_RANGE.1),
            )
        })
        .collect();
    let rise = poles
        .iter()
        .filter(|p| p.frequency_hz == 0.0 && p.decay_per_s > 1.0)
        .map(|p| p.decay_per_s)
        .fold(None, |a: Option<f64>, d| Some(a.map_or(d, |a| a.max(d))))
        .unwrap_or(20.0)
        .clamp(DECAY_RANGE.0, DECAY_RANGE.1);
    let mut best: Option<ModeFit> = None;
    for i in 0..oscillating.len() {
        for j in i + 1..oscillating.len() {
            let (a, b) = (oscillating[i], oscillating[j]);
            let start = [a.0, b.0, a.1.ln(), b.1.ln(), rise.ln()];
            let Some(fit) = refine(samples, sample_rate_hz, &start) else {
                continue;
            };
            if best.is_none_or(|b| fit.rms_residual < b.rms_residual) {
                best = Some(fit);
            }
        }
    }
    best
}

/// Variable-projection Levenberg-Marquardt from `start` = `[f1, f2, ln d1, ln d2, ln r]`.
fn refine(samples: &[f64], sample_rate_hz: f64, start: &[f64; 5]) -> Option<ModeFit> {
    let m = samples.len();
    let measured = DVector::from_column_slice(samples);
    let mut problem = FnResiduals {
        len: m,
        function: |p: &[f64], out: &mut [f64]| {
            let Some(basis) = basis(p, m, sample_rate_hz) else {
                return false;
            };
            let Ok(amplitudes) = basis.clone().svd(true, true).solve(&measured, 1.0e-12) else {
                return false;
            };
            let fitted = basis * amplitudes;
            for ((o, f), y) in out.iter_mut().zip(fitted.iter()).zip(samples) {
                *o = f - y;
            }
            true
        },
    };
    let result = minimise(start, &LmSettings::default(), &mut problem);
    let p = &result.params;
    if !result.cost.is_finite() || p.iter().any(|v| !v.is_finite()) {
        return None;
    }
    let natural = |f: f64, ln_d: f64| (f * f + (ln_d.exp() / std::f64::consts::TAU).powi(2)).sqrt();
    let mut modes = [
        (natural(p[0], p[2]), p[2].exp()),
        (natural(p[1], p[3]), p[3].exp()),
    ];
    modes.sort_by(|a, b| a.0.total_cmp(&b.0));
    // Two fits to one mode, or a mode at the edge of what the record resolves, is no
    // identification.
    let distinct = modes[1].0 > 1.02 * modes[0].0;
    let resolved = modes.iter().all(|&(f, _)| f > 0.5 && f < MAX_MODE_HZ);
    (distinct && resolved).then(|| ModeFit {
        natural_hz: [modes[0].0, modes[1].0],
        decay_per_s: [modes[0].1, modes[1].1],
        rms_residual: (result.cost / m as f64).sqrt(),
    })
}

/// The six basis columns at `p` = `[f1, f2, ln d1, ln d2, ln r]`: constant, the load
/// exponential, cosine and sine of each damped mode; `None` outside the decay range.
fn basis(p: &[f64], m: usize, sample_rate_hz: f64) -> Option<DMatrix<f64>> {
    let decay = |q: f64| {
        let d = q.exp();
        (DECAY_RANGE.0..=DECAY_RANGE.1).contains(&d).then_some(d)
    };
    let (d1, d2, r) = (decay(p[2])?, decay(p[3])?, decay(p[4])?);
    let (w1, w2) = (std::f64::consts::TAU * p[0], std::f64::consts::TAU * p[1]);
    if !(w1 > 0.0 && w2 > 0.0) {
        return None;
    }
    Some(DMatrix::from_fn(m, 6, |k, column| {
        let t = k as f64 / sample_rate_hz;
        match column {
            0 => 1.0,
            1 => (-r * t).exp(),
            2 => (-d1 * t).exp() * (w1 * t).cos(),
            3 => (-d1 * t).exp() * (w1 * t).sin(),
            4 => (-d2 * t).exp() * (w2 * t).cos(),
            _ => (-d2 * t).exp() * (w2 * t).sin(),
        }
    }))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two damped modes on an offset and a decaying load, as after a bite.
    fn record(t: f64) -> f64 {
        use std::f64::consts::TAU;
        100.0 - 30.0 * (-25.0 * t).exp()
            + 40.0 * (-6.0 * t).exp() * (TAU * 11.9 * t + 0.3).cos()
            + 15.0 * (-3.5 * t).exp() * (TAU * 20.9 * t - 1.0).sin()
    }

    #[test]
    fn the_two_modes_of_an_offset_record_are_found() {
        let samples: Vec<f64> = (0..1000).map(|k| record(k as f64 / 2000.0)).collect();
        let fit = fit_modes(&samples, 2000.0).unwrap();
        let natural = |f: f64, d: f64| (f * f + (d / std::f64::consts::TAU).powi(2)).sqrt();
        assert!(
            (fit.natural_hz[0] / natural(11.9, 6.0) - 1.0).abs() < 1e-6,
            "{fit:?}"
        );
        assert!(
            (fit.natural_hz[1] / natural(20.9, 3.5) - 1.0).abs() < 1e-6,
            "{fit:?}"
        );
        assert!((fit.decay_per_s[0] - 6.0).abs() < 1e-4, "{fit:?}");
        assert!(fit.rms_residual < 1e-6, "{fit:?}");
    }
}
