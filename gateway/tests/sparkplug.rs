//! The Sparkplug B edge node against a real broker and a host that is not ours:
//! Debian's `mosquitto` on a loopback port with a generated configuration, and
//! `sparkplug_host.py` (paho-mqtt 1.6.1 with the Tahu protobuf schema that pysparkplug
//! 0.6.1 ships) subscribed to the group. `millgate run` sits between the demo's virtual
//! DAQ and PLC with `[outputs.mqtt]`. Checked: birth order and seq, bdSeq in NBIRTH
//! and in the Will, aliases, units, one DDATA per bite with its id and the PLC's
//! values, the rebirth command, the Will at SIGKILL and the next session's bdSeq;
//! store-and-forward: after a broker outage, a primary host outage and a gateway
//! killed during one, every bite arrives once live or flagged historical, the
//! historical ones first; the replay's pacing. A server set (`brokers`): the node
//! moves on when its server is killed mid-stream (two independent mosquittos; a
//! three-node aedes cluster on redis and a three-node RabbitMQ cluster, the host
//! application on another node) or when the primary host is offline on its server,
//! and no bite is lost.
//!
//! Needs `apt install mosquitto rabbitmq-server redis-server`, `pip install
//! pysparkplug==0.6.1` (with paho-mqtt 1.6.1) and `npm ci --prefix tests/peers`
//! (aedes) (scripts/test installs them).

mod common;

use std::collections::{HashMap, HashSet};
use std::io::Write;
use std::path::Path;
use std::process::{ChildStdin, Command, Stdio};
use std::sync::mpsc::{Receiver, RecvTimeoutError};
use std::time::{Duration, Instant};

use common::broker::Broker;
use common::sparkplug as backlog;
use common::{free_port, hang_up, terminate, KillOnDrop, Setup, MILLGATE};
use millgate::history::query::{CaptureRow, Filter, HistoryReader};
use serde_json::Value;

/// The Python host: its messages as JSON, its stdin for commands.
struct Host {
    _child: common::KillOnDrop,
    stdin: ChildStdin,
    lines: Receiver<Value>,
    seen: Vec<Value>,
}

impl Host {
    fn start(port: u16, group: &str) -> Self {
        Self::with_options(port, group, &[])
    }

    /// The host with more `options` of sparkplug_host.py (TLS, user name).
    fn with_options(port: u16, group: &str, options: &[&str]) -> Self {
        let port = port.to_string();
        let args = [&["127.0.0.1", port.as_str(), group], options].concat();
        let (child, stdin, lines) = common::json_peer(&common::peer("sparkplug_host.py"), &args);
        let mut host = Self {
            _child: child,
            stdin,
            lines,
            seen: Vec::new(),
        };
        let ready = host.next(Duration::from_secs(20));
        assert_eq!(ready["ready"], true, "{ready}");
        host.seen.clear();
        host
    }

    fn next(&mut self, limit: Duration) -> Value {
        match self.lines.recv_timeout(limit) {
            Ok(value) => {
                self.seen.push(value.clone());
                value
            }
            Err(RecvTimeoutError::Timeout) => panic!("no message from the host within {limit:?}"),
            Err(RecvTimeoutError::Disconnected) => panic!("the host script ended"),
        }
    }

    /// The next message of `kind` (NBIRTH, DDATA, ...), the others kept in `seen`.
    fn next_of(&mut self, kind: &str, limit: Duration) -> Value {
        let start = Instant::now();
        loop {
            let left = limit.saturating_sub(start.elapsed());
            let message = self.next(left.max(Duration::from_millis(1)));
            if message["type"] == kind {
                return message;
            }
        }
    }

    fn command(&mut self, line: &str) {
        writeln!(self.stdin, "{line}").unwrap();
        self.stdin.flush().unwrap();
    }
}

fn metric<'a>(message: &'a Value, name: &str) -> &'a Value {
    message["metrics"]
        .as_array()
        .unwrap()
        .iter()
        .find(|m| m["name"] == name)
        .unwrap_or_else(|| panic!("no metric {name} in {message}"))
}

/// The bite DDATAs of driveline F1 among `seen`, as (bite id, flagged historical), in
/// arrival order, one list per session (each NBIRTH starts one).
fn bites_by_session(seen: &[Value], bite_alias: u64) -> Vec<Vec<(u64, bool)>> {
    let mut sessions: Vec<Vec<(u64, bool)>> = Vec::new();
    for message in seen {
        match message["type"].as_str() {
            Some("NBIRTH") => sessions.push(Vec::new()),
            Some("DDATA") if message["device"] == "F1" => {
                let metrics = message["metrics"].as_array().unwrap();
                let Some(id) = metrics.iter().find(|m| m["alias"] == bite_alias) else {
                    continue;
                };
                let historical = metrics.iter().all(|m| m["is_historical"] == true);
                assert!(
                    historical || metrics.iter().all(|m| m["is_historical"] == false),
                    "all or none flagged: {message}"
                );
                sessions
                    .last_mut()
                    .expect("a DDATA before any NBIRTH")
                    .push((id["value"].as_u64().unwrap(), historical));
            }
            _ => {}
        }
    }
    sessions
}

/// Every bite id 1..=last arrived, once live or flagged historical: a repeat only
/// flagged historical; in each session the historical ones first, then the live ones,
/// each in order.
fn assert_every_bite_once(sessions: &[Vec<(u64, bool)>], last: u64) {
    let mut live = HashSet::new();
    let mut all = HashSet::new();
    for session in sessions {
        let first_live = session
            .iter()
            .position(|(_, h)| !h)
            .unwrap_or(session.len());
        assert!(
            session[first_live..].iter().all(|(_, h)| !h),
            "historical after live: {session:?}"
        );
        for part in [&session[..first_live], &session[first_live..]] {
            assert!(
                part.windows(2).all(|w| w[0].0 < w[1].0),
                "order: {session:?}"
            );
        }
        if let (Some(h), Some(l)) = (first_live.checked_sub(1), session.get(first_live)) {
            assert!(
                session[h].0 < l.0,
                "the backlog before the live bites: {session:?}"
            );
        }
        for &(id, historical) in session {
            all.insert(id);
            if !historical {
                assert!(live.insert(id), "bite {id} twice live: {sessions:?}");
            }
        }
    }
    let missing: Vec<u64> = (1..=last).filter(|id| !all.contains(id)).collect();
    assert!(
        missing.is_empty(),
        "bites {missing:?} never arrived: {sessions:?}"
    );
}

/// Read the host until it has had bite `last` of F1 (live or historical).
fn until_bite(host: &mut Host, bite_alias: u64, last: u64, limit: Duration) {
    let start = Instant::now();
    while !bites_by_session(&host.seen, bite_alias)
        .iter()
        .flatten()
        .any(|&(id, _)| id >= last)
    {
        host.next(
            limit
                .saturating_sub(start.elapsed())
                .max(Duration::from_millis(1)),
        );
    }
}

