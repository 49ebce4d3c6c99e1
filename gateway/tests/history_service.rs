//! Acceptance of the event history against the real `millgate run` binary between the
//! demo's virtual DAQ and PLC:
//!
//! - killed with SIGKILL right after a bite reached the PLC and started again on the
//!   same file: every bite the PLC saw is in the file; the bite counter, the wear trend,
//!   the pooled gap estimate and the latched alarm continue; restored values carry the
//!   "restored" flag until the next bite;
//! - a full disk (a 4 MiB tmpfs filled while the service runs), a read-only folder (a
//!   read-only tmpfs) and a corrupt file: a clear error in the log and on `/metrics`,
//!   events counted as dropped, and the PLC writes go on; the full disk recovers once
//!   space is freed. The tmpfs are mounted in a private mount namespace
//!   (`unshare -rm`, util-linux) that only the service sees;
//! - a gap past the warning threshold: the PLC's flag, an alarm event in the file and
//!   on the Alarms page's API, the gap figures on `/metrics` as in the PLC;
//! - `/metrics`' latency histograms: bite -> PLC counts every bite the PLC was
//!   written (each committed to the history first), block wait every block taken up.

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

use common::{
    fill_file_system, free_port, http, promtool_passes, terminate, wait_for, web_ready, KillOnDrop,
    Setup, MILLGATE,
};

use millgate::analysis::wear::next_trend;
use millgate::history::query::{BiteRow, Filter, HistoryReader};
use millgate::outputs::modbus::register_map::flag_mask;
use millgate::state::catalogue::DRIVELINE;

