//! The event history's writer under load: the real [`History`] handle and writer
//! thread (WAL, `synchronous=FULL`, group commit) on a file in the system's temporary
//! folder.
//!
//! 1. **Sustained**: bites recorded as fast as the queue takes them (never dropped: the
//!    producer waits while the queue is full); prints bites stored per second, the mean
//!    group size and the mean and longest commit.
//! 2. **Commit latency**: one bite at a time, each waited for until committed (what the
//!    PLC writer waits for before a write); prints p50, p99 and max.
//! 3. **Retention** (with `--retention-mb N`, e.g. 1024): a file filled by SQL to N MiB
//!    of recent bites and wear estimates is opened with `max_size_mb` at 3/4 of it while
//!    a bite is recorded every 10 ms and waited for; prints how long the retention took
//!    to bring the file under the limit, the rows it deleted, and the bites' commit
//!    latency meanwhile (p50, p99, max): a stalled writer shows there.
//!
//! Run with:
//!
//!     cargo bench -p millgate --bench history
//!     cargo bench -p millgate --bench history -- --retention-mb 1024

use std::path::Path;
use std::time::{Duration, Instant};

use millgate::history::RunInfo;
use millgate::state::events::{BiteRecord, HistoryEvent};
use millgate::state::history::{History, QUEUE_CAPACITY};
use millgate::state::results::DrivelineResults;
use millgate::state::time::UtcTime;

const SUSTAINED_BITES: u32 = 200_000;
const LATENCY_BITES: u32 = 2_000;

fn bite(n: u32) -> HistoryEvent {
    let time = UtcTime::now();
    let taf = 1.8 + f64::from(n % 100) * 0.01;
    let mut record = BiteRecord::clean(
        &format!("F{}", n % 7 + 1),
        "spindle_top",
        time,
        DrivelineResults {
            bite_counter: n,
            static_torque_knm: Some(420.0),
            peak_torque_knm: Some(taf * 420.0),
            taf: Some(taf),
            first_period_s: Some(0.05),
            first_period_shift_s: Some(0.002),
            beta1_hz: Some(12.0),
            beta2_hz: Some(21.0),
            wear_index: Some(taf / 1.8 - 1.0),
            wear_trend: Some(0.05),
            ..DrivelineResults::default()
        },
    );
    record.second_period_s = Some(0.048);
    record.reference_taf = Some(1.8);
    record.reference_level_knm = Some(400.0);
    record.shift_over_linear_s = Some(0.001);
    HistoryEvent::Bite(Box::new(record))
}

fn run_info() -> RunInfo {
    RunInfo {
        version: "bench".into(),
        config_name: "history bench".into(),
        config_hash: String::new(),
        drivelines: Vec::new(),
    }
}

fn open(path: &Path, max_size_mb: u32) -> History {
    let history = History::new(Some(&millgate_config::History {
        path: path.to_path_buf(),
        retention_days: 400,
        max_size_mb,
        captures: millgate_config::CaptureSettings::defaults(max_size_mb),
        synchronous: millgate_config::Synchronous::default(),
    }));
    millgate::history::start(&history, run_info());
    history
}

/// `p` (0..=1) quantile of sorted `values`.
fn quantile(sorted: &[Duration], p: f64) -> Duration {
    let index = ((sorted.len() - 1) as f64 * p).round() as usize;
    sorted[index]
}

fn print_latency(what: &str, mut latencies: Vec<Duration>) {
    latencies.sort();
    println!(
        "{what}: {} bites, p50 {:.2} ms, p99 {:.2} ms, max {:.2} ms",
        latencies.len(),
        quantile(&latencies, 0.5).as_secs_f64() * 1e3,
        quantile(&latencies, 0.99).as_secs_f64() * 1e3,
        latencies.last().unwrap().as_secs_f64() * 1e3
    );
}

/// Record one bite and wait until it is committed; the time that took.
async fn stored_in(history: &History, n: u32) -> Duration {
    let start = Instant::now();
    assert!(history.record(bite(n)), "the queue took the bite");
    assert!(
        history
            .wait_settled(history.enqueued(), Duration::from_secs(30))
            .await,
        "not committed within 30 s"
    );
    start.elapsed()
}

async fn sustained(folder: &Path) {
    let path = folder.join("sustained.db");
    let history = open(&path, 4096);
    let start = Instant::now();
    for n in 1..=SUSTAINED_BITES {
        // Never drop: wait while the queue is full (one producer, so no race).
        while history.enqueued() - history.stored() >= QUEUE_CAPACITY as u64 - 1 {
            std::thread::sleep(Duration::from_micros(100));
        }
        assert!(history.record(bite(n)));
    }
    assert!(
        history
            .wait_settled(u64::from(SUSTAINED_BITES), Duration::from_secs(600))
            .await
    );
    let took = start.elapsed();
    let status = history.status();
    history.close();
    assert_eq!(status.stored, u64::from(SUSTAINED_BITES));
    println!(
        "sustained: {SUSTAINED_BITES} bites in {:.2} s = {:.0} bites/s stored; {} commits \
         (mean {:.0} bites each), commit mean {:.2} ms, max {:.2} ms; file {:.1} MiB",
        took.as_secs_f64(),
        f64::from(SUSTAINED_BITES) / took.as_secs_f64(),
        status.commits,
        status.stored as f64 / status.commits as f64,
        status.commit_seconds_sum / status.commits as f64 * 1e3,
        status.commit_seconds_max * 1e3,
        std::fs::metadata(&path).map_or(0, |m| m.len()) as f64 / (1 << 20) as f64
    );
}

