//! The wear forecast's calibration on the simulator (issue 37): drivelines whose gap
//! grows by a law ([`GrowthLaw`]: linear, accelerating, starting late, stable) bite on
//! a seeded calendar ([`BiteCalendar`]: two shifts, weekends, outages); every bite is a
//! bar of the Table 2 driveline simulated with the day's true gap in one coupling and
//! fed, sample by sample, through the service's analysis (bite detector, transient
//! analysis, the bite's likelihood against the maps, the wear trend), dated by the
//! calendar. Scored against the truth:
//!
//! - **crossing**: forecasts made 120, 90, 60, 30, 14 and 7 days before the true gap
//!   reaches the alarm (at the last bite before, at least 14 days after the start): is
//!   the true time to the crossing inside the 90% interval (`days_to_gap_alarm_low` ..
//!   `_high`; a forecast without days counts as a miss);
//! - **error**: the point forecast's error over the true time to the crossing (median);
//! - **gap**: at each day's last bite, is the true gap inside the gap's 90% interval;
//! - **near alarm**: on stable gaps, a forecast whose early end (`days_low`) is within 30
//!   days, on any day (a false near alarm);
//! - **coupling**: the coupling named at the end is the true one.
//!
//! The test (`tests/tests/wear_forecast.rs`) runs the quick plan in CI; the table in
//! `docs/wear.md` comes from the full plan (`WEAR_FORECAST=full`, release build).

use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use std::sync::Arc;
use std::time::{Duration, Instant, SystemTime};

use millgate::analysis::Analysis;
use millgate::field::acquired::Acquired;
use millgate::field::source_health::SourceHealth;
use millgate::state::board::Board;
use millgate::state::gap_maps::GapMaps;
use millgate::state::results::{ForecastState, GapResults};
use millgate_sim::model::Model;
use millgate_sim::schedule::{rolling_schedule, BarTiming};
use millgate_sim::wear_growth::{BiteCalendar, GrowthKind, GrowthLaw};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

use super::chatter_eval::parallel;

/// The forecast leads scored, days before the true crossing.
pub const LEADS_DAYS: [f64; 6] = [120.0, 90.0, 60.0, 30.0, 14.0, 7.0];
/// Forecasts are scored from this many days after the start on (the trend needs a few
/// weeks to see a growth).
const SETTLE_DAYS: f64 = 14.0;
/// A forecast whose early end is within this many days is a near alarm.
pub const NEAR_DAYS: f64 = 30.0;
/// Each driveline runs until this many days after its crossing (stable ones: the
/// plan's longest run).
pub const AFTER_CROSSING_DAYS: f64 = 10.0;
/// Each bite is one bar: idle, then rolling (the demo's timing).
const TIMING: BarTiming = BarTiming {
    idle_s: 0.6,
    rolling_s: 1.2,
};
/// Samples per block handed to the analysis, as the DAQ reader delivers them.
const BLOCK: usize = 100;
/// The calendar's day 0, a Monday: 2026-01-05T00:00:00Z.
const DAY0_UNIX_S: u64 = 1_767_571_200;

/// What to run.
#[derive(Debug, Clone)]
pub struct Plan {
    /// Drivelines per growth law.
    pub per_law: usize,
    /// Mean bites per day on working days.
    pub bites_per_day: f64,
    /// The gap alarm, mrad.
    pub alarm_mrad: f64,
    /// Longest run, days (stable drivelines run this long; others stop
    /// [`AFTER_CROSSING_DAYS`] after their crossing or here).
    pub max_days: f64,
    /// The maps' grid: `wear` settings in TOML (`gap_step_mrad = ...`).
    pub wear: String,
    /// The seed of everything drawn.
    pub seed: u64,
    /// Threads (drivelines run in parallel).
    pub threads: usize,
}

impl Plan {
    /// The plan the docs' table comes from: 12 drivelines per law, 10 bites a day,
    /// the service's default maps.
    pub fn full() -> Self {
        Self {
            per_law: 12,
            bites_per_day: 10.0,
            alarm_mrad: 4.0,
            max_days: 300.0,
            wear: "gap_step_mrad = 0.125".into(),
            seed: 37,
            threads: std::thread::available_parallelism().map_or(1, |n| n.get()),
        }
    }

    /// The plan CI runs: 2 drivelines per law, 3 bites a day, coarse maps.
    pub fn quick() -> Self {
        Self {
            per_law: 2,
            bites_per_day: 3.0,
            max_days: 240.0,
            wear: "gap_step_mrad = 0.25, torque_points = 10".into(),
            ..Self::full()
        }
    }
}

