//! Captures that are large or damaged, and the capture commands' small faults, against
//! the real `millgate` binary (round-4 audit, findings 3, 9 and 12):
//!
//! - a manual capture of 10 stands at 2.5 kHz for 120 s (3 M samples) through the
//!   web API (`/api/captures/{id}` and its `/file` as CSV and Parquet): answered
//!   whole, written as it is sent; the service's peak resident memory grows by less
//!   than 64 MiB for each (built in memory, the JSON alone took about 40 bytes a
//!   sample);
//! - capture rows damaged in the file (`samples` = 2^40, a deflate bomb of 64 MiB of
//!   zeros): the web API answers 500 naming the capture and why, `millgate capture
//!   export` exits 1 saying so; nothing aborts, the service runs on;
//! - `POST /api/captures` with `history.captures = false`: 409 naming the key;
//!   `capture list --db FOLDER` and `--since` after `--until`: exit 1 naming why.

mod common;

use std::io::Write as _;
use std::path::Path;
use std::time::Duration;

use common::{
    free_port, http, http_raw, http_within, millgate, terminate, text, wait_for, web_ready, Setup,
    MILLGATE,
};

/// How long the service may stay silent before and within its answer of the large
/// capture: its head comes after the 3 M samples are read and decoded, which in a debug
/// build on a loaded machine took more than the kit's 10 s (a rehearsal beside release
/// builds: "silent for 10s after 0 bytes of its answer" on the Parquet file).
const BIG_ANSWER: Duration = Duration::from_secs(60);

use millgate::history::rows::insert;
use millgate::history::writer::{connect, insert_run};
use millgate::history::RunInfo;
use millgate::state::captures::{CaptureChannel, CaptureKind, CaptureRecord, KeepClass};
use millgate::state::events::HistoryEvent;
use millgate::state::time::UtcTime;
use millgate_config::Scaling;

/// Stands, sample rate and seconds of the large manual capture.
const STANDS: usize = 10;
const RATE_HZ: f64 = 2500.0;
const SECONDS: usize = 120;

/// A manual capture of `stands` stands, `samples` each: 16-bit counts of 0.001 g of a
/// deterministic vibration (stored as counts, as a Modbus DAQ's are).
fn manual_capture(stands: usize, samples: usize) -> CaptureRecord {
    CaptureRecord {
        kind: CaptureKind::Manual,
        subject: "tandem".into(),
        bite: None,
        first_sample_unix_ns: UtcTime::now().unix_ms() * 1_000_000,
        kernel_time: false,
        sample_rate_hz: RATE_HZ,
        channels: (0..stands)
            .map(|stand| CaptureChannel {
                name: format!("stand{}", stand + 1),
                unit: "g".into(),
                scale: 0.001,
                offset: 0.0,
                samples: (0..samples)
                    .map(|k| {
                        let phase = k as f64 * (0.05 + stand as f64 * 0.01);
                        // Decoded as the gateway decodes a count (0.57, not 57 x 0.01).
                        Scaling::new(0.001, 0.0).apply(f64::from((phase.sin() * 8000.0) as i16))
                    })
                    .collect(),
                timing: None,
            })
            .collect(),
        gaps: vec![],
        analysis: None,
        episode: None,
        keep: KeepClass::Ordinary,
        context: None,
    }
}

/// Write `captures` into the history at `path` as the writer would (ids 1, 2, ...).
fn store(path: &Path, captures: Vec<CaptureRecord>) {
    let mut connection = connect(path).unwrap();
    let run = RunInfo {
        version: "test".into(),
        config_name: "capture faults".into(),
        config_hash: String::new(),
        drivelines: Vec::new(),
    };
    let run_id = insert_run(&connection, UtcTime::now(), &run).unwrap();
    let transaction = connection.transaction().unwrap();
    for capture in captures {
        insert(
            &transaction,
            run_id,
            &HistoryEvent::Capture(Box::new(capture)),
        )
        .unwrap();
    }
    transaction.commit().unwrap();
}

/// Damage capture `id` in the file at `path` with `sql` (`?1` is the id).
fn damage(path: &Path, sql: &str, id: i64) {
    let connection = rusqlite::Connection::open(path).unwrap();
    connection.execute(sql, [id]).unwrap();
}

