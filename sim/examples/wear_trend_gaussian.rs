//! Smoke check of the wear trend (`millgate_dsp::wear_trend`) on Gaussian per-bite
//! observations of the gap: growth laws x bite calendar x noise, the four figures of
//! issue 37 (crossing coverage of the 90% interval, median error of the point forecast
//! over the time to the crossing, current-gap coverage, false "alarm within 30 days" on
//! stable gaps). Not the product's evaluation (that one goes through the gateway's
//! likelihood on the maps); this one checks that the Rust port behaves like the design
//! prototype on the same protocol (`evaluate.py`).
//!
//! Per driveline: a [`GrowthLaw`] (the four kinds in turn), the coupling (spindles 70%:
//! a bite's gap sd 0.02-0.05 mrad; motor coupling 30%: 0.06-0.14 mrad, as the
//! prototype's single-bite posteriors), a [`BiteCalendar`], and per bite an observation
//! `y = gap + bias + chain * sd * N(0, 1)` with 2% outliers uniform over 0-8 mrad. The
//! filter is told `sd` (the chain factor 1-2 is unknown to it, as the real scatter
//! beyond the formula) and sees the likelihood `(1 - 0.02) N(y; g, sd^2) + 0.02 / 8` on
//! its grids (local 65-point grids, fine grid 0-8 mrad every 1/64 mrad). Scenario
//! "calibrated" adds a per-driveline bias of the model (sd 0.03 mrad spindles, 0.08 motor
//! coupling) and tells the filter that floor (f^2 on every 10th bite).
//!
//! Forecasts are scored 120/90/60/30/14/7 days before the true crossing (at least 14
//! days after the start) from the state after the last bite before then; the current
//! gap once a day from day 3.
//!
//! Run: `cargo run -p millgate-sim --example wear_trend_gaussian -- [drivelines]
//! [bites_per_day] [exact|calibrated] [seed]` (defaults 48 20 exact 38); the figures
//! measured are in the crate README ("Wear growth").

use millgate_dsp::wear_trend::{BiteMoments, Forecast, GapGrid, WearTrend};
use millgate_sim::wear_growth::{BiteCalendar, GrowthKind, GrowthLaw};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use rand_distr::StandardNormal;

const ALARM_MRAD: f64 = 4.0;
const REMAINING_DAYS: [f64; 6] = [120.0, 90.0, 60.0, 30.0, 14.0, 7.0];
const OUTLIER_WEIGHT: f64 = 0.02;
const FINE: GapGrid = GapGrid {
    first_mrad: 0.0,
    step_mrad: 0.015_625,
    len: 513,
};

/// One scored forecast: days remaining (truth), the forecast.
struct Scored {
    remaining: f64,
    forecast: Forecast,
}

/// What one driveline gave.
struct Record {
    kind: GrowthKind,
    forecasts: Vec<Scored>,
    /// Per day: the interval held the true gap.
    daily_held: Vec<bool>,
    /// Per day (from the 8th): the early side reached the alarm within 30 days.
    near_alarm: bool,
}

/// The bite's log-likelihood on `grid`.
fn likelihood(y: f64, sd: f64, grid: GapGrid, out: &mut Vec<f64>) {
    let span = FINE.last_mrad() - FINE.first_mrad;
    out.clear();
    out.extend((0..grid.len).map(|i| {
        let z = (y - grid.at(i)) / sd;
        let gauss = (-0.5 * z * z).exp() / (sd * (2.0 * std::f64::consts::PI).sqrt());
        ((1.0 - OUTLIER_WEIGHT) * gauss + OUTLIER_WEIGHT / span).ln()
    }));
}

fn run_driveline(
    trend: &WearTrend,
    rng: &mut StdRng,
    kind: GrowthKind,
    bites_per_day: f64,
    calibrated: bool,
) -> Record {
    let law = GrowthLaw::draw(kind, rng);
    let spindles = rng.random_bool(0.7);
    let (sd_low, sd_high, floor_sd) = if spindles {
        (0.02, 0.05, 0.03)
    } else {
        (0.06, 0.14, 0.08)
    };
    let chain = rng.random_range(1.0..2.0);
    let bias = if calibrated {
        floor_sd * rng.sample::<f64, _>(StandardNormal)
    } else {
        0.0
    };
    let crossing = law.crossing_day(ALARM_MRAD);
    let days = crossing.map_or(300.0, |c| (c + 10.0).min(300.0));
    let calendar = BiteCalendar {
        days,
        bites_per_shift: bites_per_day / 2.0,
    };
    let times = calendar.generate(rng.random()).times_days;
    let mut state = trend.state(1).expect("one hypothesis");
    // (time, days remaining), earliest first.
    let mut pending: Vec<(f64, f64)> = crossing
        .map(|c| {
            REMAINING_DAYS
                .iter()
                .filter(|&&r| c - r >= 14.0)
                .map(|&r| (c - r, r))
                .collect()
        })
        .unwrap_or_default();
    let mut record = Record {
        kind,
        forecasts: Vec::new(),
        daily_held: Vec::new(),
        near_alarm: false,
    };
    let mut day_end = times.first().map_or(0.0, |t| t.floor() + 1.0);
    let mut days_seen = 0;
    let mut ll = Vec::with_capacity(FINE.len);
    let mut fine_ll = Vec::with_capacity(FINE.len);
    for (i, &t) in times.iter().enumerate() {
        if let Some(t_last) = state.t_last_days {
            while pending.first().is_some_and(|&(at, _)| at <= t) {
                pending.remove(0);
                record.forecasts.push(Scored {
                    remaining: crossing.expect("pending only with a crossing") - t_last,
                    forecast: trend.forecast(&state, ALARM_MRAD),
                });
            }
            while t >= day_end {
                let estimate = trend.estimate(&state).expect("bites seen");
                let forecast = trend.forecast(&state, ALARM_MRAD);
                if t_last >= 3.0 {
                    let truth = law.gap_at(t_last);
                    record
                        .daily_held
                        .push(estimate.gap_low_mrad <= truth && truth <= estimate.gap_high_mrad);
                }
                days_seen += 1;
                if days_seen > 7 && forecast.days_low.is_some_and(|d| d <= 30.0) {
                    record.near_alarm = true;
                }
                day_end += 1.0;
            }
        }
        let sd = rng.random_range(sd_low..sd_high);
        let y = if rng.random_bool(OUTLIER_WEIGHT) {
            rng.random_range(0.0..FINE.last_mrad())
        } else {
            law.gap_at(t).min(7.8) + bias + chain * sd * rng.sample::<f64, _>(StandardNormal)
        };
        trend.predict(&mut state, t).expect("ascending times");
        let grid = trend.grid(&state, 0, FINE);
        likelihood(y, sd, FINE, &mut fine_ll);
        likelihood(y, sd, grid, &mut ll);
        trend
            .update(
                &mut state,
                0,
                grid,
                &ll,
                BiteMoments::from_loglik(FINE, &fine_ll).expect("valid likelihood"),
            )
            .expect("valid likelihood");
        let floor = (calibrated && i % 10 == 0).then_some(floor_sd * floor_sd);
        trend.finish_bite(&mut state, floor);
    }
    record
}

