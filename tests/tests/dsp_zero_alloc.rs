//! Proves the hot path never touches the heap: a counting global allocator wraps the
//! system one, and the measured section (detector + transient analysis + eq. (1) fit
//! over more than 1e6 samples with several bites) must allocate nothing. Only the
//! measuring thread is counted: the test harness allocates on its own threads. The
//! bites' noise level (`noise_rms`) is measured with them. The wear trend (predict,
//! grid, bite moments, update, estimate, forecast, band) over a year of bites is
//! measured too.

use millgate_dsp::bite::{BiteDetector, BiteSettings};
use millgate_dsp::fit::{eq1, fit_eq1, FitOptions};
use millgate_dsp::noise::noise_rms;
use millgate_dsp::transient::{analyze, TransientSettings};
use millgate_tests::kit::counting_allocator::{allocations_during, CountingAllocator};

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
    let (mut events, mut fits, mut f1_sum, mut noise_sum) = (0, 0, 0.0, 0.0);

    let ((), allocations) = allocations_during(|| {
        for i in 0..1_200_000 {
            if let Some(event) = detector.process(&mut state, torque(i)) {
                events += 1;
                noise_sum += noise_rms(&event.window);
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
    // So is the noise level: of the order of the pseudo-noise's RMS (1/sqrt(3); the
    // hashed sequence is not white, so not exactly that), not 0 or NaN.
    let noise = noise_sum / events as f64;
    assert!(noise > 0.1 && noise < 1.0, "{noise}");
}

#[test]
fn chatter_band_gain_and_mode_damping_never_allocate() {
    use millgate_dsp::band_gain::{BandGain, BandGainSettings};
    use millgate_dsp::mode_damping::least_damped;

    const WINDOW: usize = 1250;
    const RATE: f64 = 2500.0;
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
    // Stand s: a 150 + 20 s Hz line growing slowly, over deterministic pseudo-noise.
    let sample = |i: usize, s: usize| {
        let t = i as f64 / RATE;
        let noise = ((i * 7 + s).wrapping_mul(2_654_435_761) >> 7) % 1000;
        (1.0 + 0.05 * t) * (std::f64::consts::TAU * (150.0 + 20.0 * s as f64) * t).sin()
            + (noise as f64 / 1000.0 - 0.5)
    };
    let mut band = [[0.0; WINDOW]; 5];
    let (mut windows, mut poles, mut gain_sum) = (0, 0, 0.0);
    let ((), allocations) = allocations_during(|| {
        for i in 0..250_000 {
            let frame: [f64; 5] = core::array::from_fn(|s| sample(i, s));
            let result = detector.process(&mut state, &frame).unwrap();
            for (s, ring) in band.iter_mut().enumerate() {
                ring[i % WINDOW] = detector.band_sample(&state, s);
            }
            if let Some(window) = result {
                windows += 1;
                gain_sum += window.max_gain();
                for ring in &band {
                    if let Ok(Some(_)) = least_damped(ring, RATE, 3, (100.0, 300.0)) {
                        poles += 1;
                    }
                }
            }
        }
    });

    assert_eq!(allocations, 0);
    assert_eq!(windows, 250_000 / (WINDOW / 2) - 2);
    // The figures are real: every stand's line is found, the gain is far above 1.
    assert_eq!(poles, 5 * windows);
    assert!(
        gain_sum / windows as f64 > 3.0,
        "{}",
        gain_sum / windows as f64
    );
}

#[test]
fn wear_trend_never_allocates() {
    use millgate_dsp::wear_trend::{BiteMoments, ForecastReason, GapGrid, WearTrend};

    const FINE: GapGrid = GapGrid {
        first_mrad: 0.0,
        step_mrad: 0.015_625,
        len: 513,
    };
    let trend = WearTrend::new(365.0).unwrap();
    let mut state = trend.state(2).unwrap();
    let mut ll = [0.0; 513];
    let mut fine_ll = [0.0; 513];
    let (mut jumps, mut forecasts, mut days_sum) = (0, 0, 0.0);
    let ((), allocations) = allocations_during(|| {
        // A year, 20 bites a day on weekdays; the gap grows 0.01 mrad/day from 1 mrad.
        for i in 0..365 * 20_usize {
            let t = (i / 20) as f64 + (i % 20) as f64 * 0.04;
            if (t as usize) % 7 >= 5 {
                continue;
            }
            // Deterministic pseudo-noise of +-0.05 mrad.
            let noise = ((i * 7).wrapping_mul(2_654_435_761) >> 7) % 1000;
            let gap = 1.0 + 0.01 * t + (noise as f64 / 1000.0 - 0.5) * 0.1;
            trend.predict(&mut state, t).unwrap();
            for k in 0..2 {
                let grid = trend.grid(&state, k, FINE);
                let observed = gap + 0.5 * k as f64;
                for (j, v) in ll[..grid.len].iter_mut().enumerate() {
                    *v = -0.5 * ((observed - grid.at(j)) / 0.05).powi(2);
                }
                // The bite's own moments on the fine grid, as the gateway does.
                for (j, v) in fine_ll.iter_mut().enumerate() {
                    *v = -0.5 * ((observed - FINE.at(j)) / 0.05).powi(2);
                }
                let bite = BiteMoments::from_loglik(FINE, &fine_ll).unwrap();
                let outcome = trend.update(&mut state, k, grid, &ll[..grid.len], bite);
                jumps += outcome.unwrap().jumped as usize;
            }
            trend.finish_bite(&mut state, Some(1e-4));
            let forecast = trend.forecast(&state, 4.0);
            if forecast.reason == ForecastReason::Forecast {
                forecasts += 1;
                days_sum += forecast.days.unwrap();
            }
            let _ = std::hint::black_box((trend.estimate(&state), trend.band(&state, 30.0)));
        }
    });

    assert_eq!(allocations, 0);
    assert_eq!(jumps, 0);
    // The forecasts are real: most of the 5 200 bites give one, of a plausible size (4 mrad at day
    // 300 from a gap growing from 1 mrad).
    assert!(forecasts > 3000, "{forecasts}");
    let mean_days = days_sum / forecasts as f64;
    assert!(mean_days > 50.0 && mean_days < 300.0, "{mean_days}");
}

#[test]
fn counter_sees_an_allocation_on_the_measuring_thread() {
    // Guards the guard: a Vec allocated while measuring must be counted.
    let (v, allocations) =
        allocations_during(|| std::hint::black_box(Vec::<u64>::with_capacity(16)));
    drop(v);
    assert!(allocations > 0);
}

#[test]
fn rainflow_and_miner_never_allocate() {
    use millgate_dsp::miner::{EnduranceRule, MeanCorrection, SnCurve, SnCurveSettings};
    use millgate_dsp::rainflow::{Rainflow, RainflowSettings};

    let counter = Rainflow::<256>::new(RainflowSettings { gate_knm: 2.0 }).unwrap();
    let curve = SnCurve::new(SnCurveSettings {
        m: 5.0,
        ref_cycles: 2e6,
        ref_range_knm: 100.0,
        torque_share: 0.5,
        endurance_knm: Some(10.0),
        endurance_rule: EnduranceRule::Haibach,
        mean_correction: MeanCorrection::None,
    })
    .unwrap();
    let mut state = counter.state();
    let (mut closed, mut damage, mut residue) = (0.0, 0.0, 0.0);
    let ((), allocations) = allocations_during(|| {
        for i in 0..1_200_000 {
            counter.process(&mut state, torque(i), |cycle| {
                closed += cycle.count;
                damage += curve.damage(&cycle);
            });
            if i % 100_000 == 0 {
                counter.residue(&state, |cycle| residue += curve.damage(&cycle));
            }
        }
    });

    assert_eq!(allocations, 0);
    assert_eq!(state.overflows(), 0);
    // The counts are real: each of the 12 bites rings down through dozens of cycles
    // above the gate, and its entry and exit make a cycle of about 190 kN*m.
    assert!(closed > 12.0 * 20.0, "{closed}");
    assert!(damage > 0.0 && residue > 0.0, "{damage} {residue}");
}
