//! The event history as a store: what is recorded comes back from the file (through
//! the read API, Debian's `sqlite3` and Python's `sqlite3`), a second start restores
//! counters, wear trend, latched alarms and last values, the retention keeps the file
//! within its size and age, and an unusable file is reported, not fatal.

use std::path::Path;
use std::process::Command;
use std::time::Duration;

use millgate::history::query::{Filter, HistoryReader};
use millgate::history::retention::{Retention, RetentionState};
use millgate::history::schema;
use millgate::history::{DrivelineSettings, RunInfo};
use millgate::outputs::modbus::register_map::{flag_mask, RegisterMap};
use millgate::state::catalogue::DRIVELINE;
use millgate::state::commands::CommandOrigin;
use millgate::state::events::{
    AlarmEvent, AlarmKind, AlarmRecord, BiteRecord, EndedBy, HistoryEvent, PooledBite, StateRecord,
    SubjectResults, WearState,
};
use millgate::state::history::{History, HistoryState};
use millgate::state::results::{DrivelineResults, GapResults, Results};
use millgate::state::time::UtcTime;
use millgate_tests::kit::scratch;

fn config(path: &Path) -> millgate_config::History {
    millgate_config::History {
        path: path.to_path_buf(),
        retention_days: 400,
        max_size_mb: 1024,
        captures: millgate_config::CaptureSettings::defaults(1024),
        synchronous: millgate_config::Synchronous::default(),
    }
}

fn run_info() -> RunInfo {
    RunInfo {
        version: "test".into(),
        config_name: "Test mill".into(),
        config_hash: String::new(),
        drivelines: vec![DrivelineSettings {
            name: "F1".into(),
            taf_warning: 2.2,
            taf_alarm: 2.6,
            model: None,
            gap_warning_mrad: None,
            gap_alarm_mrad: None,
        }],
    }
}

/// Bite `n` (1-based) of F1 at `time`, with the state after it.
fn bite(n: u32, time: UtcTime, taf: f64, trend: f64, alarm: bool) -> HistoryEvent {
    let state = DrivelineResults {
        bite_counter: n,
        last_bite_unix_ms: Some(time.unix_ms()),
        static_torque_knm: Some(100.0 + f64::from(n)),
        peak_torque_knm: Some(taf * (100.0 + f64::from(n))),
        taf: Some(taf),
        first_period_s: Some(0.05),
        first_period_shift_s: Some(0.002),
        beta1_hz: Some(12.0),
        beta2_hz: Some(21.0),
        wear_index: Some(taf / 1.8 - 1.0),
        wear_trend: Some(trend),
        last_bite_degraded: n.is_multiple_of(7),
        taf_warning: taf >= 2.2,
        taf_alarm: alarm,
        source_stale: false,
        restored: false,
        ..DrivelineResults::default()
    };
    HistoryEvent::Bite(Box::new(BiteRecord {
        driveline: "F1".into(),
        channel: "spindle_top".into(),
        time,
        figures: state.clone(),
        second_period_s: Some(0.048),
        quality: "good",
        reference_taf: Some(1.8),
        reference_level_knm: Some(100.0),
        shift_over_linear_s: None,
        gap_state: None,
        gap_trend: None,
        fatigue_ledger: None,
        context: None,
        pooled: pooled(n, taf),
        state,
    }))
}

/// What bite `n` with `taf` put into the gap pool (its own static torque, TAF and
/// period shift, as the analysis pools them): nothing when its window was degraded.
fn pooled(n: u32, taf: f64) -> Option<PooledBite> {
    (!n.is_multiple_of(7)).then(|| PooledBite {
        static_torque_knm: 100.0 + f64::from(n),
        taf,
        // Values that are not round in binary: the restore must give back each bit.
        taf_sigma: 0.01 + f64::from(n) / 3.0e3,
        period_shift_s: Some(0.002),
        period_shift_sigma_s: f64::from(n) / 7.0e5,
    })
}

async fn settle(history: &History) {
    assert!(
        history
            .wait_settled(history.enqueued(), Duration::from_secs(10))
            .await,
        "the writer did not commit within 10 s"
    );
}

