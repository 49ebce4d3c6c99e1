//! Property tests: no panic and no NaN in any output, on arbitrary input (including
//! all-NaN, constant and huge values).

use millgate_dsp::bite::{BiteDetector, BiteSettings};
use millgate_dsp::chatter::{ChatterDetector, ChatterSettings, StandWindow};
use millgate_dsp::fit::{fit_eq1, FitOptions};
use millgate_dsp::stiffness::{forward, inverse, Inertias, NaturalFrequencies, Stiffness};
use millgate_dsp::transient::{analyze, TransientSettings};
use millgate_dsp::wear_trend::{BiteMoments, GapGrid, WearTrend};
use proptest::prelude::*;

/// Any f64 including NaN, infinities, huge and tiny values.
fn any_sample() -> impl Strategy<Value = f64> {
    prop_oneof![
        4 => -500.0..500.0_f64,
        1 => any::<f64>(),
        1 => Just(f64::NAN),
        1 => Just(f64::INFINITY),
        1 => Just(f64::MAX),
        1 => Just(-f64::MAX),
    ]
}

/// Arbitrary records, plus the special all-NaN, constant and huge-constant ones.
fn record(max_len: usize) -> impl Strategy<Value = Vec<f64>> {
    prop_oneof![
        3 => prop::collection::vec(any_sample(), 0..max_len),
        1 => (0..max_len).prop_map(|n| vec![f64::NAN; n]),
        1 => (0..max_len, -1e3..1e3_f64).prop_map(|(n, v)| vec![v; n]),
        1 => (0..max_len).prop_map(|n| vec![1e300; n]),
    ]
}

fn finite_opt(v: Option<f64>) -> bool {
    v.is_none_or(f64::is_finite)
}

