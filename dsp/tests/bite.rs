//! Bite detector behaviour: noise, drifting zero, dead time, gaps, NaN, saturation,
//! external trigger.

use millgate_dsp::bite::{BiteDetector, BiteEvent, BiteSettings, TriggerSource};
use rand::rngs::StdRng;
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};

const PRE: usize = 100;
const N: usize = 700;
const POST: usize = 600;

fn settings() -> BiteSettings {
    BiteSettings {
        threshold_knm: 30.0,
        rearm_knm: 15.0,
        holdoff_samples: 200,
        baseline_alpha: 2e-3,
        saturation_low_knm: -500.0,
        saturation_high_knm: 500.0,
        post_trigger_samples: POST,
    }
}

fn detector() -> BiteDetector<PRE, N> {
    BiteDetector::new(settings()).unwrap()
}

/// Runs `samples` through a fresh detector and collects the events.
fn run(samples: &[f64]) -> Vec<BiteEvent<N>> {
    let detector = detector();
    let mut state = detector.state();
    let mut events = Vec::new();
    detector.block(&mut state, samples, |e| events.push(e));
    events
}

/// Zero offset + drift + noise, with load steps of `level` at the given starts.
fn record(len: usize, bites: &[(usize, usize)], level: f64, drift_per_sample: f64) -> Vec<f64> {
    let mut rng = StdRng::seed_from_u64(11);
    let noise = Normal::new(0.0, 3.0).unwrap();
    (0..len)
        .map(|i| {
            let load = if bites.iter().any(|&(s, e)| i >= s && i < e) {
                level
            } else {
                0.0
            };
            5.0 + drift_per_sample * i as f64 + load + noise.sample(&mut rng)
        })
        .collect()
}

#[test]
fn noise_alone_never_triggers() {
    assert!(run(&record(200_000, &[], 0.0, 0.0)).is_empty());
}

#[test]
fn bites_are_found_at_their_onset_with_pre_trigger_history() {
    let bites = [(5_000, 8_000), (12_000, 15_000), (20_000, 26_000)];
    let events = run(&record(30_000, &bites, 120.0, 0.0));
    assert_eq!(events.len(), bites.len());
    for (event, &(start, _)) in events.iter().zip(&bites) {
        assert_eq!(event.trigger_sample, start as u64);
        assert_eq!(event.trigger_index, PRE);
        assert_eq!(event.window.len(), PRE + POST);
        assert_eq!(event.source, TriggerSource::Level);
        assert!(event.quality.is_good());
        assert!(
            (event.baseline_knm - 5.0).abs() < 1.0,
            "{}",
            event.baseline_knm
        );
        // Pre-trigger samples are idle, the trigger sample is loaded.
        assert!(event.window[..PRE].iter().all(|v| *v < 30.0));
        assert!(event.window[PRE] > 90.0);
    }
}

#[test]
fn drifting_zero_is_tracked() {
    // Zero drifts by 200 kN*m over the record: far more than the threshold.
    let len = 400_000;
    let drift = 200.0 / len as f64;
    let bites = [(100_000, 110_000), (300_000, 310_000)];
    let events = run(&record(len, &bites, 120.0, drift));
    assert_eq!(events.len(), 2);
    for (event, &(start, _)) in events.iter().zip(&bites) {
        assert_eq!(event.trigger_sample, start as u64);
        let zero = 5.0 + drift * start as f64;
        assert!((event.baseline_knm - zero).abs() < 2.0);
    }
}

#[test]
fn dead_time_blocks_retrigger_until_torque_returns() {
    // A single long bite with oscillation that crosses the threshold many times.
    let mut samples = vec![0.0; 20_000];
    for (i, v) in samples.iter_mut().enumerate().skip(1_000).take(10_000) {
        *v = 100.0 + 80.0 * (i as f64 * 0.05).sin();
    }
    let events = run(&samples);
    assert_eq!(events.len(), 1);
    assert_eq!(events[0].trigger_sample, 1_000);
}