/// 64 MiB of zeros, deflated (about 64 KiB).
fn deflate_bomb() -> Vec<u8> {
    let mut bomb = flate2::write::DeflateEncoder::new(Vec::new(), flate2::Compression::best());
    let zeros = vec![0u8; 1 << 20];
    for _ in 0..64 {
        bomb.write_all(&zeros).unwrap();
    }
    bomb.finish().unwrap()
}

/// `VmHWM` or `VmRSS` of process `pid`, KiB.
fn memory_kib(pid: u32, field: &str) -> u64 {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap();
    status
        .lines()
        .find_map(|line| line.strip_prefix(field)?.strip_prefix(':'))
        .and_then(|value| value.trim().trim_end_matches(" kB").trim().parse().ok())
        .unwrap_or_else(|| panic!("no {field} in /proc/{pid}/status"))
}

/// How far `pid`'s resident memory rose above what it was while `work` ran, KiB:
/// the peak is reset first (`/proc/PID/clear_refs` 5).
async fn peak_growth_kib<T>(pid: u32, work: impl std::future::Future<Output = T>) -> (T, u64) {
    std::fs::write(format!("/proc/{pid}/clear_refs"), "5").unwrap();
    let before = memory_kib(pid, "VmRSS");
    let value = work.await;
    (value, memory_kib(pid, "VmHWM").saturating_sub(before))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn large_and_damaged_captures_are_served_within_bounds_or_refused() {
    let setup = Setup::new(MILLGATE, "capture-faults", "db").await;
    let samples = SECONDS * RATE_HZ as usize;
    store(
        &setup.history,
        vec![
            manual_capture(STANDS, samples),
            manual_capture(1, 1000),
            manual_capture(1, 1000),
        ],
    );
    damage(
        &setup.history,
        "UPDATE captures SET samples = 1099511627776 WHERE id = ?1",
        2,
    );
    let bomb = deflate_bomb();
    {
        let connection = rusqlite::Connection::open(&setup.history).unwrap();
        connection
            .execute(
                "UPDATE capture_data SET data = ?1 WHERE id = 3",
                [bomb.as_slice()],
            )
            .unwrap();
    }
    let web_port = free_port();
    setup.append_config(&format!(
        "\n[outputs.web]\nbind = \"127.0.0.1:{web_port}\"\n"
    ));
    let mut service = setup.spawn("run.log");
    web_ready(web_port).await;
    let pid = service.id();

    // The large capture: whole, within bounds.
    let (json, grown) = peak_growth_kib(
        pid,
        http_within(web_port, "GET", "/api/captures/1", BIG_ANSWER),
    )
    .await;
    assert_eq!(
        json.status,
        200,
        "{}",
        &json.body[..json.body.len().min(300)]
    );
    assert!(
        !json.body.is_empty(),
        "{:?} {}",
        json.headers,
        setup.log_text("run.log")
    );
    let json = json.json();
    assert_eq!(json["channels"].as_array().unwrap().len(), STANDS);
    assert_eq!(
        json["channels"][STANDS - 1]["samples"]
            .as_array()
            .unwrap()
            .len(),
        samples
    );
    assert_eq!(json["samples"], samples);
    println!("GET /api/captures/1 ({STANDS} x {samples} samples): peak RSS +{grown} KiB");
    assert!(grown < 64 * 1024, "GET /api/captures/1: +{grown} KiB");
    for format in ["csv", "parquet"] {
        let path = format!("/api/captures/1/file?format={format}");
        let (file, grown) =
            peak_growth_kib(pid, http_within(web_port, "GET", &path, BIG_ANSWER)).await;
        assert_eq!(file.status, 200, "{path}");
        println!(
            "GET {path}: {} bytes, peak RSS +{grown} KiB",
            file.body.len()
        );
        assert!(grown < 64 * 1024, "{path}: +{grown} KiB");
        if format == "csv" {
            assert_eq!(file.body.lines().count(), samples + 1, "names, rows");
        }
    }

    // Damaged rows: an error naming the capture and why; the service runs on.
    for (id, why) in [
        (2, "1099511627776 samples of 1 channels claimed"),
        (3, "it inflates past the 10000 bytes 1000 samples can take"),
    ] {
        for path in [
            format!("/api/captures/{id}"),
            format!("/api/captures/{id}/file?format=csv"),
        ] {
            let answer = http(web_port, "GET", &path).await;
            assert_eq!(answer.status, 500, "{path}: {}", answer.body);
            let error = answer.json()["error"].as_str().unwrap().to_owned();
            assert!(
                error.contains(&format!("capture {id}: the samples are damaged ({why}")),
                "{path}: {error}"
            );
        }
    }
    assert!(service.try_wait().unwrap().is_none(), "the service runs on");
    terminate(&mut service);

    // The CLI: exit 1 with the same sentence, not an abort.
    let db = setup.history.to_str().unwrap();
    let out = setup.scratch.join("out");
    for (id, why) in [(2, "claimed, over the"), (3, "it inflates past")] {
        let export = millgate(&[
            "capture",
            "export",
            "--db",
            db,
            "--id",
            &id.to_string(),
            "--format",
            "csv",
            "--out",
            out.to_str().unwrap(),
        ]);
        assert_eq!(export.status.code(), Some(1), "{}", text(&export));
        assert!(text(&export).contains(why), "{}", text(&export));
    }
    setup.stop(service).await;
}

/// `POST /api/captures` of 5 s of F1 to the page at `web_port`.
async fn ask_for_capture(web_port: u16) -> common::HttpAnswer {
    let body = r#"{"subject": "F1", "seconds": 5}"#;
    let request = format!(
        "POST /api/captures HTTP/1.1\r\nhost: localhost\r\nconnection: close\r\n\
         content-type: application/json\r\ncontent-length: {}\r\n\r\n{body}",
        body.len()
    );
    http_raw(web_port, request.as_bytes()).await
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn capture_commands_name_what_is_wrong() {
    let setup = Setup::new(MILLGATE, "capture-small", "db").await;
    let web_port = free_port();
    // Under [history], the configuration's last table.
    setup.append_config(&format!(
        "captures = false\n\n[outputs.web]\nbind = \"127.0.0.1:{web_port}\"\n\
         allow_commands = true\n"
    ));
    let mut service = setup.spawn("run.log");
    web_ready(web_port).await;
    let answer = ask_for_capture(web_port).await;
    assert_eq!(answer.status, 409, "{}", answer.body);
    assert!(
        answer.body.contains("history.captures = false"),
        "{}",
        answer.body
    );
    terminate(&mut service);

    let folder = setup.history.parent().unwrap().to_str().unwrap().to_owned();
    let listed = millgate(&["capture", "list", "--db", &folder]);
    assert_eq!(listed.status.code(), Some(1), "{}", text(&listed));
    assert!(
        text(&listed).contains("a folder, not a history file"),
        "{}",
        text(&listed)
    );
    let db = setup.history.to_str().unwrap();
    let backwards = millgate(&[
        "capture",
        "list",
        "--db",
        db,
        "--since",
        "2030-01-01",
        "--until",
        "2020-01-01",
    ]);
    assert_eq!(backwards.status.code(), Some(1), "{}", text(&backwards));
    assert!(
        text(&backwards).contains("--since (2030-01-01T00:00:00.000Z) must be before --until"),
        "{}",
        text(&backwards)
    );
    setup.stop(service).await;
}

/// 40 `POST /api/captures` in a row from one client (round-4 audit finding 8): two
/// log lines each before (the web API's and the analysis'); now the first of each,
/// the rest counted in the next line logged.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_loop_of_capture_requests_is_logged_once_per_period() {
    let setup = Setup::new(MILLGATE, "capture-flood", "db").await;
    let web_port = free_port();
    setup.append_config(&format!(
        "\n[outputs.web]\nbind = \"127.0.0.1:{web_port}\"\nallow_commands = true\n"
    ));
    let mut service = setup.spawn("run.log");
    web_ready(web_port).await;
    for _ in 0..40 {
        let answer = ask_for_capture(web_port).await;
        assert_eq!(answer.status, 202, "{}", answer.body);
    }
    // The analysis takes the commands in its turns: the first one's line is logged
    // (waited for: a fixed half second was too short on a loaded machine).
    wait_for(
        "the manual capture started",
        Duration::from_secs(20),
        || setup.log_text("run.log").contains("manual capture started"),
    )
    .await;
    terminate(&mut service);
    let log = setup.log_text("run.log");
    let lines = |text: &str| log.lines().filter(|line| line.contains(text)).count();
    assert_eq!(
        lines("manual capture asked through the web API"),
        1,
        "{log}"
    );
    assert_eq!(lines("manual capture started"), 1, "{log}");
    setup.stop(service).await;
}
