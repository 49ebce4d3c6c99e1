//! The wear trend on synthetic bites: each bite measures two quantities that depend on
//! the gap through a coupling's "map" (a TAF-like and a shift-like line, different per
//! coupling), with Gaussian noise and a 2% uniform outlier part, as the gateway's
//! likelihood has. The filter sees only the per-point log-likelihoods on its grids.

use millgate_dsp::wear_trend::{
    BiteMoments, ForecastReason, GapGrid, Phase, TrendError, TrendEstimate, WearTrend,
    WearTrendState, Z90,
};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use rand_distr::{Distribution, Normal};

/// The maps' fine grid: 0 ..= 8 mrad every 1/32 mrad.
const FINE: GapGrid = GapGrid {
    first_mrad: 0.0,
    step_mrad: 0.031_25,
    len: 257,
};
const OUTLIER_WEIGHT: f64 = 0.02;
/// Spans the outlier part of each measure spreads over.
const SPANS: [f64; 2] = [2.0, 100.0];
/// Per coupling, per measure: intercept and slope per mrad of gap.
const MAPS: [[(f64, f64); 2]; 2] = [[(1.30, 0.05), (0.0, 0.5)], [(1.20, 0.08), (1.0, -0.3)]];

/// One bite's two measures (noise sigmas `SIGMAS`), drawn at gap `gap` of `coupling`.
struct Bite {
    measures: [f64; 2],
    sigmas: [f64; 2],
}

impl Bite {
    fn draw(rng: &mut StdRng, coupling: usize, gap: f64, noise: f64) -> Self {
        let sigmas = [0.004 * noise, 0.1 * noise];
        let measures = core::array::from_fn(|m| {
            let (a, b) = MAPS[coupling][m];
            a + b * gap + Normal::new(0.0, sigmas[m]).unwrap().sample(rng)
        });
        Self { measures, sigmas }
    }

    /// Log-likelihood of the bite at `gap` under `coupling`.
    fn loglik(&self, coupling: usize, gap: f64) -> f64 {
        (0..2)
            .map(|m| {
                let (a, b) = MAPS[coupling][m];
                let z = (self.measures[m] - a - b * gap) / self.sigmas[m];
                let gauss =
                    (-0.5 * z * z).exp() / (self.sigmas[m] * (2.0 * std::f64::consts::PI).sqrt());
                ((1.0 - OUTLIER_WEIGHT) * gauss + OUTLIER_WEIGHT / SPANS[m]).ln()
            })
            .sum()
    }

    fn on(&self, coupling: usize, grid: GapGrid) -> Vec<f64> {
        (0..grid.len)
            .map(|i| self.loglik(coupling, grid.at(i)))
            .collect()
    }

    /// The flat-prior posterior on the fine grid.
    fn moments(&self, coupling: usize) -> BiteMoments {
        BiteMoments::from_loglik(FINE, &self.on(coupling, FINE)).unwrap()
    }
}

/// Folds `bite` at `t_days` into every hypothesis; whether one jumped.
fn fold(trend: &WearTrend, state: &mut WearTrendState, t_days: f64, bite: &Bite) -> bool {
    trend.predict(state, t_days).unwrap();
    let mut jumped = false;
    for k in 0..state.couplings {
        let grid = trend.grid(state, k, FINE);
        let ll = bite.on(k, grid);
        jumped |= trend
            .update(state, k, grid, &ll, bite.moments(k))
            .unwrap()
            .jumped;
    }
    trend.finish_bite(state, None);
    jumped
}

/// Bite times over `days` days: `per_day` bites between 06:00 and 22:00 on weekdays,
/// none on weekends (day 5 and 6 of each week).
fn weekday_times(rng: &mut StdRng, days: usize, per_day: usize) -> Vec<f64> {
    let mut times = Vec::new();
    for day in (0..days).filter(|d| d % 7 < 5) {
        let mut today: Vec<f64> = (0..per_day)
            .map(|_| day as f64 + rng.random_range(0.25..0.9166))
            .collect();
        today.sort_by(f64::total_cmp);
        times.extend(today);
    }
    times
}

fn inside(value: f64, low: f64, high: f64) -> bool {
    low <= value && value <= high
}

/// Whether the estimate's growth interval holds `rate` (mrad/day).
fn rate_holds(e: &TrendEstimate, rate: f64) -> bool {
    inside(
        rate,
        e.rate_low_mrad_per_day.unwrap(),
        e.rate_high_mrad_per_day.unwrap(),
    )
}

