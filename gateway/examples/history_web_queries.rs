//! Times the history queries behind the maintenance page (issue 18) on a history
//! file, e.g. the year fixture of `examples/history_year.rs`: each query is run once
//! (the first, "cold": SQLite's page cache empty, the file in the OS cache or not),
//! then `--runs` times; prints first, median, p95 and max, ms, and the rows returned.
//!
//! Run with:
//!
//!     cargo run --release -p millgate --example history_year -- --out /tmp/year.sqlite
//!     cargo run --release -p millgate --example history_web_queries -- --db /tmp/year.sqlite
//!
//! Each query opens its own reader, as the web API does per request (the "open"
//! row is that alone).

use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::Context;
use clap::Parser;
use millgate::history::query::{AlarmRow, BiteRow, Filter, HistoryReader, OutageRow};
use millgate::state::time::UtcTime;

#[derive(Debug, Parser)]
struct Args {
    /// The history file.
    #[arg(long)]
    db: PathBuf,
    /// Timed runs per query (after the first).
    #[arg(long, default_value_t = 30)]
    runs: usize,
    /// The driveline whose page is timed.
    #[arg(long, default_value = "F1")]
    driveline: String,
}

const DAY: Duration = Duration::from_secs(86_400);
/// The web page's trend window (`outputs::web::api::TREND_WINDOW`).
const TREND_WINDOW: Duration = Duration::from_secs(28 * 86_400);

/// Runs `query` once and then `runs` times; prints the row.
fn time(
    name: &str,
    runs: usize,
    db: &std::path::Path,
    mut query: impl FnMut(&HistoryReader) -> anyhow::Result<usize>,
) -> anyhow::Result<()> {
    let mut once = || -> anyhow::Result<(Duration, usize)> {
        let begun = Instant::now();
        let reader = HistoryReader::open(db)?;
        let rows = query(&reader)?;
        Ok((begun.elapsed(), rows))
    };
    let (first, rows) = once()?;
    let mut times = Vec::with_capacity(runs);
    for _ in 0..runs {
        times.push(once()?.0);
    }
    times.sort();
    let ms = |d: Duration| d.as_secs_f64() * 1e3;
    let at = |q: f64| times[((times.len() - 1) as f64 * q).round() as usize];
    println!(
        "| {name:<44} | {:>8.2} | {:>8.2} | {:>8.2} | {:>8.2} | {rows:>6} |",
        ms(first),
        ms(at(0.5)),
        ms(at(0.95)),
        ms(*times.last().unwrap_or(&first))
    );
    Ok(())
}

fn main() -> anyhow::Result<()> {
    let args = Args::parse();
    let db = args.db.as_path();
    let reader = HistoryReader::open(db).with_context(|| format!("{}", db.display()))?;
    let name = args.driveline.clone();
    let last_bite: String = reader
        .newest::<BiteRow>(&Filter {
            name: Some(name.clone()),
            limit: Some(1),
            ..Filter::default()
        })?
        .pop()
        .with_context(|| format!("no bites of {name} in {}", db.display()))?
        .time();
    let last = UtcTime::parse(&last_bite)?;
    let drivelines = reader.drivelines()?;
    drop(reader);
    let bytes = std::fs::metadata(db)?.len();
    println!(
        "{}: {:.0} MiB, drivelines {drivelines:?}, {name}'s last bite {last}; {} runs",
        db.display(),
        bytes as f64 / (1024.0 * 1024.0),
        args.runs
    );
    println!(
        "| {:<44} | {:>8} | {:>8} | {:>8} | {:>8} | {:>6} |",
        "query", "first ms", "median", "p95", "max", "rows"
    );
    println!(
        "|{:-<46}|{:->10}|{:->10}|{:->10}|{:->10}|{:->8}|",
        "", "", "", "", "", ""
    );
    let runs = args.runs;
    time("open (read-only reader)", runs, db, |_| Ok(0))?;
    for (label, period) in [("week", 7), ("month", 30), ("year", 365)] {
        let since = last.minus(DAY * period);
        time(
            &format!("wear_series {name}, last {label}, 500 points"),
            runs,
            db,
            |reader| Ok(reader.wear_series(&name, Some(since), None, 500)?.len()),
        )?;
    }
    time(
        &format!("wear_series {name}, whole file, 300 points"),
        runs,
        db,
        |reader| Ok(reader.wear_series(&name, None, None, 300)?.len()),
    )?;
    let newest =
        |filter: Filter| move |reader: &HistoryReader| Ok(reader.newest::<BiteRow>(&filter)?.len());
    time(
        &format!("bites {name}, newest 100"),
        runs,
        db,
        newest(Filter {
            name: Some(name.clone()),
            limit: Some(100),
            ..Filter::default()
        }),
    )?;
    time(
        &format!("bites {name}, newest 100 of the last day"),
        runs,
        db,
        newest(Filter {
            name: Some(name.clone()),
            since: Some(last.minus(DAY)),
            limit: Some(100),
            ..Filter::default()
        }),
    )?;
    time(
        &format!("bites {name}, newest 100 of a day 6 months ago"),
        runs,
        db,
        newest(Filter {
            name: Some(name.clone()),
            since: Some(last.minus(DAY * 183)),
            until: Some(last.minus(DAY * 182)),
            limit: Some(100),
            ..Filter::default()
        }),
    )?;
    time(
        &format!("bites {name}, a day 6 months ago, oldest first"),
        runs,
        db,
        |reader| {
            Ok(reader
                .bites(&Filter {
                    name: Some(name.clone()),
                    since: Some(last.minus(DAY * 183)),
                    until: Some(last.minus(DAY * 182)),
                    limit: Some(10_000),
                    ..Filter::default()
                })?
                .len())
        },
    )?;
    time("alarms, newest 100", runs, db, |reader| {
        Ok(reader
            .newest::<AlarmRow>(&Filter {
                limit: Some(100),
                ..Filter::default()
            })?
            .len())
    })?;
    time(
        &format!("alarms of {name}, newest 100"),
        runs,
        db,
        |reader| {
            Ok(reader
                .newest::<AlarmRow>(&Filter {
                    name: Some(name.clone()),
                    limit: Some(100),
                    ..Filter::default()
                })?
                .len())
        },
    )?;
    time(&format!("gap_trend {name}, 28 days"), runs, db, |reader| {
        Ok(usize::from(
            reader.gap_trend(&name, None, TREND_WINDOW)?.is_some(),
        ))
    })?;
    // The overview's history part per driveline (the web's `add_history`): the gap
    // trend, the source's outages of the last 24 h and its last outage.
    time(
        &format!("overview history part, {} drivelines", drivelines.len()),
        runs,
        db,
        |reader| {
            let mut rows = 0;
            for (k, driveline) in drivelines.iter().enumerate() {
                let source = format!("daq{}", k + 1);
                rows += reader
                    .outages(&Filter {
                        name: Some(source.clone()),
                        since: Some(last.minus(DAY)),
                        ..Filter::default()
                    })?
                    .len();
                rows += reader
                    .newest::<OutageRow>(&Filter {
                        name: Some(source),
                        limit: Some(1),
                        ..Filter::default()
                    })?
                    .len();
                rows += usize::from(reader.gap_trend(driveline, None, TREND_WINDOW)?.is_some());
            }
            Ok(rows)
        },
    )?;
    time(
        "state a start restores (restore::read)",
        runs.min(5),
        db,
        |reader| Ok(reader.state()?.drivelines.len()),
    )?;
    Ok(())
}