fn bites(history: &Path) -> Vec<BiteRow> {
    HistoryReader::open(history)
        .unwrap()
        .bites(&Filter::default())
        .unwrap()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sigkill_loses_no_bite_the_plc_saw_and_the_restart_continues() {
    let setup = Setup::new(MILLGATE, "kill", "db").await;
    let history = setup.history.clone();
    let server_port = setup.server_port;
    let plc = setup.plc();

    // First run: killed the moment the PLC shows its 4th bite.
    let mut first = setup.spawn("first.log");
    wait_for("3 bites in the PLC", Duration::from_secs(40), || {
        plc.counter() >= 3
    })
    .await;
    let seen = plc.counter();
    wait_for("another bite in the PLC", Duration::from_secs(20), || {
        plc.counter() > seen
    })
    .await;
    first.kill().unwrap();
    first.wait().unwrap();
    let in_plc = plc.counter();
    let taf_in_plc = plc.taf();
    assert!(
        plc.flags() & flag_mask(DRIVELINE, "taf_alarm") != 0,
        "the alarm latched"
    );

    let stored = bites(&history);
    let counters: Vec<i64> = stored
        .iter()
        .map(|b| i64::from(b.figures.bite_counter))
        .collect();
    for counter in 1..=i64::from(in_plc) {
        assert!(
            counters.contains(&counter),
            "bite {counter} reached the PLC but is not in the file: {counters:?}"
        );
    }
    let last_seen = stored
        .iter()
        .find(|b| b.figures.bite_counter == in_plc)
        .unwrap();
    assert_eq!(
        last_seen.figures.taf.map(|taf| taf as f32),
        Some(taf_in_plc)
    );
    let before = stored.last().unwrap().clone();
    assert!(
        before.figures.wear_trend.is_some(),
        "the driveline model gives a trend"
    );

    // Second run on the same file: the state comes back before any new bite.
    let mut second = setup.spawn("second.log");
    // The PLC still holds the killed run's last write; the second run's first writes
    // are the ones with the restored flag.
    wait_for(
        "the second run writes the PLC",
        Duration::from_secs(20),
        || plc.flags() & flag_mask(DRIVELINE, "restored") != 0,
    )
    .await;
    assert_eq!(
        plc.counter(),
        before.figures.bite_counter as u32,
        "the counter restored"
    );
    assert!(
        plc.flags() & flag_mask(DRIVELINE, "taf_alarm") != 0,
        "the alarm still latched"
    );
    let restored = before.figures.bite_counter as u32;
    wait_for("a bite after the restart", Duration::from_secs(20), || {
        plc.counter() > restored
    })
    .await;
    assert_eq!(
        plc.flags() & flag_mask(DRIVELINE, "restored"),
        0,
        "a new bite clears it"
    );
    assert!(
        plc.flags() & flag_mask(DRIVELINE, "taf_alarm") != 0,
        "latched until acknowledged"
    );

    // The trend goes on from the restored value: the first bite of the second run
    // with a wear index (not degraded) moved it by one EWMA step.
    wait_for(
        "a bite of the second run with a wear index",
        Duration::from_secs(20),
        || {
            bites(&history).iter().any(|b| {
                b.figures.bite_counter > before.figures.bite_counter
                    && b.figures.wear_index.is_some()
                    && !b.figures.last_bite_degraded
            })
        },
    )
    .await;
    let after = bites(&history);
    assert!(after.iter().all(|b| b.run_id >= before.run_id));
    let resumed: Vec<&BiteRow> = after
        .iter()
        .filter(|b| b.figures.bite_counter > before.figures.bite_counter)
        .collect();
    assert_eq!(
        resumed[0].figures.bite_counter,
        before.figures.bite_counter + 1,
        "the counter continues"
    );
    // The gap pool continues: the first estimate of the second run pools the first
    // run's bites and its own (the demo's pool holds 5; a lost pool would give 1).
    let pooled_before = stored
        .iter()
        .rev()
        .find_map(|b| b.figures.gap.map(|g| g.bites_pooled))
        .expect("the first run estimated the gap");
    wait_for(
        "a gap estimate of the second run",
        Duration::from_secs(20),
        || {
            bites(&history).iter().any(|b| {
                b.figures.bite_counter > before.figures.bite_counter
                    && b.figures.gap.map(|g| g.bites_pooled).is_some()
            })
        },
    )
    .await;
    let after = bites(&history);
    let first_estimate = after
        .iter()
        .find(|b| {
            b.figures.bite_counter > before.figures.bite_counter
                && b.figures.gap.map(|g| g.bites_pooled).is_some()
        })
        .unwrap();
    assert_eq!(
        first_estimate.figures.gap.map(|g| g.bites_pooled),
        Some((pooled_before + 1).min(5)),
        "the pool survived the restart (first run's last estimate pooled {pooled_before})"
    );
    let mut trend = before.figures.wear_trend;
    for bite in resumed {
        let expected = match (bite.figures.wear_index, bite.figures.last_bite_degraded) {
            (Some(index), false) => Some(next_trend(trend, index)),
            _ => trend,
        };
        assert_eq!(
            bite.figures.wear_trend, expected,
            "bite {}",
            bite.figures.bite_counter
        );
        trend = expected;
    }

    // Acknowledged over the gateway's Modbus server from loopback: the PLC's host.
    {
        use tokio_modbus::client::Writer;
        let server = std::net::SocketAddr::from(([127, 0, 0, 1], server_port));
        let mut hmi = tokio_modbus::client::tcp::connect_slave(server, tokio_modbus::Slave(1))
            .await
            .unwrap();
        let command = plc.at("command.acknowledge_alarms") as u16;
        hmi.write_single_register(command, 1)
            .await
            .unwrap()
            .unwrap();
    }
    wait_for(
        "the acknowledgement in the file",
        Duration::from_secs(10),
        || {
            HistoryReader::open(&history)
                .unwrap()
                .alarms(&Filter::default())
                .unwrap()
                .iter()
                .any(|a| a.event == "acknowledged" && a.origin == "plc")
        },
    )
    .await;

    terminate(&mut second);
    let runs = HistoryReader::open(&history)
        .unwrap()
        .runs(&Filter::default())
        .unwrap();
    let ends: Vec<Option<&str>> = runs.iter().map(|r| r.ended.as_deref()).collect();
    assert_eq!(ends, [Some("unclean"), Some("stopped")]);
    let alarms = HistoryReader::open(&history)
        .unwrap()
        .alarms(&Filter::default())
        .unwrap();
    let raised = alarms
        .iter()
        .filter(|a| a.kind == "taf_alarm" && a.event == "raised")
        .count();
    assert_eq!(
        raised, 1,
        "latched across the restart, raised once: {alarms:#?}"
    );
    setup.stop(second).await;
}

/// The history's state gauge, its error-drop counter and its last error from `/metrics`.
async fn history_metrics(setup: &Setup) -> (f64, f64, String) {
    let page = setup.metrics().await;
    let state = setup.metric("millgate_history_state").await.unwrap();
    let dropped = setup
        .metric("millgate_history_events_dropped_total{reason=\"error\"}")
        .await
        .unwrap();
    let error = page
        .lines()
        .find_map(|line| line.strip_prefix("millgate_history_last_error_info{error=\""))
        .map(|rest| rest.split("\"} ").next().unwrap().to_owned())
        .unwrap_or_default();
    (state, dropped, error)
}

/// A service whose history cannot be opened: the PLC gets its bites, `/metrics` and
/// the log name the file and say why, the bites are counted as dropped.
async fn unusable_history_is_reported_and_the_plc_goes_on(
    setup: &Setup,
    mut service: KillOnDrop,
    why: &str,
) -> KillOnDrop {
    let plc = setup.plc();
    plc.bites_after_now(2).await;
    let (state, dropped, error) = history_metrics(setup).await;
    assert_eq!(state, 2.0, "failing");
    assert!(dropped >= 2.0, "the bites counted as dropped: {dropped}");
    assert!(error.contains(setup.history.to_str().unwrap()), "{error}");
    assert!(error.contains(why), "{error}");
    let log = std::fs::read_to_string(setup.log("run.log")).unwrap();
    assert!(
        log.contains("history not stored; the service goes on without it") && log.contains(why),
        "{log}"
    );
    assert!(service.try_wait().unwrap().is_none(), "the service runs on");
    terminate(&mut service);
    service
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_full_disk_is_reported_the_plc_goes_on_and_storing_resumes_when_space_is_freed() {
    let setup = Setup::new(MILLGATE, "full", "tmpfs").await;
    let service = setup.spawn_in_namespace("run.log", Some("size=4m"));
    let plc = setup.plc();
    plc.bites_after_now(1).await;
    // The service's view of its tmpfs (the test's own mount namespace has none).
    let folder = PathBuf::from(format!("/proc/{}/root", service.id()))
        .join(setup.history.parent().unwrap().strip_prefix("/").unwrap());
    let stored = setup.metric("millgate_history_events_stored_total").await;
    assert!(
        stored >= Some(1.0),
        "stored while there is space: {stored:?}"
    );
    assert!(
        !setup.history.exists(),
        "the file is on the service's tmpfs"
    );

    // Fill the tmpfs.
    let filler = folder.join("filler");
    fill_file_system(&filler);
    plc.bites_after_now(2).await;
    // Reported failing: a commit that needs the WAL to grow fails (its events are
    // dropped and counted), and a checkpoint that needs the database file to grow
    // fails. Commits that fit in the room the WAL has (it is reused after each
    // checkpoint) are still stored, so events need not be dropped yet.
    // The checkpoint runs within 0.5 s of the commit the PLC saw.
    // Once the WAL's room is used, a commit fails: wait for a dropped event too.
    let waited = std::time::Instant::now();
    let (state, dropped, error) = loop {
        let (state, dropped, error) = history_metrics(&setup).await;
        if (state == 2.0 && dropped >= 1.0) || waited.elapsed() > std::time::Duration::from_secs(40)
        {
            break (state, dropped, error);
        }
        tokio::time::sleep(std::time::Duration::from_millis(100)).await;
    };
    assert_eq!(state, 2.0, "failing");
    assert!(error.contains("the disk is full"), "{error}");
    assert!(dropped >= 1.0, "no commit failed in 40 s on a full disk");
    // The dropped bites' captures went with them, counted as such.
    let captures_dropped = setup
        .metric("millgate_history_captures_dropped_total")
        .await
        .unwrap();
    assert!(
        (1.0..=dropped).contains(&captures_dropped),
        "captures dropped {captures_dropped} of {dropped} events"
    );
    let log = std::fs::read_to_string(setup.log("run.log")).unwrap();
    assert!(log.contains("the disk is full"), "{log}");

    // Space again: the next bite is stored.
    std::fs::remove_file(&filler).unwrap();
    let stored_counter = plc.counter();
    let stored = setup
        .metric("millgate_history_events_stored_total")
        .await
        .unwrap();
    plc.bites_after_now(2).await;
    assert_eq!(setup.metric("millgate_history_state").await, Some(1.0));
    let now = setup
        .metric("millgate_history_events_stored_total")
        .await
        .unwrap();
    assert!(now > stored, "{stored} -> {now}");
    // Read by Debian's sqlite3 in the service's mount namespace (SQLite resolves the
    // /proc/PID/root link to the test's own view, where the file is not).
    let last = Command::new("nsenter")
        .args([
            "-t",
            &service.id().to_string(),
            "-m",
            "sqlite3",
            "-readonly",
        ])
        .arg(&setup.history)
        .arg("SELECT max(bite_counter) FROM bites")
        .output()
        .unwrap();
    assert!(last.status.success(), "{last:?}");
    let last: u32 = String::from_utf8(last.stdout)
        .unwrap()
        .trim()
        .parse()
        .unwrap();
    assert!(
        last >= stored_counter + 2,
        "the bites after the freed space are stored: {last}"
    );
    let log = std::fs::read_to_string(setup.log("run.log")).unwrap();
    assert!(log.contains("history stored again"), "{log}");
    setup.stop(service).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_read_only_folder_is_reported_and_the_plc_goes_on() {
    let setup = Setup::new(MILLGATE, "readonly", "ro").await;
    let service = setup.spawn_in_namespace("run.log", Some("ro,size=1m"));
    let service = unusable_history_is_reported_and_the_plc_goes_on(
        &setup,
        service,
        "cannot create or open the file",
    )
    .await;
    setup.stop(service).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_corrupt_file_is_reported_left_alone_and_the_plc_goes_on() {
    let setup = Setup::new(MILLGATE, "corrupt", "db").await;
    let garbage: Vec<u8> = (0..8192u32).map(|i| (i * 7 + 3) as u8).collect();
    std::fs::write(&setup.history, &garbage).unwrap();
    let service = setup.spawn("run.log");
    let service = unusable_history_is_reported_and_the_plc_goes_on(
        &setup,
        service,
        "not a readable SQLite history",
    )
    .await;
    assert_eq!(
        std::fs::read(&setup.history).unwrap(),
        garbage,
        "left as it was"
    );
    setup.stop(service).await;
}

/// A gap past the warning threshold is one truth in every output: the PLC's flag, an
/// alarm event in the history and on the Alarms page's API, and the gap figures on
/// `/metrics` equal to the PLC's registers, while `millgate run` runs.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_gap_warning_is_an_alarm_event_and_the_gap_is_on_metrics() {
    let setup = Setup::new(MILLGATE, "gap-warning", "db").await;
    let web_port = free_port();
    // The demo's gap opens from 1 mrad: a 0.5 mrad warning threshold is crossed by the
    // first estimate.
    let text = std::fs::read_to_string(&setup.config)
        .unwrap()
        .replace("gap_warning_mrad = 2.0", "gap_warning_mrad = 0.5");
    assert!(text.contains("gap_warning_mrad = 0.5"), "demo.toml changed");
    std::fs::write(&setup.config, text).unwrap();
    setup.append_config(&format!(
        "\n[outputs.web]\nbind = \"127.0.0.1:{web_port}\"\n"
    ));
    let plc = setup.plc();
    let mut service = setup.spawn("run.log");
    let warning = flag_mask(DRIVELINE, "gap_warning");
    wait_for(
        "the gap warning in the PLC",
        Duration::from_secs(60),
        || plc.flags() & warning != 0,
    )
    .await;

    // /metrics: the gap figures of the driveline, as the PLC has them. The PLC and the
    // page are read around the scrape; a bite between them is read again.
    let label = "{driveline=\"F1\"}";
    let (gap_in_plc, gap_on_metrics, pooled) = loop {
        let before = plc.counter();
        let gap = plc.f32_of("F1.gap_mrad");
        let page = setup.metrics().await;
        let value = |name: &str| -> Option<f64> {
            page.lines()
                .find_map(|line| line.strip_prefix(&format!("{name}{label} "))?.parse().ok())
        };
        let on_metrics = value("millgate_driveline_gap_mrad");
        let pooled = value("millgate_driveline_bites_pooled");
        for name in [
            "millgate_driveline_gap_low_mrad",
            "millgate_driveline_gap_high_mrad",
        ] {
            assert!(value(name).is_some(), "{name} missing: {page}");
        }
        assert_eq!(value("millgate_driveline_gap_warning"), Some(1.0), "{page}");
        if plc.counter() == before {
            break (gap, on_metrics, pooled);
        }
    };
    assert_eq!(
        gap_on_metrics.map(|gap| gap as f32),
        Some(gap_in_plc),
        "the same gap on /metrics as in the PLC"
    );
    assert!(pooled.is_some_and(|n| n >= 1.0), "bites pooled {pooled:?}");
    // The page follows Prometheus' conventions, as its own linter reads them.
    promtool_passes(&setup.metrics().await);

    // The Alarms page's API lists the warning, raised, with the gap that raised it.
    web_ready(web_port).await;
    let alarms = http(web_port, "GET", "/api/alarms?subject=F1").await.json();
    let raised = alarms
        .as_array()
        .unwrap()
        .iter()
        .find(|a| a["kind"] == "gap_warning" && a["event"] == "raised")
        .unwrap_or_else(|| panic!("no gap_warning raised on the Alarms page: {alarms}"));
    assert_eq!(raised["threshold"], 0.5, "{raised}");
    assert!(
        raised["value"].as_f64().is_some_and(|gap| gap >= 0.5),
        "{raised}"
    );

    terminate(&mut service);
    let stored = HistoryReader::open(&setup.history)
        .unwrap()
        .alarms(&Filter::default())
        .unwrap();
    let in_file: Vec<&str> = stored
        .iter()
        .filter(|a| a.kind == "gap_warning")
        .map(|a| a.event.as_str())
        .collect();
    assert_eq!(in_file.first(), Some(&"raised"), "{stored:#?}");
    setup.stop(service).await;
}

/// `/metrics`' latency histograms in a real run (the demo's virtual DAQ and PLC over
/// Modbus TCP, the history on): bite -> PLC counts every bite the PLC was written,
/// each histogram's buckets are the documented bounds, cumulative, up to `+Inf` equal
/// to `_count`, the block wait counts the blocks the analysis took up, and promtool
/// passes the page.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_bite_to_plc_latency_counts_every_bite_the_plc_was_written() {
    let setup = Setup::new(MILLGATE, "latency", "db").await;
    let plc = setup.plc();
    let service = setup.spawn("run.log");
    wait_for("3 bites in the PLC", Duration::from_secs(60), || {
        plc.counter() >= 3
    })
    .await;
    // The PLC holds a bite's counter a moment before the gateway has the answer to
    // the write that carried it: read the PLC around the scrape until the two agree
    // with no bite between them.
    let deadline = Instant::now() + Duration::from_secs(20);
    let page = loop {
        let before = plc.counter();
        let page = setup.metrics().await;
        let counted = histogram(&page, "millgate_bite_to_plc_seconds").count;
        if plc.counter() == before && counted == f64::from(before) {
            break page;
        }
        assert!(
            Instant::now() < deadline,
            "bite -> PLC counted {counted}, the PLC's counter {before}:\n{page}"
        );
        tokio::time::sleep(Duration::from_millis(20)).await;
    };
    for name in [
        "millgate_bite_to_plc_seconds",
        "millgate_block_wait_seconds",
    ] {
        let counts = histogram(&page, name);
        let bounds: Vec<&str> = counts.buckets.iter().map(|(le, _)| le.as_str()).collect();
        assert_eq!(
            bounds,
            [
                "0.0001", "0.0002", "0.0005", "0.001", "0.002", "0.005", "0.01", "0.02", "0.05",
                "0.1", "+Inf"
            ],
            "{name}"
        );
        assert!(
            counts.buckets.windows(2).all(|pair| pair[0].1 <= pair[1].1),
            "{name}: buckets not cumulative: {:?}",
            counts.buckets
        );
        assert_eq!(counts.buckets.last().unwrap().1, counts.count, "{name}");
        assert!(counts.count > 0.0 && counts.sum > 0.0, "{name}: {counts:?}");
    }
    promtool_passes(&page);
    setup.stop(service).await;
}

/// A histogram family's samples on a `/metrics` page.
#[derive(Debug)]
struct HistogramSamples {
    /// `(le, cumulative count)` in page order.
    buckets: Vec<(String, f64)>,
    count: f64,
    sum: f64,
}

/// The samples of the unlabelled histogram `name` on `page` (0 for a missing one).
fn histogram(page: &str, name: &str) -> HistogramSamples {
    let value = |rest: &str| rest.trim().parse::<f64>().unwrap_or(f64::NAN);
    let mut samples = HistogramSamples {
        buckets: Vec::new(),
        count: 0.0,
        sum: 0.0,
    };
    for line in page.lines() {
        let Some(rest) = line.strip_prefix(name) else {
            continue;
        };
        if let Some(bucket) = rest.strip_prefix("_bucket{le=\"") {
            let (le, count) = bucket.split_once("\"}").expect("a bucket line");
            samples.buckets.push((le.to_owned(), value(count)));
        } else if let Some(count) = rest.strip_prefix("_count ") {
            samples.count = value(count);
        } else if let Some(sum) = rest.strip_prefix("_sum ") {
            samples.sum = value(sum);
        }
    }
    samples
}