/// One driveline of a plan.
#[derive(Debug, Clone)]
pub struct Case {
    /// Its index in the plan.
    pub index: usize,
    /// How its gap grows.
    pub law: GrowthLaw,
    /// The coupling holding the gap (model index: 0 motor side, 1 spindles).
    pub coupling: usize,
    /// Noise on the torque signal, kN*m RMS.
    pub noise_knm: f64,
    /// Its bites, days from day 0.
    pub bites_days: Vec<f64>,
    /// Its static torques, kN*m, one per bite.
    pub torques_knm: Vec<f64>,
    /// The day its true gap reaches the alarm, if it does.
    pub crossing_day: Option<f64>,
}

/// The drivelines of `plan`: per law `per_law` of them, 70% with the gap in the
/// spindles, noise 0.3-1.0 kN*m, static torques log-uniform over 40-170 kN*m.
pub fn cases(plan: &Plan) -> Vec<Case> {
    let mut rng = StdRng::seed_from_u64(plan.seed);
    let mut cases = Vec::new();
    for kind in GrowthKind::ALL {
        for _ in 0..plan.per_law {
            let law = GrowthLaw::draw(kind, &mut rng);
            let crossing_day = law
                .crossing_day(plan.alarm_mrad)
                .filter(|&day| day <= plan.max_days - AFTER_CROSSING_DAYS);
            let days = crossing_day.map_or(plan.max_days, |day| day + AFTER_CROSSING_DAYS);
            let calendar = BiteCalendar {
                days,
                bites_per_shift: plan.bites_per_day / 2.0,
            };
            let bites_days = calendar.generate(rng.random()).times_days;
            let torques_knm = bites_days
                .iter()
                .map(|_| (rng.random_range(40f64.ln()..170f64.ln())).exp())
                .collect();
            cases.push(Case {
                index: cases.len(),
                law,
                coupling: usize::from(rng.random_range(0.0..1.0) < 0.7),
                noise_knm: rng.random_range(0.3..1.0),
                bites_days,
                torques_knm,
                crossing_day,
            });
        }
    }
    cases
}

/// A forecast scored against the truth.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Scored {
    /// Days before the true crossing it was made (one of [`LEADS_DAYS`]).
    pub lead_days: f64,
    /// The true days from its bite to the crossing.
    pub truth_days: f64,
    /// The forecast's state.
    pub state: ForecastState,
    /// Its days, early and late end.
    pub days: Option<f64>,
    /// Early end.
    pub days_low: Option<f64>,
    /// Late end (`None`: beyond the horizon).
    pub days_high: Option<f64>,
}

impl Scored {
    /// Whether the truth lies inside the interval.
    pub fn covered(&self) -> bool {
        self.days.is_some()
            && self.days_low.is_some_and(|low| low <= self.truth_days)
            && self.days_high.is_none_or(|high| self.truth_days <= high)
    }

    /// The point forecast's error over the true time to the crossing.
    pub fn relative_error(&self) -> Option<f64> {
        self.days
            .map(|days| (days - self.truth_days).abs() / self.truth_days)
    }
}

/// One driveline's outcome.
#[derive(Debug, Clone)]
pub struct Outcome {
    /// The case.
    pub kind: GrowthKind,
    /// Forecasts scored at the leads.
    pub forecasts: Vec<Scored>,
    /// Per day with bites: whether the gap's interval held the truth at its last bite.
    pub gap_days: Vec<bool>,
    /// A forecast with its early end within [`NEAR_DAYS`] while the gap was below the
    /// alarm (stable laws: a false near alarm).
    pub near_alarm: bool,
    /// The coupling named at the end (`None`: undetermined).
    pub coupling_named: Option<usize>,
    /// The true coupling.
    pub coupling: usize,
    /// Bites analysed.
    pub bites: usize,
}

