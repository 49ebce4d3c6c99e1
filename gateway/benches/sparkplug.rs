//! The Sparkplug B edge node into Debian's mosquitto on a loopback port, received by a
//! subscriber (rumqttc, decoding each DDATA with millgate's payload types; the
//! independent pysparkplug host is in the tests). The node runs in-process against a
//! history file in the system's temporary folder: bites go from the file, each as its
//! own DDATA at QoS 1 (see `outputs::sparkplug::forward`).
//!
//! 1. **Live**: the node is up with nothing pending; 20 000 bites are written into the
//!    file in one transaction (as the history writer commits a group); prints bite
//!    DDATAs per second from the commit until the subscriber has all.
//! 2. **Replay, unpaced**: a 100 000-bite backlog in the file, `replay_batch` 100000
//!    per `replay_period_ms` 1; prints bites per second from the node's start until
//!    the subscriber has all.
//! 3. **Replay, defaults** (100 per 100 ms): the same backlog; the pacing bounds it at
//!    1000 bites/s, so about 100 s.
//!
//! Each run checks that every bite id arrived, flagged historical or not as expected.
//!
//! Run with:
//!
//!     cargo bench -p millgate --bench sparkplug

use std::collections::HashSet;
use std::path::Path;
use std::time::{Duration, Instant};

use millgate::outputs::sparkplug::payload::{MetricValue, Payload};
use millgate_tests::kit::broker::Broker;
use millgate_tests::kit::scratch;
use millgate_tests::kit::sparkplug as backlog;
use prost::Message as _;
use rumqttc::{AsyncClient, Event, MqttOptions, Packet, QoS};

const LIVE_BITES: u32 = 20_000;
const BACKLOG_BITES: u32 = 100_000;

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

/// A subscriber to F1's DDATA: the bite ids it got and how many were flagged
/// historical, once it has `count` bites (or after `limit`).
struct Subscriber {
    client: AsyncClient,
    events: rumqttc::EventLoop,
}

impl Subscriber {
    async fn start(port: u16) -> Self {
        let mut options = MqttOptions::new("bench-host", "127.0.0.1", port);
        options.set_keep_alive(Duration::from_secs(30));
        options.set_max_packet_size(1 << 20, 1 << 20);
        let (client, mut events) = AsyncClient::new(options, 64);
        client
            .subscribe("spBv1.0/plant/DDATA/f1/F1", QoS::AtMostOnce)
            .await
            .unwrap();
        loop {
            if let Event::Incoming(Packet::SubAck(_)) = events.poll().await.unwrap() {
                break;
            }
        }
        Self { client, events }
    }

    async fn receive(&mut self, count: usize, limit: Duration) -> (HashSet<u64>, usize) {
        let mut ids = HashSet::new();
        let mut historical = 0;
        let start = Instant::now();
        while ids.len() < count && start.elapsed() < limit {
            let event = tokio::time::timeout(Duration::from_secs(5), self.events.poll()).await;
            let Ok(Ok(Event::Incoming(Packet::Publish(message)))) = event else {
                continue;
            };
            let payload = Payload::decode(message.payload.as_ref()).unwrap();
            // The bite id is a bite DDATA's last metric.
            if let Some(MetricValue::LongValue(id)) =
                payload.metrics.last().and_then(|m| m.value.clone())
            {
                ids.insert(id);
                historical += usize::from(
                    payload
                        .metrics
                        .iter()
                        .all(|m| m.is_historical == Some(true)),
                );
            }
        }
        (ids, historical)
    }
}

/// Append `count` bites after the file's last (bite counters go on) in one
/// transaction.
fn append_bites(path: &Path, count: u32) {
    let connection = millgate::history::writer::connect(path).unwrap();
    connection
        .execute(
            "WITH RECURSIVE n(i) AS (SELECT 1 UNION ALL SELECT i + 1 FROM n WHERE i < ?1),
                  last(c) AS (SELECT coalesce(max(bite_counter), 0) FROM bites)
             INSERT INTO bites (run_id, driveline, time, bite_counter, channel,
                 static_torque_knm, peak_torque_knm, taf, quality, degraded)
             SELECT 1, 'F1', strftime('%Y-%m-%dT%H:%M:%fZ', 'now'), last.c + i,
                 'spindle_top', 420.0, 546.0, 1.3, 'good', 0
             FROM n, last",
            [count],
        )
        .unwrap();
}