fn seq(message: &Value) -> u64 {
    message["seq"]
        .as_u64()
        .unwrap_or_else(|| panic!("no seq: {message}"))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn births_data_rebirth_and_the_will_as_an_independent_host_decodes_them() {
    let setup = Setup::new(MILLGATE, "sparkplug", "db").await;
    let port = free_port();
    let _broker = Broker::start(&setup.scratch, port);
    let mut host = Host::start(port, "plant");
    setup.append_config(&format!(
        "\n[outputs.mqtt]\nbroker = \"127.0.0.1:{port}\"\ngroup_id = \"plant\"\nnode_id = \"stand-f1\"\nkeep_alive_s = 5\ndata_period_ms = 200\n"
    ));

    let mut service = setup.spawn("run.log");
    let limit = Duration::from_secs(30);
    let nbirth = host.next_of("NBIRTH", limit);
    assert_eq!(nbirth["topic"], "spBv1.0/plant/NBIRTH/stand-f1");
    assert_eq!(seq(&nbirth), 0);
    let bd_seq = metric(&nbirth, "bdSeq")["value"].as_u64().unwrap();
    assert_eq!(bd_seq, 0, "a new history file starts at bdSeq 0");
    // bdSeq has an alias as every metric of the births, unique in the node.
    assert_eq!(metric(&nbirth, "bdSeq")["alias"], 0, "{nbirth}");
    let rebirth = metric(&nbirth, "Node Control/Rebirth");
    assert_eq!(
        (rebirth["datatype"].as_u64(), &rebirth["value"]),
        (Some(11), &Value::Bool(false))
    );
    let dbirth = host.next(limit);
    assert_eq!(
        dbirth["topic"], "spBv1.0/plant/DBIRTH/stand-f1/F1",
        "{dbirth}"
    );
    assert_eq!(seq(&dbirth), 1);
    // Every metric named, aliased, typed; units as properties.
    let mut names: HashMap<u64, String> = HashMap::new();
    for m in dbirth["metrics"].as_array().unwrap() {
        let alias = m["alias"].as_u64().expect("alias");
        assert!(m["datatype"].as_u64().unwrap() > 0, "{m}");
        assert!(names
            .insert(alias, m["name"].as_str().unwrap().to_owned())
            .is_none());
    }
    let node_aliases: HashSet<u64> = nbirth["metrics"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(|m| m["alias"].as_u64())
        .collect();
    assert!(node_aliases.is_disjoint(&names.keys().copied().collect()));
    assert_eq!(
        metric(&dbirth, "static_torque_knm")["properties"]["engUnit"],
        "kN*m"
    );
    assert_eq!(metric(&dbirth, "beta1_hz")["properties"]["engUnit"], "Hz");
    assert_eq!(metric(&dbirth, "gap_mrad")["properties"]["engUnit"], "mrad");
    assert_eq!(metric(&dbirth, "gap_alarm")["datatype"], 11, "Boolean");
    assert_eq!(
        metric(&dbirth, "static_torque_knm")["datatype"],
        10,
        "Double"
    );
    assert_eq!(
        metric(&dbirth, "bite_counter")["datatype"],
        8,
        "UInt64 (Tahu's JavaScript codec reads UInt32 as null)"
    );
    // The device's metrics are exactly the catalogue's driveline figures (and the bite
    // id), named by their keys: what a host sees is what the PLC and the page show.
    let mut born: Vec<&str> = names.values().map(String::as_str).collect();
    born.sort_unstable();
    let mut keys: Vec<&str> = millgate::state::catalogue::DRIVELINE
        .iter()
        .map(|f| f.key)
        .chain(["bite_id"])
        .chain(
            millgate::outputs::sparkplug::node::CAPTURE_METRICS
                .iter()
                .map(|(name, ..)| *name),
        )
        .collect();
    keys.sort_unstable();
    assert_eq!(born, keys);
    let bite_alias = metric(&dbirth, "bite_id")["alias"].as_u64().unwrap();
    assert_eq!(metric(&dbirth, "capture/kind")["datatype"], 12, "String");
    assert_eq!(
        metric(&dbirth, "capture/span_s")["properties"]["engUnit"],
        "s"
    );

    // Bites: each its own DDATA with the bite id, by alias only, values as in the PLC.
    let plc = setup.plc();
    let mut bites = Vec::new();
    while bites.len() < 2 {
        let data = host.next_of("DDATA", limit);
        let metrics = data["metrics"].as_array().unwrap();
        assert!(
            metrics
                .iter()
                .all(|m| m["name"].is_null() && names.contains_key(&m["alias"].as_u64().unwrap())),
            "{data}"
        );
        if let Some(id) = metrics.iter().find(|m| m["alias"] == bite_alias) {
            bites.push((id["value"].as_u64().unwrap(), data.clone()));
        }
    }
    common::wait_for("the PLC shows the bites", limit, || {
        u64::from(plc.counter()) >= bites[1].0
    })
    .await;
    assert_eq!(bites[0].0 + 1, bites[1].0, "one DDATA per bite");
    let by_name = |data: &Value, name: &str| -> Value {
        let alias = names.iter().find(|(_, n)| n.as_str() == name).unwrap().0;
        data["metrics"]
            .as_array()
            .unwrap()
            .iter()
            .find(|m| m["alias"] == *alias)
            .unwrap()["value"]
            .clone()
    };
    if u64::from(plc.counter()) == bites[1].0 {
        let taf = by_name(&bites[1].1, "taf").as_f64().unwrap();
        assert_eq!(taf as f32, plc.taf(), "the TAF the PLC has");
        // The pooled gap, once the gap maps are ready (read from the cache or built).
        if let Some(gap) = by_name(&bites[1].1, "gap_mrad").as_f64() {
            let words = plc.plc.holding();
            assert_eq!(
                Some(gap as f32),
                millgate::outputs::modbus::register_map::decode_f32(
                    &words[plc.at("F1.gap_mrad")..]
                ),
                "the gap the PLC has"
            );
        }
    }
    assert_eq!(
        by_name(&bites[1].1, "bite_counter").as_u64(),
        Some(bites[1].0)
    );

    // The edge node's counters on /metrics.
    assert_eq!(
        setup.metric("millgate_sparkplug_connected").await,
        Some(1.0)
    );
    assert_eq!(
        setup.metric("millgate_sparkplug_bd_seq").await,
        Some(bd_seq as f64)
    );
    let published = setup
        .metric("millgate_sparkplug_bites_published_total")
        .await
        .unwrap();
    assert!(published >= 2.0, "{published}");

    // Rebirth on command: NBIRTH seq 0 with the same bdSeq, then the DBIRTH.
    host.command("rebirth stand-f1");
    let again = host.next_of("NBIRTH", limit);
    assert_eq!(seq(&again), 0);
    assert_eq!(metric(&again, "bdSeq")["value"].as_u64(), Some(bd_seq));
    let dbirth_again = host.next(limit);
    assert_eq!(
        (dbirth_again["type"].as_str(), seq(&dbirth_again)),
        (Some("DBIRTH"), 1)
    );
    // The birth names the driveline's newest capture: at least the last bite's.
    let born_capture = metric(&dbirth_again, "capture/id")["value"].as_u64();
    let last_bite_capture = by_name(&bites[1].1, "capture/id").as_u64();
    assert!(
        born_capture.is_some() && born_capture >= last_bite_capture,
        "{dbirth_again}"
    );
    assert_eq!(metric(&dbirth_again, "capture/kind")["value"], "bite");

    // seq: every message after an NBIRTH is one more than the one before (mod 256).
    let mut last: Option<u64> = None;
    for message in &host.seen {
        match message["type"].as_str() {
            Some("NBIRTH") => last = Some(0),
            Some("NDEATH" | "NCMD") => {}
            _ => {
                let this = seq(message);
                assert_eq!(Some(this), last.map(|l| (l + 1) % 256), "{message}");
                last = Some(this);
            }
        }
    }

    // SIGKILL: the broker sends the Will, with the session's bdSeq; the next run's
    // NBIRTH has the next.
    service.kill().unwrap();
    service.wait().unwrap();
    let death = host.next_of("NDEATH", limit);
    assert_eq!(death["topic"], "spBv1.0/plant/NDEATH/stand-f1");
    assert_eq!(metric(&death, "bdSeq")["value"].as_u64(), Some(bd_seq));
    assert!(death["seq"].is_null());
    let mut second = setup.spawn("second.log");
    let next = host.next_of("NBIRTH", limit);
    assert_eq!(metric(&next, "bdSeq")["value"].as_u64(), Some(bd_seq + 1));
    // A clean stop sends the NDEATH itself.
    host.next_of("DBIRTH", limit);
    terminate(&mut second);
    let death = host.next_of("NDEATH", limit);
    assert_eq!(metric(&death, "bdSeq")["value"].as_u64(), Some(bd_seq + 1));
    // Each bite's DDATA announced its capture as the history file holds it (a
    // capture the writer committed after its bite's DDATA went is announced by the
    // next birth only: allowed for one of the two, not both).
    let reader = HistoryReader::open(&setup.history).unwrap();
    let captures: Vec<CaptureRow> = reader.rows(&Filter::default()).unwrap();
    let capture_alias = *names.iter().find(|(_, n)| *n == "capture/id").unwrap().0;
    let announcing: Vec<&(u64, Value)> = bites
        .iter()
        .filter(|(_, data)| {
            data["metrics"]
                .as_array()
                .unwrap()
                .iter()
                .any(|m| m["alias"] == capture_alias)
        })
        .collect();
    assert!(
        !announcing.is_empty(),
        "no bite DDATA announced its capture"
    );
    for (bite_id, data) in announcing {
        let row = captures
            .iter()
            .find(|c| c.bite_counter == Some(*bite_id as i64))
            .unwrap_or_else(|| panic!("bite {bite_id}: no capture in the file"));
        let announced = (
            by_name(data, "capture/id").as_i64(),
            by_name(data, "capture/kind"),
            by_name(data, "capture/samples").as_i64(),
            by_name(data, "capture/bytes").as_i64(),
            by_name(data, "capture/first_sample").as_i64(),
            by_name(data, "capture/span_s").as_f64(),
        );
        assert_eq!(
            announced,
            (
                Some(row.id),
                Value::from(row.kind.as_str()),
                Some(row.samples),
                Some(row.bytes),
                Some(row.first_sample_unix_ns / 1_000_000),
                Some(row.duration_s)
            ),
            "bite {bite_id}"
        );
    }
    setup.stop(second).await;
}

/// Issue 30, findings 6 and 10: a retained undecodable NCMD of 100 KiB (over rumqttc's
/// default 10 KiB) waiting on the broker made the node reconnect every second with a
/// new bdSeq, a live one ended the session, each undecodable NCMD logged a warning,
/// and each of 1 000 Rebirth NCMDs got full births. Now they are refused and counted
/// in one session, warned once per 10 s, and rebirths come at most once per 5 s.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_and_flooding_commands_neither_end_the_session_nor_multiply_births() {
    let setup = Setup::new(MILLGATE, "sparkplug-commands", "db").await;
    let port = free_port();
    let _broker = Broker::start(&setup.scratch, port);
    let mut host = Host::start(port, "plant");
    host.command("garbage stand-f1 102400 retain");
    while host.next(Duration::from_secs(10))["sent"] != "garbage" {}
    setup.append_config(&format!(
        "\n[outputs.mqtt]\nbroker = \"127.0.0.1:{port}\"\ngroup_id = \"plant\"\nnode_id = \"stand-f1\"\nkeep_alive_s = 5\n"
    ));
    let service = setup.spawn("run.log");
    let limit = Duration::from_secs(30);
    let nbirth = host.next_of("NBIRTH", limit);
    assert_eq!(metric(&nbirth, "bdSeq")["value"].as_u64(), Some(0));
    // The retained NCMD reached the node at its subscription: refused, not fatal.
    setup
        .until_metric("millgate_sparkplug_commands_refused_total", 1.0, limit)
        .await;
    // Fifty live undecodable ones, one of them 100 KiB.
    host.command("garbage stand-f1 102400");
    for _ in 0..49 {
        host.command("garbage stand-f1 7");
    }
    let mut sent = 0;
    while sent < 50 {
        if host.next(limit)["sent"] == "garbage" {
            sent += 1;
        }
    }
    setup
        .until_metric("millgate_sparkplug_commands_refused_total", 51.0, limit)
        .await;
    // A thousand rebirth commands.
    host.command("rebirth stand-f1 1000");
    setup
        .until_metric(
            "millgate_sparkplug_rebirth_requests_total",
            1000.0,
            Duration::from_secs(60),
        )
        .await;
    // Answered by the rebirths the interval allows: one at once if the last births
    // were over 5 s ago, one at the interval's end for the requests that came
    // meanwhile (their spacing is the paused-clock test of
    // `outputs::sparkplug::timers`). Before, each request got full births: hundreds
    // by the time the thousandth request is counted.
    let answered = host.next_of("NBIRTH", limit);
    assert_eq!(
        metric(&answered, "bdSeq")["value"].as_u64(),
        Some(0),
        "same session"
    );
    let rebirths = setup.metric("millgate_sparkplug_rebirths_total").await;
    assert!(
        matches!(rebirths, Some(r) if (1.0..=3.0).contains(&r)),
        "{rebirths:?} rebirths for 1000 requests"
    );
    assert_eq!(
        setup.metric("millgate_sparkplug_sessions_total").await,
        Some(1.0),
        "the session never ended"
    );
    assert_eq!(setup.metric("millgate_sparkplug_bd_seq").await, Some(0.0));
    let log = std::fs::read_to_string(setup.log("run.log")).unwrap();
    let warnings = log.matches("Sparkplug NCMD refused").count();
    eprintln!(
        "1000 rebirth requests: {rebirths:?} rebirths; 51 refused NCMDs: {warnings} warning lines"
    );
    assert!(
        (1..=3).contains(&warnings),
        "{warnings} warnings for 51 refused NCMDs: {log}"
    );
    host.command("clear stand-f1");
    setup.stop(service).await;
}

/// Issue 30, leftover of finding 6: a retained NCMD over the client's packet limit
/// (1 MiB; rumqttc refuses a packet by its header and ends the connection, it cannot
/// skip it) ended every session, the node reconnecting with backoff and a new bdSeq
/// each time for as long as the message stayed on the broker. Now the session after
/// the first clears the retained message before it subscribes: two sessions in all,
/// and the second obeys a Rebirth.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_retained_ncmd_over_the_packet_limit_ends_one_session_only() {
    let setup = Setup::new(MILLGATE, "sparkplug-oversize", "db").await;
    let port = free_port();
    let _broker = Broker::start(&setup.scratch, port);
    let mut host = Host::start(port, "plant");
    let oversize = millgate::outputs::sparkplug::MAX_INCOMING_PACKET * 2;
    host.command(&format!("garbage stand-f1 {oversize} retain"));
    while host.next(Duration::from_secs(10))["sent"] != "garbage" {}
    setup.append_config(&format!(
        "\n[outputs.mqtt]\nbroker = \"127.0.0.1:{port}\"\ngroup_id = \"plant\"\nnode_id = \"stand-f1\"\nkeep_alive_s = 5\n"
    ));
    let service = setup.spawn("run.log");
    let limit = Duration::from_secs(30);
    // The first session's births may or may not get out before the packet ends it.
    let born = |host: &mut Host| loop {
        let nbirth = host.next_of("NBIRTH", limit);
        let bd_seq = metric(&nbirth, "bdSeq")["value"].as_u64();
        if bd_seq != Some(0) {
            break bd_seq;
        }
    };
    assert_eq!(born(&mut host), Some(1), "the second session");
    setup
        .until_metric("millgate_sparkplug_sessions_total", 2.0, limit)
        .await;
    // The second session subscribed after clearing the retained NCMD: a Rebirth sent
    // now reaches it through that subscription. Had the message stayed, the broker
    // would have sent it at the subscription, before the Rebirth, ending the session
    // (the old code's next session came 2 s later, with bdSeq 2). The waits between
    // such sessions are the paused-clock tests of `outputs::sparkplug::timers`.
    host.command("rebirth stand-f1");
    assert_eq!(born(&mut host), Some(1), "a rebirth in the same session");
    assert_eq!(
        setup.metric("millgate_sparkplug_sessions_total").await,
        Some(2.0),
        "the second session stays up"
    );
    assert_eq!(setup.metric("millgate_sparkplug_bd_seq").await, Some(1.0));
    let log = std::fs::read_to_string(setup.log("run.log")).unwrap();
    assert_eq!(
        log.matches("clearing any retained NCMD").count(),
        1,
        "{log}"
    );
    setup.stop(service).await;
}

