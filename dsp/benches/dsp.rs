//! Throughput of the streaming bite detector and time per eq. (1) fit.
//!
//! Run: `cargo bench -p millgate-dsp --bench dsp`.

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use millgate_dsp::bite::{BiteDetector, BiteSettings};
use millgate_dsp::fit::{eq1, fit_eq1, FitOptions};
use rand::rngs::StdRng;
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};
use std::hint::black_box;

const TABLE1: [f64; 10] = [
    -147.0, 85.0, 191.0, -31.0, 11.99, 20.91, 22.17, 3.65, 112.0, 36.7,
];

fn detector(c: &mut Criterion) {
    const LEN: usize = 1 << 20;
    let mut rng = StdRng::seed_from_u64(1);
    let noise = Normal::new(0.0, 2.0).unwrap();
    // 2 kHz torque: a bite every 0.5 s lasting 0.25 s.
    let samples: Vec<f64> = (0..LEN)
        .map(|i| {
            let phase = i % 1000;
            let load = if (200..700).contains(&phase) {
                eq1(&TABLE1, (phase - 200) as f64 / 2000.0)
            } else {
                0.0
            };
            load + noise.sample(&mut rng)
        })
        .collect();
    let detector = BiteDetector::<200, 1400>::new(BiteSettings {
        threshold_knm: 30.0,
        rearm_knm: 15.0,
        holdoff_samples: 50,
        baseline_alpha: 1e-3,
        saturation_low_knm: -1000.0,
        saturation_high_knm: 1000.0,
        post_trigger_samples: 400,
    })
    .unwrap();
    let mut group = c.benchmark_group("bite_detector");
    group.throughput(Throughput::Elements(LEN as u64));
    group.bench_function("process_2kHz_with_bites", |b| {
        b.iter(|| {
            let mut state = detector.state();
            let mut events = 0_usize;
            detector.block(&mut state, black_box(&samples), |e| {
                events += black_box(e.window.len()) & 1;
            });
            events
        })
    });
    group.finish();
}

fn fit(c: &mut Criterion) {
    let mut group = c.benchmark_group("fit_eq1");
    for len in [500_usize, 2000] {
        // Table 1 over 0.5 s at len / 0.5 s sample rate, noise RMS 2% of a9.
        let rate = len as f64 / 0.5;
        let mut rng = StdRng::seed_from_u64(7);
        let noise = Normal::new(0.0, 0.02 * TABLE1[8]).unwrap();
        let samples: Vec<f64> = (0..len)
            .map(|i| eq1(&TABLE1, i as f64 / rate) + noise.sample(&mut rng))
            .collect();
        let options = FitOptions::new(rate);
        group.bench_with_input(BenchmarkId::from_parameter(len), &samples, |b, s| {
            b.iter(|| fit_eq1(black_box(s), &options))
        });
    }
    group.finish();
}

criterion_group!(benches, detector, fit);
criterion_main!(benches);
