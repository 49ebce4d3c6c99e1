//! One record holding several bites, split into one record per bite.
//!
//! A bite is a stretch where the torque (a centred moving mean over
//! [`SMOOTHING_S`] either side) stays above [`LOADED_FRACTION`] of the record's loaded
//! level (its 90th percentile) and above five times the noise, dips shorter than
//! [`MERGE_GAP_S`] (the transient's swings through zero) included, lasting at least
//! [`MIN_BITE_S`]. Each bite's record starts up to [`PRE_BITE_S`] before the rise (half
//! the idle stretch before it at most) and ends before the unloading: back from where
//! the torque last stood at [`UNLOAD_FRACTION`] of its settled level (the median of the
//! bite's second half) to the last point as high as the torque over the [`LOOKBACK_S`]
//! before it, within three times the moving mean's noise, less the smoothing. A record
//! with one bite comes back whole.

use millgate_dsp::noise::noise_rms;

use super::Measured;

/// Half-width of the moving mean, s.
pub(crate) const SMOOTHING_S: f64 = 0.01;
/// Share of the loaded level above which the torque counts as loaded.
pub(crate) const LOADED_FRACTION: f64 = 0.1;
/// Loaded stretches closer than this are one bite, s.
pub(crate) const MERGE_GAP_S: f64 = 0.15;
/// Shortest bite, s.
pub(crate) const MIN_BITE_S: f64 = 0.2;
/// Idle kept before a bite's rise, s.
pub(crate) const PRE_BITE_S: f64 = 0.1;
/// A bite's unloading is found where the torque last stood at this share of its settled
/// level (the record ends before, where the unloading began).
pub(crate) const UNLOAD_FRACTION: f64 = 0.9;
/// The unloading began at the last point that stood as high as the moving mean over
/// this stretch before it, s: the moving mean's width (longer, an oscillation decaying
/// from higher crests before would carry the point back into the transient).
pub(crate) const LOOKBACK_S: f64 = 2.0 * SMOOTHING_S;