fn check(ids: &HashSet<u64>, first: u64, count: u32, historical: usize, want_historical: bool) {
    let missing = (first..first + u64::from(count))
        .filter(|id| !ids.contains(id))
        .count();
    let flagged = if want_historical {
        historical
    } else {
        ids.len() - historical
    };
    println!(
        "  received {} of {count} bites ({missing} missing), {flagged} flagged as expected",
        ids.len()
    );
}

async fn live(port: u16) {
    let folder = scratch("bench-sparkplug-live");
    let history = folder.path().join("history.db");
    backlog::write_backlog(&history, "plant", 1);
    let config = backlog::node_config(port, "plant", &history, "");
    let mut subscriber = Subscriber::start(port).await;
    let (stop, status, task) = backlog::start_node(&config);
    // The one backlog bite: the node is born and has replayed it.
    let (ids, _) = subscriber.receive(1, Duration::from_secs(20)).await;
    assert_eq!(ids.len(), 1, "the node did not come up");
    let start = Instant::now();
    append_bites(&history, LIVE_BITES);
    let (ids, historical) = subscriber
        .receive(LIVE_BITES as usize, Duration::from_secs(120))
        .await;
    let elapsed = start.elapsed().as_secs_f64();
    println!(
        "live: {LIVE_BITES} bites committed at once -> subscriber in {elapsed:.2} s: {:.0} bite DDATAs/s",
        f64::from(LIVE_BITES) / elapsed
    );
    check(&ids, 2, LIVE_BITES, historical, false);
    let _ = status;
    stop.trigger();
    task.await.unwrap();
    let _ = subscriber.client.disconnect().await;
}

/// The replay of a backlog with `pacing` (config keys; empty: the defaults).
async fn replay(port: u16, name: &str, pacing: &str) {
    let folder = scratch(&format!("bench-sparkplug-{}", name));
    let history = folder.path().join("history.db");
    let written = Instant::now();
    backlog::write_backlog(&history, "plant", BACKLOG_BITES);
    println!(
        "replay ({name}): {BACKLOG_BITES} bites written into the file in {:.2} s",
        written.elapsed().as_secs_f64()
    );
    let config = backlog::node_config(port, "plant", &history, pacing);
    let mut subscriber = Subscriber::start(port).await;
    let start = Instant::now();
    let (stop, status, task) = backlog::start_node(&config);
    let (ids, historical) = subscriber
        .receive(BACKLOG_BITES as usize, Duration::from_secs(300))
        .await;
    let elapsed = start.elapsed().as_secs_f64();
    println!(
        "replay ({name}: {}): {BACKLOG_BITES} bites -> subscriber in {elapsed:.2} s: {:.0} bites/s",
        if pacing.is_empty() {
            "100 per 100 ms"
        } else {
            "replay_batch 100000 per 1 ms"
        },
        f64::from(BACKLOG_BITES) / elapsed
    );
    check(&ids, 1, BACKLOG_BITES, historical, true);
    let settled = Instant::now();
    while status.counts().backlog > 0 && settled.elapsed() < Duration::from_secs(10) {
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    println!(
        "  backlog on /metrics afterwards: {}",
        status.counts().backlog
    );
    stop.trigger();
    task.await.unwrap();
    let _ = subscriber.client.disconnect().await;
}

fn main() {
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap();
    let folder = scratch("bench-sparkplug-broker");
    let port = free_port();
    let _broker = Broker::start(folder.path(), port);
    runtime.block_on(async {
        live(port).await;
        replay(
            port,
            "unpaced",
            "replay_batch = 100000\nreplay_period_ms = 1",
        )
        .await;
        replay(port, "defaults", "").await;
    });
}
