//! `millgate run` as systemd runs it: a start-up failure exits non-zero at once with
//! the reason; readiness (READY=1) comes once the listeners are bound and the first
//! PLC write was attempted, then watchdog pings (WATCHDOG=1) while the service makes
//! progress, and STOPPING=1 on SIGTERM; the orderly stop's final image is not a
//! fault. The service manager's side is a Unix datagram socket bound here, as
//! systemd's `NOTIFY_SOCKET`.

use std::os::unix::net::UnixDatagram;
use std::path::Path;
use std::process::{Command, Output, Stdio};

use millgate_tests::kit::{scratch, KillOnDrop};
use std::time::{Duration, Instant};

use millgate_sim::devices::demo::{demo_daq, setup};
use millgate_sim::devices::modbus_bank::ServeOptions;
use millgate_sim::devices::virtual_plc::VirtualPlc;

/// The demo configuration, its driveline model named by absolute path so the text
/// works from any folder.
fn demo_text() -> String {
    let examples = Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/examples");
    std::fs::read_to_string(examples.join("demo.toml"))
        .unwrap()
        .replace(
            DEMO_MODEL,
            &format!("model = {:?}", examples.join("table2-adjusted.toml")),
        )
}

/// The demo's driveline model line.
const DEMO_MODEL: &str = "model = \"table2-adjusted.toml\"";