#[test]
fn a_linear_ramp_is_recovered_with_gap_and_rate_in_their_intervals() {
    let trend = WearTrend::new(365.0).unwrap();
    let mut state = trend.state(2).unwrap();
    let mut rng = StdRng::seed_from_u64(37);
    let truth = |t: f64| 0.8 + 0.03 * t;
    let (mut days, mut held, mut rate_held, mut last_day) = (0, 0, 0, 0);
    for t in weekday_times(&mut rng, 70, 20) {
        let bite = Bite::draw(&mut rng, 1, truth(t), 1.0);
        fold(&trend, &mut state, t, &bite);
        if t as usize > last_day && t > 3.0 {
            // Once a day: does the interval hold the truth?
            last_day = t as usize;
            let e = trend.estimate(&state).unwrap();
            days += 1;
            held += inside(truth(t), e.gap_low_mrad, e.gap_high_mrad) as usize;
            rate_held += rate_holds(&e, 0.03) as usize;
        }
    }
    let e = trend.estimate(&state).unwrap();
    let t = state.t_last_days.unwrap();
    assert_eq!(e.coupling, Some(1));
    assert!(inside(truth(t), e.gap_low_mrad, e.gap_high_mrad), "{e:?}");
    let (rate, low, high) = (
        e.rate_mrad_per_day.unwrap(),
        e.rate_low_mrad_per_day.unwrap(),
        e.rate_high_mrad_per_day.unwrap(),
    );
    assert!(inside(0.03, low, high), "{e:?}");
    assert!((rate - 0.03).abs() < 0.005, "{rate}");
    // The interval is informative, not merely wide.
    assert!(e.gap_high_mrad - e.gap_low_mrad < 0.2, "{e:?}");
    assert!(
        held as f64 >= 0.85 * days as f64,
        "gap held on {held} of {days} days"
    );
    assert!(
        rate_held as f64 >= 0.85 * days as f64,
        "rate held on {rate_held} of {days} days"
    );
    // The forecast: 4 mrad at day (4 - 0.8) / 0.03 = 106.7.
    let f = trend.forecast(&state, 4.0);
    assert_eq!(f.reason, ForecastReason::Forecast);
    let remaining = (4.0 - 0.8) / 0.03 - t;
    assert!(
        inside(remaining, f.days_low.unwrap(), f.days_high.unwrap()),
        "{f:?} vs {remaining}"
    );
    assert!(
        (f.days.unwrap() - remaining).abs() < 0.15 * remaining,
        "{f:?}"
    );
    assert!(f.days_low.unwrap() <= f.days.unwrap() && f.days.unwrap() <= f.days_high.unwrap());
}

#[test]
fn a_constant_gap_shows_no_growth_and_no_forecast() {
    let trend = WearTrend::new(365.0).unwrap();
    let mut state = trend.state(2).unwrap();
    let mut rng = StdRng::seed_from_u64(38);
    for t in weekday_times(&mut rng, 60, 20) {
        fold(&trend, &mut state, t, &Bite::draw(&mut rng, 1, 1.7, 1.0));
    }
    let e = trend.estimate(&state).unwrap();
    assert!(inside(1.7, e.gap_low_mrad, e.gap_high_mrad), "{e:?}");
    assert!(rate_holds(&e, 0.0), "{e:?}");
    let f = trend.forecast(&state, 4.0);
    assert!(
        matches!(
            f.reason,
            ForecastReason::NotGrowing | ForecastReason::BeyondHorizon
        ),
        "{f:?}"
    );
    assert_eq!(f.days, None);
    // No near alarm: the early side does not reach 4 mrad within 30 days.
    assert!(f.days_low.is_none_or(|d| d > 30.0), "{f:?}");
}

