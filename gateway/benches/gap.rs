//! Cost of the gap diagnosis: building a driveline's gap maps (the service's default
//! grid, no cache), estimating the gap of one bite, folding a bite into the wear trend,
//! and the trend's estimate with its forecast.
//!
//!     cargo bench -p millgate --bench gap
//!
//! The maps of the demo's Table 2 driveline (2 couplings, 65 gaps x 16 static torques:
//! 2064 simulated bites) are built on every core, then on one; the estimates run over
//! observations of bites simulated at static torques over 40-170 kN*m with a 2 mrad
//! gap in the spindles and 0.5 kN*m of noise. Prints the median, p99 and max.

use std::path::Path;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;
use std::time::{Duration, Instant};

use millgate::analysis::gap_estimate::{estimate, GapObservation};
use millgate::analysis::gap_trend::GapTrend;
use millgate::analysis::Analysis;
use millgate::field::acquired::Acquired;
use millgate::field::source_health::SourceHealth;
use millgate::state::board::Board;
use millgate_sim::model::Model;
use millgate_sim::schedule::{rolling_schedule, BarTiming};

const MODELS: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../sim/models");
/// Estimates timed per kind.
const ROUNDS: usize = 2000;

fn quantiles(mut times: Vec<Duration>) -> String {
    times.sort();
    let at = |q: f64| times[((times.len() - 1) as f64 * q).round() as usize].as_secs_f64() * 1e3;
    format!(
        "median {:.3} ms, p99 {:.3} ms, max {:.3} ms",
        at(0.5),
        at(0.99),
        at(1.0)
    )
}

fn main() -> anyhow::Result<()> {
    let cache = std::env::temp_dir().join(format!("millgate-gap-bench-{}", std::process::id()));
    let mut config = millgate_config::from_toml_str(
        include_str!("../../config/examples/demo.toml"),
        "demo.toml",
        Path::new(MODELS),
    )?;
    // The service's default grid (the demo's is coarser) and a cache of its own.
    config.drivelines[0].wear = millgate_config::WearSettings::default();
    config.cache_dir = Some(cache.clone());
    let health = Arc::new(SourceHealth::new(
        Duration::from_secs(9),
        Duration::from_secs(9),
    ));
    let board = Arc::new(Board::new(&config, vec![health]));
    let (bites, _) = tokio::sync::broadcast::channel(64);
    let mut analysis = Analysis::new(&config, board, bites)?;
    let job = analysis.take_gap_map_jobs().remove(0);
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let mut maps = None;
    for threads in [cores, 1] {
        let _ = std::fs::remove_dir_all(&cache);
        let started = Instant::now();
        let (built, _) = job.run(threads, &AtomicBool::new(false), &|_, _| {})?;
        println!(
            "gap maps, {} simulated bites on {threads} thread(s): {:.2} s",
            job.spec().simulations(),
            started.elapsed().as_secs_f64()
        );
        maps = Some(built);
    }
    let maps = maps.expect("built");
    let started = Instant::now();
    let (from_cache, _) = job.run(cores, &AtomicBool::new(false), &|_, _| {})?;
    println!(
        "gap maps from the cache: {:.1} ms",
        started.elapsed().as_secs_f64() * 1e3
    );
    assert_eq!(from_cache, maps);
    let _ = std::fs::remove_dir_all(&cache);

    analysis.install_gap_maps(0, Ok(maps.clone()));
    let mut model = Model::load(Path::new(MODELS).join("table2-adjusted.toml"))?;
    model.couplings[1].backlash = 2e-3;
    let torques: Vec<f64> = (0..20)
        .map(|k| 40.0 + 130.0 * f64::from(k) / 19.0)
        .collect();
    let timing = BarTiming {
        idle_s: 0.6,
        rolling_s: 1.2,
    };
    let schedule = rolling_schedule(&model, &torques, timing, 0.5, 1)?;
    let mut observations: Vec<GapObservation> = Vec::new();
    for block in schedule.torque_knm.chunks(100) {
        for report in analysis.handle(Acquired::Samples {
            channel: 0,
            values: block.to_vec(),
            received: None,
            handed: Instant::now(),
        }) {
            observations.extend(report.gap.map(|gap| gap.observation));
        }
    }
    assert_eq!(observations.len(), 20);
    let mut single = Vec::with_capacity(ROUNDS);
    let mut folds = Vec::with_capacity(ROUNDS);
    let mut forecasts = Vec::with_capacity(ROUNDS);
    let mut trend = GapTrend::new(365.0)?;
    // A bite every 2 minutes: the trend's filters narrow, the local grids take over.
    let t0_ms = 1_780_000_000_000_i64;
    for round in 0..ROUNDS {
        let observation = observations[round % observations.len()];
        let started = Instant::now();
        std::hint::black_box(estimate(&maps, std::hint::black_box(&observation)));
        single.push(started.elapsed());
        let started = Instant::now();
        let time = t0_ms + 120_000 * round as i64;
        std::hint::black_box(trend.fold(&maps, std::hint::black_box(&observation), time))?;
        folds.push(started.elapsed());
        let started = Instant::now();
        std::hint::black_box(trend.results(std::hint::black_box(4.0)));
        forecasts.push(started.elapsed());
    }
    println!("estimate of one bite: {}", quantiles(single));
    println!("one bite folded into the wear trend: {}", quantiles(folds));
    println!(
        "the trend's estimate, forecast and cone: {}",
        quantiles(forecasts)
    );
    Ok(())
}
