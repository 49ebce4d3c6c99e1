//! The maintenance page under attack, against the real `millgate run` (between the
//! demo's virtual DAQ and PLC) over real HTTP on loopback (issue 30, findings 1, 8
//! and the page's part of 11):
//!
//! - heavy history queries whose clients close at once, against a history of
//!   300 000 bites: the gateway's threads stay within the query slots, a request
//!   past the slots gets 503 with `Retry-After`, the page answers again once the
//!   attack ends, and SIGTERM during the attack stops the service with the stop
//!   recorded;
//! - live-update streams past `max_event_streams` are refused, and clients holding
//!   slow-header connections from another address do not lock a page's client out;
//! - a `Host` header naming another host is refused (DNS rebinding), a driveline
//!   name that is not UTF-8 gets the API's JSON error.

mod common;

use std::net::SocketAddr;
use std::path::Path;
use std::time::{Duration, Instant};

use common::{
    connect, free_port, http, http_raw, terminate, web_ready, FromSource, Setup, MILLGATE,
};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

/// Bites in the history fixture: a year at one every 100 s.
const FIXTURE_BITES: u32 = 300_000;
/// `outputs.web.history_queries` of these tests.
const SLOTS: usize = 2;
/// Hang guard for what the service does at once.
const LIVE: Duration = Duration::from_secs(15);

/// A history of [`FIXTURE_BITES`] bites of F1 (schema by the gateway's own
/// `connect`, rows by SQLite), its counter at the last one.
fn year_of_bites(path: &Path) {
    let connection = millgate::history::writer::connect(path).unwrap();
    connection
        .execute_batch(&format!(
            "BEGIN;
             INSERT INTO gateway_runs (started_at, stopped_at, ended, version, config_name)
                 VALUES ('2025-01-01T00:00:00.000Z', '2025-12-31T00:00:00.000Z', 'stopped',
                     'fixture', 'fixture');
             WITH RECURSIVE n(i) AS (SELECT 1 UNION ALL SELECT i + 1 FROM n WHERE i < {FIXTURE_BITES})
             INSERT INTO bites (run_id, driveline, time, bite_counter, channel,
                 static_torque_knm, peak_torque_knm, taf, period_shift_s, quality, degraded,
                 gap_mrad, gap_low_mrad, gap_high_mrad)
             SELECT 1, 'F1', strftime('%Y-%m-%dT%H:%M:%f', 1735689600 + i * 100, 'unixepoch') || 'Z',
                 i, 'torque', 100.0, 180.0 + (i % 7), 1.5 + (i % 100) / 1000.0, 0.001, 'good', 0,
                 5.0 + (i % 13) / 10.0, 4.0, 6.0
             FROM n;
             INSERT INTO driveline_state (driveline, updated_at, bite_counter, last_bite_time,
                     degraded, warning, alarm_latched)
                 SELECT 'F1', max(time), {FIXTURE_BITES}, max(time), 0, 0, 0 FROM bites;
             COMMIT;"
        ))
        .unwrap();
}

/// A figure of the service's `/proc/PID/status` (`Threads:`, `VmRSS:` in kB).
fn status(pid: u32, field: &str) -> usize {
    std::fs::read_to_string(format!("/proc/{pid}/status"))
        .unwrap()
        .lines()
        .find_map(|line| line.strip_prefix(field))
        .unwrap()
        .trim()
        .trim_end_matches(" kB")
        .parse()
        .unwrap()
}

fn threads(pid: u32) -> usize {
    status(pid, "Threads:")
}

/// Blocks the acquisition missed so far (every channel's, from `/metrics`).
async fn blocks_missed(setup: &Setup) -> f64 {
    setup
        .metrics()
        .await
        .lines()
        .filter(|line| line.contains("blocks_missed") && !line.starts_with('#'))
        .filter_map(|line| line.rsplit_once(' ')?.1.parse::<f64>().ok())
        .sum()
}

