//! A detector started while the mill is rolling (its first samples are a loaded
//! level) must find the true zero at the next tail-out and measure the next bite
//! against it.

use millgate_dsp::bite::{BiteDetector, BiteSettings};

#[test]
fn start_mid_bar_measures_the_next_bite_from_the_true_zero() {
    let settings = BiteSettings {
        threshold_knm: 20.0,
        rearm_knm: 10.0,
        holdoff_samples: 100,
        baseline_alpha: 1e-3,
        saturation_low_knm: -300.0,
        saturation_high_knm: 300.0,
        post_trigger_samples: 200,
    };
    let detector = BiteDetector::<32, 256>::new(settings).unwrap();
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