async fn commit_latency(folder: &Path) {
    let history = open(&folder.join("latency.db"), 4096);
    let mut latencies = Vec::new();
    for n in 1..=LATENCY_BITES {
        latencies.push(stored_in(&history, n).await);
    }
    history.close();
    print_latency("commit latency, one bite at a time", latencies);
}

/// Fill `path` by SQL with recent bites and their wear estimates to `mb` MiB.
fn fill(path: &Path, mb: u64) {
    let connection = millgate::history::writer::connect(path).unwrap();
    connection
        .execute(
            "INSERT INTO gateway_runs (started_at, stopped_at, ended, version, config_name)
             VALUES (?1, ?1, 'stopped', 'bench', 'bench')",
            [UtcTime::now().to_string()],
        )
        .unwrap();
    let size = |connection: &rusqlite::Connection| -> u64 {
        let pages: i64 = connection
            .query_row("PRAGMA page_count", [], |row| row.get(0))
            .unwrap();
        u64::try_from(pages).unwrap() * 4096
    };
    let start = Instant::now();
    while size(&connection) < mb << 20 {
        // 200 000 more bites 10 s apart from 300 days ago on (in time order, as the
        // service writes them), then their wear estimates.
        connection
            .execute_batch(
                "BEGIN;
                 WITH RECURSIVE n(i) AS (SELECT 1 UNION ALL SELECT i + 1 FROM n WHERE i < 200000),
                     base(b) AS (SELECT coalesce(max(id), 0) FROM bites)
                 INSERT INTO bites (run_id, driveline, time, bite_counter, channel,
                     static_torque_knm, peak_torque_knm, taf, first_period_s, second_period_s,
                     period_shift_s, beta1_hz, beta2_hz, quality, degraded, wear_index,
                     wear_trend, reference_taf, shift_over_linear_s)
                 SELECT 1, 'F' || ((b + i) % 7 + 1),
                     strftime('%Y-%m-%dT%H:%M:%fZ', 'now', '-300 days', '+' || ((b + i) * 10) || ' seconds'),
                     b + i, 'spindle_top', 420.0 + i % 13, 800.0 + i % 17, 1.9 + (i % 10) * 0.01,
                     0.05, 0.048, 0.002, 12.0, 21.0, 'good', 0, 0.05, 0.04, 1.8, 0.001
                 FROM n, base;
                 INSERT INTO wear_estimates (run_id, driveline, time, event, origin, wear_index,
                     wear_trend, reference_taf, reference_level_knm, shift_over_linear_s)
                 SELECT 1, driveline, time, 'bite', 'analysis', wear_index, wear_trend,
                     reference_taf, 400.0, shift_over_linear_s
                 FROM bites WHERE id > (SELECT coalesce(max(id), 0) - 200000 FROM bites);
                 COMMIT;",
            )
            .unwrap();
    }
    connection
        .execute_batch("PRAGMA wal_checkpoint(TRUNCATE)")
        .unwrap();
    println!(
        "retention: filled {:.0} MiB in {:.1} s",
        size(&connection) as f64 / (1 << 20) as f64,
        start.elapsed().as_secs_f64()
    );
}

async fn retention(folder: &Path, mb: u64) {
    let path = folder.join("retention.db");
    fill(&path, mb);
    let limit_mb = u32::try_from(mb * 3 / 4).unwrap();
    let history = open(&path, limit_mb);
    let limit = u64::from(limit_mb) << 20;
    let start = Instant::now();
    let mut latencies = Vec::new();
    let mut n = 0;
    loop {
        n += 1;
        latencies.push(stored_in(&history, n).await);
        let status = history.status();
        if status.retention_deleted > 0 && status.file_bytes > 0 && status.file_bytes <= limit {
            break;
        }
        assert!(start.elapsed() < Duration::from_secs(1800), "{status:?}");
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    let took = start.elapsed();
    let status = history.status();
    history.close();
    println!(
        "retention: {mb} MiB file to under {limit_mb} MiB in {:.1} s, {} rows deleted, \
         file now {:.0} MiB",
        took.as_secs_f64(),
        status.retention_deleted,
        status.file_bytes as f64 / (1 << 20) as f64
    );
    print_latency("retention: commit latency meanwhile", latencies);
}

#[tokio::main(flavor = "current_thread")]
async fn main() {
    let args: Vec<String> = std::env::args().collect();
    let retention_mb = args
        .iter()
        .position(|arg| arg == "--retention-mb")
        .map(|at| args[at + 1].parse::<u64>().expect("--retention-mb MiB"));
    let folder =
        std::env::temp_dir().join(format!("millgate-history-bench-{}", std::process::id()));
    std::fs::create_dir_all(&folder).unwrap();
    sustained(&folder).await;
    commit_latency(&folder).await;
    if let Some(mb) = retention_mb {
        retention(&folder, mb).await;
    }
    std::fs::remove_dir_all(&folder).unwrap();
}