fn median(mut values: Vec<f64>) -> f64 {
    values.sort_by(f64::total_cmp);
    values.get(values.len() / 2).copied().unwrap_or(f64::NAN)
}

/// Whether the 90% interval of `s` holds the true remaining days.
fn covered(s: &Scored) -> bool {
    let f = s.forecast;
    f.days_low.is_some_and(|l| l <= s.remaining) && f.days_high.is_some_and(|h| s.remaining <= h)
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let drivelines: usize = args.first().map_or(48, |a| a.parse().expect("drivelines"));
    let bites_per_day: f64 = args.get(1).map_or(20.0, |a| a.parse().expect("bites/day"));
    let scenario = args.get(2).map_or("exact", String::as_str);
    let seed: u64 = args.get(3).map_or(38, |a| a.parse().expect("seed"));
    let calibrated = match scenario {
        "exact" => false,
        "calibrated" => true,
        other => panic!("scenario {other}: exact or calibrated"),
    };
    let trend = WearTrend::new(365.0).expect("a valid horizon");
    let mut rng = StdRng::seed_from_u64(seed);
    let started = std::time::Instant::now();
    let records: Vec<Record> = (0..drivelines)
        .map(|i| {
            let kind = GrowthKind::ALL[i % 4];
            run_driveline(&trend, &mut rng, kind, bites_per_day, calibrated)
        })
        .collect();
    println!(
        "{drivelines} drivelines, {bites_per_day} bites/day, scenario {scenario}, seed {seed}: {:.1} s",
        started.elapsed().as_secs_f64()
    );
    println!("| law | crossing in 90% interval | median error / time to crossing | current gap in interval | stable: alarm <= 30 d |");
    println!("|---|---|---|---|---|");
    let rows = GrowthKind::ALL
        .iter()
        .map(|&k| (k.name(), Some(k)))
        .chain([("all", None)]);
    for (name, kind) in rows {
        let chosen: Vec<&Record> = records
            .iter()
            .filter(|r| kind.is_none_or(|k| r.kind == k))
            .collect();
        let scored: Vec<&Scored> = chosen.iter().flat_map(|r| &r.forecasts).collect();
        let covered = scored.iter().filter(|s| covered(s)).count();
        let errors: Vec<f64> = scored
            .iter()
            .map(|s| {
                s.forecast
                    .days
                    .map_or(f64::INFINITY, |d| (d - s.remaining).abs() / s.remaining)
            })
            .collect();
        let days: Vec<bool> = chosen.iter().flat_map(|r| r.daily_held.clone()).collect();
        let held = days.iter().filter(|&&h| h).count();
        let stable: Vec<&&Record> = chosen
            .iter()
            .filter(|r| r.kind == GrowthKind::Stable)
            .collect();
        let near = stable.iter().filter(|r| r.near_alarm).count();
        let crossing = if scored.is_empty() {
            "-".to_string()
        } else {
            format!(
                "{covered}/{} = {:.1}%",
                scored.len(),
                100.0 * covered as f64 / scored.len() as f64
            )
        };
        let error = if errors.is_empty() {
            "-".to_string()
        } else {
            format!("{:.1}%", 100.0 * median(errors))
        };
        let stable = if stable.is_empty() {
            "-".to_string()
        } else {
            format!("{near}/{}", stable.len())
        };
        println!(
            "| {name} | {crossing} | {error} | {held}/{} = {:.1}% | {stable} |",
            days.len(),
            100.0 * held as f64 / days.len().max(1) as f64
        );
    }
    let scored: Vec<&Scored> = records.iter().flat_map(|r| &r.forecasts).collect();
    let by_remaining: Vec<String> = REMAINING_DAYS
        .iter()
        .map(|&r| {
            let at: Vec<&&Scored> = scored
                .iter()
                .filter(|s| (s.remaining - r).abs() < 3.0)
                .collect();
            let held = at.iter().filter(|s| covered(s)).count();
            format!("{r} d {held}/{}", at.len())
        })
        .collect();
    let no_point = scored.iter().filter(|s| s.forecast.days.is_none()).count();
    println!(
        "crossing held by days remaining: {}; no point forecast: {no_point}",
        by_remaining.join(", ")
    );
}