/// Run `case` through the service's analysis with `maps` and the configuration of
/// `plan` (the model in `models`).
pub fn run(case: &Case, plan: &Plan, maps: &GapMaps, models: &Path) -> anyhow::Result<Outcome> {
    let mut analysis = analysis(&config(plan, models)?)?;
    analysis.take_gap_map_jobs();
    analysis.install_gap_maps(0, Ok(maps.clone()));
    let mut model = Model::load(models.join("table2-adjusted.toml"))?;
    let mut outcome = Outcome {
        kind: case.law.kind(),
        forecasts: Vec::new(),
        gap_days: Vec::new(),
        near_alarm: false,
        coupling_named: None,
        coupling: case.coupling,
        bites: 0,
    };
    let mut leads = LEADS_DAYS.to_vec();
    let mut last: Option<(f64, GapResults)> = None;
    for (n, (&day, &torque)) in case.bites_days.iter().zip(&case.torques_knm).enumerate() {
        let truth = case.law.gap_at(day);
        model.couplings[case.coupling].backlash = truth * 1e-3;
        let schedule = rolling_schedule(
            &model,
            &[torque],
            TIMING,
            case.noise_knm,
            case_seed(case, n),
        )?;
        let rate = schedule.sample_rate_hz;
        let start =
            SystemTime::UNIX_EPOCH + Duration::from_secs_f64(DAY0_UNIX_S as f64 + day * 86_400.0);
        let mut gap = None;
        for (k, block) in schedule.torque_knm.chunks(BLOCK).enumerate() {
            let end = ((k * BLOCK + block.len()) as f64) / rate;
            for report in analysis.handle(Acquired::Samples {
                channel: 0,
                values: block.to_vec(),
                received: Some(start + Duration::from_secs_f64(end)),
                handed: Instant::now(),
            }) {
                outcome.bites += 1;
                gap = report.gap.as_ref().and_then(|g| g.trend).or(gap);
            }
        }
        let Some(gap) = gap else { continue };
        // The day's last bite: the gap against the truth.
        let next_day = case.bites_days.get(n + 1).map(|d| d.floor());
        if next_day != Some(day.floor()) && day >= SETTLE_DAYS {
            outcome
                .gap_days
                .push(gap.low_mrad <= truth && truth <= gap.high_mrad);
        }
        if let Some(forecast) = gap.forecast {
            let near = forecast.days_low.is_some_and(|low| low <= NEAR_DAYS);
            outcome.near_alarm |= near && truth < plan.alarm_mrad && case.crossing_day.is_none();
        }
        // Forecasts at the leads: the last bite before each lead's day.
        if let Some(crossing) = case.crossing_day {
            while let Some(&lead) = leads.first() {
                let at = crossing - lead;
                let next = case.bites_days.get(n + 1).copied().unwrap_or(f64::INFINITY);
                if next <= at {
                    break;
                }
                leads.remove(0);
                if day < at && day >= SETTLE_DAYS && day > at - lead.min(7.0) {
                    if let Some(forecast) = gap.forecast {
                        outcome.forecasts.push(Scored {
                            lead_days: lead,
                            truth_days: crossing - day,
                            state: forecast.state,
                            days: forecast.days,
                            days_low: forecast.days_low,
                            days_high: forecast.days_high,
                        });
                    }
                }
            }
        }
        last = Some((day, gap));
    }
    outcome.coupling_named = last.and_then(|(_, gap)| gap.coupling);
    Ok(outcome)
}

/// The configuration of every driveline of `plan`: the demo's, with the Table 2 model
/// and the plan's maps and alarm.
fn config(plan: &Plan, models: &Path) -> anyhow::Result<millgate_config::Config> {
    let text = include_str!("../../../config/examples/demo.toml")
        .replace(
            "wear = { gap_step_mrad = 0.25, torque_points = 12, growth_span_s = 0 }",
            &format!("wear = {{ {} }}", plan.wear),
        )
        .replace(
            "gap_alarm_mrad = 4",
            &format!("gap_alarm_mrad = {}", plan.alarm_mrad),
        );
    anyhow::ensure!(
        text.contains(&format!("wear = {{ {} }}", plan.wear)),
        "demo.toml's wear line changed: the plan's maps were not set"
    );
    Ok(millgate_config::from_toml_str(&text, "demo.toml", models)?)
}

/// The service's analysis of `config` (its one source healthy, nobody listening to
/// its bites).
fn analysis(config: &millgate_config::Config) -> anyhow::Result<Analysis> {
    let health = SourceHealth::new(Duration::from_secs(9), Duration::from_secs(9));
    let board = Arc::new(Board::new(config, vec![Arc::new(health)]));
    let (bites, _) = tokio::sync::broadcast::channel(16);
    Ok(Analysis::new(config, board, bites)?)
}

/// The seed of bite `n` of `case`'s noise.
fn case_seed(case: &Case, n: usize) -> u64 {
    (case.index as u64) << 32 | n as u64
}

/// The maps of `plan` (from the cache in `cache`, else built on every core).
pub fn maps(plan: &Plan, models: &Path, cache: &Path) -> anyhow::Result<GapMaps> {
    let mut config = config(plan, models)?;
    config.cache_dir = Some(cache.to_path_buf());
    let job = analysis(&config)?.take_gap_map_jobs().remove(0);
    let (maps, _) = job.run(plan.threads, &AtomicBool::new(false), &|_, _| {})?;
    Ok(maps)
}