/// The detector of the property tests, `post` samples after its trigger.
fn detector(post: usize) -> BiteDetector<32, 256> {
    BiteDetector::new(BiteSettings {
        threshold_knm: 20.0,
        rearm_knm: 10.0,
        holdoff_samples: 10,
        baseline_alpha: 0.01,
        saturation_low_knm: -400.0,
        saturation_high_knm: 400.0,
        post_trigger_samples: post,
    })
    .unwrap()
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    #[test]
    fn detector_outputs_are_finite(samples in record(3000), gaps in prop::collection::vec(0..3000usize, 0..4)) {
        let detector = detector(200);
        let mut state = detector.state();
        let check = |event: millgate_dsp::bite::BiteEvent<256>| {
            assert!(event.window.iter().all(|v| !v.is_nan()));
            assert!(!event.baseline_knm.is_nan());
            assert!(event.trigger_index < event.window.len());
        };
        for (i, &sample) in samples.iter().enumerate() {
            if gaps.contains(&i) {
                if let Some(event) = detector.gap(&mut state, 3) {
                    check(event);
                }
            }
            if i % 7 == 0 {
                let _ = detector.trigger(&mut state);
            }
            if let Some(event) = detector.process(&mut state, sample) {
                check(event);
            }
        }
        prop_assert!(!state.baseline_knm().is_nan());
    }

    /// `samples_to_window_end` is a bound a caller can plan on: a window comes from
    /// `process` only at the sample it counted down to, and from `gap` only while
    /// one is being captured.
    #[test]
    fn a_window_comes_only_when_its_samples_are_in(samples in record(3000), gaps in prop::collection::vec(0..3000usize, 0..4), post in 1..200usize) {
        let detector = detector(post);
        let mut state = detector.state();
        let mut windows = 0;
        for (i, &sample) in samples.iter().enumerate() {
            if gaps.contains(&i) {
                let capturing = state.is_capturing();
                let ended = detector.gap(&mut state, 3).is_some();
                prop_assert!(!ended || capturing, "a gap handed a window over with none captured");
            }
            if i % 7 == 0 {
                let _ = detector.trigger(&mut state);
            }
            let before = detector.samples_to_window_end(&state);
            prop_assert!(before >= 1);
            if detector.process(&mut state, sample).is_some() {
                windows += 1;
                prop_assert_eq!(before, 1, "a window came with {} samples still to go", before);
            }
        }
        prop_assert!(windows <= samples.len() / post.max(1));
    }

    #[test]
    fn transient_outputs_are_finite(window in record(600), trigger in 0..600usize, baseline in any_sample()) {
        let settings = TransientSettings {
            sample_rate_hz: 1000.0,
            period_lowpass_hz: 20.0,
            peak_lowpass_hz: Some(60.0),
            settled_fraction: 0.3,
            min_static_knm: 1.0,
            reference_shift_s: Some(0.001),
        };
        if let Ok(r) = analyze::<600>(&window, trigger, baseline, &settings) {
            prop_assert!(r.static_torque_knm.is_finite() && r.peak_torque_knm.is_finite());
            prop_assert!(r.peak_time_s.is_finite());
            prop_assert!(finite_opt(r.taf) && finite_opt(r.first_period_s));
            prop_assert!(finite_opt(r.second_period_s) && finite_opt(r.period_shift_s));
            prop_assert!(finite_opt(r.shift_excess_s) && finite_opt(r.rise_time_s));
        }
    }

    #[test]
    fn fit_outputs_are_finite(samples in record(400), positive_only in any::<bool>()) {
        let options = FitOptions { positive_only, ..FitOptions::new(1000.0) };
        if let Ok(fit) = fit_eq1(&samples, &options) {
            prop_assert!(fit.params.iter().all(|v| v.is_finite()));
            prop_assert!(fit.f1_hz <= fit.f2_hz);
            prop_assert!(fit.zeta1.is_finite() && fit.zeta2.is_finite());
            prop_assert!(fit.rms_residual.is_finite() && finite_opt(fit.taf));
        }
    }

    #[test]
    fn chatter_outputs_are_finite(
        a in prop::collection::vec(any_sample(), 64),
        b in prop::collection::vec(any_sample(), 64),
        magnitude_a in prop::collection::vec(any_sample(), 33),
        magnitude_b in prop::collection::vec(any_sample(), 33),
    ) {
        let detector = ChatterDetector::new(ChatterSettings {
            band_low_hz: 3.0, band_high_hz: 20.0, k_max: 0.25,
        }).unwrap();
        let abs = |m: &[f64]| m.iter().map(|v| v.abs()).collect::<Vec<f64>>();
        let (ma, mb) = (abs(&magnitude_a), abs(&magnitude_b));
        let stands = [
            StandWindow { magnitude: &ma, signal: &a },
            StandWindow { magnitude: &mb, signal: &b },
        ];
        if let Ok(r) = detector.evaluate(&stands, 1.0) {
            prop_assert!(r.sigma_n_hz.is_finite() && r.k_mean.is_finite());
            prop_assert!((-1.0..=1.0).contains(&r.k_mean));
            for s in &r.stands {
                prop_assert!(s.principal_hz.is_finite() && s.amplitude.is_finite());
                prop_assert!(s.band_energy.is_finite());
            }
        }
    }

    #[test]
    fn stiffness_outputs_are_finite(values in prop::collection::vec(any_sample(), 7)) {
        let q = Inertias { q1_kgm2: values[0], q2_kgm2: values[1], q3_kgm2: values[2] };
        let c = Stiffness { c12_nm_per_rad: values[3], c23_nm_per_rad: values[4] };
        if let Ok(beta) = forward(&q, &c) {
            prop_assert!(beta.beta1_hz.is_finite() && beta.beta2_hz.is_finite());
        }
        let beta = NaturalFrequencies { beta1_hz: values[5], beta2_hz: values[6] };
        if let Ok(roots) = inverse(&q, &beta, Some(&c)) {
            for root in &roots {
                prop_assert!(root.c12_nm_per_rad.is_finite() && root.c23_nm_per_rad.is_finite());
            }
        }
    }

    #[test]
    fn wear_trend_outputs_are_finite_for_finite_input(
        steps in prop::collection::vec(
            (0.0..3.0_f64, prop::collection::vec(-1e3..1e3_f64, 3), -10.0..20.0_f64, 0.0..2.0_f64, any::<u8>()),
            0..60,
        ),
        couplings in 0..4usize,
        alarm in -5.0..50.0_f64,
    ) {
        let fine = GapGrid { first_mrad: 0.0, step_mrad: 0.125, len: 65 };
        let trend = WearTrend::new(365.0).unwrap();
        let mut state = trend.state(couplings).unwrap();
        let mut t = 0.0;
        for (dt, shape, mean, var, choice) in steps {
            // Steps of 0 (same time), tiny and long; any time error leaves the state as is.
            t += if choice % 5 == 0 { 0.0 } else if choice % 5 == 1 { dt * 1e-7 } else { dt * dt * dt };
            let before = state;
            if trend.predict(&mut state, t).is_err() {
                prop_assert_eq!(state, before);
                continue;
            }
            for k in 0..couplings {
                let grid = trend.grid(&state, k, fine);
                prop_assert!(grid.first_mrad >= 0.0 && grid.last_mrad() <= fine.last_mrad() + 1e-9);
                // A quadratic log-likelihood of any curvature and centre, or a flat one.
                let ll: Vec<f64> = (0..grid.len)
                    .map(|i| {
                        let g = grid.at(i);
                        shape[0] * 1e-3 - (shape[1] * 1e-3).abs() * (g - shape[2] * 1e-2).powi(2)
                    })
                    .collect();
                if let Ok(own) = BiteMoments::from_loglik(grid, &ll) {
                    prop_assert!(own.mean_mrad.is_finite() && own.var_mrad2.is_finite());
                    prop_assert!(own.var_mrad2 > 0.0);
                    prop_assert!(own.mean_mrad >= grid.first_mrad - 1e-9 && own.mean_mrad <= grid.last_mrad() + 1e-9);
                }
                let bite = BiteMoments { mean_mrad: mean, var_mrad2: var };
                let before = state;
                let outcome = if choice % 3 == 0 {
                    trend.update_gaussian(&mut state, k, mean, var + 1e-6)
                } else {
                    trend.update(&mut state, k, grid, &ll, bite)
                };
                if outcome.is_err() {
                    prop_assert_eq!(state, before);
                }
            }
            trend.finish_bite(&mut state, (choice % 4 == 0).then_some(var * 1e-2));
            for h in &state.hypotheses[..couplings] {
                prop_assert!(h.gap_mrad.is_finite() && h.rate_mrad_per_day.is_finite() && h.loglik.is_finite());
                prop_assert!(h.p.iter().flatten().all(|v| v.is_finite()));
                prop_assert!(h.p[0][0] > 0.0 && h.p[1][1] >= 0.0 && h.p[0][1] == h.p[1][0]);
            }
            if let Some(e) = trend.estimate(&state) {
                prop_assert!(e.gap_mrad.is_finite() && e.gap_low_mrad.is_finite() && e.gap_high_mrad.is_finite());
                prop_assert!(e.gap_low_mrad >= 0.0 && e.gap_low_mrad <= e.gap_high_mrad);
                prop_assert!(finite_opt(e.rate_mrad_per_day) && finite_opt(e.rate_low_mrad_per_day));
                prop_assert!(finite_opt(e.rate_high_mrad_per_day));
            }
            let f = trend.forecast(&state, alarm);
            prop_assert!(finite_opt(f.days) && finite_opt(f.days_low) && finite_opt(f.days_high));
            for days in [f.days, f.days_low, f.days_high].into_iter().flatten() {
                prop_assert!((0.0..=365.0).contains(&days));
            }
            if let Some(band) = trend.band(&state, dt * 100.0) {
                prop_assert!(band.mean_mrad.is_finite() && band.high_mrad.is_finite() && band.low_mrad.is_finite());
                prop_assert!(band.low_mrad >= 0.0 && band.high_mrad >= band.mean_mrad);
            }
        }
    }

    #[test]
    fn rainflow_cycles_and_damage_are_never_nan(samples in record(3000), gate in 0.0..50.0_f64) {
        use millgate_dsp::miner::{EnduranceRule, MeanCorrection, SnCurve, SnCurveSettings};
        use millgate_dsp::rainflow::{Cycle, Rainflow, RainflowSettings};
        let counter = Rainflow::<8>::new(RainflowSettings { gate_knm: gate }).unwrap();
        let curve = SnCurve::new(SnCurveSettings {
            m: 6.0,
            ref_cycles: 1e6,
            ref_range_knm: 100.0,
            torque_share: 0.5,
            endurance_knm: Some(10.0),
            endurance_rule: EnduranceRule::Haibach,
            mean_correction: MeanCorrection::Goodman { ultimate_knm: 500.0 },
        }).unwrap();
        let check = |cycle: Cycle| {
            assert!(cycle.range_knm >= 0.0 && !cycle.mean_knm.is_nan(), "{cycle:?}");
            assert!(cycle.count == 1.0 || cycle.count == 0.5);
            let damage = curve.damage(&cycle);
            assert!((0.0..=cycle.count).contains(&damage), "{damage} of {cycle:?}");
        };
        let mut state = counter.state();
        counter.block(&mut state, &samples, check);
        counter.residue(&state, check);
        prop_assert!(state.residue_len() <= 8);
        let bad = samples.iter().filter(|v| !v.is_finite()).count() as u64;
        prop_assert_eq!(state.non_finite(), bad);
    }
}