/// `millgate run --config path`, waited for at most `limit`; `None` when it was still
/// running then (it is killed).
fn run_for(path: &Path, limit: Duration) -> Option<(Output, Duration)> {
    let started = Instant::now();
    let mut child = Command::new(env!("CARGO_BIN_EXE_millgate"))
        .args(["run", "--config", path.to_str().unwrap()])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    while started.elapsed() < limit {
        if child.try_wait().unwrap().is_some() {
            let took = started.elapsed();
            return Some((child.wait_with_output().unwrap(), took));
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    child.kill().unwrap();
    child.wait().unwrap();
    None
}

#[test]
fn run_exits_at_once_when_a_listener_cannot_bind() {
    // Another process holds the HMI server's port: before, `run` stayed alive with no
    // server and no error until SIGINT.
    let taken = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let port = taken.local_addr().unwrap().port();
    let scratch = scratch("run-bind");
    let dir = scratch.path();
    let path = dir.join("mill.toml");
    std::fs::write(
        &path,
        demo_text()
            .replace("127.0.0.1:5020", "127.0.0.1:1")
            .replace("127.0.0.1:5502", "127.0.0.1:1")
            .replace("127.0.0.1:5503", &format!("127.0.0.1:{port}")),
    )
    .unwrap();
    let (output, took) =
        run_for(&path, Duration::from_secs(10)).expect("run must exit, not wait for a signal");
    let logs = String::from_utf8_lossy(&output.stderr);
    assert!(!output.status.success(), "{logs}");
    assert!(
        logs.contains(&format!(
            "cannot bind the Modbus server to 127.0.0.1:{port}"
        )),
        "{logs}"
    );
    assert!(took < Duration::from_secs(5), "took {took:?}");
}

#[test]
fn run_exits_at_once_when_a_model_does_not_load() {
    let scratch = scratch("run-model");
    let dir = scratch.path();
    std::fs::write(dir.join("broken.toml"), "[[mass]]\ninertia = -3\n").unwrap();
    let path = dir.join("mill.toml");
    std::fs::write(
        &path,
        demo_text()
            .replace("127.0.0.1:5020", "127.0.0.1:1")
            .replace("127.0.0.1:5503", "127.0.0.1:0")
            .replace(
                &format!(
                    "model = {:?}",
                    Path::new(env!("CARGO_MANIFEST_DIR"))
                        .join("../config/examples/table2-adjusted.toml")
                ),
                "model = \"broken.toml\"",
            ),
    )
    .unwrap();
    let (output, took) = run_for(&path, Duration::from_secs(10)).expect("run must exit");
    let logs = String::from_utf8_lossy(&output.stderr);
    assert!(!output.status.success(), "{logs}");
    assert!(
        logs.contains("mill.toml: drivelines[0].model: ") && logs.contains("broken.toml"),
        "{logs}"
    );
    assert!(took < Duration::from_secs(5), "took {took:?}");
}

/// Datagrams received on `socket` until `until` says stop or `limit` passes.
fn receive_until(
    socket: &UnixDatagram,
    limit: Duration,
    mut until: impl FnMut(&[String]) -> bool,
) -> Vec<String> {
    let started = Instant::now();
    let mut messages = Vec::new();
    let mut buffer = [0u8; 512];
    socket
        .set_read_timeout(Some(Duration::from_millis(100)))
        .unwrap();
    while started.elapsed() < limit && !until(&messages) {
        if let Ok(len) = socket.recv(&mut buffer) {
            messages.push(String::from_utf8_lossy(&buffer[..len]).trim().to_owned());
        }
    }
    messages
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn readiness_watchdog_and_an_orderly_stop_under_a_service_manager() {
    // A live DAQ playing the demo schedule and a live PLC: the sources are ok while
    // the gateway runs, so the final image must show them ok too.
    let demo = setup(30.0, 0.0, 1).unwrap();
    let daq_listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let daq_address = daq_listener.local_addr().unwrap();
    let daq = demo_daq(&demo.config, &demo.schedule)
        .unwrap()
        .spawn(daq_listener, ServeOptions::default());
    // The demo's PLC is written the whole map, extension blocks too.
    let map = millgate::outputs::modbus::register_map::RegisterMap::new(&demo.config);
    let plc = VirtualPlc::new(usize::from(map.plc_span(true)));
    let plc_listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let plc_address = plc_listener.local_addr().unwrap();
    let running_plc = plc.spawn(plc_listener, ServeOptions::default());

    let scratch = scratch("run-notify");
    let dir = scratch.path();
    let path = dir.join("mill.toml");
    std::fs::write(
        &path,
        demo_text()
            .replace("127.0.0.1:5020", &daq_address.to_string())
            .replace("127.0.0.1:5502", &plc_address.to_string())
            .replace("127.0.0.1:5503", "127.0.0.1:0"),
    )
    .unwrap();
    let socket_path = dir.join("notify.sock");
    let socket = UnixDatagram::bind(&socket_path).unwrap();
    // Killed when a failing check ends the test early.
    let mut child = KillOnDrop(
        Command::new(env!("CARGO_BIN_EXE_millgate"))
            .args(["run", "--config", path.to_str().unwrap()])
            .env("NOTIFY_SOCKET", &socket_path)
            // 1 s: four PLC write periods of 100 ms fit; pings every 250 ms.
            .env("WATCHDOG_USEC", "1000000")
            .stderr(Stdio::piped())
            .spawn()
            .unwrap(),
    );

    let (socket, messages) = tokio::task::spawn_blocking(move || {
        let messages = receive_until(&socket, Duration::from_secs(15), |messages| {
            messages.iter().filter(|m| *m == "WATCHDOG=1").count() >= 4
        });
        (socket, messages)
    })
    .await
    .unwrap();
    assert_eq!(
        messages.first().map(String::as_str),
        Some("READY=1"),
        "{messages:?}"
    );
    let pings = messages.iter().filter(|m| *m == "WATCHDOG=1").count();
    assert!(pings >= 4, "{messages:?}");
    // Ready means the first PLC write was attempted: it went through.
    assert!(plc.writes() > 0, "READY before the first PLC write");

    // Let the readers see the DAQ, then stop as systemd does.
    let running = Instant::now();
    while plc.holding()[2] & 1 == 0 {
        assert!(running.elapsed() < Duration::from_secs(10), "DAQ never ok");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    let before_stop = plc.holding();
    assert_eq!(before_stop[1], 0b001, "running, sources ok");
    let killed = Command::new("kill")
        .args(["-TERM", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(killed.success());
    let stopping = tokio::task::spawn_blocking(move || {
        receive_until(&socket, Duration::from_secs(10), |messages| {
            messages.iter().any(|m| m == "STOPPING=1")
        })
    })
    .await
    .unwrap();
    assert!(stopping.iter().any(|m| m == "STOPPING=1"), "{stopping:?}");
    let output = tokio::task::spawn_blocking(move || child.wait_with_output())
        .await
        .unwrap()
        .unwrap();
    let logs = String::from_utf8_lossy(&output.stderr);
    assert!(output.status.success(), "exit {:?}: {logs}", output.status);

    // The final image: stopped, not running, no source problem, the DAQ still ok,
    // nothing stale or lost, no driveline flagged stale.
    let after = plc.holding();
    assert_eq!(after[1], 0b010, "gateway_status: stopped only; {logs}");
    assert_eq!(after[2] & 1, 1, "sources_ok: the DAQ as it was");
    assert_eq!((after[3], after[4]), (0, 0), "nothing stale or lost");
    assert_eq!(after[16] & 0b100, 0, "F1 flags: no source stale");
    running_plc.stop().await.unwrap();
    daq.stop().await.unwrap();
}
