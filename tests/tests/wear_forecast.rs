//! The wear forecast's calibration on the simulator (see
//! `millgate_tests::experiments::wear_forecast` for the runs and the scoring).
//!
//! ```text
//! WEAR_FORECAST=full cargo test --release -p millgate-tests --test wear_forecast -- --nocapture
//! ```
//! prints the table of docs/wear.md (12 drivelines per growth law, 10 bites a day, the
//! service's default maps); without `WEAR_FORECAST=full` the quick plan runs (2 per
//! law, 3 bites a day, coarse maps), as CI does.

use millgate_tests::experiments::wear_forecast::{by_lead, evaluate, score, table, Plan};
use millgate_tests::kit::scratch;

#[test]
fn the_forecast_interval_holds_the_true_crossing_and_stable_gaps_raise_no_near_alarm() {
    let full = std::env::var("WEAR_FORECAST").is_ok_and(|v| v == "full");
    let plan = if full { Plan::full() } else { Plan::quick() };
    let cache = scratch("wear-forecast");
    let started = std::time::Instant::now();
    let outcomes = evaluate(&plan, cache.path()).expect("the evaluation runs");
    let bites: usize = outcomes.iter().map(|o| o.bites).sum();
    println!(
        "{} drivelines, {bites} bites, {:.0} s wall ({plan:?})\n\n{}\ncrossing in the interval by lead: {}",
        outcomes.len(),
        started.elapsed().as_secs_f64(),
        table(&outcomes),
        by_lead(&outcomes)
    );
    let all = score(&outcomes);
    // The issue's goals: coverage >= 85%, median error <= 20% of the time to the
    // crossing, no false near alarm on a stable gap. The quick plan has few forecasts
    // (one miss is 4-8%): it must still meet the error and near-alarm goals, and
    // cover at least 75% of crossings and 80% of days.
    let (crossing, gap) = if full { (0.85, 0.85) } else { (0.75, 0.80) };
    assert!(all.forecasts >= 8, "{all:?}");
    assert!(
        all.covered as f64 >= crossing * all.forecasts as f64,
        "crossing coverage: {all:?}"
    );
    assert!(all.median_error <= 0.20, "median error: {all:?}");
    assert!(
        all.gap_covered as f64 >= gap * all.gap_days as f64,
        "gap coverage: {all:?}"
    );
    assert_eq!(
        all.near_alarms, 0,
        "false near alarms on stable gaps: {all:?}"
    );
    assert_eq!(
        all.named_right, all.named,
        "a wrong coupling named: {all:?}"
    );
}