#[test]
fn the_demo_publishes_its_edge_node() {
    let folder = common::scratch("sparkplug-demo");
    let scratch = folder.path();
    let port = free_port();
    let _broker = Broker::start(scratch, port);
    let mut host = Host::start(port, "demo-plant");
    let broker = format!("127.0.0.1:{port}");
    let history = scratch.join("history.db");
    // Killed when a failing check ends the test early.
    let mut demo = KillOnDrop(
        MILLGATE
            .command()
            .args([
                "demo",
                "--duration",
                "4",
                "--mqtt",
                &broker,
                "--group",
                "demo-plant",
                "--node",
                "n1",
            ])
            .arg("--history")
            .arg(&history)
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .unwrap(),
    );
    let limit = Duration::from_secs(30);
    let nbirth = host.next_of("NBIRTH", limit);
    assert_eq!(nbirth["topic"], "spBv1.0/demo-plant/NBIRTH/n1");
    let dbirth = host.next_of("DBIRTH", limit);
    assert_eq!(dbirth["device"], "F1");
    let bite = host.next_of("DDATA", limit);
    assert!(!bite["metrics"].as_array().unwrap().is_empty());
    let death = host.next_of("NDEATH", limit);
    assert_eq!(
        metric(&death, "bdSeq")["value"],
        metric(&nbirth, "bdSeq")["value"]
    );
    let output = demo.wait_with_output().unwrap();
    assert!(output.status.success());
    let stdout = String::from_utf8_lossy(&output.stdout);
    assert!(
        stdout.contains(&format!(
            "Sparkplug B: edge node demo-plant/n1 on mqtt://{broker}"
        )),
        "{stdout}"
    );
    let bad = MILLGATE
        .command()
        .args(["demo", "--mqtt", &broker, "--node", "a/b"])
        .output()
        .unwrap();
    assert!(!bad.status.success());
    assert!(String::from_utf8_lossy(&bad.stderr).contains("\"a/b\" is not allowed"));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn no_birth_before_the_primary_host_is_online_and_its_offline_ends_the_session() {
    let setup = Setup::new(MILLGATE, "sparkplug-state", "db").await;
    let port = free_port();
    let _broker = Broker::start(&setup.scratch, port);
    let mut host = Host::start(port, "plant");
    setup.append_config(&format!(
        "\n[outputs.mqtt]\nbroker = \"127.0.0.1:{port}\"\ngroup_id = \"plant\"\nnode_id = \"f1\"\nprimary_host_id = \"scada\"\n"
    ));
    let mut service = setup.spawn("run.log");
    // Connected (the /metrics gauge) but silent while the host has no STATE.
    common::wait_for("connected", Duration::from_secs(20), || {
        std::fs::read_to_string(setup.log("run.log"))
            .unwrap()
            .contains("Sparkplug session up")
    })
    .await;
    // The window: from the session's start (where a node that did not wait for the
    // host sends its births) until a bite made since is in the history, held back
    // (the backlog counts it) where such a node would have sent its DDATA. The
    // node's own count of what it handed to the broker, then what the host got.
    setup.plc().bites_after_now(1).await;
    common::until_scraped_at_least(
        setup.metrics_port,
        "millgate_sparkplug_backlog_bites",
        1.0,
        Duration::from_secs(20),
    )
    .await;
    assert_eq!(
        setup
            .metric("millgate_sparkplug_messages_published_total")
            .await,
        Some(0.0),
        "nothing handed to the broker before the host is online"
    );
    let early = host.lines.try_recv();
    assert!(
        early.is_err(),
        "nothing before the host is online: {early:?}"
    );

    host.command("state scada online");
    let limit = Duration::from_secs(20);
    let nbirth = host.next_of("NBIRTH", limit);
    let bd_seq = metric(&nbirth, "bdSeq")["value"].as_u64().unwrap();
    host.next_of("DBIRTH", limit);
    host.command("state scada offline");
    let death = host.next_of("NDEATH", limit);
    assert_eq!(metric(&death, "bdSeq")["value"].as_u64(), Some(bd_seq));
    host.command("state scada online");
    let next = host.next_of("NBIRTH", limit);
    assert_eq!(
        metric(&next, "bdSeq")["value"].as_u64(),
        Some(bd_seq + 1),
        "a new session"
    );
    let dbirth = host.next_of("DBIRTH", limit);
    let bite_alias = metric(&dbirth, "bite_id")["alias"].as_u64().unwrap();

    // Store-and-forward: the host goes offline; a bite; the gateway is killed and
    // started again (the replay cursor is in the file); another bite; the host comes
    // back: the bites in between arrive flagged historical, before the live ones.
    let plc = setup.plc();
    plc.bites_after_now(1).await;
    host.command("state scada offline");
    host.next_of("NDEATH", limit);
    plc.bites_after_now(1).await;
    service.kill().unwrap();
    service.wait().unwrap();
    let mut service = setup.spawn("second.log");
    plc.bites_after_now(1).await;
    let backlog = setup.metric("millgate_sparkplug_backlog_bites").await;
    assert!(backlog.is_some_and(|b| b >= 1.0), "{backlog:?}");
    host.command("state scada online");
    host.next_of("NBIRTH", limit);
    let last_at_online = u64::from(plc.counter());
    until_bite(&mut host, bite_alias, last_at_online + 1, limit);
    let sessions = bites_by_session(&host.seen, bite_alias);
    assert_every_bite_once(&sessions, last_at_online + 1);
    let replayed: Vec<u64> = sessions
        .last()
        .unwrap()
        .iter()
        .filter(|(_, h)| *h)
        .map(|(id, _)| *id)
        .collect();
    assert!(
        replayed.len() >= 2,
        "the outage's bites replayed: {sessions:?}"
    );
    assert!(
        setup
            .metric("millgate_sparkplug_replayed_total")
            .await
            .is_some_and(|n| n >= replayed.len() as f64),
        "replayed on /metrics"
    );
    common::wait_for("the backlog confirmed", limit, || {
        let page = std::fs::read_to_string(setup.log("second.log")).unwrap();
        page.contains("Sparkplug backlog replayed")
    })
    .await;
    terminate(&mut service);
    setup.stop(service).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn after_a_broker_restart_the_node_is_born_again_with_the_next_bd_seq() {
    let setup = Setup::new(MILLGATE, "sparkplug-restart", "db").await;
    let port = free_port();
    let mut broker = Broker::start(&setup.scratch, port);
    let mut host = Host::start(port, "plant");
    // A primary host: the node births (and replays) only once the host, back on the
    // restarted broker, has subscribed and said so; otherwise the replay could go
    // before the host's reconnection and be lost to it (not to the broker).
    setup.append_config(&format!(
        "\n[outputs.mqtt]\nbroker = \"127.0.0.1:{port}\"\ngroup_id = \"plant\"\nnode_id = \"f1\"\nkeep_alive_s = 5\nprimary_host_id = \"scada\"\n"
    ));
    host.command("state scada online");
    let mut service = setup.spawn("run.log");
    let limit = Duration::from_secs(30);
    let nbirth = host.next_of("NBIRTH", limit);
    let bd_seq = metric(&nbirth, "bdSeq")["value"].as_u64().unwrap();
    let dbirth = host.next_of("DBIRTH", limit);
    let bite_alias = metric(&dbirth, "bite_id")["alias"].as_u64().unwrap();
    until_bite(&mut host, bite_alias, 1, limit);

    // The broker dies (no Will: the broker itself is gone) and comes back after a
    // few bites and after the node has failed to connect a few times: those attempts
    // use no bdSeq.
    let plc = setup.plc();
    drop(broker);
    plc.bites_after_now(2).await;
    broker = Broker::start(&setup.scratch, port);
    while host.next(limit)["ready"] != true {}
    host.command("state scada online");
    let next = host.next_of("NBIRTH", limit);
    assert_eq!(seq(&next), 0);
    assert_eq!(metric(&next, "bdSeq")["value"].as_u64(), Some(bd_seq + 1));
    let dbirth = host.next_of("DBIRTH", limit);
    assert_eq!(seq(&dbirth), 1);
    let last_at_birth = u64::from(plc.counter());
    until_bite(&mut host, bite_alias, last_at_birth + 1, limit);
    assert_every_bite_once(&bites_by_session(&host.seen, bite_alias), last_at_birth + 1);
    // The Will at SIGKILL carries the last NBIRTH's bdSeq.
    service.kill().unwrap();
    service.wait().unwrap();
    let death = host.next_of("NDEATH", limit);
    assert_eq!(metric(&death, "bdSeq")["value"].as_u64(), Some(bd_seq + 1));
    drop(broker);
    setup.stop(service).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_backlog_is_replayed_historical_in_order_at_the_configured_pace() {
    let folder = common::scratch("sparkplug-pace");
    let scratch = folder.path();
    let port = free_port();
    let _broker = Broker::start(scratch, port);
    // A group of its own: free_port() may hand another test's broker port out too.
    let mut host = Host::start(port, "pace");
    let history = scratch.join("history.db");
    const BITES: u32 = 24;
    const BATCH: u32 = 4;
    const PERIOD_MS: u32 = 150;
    backlog::write_backlog(&history, "pace", BITES);
    let config = backlog::node_config(
        port,
        "pace",
        &history,
        &format!("replay_batch = {BATCH}\nreplay_period_ms = {PERIOD_MS}"),
    );
    let started = Instant::now();
    let (stop, status, task) = backlog::start_node(&config);
    let limit = Duration::from_secs(20);
    let dbirth = host.next_of("DBIRTH", limit);
    let bite_alias = metric(&dbirth, "bite_id")["alias"].as_u64().unwrap();
    until_bite(&mut host, bite_alias, u64::from(BITES), limit);
    let sessions = bites_by_session(&host.seen, bite_alias);
    let expected: Vec<(u64, bool)> = (1..=u64::from(BITES)).map(|id| (id, true)).collect();
    assert_eq!(sessions, [expected]);
    let span_s = started.elapsed().as_secs_f64();
    // The replay starts at the births, after the node's start; its batches go at the
    // period's ticks, the first at once: the last batch leaves (N/b - 1) periods
    // later, and the host has it after that.
    let least_s = f64::from(BITES / BATCH - 1) * f64::from(PERIOD_MS) / 1000.0;
    assert!(span_s >= least_s, "{span_s} s < {least_s} s");
    assert!(span_s < least_s + 5.0, "{span_s} s: stalled");
    // The replay's bites carry the rows' own times (10 ms apart) and values.
    let ddata: Vec<&Value> = host.seen.iter().filter(|m| m["type"] == "DDATA").collect();
    assert_eq!(ddata[0]["timestamp"], 1_767_225_600_010u64);
    assert_eq!(ddata[1]["timestamp"], 1_767_225_600_020u64);
    common::wait_for("the cursor confirmed", limit, || {
        status.counts().backlog == 0 && status.counts().replayed == u64::from(BITES)
    })
    .await;
    stop.trigger();
    task.await.unwrap();
}

/// PEM files made for the TLS test in `folder`: a CA (`ca.pem`), the broker's
/// certificate for 127.0.0.1 and the gateway's client certificate, both signed by it
/// (`server.pem`/`server.key`, `client.pem`/`client.key`), and a second CA that signed
/// nothing here (`other-ca.pem`).
fn certificates(folder: &Path) {
    use rcgen::{BasicConstraints, CertificateParams, CertifiedIssuer, DnType, IsCa, KeyPair};
    let authority = |name: &str| {
        let mut params = CertificateParams::new(Vec::<String>::new()).unwrap();
        params.is_ca = IsCa::Ca(BasicConstraints::Unconstrained);
        params.distinguished_name.push(DnType::CommonName, name);
        CertifiedIssuer::self_signed(params, KeyPair::generate().unwrap()).unwrap()
    };
    let write = |name: &str, text: String| std::fs::write(folder.join(name), text).unwrap();
    let ca = authority("millgate test CA");
    write("ca.pem", ca.pem());
    write("other-ca.pem", authority("another CA").pem());
    for (name, subject) in [("server", "127.0.0.1"), ("client", "gateway f1")] {
        let key = KeyPair::generate().unwrap();
        let mut params = CertificateParams::new(vec![subject.to_owned()]).unwrap();
        params.distinguished_name.push(DnType::CommonName, subject);
        let certificate = params.signed_by(&key, &ca).unwrap();
        write(&format!("{name}.pem"), certificate.pem());
        write(&format!("{name}.key"), key.serialize_pem());
    }
}

/// The [`certificates`], a mosquitto password file with user `gw` (password `s3cret`)
/// and the gateway's password file `secret`, in `folder`; the password file's path.
fn tls_and_passwords(folder: &Path) -> std::path::PathBuf {
    certificates(folder);
    let passwords = folder.join("passwords");
    let made = Command::new("mosquitto_passwd")
        .args(["-b", "-c"])
        .arg(&passwords)
        .args(["gw", "s3cret"])
        .status()
        .expect("mosquitto_passwd (Debian's mosquitto)");
    assert!(made.success());
    std::fs::write(folder.join("secret"), "s3cret\n").unwrap();
    passwords
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn over_tls_with_a_password_and_a_client_certificate_and_clear_errors_when_refused() {
    let setup = Setup::new(MILLGATE, "sparkplug-tls", "db").await;
    let folder = &setup.scratch;
    let passwords = tls_and_passwords(folder);
    std::fs::write(folder.join("wrong-secret"), "guess\n").unwrap();
    // Two TLS listeners: one that requires a client certificate, one that does not;
    // both with passwords.
    let (with_certificate, without) = (free_port(), free_port());
    let tls = |port: u16, require: bool| {
        format!(
            "listener {port} 127.0.0.1\ncafile {ca}\ncertfile {cert}\nkeyfile {key}\n\
             require_certificate {require}\nallow_anonymous false\npassword_file {passwords}\n",
            ca = folder.join("ca.pem").display(),
            cert = folder.join("server.pem").display(),
            key = folder.join("server.key").display(),
            passwords = passwords.display(),
        )
    };
    let _broker = Broker::with_listeners(
        folder,
        with_certificate,
        &format!(
            "per_listener_settings true\n{}{}",
            tls(with_certificate, true),
            tls(without, false)
        ),
    );
    let file = |name: &str| folder.join(name).display().to_string();
    let mut host = Host::with_options(
        with_certificate,
        "plant",
        &[
            "--ca",
            &file("ca.pem"),
            "--cert",
            &file("client.pem"),
            "--key",
            &file("client.key"),
            "--username",
            "gw",
            "--password",
            "s3cret",
        ],
    );
    let base = std::fs::read_to_string(&setup.config).unwrap();
    let configure = |node: &str, port: u16, secret: &str, tls: &str| {
        std::fs::write(
            &setup.config,
            format!(
                "{base}\n[outputs.mqtt]\nbroker = \"127.0.0.1:{port}\"\ngroup_id = \"plant\"\n\
                 node_id = \"{node}\"\nusername = \"gw\"\npassword_file = \"{}\"\n\
                 [outputs.mqtt.tls]\n{tls}\n",
                file(secret)
            ),
        )
        .unwrap();
    };

    // Client certificate and password: born over TLS, the host decodes a bite.
    configure(
        "f1",
        with_certificate,
        "secret",
        &format!(
            "ca_file = \"{}\"\ncert_file = \"{}\"\nkey_file = \"{}\"",
            file("ca.pem"),
            file("client.pem"),
            file("client.key")
        ),
    );
    let mut service = setup.spawn("tls.log");
    let limit = Duration::from_secs(30);
    let nbirth = host.next_of("NBIRTH", limit);
    assert_eq!(nbirth["topic"], "spBv1.0/plant/NBIRTH/f1");
    let dbirth = host.next_of("DBIRTH", limit);
    let bite_alias = metric(&dbirth, "bite_id")["alias"].as_u64().unwrap();
    loop {
        let data = host.next_of("DDATA", limit);
        if data["metrics"]
            .as_array()
            .unwrap()
            .iter()
            .any(|m| m["alias"] == bite_alias)
        {
            break;
        }
    }
    assert_eq!(
        setup.metric("millgate_sparkplug_connected").await,
        Some(1.0)
    );
    terminate(&mut service);
    let death = host.next_of("NDEATH", limit);
    assert_eq!(
        metric(&death, "bdSeq")["value"],
        metric(&nbirth, "bdSeq")["value"]
    );

    // A CA that did not sign the broker's certificate: a TLS error in the log and on
    // /metrics, retried, and the service goes on (the PLC gets its bites).
    let failures =
        |reason: &str| format!("millgate_sparkplug_connect_failures_total{{reason=\"{reason}\"}}");
    configure(
        "f1-wrong-ca",
        without,
        "secret",
        &format!("ca_file = \"{}\"", file("other-ca.pem")),
    );
    let mut service = setup.spawn("wrong-ca.log");
    let logged = |log: &str, text: &str| {
        std::fs::read_to_string(setup.log(log))
            .unwrap()
            .contains(text)
    };
    common::wait_for("the TLS failure in the log", limit, || {
        logged("wrong-ca.log", "Sparkplug broker connection failed")
    })
    .await;
    let start = Instant::now();
    while setup.metric(&failures("tls")).await.unwrap_or(0.0) < 2.0 {
        assert!(
            start.elapsed() < limit,
            "no retried TLS failure on /metrics"
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    setup.plc().bites_after_now(1).await;
    assert!(service.try_wait().unwrap().is_none(), "the service runs");
    assert_eq!(
        setup.metric("millgate_sparkplug_connected").await,
        Some(0.0)
    );
    let log = std::fs::read_to_string(setup.log("wrong-ca.log")).unwrap();
    assert!(
        log.contains("Sparkplug broker connection failed")
            && log.contains("invalid peer certificate")
            && log.contains("check outputs.mqtt.tls"),
        "{log}"
    );
    terminate(&mut service);

    // A wrong password: "not authorised", on /metrics too.
    configure(
        "f1-bad-password",
        without,
        "wrong-secret",
        &format!("ca_file = \"{}\"", file("ca.pem")),
    );
    let mut service = setup.spawn("password.log");
    common::wait_for("the refusal in the log", limit, || {
        logged("password.log", "Sparkplug broker connection failed")
    })
    .await;
    let start = Instant::now();
    while setup
        .metric(&failures("not_authorised"))
        .await
        .unwrap_or(0.0)
        < 1.0
    {
        assert!(
            start.elapsed() < limit,
            "no not_authorised failure on /metrics"
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    assert_eq!(setup.metric(&failures("tls")).await, Some(0.0));
    let log = std::fs::read_to_string(setup.log("password.log")).unwrap();
    assert!(
        log.contains("not authorised: check outputs.mqtt.username"),
        "{log}"
    );
    terminate(&mut service);
    // Neither refused node was ever born.
    while let Ok(message) = host.lines.try_recv() {
        host.seen.push(message);
    }
    assert!(
        host.seen
            .iter()
            .all(|m| m["node"] == "f1" || m["node"].is_null()),
        "only f1 was born"
    );
    setup.stop(service).await;
}

/// The rod mill example's block (`sim/models/rod`) as a device: a virtual process
/// PLC holds the drive configuration, the pass and the finishing speed; the DBIRTH has
/// one `span<i>/` set per span of the mill file; the values match what the simulator's
/// library gives for the pass at that speed (`PassSetup::status`), and the worst
/// margin and span are the smallest margin and its span.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_rod_mill_is_a_device_with_its_spans_and_worst_margin() {
    use millgate_config::layout::encode_value;
    use millgate_config::{ValueType, WordOrder};
    use millgate_sim::devices::modbus_bank::ServeOptions;
    use millgate_sim::devices::virtual_plc::VirtualPlc;
    use millgate_sim::rod::check::PassSetup;
    use millgate_sim::rod::mill::RodMill;
    use millgate_sim::rod::schedule;

    let folder = common::scratch("sparkplug-rod");
    let scratch = folder.path();
    let models = common::repo().join("sim/models/rod");
    // Pass P1 (table3) at 51.5 m/s: inside span 2's band (50.8-52.3 m/s).
    let speed = 51.5;
    let mill = std::sync::Arc::new(RodMill::load(models.join("rsm-mill.toml")).unwrap());
    let passes = schedule::load(models.join("rsm-schedule.csv")).unwrap();
    let expected = PassSetup::new(&mill, &passes[0])
        .unwrap()
        .status(speed)
        .unwrap();
    assert_eq!(expected.len(), mill.spans.len());

    let process = VirtualPlc::new(16);
    {
        let bank = process.bank();
        let mut bank = bank.lock();
        bank.holding[0] = 0;
        bank.holding[1] = 1;
        let (words, _) = encode_value(speed, ValueType::F32, WordOrder::Abcd);
        bank.holding[2..4].copy_from_slice(&words);
    }
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let process_address = listener.local_addr().unwrap();
    let process_running = process.spawn(listener, ServeOptions::default());
    let port = free_port();
    let _broker = Broker::start(scratch, port);
    let mut host = Host::start(port, "rods");
    let config = scratch.join("rod.toml");
    std::fs::write(
        &config,
        format!(
            "name = \"rod sparkplug\"\n\
             [[sources.modbus]]\nname = \"process_plc\"\naddress = \"{process_address}\"\n\
             poll_period_ms = 20\ntimeout_ms = 200\n\
             [[channels]]\nname = \"rsm_configuration\"\nkind = \"process_value\"\nunit = \"1\"\n\
             source = {{ modbus = \"process_plc\", table = \"holding\", address = 0 }}\n\
             [[channels]]\nname = \"rsm_pass\"\nkind = \"process_value\"\nunit = \"1\"\n\
             source = {{ modbus = \"process_plc\", table = \"holding\", address = 1 }}\n\
             [[channels]]\nname = \"rsm_speed\"\nkind = \"process_value\"\nunit = \"m/s\"\n\
             source = {{ modbus = \"process_plc\", table = \"holding\", address = 2, type = \"f32\" }}\n\
             [[rod_mills]]\nname = \"RSM\"\nmill = \"{mill}\"\nschedule = \"{schedule}\"\n\
             configuration = \"rsm_configuration\"\nconfigurations = [\"table3\", \"fast\"]\n\
             pass = \"rsm_pass\"\nfinishing_speed = \"rsm_speed\"\n\
             [outputs.mqtt]\nbroker = \"127.0.0.1:{port}\"\ngroup_id = \"rods\"\n\
             node_id = \"block\"\ndata_period_ms = 100\n\
             [history]\npath = \"history.db\"\n",
            mill = models.join("rsm-mill.toml").display(),
            schedule = models.join("rsm-schedule.csv").display(),
        ),
    )
    .unwrap();
    let log = std::fs::File::create(scratch.join("run.log")).unwrap();
    // Killed when a failing check ends the test early.
    let mut service = KillOnDrop(
        MILLGATE
            .command()
            .args(["run", "--config"])
            .arg(&config)
            .env("RUST_LOG", "info")
            .stdout(Stdio::null())
            .stderr(log)
            .spawn()
            .unwrap(),
    );

    let limit = Duration::from_secs(30);
    let dbirth = host.next_of("DBIRTH", limit);
    assert_eq!(dbirth["topic"], "spBv1.0/rods/DBIRTH/block/RSM");
    let mut names: HashMap<u64, String> = HashMap::new();
    let mut values: HashMap<String, Value> = HashMap::new();
    for m in dbirth["metrics"].as_array().unwrap() {
        let name = m["name"].as_str().unwrap().to_owned();
        names.insert(m["alias"].as_u64().unwrap(), name.clone());
        values.insert(name, m["value"].clone());
    }
    let spans = names
        .values()
        .filter(|n| n.ends_with("/speed_margin_m_s"))
        .count();
    assert_eq!(spans, mill.spans.len(), "one span<i>/ set per span");
    assert!(names
        .values()
        .any(|n| n == &format!("span{spans}/worst_exponent_per_s")));
    assert_eq!(
        metric(&dbirth, "worst_margin_m_s")["properties"]["engUnit"],
        "m/s"
    );
    // Until the mill is evaluated at the speed (the DBIRTH may predate it).
    let start = Instant::now();
    while values["invalid"] != Value::Bool(false)
        || values["finishing_speed_m_s"].as_f64() != Some(speed)
    {
        let left = limit.saturating_sub(start.elapsed());
        let data = host.next_of("DDATA", left.max(Duration::from_millis(1)));
        for m in data["metrics"].as_array().unwrap() {
            let name = &names[&m["alias"].as_u64().unwrap()];
            values.insert(name.clone(), m["value"].clone());
        }
    }
    let mut worst: Option<(usize, f64)> = None;
    for (index, status) in expected.iter().enumerate() {
        let value = |field: &str| values[&format!("span{}/{field}", index + 1)].clone();
        assert_eq!(value("invalid"), Value::Bool(false), "span {}", index + 1);
        assert_eq!(
            value("unstable"),
            Value::Bool(!status.stable),
            "span {}: {status:?}",
            index + 1
        );
        match status.speed_margin_m_s {
            Some(margin) => {
                let published = value("speed_margin_m_s").as_f64().unwrap();
                assert!((published - margin).abs() < 1e-9, "{published} vs {margin}");
                if worst.is_none_or(|(_, w)| margin < w) {
                    worst = Some((index, margin));
                }
            }
            None => assert!(value("speed_margin_m_s").is_null()),
        }
    }
    let (worst_span, worst_margin) = worst.expect("a span with a margin");
    assert_eq!(values["worst_span"].as_u64(), Some(worst_span as u64 + 1));
    assert_eq!(values["worst_margin_m_s"].as_f64(), Some(worst_margin));
    assert!(worst_margin < 0.0, "span 2 is in its band at {speed} m/s");
    assert_eq!(values["unstable"], Value::Bool(true));
    terminate(&mut service);
    process_running.stop().await.unwrap();
}

/// The failover run shared by the server-set tests: `millgate run` with `brokers` on
/// `ports` (in this order, `extra` more keys of `[outputs.mqtt]`) and every bite the PLC saw reaching `hosts` (each a host
/// application subscribed on one server; their messages are read in this order, as
/// the node moves from server to server). Once the first server has the node's
/// session and a bite went out, `kill` stops it mid-stream; the node moves on to the
/// next server that answers, born again with the next bdSeq, and replays flagged
/// historical what no server confirmed. Returns the sessions' bites and every message
/// the hosts saw, for more checks.
/// What `hosts` have seen, one after the other.
fn seen(hosts: &[Host]) -> Vec<Value> {
    hosts.iter().flat_map(|h| h.seen.clone()).collect()
}

/// Read `hosts` (each in turn, 100 ms each) until `found` finds something in what they
/// have seen, at most `limit`.
fn read_until<T>(
    hosts: &mut [Host],
    what: &str,
    limit: Duration,
    found: impl Fn(&[Value]) -> Option<T>,
) -> T {
    let start = Instant::now();
    loop {
        if let Some(value) = found(&seen(hosts)) {
            return value;
        }
        assert!(start.elapsed() < limit, "no {what} within {limit:?}");
        for host in hosts.iter_mut() {
            if let Ok(value) = host.lines.recv_timeout(Duration::from_millis(100)) {
                host.seen.push(value);
            }
        }
    }
}

/// The `n`th NBIRTH (0-based) among `seen`.
fn nth_birth(seen: &[Value], n: usize) -> Option<Value> {
    seen.iter()
        .filter(|m| m["type"] == "NBIRTH")
        .nth(n)
        .cloned()
}

/// The node's first births among what `hosts` see: the NBIRTH's bdSeq and the alias
/// of F1's `bite_id` in its DBIRTH.
fn first_births(hosts: &mut [Host], limit: Duration) -> (u64, u64) {
    let nbirth = read_until(hosts, "NBIRTH", limit, |seen| nth_birth(seen, 0));
    let bd_seq = metric(&nbirth, "bdSeq")["value"].as_u64().unwrap();
    let dbirth = read_until(hosts, "DBIRTH", limit, |seen| {
        seen.iter()
            .find(|m| m["type"] == "DBIRTH" && m["device"] == "F1")
            .cloned()
    });
    (
        bd_seq,
        metric(&dbirth, "bite_id")["alias"].as_u64().unwrap(),
    )
}

/// Wait for the node's second NBIRTH among what `hosts` see: a new session, with the
/// bdSeq after `bd_seq` and seq from 0.
fn born_again(hosts: &mut [Host], bd_seq: u64, limit: Duration) {
    let next_birth = read_until(hosts, "second NBIRTH", limit, |seen| nth_birth(seen, 1));
    assert_eq!(
        metric(&next_birth, "bdSeq")["value"].as_u64(),
        Some(bd_seq + 1),
        "{next_birth}"
    );
    assert_eq!(seq(&next_birth), 0);
}

/// After a reload that restarts the node: its NDEATH with `bd_seq`, then its next
/// birth among what `hosts` see.
fn ended_and_born_again(hosts: &mut [Host], bd_seq: u64, limit: Duration) {
    let death = read_until(hosts, "NDEATH", limit, |seen| {
        seen.iter().find(|m| m["type"] == "NDEATH").cloned()
    });
    assert_eq!(metric(&death, "bdSeq")["value"].as_u64(), Some(bd_seq));
    born_again(hosts, bd_seq, limit);
}

/// Once the PLC shows another bite of F1 and `hosts` see it: two sessions between
/// them, with every bite of F1 the PLC saw once.
async fn every_bite_in_two_sessions(
    hosts: &mut [Host],
    plc: &common::Plc<'_>,
    bite_alias: u64,
    limit: Duration,
) {
    plc.bites_after_now(1).await;
    let last = u64::from(plc.counter());
    read_until(hosts, "a bite of F1 after the reload", limit, |seen| {
        bite_after(seen, bite_alias, last - 1)
    });
    let sessions = bites_by_session(&seen(hosts), bite_alias);
    assert_eq!(sessions.len(), 2, "{sessions:?}");
    assert_every_bite_once(&sessions, last);
}

/// Whether a bite of F1 after `after` is among `seen`.
fn bite_after(seen: &[Value], bite_alias: u64, after: u64) -> Option<()> {
    let sessions = bites_by_session(seen, bite_alias);
    sessions
        .iter()
        .flatten()
        .any(|&(id, _)| id > after)
        .then_some(())
}

/// The failover run shared by the server-set tests: `millgate run` with `brokers` on
/// `ports` (in this order, `extra` more keys of `[outputs.mqtt]`) and every bite the
/// PLC saw reaching `hosts` (host applications subscribed on servers that stay up, or
/// one per server; their messages are read in this order, as the node moves on).
/// Once a server has the node's session and a bite went out, `kill` stops that server
/// (its index in `ports`) mid-stream and returns what ends the outage, called once the
/// PLC has seen the next bite (`|| ()`: nothing more); the node moves on to the next
/// server that answers, born again with the next bdSeq, and replays flagged
/// historical what no server confirmed. Returns the sessions' bites and the hosts.
async fn failover_keeps_every_bite<End: FnOnce()>(
    setup: Setup,
    ports: &[u16],
    extra: &str,
    hosts: Vec<Host>,
    kill: impl FnOnce(usize) -> End,
) -> (Vec<Vec<(u64, bool)>>, Vec<Host>) {
    let servers: Vec<String> = ports.iter().map(|p| format!("\"127.0.0.1:{p}\"")).collect();
    failover_through(setup, (ports, &servers), extra, hosts, kill).await
}

/// As [`failover_keeps_every_bite`], with the `brokers` entries written as `servers`
/// (a `"host:port"` or a table each, for `ports` in this order).
async fn failover_through<End: FnOnce()>(
    setup: Setup,
    (ports, servers): (&[u16], &[String]),
    extra: &str,
    mut hosts: Vec<Host>,
    kill: impl FnOnce(usize) -> End,
) -> (Vec<Vec<(u64, bool)>>, Vec<Host>) {
    setup.append_config(&format!(
        "\n[outputs.mqtt]\nbrokers = [{}]\ngroup_id = \"plant\"\nnode_id = \"f1\"\nkeep_alive_s = 5\n{extra}\n",
        servers.join(", ")
    ));
    let in_use =
        |port: u16| format!("millgate_sparkplug_server_in_use{{server=\"127.0.0.1:{port}\"}}");
    let mut service = setup.spawn("run.log");
    let log_on_failure = setup.log_on_failure("run.log");
    let limit = Duration::from_secs(60);
    let (bd_seq, bite_alias) = first_births(&mut hosts, limit);
    let mut used = None;
    for (index, &port) in ports.iter().enumerate() {
        if setup.metric(&in_use(port)).await == Some(1.0) {
            used = Some(index);
        }
    }
    let used = used.unwrap_or_else(|| panic!("no server in use:\n{}", setup.log_text("run.log")));

    // Mid-stream: a bite has just gone out, the next ones follow at the demo's pace.
    let plc = setup.plc();
    plc.bites_after_now(1).await;
    let last = u64::from(plc.counter());
    read_until(&mut hosts, "the bite", limit, |seen| {
        bite_after(seen, bite_alias, last - 1)
    });
    let switches = setup
        .metric("millgate_sparkplug_server_switches_total")
        .await;
    let end_outage = kill(used);
    plc.bites_after_now(1).await;
    end_outage();

    // Born again on another server, with the next bdSeq and seq from 0.
    born_again(&mut hosts, bd_seq, limit);
    let last_at_birth = u64::from(plc.counter());
    read_until(&mut hosts, "a bite after the birth", limit, |seen| {
        bite_after(seen, bite_alias, last_at_birth)
    });
    let sessions = bites_by_session(&seen(&hosts), bite_alias);
    assert_every_bite_once(&sessions, last_at_birth + 1);

    // /metrics: another server in use, the switches, the time without one.
    assert_eq!(setup.metric(&in_use(ports[used])).await, Some(0.0));
    assert_eq!(
        setup.metric("millgate_sparkplug_connected").await,
        Some(1.0)
    );
    let now = setup
        .metric("millgate_sparkplug_server_switches_total")
        .await;
    assert!(
        now.zip(switches).is_some_and(|(now, before)| now > before),
        "{switches:?} -> {now:?}"
    );
    let without = setup
        .metric("millgate_sparkplug_without_broker_seconds_total")
        .await;
    assert!(without.is_some_and(|s| s > 0.0), "{without:?}");
    terminate(&mut service);
    drop(log_on_failure);
    setup.stop(service).await;
    (sessions, hosts)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn killing_the_cluster_node_of_the_session_loses_no_bite() {
    let setup = Setup::new(MILLGATE, "sparkplug-cluster", "db").await;
    let mut cluster = common::cluster::RabbitCluster::start(&setup.scratch);
    let ports = cluster.mqtt_ports().to_vec();
    // The node knows the first two nodes, the host application is on the third. The
    // node's NCMD subscription at QoS 0: RabbitMQ 3.10 keeps a QoS 1 subscription's
    // queue on the node of the first session, and refuses the resubscription on the
    // others while that node is down (docs/sparkplug.md).
    let host = Host::with_options(ports[2], "plant", &["--dots-as-slashes"]);
    let (sessions, hosts) =
        failover_keeps_every_bite(setup, &ports[..2], "command_qos = 0", vec![host], |node| {
            cluster.kill(node);
            || ()
        })
        .await;
    assert!(sessions.len() >= 2, "{sessions:?}");
    let seen = seen(&hosts);
    // RabbitMQ 3.10 delivers `spBv1.0/...` as `spBv1/0/...` (docs/sparkplug.md): a
    // plant's host needs a broker that keeps the topic.
    assert!(
        seen.iter()
            .filter(|m| m.get("type").is_some())
            .all(|m| m["rewritten"] == true),
        "RabbitMQ keeps the topics now: update docs/sparkplug.md"
    );
}

/// A Sparkplug-clean cluster (issue 41): three aedes nodes sharing one redis
/// (tests/src/kit/cluster.rs). The primary host application is on the third node and
/// has published its retained STATE there; the node knows the first two, waits for
/// that STATE (kept for every node in redis) before each birth, and its node is
/// killed mid-stream. Every bite reaches the host, topics as sent, the one the PLC saw
/// while no server answered replayed flagged historical; the Will of the
/// killed node's session (NDEATH with that session's bdSeq) is sent by a node that
/// stays up once the dead node's heartbeat is missed.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn killing_the_aedes_cluster_node_of_the_session_loses_no_bite() {
    let setup = Setup::new(MILLGATE, "sparkplug-aedes", "db").await;
    let mut cluster = common::cluster::AedesCluster::start(&setup.scratch);
    let ports = cluster.mqtt_ports().to_vec();
    let mut host = Host::start(ports[2], "plant");
    host.command("state scada online");
    while host.next(Duration::from_secs(10))["sent"] != "state" {}
    host.seen.clear();
    // The node's server killed and the other one stopped (SIGSTOP) until the PLC has
    // seen a bite: that bite waits in the history and reaches the host replayed,
    // flagged historical. (The closures borrow the cluster: it lives to the end.)
    let nodes = &mut cluster;
    let (sessions, mut hosts) = failover_keeps_every_bite(
        setup,
        &ports[..2],
        "primary_host_id = \"scada\"",
        vec![host],
        |node| {
            nodes.kill(node);
            let other = 1 - node;
            nodes.pause(other);
            move || nodes.resume(other)
        },
    )
    .await;
    eprintln!("bites by session (id, historical): {sessions:?}");
    assert_eq!(sessions.len(), 2, "{sessions:?}");
    assert!(
        sessions[1].iter().any(|&(_, historical)| historical),
        "the bite seen during the outage replayed: {sessions:?}"
    );
    let first_bd_seq = metric(&nth_birth(&seen(&hosts), 0).unwrap(), "bdSeq")["value"]
        .as_u64()
        .unwrap();
    // The Will: sent 3-7 s after the kill (3 missed heartbeats of 1 s, checked every
    // 4 s); it carries the first session's bdSeq, so a host that saw the second
    // birth (bdSeq + 1) knows it is not the current session's death.
    let node_messages = |seen: &[Value]| -> Vec<(String, Option<u64>)> {
        seen.iter()
            .filter(|m| m["type"] == "NBIRTH" || m["type"] == "NDEATH")
            .map(|m| {
                let bd_seq = metric(m, "bdSeq")["value"].as_u64();
                (m["type"].as_str().unwrap().to_owned(), bd_seq)
            })
            .collect()
    };
    let is_will = |m: &&Value| {
        m["type"] == "NDEATH" && metric(m, "bdSeq")["value"].as_u64() == Some(first_bd_seq)
    };
    let started = Instant::now();
    while !seen(&hosts).iter().any(|m| is_will(&m)) && started.elapsed() < Duration::from_secs(30) {
        if let Ok(value) = hosts[0].lines.recv_timeout(Duration::from_millis(100)) {
            hosts[0].seen.push(value);
        }
    }
    let seen = seen(&hosts);
    eprintln!(
        "node messages at the host (type, bdSeq): {:?}",
        node_messages(&seen)
    );
    let will = seen
        .iter()
        .find(is_will)
        .unwrap_or_else(|| panic!("no Will within 30 s: {:?}", node_messages(&seen)));
    assert_eq!(will["topic"], "spBv1.0/plant/NDEATH/f1");
    // aedes keeps the topics: nothing rewritten, every message under spBv1.0/plant/.
    assert!(
        seen.iter()
            .filter(|m| m.get("type").is_some())
            .all(|m| m["rewritten"] == false
                && m["topic"].as_str().unwrap().starts_with("spBv1.0/plant/")),
        "{seen:?}"
    );
}

/// Two independent mosquittos (no bridge, nothing shared), each with its folder in
/// `setup`'s scratch folder: their ports, and the brokers (drop one to kill it).
fn two_brokers(setup: &Setup) -> ([u16; 2], Vec<Option<Broker>>) {
    let ports = [free_port(), free_port()];
    let brokers = ["first", "second"]
        .into_iter()
        .zip(ports)
        .map(|(name, port)| {
            let folder = setup.scratch.join(name);
            std::fs::create_dir_all(&folder).unwrap();
            Some(Broker::start(&folder, port))
        })
        .collect();
    (ports, brokers)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn with_two_independent_brokers_the_node_moves_to_the_other() {
    let setup = Setup::new(MILLGATE, "sparkplug-two-brokers", "db").await;
    let (ports, mut brokers) = two_brokers(&setup);
    // A host application on each broker: they share nothing.
    let hosts = vec![
        Host::start(ports[0], "plant"),
        Host::start(ports[1], "plant"),
    ];
    let (sessions, _) = failover_keeps_every_bite(setup, &ports, "", hosts, |broker| {
        brokers[broker] = None;
        || ()
    })
    .await;
    assert_eq!(
        sessions.len(),
        2,
        "one session on each broker: {sessions:?}"
    );
}

/// A reload mid-stream that gives the node another server (`brokers` changed, issue
/// 41): the node ends its session on the old one with its NDEATH, is born on the new
/// one with the next bdSeq, and every bite the PLC saw reaches a host application,
/// live or replayed flagged historical; the PLC writer and the analysis run on.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_reload_moves_the_node_to_its_new_server_and_loses_no_bite() {
    let setup = Setup::new(MILLGATE, "sparkplug-reload", "db").await;
    let (ports, _brokers) = two_brokers(&setup);
    let mut hosts = vec![
        Host::start(ports[0], "plant"),
        Host::start(ports[1], "plant"),
    ];
    let original = std::fs::read_to_string(&setup.config).unwrap();
    let mqtt = |port: u16| {
        format!(
            "\n[outputs.mqtt]\nbrokers = [\"127.0.0.1:{port}\"]\ngroup_id = \"plant\"\n\
             node_id = \"f1\"\nkeep_alive_s = 5\n"
        )
    };
    setup.append_config(&mqtt(ports[0]));
    let mut service = setup.spawn("run.log");
    let limit = Duration::from_secs(60);
    let (bd_seq, bite_alias) = first_births(&mut hosts, limit);
    let plc = setup.plc();
    plc.bites_after_now(1).await;
    let last = u64::from(plc.counter());
    read_until(&mut hosts, "the bite", limit, |seen| {
        bite_after(seen, bite_alias, last - 1)
    });

    std::fs::write(&setup.config, original + &mqtt(ports[1])).unwrap();
    hang_up(service.id());
    ended_and_born_again(&mut hosts, bd_seq, limit);
    // (With two hosts, the first saw the first session, the second the second.)
    every_bite_in_two_sessions(&mut hosts, &plc, bite_alias, limit).await;
    assert_eq!(
        setup
            .metric("millgate_config_reloads_total{outcome=\"applied\"}")
            .await,
        Some(1.0)
    );
    assert!(setup
        .log_text("run.log")
        .contains("reload: applied outputs.mqtt"));
    terminate(&mut service);
    setup.stop(service).await;
}

/// A driveline added by a reload within `outputs.driveline_slots` (issue 41): the node
/// ends its session (NDEATH) and is born again with the next bdSeq, its births now
/// with the new device's DBIRTH, which comes before any DDATA of that device; the new
/// driveline's bites follow as DDATA, and every bite of F1 the PLC saw reaches the
/// host once.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_driveline_added_by_a_reload_is_born_before_its_data() {
    let setup = Setup::new(MILLGATE, "sparkplug-added-driveline", "db").await;
    let port = free_port();
    let _broker = Broker::start(&setup.scratch, port);
    let mut hosts = vec![Host::start(port, "plant")];
    // The kit's PLC holds the first layout with a slot reserved (reload.rs says why).
    let demo = std::fs::read_to_string(&setup.config).unwrap();
    let first_layout = demo.replace("extension_blocks = true", "extension_blocks = false");
    std::fs::write(&setup.config, first_layout).unwrap();
    setup.append_config(&format!(
        "\n[outputs.mqtt]\nbroker = \"127.0.0.1:{port}\"\ngroup_id = \"plant\"\n\
         node_id = \"f1\"\nkeep_alive_s = 5\n\n[outputs]\ndriveline_slots = 2\n"
    ));
    let reserved = millgate::outputs::modbus::register_map::RegisterMap::new(
        &millgate_config::load(&setup.config).unwrap(),
    );
    let plc = common::Plc {
        plc: &setup.devices.plc,
        map: &reserved,
    };
    let mut service = setup.spawn("run.log");
    let limit = Duration::from_secs(60);
    let (bd_seq, bite_alias) = first_births(&mut hosts, limit);
    plc.bites_after_now(1).await;

    let original = std::fs::read_to_string(&setup.config).unwrap();
    let f2 = "[[drivelines]]\nname = \"F2\"\ntorque = \"spindle_top\"\n\
              bite = { threshold_knm = 20.0, pre_trigger_s = 0.1, post_trigger_s = 0.5 }\n\
              thresholds = { taf_warning = 2.2, taf_alarm = 2.6 }\n\n[outputs.plc]";
    std::fs::write(&setup.config, original.replacen("[outputs.plc]", f2, 1)).unwrap();
    hang_up(service.id());
    ended_and_born_again(&mut hosts, bd_seq, limit);
    let position = |seen: &[Value], kind: &str| {
        seen.iter()
            .position(|m| m["type"] == kind && m["device"] == "F2")
    };
    let dbirth = read_until(&mut hosts, "F2's DBIRTH", limit, |seen| {
        position(seen, "DBIRTH").map(|at| seen[at].clone())
    });
    assert_eq!(dbirth["topic"], "spBv1.0/plant/DBIRTH/f1/F2", "{dbirth}");
    let f2_bite_alias = metric(&dbirth, "bite_id")["alias"].as_u64().unwrap();
    assert_ne!(f2_bite_alias, bite_alias, "aliases are unique in the node");
    // F2's bites as DDATA, each after its DBIRTH.
    let f2_bite = read_until(&mut hosts, "F2's bite", limit, |seen| {
        seen.iter()
            .find(|m| {
                m["type"] == "DDATA"
                    && m["device"] == "F2"
                    && m["metrics"]
                        .as_array()
                        .is_some_and(|ms| ms.iter().any(|x| x["alias"] == f2_bite_alias))
            })
            .cloned()
    });
    let seen_now = seen(&hosts);
    assert!(
        position(&seen_now, "DDATA") > position(&seen_now, "DBIRTH"),
        "a DDATA of F2 before its DBIRTH"
    );
    let first_f2 = f2_bite["metrics"]
        .as_array()
        .unwrap()
        .iter()
        .find(|m| m["alias"] == f2_bite_alias)
        .unwrap();
    assert_eq!(first_f2["value"].as_u64(), Some(1), "{f2_bite}");

    every_bite_in_two_sessions(&mut hosts, &plc, bite_alias, limit).await;
    assert!(setup
        .log_text("run.log")
        .contains("reload: applied drivelines.F2"));
    terminate(&mut service);
    setup.stop(service).await;
}

/// TLS and credentials per server (issue 41): the first server of the set a mosquitto
/// over TLS with a password file (its table in `brokers` names its CA, user and
/// password file), the second a plain one without users (a `"host:port"`: the shared
/// settings, none here). The node is born over TLS with its password on the first; the
/// first is killed mid-stream and the node moves to the plain one, where it sends no
/// credentials; every bite reaches one of the hosts.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_server_of_the_set_with_its_own_tls_and_password_and_a_plain_one() {
    let setup = Setup::new(MILLGATE, "sparkplug-per-server", "db").await;
    let folder = setup.scratch.clone();
    let passwords = tls_and_passwords(&folder);
    let file = |name: &str| folder.join(name).display().to_string();
    let ports = [free_port(), free_port()];
    let secure = folder.join("secure");
    std::fs::create_dir_all(&secure).unwrap();
    let tls_broker = Broker::with_listeners(
        &secure,
        ports[0],
        &format!(
            "listener {} 127.0.0.1\ncafile {}\ncertfile {}\nkeyfile {}\n\
             allow_anonymous false\npassword_file {}\n",
            ports[0],
            file("ca.pem"),
            file("server.pem"),
            file("server.key"),
            passwords.display(),
        ),
    );
    let plain = folder.join("plain");
    std::fs::create_dir_all(&plain).unwrap();
    let plain_broker = Broker::start(&plain, ports[1]);
    let mut brokers = [Some(tls_broker), Some(plain_broker)];
    let hosts = vec![
        Host::with_options(
            ports[0],
            "plant",
            &[
                "--ca",
                &file("ca.pem"),
                "--username",
                "gw",
                "--password",
                "s3cret",
            ],
        ),
        Host::start(ports[1], "plant"),
    ];
    let servers = [
        format!(
            "{{ address = \"127.0.0.1:{}\", tls = {{ ca_file = \"{}\" }}, username = \"gw\", \
             password_file = \"{}\" }}",
            ports[0],
            file("ca.pem"),
            file("secret")
        ),
        format!("\"127.0.0.1:{}\"", ports[1]),
    ];
    let (sessions, _) = failover_through(setup, (&ports, &servers), "", hosts, |broker| {
        brokers[broker] = None;
        || ()
    })
    .await;
    // One session on each: the TLS host saw the first, the plain host the second.
    assert_eq!(sessions.len(), 2, "{sessions:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_primary_host_offline_on_one_server_sends_the_node_to_the_next() {
    let setup = Setup::new(MILLGATE, "sparkplug-host-elsewhere", "db").await;
    let (ports, _brokers) = two_brokers(&setup);
    // The primary host left the first server (its retained STATE says offline there)
    // and is online on the second.
    let mut away = Host::start(ports[0], "plant");
    let mut present = Host::start(ports[1], "plant");
    away.command("state scada offline");
    present.command("state scada online");
    for host in [&mut away, &mut present] {
        while host.next(Duration::from_secs(10))["sent"] != "state" {}
    }
    setup.append_config(&format!(
        "\n[outputs.mqtt]\nbrokers = [\"127.0.0.1:{}\", \"127.0.0.1:{}\"]\ngroup_id = \"plant\"\nnode_id = \"f1\"\nprimary_host_id = \"scada\"\n",
        ports[0], ports[1]
    ));
    let mut service = setup.spawn("run.log");
    let limit = Duration::from_secs(30);
    let nbirth = present.next_of("NBIRTH", limit);
    // The first server's session ended unborn: its bdSeq is used up, the births go
    // out with the next.
    assert_eq!(metric(&nbirth, "bdSeq")["value"].as_u64(), Some(1));
    assert!(
        setup
            .log_text("run.log")
            .contains("primary host offline on this MQTT server: moving on to the next"),
        "{}",
        setup.log_text("run.log")
    );
    let in_second = format!(
        "millgate_sparkplug_server_in_use{{server=\"127.0.0.1:{}\"}}",
        ports[1]
    );
    assert_eq!(setup.metric(&in_second).await, Some(1.0));
    assert_eq!(
        setup
            .metric("millgate_sparkplug_server_switches_total")
            .await,
        Some(1.0)
    );
    while let Ok(message) = away.lines.try_recv() {
        assert_ne!(
            message["type"], "NBIRTH",
            "no birth where the host is offline"
        );
    }
    terminate(&mut service);
    setup.stop(service).await;
}
