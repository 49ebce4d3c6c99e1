//! Proves the hot path never touches the heap: a counting global allocator wraps the
//! system one, and the measured section (detector + transient analysis + eq. (1) fit
//! over more than 1e6 samples with several bites) must allocate nothing. Only the
//! measuring thread is counted: the test harness allocates on its own threads.

use millgate_dsp::bite::{BiteDetector, BiteSettings};
use millgate_dsp::fit::{eq1, fit_eq1, FitOptions};
use millgate_dsp::transient::{analyze, TransientSettings};
use millgate_tests::counting_allocator::{allocations_during, CountingAllocator};

#[global_allocator]
static GLOBAL: CountingAllocator = CountingAllocator;

const TABLE1: [f64; 10] = [
    -147.0, 85.0, 191.0, -31.0, 11.99, 20.91, 22.17, 3.65, 112.0, 36.7,
];
const FS: f64 = 2000.0;
const PRE: usize = 200;
const N: usize = 1400;

/// Torque at sample `i` of a record with a bite every 100_000 samples (50 s at 2 kHz),
/// each lasting 40_000 samples; deterministic pseudo-noise, no allocation.
fn torque(i: usize) -> f64 {
    let phase = i % 100_000;
    let noise = ((i.wrapping_mul(2_654_435_761) >> 7) % 1000) as f64 / 1000.0 - 0.5;
    let load = if (10_000..50_000).contains(&phase) {
        eq1(&TABLE1, (phase - 10_000) as f64 / FS)
    } else {
        0.0
    };
    3.0 + load + 2.0 * noise
}

#[test]
fn detector_analysis_and_fit_never_allocate() {
    let detector = BiteDetector::<PRE, N>::new(BiteSettings {
        threshold_knm: 30.0,
        rearm_knm: 15.0,
        holdoff_samples: 1_000,
        baseline_alpha: 1e-3,
        saturation_low_knm: -1000.0,
        saturation_high_knm: 1000.0,
        post_trigger_samples: N - PRE,
    })
    .unwrap();
    let transient = TransientSettings {
        sample_rate_hz: FS,
        period_lowpass_hz: 16.0,
        peak_lowpass_hz: Some(60.0),
        settled_fraction: 0.3,
        min_static_knm: 1.0,
        reference_shift_s: None,
    };
    let options = FitOptions::new(FS);
    let mut state = detector.state();
    let (mut events, mut fits, mut f1_sum) = (0, 0, 0.0);

    let ((), allocations) = allocations_during(|| {
        for i in 0..1_200_000 {
            if let Some(event) = detector.process(&mut state, torque(i)) {
                events += 1;
                let result = analyze::<N>(
                    &event.window,
                    event.trigger_index,
                    event.baseline_knm,
                    &transient,
                );
                if result.is_ok() {
                    let post = &event.window[event.trigger_index..];
                    if let Ok(fit) = fit_eq1(post, &options) {
                        fits += 1;
                        f1_sum += fit.f1_hz;
                    }
                }
            }
        }
    });

    assert_eq!(allocations, 0);
    assert_eq!(events, 12);
    assert_eq!(fits, 12);
    // The fits are real, not skipped: the first mode is found each time.
    assert!(
        (f1_sum / fits as f64 - TABLE1[4]).abs() < 0.5,
        "{}",
        f1_sum / fits as f64
    );
}

#[test]
fn counter_sees_an_allocation_on_the_measuring_thread() {
    // Guards the guard: a Vec allocated while measuring must be counted.
    let (v, allocations) =
        allocations_during(|| std::hint::black_box(Vec::<u64>::with_capacity(16)));
    drop(v);
    assert!(allocations > 0);
}