#[tokio::test]
async fn what_is_recorded_is_read_back_and_restored_at_the_next_start() {
    let scratch = scratch("history-roundtrip");
    let path = scratch.path().join("history.db");
    let history = History::new(Some(&config(&path)));
    let restored = millgate::history::start(&history, run_info());
    assert!(
        restored.drivelines.is_empty(),
        "a new file restores nothing"
    );
    let t0 = UtcTime::parse("2026-03-01T08:00:00Z").unwrap();
    let mut trend = 0.0;
    let mut last = None;
    for n in 1..=40u32 {
        let taf = 1.9 + f64::from(n % 5) * 0.2;
        trend += 0.1 * (taf / 1.8 - 1.0 - trend);
        let time = UtcTime::from_unix_ms(t0.unix_ms() + i64::from(n) * 60_000);
        let event = bite(n, time, taf, trend, n >= 10);
        if let HistoryEvent::Bite(record) = &event {
            last = Some(record.state.clone());
        }
        assert!(history.record(event));
    }
    let at = |minutes: i64| UtcTime::from_unix_ms(t0.unix_ms() + minutes * 60_000);
    history.record(HistoryEvent::Alarm(AlarmRecord {
        time: at(10),
        subject: "F1".into(),
        kind: AlarmKind::TafAlarm,
        event: AlarmEvent::Raised,
        origin: None,
        value: Some(2.7),
        threshold: Some(2.6),
    }));
    let hmi: std::net::SocketAddr = "10.0.0.7:50211".parse().unwrap();
    history.record(HistoryEvent::WearReset {
        time: at(41),
        driveline: "F1".into(),
        origin: CommandOrigin::Hmi(hmi),
    });
    // The state after the reset, as the board records it with the reset.
    history.record(HistoryEvent::State(StateRecord {
        time: at(41),
        subject: "F1".into(),
        results: SubjectResults::Driveline(Box::new(DrivelineResults {
            wear_trend: None,
            ..last.expect("40 bites")
        })),
    }));
    history.record(HistoryEvent::OutageStarted {
        time: at(42),
        source: "daq1".into(),
        status: "stale",
    });
    history.record(HistoryEvent::OutageWorse {
        source: "daq1".into(),
    });
    history.record(HistoryEvent::OutageEnded {
        time: at(43),
        source: "daq1".into(),
        blocks_missed: 17,
        ended_by: EndedBy::Recovered,
    });
    settle(&history).await;
    assert_eq!(history.stored(), 46);
    let status = history.status();
    assert_eq!(status.state, HistoryState::Ok);
    assert!(status.commits >= 1 && status.commits <= 45, "{status:?}");
    history.close();
    assert!(!history.record(bite(41, at(44), 2.0, 0.0, false)), "closed");

    let reader = HistoryReader::open(&path).unwrap();
    let bites = reader.bites(&Filter::default()).unwrap();
    assert_eq!(bites.len(), 40);
    assert_eq!(
        bites
            .iter()
            .map(|b| b.figures.bite_counter)
            .collect::<Vec<_>>(),
        (1..=40).collect::<Vec<_>>()
    );
    assert_eq!(bites[4].time(), "2026-03-01T08:05:00.000Z");
    assert_eq!(bites[4].figures.taf, Some(1.9));
    assert!(bites[6].figures.last_bite_degraded && !bites[5].figures.last_bite_degraded);
    let window = Filter {
        name: Some("F1".into()),
        since: Some(at(10)),
        until: Some(at(20)),
        limit: Some(5),
        ..Filter::default()
    };
    let page = reader.bites(&window).unwrap();
    assert_eq!(
        page.iter()
            .map(|b| b.figures.bite_counter)
            .collect::<Vec<_>>(),
        [10, 11, 12, 13, 14]
    );
    let next = reader
        .bites(&Filter {
            after_id: Some(page[4].id),
            ..window.clone()
        })
        .unwrap();
    assert_eq!(
        next[0].figures.bite_counter, 15,
        "paging by id goes on where it stopped"
    );
    let wear = reader.wear(&Filter::default()).unwrap();
    assert_eq!(wear.len(), 41, "one estimate per bite and the reset");
    let reset = wear.last().unwrap();
    assert_eq!(
        (
            reset.event.as_str(),
            reset.origin.as_str(),
            reset.peer.as_deref()
        ),
        ("reset", "hmi", Some("10.0.0.7:50211"))
    );
    let outages = reader.outages(&Filter::default()).unwrap();
    assert_eq!(outages.len(), 1);
    assert_eq!(
        (
            outages[0].worst_status.as_str(),
            outages[0].blocks_missed,
            outages[0].ended_by.as_deref()
        ),
        ("lost", 17, Some("recovered"))
    );
    let runs = reader.runs(&Filter::default()).unwrap();
    assert_eq!(runs.len(), 1);
    assert_eq!(runs[0].ended.as_deref(), Some("stopped"));

    // The second start: the state after the last event, marked restored.
    let history = History::new(Some(&config(&path)));
    let restored = millgate::history::start(&history, run_info());
    history.close();
    assert_eq!(restored.drivelines.len(), 1);
    let f1 = &restored.drivelines[0];
    assert_eq!(f1.results.bite_counter, 40);
    assert_eq!(f1.results.wear_trend, None, "the reset came last");
    assert!(f1.gap_bites.is_empty(), "the reset came last");
    assert_eq!(f1.gap_trend, None, "the reset came last");
    assert!(f1.results.taf_alarm, "the alarm stays latched");
    assert!(f1.results.restored);
    assert_eq!(f1.results.taf, bites[39].figures.taf);
    assert_eq!(f1.results.last_bite_unix_ms, Some(at(40).unix_ms()));
    // Every figure the catalogue keeps in the state row, the first period too.
    assert_eq!(f1.results.first_period_s, Some(0.05));
    assert_eq!(f1.results.beta2_hz, bites[39].figures.beta2_hz);
    // In the register map: the restored bit with valid values.
    let demo = millgate_sim::devices::demo::setup(1.0, 0.5, 1).unwrap();
    let mut config_f1 = demo.config;
    config_f1.drivelines[0].name = "F1".into();
    let map = RegisterMap::new(&config_f1);
    let mut results = Results::new(1, 1, 0);
    results.sources = vec![Some(millgate::field::source_health::SourceStatus::Ok)];
    // On the board as the analysis resumes it (`Analysis::resume_driveline`).
    results.drivelines[0] = f1.results.clone();
    let words = map.encode(&results);
    let flags = map
        .registers()
        .iter()
        .find(|r| r.name == "F1.flags")
        .unwrap();
    let flags = words[usize::from(flags.address)];
    assert_eq!(
        flags & (flag_mask(DRIVELINE, "restored") | flag_mask(DRIVELINE, "taf_alarm")),
        flag_mask(DRIVELINE, "restored") | flag_mask(DRIVELINE, "taf_alarm")
    );
    let runs = HistoryReader::open(&path)
        .unwrap()
        .runs(&Filter::default())
        .unwrap();
    assert_eq!(runs.len(), 2);
}