#[test]
fn a_weekend_and_an_outage_widen_the_prediction_and_the_trend_carries_on() {
    let trend = WearTrend::new(365.0).unwrap();
    let mut state = trend.state(1).unwrap();
    let mut rng = StdRng::seed_from_u64(39);
    let truth = |t: f64| 1.0 + 0.04 * t;
    // Weekdays of four weeks, then nothing for 10 days, then two more weeks.
    let times: Vec<f64> = weekday_times(&mut rng, 42, 20)
        .into_iter()
        .filter(|&t| !(28.0..38.0).contains(&t))
        .collect();
    let mut checked = 0;
    for pair in times.windows(2) {
        let (t, next) = (pair[0], pair[1]);
        fold(
            &trend,
            &mut state,
            t,
            &Bite::draw(&mut rng, 0, truth(t), 1.0),
        );
        if next - t > 2.0 {
            // A weekend (~2.5 days) or the outage: the prediction over it widens with
            // the time, and it still holds the truth.
            let before = state.hypotheses[0].p[0][0];
            let mut ahead = state;
            trend.predict(&mut ahead, next).unwrap();
            let widened = ahead.hypotheses[0].p[0][0];
            assert!(widened > before, "{before} -> {widened}");
            let sd = widened.sqrt();
            let predicted = ahead.hypotheses[0].gap_mrad;
            assert!(
                (predicted - truth(next)).abs() < Z90 * 2.0 * sd + 0.05,
                "over {:.1} d: {predicted} vs {} (sd {sd})",
                next - t,
                truth(next)
            );
            checked += 1;
        }
    }
    assert_eq!(checked, 4, "three weekends and the outage");
    let e = trend.estimate(&state).unwrap();
    let t = state.t_last_days.unwrap();
    assert!(inside(truth(t), e.gap_low_mrad, e.gap_high_mrad), "{e:?}");
    assert!(rate_holds(&e, 0.04), "{e:?}");
}

#[test]
fn reset_starts_afresh() {
    let trend = WearTrend::new(365.0).unwrap();
    let mut state = trend.state(2).unwrap();
    let mut rng = StdRng::seed_from_u64(40);
    for i in 0..30 {
        let t = i as f64 * 0.1;
        fold(
            &trend,
            &mut state,
            t,
            &Bite::draw(&mut rng, 1, 1.0 + 0.02 * t, 1.0),
        );
    }
    assert!(trend.estimate(&state).is_some());
    trend.reset(&mut state, 2).unwrap();
    assert_eq!(state, trend.state(2).unwrap());
    assert_eq!(trend.estimate(&state), None);
    assert_eq!(
        trend.forecast(&state, 4.0).reason,
        ForecastReason::NoEstimate
    );
    // A time before the old bites is fine after a reset: there is no last bite.
    fold(&trend, &mut state, -5.0, &Bite::draw(&mut rng, 0, 2.5, 1.0));
    assert_eq!(state.bites, 1);
    assert_eq!(
        trend.reset(&mut state, 9),
        Err(TrendError::Couplings),
        "more hypotheses than room"
    );
    assert_eq!(state.bites, 1, "unchanged on an error");
}

#[test]
fn a_jump_of_the_gap_reopens_the_hypothesis_and_is_followed() {
    let trend = WearTrend::new(365.0).unwrap();
    let mut state = trend.state(1).unwrap();
    let mut rng = StdRng::seed_from_u64(41);
    let times = weekday_times(&mut rng, 40, 20);
    let step_at = 21.0;
    let mut jumps = Vec::new();
    for &t in &times {
        let gap = if t < step_at { 1.0 } else { 2.5 };
        if fold(&trend, &mut state, t, &Bite::draw(&mut rng, 0, gap, 1.0)) {
            jumps.push(t);
        }
    }
    assert_eq!(jumps.len(), 1, "{jumps:?}");
    let bites_to_jump = times
        .iter()
        .filter(|&&t| t >= step_at && t <= jumps[0])
        .count();
    assert_eq!(bites_to_jump, 10, "the tenth far bite reopens");
    let e = trend.estimate(&state).unwrap();
    assert!(inside(2.5, e.gap_low_mrad, e.gap_high_mrad), "{e:?}");
    assert!(rate_holds(&e, 0.0), "{e:?}");
}

#[test]
fn the_demo_time_scale_is_followed_from_the_second_bite() {
    // The demo compresses wear: 1 -> 3 mrad over 20 s (8 640 mrad/day), bites 2 s apart,
    // with no growth span (its configuration's `growth_span_s = 0`).
    let mut trend = WearTrend::new(365.0).unwrap();
    trend.set_growth_span_days(0.0).unwrap();
    let mut state = trend.state(2).unwrap();
    let mut rng = StdRng::seed_from_u64(42);
    let day_s = 86_400.0;
    let rate = 0.1 * day_s;
    let mut held = 0;
    for bar in 0..11 {
        let t = 20_000.0 + 2.0 * bar as f64 / day_s;
        let truth = 1.0 + 0.2 * bar as f64;
        fold(&trend, &mut state, t, &Bite::draw(&mut rng, 1, truth, 1.0));
        let e = trend.estimate(&state).unwrap();
        held += inside(truth, e.gap_low_mrad, e.gap_high_mrad) as usize;
    }
    assert_eq!(held, 11);
    let e = trend.estimate(&state).unwrap();
    let r = e.rate_mrad_per_day.unwrap();
    assert!((r / rate - 1.0).abs() < 0.05, "{} mrad/s", r / day_s);
    assert!(rate_holds(&e, rate));
    // The alarm at 4 mrad comes 10 s after the last bar (3 mrad).
    let f = trend.forecast(&state, 4.0);
    assert_eq!(f.reason, ForecastReason::Forecast);
    let seconds = |d: Option<f64>| d.unwrap() * day_s;
    assert!((seconds(f.days) - 10.0).abs() < 1.0, "{f:?}");
    assert!(
        seconds(f.days_low) <= 10.0 && seconds(f.days_high) >= 10.0,
        "{f:?}"
    );
}

