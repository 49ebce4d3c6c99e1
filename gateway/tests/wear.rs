//! Wear index against the linear reference: the analysis task fed with simulated
//! bars of the Table 2 driveline with gaps of 0 to 4 mrad in the spindles.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant};

use millgate::analysis::driveline::BiteReport;
use millgate::analysis::Analysis;
use millgate::field::acquired::Acquired;
use millgate::field::source_health::SourceHealth;
use millgate::outputs::modbus::register_map::RegisterMap;
use millgate::state::board::Board;
use millgate::state::commands::{Command, CommandOrigin};
use millgate_sim::model::Model;
use millgate_sim::schedule::{rolling_schedule, BarTiming};

const MODELS: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../sim/models");
const BACKLASH_MODEL: &str = "table2-adjusted-backlash.toml";
const TIMING: BarTiming = BarTiming {
    idle_s: 0.6,
    rolling_s: 1.2,
};
/// Bound on |wear index| of a driveline without gap, with 0.5 kN*m RMS noise.
const NO_GAP_BOUND: f64 = 0.03;

/// The demo configuration, with the driveline model when `model` is set.
fn config(model: bool) -> millgate_config::Config {
    let mut config = millgate_config::from_toml_str(
        include_str!("../../config/examples/demo.toml"),
        "demo.toml",
        Path::new(MODELS),
    )
    .expect("demo config");
    config.drivelines[0].model = model.then(|| PathBuf::from(MODELS).join(BACKLASH_MODEL));
    config
}

/// The driveline with a `gap_rad` gap in the spindles.
fn driveline(gap_rad: f64) -> Model {
    let mut model = Model::load(PathBuf::from(MODELS).join(BACKLASH_MODEL)).expect("model");
    model.couplings[1].backlash = gap_rad;
    model
}

/// An analysis task over `config`, its board, and the bites it reports when fed
/// the bars of `static_torques_knm` simulated with `model` (0.5 kN*m RMS noise).
fn analyse(
    config: &millgate_config::Config,
    model: &Model,
    static_torques_knm: &[f64],
) -> (Arc<Board>, Vec<BiteReport>) {
    let (board, reports, _) = analyse_with(config, model, static_torques_knm);
    (board, reports)
}

/// [`analyse`], and the analysis (for its commands).
fn analyse_with(
    config: &millgate_config::Config,
    model: &Model,
    static_torques_knm: &[f64],
) -> (Arc<Board>, Vec<BiteReport>, Analysis) {
    let schedule = rolling_schedule(model, static_torques_knm, TIMING, 0.5, 3).expect("schedule");
    let health = Arc::new(SourceHealth::new(
        Duration::from_secs(3600),
        Duration::from_secs(3600),
    ));
    let board = Arc::new(Board::new(config, vec![health]));
    let (bites, _) = tokio::sync::broadcast::channel(64);
    let mut analysis = Analysis::new(config, Arc::clone(&board), bites).expect("analysis");
    let mut reports = Vec::new();
    for block in schedule.torque_knm.chunks(100) {
        reports.extend(analysis.handle(Acquired::Samples {
            channel: 0,
            values: block.to_vec(),
            received: None,
            handed: Instant::now(),
        }));
    }
    assert_eq!(reports.len(), static_torques_knm.len(), "one bite per bar");
    (board, reports, analysis)
}

fn wear_indices(reports: &[BiteReport]) -> Vec<f64> {
    reports
        .iter()
        .map(|r| r.wear.expect("wear index with a model").index)
        .collect()
}

#[test]
fn wear_index_is_zero_without_gap_and_grows_with_it() {
    let config = config(true);
    let torques = [112.0, 60.0];
    let mut previous: Option<Vec<f64>> = None;
    for gap_mrad in [0.0, 1.0, 2.0, 4.0] {
        let (_, reports) = analyse(&config, &driveline(gap_mrad * 1e-3), &torques);
        let indices = wear_indices(&reports);
        println!("gap {gap_mrad} mrad: wear index {indices:?}");
        if gap_mrad == 0.0 {
            for index in &indices {
                assert!(index.abs() < NO_GAP_BOUND, "no gap: wear index {index}");
            }
        } else {
            for index in &indices {
                assert!(*index > NO_GAP_BOUND, "gap {gap_mrad} mrad: {index}");
            }
        }
        if let Some(previous) = previous {
            for (now, before) in indices.iter().zip(&previous) {
                assert!(now > before, "gap {gap_mrad} mrad: {now} <= {before}");
            }
        }
        previous = Some(indices);
    }
}

#[test]
fn the_gap_weighs_more_at_light_load() {
    // Domain notes 1.3: for a given gap, TAF rises as the static torque falls.
    let (_, reports) = analyse(&config(true), &driveline(2e-3), &[150.0, 60.0]);
    let indices = wear_indices(&reports);
    assert!(indices[1] > indices[0], "{indices:?}");
    let reference = reports[1].wear.unwrap().reference;
    assert_eq!(
        reference.level_knm % millgate::analysis::wear::STATIC_TORQUE_STEP_KNM,
        0.0
    );
    assert!(
        (reference.level_knm - reports[1].transient.static_torque_knm).abs()
            <= millgate::analysis::wear::STATIC_TORQUE_STEP_KNM / 2.0,
        "reference level {} for a static torque of {}",
        reference.level_knm,
        reports[1].transient.static_torque_knm
    );
}

