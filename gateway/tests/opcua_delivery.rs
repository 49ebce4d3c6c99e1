//! The OPC UA server at scale (issue 42, item 5): 8 800 variables changing together,
//! a subscriber that is not ours (Python asyncua 2.1.0, `tests/peers/opcua_delivery.py`,
//! queue size 4) slower than the changes. Every change must arrive, or the value after
//! the ones the server dropped must carry the Overflow bit; no Publish response may
//! fail (a `Bad_ResponseTooLarge` lost every value in it, unmarked); and once the
//! values stop changing, the last one of every variable arrives.
//!
//! Needs `pip install asyncua==2.1.0` and the `opcua` feature: `cargo test -p millgate
//! --features opcua --test opcua_delivery`.

mod common;

#[path = "common/opcua_space.rs"]
mod opcua_space;

use std::io::Write;
use std::sync::Arc;
use std::time::{Duration, Instant};

use millgate::outputs::opcua::OpcUaServer;
use millgate_config::OpcUaOutput;
use serde_json::Value;
use tokio::sync::{mpsc, watch};

/// 400 drivelines of 22 figures: the size whose responses outgrew a message.
const OBJECTS: usize = 400;
const VARIABLES: usize = 22;
/// Changes, each of every variable; slower than the server's 100 ms sampling
/// interval, so only the queues, not the sampling, can drop a value.
const CHANGES: u64 = 20;
const CHANGE_PERIOD: Duration = Duration::from_millis(250);

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_change_arrives_or_is_marked_as_dropped() {
    let pki = common::scratch("opcua-delivery");
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let address = listener.local_addr().unwrap();
    let mut settings = OpcUaOutput::on(address, pki.path().to_path_buf());
    settings.max_monitored_items_per_subscription = OBJECTS * VARIABLES;
    let url = settings.endpoint_url();
    let (updates, updates_rx) = watch::channel(opcua_space::snapshot(OBJECTS, VARIABLES, 0));
    let (_events, events_rx) = mpsc::channel(1);
    let (_grown, grown_rx) = mpsc::channel(1);
    let (stop, shutdown) = millgate::shutdown::channel();
    let server = OpcUaServer::new(
        settings,
        opcua_space::spec(OBJECTS, VARIABLES),
        Arc::new(|_| {}),
    )
    .unwrap();
    let served = tokio::spawn(server.run(listener, updates_rx, events_rx, grown_rx, shutdown));
    opcua_space::serving(address, &url).await;

    let (_child, mut stdin, lines) = common::json_peer(
        &common::peer("opcua_delivery.py"),
        &[&url, &OBJECTS.to_string(), &VARIABLES.to_string(), "4"],
    );
    let ready = lines
        .recv_timeout(Duration::from_secs(120))
        .expect("the subscriber is ready");
    assert_eq!(ready["ready"], true, "{ready}");

    for change in 1..=CHANGES {
        updates.send_replace(opcua_space::snapshot(OBJECTS, VARIABLES, change));
        tokio::time::sleep(CHANGE_PERIOD).await;
    }
    // The values stand still now: every variable's last one must come.
    let deadline = Instant::now() + Duration::from_secs(60);
    let report = loop {
        writeln!(stdin, "report").unwrap();
        let report: Value = lines
            .recv_timeout(Duration::from_secs(30))
            .expect("the subscriber reports");
        if report["least_latest"].as_f64() == Some(CHANGES as f64) || Instant::now() > deadline {
            break report;
        }
        tokio::time::sleep(Duration::from_millis(500)).await;
    };
    let _ = writeln!(stdin, "quit");
    stop.trigger();
    let _ = served.await;

    eprintln!("{report}");
    assert_eq!(
        report["faults"], 0,
        "no Publish response may fail: {report}"
    );
    assert_eq!(
        report["unmarked_gaps"], 0,
        "a dropped value is marked by the Overflow bit on the next: {report}"
    );
    assert_eq!(
        report["least_latest"].as_f64(),
        Some(CHANGES as f64),
        "every variable's last value arrives: {report}"
    );
    assert!(
        report["changes"].as_u64().unwrap() >= (OBJECTS * VARIABLES) as u64,
        "{report}"
    );
}