#[test]
fn the_forecast_gives_each_reason() {
    let trend = WearTrend::new(365.0).unwrap();
    let mut state = trend.state(1).unwrap();
    assert_eq!(
        trend.forecast(&state, 4.0).reason,
        ForecastReason::NoEstimate
    );
    // Four bites a day apart: too few.
    let observe = |state: &mut WearTrendState, t: f64, gap: f64| {
        trend.predict(state, t).unwrap();
        trend.update_gaussian(state, 0, gap, 1e-4).unwrap();
        trend.finish_bite(state, None);
    };
    for day in 0..4 {
        observe(&mut state, day as f64, 1.0 + 0.05 * day as f64);
    }
    assert_eq!(
        trend.forecast(&state, 4.0).reason,
        ForecastReason::TooFewBites
    );
    // Ten bites, all at one time: no rate, too few.
    let mut one_time = trend.state(1).unwrap();
    for _ in 0..10 {
        observe(&mut one_time, 3.0, 1.0);
    }
    assert_eq!(one_time.hypotheses[0].phase, Phase::GapOnly);
    assert_eq!(trend.estimate(&one_time).unwrap().rate_mrad_per_day, None);
    assert_eq!(
        trend.forecast(&one_time, 4.0).reason,
        ForecastReason::TooFewBites
    );
    // Growing 0.05 mrad/day from 1 mrad: 4 mrad at day 60.
    for day in 4..20 {
        observe(&mut state, day as f64, 1.0 + 0.05 * day as f64);
    }
    let f = trend.forecast(&state, 4.0);
    assert_eq!(f.reason, ForecastReason::Forecast);
    assert!((f.days.unwrap() - 41.0).abs() < 1.0, "{f:?}");
    // The alarm below the gap: at the alarm, days 0.
    let f = trend.forecast(&state, 1.5);
    assert_eq!(
        (f.reason, f.days, f.days_low),
        (ForecastReason::AtAlarm, Some(0.0), Some(0.0))
    );
    // An alarm the mean reaches after the horizon (13 mrad: 221 days; horizon 200).
    let short = WearTrend::new(200.0).unwrap();
    let f = short.forecast(&state, 13.0);
    assert_eq!(
        (f.reason, f.days, f.days_high),
        (ForecastReason::BeyondHorizon, None, None)
    );
    assert!(
        f.days_low.is_some_and(|d| d < 200.0),
        "the early side gets there: {f:?}"
    );
    // Shrinking: not growing.
    let mut shrinking = trend.state(1).unwrap();
    for day in 0..20 {
        observe(&mut shrinking, day as f64, 3.0 - 0.02 * day as f64);
    }
    let f = trend.forecast(&shrinking, 4.0);
    assert_eq!(
        (f.reason, f.days, f.days_high),
        (ForecastReason::NotGrowing, None, None)
    );
    // A non-finite alarm has no forecast.
    assert_eq!(
        trend.forecast(&state, f64::NAN).reason,
        ForecastReason::NoEstimate
    );
    let keys: Vec<&str> = ForecastReason::ALL.iter().map(|r| r.key()).collect();
    assert_eq!(
        keys,
        [
            "forecast",
            "at_alarm",
            "not_growing",
            "beyond_horizon",
            "too_few_bites",
            "no_estimate"
        ]
    );
}

