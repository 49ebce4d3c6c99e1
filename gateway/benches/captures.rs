//! Captures: storage throughput and bytes per bite, and export throughput on a large
//! file in bounded memory.
//!
//! The bite windows are the demo's (its simulated driveline with a growing gap, noise
//! 0.5 kN*m RMS), read as the DAQ gives them (16-bit counts of the torque channel's
//! scale) and analysed by the real analysis with captures on.
//!
//! 1. **Storage**: bites with their captures recorded through the real [`History`]
//!    and writer thread as fast as the queue takes them; prints bites stored per
//!    second and the file's bytes per bite with captures minus a file of the same
//!    bites without them (pages in use, so the row, its indexes and the page packing
//!    are counted), and the blob alone.
//! 2. **Export**: a file of `--captures N` captures (default 20 000; `--captures
//!    123000` is a year of one bite every 30 s thinned after 7 days to every 10th)
//!    written by the writer's own insert; then `millgate capture export` of the last
//!    2 000 of them (by time range) to CSV and to Parquet; prints captures/s, MB/s and
//!    the peak resident memory during the export (`VmHWM` after resetting it).
//!
//! Run with:
//!
//!     cargo bench -p millgate --bench captures
//!     cargo bench -p millgate --bench captures -- --captures 123000

use std::path::Path;
use std::sync::Arc;
use std::time::{Duration, Instant};

use millgate::analysis::driveline::{bite_record, BiteReport};
use millgate::analysis::Analysis;
use millgate::cli::capture::{ExportArgs, ExportFormat, Selection};
use millgate::field::acquired::Acquired;
use millgate::field::source_health::SourceHealth;
use millgate::history::rows::insert;
use millgate::history::writer::{connect, insert_run};
use millgate::history::RunInfo;
use millgate::state::board::Board;
use millgate::state::captures::{CaptureRecord, CapturedBite, KeepClass};
use millgate::state::events::{BiteRecord, HistoryEvent};
use millgate::state::history::History;
use millgate::state::results::DrivelineResults;
use millgate::state::time::UtcTime;

const STORED_BITES: usize = 5_000;
const EXPORTED: usize = 2_000;

/// A bite's record and its capture, as the analysis makes them.
type Captured = (BiteRecord, CaptureRecord);

/// The demo's bites with their captures, as the analysis records them.
fn demo_bites() -> anyhow::Result<Vec<Captured>> {
    let demo = millgate_sim::devices::demo::setup(120.0, 0.5, 7)?;
    let mut config = demo.config;
    let scratch =
        std::env::temp_dir().join(format!("millgate-bench-captures-{}", std::process::id()));
    config.history = Some(millgate_config::History {
        path: scratch.join("unused.db"),
        retention_days: 400,
        max_size_mb: 1024,
        captures: millgate_config::CaptureSettings::defaults(1024),
        synchronous: millgate_config::Synchronous::default(),
    });
    let torque = config.channels[config.drivelines[0].torque].clone();
    let health = Arc::new(SourceHealth::new(
        Duration::from_secs(3600),
        Duration::from_secs(3600),
    ));
    let board = Arc::new(Board::new(&config, vec![health]));
    let (bites, mut reports) = tokio::sync::broadcast::channel(4096);
    let mut analysis = Analysis::new(&config, Arc::clone(&board), bites)?;
    let counts = millgate_tests::kit::as_daq_sends(&demo.schedule, &torque);
    for block in counts.chunks(100) {
        analysis.handle(Acquired::Samples {
            channel: 0,
            values: block.to_vec(),
            received: None,
            handed: Instant::now(),
        });
    }
    let mut pairs = Vec::new();
    while let Ok(report) = reports.try_recv() {
        let time = UtcTime::from_system(report.time);
        let capture = report.capture(CapturedBite { counter: 0, time }, KeepClass::Ordinary);
        if let Some(capture) = capture {
            pairs.push((bite_record_of(&report), capture));
        }
    }
    anyhow::ensure!(!pairs.is_empty(), "the demo gave no bites");
    Ok(pairs)
}

