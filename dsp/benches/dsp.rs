//! Throughput of the streaming bite detector, time per eq. (1) fit, and time per
//! chatter window (band gain, mode damping) of 5 stands.
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

/// One 0.5 s window of 5 stands at 2500 Hz: the band gain's filtering of a hop (the
/// window's other half was filtered the hop before) and the matrix pencil on each
/// stand's chatter band.
fn chatter_window(c: &mut Criterion) {
    use millgate_dsp::band_gain::{BandGain, BandGainSettings};
    use millgate_dsp::mode_damping::least_damped;

    const RATE: f64 = 2500.0;
    const WINDOW: usize = 1250;
    let mut rng = StdRng::seed_from_u64(2);
    let noise = Normal::new(0.0, 0.3).unwrap();
    let frames: Vec<[f64; 5]> = (0..WINDOW)
        .map(|i| {
            let t = i as f64 / RATE;
            core::array::from_fn(|s| {
                (std::f64::consts::TAU * (150.0 + 20.0 * s as f64) * t).sin()
                    + noise.sample(&mut rng)
            })
        })
        .collect();
    let detector = BandGain::new(BandGainSettings {
        sample_rate_hz: RATE,
        chatter_band_hz: (100.0, 300.0),
        reference_band_hz: (450.0, 900.0),
        hop_samples: WINDOW / 2,
        window_hops: 2,
        stands: 5,
    })
    .unwrap();
    let mut state = detector.state();
    let mut group = c.benchmark_group("chatter_window_5_stands");
    group.bench_function("band_gain_hop", |b| {
        b.iter(|| {
            let mut last = None;
            for frame in &frames[..WINDOW / 2] {
                last = detector.process(&mut state, black_box(frame)).unwrap();
            }
            black_box(last)
        })
    });
    let band: Vec<f64> = frames.iter().map(|f| f[2]).collect();
    group.bench_function("mode_damping_pencil", |b| {
        b.iter(|| {
            for _ in 0..5 {
                black_box(least_damped(black_box(&band), RATE, 3, (100.0, 300.0)).ok());
            }
        })
    });
    group.finish();
}

criterion_group!(benches, detector, fit, chatter_window);
criterion_main!(benches);