#[test]
fn the_coupling_is_named_when_one_hypothesis_wins_by_ln_100() {
    let trend = WearTrend::new(365.0).unwrap();
    for truth in [0, 1] {
        let mut state = trend.state(2).unwrap();
        let mut rng = StdRng::seed_from_u64(43 + truth as u64);
        for i in 0..40 {
            let t = i as f64 * 0.05;
            fold(
                &trend,
                &mut state,
                t,
                &Bite::draw(&mut rng, truth, 2.0 + 0.03 * t, 1.0),
            );
        }
        let e = trend.estimate(&state).unwrap();
        assert_eq!((e.coupling, e.likeliest), (Some(truth), truth), "{e:?}");
        let lead = state.hypotheses[truth].loglik - state.hypotheses[1 - truth].loglik;
        assert!(lead > 4.6, "{lead}");
    }
    // Two hypotheses told the same: neither named, the interval spans both.
    let mut state = trend.state(2).unwrap();
    for i in 0..20 {
        trend.predict(&mut state, i as f64).unwrap();
        trend.update_gaussian(&mut state, 0, 1.0, 0.01).unwrap();
        trend.update_gaussian(&mut state, 1, 2.0, 0.01).unwrap();
        trend.finish_bite(&mut state, None);
    }
    let e = trend.estimate(&state).unwrap();
    assert_eq!(e.coupling, None);
    assert!(e.gap_low_mrad < 1.0 && e.gap_high_mrad > 2.0, "{e:?}");
}

#[test]
fn the_model_floor_widens_the_published_interval() {
    let trend = WearTrend::new(365.0).unwrap();
    let mut state = trend.state(1).unwrap();
    for i in 0..50 {
        trend.predict(&mut state, i as f64 * 0.1).unwrap();
        trend.update_gaussian(&mut state, 0, 1.0, 0.01).unwrap();
        trend.finish_bite(&mut state, if i % 10 == 0 { Some(0.04) } else { None });
    }
    let e = trend.estimate(&state).unwrap();
    let sd = (state.hypotheses[0].p[0][0] + 0.04).sqrt();
    assert!((e.gap_high_mrad - 1.0 - Z90 * sd).abs() < 1e-9, "{e:?}");
    // NaN or negative floors are no measurement.
    trend.finish_bite(&mut state, Some(f64::NAN));
    assert_eq!(state.floor2_mrad2, 0.04);
}

#[test]
fn grid_updates_agree_with_the_gaussian_update_for_a_gaussian_likelihood() {
    // The moment-matched update on a grid, for a Gaussian likelihood, is the Kalman
    // update (to the grid's resolution).
    let trend = WearTrend::new(365.0).unwrap();
    let (mut grid_state, mut gauss_state) = (trend.state(1).unwrap(), trend.state(1).unwrap());
    let mut rng = StdRng::seed_from_u64(44);
    let sd = 0.05;
    for i in 0..200 {
        let t = i as f64 * 0.3;
        let y = 1.0 + 0.01 * t + Normal::new(0.0, sd).unwrap().sample(&mut rng);
        trend.predict(&mut grid_state, t).unwrap();
        let grid = trend.grid(&grid_state, 0, FINE);
        let norm = -(sd * (2.0 * std::f64::consts::PI).sqrt()).ln();
        let ll: Vec<f64> = (0..grid.len)
            .map(|i| norm - 0.5 * ((y - grid.at(i)) / sd).powi(2))
            .collect();
        let moments = BiteMoments {
            mean_mrad: y,
            var_mrad2: sd * sd,
        };
        trend
            .update(&mut grid_state, 0, grid, &ll, moments)
            .unwrap();
        trend.finish_bite(&mut grid_state, None);
        // The grid path divides the log-likelihood by its adaptive scale: the same
        // variance for the Gaussian path.
        let scale = grid_state.hypotheses[0].scale;
        trend.predict(&mut gauss_state, t).unwrap();
        trend
            .update_gaussian(&mut gauss_state, 0, y, scale * sd * sd)
            .unwrap();
        trend.finish_bite(&mut gauss_state, None);
    }
    let (a, b) = (grid_state.hypotheses[0], gauss_state.hypotheses[0]);
    assert!(a.scale > 1.0, "the scale moved: the comparison covers it");
    assert!((a.gap_mrad - b.gap_mrad).abs() < 1e-3, "{a:?} {b:?}");
    assert!(
        (a.rate_mrad_per_day - b.rate_mrad_per_day).abs() < 1e-4,
        "{a:?} {b:?}"
    );
    // Variances within 5%: the first two bites (flat prior) are taken on the fine grid,
    // whose step^2/12 adds 3% to their variance, and the rate remembers them.
    assert!((a.p[0][0] / b.p[0][0] - 1.0).abs() < 0.05, "{a:?} {b:?}");
    assert!((a.p[1][1] / b.p[1][1] - 1.0).abs() < 0.05, "{a:?} {b:?}");
}