#[tokio::test]
async fn the_gap_trend_and_bites_since_the_last_reset_and_the_gap_alarm_are_restored() {
    let scratch = scratch("history-gap-pool");
    let path = scratch.path().join("history.db");
    let t0 = UtcTime::parse("2026-03-01T08:00:00Z").unwrap();
    let at = |minutes: i64| UtcTime::from_unix_ms(t0.unix_ms() + minutes * 60_000);
    let start = |history: &History| millgate::history::start(history, run_info());
    let history = History::new(Some(&config(&path)));
    start(&history);
    for n in 1..=16u32 {
        let mut event = bite(n, at(i64::from(n)), 2.0, 0.1, false);
        if let HistoryEvent::Bite(record) = &mut event {
            let gap = GapResults {
                gap_mrad: 1.5 + f64::from(n) * 0.1,
                low_mrad: 1.2,
                high_mrad: 2.9,
                coupling: (n > 2).then_some(1),
                likeliest_coupling: None,
                bites_pooled: n as usize,
                growth: None,
                forecast: None,
            };
            record.figures.gap = Some(gap);
            record.state.gap = Some(gap);
            record.gap_state = Some(WearState::Warning);
            record.state.gap_alarm = n >= 12;
            // The history keeps the trend's saved form as the analysis hands it over.
            record.gap_trend = Some(format!("{{\"trend after bite\": {n}}}"));
        }
        history.record(event);
        if n == 5 {
            history.record(HistoryEvent::WearReset {
                time: UtcTime::from_unix_ms(at(5).unix_ms() + 30_000),
                driveline: "F1".into(),
                origin: CommandOrigin::Local,
            });
        }
    }
    settle(&history).await;
    history.close();
    let bites = HistoryReader::open(&path)
        .unwrap()
        .bites(&Filter::default())
        .unwrap();
    assert_eq!(
        bites[0].figures.gap.and_then(|g| g.coupling),
        None,
        "undetermined"
    );
    assert_eq!(bites[4].figures.gap.and_then(|g| g.coupling), Some(1));
    assert_eq!(bites[4].figures.gap.map(|g| g.gap_mrad), Some(2.0));

    let history = History::new(Some(&config(&path)));
    let restored = start(&history);
    let f1 = &restored.drivelines[0];
    let expected: Vec<PooledBite> = (6..=16).filter_map(|n| pooled(n, 2.0)).collect();
    assert_eq!(expected.len(), 9, "bites 7 and 14 were degraded");
    let (times, kept): (Vec<i64>, Vec<PooledBite>) = f1.gap_bites.iter().copied().unzip();
    assert_eq!(kept, expected, "the bites after the reset, oldest first");
    let expected_times: Vec<i64> = (6..=16)
        .filter(|&n| pooled(n, 2.0).is_some())
        .map(|n| at(i64::from(n)).unix_ms())
        .collect();
    assert_eq!(times, expected_times, "with their times");
    assert_eq!(
        f1.gap_trend.as_deref(),
        Some("{\"trend after bite\": 16}"),
        "the last bite's saved trend"
    );
    assert!(f1.results.gap_alarm, "the gap alarm stays latched");
    // The last estimate is restored with the state (the pool estimates again once the
    // maps are ready).
    let gap = f1.results.gap.expect("the last estimate is restored");
    assert_eq!(
        (gap.gap_mrad, gap.low_mrad, gap.high_mrad),
        (1.5 + 16.0 * 0.1, 1.2, 2.9)
    );
    assert_eq!((gap.coupling, gap.bites_pooled), (Some(1), 16));
    history.record(HistoryEvent::Alarm(AlarmRecord {
        time: at(17),
        subject: "F1".into(),
        kind: AlarmKind::GapAlarm,
        event: AlarmEvent::Acknowledged,
        origin: Some(CommandOrigin::Local),
        value: None,
        threshold: None,
    }));
    // With the state after it, as the board records an acknowledgement.
    history.record(HistoryEvent::State(StateRecord {
        time: at(17),
        subject: "F1".into(),
        results: SubjectResults::Driveline(Box::new(DrivelineResults {
            gap_alarm: false,
            restored: false,
            ..f1.results.clone()
        })),
    }));
    settle(&history).await;
    history.close();
    let history = History::new(Some(&config(&path)));
    let restored = start(&history);
    history.close();
    assert!(!restored.drivelines[0].results.gap_alarm, "acknowledged");
    assert_eq!(restored.drivelines[0].gap_bites.len(), expected.len());
    assert!(restored.drivelines[0].gap_trend.is_some());
}

