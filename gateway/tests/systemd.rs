//! The shipped unit under a real systemd: `deploy/millgate.service` and its drop-ins
//! (`deploy/millgate.service.d/`), installed as the README says, in a User-Mode Linux
//! guest whose PID 1 is systemd. `scripts/uml-systemd` boots the guest (its root is the
//! host's files under a copy-on-write overlay, so `/etc`, `/usr/local/bin` and `/var`
//! are written only in the guest) and runs this test there as root.
//!
//! The gateway runs the README's full setup between the demo's virtual DAQ and PLC
//! (served by this process): the history in `$STATE_DIRECTORY` (`path = "history.db"`),
//! the gap-map cache in `$CACHE_DIRECTORY`, Sparkplug B to Debian's mosquitto (its own
//! unit, passwords required) with the password from `LoadCredential=`
//! (`mqtt-password.conf`), the web page, `/metrics`, the HMI server and a CAN source on
//! `vcan0`. Checked:
//!
//! - `systemctl enable --now` returns once READY=1 came (`Type=notify`): active, run by
//!   a dynamic user in a private user namespace without capabilities, with a seccomp
//!   filter and no new privileges; `ExecStartPre=millgate check` saw the service
//!   folders;
//! - the history file appears in /var/lib/millgate, the gap maps in /var/cache/millgate,
//!   the HMI server and the page answer, CAN frames from `cansend` are decoded, a host
//!   sees the node's NBIRTH (the broker refuses clients without a password);
//! - `kill -9` of the main process: systemd restarts it; the gap maps come from the
//!   cache, the bite counter goes on from where the PLC saw it, the next NBIRTH's bdSeq
//!   is one more (kept in the history);
//! - with `modbus-port-502.conf` and the HMI server moved to port 502, `systemctl
//!   restart`: it answers on 502, CAP_NET_BIND_SERVICE its only capability;
//! - `systemctl stop`: a clean stop (result "success"), the runs in the history ended
//!   "unclean" (the killed one), "stopped" (the one restarted for port 502) and
//!   "stopped", and every bite the PLC counted is in the file once, counters 1..=N
//!   without a gap (read with Debian's `sqlite3`);
//! - `systemd-analyze security` rates the installed unit "OK": at most 1.3 with the
//!   credential drop-in, 1.6 with the port 502 one too.
//!
//! Outside that guest (no `MILLGATE_SYSTEMD_SUITE=1`) the test says it is skipped.

mod common;

use std::collections::HashMap;
use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use common::{http, repo, web_ready, Plc};
use millgate::outputs::modbus::register_map::RegisterMap;
use millgate::outputs::sparkplug::payload::{MetricValue, Payload};
use millgate_sim::devices::demo::{setup, DemoDevices};
use prost::Message as _;
use rumqttc::{AsyncClient, Event, MqttOptions, Packet, QoS};
use tokio::process::Command;

/// The MQTT password the unit hands over as the credential `mqtt`.
const GATEWAY_PASSWORD: &str = "gateway-secret";
/// The subscribing host's account on the broker.
const HOST_USER: (&str, &str) = ("host", "host-secret");
/// Exposure `systemd-analyze security` gives the installed unit (measured; README,
/// "Running under systemd"): with the credential drop-in, and with both drop-ins.
const MAX_EXPOSURE: [f64; 2] = [1.3, 1.6];
/// The HMI server's port before and after the port 502 drop-in.
const HMI_PORTS: [u16; 2] = [5503, 502];

/// Runs `program` with `args`; its standard output, or a panic with what it said.
async fn run(program: &str, args: &[&str]) -> String {
    let output = Command::new(program)
        .args(args)
        .output()
        .await
        .unwrap_or_else(|error| panic!("{program}: {error}"));
    assert!(
        output.status.success(),
        "{program} {args:?}: {}\n{}{}",
        output.status,
        String::from_utf8_lossy(&output.stdout),
        String::from_utf8_lossy(&output.stderr)
    );
    String::from_utf8_lossy(&output.stdout).into_owned()
}

/// `systemctl show millgate` of `properties`, by name.
async fn unit_state(properties: &[&str]) -> HashMap<String, String> {
    let mut args = vec!["show", "millgate.service"];
    for property in properties {
        args.extend(["-p", property]);
    }
    run("systemctl", &args)
        .await
        .lines()
        .filter_map(|line| line.split_once('='))
        .map(|(key, value)| (key.to_owned(), value.to_owned()))
        .collect()
}