#[test]
fn bites_within_the_growth_span_are_one_gap_and_the_rate_comes_after_it() {
    // A constant 3 mrad in coupling 0, bites a bar (1.8 s) apart: within the default
    // hour no rate is taken, the estimate is every bite's; the first bite after the
    // hour starts the growth.
    let mut rng = StdRng::seed_from_u64(7);
    // `bars` bites of the 3 mrad gap from day 100 on, a bar apart.
    let fold_bars = |trend: &WearTrend, state: &mut WearTrendState, rng: &mut StdRng, bars| {
        for bar in 0..bars {
            let t = 100.0 + f64::from(bar) * 1.8 / 86_400.0;
            fold(trend, state, t, &Bite::draw(rng, 0, 3.0, 1.0));
        }
    };
    let trend = WearTrend::new(365.0).unwrap();
    let mut state = trend.state(2).unwrap();
    fold_bars(&trend, &mut state, &mut rng, 10);
    assert!(state.hypotheses[..2]
        .iter()
        .all(|h| h.phase == Phase::GapOnly));
    let e = trend.estimate(&state).unwrap();
    assert_eq!(e.rate_mrad_per_day, None);
    assert!(inside(3.0, e.gap_low_mrad, e.gap_high_mrad), "{e:?}");
    assert_eq!(e.coupling, Some(0), "{e:?}");
    let bite = Bite::draw(&mut rng, 0, 3.0, 1.0);
    fold(&trend, &mut state, 100.0 + 2.0 / 24.0, &bite);
    assert_eq!(state.hypotheses[0].phase, Phase::Tracking);
    // With no span the second bite already gives a rate.
    let mut eager = WearTrend::new(365.0).unwrap();
    eager.set_growth_span_days(0.0).unwrap();
    let mut state = eager.state(1).unwrap();
    fold_bars(&eager, &mut state, &mut rng, 2);
    assert_eq!(state.hypotheses[0].phase, Phase::Tracking);
    // Refused spans leave it as it was.
    for bad in [-1.0, f64::NAN, 30.5, f64::INFINITY] {
        assert_eq!(eager.set_growth_span_days(bad), Err(TrendError::GrowthSpan));
    }
    assert_eq!(eager.growth_span_days(), 0.0);
}

#[test]
fn the_information_form_start_gives_the_two_point_rate() {
    let mut trend = WearTrend::new(365.0).unwrap();
    trend.set_growth_span_days(0.0).unwrap();
    let mut state = trend.state(1).unwrap();
    trend.predict(&mut state, 10.0).unwrap();
    trend.update_gaussian(&mut state, 0, 1.0, 0.01).unwrap();
    trend.finish_bite(&mut state, None);
    trend.predict(&mut state, 12.0).unwrap();
    trend.update_gaussian(&mut state, 0, 1.2, 0.02).unwrap();
    trend.finish_bite(&mut state, None);
    let h = state.hypotheses[0];
    assert_eq!(h.phase, Phase::Tracking);
    assert!((h.rate_mrad_per_day - 0.1).abs() < 1e-12);
    // (V1 + V2) / dt^2 plus the process noise over dt: q_rate dt / 3 + q_gap / dt.
    let expected = 0.03 / 4.0 + 2e-6 * 2.0 / 3.0 + 1e-5 / 2.0;
    assert!((h.p[1][1] - expected).abs() < 1e-12, "{:?}", h.p);
    assert!((h.p[0][1] - 0.01).abs() < 1e-12 && (h.p[0][0] - 0.02).abs() < 1e-12);
}