/// The history's record of `report` as the analysis makes it (the state after it: its
/// time, no gap estimate; [`event`] numbers it).
fn bite_record_of(report: &BiteReport) -> BiteRecord {
    let state = DrivelineResults {
        last_bite_unix_ms: Some(UtcTime::from_system(report.time).unix_ms()),
        ..DrivelineResults::default()
    };
    bite_record(report, &state, None)
}

/// The event the analysis records for bite `n` (counter n + 1) of `bites`: the bite with
/// its capture (one event, as the service's), or the bite alone; at `time` when given.
fn event(bites: &[Captured], n: usize, captured: bool, time: Option<UtcTime>) -> HistoryEvent {
    let (bite, capture) = &bites[n % bites.len()];
    let mut bite = bite.clone();
    let counter = n as u32 + 1;
    for figures in [&mut bite.figures, &mut bite.state] {
        figures.bite_counter = counter;
        if let Some(time) = time {
            figures.last_bite_unix_ms = Some(time.unix_ms());
        }
    }
    if let Some(time) = time {
        bite.time = time;
    }
    if !captured {
        return HistoryEvent::Bite(Box::new(bite));
    }
    let mut capture = capture.clone();
    if let Some(time) = time {
        capture.first_sample_unix_ns = time.unix_ms() * 1_000_000;
    }
    if let Some(of) = &mut capture.bite {
        of.counter = counter;
        of.time = bite.time;
    }
    HistoryEvent::CapturedBite(Box::new(bite), Box::new(capture))
}

fn run_info() -> RunInfo {
    RunInfo {
        version: "bench".into(),
        config_name: "captures bench".into(),
        config_hash: String::new(),
        drivelines: Vec::new(),
    }
}

fn data_bytes(path: &Path) -> anyhow::Result<u64> {
    let connection = rusqlite::Connection::open(path)?;
    connection.execute_batch("PRAGMA wal_checkpoint(TRUNCATE)")?;
    let pragma = |name: &str| -> anyhow::Result<i64> {
        Ok(connection.pragma_query_value(None, name, |row| row.get(0))?)
    };
    Ok(((pragma("page_count")? - pragma("freelist_count")?) * pragma("page_size")?) as u64)
}

/// Record `bites` (each with its capture when `captures`) through the real writer;
/// returns the time it took until all were committed.
async fn store(path: &Path, bites: &[Captured], captures: bool) -> anyhow::Result<Duration> {
    let config = millgate_config::History {
        path: path.to_path_buf(),
        retention_days: 400,
        max_size_mb: 1_000_000,
        captures: millgate_config::CaptureSettings {
            max_mb: 500_000,
            ..millgate_config::CaptureSettings::defaults(1_000_000)
        },
        synchronous: millgate_config::Synchronous::default(),
    };
    let history = History::new(Some(&config));
    millgate::history::start(&history, run_info());
    let started = Instant::now();
    for n in 0..STORED_BITES {
        let event = event(bites, n, captures, None);
        while !history.record(event.clone()) {
            tokio::time::sleep(Duration::from_millis(1)).await;
        }
    }
    let through = history.enqueued();
    while !history.wait_settled(through, Duration::from_secs(60)).await {}
    let took = started.elapsed();
    tokio::task::spawn_blocking(move || history.close()).await?;
    Ok(took)
}

/// A file of `count` captures, one bite every 30 s up to now: the writer's inserts in
/// transactions of 1 000.
fn year_file(path: &Path, bites: &[Captured], count: usize) -> anyhow::Result<()> {
    let mut connection = connect(path)?;
    let now = UtcTime::now().unix_ms();
    let first = now - count as i64 * 30_000;
    let run = insert_run(&connection, UtcTime::from_unix_ms(first), &run_info())?;
    for chunk in (0..count).collect::<Vec<_>>().chunks(1000) {
        let transaction = connection.transaction()?;
        for &n in chunk {
            let time = UtcTime::from_unix_ms(first + n as i64 * 30_000);
            insert(&transaction, run, &event(bites, n, true, Some(time)))?;
        }
        transaction.commit()?;
    }
    Ok(())
}