/// The bites of `record`, each as its own record (times kept); `record` itself when it
/// holds one bite or none.
pub fn split_bites<'a>(record: &Measured<'a>) -> Vec<Measured<'a>> {
    let y = record.torque_knm;
    let m = y.len();
    let fs = record.sample_rate_hz;
    let half = ((SMOOTHING_S * fs).round() as usize).max(1);
    // Centred moving mean by a running sum.
    let mut prefix = Vec::with_capacity(m + 1);
    prefix.push(0.0);
    for v in y {
        prefix.push(prefix[prefix.len() - 1] + v);
    }
    let smooth: Vec<f64> = (0..m)
        .map(|k| {
            let (a, b) = (k.saturating_sub(half), (k + half + 1).min(m));
            (prefix[b] - prefix[a]) / (b - a) as f64
        })
        .collect();
    let mut sorted = smooth.clone();
    sorted.sort_by(f64::total_cmp);
    let Some(&level) = sorted.get(m * 9 / 10) else {
        return vec![*record];
    };
    let noise = noise_rms(y);
    let threshold = (LOADED_FRACTION * level).max(5.0 * noise);
    let merge = (MERGE_GAP_S * fs).round() as usize;
    let mut runs: Vec<(usize, usize)> = Vec::new();
    let mut k = 0;
    while k < m {
        if smooth[k] <= threshold {
            k += 1;
            continue;
        }
        let start = k;
        while k < m && smooth[k] > threshold {
            k += 1;
        }
        match runs.last_mut() {
            Some(last) if start - last.1 < merge => last.1 = k,
            _ => runs.push((start, k)),
        }
    }
    runs.retain(|&(a, b)| (b - a) as f64 >= MIN_BITE_S * fs);
    if runs.len() < 2 {
        return vec![*record];
    }
    let pre = (PRE_BITE_S * fs).round() as usize;
    let mut bites = Vec::with_capacity(runs.len());
    for (i, &(a, b)) in runs.iter().enumerate() {
        let idle_before = if i == 0 { a } else { a - runs[i - 1].1 };
        let start = a - pre.min(idle_before / 2);
        let end = if b == m {
            m
        } else {
            let mut tail = smooth[(a + b) / 2..b].to_vec();
            let middle = tail.len() / 2;
            let (_, settled, _) = tail.select_nth_unstable_by(middle, f64::total_cmp);
            let settled = *settled;
            let unloading = (a..b)
                .rev()
                .find(|&j| smooth[j] >= UNLOAD_FRACTION * settled)
                .unwrap_or(b);
            // Back from there to where the unloading began: the last point whose moving
            // mean comes within three times its own noise of the highest one over the
            // [`LOOKBACK_S`] before it (inside a falling unloading every earlier value is
            // higher; on the settled part, or at an oscillation's crest, the point is the
            // top). A smooth unloading (a raised-cosine tail-out) takes tens of ms to
            // reach the fraction above; a bite ending there keeps a drop of several % of
            // the load that no driveline model has, and the fits bend to it (fresh bites
            // were named a sensor lag). The settled median is no reference: with the
            // tail-out and a slow oscillation in the second half it sits % below.
            let margin = 3.0 * noise / ((2 * half + 1) as f64).sqrt();
            let lookback = (LOOKBACK_S * fs).round() as usize;
            let last = (a..=unloading)
                .rev()
                .find(|&j| {
                    let highest = smooth[j.saturating_sub(lookback).max(a)..=j]
                        .iter()
                        .fold(f64::NEG_INFINITY, |h, &v| h.max(v));
                    smooth[j] >= highest - margin
                })
                .unwrap_or(unloading);
            last.saturating_sub(half).max(a + 1)
        };
        bites.push(Measured {
            t0_s: record.t0_s + start as f64 / fs,
            sample_rate_hz: fs,
            torque_knm: &y[start..end],
        });
    }
    bites
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::chain::simulate_with_noise;
    use crate::model::Model;
    use crate::schedule::{rolling_schedule, BarTiming, TAIL_OUT_S};

    #[test]
    fn three_bites_with_idle_and_unloading_between_are_three_records() {
        let mut model =
            Model::from_toml_str(include_str!("../../models/table2-adjusted.toml"), "t2").unwrap();
        let fs = model.measurement.sample_rate;
        let mut record = Vec::new();
        let mut onsets = Vec::new();
        let mut unloads = Vec::new();
        for (b, static_knm) in [60.0, 150.0, 100.0].into_iter().enumerate() {
            record.extend(std::iter::repeat_n(0.0, 600)); // 0.3 s idle
            model.load.static_torque = static_knm;
            let bite = simulate_with_noise(&model, 0.5, b as u64)
                .unwrap()
                .torque_knm;
            onsets.push(record.len() + (model.load.onset * fs) as usize);
            let last = *bite.last().unwrap();
            record.extend(bite);
            unloads.push(record.len());
            // Unloading: a 50 ms ramp down.
            record.extend((1..=100).map(|k| last * (1.0 - k as f64 / 100.0)));
        }
        record.extend(std::iter::repeat_n(0.0, 600));
        let whole = Measured {
            t0_s: 1.0,
            sample_rate_hz: fs,
            torque_knm: &record,
        };
        let bites = split_bites(&whole);
        assert_eq!(bites.len(), 3);
        for (bite, (&onset, &unload)) in bites.iter().zip(onsets.iter().zip(&unloads)) {
            let start = ((bite.t0_s - 1.0) * fs).round() as usize;
            let end = start + bite.torque_knm.len();
            // The rise inside, with idle before it; the unloading outside, most of the
            // settled part inside.
            assert!(
                start + 50 <= onset && onset < start + 250,
                "{start} {onset}"
            );
            assert!(end <= unload && end + 200 > unload, "{end} {unload}");
        }
        // One bite: the record itself.
        let one = &record[..1800];
        let single = Measured {
            torque_knm: one,
            ..whole
        };
        assert_eq!(split_bites(&single).len(), 1);
        assert_eq!(split_bites(&single)[0].torque_knm.len(), 1800);
    }

    #[test]
    fn a_bite_ends_where_a_smooth_unloading_begins() {
        // The rolling schedule's tail-out is a 0.2 s raised cosine: it reaches 90% of
        // the load only ~41 ms in. A bite record must end where it begins (before, the
        // bites kept ~30 ms of a drop no driveline model has, and three fresh bites were
        // named a sensor lag).
        let model =
            Model::from_toml_str(include_str!("../../models/table2-adjusted.toml"), "t2").unwrap();
        let timing = BarTiming {
            idle_s: 0.3,
            rolling_s: 0.7,
        };
        let torques = [60.0, 160.0, 110.0];
        let schedule = rolling_schedule(&model, &torques, timing, 0.5, 3).unwrap();
        let fs = schedule.sample_rate_hz;
        let whole = Measured {
            t0_s: 0.0,
            sample_rate_hz: fs,
            torque_knm: &schedule.torque_knm,
        };
        let bites = split_bites(&whole);
        assert_eq!(bites.len(), torques.len());
        let per_bar = ((timing.idle_s + timing.rolling_s + TAIL_OUT_S) * fs).round() as usize;
        for (b, bite) in bites.iter().enumerate() {
            let start = (bite.t0_s * fs).round() as usize;
            let end = start + bite.torque_knm.len();
            let unloading = b * per_bar + ((timing.idle_s + timing.rolling_s) * fs) as usize;
            // Share of the load the taper has shed by the bite's last sample.
            let kept = end.saturating_sub(unloading) as f64 / (TAIL_OUT_S * fs);
            let shed = 0.5 * (1.0 - (std::f64::consts::PI * kept).cos());
            assert!(
                shed < 0.01 && end + 40 > unloading,
                "bite {b}: ends at {end} ({:.1}% shed), the unloading begins at {unloading}",
                100.0 * shed
            );
        }
    }
}