#[tokio::test]
async fn a_run_that_never_stopped_is_marked_unclean_and_its_open_outage_closed() {
    let scratch = scratch("history-unclean");
    let path = scratch.path().join("history.db");
    let first = History::new(Some(&config(&path)));
    millgate::history::start(&first, run_info());
    first.record(HistoryEvent::OutageStarted {
        time: UtcTime::now(),
        source: "daq1".into(),
        status: "lost",
    });
    settle(&first).await;
    // No close: as after a kill, the next start finds the run open.
    let second = History::new(Some(&config(&path)));
    millgate::history::start(&second, run_info());
    second.close();
    let reader = HistoryReader::open(&path).unwrap();
    let runs = reader.runs(&Filter::default()).unwrap();
    assert_eq!(runs[0].ended.as_deref(), Some("unclean"));
    assert_eq!(runs[0].stopped_at, None);
    assert_eq!(runs[1].ended.as_deref(), Some("stopped"));
    let outage = &reader.outages(&Filter::default()).unwrap()[0];
    assert_eq!(outage.ended_by.as_deref(), Some("restart"));
    first.close();
}

#[tokio::test]
async fn debian_sqlite3_and_python_read_the_file() {
    let scratch = scratch("history-tools");
    let path = scratch.path().join("history.db");
    let history = History::new(Some(&config(&path)));
    millgate::history::start(&history, run_info());
    let t0 = UtcTime::parse("2026-05-04T23:59:58.250Z").unwrap();
    for n in 1..=12u32 {
        let time = UtcTime::from_unix_ms(t0.unix_ms() + i64::from(n) * 750);
        history.record(bite(n, time, 2.0 + f64::from(n) / 100.0, 0.1, false));
    }
    settle(&history).await;
    // While the gateway runs (WAL, writer connected), as an operator would.
    let sqlite3 = Command::new("sqlite3")
        .arg("-readonly")
        .arg(&path)
        .arg(
            "SELECT count(*), sum(bite_counter), min(time), max(time), \
             strftime('%Y-%m-%d %H:%M:%f', max(time)), round(max(taf), 2) FROM bites",
        )
        .output()
        .expect("Debian's sqlite3 (scripts/test installs it)");
    assert!(sqlite3.status.success(), "{sqlite3:?}");
    let line = String::from_utf8_lossy(&sqlite3.stdout).trim().to_owned();
    assert_eq!(
        line,
        "12|78|2026-05-04T23:59:59.000Z|2026-05-05T00:00:07.250Z|2026-05-05 00:00:07.250|2.12"
    );
    let script = millgate_tests::kit::peers::peer("history_read.py");
    let python = Command::new("python3")
        .arg(&script)
        .arg(&path)
        .output()
        .expect("python3");
    assert!(
        python.status.success(),
        "{}",
        String::from_utf8_lossy(&python.stderr)
    );
    let read: serde_json::Value = serde_json::from_slice(&python.stdout).unwrap();
    // Python computes the span with datetime from the ISO text; the file's times are
    // 750 ms apart.
    assert_eq!(read["bites"], 12);
    assert_eq!(read["span_s"], 8.25);
    assert_eq!(read["ordered"], true);
    assert_eq!(read["user_version"], schema::current_version());
    assert_eq!(read["journal_mode"], "wal");
    history.close();
}