/// Peak resident memory since the last reset, kB (Linux `VmHWM`).
fn peak_rss_kb() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    status
        .lines()
        .find_map(|line| line.strip_prefix("VmHWM:"))
        .and_then(|rest| rest.trim().trim_end_matches("kB").trim().parse().ok())
}

fn reset_peak_rss() {
    let _ = std::fs::write("/proc/self/clear_refs", "5");
}

fn folder_bytes(folder: &Path) -> u64 {
    std::fs::read_dir(folder)
        .map(|entries| {
            entries
                .filter_map(|e| e.ok()?.metadata().ok())
                .map(|m| m.len())
                .sum()
        })
        .unwrap_or(0)
}

#[tokio::main(flavor = "multi_thread", worker_threads = 2)]
async fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let count = args
        .iter()
        .position(|a| a == "--captures")
        .and_then(|i| args.get(i + 1)?.parse().ok())
        .unwrap_or(20_000usize);
    let scratch =
        std::env::temp_dir().join(format!("millgate-bench-captures-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&scratch);
    std::fs::create_dir_all(&scratch)?;
    let bites = demo_bites()?;
    let blob_mean = bites
        .iter()
        .filter_map(|(_, capture)| {
            millgate::history::captures::encode(capture)
                .ok()
                .map(|(blob, _)| blob.len())
        })
        .sum::<usize>() as f64
        / bites.len() as f64;
    let samples = bites[0].1.samples();

    let with = scratch.join("with.db");
    let without = scratch.join("without.db");
    let took_with = store(&with, &bites, true).await?;
    let took_without = store(&without, &bites, false).await?;
    let per_bite = (data_bytes(&with)? as f64 - data_bytes(&without)? as f64) / STORED_BITES as f64;
    println!(
        "storage: {STORED_BITES} bites ({} distinct demo windows of {samples} samples) with captures \
         {:.0} bites/s, without {:.0} bites/s; capture bytes per bite in the file {per_bite:.0} \
         (blob alone {blob_mean:.0})",
        bites.len(),
        STORED_BITES as f64 / took_with.as_secs_f64(),
        STORED_BITES as f64 / took_without.as_secs_f64(),
    );
    println!(
        "  a year of one bite every 30 s per driveline: {:.2} GB kept whole, {:.2} GB thinned to \
         every 10th after 7 days",
        per_bite * 365.0 * 2880.0 / 1e9,
        per_bite * (7.0 * 2880.0 + 358.0 * 288.0) / 1e9
    );

    let big = scratch.join("year.db");
    let started = Instant::now();
    year_file(&big, &bites, count)?;
    println!(
        "export: a file of {count} captures ({:.0} MB) written in {:.1} s",
        std::fs::metadata(&big)?.len() as f64 / 1e6,
        started.elapsed().as_secs_f64()
    );
    let since = UtcTime::from_unix_ms(UtcTime::now().unix_ms() - EXPORTED as i64 * 30_000 - 15_000);
    for format in [ExportFormat::Csv, ExportFormat::Parquet] {
        let out = scratch.join(format!("out-{format:?}"));
        reset_peak_rss();
        let started = Instant::now();
        let written = millgate::cli::capture::export(&ExportArgs {
            selection: Selection {
                db: big.clone(),
                driveline: None,
                kind: None,
                since: Some(since.to_string()),
                until: None,
                product: None,
                coil: None,
            },
            bite: None,
            id: None,
            format,
            out: out.clone(),
        })?;
        let took = started.elapsed().as_secs_f64();
        println!(
            "  {format:?}: {} captures in {took:.2} s, {:.0} captures/s, {:.1} MB/s written, peak RSS {} kB",
            written.len(),
            written.len() as f64 / took,
            folder_bytes(&out) as f64 / 1e6 / took,
            peak_rss_kb().map_or("?".to_owned(), |kb| kb.to_string())
        );
    }
    let _ = std::fs::remove_dir_all(&scratch);
    Ok(())
}