/// Run every case of `plan` (in parallel), the maps cached in `cache`.
pub fn evaluate(plan: &Plan, cache: &Path) -> anyhow::Result<Vec<Outcome>> {
    let models = models();
    let maps = maps(plan, &models, cache)?;
    let cases = cases(plan);
    parallel(plan.threads, &cases, |case| run(case, plan, &maps, &models))
}

/// The simulator's model folder.
pub fn models() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../sim/models")
}

/// The figures of a set of outcomes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Score {
    /// Forecasts scored, and those whose interval held the true crossing.
    pub forecasts: usize,
    /// Of which covered.
    pub covered: usize,
    /// Median of the point forecast's relative error (over forecasts with days).
    pub median_error: f64,
    /// Days with a gap estimate scored, and those whose interval held the truth.
    pub gap_days: usize,
    /// Of which covered.
    pub gap_covered: usize,
    /// Stable drivelines, and those with a false near alarm.
    pub stable: usize,
    /// Of which raised a near alarm.
    pub near_alarms: usize,
    /// Drivelines whose gap was named at the end, and of those the right coupling.
    pub named: usize,
    /// Of which right.
    pub named_right: usize,
}

/// The score of `outcomes` (of one law, or all).
pub fn score<'a>(outcomes: impl IntoIterator<Item = &'a Outcome>) -> Score {
    let mut score = Score {
        forecasts: 0,
        covered: 0,
        median_error: f64::NAN,
        gap_days: 0,
        gap_covered: 0,
        stable: 0,
        near_alarms: 0,
        named: 0,
        named_right: 0,
    };
    let mut errors = Vec::new();
    for outcome in outcomes {
        score.forecasts += outcome.forecasts.len();
        score.covered += outcome.forecasts.iter().filter(|f| f.covered()).count();
        errors.extend(outcome.forecasts.iter().filter_map(Scored::relative_error));
        score.gap_days += outcome.gap_days.len();
        score.gap_covered += outcome.gap_days.iter().filter(|&&c| c).count();
        if outcome.kind == GrowthKind::Stable {
            score.stable += 1;
            score.near_alarms += usize::from(outcome.near_alarm);
        } else if let Some(named) = outcome.coupling_named {
            score.named += 1;
            score.named_right += usize::from(named == outcome.coupling);
        }
    }
    errors.sort_by(f64::total_cmp);
    if !errors.is_empty() {
        score.median_error = errors[errors.len() / 2];
    }
    score
}

/// The table of `outcomes`: per law and overall (Markdown).
pub fn table(outcomes: &[Outcome]) -> String {
    let percent = |part: usize, whole: usize| {
        if whole == 0 {
            "-".to_owned()
        } else {
            format!(
                "{part}/{whole} = {:.1}%",
                100.0 * part as f64 / whole as f64
            )
        }
    };
    let row = |name: &str, s: Score| {
        format!(
            "| {name} | {} | {} | {} | {} | {} |\n",
            percent(s.covered, s.forecasts),
            if s.median_error.is_nan() {
                "-".to_owned()
            } else {
                format!("{:.1}%", 100.0 * s.median_error)
            },
            percent(s.gap_covered, s.gap_days),
            if s.stable == 0 {
                "-".to_owned()
            } else {
                format!("{}/{}", s.near_alarms, s.stable)
            },
            percent(s.named_right, s.named),
        )
    };
    let mut text = String::from(
        "| growth | true crossing in the 90% interval | median error / time to crossing | true gap in the 90% interval (days) | stable: alarm within 30 days | coupling named right |\n\
         |---|---|---|---|---|---|\n",
    );
    for kind in GrowthKind::ALL {
        text.push_str(&row(
            kind.name(),
            score(outcomes.iter().filter(|o| o.kind == kind)),
        ));
    }
    text.push_str(&row("**all**", score(outcomes)));
    text
}

/// The coverage of the crossing per lead (Markdown, one line).
pub fn by_lead(outcomes: &[Outcome]) -> String {
    LEADS_DAYS
        .iter()
        .map(|&lead| {
            let at: Vec<&Scored> = outcomes
                .iter()
                .flat_map(|o| &o.forecasts)
                .filter(|f| f.lead_days == lead)
                .collect();
            let covered = at.iter().filter(|f| f.covered()).count();
            format!("{lead:.0} d: {covered}/{}", at.len())
        })
        .collect::<Vec<_>>()
        .join(", ")
}
