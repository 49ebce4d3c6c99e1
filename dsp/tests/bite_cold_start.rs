//! A detector started while the mill is rolling (its first samples are a loaded
//! level) must find the true zero at the next tail-out and measure the next bite
//! against it.

use millgate_dsp::bite::{BiteDetector, BiteSettings};

/// The detector both tests run: a 20 kN*m threshold, 32 samples of pre-trigger.
fn detector() -> BiteDetector<32, 256> {
    BiteDetector::new(BiteSettings {
        threshold_knm: 20.0,
        rearm_knm: 10.0,
        holdoff_samples: 100,
        baseline_alpha: 1e-3,
        saturation_low_knm: -300.0,
        saturation_high_knm: 300.0,
        post_trigger_samples: 200,
    })
    .unwrap()
}

#[test]
fn start_mid_bar_measures_the_next_bite_from_the_true_zero() {
    let detector = detector();
    let mut state = detector.state();
    let mut events = Vec::new();
    // 0.5 s rolling at 112 kN*m, the bar leaves, 0.3 s idle at 0, a 60 kN*m step.
    let record = [(500, 112.0), (300, 0.0), (400, 60.0)];
    for (count, level) in record {
        for _ in 0..count {
            events.extend(detector.process(&mut state, level));
        }
    }
    assert_eq!(events.len(), 1, "only the real bite");
    let event = &events[0];
    assert_eq!(event.trigger_sample, 800);
    assert!(
        event.baseline_knm.abs() < 1e-9,
        "baseline {}",
        event.baseline_knm
    );
}

/// A live stream joined during a bite's rise (the first sample is partway up): the
/// rise already under way is not a bite (its pre-trigger was never seen, as after a
/// gap); the next one is, measured from the true zero. A detector started with
/// `state()` (a record cut by its author) triggers on that rise and then misses the
/// real bite.
#[test]
fn joined_mid_rise_reports_only_the_next_bite() {
    let detector = detector();
    let mut state = detector.joining_state();
    let mut events = Vec::new();
    // The rise from 23 to 112 kN*m over 40 samples, 0.5 s rolling, the bar leaves,
    // 0.3 s idle at 0, a 60 kN*m step.
    for k in 0..40 {
        events.extend(detector.process(&mut state, 23.0 + 89.0 * f64::from(k) / 39.0));
    }
    let record = [(500, 112.0), (300, 0.0), (400, 60.0)];
    for (count, level) in record {
        for _ in 0..count {
            events.extend(detector.process(&mut state, level));
        }
    }
    let triggers: Vec<u64> = events.iter().map(|e| e.trigger_sample).collect();
    assert_eq!(triggers, [840], "only the real bite");
    assert!(
        events[0].baseline_knm.abs() < 1e-9,
        "{}",
        events[0].baseline_knm
    );

    // The same samples from `state()`: a trigger on the rise, none at the real bite.
    let mut state = detector.state();
    let rise = (0..40).map(|k| 23.0 + 89.0 * f64::from(k) / 39.0);
    let rest = record
        .iter()
        .flat_map(|&(count, level)| std::iter::repeat_n(level, count));
    let triggers: Vec<u64> = rise
        .chain(rest)
        .filter_map(|torque| detector.process(&mut state, torque))
        .map(|e| e.trigger_sample)
        .collect();
    assert_eq!(triggers, [9]);
}