/// Polls `done` every 200 ms (each poll may start a process), at most `limit`.
async fn wait_for<F: std::future::Future<Output = bool>>(
    what: &str,
    limit: Duration,
    mut done: impl FnMut() -> F,
) {
    let start = Instant::now();
    while !done().await {
        if start.elapsed() > limit {
            let journal = run(
                "journalctl",
                &["-u", "millgate.service", "-o", "cat", "-n", "60"],
            );
            panic!(
                "{what}: not within {limit:?}; the unit's journal:\n{}",
                journal.await
            );
        }
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
}

/// The unit's journal, messages only.
async fn journal() -> String {
    run("journalctl", &["--sync"]).await;
    run("journalctl", &["-u", "millgate.service", "-o", "cat"]).await
}

/// The value of the first `/metrics` sample whose name starts with `prefix` and has
/// `part` in it, with `label`.
async fn metric(prefix: &str, part: &str, label: &str) -> Option<f64> {
    let page = http(9187, "GET", "/metrics").await.body;
    page.lines()
        .filter(|line| !line.starts_with('#') && line.contains(label))
        .filter(|line| {
            let name = line.split('{').next().unwrap_or_default();
            name.starts_with(prefix) && name.contains(part)
        })
        .find_map(|line| line.rsplit_once(' ')?.1.parse().ok())
}

/// `/proc/<pid>/status` field `name`.
fn status_field(pid: &str, name: &str) -> String {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap();
    status
        .lines()
        .find_map(|line| line.strip_prefix(name)?.strip_prefix(':'))
        .unwrap_or_else(|| panic!("no {name} in /proc/{pid}/status"))
        .trim()
        .to_owned()
}

/// The NBIRTHs a host subscribed to `spBv1.0/plant/#` has seen: their bdSeq.
type Births = Arc<Mutex<Vec<u64>>>;

/// A Sparkplug host on the broker, with its own account; records every NBIRTH's bdSeq.
async fn sparkplug_host() -> Births {
    let births = Births::default();
    let mut options = MqttOptions::new("suite-host", "localhost", 1883);
    options.set_credentials(HOST_USER.0, HOST_USER.1);
    options.set_max_packet_size(1 << 20, 1 << 20);
    let (client, mut events) = AsyncClient::new(options, 256);
    client
        .subscribe("spBv1.0/plant/#", QoS::AtLeastOnce)
        .await
        .unwrap();
    let seen = Arc::clone(&births);
    tokio::spawn(async move {
        let _client = client;
        loop {
            match events.poll().await {
                Ok(Event::Incoming(Packet::Publish(message)))
                    if message.topic == "spBv1.0/plant/NBIRTH/f1" =>
                {
                    let payload = Payload::decode(message.payload).expect("a Sparkplug payload");
                    let bd_seq = payload
                        .metrics
                        .iter()
                        .find(|metric| metric.name.as_deref() == Some("bdSeq"))
                        .and_then(|metric| match metric.value {
                            Some(MetricValue::LongValue(value)) => Some(value),
                            _ => None,
                        })
                        .expect("NBIRTH has bdSeq");
                    seen.lock().unwrap().push(bd_seq);
                }
                Ok(_) => {}
                Err(_) => tokio::time::sleep(Duration::from_millis(200)).await,
            }
        }
    });
    births
}

/// Debian's mosquitto under its own unit, on port 1883 of every address, with
/// passwords required: the gateway's account and the host's.
async fn start_broker() {
    let passwords = "/etc/mosquitto/millgate-suite.passwd";
    run(
        "mosquitto_passwd",
        &["-b", "-c", passwords, "millgate", GATEWAY_PASSWORD],
    )
    .await;
    run(
        "mosquitto_passwd",
        &["-b", passwords, HOST_USER.0, HOST_USER.1],
    )
    .await;
    run("chown", &["root:mosquitto", passwords]).await;
    run("chmod", &["640", passwords]).await;
    std::fs::write(
        "/etc/mosquitto/conf.d/millgate-suite.conf",
        format!("listener 1883\nallow_anonymous false\npassword_file {passwords}\n"),
    )
    .unwrap();
    run("systemctl", &["start", "mosquitto.service"]).await;
}

/// The gateway's configuration: the demo's (driveline model, PLC, HMI server on 5503)
/// with the devices' addresses, a CAN source on vcan0, the history by a relative path,
/// Sparkplug with the password credential, `/metrics` and the page.
fn configuration(daq: &str, plc: &str) -> String {
    let demo = std::fs::read_to_string(repo().join("config/examples/demo.toml")).unwrap();
    for address in ["127.0.0.1:5020", "127.0.0.1:5502", "127.0.0.1:5503"] {
        assert!(demo.contains(address), "demo.toml changed: no {address}");
    }
    demo.replace("127.0.0.1:5020", daq)
        .replace("127.0.0.1:5502", plc)
        + r#"
[[sources.can]]
name = "stand_can"
interface = "vcan0"
dbc = "mill.dbc"

[[channels]]
name = "f1_gearbox_oil"
kind = "process_value"
unit = "degC"
sample_rate_hz = 1.0
source = { can = "stand_can", message = "GearboxTemp", signal = "OilTemp" }

[outputs.metrics]
bind = "127.0.0.1:9187"

[outputs.web]
bind = "127.0.0.1:8080"

[outputs.mqtt]
broker = "localhost:1883"
group_id = "plant"
node_id = "f1"
username = "millgate"
password_credential = "mqtt"

[history]
path = "history.db"
"#
}

/// `install` of the repository file `relative` with `mode` to `target`.
async fn install(mode: &str, relative: &str, target: &str) {
    let source = repo().join(relative);
    run(
        "install",
        &["-D", "-m", mode, source.to_str().unwrap(), target],
    )
    .await;
}

/// Installs the binary, the configuration with its model and DBC, the credential, the
/// unit and its credential drop-in as the README says, and starts it (`enable --now`).
async fn install_and_start(config: &str) {
    let millgate = env!("CARGO_BIN_EXE_millgate");
    run(
        "install",
        &["-m", "755", millgate, "/usr/local/bin/millgate"],
    )
    .await;
    run("install", &["-d", "/etc/millgate"]).await;
    std::fs::write("/etc/millgate/mill.toml", config).unwrap();
    install(
        "644",
        "sim/models/table2-adjusted.toml",
        "/etc/millgate/table2-adjusted.toml",
    )
    .await;
    install("644", "config/examples/mill.dbc", "/etc/millgate/mill.dbc").await;
    std::fs::write("/tmp/mqtt-password", format!("{GATEWAY_PASSWORD}\n")).unwrap();
    run(
        "install",
        &[
            "-m",
            "600",
            "/tmp/mqtt-password",
            "/etc/millgate/mqtt-password",
        ],
    )
    .await;
    std::fs::remove_file("/tmp/mqtt-password").unwrap();
    install(
        "644",
        "deploy/millgate.service",
        "/etc/systemd/system/millgate.service",
    )
    .await;
    install(
        "644",
        "deploy/millgate.service.d/mqtt-password.conf",
        "/etc/systemd/system/millgate.service.d/mqtt-password.conf",
    )
    .await;
    run("systemctl", &["daemon-reload"]).await;
    run("systemctl", &["enable", "--now", "millgate"]).await;
}

/// The `bite_counter` of every bite in the history, in file order; and the runs' ends.
async fn history_rows() -> (Vec<u32>, Vec<String>) {
    let db = "/var/lib/millgate/history.db";
    let counters = run(
        "sqlite3",
        &[
            "-readonly",
            db,
            "SELECT bite_counter FROM bites WHERE driveline = 'F1' ORDER BY id",
        ],
    )
    .await
    .lines()
    .map(|line| line.parse().expect("a counter"))
    .collect();
    let runs = run(
        "sqlite3",
        &[
            "-readonly",
            db,
            "SELECT coalesce(ended, 'running') FROM gateway_runs ORDER BY id",
        ],
    )
    .await
    .lines()
    .map(str::to_owned)
    .collect();
    (counters, runs)
}

/// `systemd-analyze security millgate.service`: the overall exposure is "OK" and at
/// most `most`.
async fn assert_rating(most: f64) {
    let rating = run(
        "systemd-analyze",
        &["security", "--no-pager", "millgate.service"],
    )
    .await;
    let overall = rating
        .lines()
        .find_map(|line| line.split_once("Overall exposure level for millgate.service: "))
        .map(|(_, level)| level.to_owned())
        .unwrap_or_else(|| panic!("no overall level in:\n{rating}"));
    println!("systemd-analyze security millgate.service: {overall}");
    let exposure: f64 = overall.split_whitespace().next().unwrap().parse().unwrap();
    assert!(
        overall.contains(" OK") && exposure <= most,
        "exposure {overall}, allowed up to {most} OK"
    );
}

/// The HMI server on `port` answers a read of the map's first registers.
async fn hmi_answers(port: u16) {
    let address = std::net::SocketAddr::from(([127, 0, 0, 1], port));
    let mut hmi = tokio_modbus::client::tcp::connect(address)
        .await
        .unwrap_or_else(|error| panic!("the HMI server on port {port}: {error}"));
    let registers = tokio_modbus::client::Reader::read_holding_registers(&mut hmi, 0, 8)
        .await
        .expect("a Modbus answer")
        .expect("no exception");
    assert_eq!(registers.len(), 8);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[ignore = "needs systemd as PID 1 and root: run scripts/uml-systemd"]
async fn the_shipped_unit_runs_the_full_setup_under_systemd() {
    if std::env::var_os("MILLGATE_SYSTEMD_SUITE").is_none() {
        println!("skipped: not in the systemd suite's guest (run scripts/uml-systemd)");
        return;
    }
    assert!(
        Path::new("/run/systemd/system").is_dir(),
        "systemd is not PID 1"
    );
    let started = Instant::now();
    let step = |what: &str| println!("[{:6.1} s] {what}", started.elapsed().as_secs_f64());

    // The field: the demo's DAQ and PLC, here; the broker under its unit; a host.
    let demo = setup(600.0, 0.5, 3).unwrap();
    let mut config = demo.config;
    let map = RegisterMap::new(&config);
    let devices = DemoDevices::start(&mut config, &demo.schedule, usize::from(map.len()) + 16)
        .await
        .unwrap();
    let plc = Plc {
        plc: &devices.plc,
        map: &map,
    };
    start_broker().await;
    let births = sparkplug_host().await;
    step("devices, broker and host up");

    // Installed as the README says; `enable --now` returns after READY=1.
    let plc_address = config.outputs.plc.as_ref().unwrap().address.clone();
    install_and_start(&configuration(
        &config.modbus_sources[0].address,
        &plc_address,
    ))
    .await;
    step("systemctl enable --now returned");
    // How the start went, for the record (a debug build on the guest's one CPU).
    run("journalctl", &["--sync"]).await;
    let start_log = run(
        "journalctl",
        &[
            "-u",
            "millgate.service",
            "-o",
            "short-monotonic",
            "--no-pager",
        ],
    )
    .await;
    for line in start_log.lines().filter(|line| {
        ["Starting", ": OK", "history open", "ready", "Started"]
            .iter()
            .any(|mark| line.contains(mark))
    }) {
        println!("  {line}");
    }
    let state = unit_state(&["ActiveState", "SubState", "MainPID"]).await;
    assert_eq!(
        (state["ActiveState"].as_str(), state["SubState"].as_str()),
        ("active", "running"),
        "{state:?}"
    );
    let first_pid = state["MainPID"].clone();
    assert_ne!(
        status_field(&first_pid, "Uid").split_whitespace().next(),
        Some("0")
    );
    assert_eq!(status_field(&first_pid, "CapEff"), "0000000000000000");
    assert_eq!(status_field(&first_pid, "NoNewPrivs"), "1");
    assert_eq!(status_field(&first_pid, "Seccomp"), "2", "a seccomp filter");
    let uid_map = std::fs::read_to_string(format!("/proc/{first_pid}/uid_map")).unwrap();
    assert!(
        !uid_map.contains("4294967295"),
        "a private user namespace maps a few users, not all: {uid_map}"
    );
    let log = journal().await;
    assert!(
        log.contains("/etc/millgate/mill.toml: OK")
            && log.contains("History: /var/lib/millgate/history.db")
            && log.contains("Cache: /var/cache/millgate"),
        "ExecStartPre=millgate check saw the service folders:\n{log}"
    );

    // What the full setup serves.
    assert!(Path::new("/var/lib/millgate/history.db").is_file());
    hmi_answers(HMI_PORTS[0]).await;
    web_ready(8080).await;
    assert_eq!(http(8080, "GET", "/").await.status, 200);
    // Gearbox oil at 60 degC: OilTemp raw 1000 (0.1 degC per count, -40 offset).
    for _ in 0..5 {
        run(
            &std::env::var("MILLGATE_CANSEND").unwrap_or_else(|_| "cansend".into()),
            &["vcan0", "18FF5A01#E803E80300000000"],
        )
        .await;
    }
    wait_for(
        "the CAN frames decoded",
        Duration::from_secs(20),
        || async {
            metric("millgate_can_", "decoded", "source=\"stand_can\"")
                .await
                .is_some_and(|frames| frames >= 5.0)
        },
    )
    .await;
    wait_for(
        "the host sees an NBIRTH",
        Duration::from_secs(30),
        || async { !births.lock().unwrap().is_empty() },
    )
    .await;
    step("history, HMI server, page, CAN and Sparkplug up");
    assert_rating(MAX_EXPOSURE[0]).await;
    wait_for(
        "the gap maps in /var/cache/millgate",
        Duration::from_secs(240),
        || async { journal().await.contains("origin=Built") },
    )
    .await;
    let log = journal().await;
    assert!(
        log.contains("saved: Some(\"/var/cache/millgate/gap-maps-"),
        "the maps cached in $CACHE_DIRECTORY:\n{log}"
    );
    step("gap maps built and cached");

    // kill -9: systemd restarts it; nothing the PLC saw is lost.
    wait_for("2 bites in the PLC", Duration::from_secs(60), || async {
        plc.counter() >= 2
    })
    .await;
    run("kill", &["-KILL", &first_pid]).await;
    let seen_before_kill = plc.counter();
    step(&format!(
        "killed {first_pid} after {seen_before_kill} bites"
    ));
    wait_for("systemd restarts it", Duration::from_secs(60), || async {
        let state = unit_state(&["ActiveState", "SubState", "MainPID", "NRestarts"]).await;
        state["NRestarts"] == "1"
            && state["ActiveState"] == "active"
            && state["SubState"] == "running"
            && state["MainPID"] != first_pid
    })
    .await;
    step("restarted");
    wait_for(
        "2 bites after the restart",
        Duration::from_secs(60),
        || async { plc.counter() >= seen_before_kill + 2 },
    )
    .await;
    wait_for("the second NBIRTH", Duration::from_secs(30), || async {
        births.lock().unwrap().len() >= 2
    })
    .await;
    let bd_seqs = births.lock().unwrap().clone();
    assert_eq!(
        bd_seqs[1],
        bd_seqs[0] + 1,
        "bdSeq from the history: {bd_seqs:?}"
    );
    wait_for(
        "the gap maps from the cache",
        Duration::from_secs(60),
        || async {
            journal()
                .await
                .contains("origin=Cache(\"/var/cache/millgate/gap-maps-")
        },
    )
    .await;
    step("counter, bdSeq and gap maps continue");

    // Port 502: the drop-in, the configuration moved, a restart (a clean stop first).
    install(
        "644",
        "deploy/millgate.service.d/modbus-port-502.conf",
        "/etc/systemd/system/millgate.service.d/modbus-port-502.conf",
    )
    .await;
    let text = std::fs::read_to_string("/etc/millgate/mill.toml").unwrap();
    let moved = text.replace(
        &format!("127.0.0.1:{}", HMI_PORTS[0]),
        &format!("127.0.0.1:{}", HMI_PORTS[1]),
    );
    assert_ne!(text, moved, "the HMI server's bind in the configuration");
    std::fs::write("/etc/millgate/mill.toml", moved).unwrap();
    run("systemctl", &["daemon-reload"]).await;
    run("systemctl", &["restart", "millgate"]).await;
    let pid = unit_state(&["MainPID"]).await["MainPID"].clone();
    assert_eq!(
        status_field(&pid, "CapEff"),
        "0000000000000400",
        "CAP_NET_BIND_SERVICE only"
    );
    hmi_answers(HMI_PORTS[1]).await;
    let seen_before_restart = plc.counter();
    wait_for(
        "a bite after the restart on port 502",
        Duration::from_secs(60),
        || async { plc.counter() > seen_before_restart },
    )
    .await;
    step("restarted with the HMI server on port 502");
    assert_rating(MAX_EXPOSURE[1]).await;

    // A clean stop.
    run("systemctl", &["stop", "millgate"]).await;
    let state = unit_state(&["ActiveState", "Result"]).await;
    assert_eq!(
        (state["ActiveState"].as_str(), state["Result"].as_str()),
        ("inactive", "success"),
        "{state:?}"
    );
    let in_plc = plc.counter();
    let (counters, runs) = history_rows().await;
    assert_eq!(
        counters,
        (1..=in_plc).collect::<Vec<_>>(),
        "every bite the PLC counted ({in_plc}) in the file, once, without a gap"
    );
    assert_eq!(
        runs,
        ["unclean", "stopped", "stopped"],
        "the killed run, the one restarted for port 502, the stopped one"
    );
    step(&format!(
        "stopped cleanly; {in_plc} bites in the PLC and the file"
    ));

    run("systemctl", &["stop", "mosquitto.service"]).await;
    devices.stop().await.unwrap();
}