#[test]
fn trend_follows_the_index_and_resets() {
    let (board, reports, mut analysis) =
        analyse_with(&config(true), &driveline(2e-3), &[112.0, 112.0, 112.0]);
    let indices = wear_indices(&reports);
    let mut expected = None;
    for index in &indices {
        expected = Some(millgate::analysis::wear::next_trend(expected, *index));
    }
    let results = board.results();
    let driveline = &results.drivelines[0];
    assert_eq!(driveline.wear_index, indices.last().copied());
    let trend = driveline.wear_trend.expect("trend after three bites");
    assert!((trend - expected.unwrap()).abs() < 1e-12);
    // Between the first index and the last: a mean, not a copy.
    let (low, high) = indices
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &v| {
            (lo.min(v), hi.max(v))
        });
    assert!(
        trend >= low && trend <= high,
        "{trend} outside {low}..{high}"
    );

    let origin = CommandOrigin::Local;
    analysis.command(Command::ResetWear {
        driveline: 1,
        origin,
    });
    assert!(
        board.results().drivelines[0].wear_trend.is_some(),
        "driveline 1 is another driveline"
    );
    analysis.command(Command::ResetWear {
        driveline: 0,
        origin,
    });
    let results = board.results();
    assert_eq!(results.drivelines[0].wear_trend, None);
    assert_eq!(
        results.drivelines[0].wear_index,
        indices.last().copied(),
        "the last index stays"
    );
}

#[test]
fn without_a_model_the_index_is_invalid_not_zero() {
    let config = config(false);
    let (board, reports) = analyse(&config, &driveline(2e-3), &[112.0]);
    assert!(reports[0].wear.is_none());
    assert!(reports[0].transient.taf.is_some(), "TAF is still measured");
    let map = RegisterMap::new(&config);
    // As published once the source answers (this test has no source).
    let mut results = board.results();
    results.drivelines[0].source_stale = false;
    let words = map.encode(&results);
    let quality = map
        .registers()
        .iter()
        .find(|r| r.name == "F1.quality")
        .unwrap();
    let quality = words[usize::from(quality.address)];
    assert_eq!(quality & (1 << 3), 1 << 3, "taf valid");
    assert_eq!(
        quality & (0b11 << 7),
        0,
        "wear_index and wear_trend invalid"
    );
}

#[test]
fn a_model_that_does_not_load_is_named_and_the_driveline_runs_without_wear() {
    let mut config = config(false);
    config.drivelines[0].model = Some(PathBuf::from(MODELS).join("no-such-model.toml"));
    let health = Arc::new(SourceHealth::new(
        Duration::from_secs(1),
        Duration::from_secs(1),
    ));
    let board = Arc::new(Board::new(&config, vec![health]));
    let (bites, _) = tokio::sync::broadcast::channel(1);
    let mut analysis = Analysis::new(&config, board, bites).expect("the driveline still runs");
    let problems: Vec<String> = analysis
        .wear_problems()
        .iter()
        .map(ToString::to_string)
        .collect();
    assert_eq!(problems.len(), 1, "{problems:?}");
    assert!(
        problems[0].starts_with("drivelines[0].model:")
            && problems[0].contains("no-such-model.toml"),
        "{problems:?}"
    );
    assert!(analysis.take_gap_map_jobs().is_empty(), "no maps to build");
}

#[test]
fn first_period_shift_over_the_linear_reference_grows_with_the_gap() {
    // The same measure as the wear map (`millgate sim wear-map`): the first-period
    // shift of the bite minus that of the linear driveline at the same load, with the
    // map's period cut-off (1.5 x the second mode).
    let config = config(true);
    let torques = [112.0, 60.0];
    let mut previous: Option<Vec<f64>> = None;
    for gap_mrad in [0.0, 2.0, 4.0] {
        let (_, reports) = analyse(&config, &driveline(gap_mrad * 1e-3), &torques);
        let excess: Vec<f64> = reports
            .iter()
            .map(|r| {
                r.wear
                    .and_then(|w| w.shift_excess_s)
                    .expect("shift measured")
                    * 1e3
            })
            .collect();
        println!("gap {gap_mrad} mrad: first-period shift over linear {excess:?} ms");
        for (value, previous) in excess.iter().zip(previous.as_deref().unwrap_or(&[])) {
            assert!(
                value > previous,
                "gap {gap_mrad} mrad: {value} <= {previous} ms"
            );
        }
        if gap_mrad == 0.0 {
            assert!(
                excess.iter().all(|ms| ms.abs() < 1.0),
                "no gap: {excess:?} ms"
            );
        } else {
            assert!(
                excess.iter().all(|&ms| ms > 3.0),
                "gap {gap_mrad} mrad: {excess:?} ms"
            );
        }
        previous = Some(excess);
    }
}