#[test]
fn bad_input_is_an_error_and_changes_nothing() {
    let trend = WearTrend::new(365.0).unwrap();
    assert_eq!(WearTrend::new(0.0), Err(TrendError::HorizonDays));
    assert_eq!(WearTrend::new(f64::NAN), Err(TrendError::HorizonDays));
    let mut state = trend.state(2).unwrap();
    let bite = BiteMoments {
        mean_mrad: 1.0,
        var_mrad2: 0.01,
    };
    let ll = vec![0.0; FINE.len];
    assert_eq!(
        trend.update(&mut state, 0, FINE, &ll, bite),
        Err(TrendError::NoTime)
    );
    for i in 0..10 {
        trend.predict(&mut state, i as f64).unwrap();
        for k in 0..2 {
            trend
                .update_gaussian(&mut state, k, 1.0 + 0.1 * i as f64, 0.01)
                .unwrap();
        }
        trend.finish_bite(&mut state, None);
    }
    let before = state;
    assert_eq!(
        trend.predict(&mut state, 8.5),
        Err(TrendError::TimeBackwards)
    );
    assert_eq!(
        trend.predict(&mut state, f64::NAN),
        Err(TrendError::NotFinite)
    );
    assert_eq!(trend.predict(&mut state, 1e9), Err(TrendError::TimeStep));
    trend.predict(&mut state, 9.0).unwrap();
    assert_eq!(state, before, "a zero step predicts nothing");
    let mut nan = ll.clone();
    nan[3] = f64::NAN;
    let cases: [(GapGrid, &[f64], BiteMoments, usize, TrendError); 7] = [
        (FINE, &nan, bite, 0, TrendError::NotFinite),
        (FINE, &ll[1..], bite, 0, TrendError::GridLength),
        (
            GapGrid { len: 1, ..FINE },
            &ll[..1],
            bite,
            0,
            TrendError::EmptyGrid,
        ),
        (
            GapGrid {
                step_mrad: -1.0,
                ..FINE
            },
            &ll,
            bite,
            0,
            TrendError::EmptyGrid,
        ),
        (FINE, &ll, bite, 2, TrendError::Coupling),
        (
            FINE,
            &[f64::NEG_INFINITY; 257],
            bite,
            0,
            TrendError::NotFinite,
        ),
        (
            FINE,
            &ll,
            BiteMoments {
                var_mrad2: -1.0,
                ..bite
            },
            0,
            TrendError::Observation,
        ),
    ];
    for (grid, ll, bite, k, error) in cases {
        assert_eq!(trend.update(&mut state, k, grid, ll, bite), Err(error));
        assert_eq!(state, before);
    }
    assert_eq!(
        trend.update(&mut state, 0, FINE, &vec![2e6; FINE.len], bite),
        Err(TrendError::LogLikelihood)
    );
    assert_eq!(
        trend.update_gaussian(&mut state, 0, 1.0, 0.0),
        Err(TrendError::Observation)
    );
    assert_eq!(
        trend.update_gaussian(&mut state, 0, f64::INFINITY, 1.0),
        Err(TrendError::NotFinite)
    );
    assert_eq!(state, before);
    // Every error is a sentence.
    assert_eq!(
        TrendError::TimeBackwards.to_string(),
        "the bite's time is before the last bite's"
    );
}

#[test]
fn the_covariance_stays_symmetric_positive_semidefinite_over_a_million_updates() {
    let trend = WearTrend::new(365.0).unwrap();
    let mut state = trend.state(2).unwrap();
    let mut rng = StdRng::seed_from_u64(45);
    let mut t = 0.0;
    let mut ll = [0.0; 65];
    let mut grid_updates = 0;
    // 500 000 bites, two hypotheses each: 1e6 updates.
    for i in 0..500_000u32 {
        // Mostly 20 bites a day, sometimes many at one time, sometimes a long pause.
        t += match i % 1000 {
            0 => 10.0,
            1..=20 => 0.0,
            _ => rng.random_range(0.0..0.1),
        };
        let truth = 1.0 + 1e-4 * (i % 20_000) as f64;
        let y = truth + rng.random_range(-0.05..0.05);
        trend.predict(&mut state, t).unwrap();
        for k in 0..2 {
            let observed = y + 0.3 * k as f64;
            let grid = trend.grid(&state, k, FINE);
            // Every 20th bite on the grid path when the local grid is used (the
            // unoptimised test loop is the cost), else the Gaussian path.
            if grid.len != ll.len() || i % 20 != 0 {
                trend
                    .update_gaussian(&mut state, k, observed, 0.0025)
                    .unwrap();
                continue;
            }
            for (j, v) in ll.iter_mut().enumerate() {
                *v = -0.5 * ((observed - grid.at(j)) / 0.05).powi(2);
            }
            let bite = BiteMoments {
                mean_mrad: observed,
                var_mrad2: 0.0025,
            };
            trend.update(&mut state, k, grid, &ll, bite).unwrap();
            grid_updates += 1;
        }
        trend.finish_bite(&mut state, Some(1e-4));
        if i % 5_000 == 0 || i == 499_999 {
            for h in &state.hypotheses[..2] {
                let [[a, b], [c, d]] = h.p;
                assert_eq!(b, c, "symmetric");
                assert!(
                    a > 0.0 && d >= 0.0 && a * d - b * c >= -1e-12 * a * d,
                    "{h:?}"
                );
                assert!(h.gap_mrad.is_finite() && h.rate_mrad_per_day.is_finite());
            }
            let e = trend.estimate(&state).unwrap();
            assert!(e.gap_low_mrad.is_finite() && e.gap_high_mrad.is_finite());
        }
    }
    assert!(grid_updates > 40_000, "{grid_updates}");
    // Still tracking: each hypothesis near its own observations.
    let truth = 1.0 + 1e-4 * (499_999 % 20_000) as f64;
    for (k, h) in state.hypotheses[..2].iter().enumerate() {
        assert!((h.gap_mrad - truth - 0.3 * k as f64).abs() < 0.05, "{h:?}");
    }
}

