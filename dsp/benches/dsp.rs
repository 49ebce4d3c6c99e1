//! Throughput of the streaming bite detector, time per eq. (1) fit, time per bite of
//! the transient analysis (static, peak, TAF, periods about the fitted load trend),
//! time per chatter
//! window (band gain, mode damping) of 5 stands, the wear trend's time per bite
//! (two hypotheses on 65-point local grids) and per forecast, and throughput of the
//! streaming rainflow count with Miner's damage of three components (the fatigue
//! ledger's hot path: under 2% of a core per 2 kHz channel is >= 100 k samples/s).
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

/// The transient analysis of one bite window as the demo's drivelines record it: 2 kHz,
/// 0.1 s before the trigger and 0.5 s after, Table 1's torque with 2% noise, periods
/// low-passed at 40 Hz (the gateway's default).
fn transient(c: &mut Criterion) {
    use millgate_dsp::transient::{analyze, TransientSettings};

    const RATE: f64 = 2000.0;
    const PRE: usize = 200;
    let mut rng = StdRng::seed_from_u64(3);
    let noise = Normal::new(0.0, 0.02 * TABLE1[8]).unwrap();
    let window: Vec<f64> = (0..PRE + 1000)
        .map(|i| {
            let load = match i.checked_sub(PRE) {
                Some(k) => eq1(&TABLE1, k as f64 / RATE),
                None => 0.0,
            };
            load + noise.sample(&mut rng)
        })
        .collect();
    let settings = TransientSettings {
        sample_rate_hz: RATE,
        period_lowpass_hz: 40.0,
        peak_lowpass_hz: Some(100.0),
        settled_fraction: 0.3,
        min_static_knm: 1.0,
        reference_shift_s: None,
    };
    c.bench_function("transient_analyze_bite_2kHz", |b| {
        b.iter(|| analyze::<2048>(black_box(&window), PRE, 0.0, &settings))
    });
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

/// The wear trend after 60 days of 20 bites a day (gap growing 0.02 mrad/day, two
/// hypotheses): one bite's predict + two 65-point grid updates + finish, and one
/// forecast (both cone sides scanned and bisected).
fn wear_trend(c: &mut Criterion) {
    use millgate_dsp::wear_trend::{BiteMoments, GapGrid, WearTrend, WearTrendState};

    const FINE: GapGrid = GapGrid {
        first_mrad: 0.0,
        step_mrad: 0.015_625,
        len: 513,
    };
    let trend = WearTrend::new(365.0).unwrap();
    let mut rng = StdRng::seed_from_u64(3);
    let noise = Normal::new(0.0, 0.05).unwrap();
    let mut ll = vec![0.0; FINE.len];
    let mut bite = |trend: &WearTrend, state: &mut WearTrendState, t: f64, gap: f64| {
        trend.predict(state, t).unwrap();
        for k in 0..2 {
            let grid = trend.grid(state, k, FINE);
            let observed = gap + 0.4 * k as f64 + noise.sample(&mut rng);
            for (i, v) in ll[..grid.len].iter_mut().enumerate() {
                *v = -0.5 * ((observed - grid.at(i)) / 0.05).powi(2);
            }
            let moments = BiteMoments {
                mean_mrad: observed,
                var_mrad2: 0.0025,
            };
            trend
                .update(state, k, grid, &ll[..grid.len], moments)
                .unwrap();
        }
        trend.finish_bite(state, Some(1e-4));
    };
    let mut state = trend.state(2).unwrap();
    for i in 0..1200 {
        let t = i as f64 / 20.0;
        bite(&trend, &mut state, t, 1.0 + 0.02 * t);
    }
    assert_eq!(trend.grid(&state, 0, FINE).len, 65, "local grids");
    // The likelihoods of one bite on the two local grids, computed once: the bench
    // times the trend, not the test likelihood.
    let grids = [trend.grid(&state, 0, FINE), trend.grid(&state, 1, FINE)];
    let lls: Vec<Vec<f64>> = grids
        .iter()
        .enumerate()
        .map(|(k, g)| {
            let observed = 2.2 + 0.4 * k as f64;
            (0..g.len)
                .map(|i| -0.5 * ((observed - g.at(i)) / 0.05).powi(2))
                .collect()
        })
        .collect();
    let t_next = 60.0;
    let mut group = c.benchmark_group("wear_trend");
    group.bench_function("bite_2_hypotheses_65_points", |b| {
        b.iter(|| {
            let mut s = state;
            trend.predict(&mut s, black_box(t_next)).unwrap();
            for k in 0..2 {
                let moments = BiteMoments {
                    mean_mrad: 2.2 + 0.4 * k as f64,
                    var_mrad2: 0.0025,
                };
                trend
                    .update(&mut s, k, grids[k], black_box(&lls[k]), moments)
                    .unwrap();
            }
            trend.finish_bite(&mut s, None);
            black_box(s.hypotheses[0].gap_mrad)
        })
    });
    group.bench_function("forecast", |b| {
        b.iter(|| black_box(trend.forecast(black_box(&state), 4.0)))
    });
    group.finish();
}

/// The fatigue ledger's per-sample work: rainflow with the gate at 3 noise RMS (as
/// configured) and at 0 (every noise wiggle a reversal, the worst case), Miner's
/// damage of three components per counted cycle.
fn rainflow(c: &mut Criterion) {
    use millgate_dsp::miner::{EnduranceRule, MeanCorrection, SnCurve, SnCurveSettings};
    use millgate_dsp::rainflow::{Rainflow, RainflowSettings};

    const LEN: usize = 1 << 20;
    let mut rng = StdRng::seed_from_u64(2);
    let noise = Normal::new(0.0, 2.0).unwrap();
    // 2 kHz torque: a 4 s bar every 6 s, its bite transient then the static load.
    let samples: Vec<f64> = (0..LEN)
        .map(|i| {
            let phase = i % 12_000;
            let load = if (2_000..10_000).contains(&phase) {
                eq1(&TABLE1, (phase - 2_000) as f64 / 2000.0)
            } else {
                0.0
            };
            load + noise.sample(&mut rng)
        })
        .collect();
    let curves: Vec<SnCurve> = [1.0, 0.5, 0.5]
        .iter()
        .map(|&torque_share| {
            SnCurve::new(SnCurveSettings {
                m: 6.0,
                ref_cycles: 2e6,
                ref_range_knm: 150.0,
                torque_share,
                endurance_knm: Some(20.0),
                endurance_rule: EnduranceRule::Haibach,
                mean_correction: MeanCorrection::None,
            })
            .unwrap()
        })
        .collect();
    let mut group = c.benchmark_group("rainflow");
    group.throughput(Throughput::Elements(LEN as u64));
    for gate_knm in [6.0, 0.0] {
        let counter = Rainflow::<256>::new(RainflowSettings { gate_knm }).unwrap();
        group.bench_with_input(
            BenchmarkId::new("process_2kHz_3_components_gate_knm", gate_knm),
            &samples,
            |b, samples| {
                b.iter(|| {
                    let mut state = counter.state();
                    let mut damage = [0.0; 3];
                    counter.block(&mut state, black_box(samples), |cycle| {
                        for (sum, curve) in damage.iter_mut().zip(&curves) {
                            *sum += curve.damage(&cycle);
                        }
                    });
                    damage
                })
            },
        );
    }
    group.finish();
}

criterion_group!(
    benches,
    detector,
    fit,
    transient,
    chatter_window,
    wear_trend,
    rainflow
);
criterion_main!(benches);