#[tokio::test]
async fn a_corrupt_file_is_reported_and_left_alone() {
    let scratch = scratch("history-corrupt");
    let path = scratch.path().join("history.db");
    let garbage: Vec<u8> = (0..8192u32).map(|i| (i * 7 + 3) as u8).collect();
    std::fs::write(&path, &garbage).unwrap();
    let history = History::new(Some(&config(&path)));
    let restored = millgate::history::start(&history, run_info());
    assert!(restored.drivelines.is_empty());
    let status = history.status();
    assert_eq!(status.state, HistoryState::Failing);
    let (_, error) = status.last_error.expect("an error");
    assert!(
        error.contains("history.db") && error.contains("not a readable SQLite history"),
        "{error}"
    );
    for n in 1..=3 {
        history.record(bite(n, UtcTime::now(), 2.0, 0.0, false));
    }
    // A failing history is not waited for (the PLC must go on), so wait for the count.
    let deadline = std::time::Instant::now() + Duration::from_secs(10);
    while history.status().dropped_error < 3 {
        assert!(
            std::time::Instant::now() < deadline,
            "{:?}",
            history.status()
        );
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    assert_eq!(history.stored(), 0);
    history.close();
    assert_eq!(
        std::fs::read(&path).unwrap(),
        garbage,
        "the file is left as it was"
    );
}

/// Rows of `bites` and `wear_estimates` made by SQL (fast), `count` of each, one a
/// minute from `start`.
fn fill(connection: &rusqlite::Connection, start: UtcTime, count: u32) {
    connection
        .execute(
            "INSERT INTO gateway_runs (started_at, version, config_name) VALUES (?1, 't', 't')",
            [start.to_string()],
        )
        .unwrap();
    connection
        .execute(
            "WITH RECURSIVE n(i) AS (SELECT 0 UNION ALL SELECT i + 1 FROM n WHERE i < ?2 - 1)
             INSERT INTO bites (run_id, driveline, time, bite_counter, channel,
                 static_torque_knm, peak_torque_knm, taf, quality, degraded)
             SELECT 1, 'F1', strftime('%Y-%m-%dT%H:%M:%fZ', ?1, '+' || i || ' minutes'), i,
                 'spindle_top', 100.0, 200.0, 2.0, 'good', 0 FROM n",
            rusqlite::params![start.to_string(), count],
        )
        .unwrap();
    connection
        .execute(
            "INSERT INTO wear_estimates (run_id, driveline, time, event, origin, wear_index)
             SELECT 1, driveline, time, 'bite', 'analysis', 0.1 FROM bites",
            [],
        )
        .unwrap();
}

#[test]
fn retention_deletes_by_age_and_size_in_chunks_and_the_file_shrinks() {
    let scratch = scratch("history-retention");
    let path = scratch.path().join("history.db");
    let connection = millgate::history::writer::connect(&path).unwrap();
    let now = UtcTime::parse("2026-06-01T00:00:00Z").unwrap();
    // 12 000 bites, one a minute: 8.3 days up to `now`.
    let start = now.minus(Duration::from_secs(12_000 * 60));
    fill(&connection, start, 12_000);
    let pages = |name: &str| -> i64 {
        connection
            .pragma_query_value(None, name, |row| row.get(0))
            .unwrap()
    };
    let full_bytes = pages("page_count") * pages("page_size");
    assert!(full_bytes > 2 << 20, "{full_bytes} bytes filled");

    // By age: keep 5 days.
    let age = Retention {
        max_age: Duration::from_secs(5 * 86_400),
        max_bytes: 1 << 40,
        chunk_rows: 1000,
        vacuum_pages: 64,
        captures: None,
    };
    let mut state = RetentionState::default();
    let mut steps = 0;
    let mut most_released = 0;
    loop {
        let step = age.step(&connection, now, &mut state).unwrap();
        steps += 1;
        most_released = most_released.max(step.released_pages);
        assert!(step.deleted <= 2 * 1000, "a chunk per table at most");
        if !step.more {
            break;
        }
        assert!(steps < 1000);
    }
    let cutoff = now.minus(age.max_age).to_string();
    let (old, kept): (i64, i64) = connection
        .query_row(
            "SELECT count(*) FILTER (WHERE time < ?1), count(*) FROM bites",
            [&cutoff],
            |row| Ok((row.get(0)?, row.get(1)?)),
        )
        .unwrap();
    assert_eq!(old, 0);
    assert_eq!(kept, 5 * 24 * 60);
    assert!(steps >= 5, "{steps} steps: deleted in chunks");
    // (A pointer-map page of the auto-vacuum file may go with them.)
    assert!(
        most_released >= u64::from(age.vacuum_pages),
        "a step releases vacuum_pages free pages, not one: at most {most_released}"
    );

    // By size: at most 1 MiB of data; the oldest go first and the file shrinks.
    let size = Retention {
        max_bytes: 1 << 20,
        ..age
    };
    let before = pages("page_count") * pages("page_size");
    loop {
        let step = size.step(&connection, now, &mut state).unwrap();
        if !step.more {
            assert!(step.data_bytes <= 1 << 20, "{step:?}");
            break;
        }
    }
    let after = pages("page_count") * pages("page_size");
    assert!(after <= 1 << 20, "file {after} bytes");
    assert!(after < before / 2, "{before} -> {after} bytes");
    assert_eq!(pages("freelist_count"), 0, "free pages handed back");
    let newest: String = connection
        .query_row("SELECT max(time) FROM bites", [], |row| row.get(0))
        .unwrap();
    assert_eq!(
        UtcTime::parse(&newest).unwrap(),
        UtcTime::from_unix_ms(start.unix_ms() + 11_999 * 60_000),
        "the newest bite is kept"
    );
}

/// A long run (its start past the age limit, most of its bites not) and a size limit
/// that deletes a chunk at a time: the run's row stays while any row refers to it,
/// every step succeeds, and the run goes with its last bite.
#[test]
fn retention_keeps_a_run_while_its_rows_remain() {
    let scratch = scratch("history-retention-runs");
    let path = scratch.path().join("history.db");
    let connection = millgate::history::writer::connect(&path).unwrap();
    let now = UtcTime::parse("2026-06-01T00:00:00Z").unwrap();
    let day = |d: u64| now.minus(Duration::from_secs(d * 86_400)).to_string();
    for (started, ended) in [(day(10), "stopped"), (day(2), "unclean")] {
        connection
            .execute(
                "INSERT INTO gateway_runs (started_at, ended, version, config_name)
                 VALUES (?1, ?2, 't', 't')",
                [started, ended.to_owned()],
            )
            .unwrap();
    }
    // Run 1: 3 000 bites a minute apart from 10 days ago (2.1 days); run 2: 100.
    connection
        .execute(
            "WITH RECURSIVE n(i) AS (SELECT 0 UNION ALL SELECT i + 1 FROM n WHERE i < 3099)
             INSERT INTO bites (run_id, driveline, time, bite_counter, channel,
                 static_torque_knm, peak_torque_knm, taf, quality, degraded)
             SELECT CASE WHEN i < 3000 THEN 1 ELSE 2 END, 'F1',
                 strftime('%Y-%m-%dT%H:%M:%fZ', CASE WHEN i < 3000 THEN ?1 ELSE ?2 END,
                     '+' || (i % 3000) || ' minutes'),
                 i, 'spindle_top', 100.0, 200.0, 2.0, 'good', 0 FROM n",
            [day(10), day(2)],
        )
        .unwrap();
    // Keep 9 days: run 1 started before the limit but most of its bites are younger.
    let age = Retention {
        max_age: Duration::from_secs(9 * 86_400),
        max_bytes: 1 << 40,
        chunk_rows: 500,
        vacuum_pages: 64,
        captures: None,
    };
    let mut state = RetentionState::default();
    let runs = |connection: &rusqlite::Connection| -> Vec<i64> {
        let mut statement = connection
            .prepare("SELECT id FROM gateway_runs ORDER BY id")
            .unwrap();
        let ids = statement.query_map([], |row| row.get(0)).unwrap();
        ids.map(Result::unwrap).collect()
    };
    loop {
        let step = age
            .step(&connection, now, &mut state)
            .unwrap_or_else(|error| panic!("a retention step failed: {error}"));
        if !step.more {
            break;
        }
    }
    assert_eq!(runs(&connection), [1, 2], "run 1 still has bites");
    // Then a size limit below the data: chunks go, run 1's row with its last bite.
    let size = Retention {
        max_bytes: 64 << 10,
        ..age
    };
    for _ in 0..100 {
        let step = size
            .step(&connection, now, &mut state)
            .unwrap_or_else(|error| panic!("a retention step failed: {error}"));
        let (first_run, left): (Option<i64>, i64) = connection
            .query_row("SELECT min(run_id), count(*) FROM bites", [], |row| {
                Ok((row.get(0)?, row.get(1)?))
            })
            .unwrap();
        let kept = runs(&connection);
        if let Some(run) = first_run {
            assert!(
                kept.contains(&run),
                "run {run} deleted while {left} bites remain"
            );
        }
        if !step.more {
            break;
        }
    }
    assert!(
        !runs(&connection).contains(&1),
        "run 1 deleted after its bites"
    );
}