#[test]
fn holdoff_delays_rearm() {
    // Second bite starts 100 samples after the first window ends: within the hold-off.
    let first_end = 1_000 + POST;
    let mut samples = vec![0.0; 5_000];
    for v in &mut samples[1_000..first_end] {
        *v = 100.0;
    }
    for v in &mut samples[first_end + 100..first_end + 900] {
        *v = 100.0;
    }
    let events = run(&samples);
    assert_eq!(events.len(), 1);
    // After a longer pause the second bite is found.
    for v in &mut samples[first_end + 100..first_end + 900] {
        *v = 0.0;
    }
    for v in &mut samples[first_end + 400..first_end + 1_200] {
        *v = 100.0;
    }
    let events = run(&samples);
    assert_eq!(events.len(), 2);
    assert_eq!(events[1].trigger_sample, (first_end + 400) as u64);
}

#[test]
fn gap_during_capture_ends_the_window_flagged() {
    let detector = detector();
    let mut state = detector.state();
    for _ in 0..1_000 {
        assert!(detector.process(&mut state, 0.0).is_none());
    }
    for _ in 0..50 {
        assert!(detector.process(&mut state, 100.0).is_none());
    }
    let event = detector.gap(&mut state, 25).unwrap();
    assert!(event.quality.gap);
    assert_eq!(event.window.len(), PRE + 50);
    assert_eq!(event.trigger_sample, 1_000);
    assert_eq!(state.sample_index(), 1_075);
}

#[test]
fn gap_before_trigger_clears_history_and_needs_a_whole_pre_trigger() {
    let detector = detector();
    let mut state = detector.state();
    for _ in 0..1_000 {
        let _ = detector.process(&mut state, 0.0);
    }
    assert!(detector.gap(&mut state, 10).is_none());
    assert!(state.is_resyncing());
    // 20 fresh samples are not a pre-trigger: a rise after them is no onset, and the
    // external trigger is refused too.
    for _ in 0..20 {
        let _ = detector.process(&mut state, 0.0);
    }
    assert!(!detector.trigger(&mut state));
    let mut events = Vec::new();
    detector.block(&mut state, &[100.0; POST], |e| events.push(e));
    assert!(events.is_empty(), "{events:?}");
    // PRE idle samples in a row: the next rise is a bite with a whole pre-trigger.
    detector.block(&mut state, &[0.0; PRE], |e| events.push(e));
    assert!(!state.is_resyncing());
    detector.block(&mut state, &[100.0; POST], |e| events.push(e));
    assert_eq!(events.len(), 1);
    assert_eq!(events[0].trigger_index, PRE);
    assert_eq!(events[0].trigger_sample, (1_030 + POST + PRE) as u64);
    assert!(events[0].quality.is_good());
}

/// Issue 30, finding 4: data resuming after an outage while the mill is loaded (the
/// bite began in the outage) made a "bite" whose window starts loaded: TAF ~1.0,
/// published as valid. Now it is no onset; the next bar's bite is whole.
#[test]
fn data_resuming_loaded_after_a_gap_is_no_bite() {
    let detector = detector();
    let mut state = detector.state();
    let mut events = Vec::new();
    detector.block(&mut state, &[0.0; 1_000], |e| events.push(e));
    assert!(detector.gap(&mut state, 2_000).is_none());
    // Loaded, with a short idle dip and a second rise: still no onset.
    detector.block(&mut state, &[120.0; 800], |e| events.push(e));
    detector.block(&mut state, &[0.0; PRE / 2], |e| events.push(e));
    detector.block(&mut state, &[120.0; 300], |e| events.push(e));
    assert!(events.is_empty(), "{events:?}");
    // Unloaded, then the next bar.
    detector.block(&mut state, &[0.0; 2 * PRE], |e| events.push(e));
    detector.block(&mut state, &[120.0; POST], |e| events.push(e));
    assert_eq!(events.len(), 1);
    assert_eq!(events[0].trigger_index, PRE, "a whole pre-trigger");
    assert!(events[0].quality.is_good());
}