#[test]
fn bite_moments_leave_the_outlier_floor_out() {
    // One measure: a Gaussian peak of sd 0.03 mrad at 2 mrad over a 2% uniform floor.
    let sd = 0.03;
    let ll: Vec<f64> = (0..FINE.len)
        .map(|i| {
            let z = (FINE.at(i) - 2.0) / sd;
            (0.98 * (-0.5 * z * z).exp() / (sd * 2.5066) + 0.02 / 8.0).ln()
        })
        .collect();
    let m = BiteMoments::from_loglik(FINE, &ll).unwrap();
    assert!((m.mean_mrad - 2.0).abs() < 1e-6, "{m:?}");
    let expected = sd * sd + FINE.step_mrad * FINE.step_mrad / 12.0;
    assert!(
        (m.var_mrad2 / expected - 1.0).abs() < 0.02,
        "{m:?} vs {expected}"
    );
    // All points: the floor's mass (~2%) spread over 8 mrad dominates.
    let top = ll.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let w: Vec<f64> = ll.iter().map(|v| (v - top).exp()).collect();
    let total: f64 = w.iter().sum();
    let mean = (0..FINE.len).map(|i| w[i] * FINE.at(i)).sum::<f64>() / total;
    let var = (0..FINE.len)
        .map(|i| w[i] * (FINE.at(i) - mean).powi(2))
        .sum::<f64>()
        / total;
    assert!(var > 50.0 * m.var_mrad2, "{var}");
    assert_eq!(
        BiteMoments::from_loglik(FINE, &ll[1..]),
        Err(TrendError::GridLength)
    );
}

/// The moments as they were before the floor's points skipped their exponential:
/// every point through it.
fn moments_of_every_point(grid: GapGrid, ll: &[f64]) -> (f64, f64) {
    let top = ll.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let floor = libm::exp(ll.iter().copied().fold(f64::INFINITY, f64::min) - top);
    let weight = |v: f64, floor: f64| (libm::exp(v - top) - floor).max(0.0);
    let floor = if ll.iter().any(|&v| weight(v, floor) > 0.0) {
        floor
    } else {
        0.0
    };
    let (mut sum, mut first, mut second) = (0.0, 0.0, 0.0);
    for (i, &v) in ll.iter().enumerate() {
        let w = weight(v, floor);
        let offset = grid.step_mrad * i as f64;
        sum += w;
        first += w * offset;
        second += w * offset * offset;
    }
    let mean_offset = first / sum;
    let var = (second / sum - mean_offset * mean_offset).max(0.0);
    (
        grid.first_mrad + mean_offset,
        var + grid.step_mrad * grid.step_mrad / 12.0,
    )
}

/// The points at the floor skip their exponential without changing a bit: seeded
/// log-likelihoods with a peak or two over a floor that holds from none to nearly all
/// of the points, flat ones among them.
#[test]
fn bite_moments_skip_the_floor_without_changing_a_bit() {
    let mut rng = StdRng::seed_from_u64(11);
    for case in 0..2_000 {
        let floor = rng.random_range(-10.0..0.0);
        let peaks: Vec<(f64, f64, f64)> = (0..rng.random_range(0..3))
            .map(|_| {
                (
                    rng.random_range(0.0..8.0),
                    10f64.powf(rng.random_range(-2.0..0.5)),
                    rng.random_range(0.0..20.0),
                )
            })
            .collect();
        let ll: Vec<f64> = (0..FINE.len)
            .map(|i| {
                let gap = FINE.at(i);
                peaks
                    .iter()
                    .map(|&(at, sd, height)| height - 0.5 * ((gap - at) / sd).powi(2))
                    .fold(floor, f64::max)
            })
            .collect();
        let m = BiteMoments::from_loglik(FINE, &ll).unwrap();
        let (mean, var) = moments_of_every_point(FINE, &ll);
        assert_eq!(
            (m.mean_mrad.to_bits(), m.var_mrad2.to_bits()),
            (mean.to_bits(), var.to_bits()),
            "case {case}: {m:?} against {mean}, {var}"
        );
    }
}