/// `clients` tasks sending heavy history requests and closing at once, until
/// `stop` is set; returns the requests sent.
fn attack(
    port: u16,
    clients: usize,
    stop: std::sync::Arc<std::sync::atomic::AtomicBool>,
) -> tokio::task::JoinSet<u32> {
    let mut tasks = tokio::task::JoinSet::new();
    for client in 0..clients {
        let stop = std::sync::Arc::clone(&stop);
        tasks.spawn(async move {
            let paths = [
                "/api/drivelines/F1/wear?points=10000",
                "/api/drivelines/F1/bites?limit=10000",
            ];
            let mut sent = 0u32;
            while !stop.load(std::sync::atomic::Ordering::Relaxed) {
                let path = paths[(client + sent as usize) % 2];
                if let Ok(mut stream) = TcpStream::connect(("127.0.0.1", port)).await {
                    let request = format!("GET {path} HTTP/1.1\r\nhost: localhost\r\n\r\n");
                    if stream.write_all(request.as_bytes()).await.is_ok() {
                        sent += 1;
                    }
                    // Let the request reach the handler, then go.
                    tokio::time::sleep(Duration::from_millis(5)).await;
                }
            }
            sent
        });
    }
    tasks
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn abandoned_history_queries_are_bounded_in_work_and_sigterm_stops_during_them() {
    let setup = Setup::new(MILLGATE, "web-work", "db").await;
    year_of_bites(&setup.history);
    let port = free_port();
    setup.append_config(&format!(
        "\n[outputs.web]\nbind = \"127.0.0.1:{port}\"\nhistory_queries = {SLOTS}\n\
         request_timeout_ms = 3000\n"
    ));
    let mut service = setup.spawn("run.log");
    web_ready(port).await;
    setup.plc().bites_after_now(1).await;
    let pid = service.id();
    let mut baseline = 0;
    for _ in 0..50 {
        baseline = baseline.max(threads(pid));
        tokio::time::sleep(Duration::from_millis(20)).await;
    }

    let missed_before = blocks_missed(&setup).await;
    let rss_before = status(pid, "VmRSS:");
    let mut rss_most = rss_before;
    // Six clients, each sending heavy queries and leaving, for 4 s.
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let mut clients = attack(port, 6, std::sync::Arc::clone(&stop));
    let start = Instant::now();
    let mut most = 0;
    let mut answers = Vec::new();
    while start.elapsed() < Duration::from_secs(4) {
        most = most.max(threads(pid));
        rss_most = rss_most.max(status(pid, "VmRSS:"));
        if answers.len() < 3 {
            // A client that waits for its answer: 200, or 503 with Retry-After. From
            // an address of its own, as a client on another machine: the page evicts
            // an idle connection of the address holding the most, and on 127.0.0.1 that
            // would be this one's while it is still sending its request (CI: "connection
            // reset").
            answers.push(
                http(
                    from([127, 0, 0, 2], port),
                    "GET",
                    "/api/drivelines/F1/wear?points=10000",
                )
                .await,
            );
        }
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    stop.store(true, std::sync::atomic::Ordering::Relaxed);
    let mut sent = 0;
    while let Some(client) = clients.join_next().await {
        sent += client.unwrap();
    }
    let missed = blocks_missed(&setup).await - missed_before;
    let statuses: Vec<u16> = answers.iter().map(|answer| answer.status).collect();
    eprintln!(
        "{sent} abandoned requests; threads {baseline} before, at most {most} during; \
         RSS {rss_before} kB before, at most {rss_most} kB; blocks missed meanwhile {missed}; \
         waiting clients' answers {statuses:?}"
    );
    assert!(sent >= 100, "the attack sent {sent} requests");
    assert!(
        most <= baseline + SLOTS + 2,
        "threads: {baseline} before, {most} during the attack (slots: {SLOTS})"
    );
    for answer in &answers {
        match answer.status {
            200 => assert!(answer.json().as_array().is_some_and(|a| !a.is_empty())),
            503 => {
                assert_eq!(answer.header("retry-after"), Some("2"));
                assert!(answer.json()["error"].is_string());
            }
            other => panic!("{other}: {}", answer.body),
        }
    }
    // The slots free once the attack ends.
    let start = Instant::now();
    loop {
        let answer = http(
            from([127, 0, 0, 2], port),
            "GET",
            "/api/drivelines/F1/bites?limit=5",
        )
        .await;
        if answer.status == 200 {
            assert_eq!(answer.json().as_array().unwrap().len(), 5);
            break;
        }
        assert!(start.elapsed() < LIVE, "no slot freed: {}", answer.body);
        tokio::time::sleep(Duration::from_millis(50)).await;
    }

    // SIGTERM during an attack: the service stops, and records the stop.
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let mut clients = attack(port, 6, std::sync::Arc::clone(&stop));
    tokio::time::sleep(Duration::from_secs(1)).await;
    let stopping = Instant::now();
    let waited = tokio::task::spawn_blocking(move || {
        terminate(&mut service);
        service
    });
    let service = tokio::time::timeout(Duration::from_secs(15), waited)
        .await
        .expect("stopped within TimeoutStopSec (15 s)")
        .unwrap();
    eprintln!(
        "SIGTERM during the attack: stopped in {:?}",
        stopping.elapsed()
    );
    stop.store(true, std::sync::atomic::Ordering::Relaxed);
    while clients.join_next().await.is_some() {}
    let ended = rusqlite::Connection::open(&setup.history)
        .unwrap()
        .query_row(
            "SELECT ended FROM gateway_runs ORDER BY id DESC LIMIT 1",
            [],
            |row| row.get::<_, Option<String>>(0),
        )
        .unwrap();
    assert_eq!(ended.as_deref(), Some("stopped"));
    drop(service);
    setup.finish().await;
}

/// `port` on 127.0.0.1 reached from another loopback address, `local`: a client the
/// page tells apart from the others (on 127.0.0.1).
fn from(local: [u8; 4], port: u16) -> FromSource {
    FromSource {
        source: local.into(),
        to: SocketAddr::from(([127, 0, 0, 1], port)),
    }
}

/// A connection from `local` (another loopback address) to the page.
async fn connect_from(local: [u8; 4], port: u16) -> TcpStream {
    connect(&from(local, port)).await.unwrap()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn streams_are_limited_slow_headers_do_not_lock_clients_out_and_hosts_are_checked() {
    let setup = Setup::new(MILLGATE, "web-held", "db").await;
    let port = free_port();
    setup.append_config(&format!(
        "\n[outputs.web]\nbind = \"127.0.0.1:{port}\"\nmax_connections = 8\n\
         max_event_streams = 3\nheader_timeout_ms = 60000\n\
         allowed_hosts = [\"mill-gw.plant.example\"]\n"
    ));
    let service = setup.spawn("run.log");
    web_ready(port).await;

    // Three streams are taken; a fourth is refused.
    let mut streams = Vec::new();
    for _ in 0..3 {
        let mut stream = TcpStream::connect(("127.0.0.1", port)).await.unwrap();
        stream
            .write_all(b"GET /api/events HTTP/1.1\r\nhost: localhost\r\n\r\n")
            .await
            .unwrap();
        let mut seen = Vec::new();
        while !String::from_utf8_lossy(&seen).contains("event: results") {
            let mut buffer = [0u8; 4096];
            let read = tokio::time::timeout(LIVE, stream.read(&mut buffer))
                .await
                .expect("the first event")
                .unwrap();
            assert!(read > 0);
            seen.extend_from_slice(&buffer[..read]);
        }
        assert!(seen.starts_with(b"HTTP/1.1 200"));
        streams.push(stream);
    }
    let refused = http(port, "GET", "/api/events").await;
    assert_eq!(refused.status, 503, "{}", refused.body);
    assert_eq!(refused.header("retry-after"), Some("2"));

    // Forty slow-header connections from 127.0.0.2, each sending half a head and
    // holding it (the header timeout is a minute).
    let mut slow = Vec::new();
    for _ in 0..40 {
        let mut stream = connect_from([127, 0, 0, 2], port).await;
        let _ = stream.write_all(b"GET / HTTP/1.1\r\nhost: loc").await;
        slow.push(stream);
    }
    // Let the burst of connections settle (the kernel accepted them before the
    // service did), then: a page's client from 127.0.0.1 is served, every time.
    tokio::time::sleep(Duration::from_millis(500)).await;
    for _ in 0..10 {
        let answer = http(port, "GET", "/api/overview").await;
        assert_eq!(answer.status, 200, "{}", answer.body);
    }
    // The live streams were not the ones evicted: each still gets the next update
    // (a change, or the keep-alive comment every 15 s).
    for stream in &mut streams {
        let mut buffer = [0u8; 4096];
        let read = tokio::time::timeout(Duration::from_secs(20), stream.read(&mut buffer))
            .await
            .expect("the stream still sends")
            .unwrap();
        assert!(read > 0, "the stream was closed");
    }
    drop(slow);

    // The Host header: addresses, localhost and the allowed names only.
    let with_host = |host: &str| {
        format!("GET /api/overview HTTP/1.1\r\nhost: {host}\r\nconnection: close\r\n\r\n")
    };
    for host in [
        "localhost".to_owned(),
        format!("127.0.0.1:{port}"),
        format!("[::1]:{port}"),
        format!("mill-gw.plant.example:{port}"),
    ] {
        let answer = http_raw(port, with_host(&host).as_bytes()).await;
        assert_eq!(answer.status, 200, "{host}: {}", answer.body);
    }
    for host in [
        "evil.example",
        "evil.example:8080",
        "127.0.0.1.evil.example",
    ] {
        let answer = http_raw(port, with_host(host).as_bytes()).await;
        assert_eq!(answer.status, 421, "{host}: {}", answer.body);
        assert!(
            answer.json()["error"].as_str().unwrap().contains(host),
            "{host}: {}",
            answer.body
        );
    }
    // A name that is not UTF-8: the API's JSON error.
    let answer = http(port, "GET", "/api/drivelines/%ff%fe").await;
    assert_eq!(answer.status, 400, "{}", answer.body);
    assert_eq!(answer.header("content-type"), Some("application/json"));
    assert!(answer.json()["error"].is_string());
    drop(service);
    setup.finish().await;
}