#[test]
fn nan_and_saturation_mark_quality_and_never_leak() {
    let mut samples = vec![0.0; 3_000];
    for v in &mut samples[1_000..2_000] {
        *v = 100.0;
    }
    samples[1_200] = f64::NAN;
    samples[1_300] = 600.0;
    let events = run(&samples);
    assert_eq!(events.len(), 1);
    let event = &events[0];
    assert!(event.quality.non_finite && event.quality.saturated && !event.quality.gap);
    assert!(event.window.iter().all(|v| v.is_finite()));
    assert_eq!(event.window[PRE + 200], 100.0); // NaN held at the previous value

    // NaN alone before any bite does not trigger and does not poison the baseline.
    let mut samples = vec![f64::NAN; 500];
    samples.extend(std::iter::repeat_n(0.0, 500));
    samples.extend(std::iter::repeat_n(100.0, 1_000));
    let events = run(&samples);
    assert_eq!(events.len(), 1);
    assert_eq!(events[0].trigger_sample, 1_000);
    assert!(events[0].quality.is_good());
    assert_eq!(events[0].baseline_knm, 0.0);
}

#[test]
fn external_trigger_captures_without_level_rise() {
    let detector = detector();
    let mut state = detector.state();
    for _ in 0..500 {
        let _ = detector.process(&mut state, 1.0);
    }
    assert!(detector.trigger(&mut state));
    let mut events = Vec::new();
    detector.block(&mut state, &[2.0; 1_000], |e| events.push(e));
    assert_eq!(events.len(), 1);
    assert_eq!(events[0].source, TriggerSource::External);
    assert_eq!(events[0].trigger_sample, 500);
    assert_eq!(events[0].window[PRE], 2.0);
    // Not armed during dead time: the trigger is refused.
    assert!(!detector.trigger(&mut state) || state.is_armed());
}

#[test]
fn settings_are_validated() {
    use millgate_dsp::bite::BiteSettingsError as E;
    let bad = |s: BiteSettings| BiteDetector::<PRE, N>::new(s).err();
    assert_eq!(
        bad(BiteSettings {
            threshold_knm: 0.0,
            ..settings()
        }),
        Some(E::ThresholdKnm)
    );
    assert_eq!(
        bad(BiteSettings {
            baseline_alpha: 1.5,
            ..settings()
        }),
        Some(E::BaselineAlpha)
    );
    assert_eq!(
        bad(BiteSettings {
            saturation_low_knm: f64::NAN,
            ..settings()
        }),
        Some(E::SaturationLimits)
    );
    assert_eq!(
        bad(BiteSettings {
            post_trigger_samples: N,
            ..settings()
        }),
        Some(E::PostTriggerSamples)
    );
}

#[test]
fn coming_back_from_negative_full_scale_invents_no_bite_and_misses_none() {
    // Idle at 5 kN*m, the channel pinned at -500 (the converter's negative end, a
    // cable fault) for 2000 samples, back to idle, then a real bite at 4000. Before,
    // the fall reset the baseline to -500, the return to idle was a "bite" of +505,
    // and its dead time swallowed the real one.
    let mut samples = record(6000, &[(4000, 5000)], 100.0, 0.0);
    for sample in &mut samples[1000..3000] {
        *sample = -500.0;
    }
    let events = run(&samples);
    assert_eq!(
        events.len(),
        1,
        "{:?}",
        events.iter().map(|e| e.trigger_sample).collect::<Vec<_>>()
    );
    assert!(
        (4000..4005).contains(&events[0].trigger_sample),
        "the real bite, at {}",
        events[0].trigger_sample
    );
    assert!(events[0].quality.is_good());
    assert!(
        (events[0].baseline_knm - 5.0).abs() < 2.0,
        "baseline {}",
        events[0].baseline_knm
    );
}

#[test]
fn a_start_at_full_scale_sets_no_baseline() {
    // The first samples are pinned at +500: no baseline from them; once the channel
    // reads idle, a bite from there is found.
    let mut samples = record(4000, &[(3000, 3800)], 100.0, 0.0);
    for sample in &mut samples[..1000] {
        *sample = 500.0;
    }
    let events = run(&samples);
    let triggers: Vec<u64> = events.iter().map(|e| e.trigger_sample).collect();
    assert!(
        events.iter().all(|e| e.trigger_sample >= 3000),
        "nothing before the bite: {triggers:?}"
    );
    assert_eq!(events.len(), 1, "{triggers:?}");
}
