//! The OPC UA server against clients that are not ours: Python asyncua 2.1.0
//! (`opcua_client.py`) and, for Alarms & Conditions, node-opcua 2.180.0
//! (`opcua_node_client.mjs`), with the gateway between the demo's virtual DAQ and PLC.
//! Checked: the address space (objects, keys, data types, EUInformation by UNECE code,
//! EURange) and every value against the PLC's registers of the same run; a
//! subscription receiving a bite; alarm events, the acknowledge method and its guard;
//! Bad and Uncertain statuses while the DAQ is gone; certificates (an untrusted one
//! refused and kept in `rejected/`, then trusted) and passwords; hostile streams,
//! counted, while the service and the PLC writes go on.
//!
//! Needs `pip install asyncua==2.1.0` and `npm ci --prefix tests/peers` (scripts/test
//! installs both) and the `opcua` feature: `cargo test -p millgate --features opcua
//! --test opcua`.

mod common;

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::ChildStdin;
use std::sync::mpsc::{Receiver, RecvTimeoutError};
use std::time::{Duration, Instant};

use millgate::outputs::modbus::register_map::{decode_f32, decode_u32, RegisterMap};
use millgate::service::RunningService;
use millgate::state::catalogue::{self, FigureType, Guard, Register};
use millgate_config::{
    Config, IdentificationField, IdentificationValue, MetricsOutput, OpcUaOutput,
    OpcUaSecurityMode, OpcUaUser,
};
use millgate_sim::devices::demo::{demo_daq, setup, SAMPLES_PER_BLOCK};
use millgate_sim::devices::modbus_bank::{Running, ServeOptions};
use millgate_sim::devices::virtual_plc::VirtualPlc;
use serde_json::Value;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};

/// The Python client: its JSON lines, its stdin for commands; killed on drop.
struct Peer {
    _child: common::KillOnDrop,
    stdin: ChildStdin,
    lines: Receiver<Value>,
}

impl Peer {
    /// Connect to `url` with `options` of opcua_client.py: `Ok` once the session is
    /// up, `Err` with the client's `refused` line.
    fn connect(url: &str, options: &[&str]) -> Result<Self, Value> {
        Self::connect_with("opcua_client.py", url, options)
    }

    /// Connect with node-opcua (`opcua_node_client.mjs`), security none, anonymous.
    fn node_opcua(url: &str) -> Result<Self, Value> {
        Self::connect_with("opcua_node_client.mjs", url, &[])
    }

    fn connect_with(script: &str, url: &str, options: &[&str]) -> Result<Self, Value> {
        let args = [&[url], options].concat();
        let (child, stdin, lines) = common::json_peer(&common::peer(script), &args);
        let mut peer = Self {
            _child: child,
            stdin,
            lines,
        };
        let first = peer.next(Duration::from_secs(60));
        match first["type"].as_str() {
            Some("ready") => Ok(peer),
            Some("refused") => Err(first),
            _ => panic!("unexpected first line {first}"),
        }
    }

    fn next(&mut self, limit: Duration) -> Value {
        match self.lines.recv_timeout(limit) {
            Ok(value) => value,
            Err(RecvTimeoutError::Timeout) => panic!("no line from the client within {limit:?}"),
            Err(RecvTimeoutError::Disconnected) => panic!("the client script ended"),
        }
    }

    /// The next line of `kind`; the lines of other kinds are skipped (and named in
    /// the panic when none comes in time).
    fn next_of(&mut self, kind: &str, limit: Duration) -> Value {
        let start = Instant::now();
        let mut skipped = Vec::new();
        loop {
            let left = limit.saturating_sub(start.elapsed());
            let line = match self.lines.recv_timeout(left.max(Duration::from_millis(1))) {
                Ok(line) => line,
                Err(error) => {
                    panic!("no {kind} line within {limit:?} ({error}); skipped: {skipped:#?}")
                }
            };
            assert_ne!(line["type"], "error", "{line}");
            if line["type"] == kind {
                return line;
            }
            skipped.push(line);
        }
    }

    fn send(&mut self, command: &str) {
        writeln!(self.stdin, "{command}").unwrap();
        self.stdin.flush().unwrap();
    }

    fn ask(&mut self, command: &str, answer: &str) -> Value {
        self.send(command);
        self.next_of(answer, Duration::from_secs(60))
    }
}

/// The gateway between the demo's virtual DAQ (its own task, so it can be stopped) and
/// PLC, with `[outputs.opcua]`.
struct Rig {
    scratch: PathBuf,
    _folder: common::TempDir,
    daq: Option<Running>,
    plc: VirtualPlc,
    plc_running: Running,
    gateway: RunningService,
    map: RegisterMap,
    bites: usize,
    /// The DAQ blocks of the schedule (it plays from the gateway's first read).
    schedule_blocks: u64,
    /// The driveline's torque channel.
    torque: usize,
    url: String,
}

impl Rig {
    /// A schedule of `duration_s` seconds of bars; `edit` changes the configuration
    /// (`outputs.opcua` is set on a free loopback port with its pki in the scratch
    /// folder first).
    async fn start(tag: &str, duration_s: f64, edit: impl FnOnce(&mut Config, &Path)) -> Self {
        let folder = common::scratch(&format!("opcua-{tag}"));
        let scratch = folder.path().to_path_buf();
        let _ = tracing_subscriber::fmt()
            .with_env_filter(tracing_subscriber::EnvFilter::from_default_env())
            .with_test_writer()
            .try_init();
        let demo = setup(duration_s, 0.5, 5).unwrap();
        let mut config = demo.config;
        config.outputs.server = None;
        config.outputs.web = None;
        let pki = scratch.join("pki");
        copy_pki(&pki);
        config.outputs.opcua = Some(OpcUaOutput::on("127.0.0.1:0".parse().unwrap(), pki));
        edit(&mut config, &scratch);
        let map = RegisterMap::new(&config);
        // The schedule from its first block whenever the gateway starts reading.
        let daq = demo_daq(&config, &demo.schedule)
            .unwrap()
            .playing_from_first_read();
        let plc = VirtualPlc::new(usize::from(map.len()) + 16);
        let daq_listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
        let plc_listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
        config.modbus_sources[0].address = daq_listener.local_addr().unwrap().to_string();
        config.outputs.plc.as_mut().unwrap().address =
            plc_listener.local_addr().unwrap().to_string();
        let daq = daq.spawn(daq_listener, ServeOptions::default());
        let plc_running = plc.spawn(plc_listener, ServeOptions::default());
        let settings = config.outputs.opcua.clone().unwrap();
        let torque = config.drivelines[0].torque;
        let mut gateway = millgate::Service::new(config)
            .unwrap()
            .spawn()
            .await
            .unwrap();
        gateway.ready().await.unwrap();
        let bound = gateway.bound().opcua.expect("the OPC UA server is bound");
        let url = format!("opc.tcp://{}:{}/", settings.host, bound.port());
        serving(bound, &url).await;
        Self {
            scratch,
            _folder: folder,
            daq: Some(daq),
            plc,
            plc_running,
            gateway,
            map,
            bites: demo.schedule.bites.len(),
            schedule_blocks: demo
                .schedule
                .torque_knm
                .len()
                .div_ceil(usize::from(SAMPLES_PER_BLOCK)) as u64,
            torque,
            url,
        }
    }

    fn register(&self, name: &str) -> usize {
        let register = self.map.registers().iter().find(|r| r.name == name);
        usize::from(
            register
                .unwrap_or_else(|| panic!("no register {name}"))
                .address,
        )
    }

    fn u32_at(&self, words: &[u16], name: &str) -> u32 {
        decode_u32(&words[self.register(name)..]).unwrap()
    }

    fn f32_at(&self, words: &[u16], name: &str) -> f32 {
        decode_f32(&words[self.register(name)..]).unwrap()
    }

    fn bite_counter(&self) -> u32 {
        self.u32_at(&self.plc.holding(), "F1.bite_counter")
    }

    /// Wait until the PLC shows every bite of the schedule and then no more for a
    /// second: the values hold still. The DAQ plays the schedule from the gateway's
    /// first read, so every bite comes unless a loaded machine made the gateway miss a
    /// DAQ block (a bite window with a gap, or a trigger just after one, is not
    /// analysed): only when the gateway counted blocks missed (or a sequence restart)
    /// does it count as done once the reader is past the schedule's last block and 2 s
    /// passed without another bite; the test is told how many blocks were missed
    /// (0: every bite reached the PLC).
    async fn wait_schedule_done(&self) -> u64 {
        let start = Instant::now();
        let mut last = (self.bite_counter(), Instant::now());
        loop {
            let now = self.bite_counter();
            if now != last.0 {
                last = (now, Instant::now());
            }
            let still = last.1.elapsed();
            if now as usize >= self.bites && still > Duration::from_secs(1) {
                return 0;
            }
            let torque = self.gateway.counters()[self.torque].snapshot();
            let missed = torque.blocks_missed + torque.sequence_restarts;
            if missed > 0
                && torque.blocks_read + torque.blocks_missed > self.schedule_blocks
                && still > Duration::from_secs(2)
            {
                println!(
                    "the gateway missed {} DAQ blocks ({} sequence restarts): {now} of the \
                     schedule's {} bites reached the PLC",
                    torque.blocks_missed, torque.sequence_restarts, self.bites
                );
                return missed;
            }
            assert!(
                start.elapsed() < Duration::from_secs(90),
                "the schedule's {} bites did not reach the PLC (it shows {now}; the torque's \
                 counters {torque:?})",
                self.bites
            );
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    }

    async fn stop(mut self) {
        tokio::time::timeout(Duration::from_secs(20), self.gateway.stop())
            .await
            .expect("the gateway stops")
            .unwrap();
        if let Some(daq) = self.daq.take() {
            daq.stop().await.unwrap();
        }
        self.plc_running.stop().await.unwrap();
    }
}

/// The `/metrics` page at `address`.
async fn metrics_page(address: std::net::SocketAddr) -> String {
    let mut stream = TcpStream::connect(address).await.unwrap();
    stream
        .write_all(b"GET /metrics HTTP/1.0\r\nHost: localhost\r\n\r\n")
        .await
        .unwrap();
    let mut page = String::new();
    stream.read_to_string(&mut page).await.unwrap();
    page
}

/// A Hello to `url` at `address`.
fn hello(url: &str) -> Vec<u8> {
    let mut body = Vec::new();
    for word in [0u32, 65_535, 65_535, 0, 0] {
        body.extend_from_slice(&word.to_le_bytes());
    }
    body.extend_from_slice(&(url.len() as u32).to_le_bytes());
    body.extend_from_slice(url.as_bytes());
    let mut message = b"HELF".to_vec();
    message.extend_from_slice(&(8 + body.len() as u32).to_le_bytes());
    message.extend_from_slice(&body);
    message
}

/// Wait until the server at `address` answers a Hello (it makes its certificate
/// first, at its first start), at most 60 s.
async fn serving(address: std::net::SocketAddr, url: &str) {
    let start = Instant::now();
    let mut stream = TcpStream::connect(address).await.unwrap();
    stream.write_all(&hello(url)).await.unwrap();
    let mut answer = [0u8; 4];
    tokio::time::timeout(Duration::from_secs(60), stream.read_exact(&mut answer))
        .await
        .expect("the OPC UA server answers within 60 s")
        .unwrap();
    assert_eq!(&answer, b"ACKF", "after {:?}", start.elapsed());
}

/// Where the server certificate made once per test process (an RSA key takes seconds
/// in a debug build) is kept for the next servers: a scratch folder that a static
/// holds, so it is left for the system's temporary-folder cleaning.
fn made_pki() -> &'static Path {
    static MADE: std::sync::OnceLock<common::TempDir> = std::sync::OnceLock::new();
    MADE.get_or_init(|| common::scratch("opcua-pki")).path()
}

/// A certificate store with the server's certificate (once made) copied for a server.
fn copy_pki(to: &Path) {
    let made = made_pki();
    for sub in ["own", "private", "trusted", "rejected"] {
        std::fs::create_dir_all(to.join(sub)).unwrap();
        if let Ok(files) = std::fs::read_dir(made.join(sub)) {
            for file in files.flatten() {
                std::fs::copy(file.path(), to.join(sub).join(file.file_name())).unwrap();
            }
        }
    }
}

/// Keep the server certificate a test's server made for the next servers.
fn keep_pki(from: &Path) {
    let made = made_pki();
    if made.join("own/cert.der").exists() {
        return;
    }
    for sub in ["own", "private"] {
        std::fs::create_dir_all(made.join(sub)).unwrap();
        for file in std::fs::read_dir(from.join(sub)).unwrap().flatten() {
            std::fs::copy(file.path(), made.join(sub).join(file.file_name())).unwrap();
        }
    }
}

fn variable<'a>(browse: &'a Value, path: &str) -> &'a Value {
    browse["variables"]
        .as_array()
        .unwrap()
        .iter()
        .find(|v| v["path"] == path)
        .unwrap_or_else(|| panic!("no variable {path}"))
}

/// `value` (a double the server sent) is the PLC's f32 `register`, as rounding to
/// f32 allows.
fn same_as_f32(value: &Value, register: f32, what: &str) {
    let value = value.as_f64().unwrap_or_else(|| panic!("{what}: {value}"));
    assert_eq!(
        value as f32, register,
        "{what}: OPC UA {value}, PLC {register}"
    );
}

/// The UNECE common code as EUInformation's unitId, computed here from OPC 10000-8's
/// rule (the code's bytes, big-endian), apart from the server's code.
fn unit_id(code: &str) -> i64 {
    code.bytes().fold(0, |id, byte| (id << 8) | i64::from(byte))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_address_space_holds_what_the_plc_holds() {
    let rig = Rig::start("browse", 6.0, |_, _| {}).await;
    keep_pki(&rig.scratch.join("pki"));
    let missed = rig.wait_schedule_done().await;
    let mut peer = Peer::connect(&rig.url, &[]).expect("anonymous on loopback");
    let before = rig.plc.holding();
    let browse = peer.ask("browse", "browse");
    let after = rig.plc.holding();
    assert_eq!(
        rig.u32_at(&before, "F1.bite_counter"),
        rig.u32_at(&after, "F1.bite_counter"),
        "no bite during the browse"
    );
    let words = after;

    // The structure: the gateway, its source, the driveline; the method.
    let objects: Vec<&str> = browse["objects"]
        .as_array()
        .unwrap()
        .iter()
        .map(|o| o["path"].as_str().unwrap())
        .collect();
    for path in [
        "Gateway",
        "Sources",
        "Sources/daq1",
        "Drivelines",
        "Drivelines/F1",
    ] {
        assert!(objects.contains(&path), "{path} in {objects:?}");
    }
    assert_eq!(browse["methods"][0]["path"], "Gateway/AcknowledgeAlarms");
    // Every figure of the catalogue, by its key (a browse comes in no set order).
    let mut keys: Vec<&str> = browse["variables"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(|v| v["path"].as_str()?.strip_prefix("Drivelines/F1/"))
        .collect();
    let mut catalogue: Vec<&str> = catalogue::DRIVELINE.iter().map(|f| f.key).collect();
    keys.sort_unstable();
    catalogue.sort_unstable();
    assert_eq!(keys, catalogue);

    // Types, units (UNECE codes) and ranges.
    let taf = variable(&browse, "Drivelines/F1/taf");
    assert_eq!(taf["datatype"], "Double");
    assert!(taf.get("EngineeringUnits").is_none(), "TAF has no unit");
    for (path, code, symbol) in [
        ("Drivelines/F1/static_torque_knm", "B48", "kN·m"),
        ("Drivelines/F1/peak_torque_knm", "B48", "kN·m"),
        ("Drivelines/F1/period_shift_s", "SEC", "s"),
        ("Drivelines/F1/beta1_hz", "HTZ", "Hz"),
        ("Drivelines/F1/gap_mrad", "C25", "mrad"),
        ("Drivelines/F1/days_to_gap_alarm", "DAY", "d"),
    ] {
        let variable = variable(&browse, path);
        let units = &variable["EngineeringUnits"];
        assert_eq!(units["unit_id"], unit_id(code), "{path}");
        assert_eq!(units["display"], symbol, "{path}");
        assert_eq!(
            units["namespace"],
            "http://www.opcfoundation.org/UA/units/un/cefact"
        );
        // BaseAnalogType (i=15318): a number with a unit.
        assert_eq!(variable["type_definition"], "i=15318", "{path}");
    }
    // The growth: no UNECE code, unitId -1 ("not available") and the symbol.
    let growth = &variable(&browse, "Drivelines/F1/gap_growth_mrad_per_day")["EngineeringUnits"];
    assert_eq!(
        (growth["unit_id"].as_i64(), &growth["display"]),
        (Some(-1), &serde_json::json!("mrad/d"))
    );
    let datatype = |figure_type| match figure_type {
        FigureType::Real => "Double",
        FigureType::Count => "UInt64",
        FigureType::Index | FigureType::State(_) | FigureType::Sequence => "UInt32",
        FigureType::Bool => "Boolean",
        FigureType::Time => "DateTime",
    };
    for figure in catalogue::DRIVELINE {
        let path = format!("Drivelines/F1/{}", figure.key);
        let expected = datatype(figure.figure_type);
        assert_eq!(variable(&browse, &path)["datatype"], expected, "{path}");
    }
    // The gateway's: `state` and `heartbeat` UInt32, `sources_ok` Boolean, as before.
    for figure in catalogue::GATEWAY {
        let path = format!("Gateway/{}", figure.key);
        let expected = datatype(figure.figure_type);
        assert_eq!(variable(&browse, &path)["datatype"], expected, "{path}");
    }
    assert_eq!(variable(&browse, "Gateway/state")["datatype"], "UInt32");
    assert_eq!(variable(&browse, "Gateway/heartbeat")["datatype"], "UInt32");

    // Every value is the PLC's, and good; figures carry the bite's time.
    let bite_counter = variable(&browse, "Drivelines/F1/bite_counter");
    assert_eq!(bite_counter["value"], rig.u32_at(&words, "F1.bite_counter"));
    let bites = bite_counter["value"].as_u64().unwrap() as usize;
    if missed == 0 {
        assert_eq!(bites, rig.bites, "every bite of the schedule");
    } else {
        assert!(
            bites > 0 && bites <= rig.bites,
            "{bites} of {} bites",
            rig.bites
        );
    }
    let last_bite = rig.u32_at(&words, "F1.last_bite_time");
    let last_bite_time = variable(&browse, "Drivelines/F1/last_bite_time");
    assert_eq!(
        last_bite_time["value"]["unix"].as_f64().unwrap().floor(),
        f64::from(last_bite),
        "the PLC has whole seconds"
    );
    let flags = words[rig.register("F1.flags")];
    let mut compared = 0;
    for figure in catalogue::DRIVELINE {
        let path = format!("Drivelines/F1/{}", figure.key);
        let opcua = variable(&browse, &path);
        // A figure of the extension block has its bit in that block's quality register.
        let quality = match figure.register {
            Register::At { page: 1, .. } => words[rig.register("F1.extension_quality")],
            _ => words[rig.register("F1.quality")],
        };
        match (figure.guard, figure.figure_type) {
            (Guard::FlagBit(bit), _) => {
                assert_eq!(opcua["value"], flags & (1 << bit) != 0, "{path}");
                assert_eq!(opcua["status"], "Good", "{path}");
            }
            // The PLC's quality bit clear: no value over OPC UA either.
            (Guard::QualityBit(bit), _) if quality & (1 << bit) == 0 => {
                assert_ne!(opcua["status"], "Good", "{path}: {opcua}");
                assert_eq!(opcua["value"], Value::Null, "{path}: {opcua}");
            }
            (Guard::QualityBit(_), FigureType::Real) => {
                assert_eq!(opcua["status"], "Good", "{path}: {opcua}");
                assert_eq!(
                    opcua["source"]["unix"], last_bite_time["value"]["unix"],
                    "{path}: source time = the bite's"
                );
                same_as_f32(
                    &opcua["value"],
                    rig.f32_at(&words, &format!("F1.{}", figure.key)),
                    figure.key,
                );
                compared += 1;
            }
            (Guard::QualityBit(_), FigureType::Index) => {
                let register = words[rig.register(&format!("F1.{}", figure.key))];
                assert_eq!(opcua["value"], u64::from(register), "{path}");
                compared += 1;
            }
            _ => {}
        }
    }
    assert!(compared >= 8, "{compared} figures compared with the PLC");
    let sources_ok = words[rig.register("sources_ok")];
    assert_eq!(sources_ok & 1, 1);
    assert_eq!(variable(&browse, "Sources/daq1/status")["value"], 0);
    assert_eq!(variable(&browse, "Gateway/sources_ok")["value"], true);
    assert_eq!(variable(&browse, "Gateway/state")["value"], 1);
    peer.send("quit");
    rig.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn subscriptions_get_each_bite_and_alarms_come_as_events() {
    // TAF thresholds every demo bite passes: the alarm latches at each bite.
    let rig = Rig::start("events", 40.0, |config, _| {
        let thresholds = &mut config.drivelines[0].thresholds;
        thresholds.taf_warning = 1.1;
        thresholds.taf_alarm = 1.15;
        config.outputs.metrics = Some(MetricsOutput {
            bind: "127.0.0.1:0".parse().unwrap(),
        });
    })
    .await;
    let mut peer = Peer::connect(&rig.url, &[]).expect("anonymous on loopback");
    peer.ask(
        "subscribe Drivelines/F1/bite_counter Drivelines/F1/taf",
        "subscribed",
    );
    peer.ask("events", "subscribed");
    // A second client with asyncua's default event subscription (no arguments:
    // BaseEventType's fields, every event type).
    let mut base = Peer::connect(&rig.url, &[]).expect("anonymous on loopback");
    base.ask("baseevents", "subscribed");
    // A bite: the counter's data change carries the PLC's count, the TAF the PLC's
    // (both come in one publish, in either order, with the bite's time).
    let seen = rig.bite_counter();
    let mut tafs = Vec::new();
    let change = loop {
        let data = peer.next_of("data", Duration::from_secs(30));
        if data["path"] == "Drivelines/F1/taf" {
            tafs.push(data);
        } else if data["path"] == "Drivelines/F1/bite_counter"
            && data["value"].as_u64().unwrap() > u64::from(seen)
        {
            break data;
        }
    };
    assert_eq!(change["status"], "Good");
    let counter = change["value"].as_u64().unwrap();
    let taf = match tafs.iter().find(|taf| taf["source"] == change["source"]) {
        Some(taf) => taf.clone(),
        None => loop {
            let data = peer.next_of("data", Duration::from_secs(10));
            if data["path"] == "Drivelines/F1/taf" && data["source"] == change["source"] {
                break data;
            }
        },
    };
    common::wait_for("the PLC has the bite", Duration::from_secs(5), || {
        u64::from(rig.bite_counter()) >= counter
    })
    .await;
    if u64::from(rig.bite_counter()) == counter {
        same_as_f32(
            &taf["value"],
            rig.f32_at(&rig.plc.holding(), "F1.taf"),
            "taf",
        );
    }

    // Acknowledge from this host: the latched alarm clears (an event says so, the PLC
    // flag too), and the next bite raises it again.
    let ack = peer.ask("ack", "ack");
    assert_eq!(ack["status"], "Good", "{ack}");
    let acknowledged = loop {
        let event = peer.next_of("event", Duration::from_secs(10));
        if event["fields"]["ConditionName"] == "taf_alarm" {
            break event;
        }
    };
    let fields = &acknowledged["fields"];
    assert_eq!(fields["ActiveState/Id"], false, "{fields}");
    assert_eq!(fields["AckedState/Id"], true, "{fields}");
    assert_eq!(fields["Severity"], 800);
    assert_eq!(fields["SourceName"], "Drivelines/F1");
    assert!(
        fields["Message"].as_str().unwrap().contains("acknowledged"),
        "{fields}"
    );
    let raised = loop {
        let event = peer.next_of("event", Duration::from_secs(30));
        if event["fields"]["ConditionName"] == "taf_alarm" {
            break event;
        }
    };
    let fields = &raised["fields"];
    assert_eq!(fields["ActiveState/Id"], true, "{fields}");
    assert_eq!(fields["AckedState/Id"], false, "{fields}");
    assert_eq!(fields["Retain"], true);
    assert!(fields["Message"]
        .as_str()
        .unwrap()
        .starts_with("F1: taf_alarm raised, taf "));
    // The default subscription got the alarm's events too, with BaseEventType's fields
    // (BaseEventType has no ConditionName: the alarm's events are told from the TAF
    // warning's, which may come first, by their message).
    let by_default = loop {
        let event = base.next_of("event", Duration::from_secs(30));
        let message = event["fields"]["Message"].as_str().unwrap_or_default();
        if event["fields"]["SourceName"] == "Drivelines/F1" && message.starts_with("F1: taf_alarm ")
        {
            break event;
        }
    };
    let fields = &by_default["fields"];
    assert_eq!(fields["Severity"], 800, "{fields}");
    assert!(
        fields["Message"]
            .as_str()
            .unwrap()
            .starts_with("F1: taf_alarm "),
        "{fields}"
    );
    assert!(
        fields["EventId"].as_str().is_some_and(|id| !id.is_empty()),
        "{fields}"
    );
    base.send("quit");
    let status = rig.gateway.opcua().unwrap().counts();
    assert_eq!(status.acknowledgements, 1);
    assert!(status.events >= 2, "{status:?}");
    // The same counts on /metrics.
    let page = metrics_page(rig.gateway.bound().metrics.unwrap()).await;
    assert!(
        page.contains("\nmillgate_opcua_acknowledgements_total 1\n"),
        "{page}"
    );
    assert!(
        page.contains("\nmillgate_opcua_connections_total "),
        "{page}"
    );
    peer.send("quit");
    rig.stop().await;
}

/// The events of a ConditionRefresh (asyncua's `refresh`): the event types and the
/// retained conditions' events between RefreshStart (i=2787) and RefreshEnd (i=2788).
fn refreshed(peer: &mut Peer, command: &str) -> Vec<Value> {
    let answer = peer.ask(command, "refresh");
    assert_eq!(answer["status"], "Good", "{answer}");
    let mut started = false;
    let mut conditions = Vec::new();
    loop {
        let event = peer.next_of("event", Duration::from_secs(10));
        match event["fields"]["EventType"].as_str() {
            Some("i=2787") => started = true,
            Some("i=2788") if started => return conditions,
            _ if started => conditions.push(event),
            _ => {}
        }
    }
}

/// The event of `kind` among `events`, if one.
fn condition<'a>(events: &'a [Value], kind: &str) -> Option<&'a Value> {
    events
        .iter()
        .find(|event| event["fields"]["ConditionName"] == kind)
}

/// Issue 40: each alarm is a condition instance (OPC 10000-9) that asyncua's and
/// node-opcua's default alarm filters receive; a client that connects during an
/// active alarm sees it through ConditionRefresh; node-opcua acknowledges it as it
/// acknowledges any condition, which clears the latched alarm as the PLC's
/// acknowledge does; a refresh of an unknown subscription, a stale or another
/// condition's EventId are refused with their status, counted, and change nothing.
/// The address space's conventions: browse names in the millgate namespace (a
/// browse path resolves), children in the catalogue's order, BuildInfo.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn alarms_are_conditions_that_both_clients_see_refresh_and_acknowledge() {
    // TAF thresholds every demo bite passes: the alarm latches at each bite.
    let rig = Rig::start("conditions", 60.0, |config, _| {
        let thresholds = &mut config.drivelines[0].thresholds;
        thresholds.taf_warning = 1.1;
        thresholds.taf_alarm = 1.15;
        let text = |text: &str| IdentificationValue::Text(text.into());
        config.gateway_identification.fields = vec![
            (IdentificationField::Manufacturer, text("Example IPC Maker")),
            (IdentificationField::AssetId, text("IPC-7")),
        ];
    })
    .await;
    common::wait_for("a bite", Duration::from_secs(30), || {
        rig.bite_counter() >= 1
    })
    .await;
    let Guard::FlagBit(alarm_bit) = catalogue::find(catalogue::DRIVELINE, "taf_alarm").guard else {
        panic!("taf_alarm is a flag");
    };
    let alarm_flag =
        |rig: &Rig| rig.plc.holding()[rig.register("F1.flags")] & (1 << alarm_bit) != 0;
    common::wait_for(
        "the PLC shows the TAF alarm",
        Duration::from_secs(10),
        || alarm_flag(&rig),
    )
    .await;

    // asyncua, connecting during the alarm: its own filter for AlarmConditionType
    // and the refresh events (where clause EventType InList [...]); the refresh
    // shows the alarm, active, unacknowledged, enabled, retained, with its instance.
    let mut asyncua = Peer::connect(&rig.url, &[]).expect("anonymous on loopback");
    let ready = asyncua.ask("defaultevents", "subscribed");
    assert!(ready["subscription"].as_u64().is_some(), "{ready}");
    let build = asyncua.ask("buildinfo", "buildinfo");
    assert_eq!(build["product"], "millgate", "{build}");
    assert_eq!(build["version"], env!("CARGO_PKG_VERSION"), "{build}");
    assert_eq!(build["uri"], "urn:millgate", "{build}");
    let start = Instant::now();
    let conditions = loop {
        let conditions = refreshed(&mut asyncua, "refresh");
        if condition(&conditions, "taf_alarm").is_some()
            || start.elapsed() > Duration::from_secs(10)
        {
            break conditions;
        }
    };
    let alarm = condition(&conditions, "taf_alarm").expect("the TAF alarm in the refresh");
    let fields = &alarm["fields"];
    // The millgate namespace's index, from a browse name.
    let ready_ns = {
        let line = asyncua.ask("children Gateway", "children");
        let first = line["names"][0].as_str().unwrap().to_owned();
        first.split_once(':').unwrap().0.to_owned()
    };
    let condition_id = format!("ns={ready_ns};s=Millgate/Drivelines/F1/Conditions/taf_alarm");
    assert_eq!(
        fields["NodeId"],
        condition_id.as_str(),
        "ConditionId: {fields}"
    );
    assert_eq!(fields["EventType"], "i=2915", "{fields}");
    assert_eq!(fields["ActiveState/Id"], true, "{fields}");
    assert_eq!(fields["ActiveState"], "Active", "{fields}");
    assert_eq!(fields["AckedState/Id"], false, "{fields}");
    assert_eq!(fields["AckedState"], "Unacknowledged", "{fields}");
    assert_eq!(fields["EnabledState/Id"], true, "{fields}");
    assert_eq!(fields["EnabledState"], "Enabled", "{fields}");
    assert_eq!(fields["Retain"], true, "{fields}");
    assert_eq!(fields["Severity"], 800, "{fields}");
    assert_eq!(fields["SourceName"], "Drivelines/F1", "{fields}");
    let stale_event_id = fields["EventId"].as_str().unwrap().to_owned();
    // The companion model: the driveline as a Machinery item (OPC 40001-1) under
    // Objects/Machines, executing, its NE 107 health MAINTENANCE_REQUIRED (4) while
    // the TAF alarm is latched; the gateway's identification.
    let index = |peer: &mut Peer, uri: &str| {
        let line = peer.ask(&format!("nsindex {uri}"), "nsindex");
        line["index"].as_u64().unwrap_or_else(|| panic!("{line}"))
    };
    let machinery = index(&mut asyncua, "http://opcfoundation.org/UA/Machinery/");
    let di = index(&mut asyncua, "http://opcfoundation.org/UA/DI/");
    let item = format!("{machinery}:Machines {ready_ns}:F1");
    let health = asyncua.ask(&format!("readpath {item} {di}:DeviceHealth"), "readpath");
    assert_eq!(
        (&health["value"], &health["status"]),
        (&4.into(), &"Good".into()),
        "{health}"
    );
    let state = asyncua.ask(
        &format!("readpath {item} {machinery}:MachineryItemState 0:CurrentState"),
        "readpath",
    );
    assert_eq!(state["value"], "Executing", "{state}");
    let revision = asyncua.ask(
        &format!("readpath {machinery}:Machines {ready_ns}:Gateway {di}:Identification {di}:SoftwareRevision"),
        "readpath",
    );
    assert_eq!(revision["value"], env!("CARGO_PKG_VERSION"), "{revision}");
    // The nameplates from the configuration: the demo's `drivelines[0].identification`
    // and the `[gateway.identification]` this test sets, each of DI's data type.
    let nameplate = |peer: &mut Peer, item: &str, property: &str| {
        let path =
            format!("{machinery}:Machines {ready_ns}:{item} {di}:Identification {di}:{property}");
        let line = peer.ask(&format!("readpath {path}"), "readpath");
        assert_eq!(line["status"], "Good", "{path}: {line}");
        (
            line["value"].clone(),
            line["variant"].as_str().unwrap_or_default().to_owned(),
        )
    };
    for (item, property, value, variant) in [
        (
            "F1",
            "Manufacturer",
            Value::from("Example Mill Works"),
            "LocalizedText",
        ),
        (
            "F1",
            "Model",
            "HSM finishing stand drive".into(),
            "LocalizedText",
        ),
        ("F1", "SerialNumber", "F1-0001".into(), "String"),
        (
            "F1",
            "ProductInstanceUri",
            "urn:example:millgate-demo:F1".into(),
            "String",
        ),
        ("F1", "YearOfConstruction", 1998.into(), "UInt16"),
        (
            "Gateway",
            "Manufacturer",
            "Example IPC Maker".into(),
            "LocalizedText",
        ),
        ("Gateway", "Model", "millgate".into(), "LocalizedText"),
        ("Gateway", "AssetId", "IPC-7".into(), "String"),
    ] {
        assert_eq!(
            nameplate(&mut asyncua, item, property),
            (value, variant.to_owned()),
            "{item}/Identification/{property}"
        );
    }

    // ConditionRefresh2 of the event item gives the same.
    let again = refreshed(&mut asyncua, "refresh2");
    assert_eq!(
        condition(&again, "taf_alarm").unwrap()["fields"]["EventId"],
        stale_event_id.as_str(),
        "a refresh sends the last event again"
    );

    // node-opcua, connecting during the alarm: its alarm monitoring (OfType
    // AcknowledgeableConditionType, then ConditionRefresh) holds the alarm.
    let mut node = Peer::node_opcua(&rig.url).expect("anonymous on loopback");
    node.ask("alarms", "subscribed");
    let seen = loop {
        let alarm = node.next_of("alarm", Duration::from_secs(20));
        if alarm["conditionName"] == "taf_alarm" {
            break alarm;
        }
    };
    assert_eq!(seen["conditionId"], condition_id.as_str(), "{seen}");
    assert_eq!(
        (
            &seen["active"],
            &seen["acked"],
            &seen["enabled"],
            &seen["retain"]
        ),
        (&true.into(), &false.into(), &true.into(), &true.into()),
        "{seen}"
    );
    assert_eq!(seen["eventId"], stale_event_id.as_str(), "{seen}");

    // Bad input: refused with its status, counted, nothing changed.
    let counts = || rig.gateway.opcua().unwrap().counts();
    let unknown = asyncua.ask("refresh 4000000000", "refresh");
    assert_eq!(unknown["status"], "BadSubscriptionIdInvalid", "{unknown}");
    let foreign = condition(&conditions, "taf_warning")
        .map(|warning| warning["fields"]["EventId"].as_str().unwrap().to_owned())
        .unwrap_or_else(|| "00".repeat(16));
    for event_id in [foreign.as_str(), "0123456789abcdef0123456789abcdef"] {
        let refused = asyncua.ask(&format!("ackcondition {condition_id} {event_id} no"), "ack");
        assert_eq!(refused["status"], "BadEventIdUnknown", "{refused}");
    }
    assert_eq!(counts().condition_calls_refused, 3, "{:?}", counts());
    assert_eq!(counts().acknowledgements, 0, "{:?}", counts());
    assert!(alarm_flag(&rig), "the PLC's TAF alarm is still set");

    // node-opcua acknowledges: the latched alarm clears as the PLC's acknowledge
    // does (the alarm stream's `acknowledged`), and both clients are told.
    let ack = node.ask(&format!("ack {condition_id} seen by the test"), "ack");
    assert_eq!(ack["status"], "Good", "{ack}");
    let acknowledged = loop {
        let event = asyncua.next_of("event", Duration::from_secs(10));
        if event["fields"]["ConditionName"] == "taf_alarm" {
            break event;
        }
    };
    let fields = &acknowledged["fields"];
    assert_eq!(fields["AckedState/Id"], true, "{fields}");
    assert_eq!(fields["AckedState"], "Acknowledged", "{fields}");
    assert_eq!(fields["ActiveState/Id"], false, "{fields}");
    assert_eq!(fields["Comment"], "seen by the test", "{fields}");
    assert!(
        fields["Message"].as_str().unwrap().contains("acknowledged"),
        "{fields}"
    );
    let changed = loop {
        let alarm = node.next_of("alarm", Duration::from_secs(10));
        if alarm["conditionName"] == "taf_alarm" && alarm["acked"] == true {
            break alarm;
        }
    };
    assert_eq!(changed["active"], false, "{changed}");
    assert_eq!(counts().acknowledgements, 1, "{:?}", counts());
    // The EventId acknowledged is stale now.
    let stale = node.ask(&format!("ackwith {condition_id} {stale_event_id}"), "ack");
    assert_eq!(stale["status"], "BadEventIdUnknown", "{stale}");
    assert_eq!(counts().condition_calls_refused, 4, "{:?}", counts());
    assert_eq!(counts().acknowledgements, 1, "{:?}", counts());

    // Browse names in the millgate namespace: the browse path resolves; children
    // in the catalogue's order, then the conditions' folder.
    let path = format!("translate {ready_ns}:Millgate {ready_ns}:Gateway {ready_ns}:state");
    let state = asyncua.ask(&path, "translate");
    assert_eq!(
        state["node"],
        format!("ns={ready_ns};s=Millgate/Gateway/state").as_str(),
        "{state}"
    );
    let children = asyncua.ask("children Drivelines/F1", "children");
    let mut expected: Vec<String> = catalogue::DRIVELINE
        .iter()
        .map(|figure| format!("{ready_ns}:{}", figure.key))
        .collect();
    expected.push(format!("{ready_ns}:Conditions"));
    assert_eq!(children["names"], serde_json::json!(expected));
    node.send("quit");
    asyncua.send("quit");
    rig.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_stale_source_is_bad_or_uncertain_never_good() {
    let mut rig = Rig::start("stale", 6.0, |_, _| {}).await;
    rig.wait_schedule_done().await;
    let mut peer = Peer::connect(&rig.url, &[]).expect("anonymous on loopback");
    let counter = rig.bite_counter();
    let Guard::QualityBit(taf_bit) = catalogue::find(catalogue::DRIVELINE, "taf").guard else {
        panic!("the TAF has a quality bit");
    };
    // The last bite is good, or degraded when the loaded machine made the gateway
    // miss a DAQ block in its window: OPC UA says what the PLC's quality bit says.
    let fresh = rig.plc.holding()[rig.register("F1.quality")] & (1 << taf_bit) != 0;
    let before = peer.ask("read Drivelines/F1/taf", "read");
    let expected = if fresh { "Good" } else { "BadDeviceFailure" };
    assert_eq!(before["status"], expected, "{before}");
    let Guard::FlagBit(bit) = catalogue::find(catalogue::DRIVELINE, "source_stale").guard else {
        panic!("source_stale is a flag");
    };
    let stale_bit = 1 << bit;
    // The cable pulled: the DAQ stops answering.
    rig.daq.take().unwrap().stop().await.unwrap();
    common::wait_for(
        "the PLC shows the source stale",
        Duration::from_secs(20),
        || rig.plc.holding()[rig.register("F1.flags")] & stale_bit != 0,
    )
    .await;
    // The last bite's figures stay true of that bite: their last usable value,
    // marked so, while the PLC reads them with the quality bit clear; a figure the
    // bite did not give stays without a value.
    let expected = if fresh {
        "UncertainLastUsableValue"
    } else {
        "BadNoCommunication"
    };
    let start = Instant::now();
    let taf = loop {
        let taf = peer.ask("read Drivelines/F1/taf", "read");
        if taf["status"] == expected || start.elapsed() > Duration::from_secs(5) {
            break taf;
        }
    };
    assert_eq!(taf["status"], expected, "{taf}");
    assert_eq!(taf["value"] != Value::Null, fresh, "{taf}");
    assert_eq!(
        rig.plc.holding()[rig.register("F1.quality")] & (1 << taf_bit),
        0,
        "the PLC's TAF quality bit is clear"
    );
    for key in ["gap_mrad", "wear_trend", "last_bite_time"] {
        let read = peer.ask(&format!("read Drivelines/F1/{key}"), "read");
        let uncertain = read["status"] == "UncertainLastUsableValue";
        assert!(
            uncertain || (read["status"] != "Good" && read["value"] == Value::Null),
            "{key}: never good while stale: {read}"
        );
        assert!(uncertain || key != "last_bite_time", "{key}: {read}");
    }
    // Counters say what happened: kept, good.
    let bites = peer.ask("read Drivelines/F1/bite_counter", "read");
    assert_eq!(bites["status"], "Good", "{bites}");
    assert_eq!(bites["value"], counter);
    let stale = peer.ask("read Drivelines/F1/source_stale", "read");
    assert_eq!(
        (&stale["status"], &stale["value"]),
        (&"Good".into(), &true.into())
    );
    let source = peer.ask("read Sources/daq1/status", "read");
    assert!(matches!(source["value"].as_u64(), Some(1 | 2)), "{source}");
    peer.send("quit");
    rig.stop().await;
}

/// A non-loopback address of this host, if it has one.
fn host_address() -> Option<std::net::IpAddr> {
    let socket = std::net::UdpSocket::bind("0.0.0.0:0").ok()?;
    socket.connect("192.0.2.1:9").ok()?;
    let ip = socket.local_addr().ok()?.ip();
    (!ip.is_loopback() && !ip.is_unspecified()).then_some(ip)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn certificates_and_passwords_are_checked() {
    let users = "operator:s3cret\n";
    let remote = host_address();
    let rig = Rig::start("security", 30.0, |config, scratch| {
        std::fs::write(scratch.join("users"), users).unwrap();
        let opcua = config.outputs.opcua.as_mut().unwrap();
        opcua.security_modes = vec![OpcUaSecurityMode::SignAndEncrypt];
        opcua.anonymous = false;
        opcua.users = vec![OpcUaUser {
            name: "operator".into(),
            password: "s3cret".into(),
        }];
        opcua.allow_remote_commands = false;
        if let Some(ip) = remote {
            opcua.bind = std::net::SocketAddr::new("0.0.0.0".parse().unwrap(), 0);
            opcua.host = ip.to_string();
        }
    })
    .await;
    let pki = rig.scratch.join("pki");
    let certs = rig.scratch.join("client-certs");
    let certs = certs.to_str().unwrap();
    let secure = ["--cert-dir", certs, "--mode", "sign_and_encrypt"];
    let with_user = |password: &'static str| {
        [
            secure.as_slice(),
            &["--user", "operator", "--password", password],
        ]
        .concat()
    };
    let status = || rig.gateway.opcua().unwrap().counts();

    // No certificate (security none) is not offered; an unknown certificate is
    // refused and kept in rejected/ for the operator.
    let refused = Peer::connect(&rig.url, &[])
        .err()
        .expect("no none endpoint");
    assert!(refused["error"].as_str().is_some());
    let refused = Peer::connect(&rig.url, &with_user("s3cret"))
        .err()
        .expect("an untrusted certificate is refused");
    assert_eq!(refused["status"], "BadCertificateUntrusted", "{refused}");
    assert!(status().rejected_requests >= 1, "{:?}", status());
    let rejected: Vec<PathBuf> = std::fs::read_dir(pki.join("rejected"))
        .unwrap()
        .flatten()
        .map(|f| f.path())
        .collect();
    assert_eq!(rejected.len(), 1, "{refused} {rejected:?}");
    // The operator trusts it: moved from rejected/ to trusted/.
    let name = rejected[0].file_name().unwrap();
    std::fs::rename(&rejected[0], pki.join("trusted").join(name)).unwrap();

    // A wrong password, no user: refused and counted.
    let before = status().identities_refused;
    let wrong = Peer::connect(&rig.url, &with_user("guess"))
        .err()
        .expect("a wrong password is refused");
    assert!(wrong["error"].as_str().is_some());
    assert_eq!(status().identities_refused, before + 1, "{:?}", status());
    let anonymous = Peer::connect(&rig.url, &secure)
        .err()
        .expect("anonymous is refused");
    assert!(
        anonymous["error"]
            .as_str()
            .unwrap()
            .contains("BadIdentityToken"),
        "{anonymous}"
    );

    // The right password over a trusted certificate reads.
    let mut peer = Peer::connect(&rig.url, &with_user("s3cret")).expect("trusted and signed in");
    let read = peer.ask("read Gateway/state", "read");
    assert_eq!(read["value"], 1);
    // Acknowledge from another host's address needs allow_remote_commands, a
    // condition's too (refused before its EventId is looked at).
    let ack = peer.ask("ack", "ack");
    let ns = peer.ask("nsindex urn:millgate:results", "nsindex")["index"].clone();
    let condition = format!("ns={ns};s=Millgate/Sources/daq1/Conditions/source_stale");
    let condition_ack = peer.ask(&format!("ackcondition {condition} 00 remote"), "ack");
    match remote {
        Some(_) => {
            assert_eq!(ack["status"], "BadUserAccessDenied", "{ack}");
            assert_eq!(
                condition_ack["status"], "BadUserAccessDenied",
                "{condition_ack}"
            );
            assert_eq!(status().acknowledgements_refused, 2);
            assert_eq!(status().condition_calls_refused, 0);
        }
        None => {
            eprintln!("no non-loopback address: the remote acknowledge is not tested");
            assert_eq!(ack["status"], "Good", "{ack}");
            assert_eq!(
                condition_ack["status"], "BadEventIdUnknown",
                "{condition_ack}"
            );
        }
    }
    peer.send("quit");
    rig.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn hostile_streams_are_counted_and_the_service_goes_on() {
    // Loopback, security none, anonymous and a user.
    let rig = Rig::start("hostile", 30.0, |config, _| {
        config.outputs.opcua.as_mut().unwrap().users = vec![OpcUaUser {
            name: "operator".into(),
            password: "s3cret".into(),
        }];
    })
    .await;
    let address = rig.gateway.bound().opcua.unwrap();
    let exchange = |bytes: Vec<u8>| async move {
        let mut stream = TcpStream::connect(address).await.unwrap();
        let _ = stream.write_all(&bytes).await;
        let mut answer = Vec::new();
        let _ = tokio::time::timeout(Duration::from_secs(10), stream.read_to_end(&mut answer))
            .await
            .expect("the server closes a hostile stream");
        answer
    };
    // Not OPC UA at all; a Hello claiming 2 GB; a good Hello then a chunk of garbage on
    // a channel never opened; a good Hello then a message too large.
    let http = exchange(b"GET / HTTP/1.1\r\nHost: x\r\n\r\n".to_vec()).await;
    assert!(http.starts_with(b"ERRF"), "{http:?}");
    let mut huge = b"HELF".to_vec();
    huge.extend_from_slice(&0x7fff_ffffu32.to_le_bytes());
    huge.extend_from_slice(&[0; 24]);
    assert!(exchange(huge).await.starts_with(b"ERRF"));
    let mut garbage = hello(&rig.url);
    garbage.extend_from_slice(b"MSGF");
    garbage.extend_from_slice(&64u32.to_le_bytes());
    garbage.extend((0..56u8).map(|i| i.wrapping_mul(37)));
    let answer = exchange(garbage).await;
    assert!(
        answer.starts_with(b"ACKF"),
        "the Hello is answered: {answer:?}"
    );
    let mut too_large = hello(&rig.url);
    too_large.extend_from_slice(b"MSGF");
    too_large.extend_from_slice(&1_000_000u32.to_le_bytes());
    assert!(exchange(too_large)
        .await
        .ends_with(b"out of range (allowed 12..=65535)"));
    // Random framed junk, from a fixed seed.
    let mut state = 0x2545_f491_4f6c_dd1du64;
    for _ in 0..20 {
        let mut junk = hello(&rig.url);
        let kind: &[u8; 4] = [b"OPNF", b"MSGF", b"CLOF", b"MSGC"][(state % 4) as usize];
        let len = 12 + (state >> 8) as usize % 500;
        junk.extend_from_slice(kind);
        junk.extend_from_slice(&(len as u32).to_le_bytes());
        for _ in 8..len {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            junk.push(state as u8);
        }
        exchange(junk).await;
    }
    let counts = rig.gateway.opcua().unwrap().counts();
    assert_eq!(counts.malformed_frames, 3, "{counts:?}");
    assert!(counts.protocol_errors >= 1, "{counts:?}");
    // The service goes on: a client reads, and bites still reach the PLC.
    let before = rig.bite_counter();
    let mut peer = Peer::connect(&rig.url, &["--user", "operator", "--password", "s3cret"])
        .expect("a good client after the hostile ones, signed in on the none endpoint");
    assert_eq!(peer.ask("read Gateway/state", "read")["value"], 1);
    common::wait_for(
        "a bite after the hostile streams",
        Duration::from_secs(20),
        || rig.bite_counter() > before,
    )
    .await;
    peer.send("quit");
    rig.stop().await;
}

/// `millgate check` with `[outputs.opcua]`: the summary names the endpoint and the
/// settings, a non-loopback bind is warned of, a bad value names its key and range.
#[test]
fn check_names_the_server_and_warns_of_other_hosts() {
    let folder = common::scratch("opcua-check");
    let scratch = folder.path();
    let repo = common::repo();
    std::fs::copy(
        repo.join("config/examples/table2-adjusted.toml"),
        scratch.join("table2-adjusted.toml"),
    )
    .unwrap();
    let demo = std::fs::read_to_string(repo.join("config/examples/demo.toml")).unwrap();
    let check = |opcua: &str| {
        let path = scratch.join("mill.toml");
        std::fs::write(&path, format!("{demo}\n[outputs.opcua]\n{opcua}\n")).unwrap();
        let output = common::MILLGATE
            .command()
            .args(["check", "--config", path.to_str().unwrap()])
            .output()
            .unwrap();
        let text = String::from_utf8_lossy(&output.stdout).to_string()
            + &String::from_utf8_lossy(&output.stderr);
        (output.status.success(), text)
    };
    let (ok, text) = check("bind = \"127.0.0.1:4841\"");
    assert!(ok, "{text}");
    assert!(
        text.contains(
            "OPC UA server: opc.tcp://127.0.0.1:4841/ (listen on 127.0.0.1:4841), security none"
        ),
        "{text}"
    );
    assert!(!text.contains("warning:"), "{text}");
    // A wildcard bind: the warning, the endpoint at the host clients use.
    let (ok, text) = check("bind = \"0.0.0.0:4841\"\nhost = \"gateway1\"\nsecurity_modes = [\"none\", \"sign_and_encrypt\"]");
    assert!(ok, "{text}");
    assert!(
        text.contains(
            "mill.toml: outputs.opcua.bind: 0.0.0.0:4841 accepts OPC UA clients from other \
             hosts; outputs.opcua.security_modes has none"
        ),
        "{text}"
    );
    assert!(
        text.contains("warning: ") && text.contains("OPC UA server: opc.tcp://gateway1:4841/"),
        "{text}"
    );
    let (ok, text) = check("max_sessions = 0");
    assert!(!ok);
    assert!(
        text.contains("outputs.opcua.max_sessions: 0 is not allowed (must be 1..=100)"),
        "{text}"
    );
}

/// docs/opcua.md's address space table is `millgate address-space` of the demo's
/// configuration (a driveline with its model), generated from the spec the server
/// publishes.
#[test]
fn readme_address_space_table_is_generated() {
    let repo = common::repo();
    let output = common::MILLGATE
        .command()
        .args([
            "address-space",
            "--config",
            repo.join("config/examples/demo.toml").to_str().unwrap(),
        ])
        .output()
        .unwrap();
    assert!(output.status.success());
    let table = String::from_utf8(output.stdout).unwrap();
    assert!(table.contains("| `Drivelines/F1/gap_mrad` | Double | mrad (C25) |  |"));
    let readme = std::fs::read_to_string(repo.join("docs/opcua.md")).unwrap();
    let begin = "<!-- address-space:begin -->\n";
    let start = readme
        .find(begin)
        .expect("docs/opcua.md has the address-space:begin marker")
        + begin.len();
    let end = readme
        .find("<!-- address-space:end -->")
        .expect("docs/opcua.md has the address-space:end marker");
    assert_eq!(
        &readme[start..end],
        table,
        "docs/opcua.md address space table differs: regenerate it with millgate address-space \
         --config config/examples/demo.toml"
    );
}

// The round-4 audit's OPC UA findings (issue 41): what one client can cost the server.

/// SecurityPolicy None.
const POLICY_NONE: &str = "http://opcfoundation.org/UA/SecurityPolicy#None";

/// An OPC UA string (or byte string) on the wire: its length, its bytes.
fn ua_string(bytes: &mut Vec<u8>, value: Option<&[u8]>) {
    match value {
        Some(value) => {
            bytes.extend_from_slice(&(value.len() as i32).to_le_bytes());
            bytes.extend_from_slice(value);
        }
        None => bytes.extend_from_slice(&(-1i32).to_le_bytes()),
    }
}

/// A RequestHeader without a session (OPC 10000-4, 7.33).
fn request_header(bytes: &mut Vec<u8>, handle: u32) {
    bytes.extend_from_slice(&[0, 0]); // authenticationToken: null NodeId
    bytes.extend_from_slice(&0i64.to_le_bytes()); // timestamp
    bytes.extend_from_slice(&handle.to_le_bytes());
    bytes.extend_from_slice(&0u32.to_le_bytes()); // returnDiagnostics
    ua_string(bytes, None); // auditEntryId
    bytes.extend_from_slice(&10_000u32.to_le_bytes()); // timeoutHint
    bytes.extend_from_slice(&[0, 0, 0]); // additionalHeader: empty extension object
}

/// A message of `kind` (`OPNF`, `MSGF`) around `body`.
fn framed(kind: &[u8; 4], body: &[u8]) -> Vec<u8> {
    let mut message = kind.to_vec();
    message.extend_from_slice(&(8 + body.len() as u32).to_le_bytes());
    message.extend_from_slice(body);
    message
}

/// A raw OPC UA TCP client that is not asyncua, for what asyncua will not do: a
/// secure channel of SecurityPolicy None, then sessionless requests (GetEndpoints)
/// written without reading the answers, or a silent connection held open.
struct RawChannel {
    stream: TcpStream,
    channel: u32,
    token: u32,
    sequence: u32,
    url: String,
}

impl RawChannel {
    /// Hello and a channel without security, from the loopback address `from`; an
    /// error when the server closes the connection instead.
    async fn open(
        address: std::net::SocketAddr,
        url: &str,
        from: [u8; 4],
    ) -> std::io::Result<Self> {
        let source = common::FromSource {
            source: from.into(),
            to: address,
        };
        let mut stream = common::connect(&source).await?;
        stream.write_all(&hello(url)).await?;
        let ack = Self::read_message(&mut stream).await?;
        if !ack.starts_with(b"ACKF") {
            return Err(std::io::Error::other(format!("no ACK: {ack:?}")));
        }
        let mut body = 0u32.to_le_bytes().to_vec(); // secure channel id: none yet
        ua_string(&mut body, Some(POLICY_NONE.as_bytes()));
        ua_string(&mut body, None); // senderCertificate
        ua_string(&mut body, None); // receiverCertificateThumbprint
        body.extend_from_slice(&1u32.to_le_bytes()); // sequence number
        body.extend_from_slice(&1u32.to_le_bytes()); // request id
        body.extend_from_slice(&[1, 0]);
        body.extend_from_slice(&446u16.to_le_bytes()); // OpenSecureChannelRequest
        request_header(&mut body, 1);
        body.extend_from_slice(&0u32.to_le_bytes()); // clientProtocolVersion
        body.extend_from_slice(&0u32.to_le_bytes()); // requestType: Issue
        body.extend_from_slice(&1u32.to_le_bytes()); // securityMode: None
        ua_string(&mut body, Some(&[])); // clientNonce
        body.extend_from_slice(&600_000u32.to_le_bytes()); // requestedLifetime
        stream.write_all(&framed(b"OPNF", &body)).await?;
        let answer = Self::read_message(&mut stream).await?;
        if !answer.starts_with(b"OPNF") {
            return Err(std::io::Error::other(format!("no OPN: {answer:?}")));
        }
        // The token id: after the security header, sequence header, type id and
        // response header (with no diagnostics, string table or additional header),
        // the protocol version and channel id.
        let word = |at: usize| u32::from_le_bytes(answer[at..at + 4].try_into().unwrap());
        let channel = word(8);
        let mut at = 12;
        for _ in 0..3 {
            let len = i32::from_le_bytes(answer[at..at + 4].try_into().unwrap());
            at += 4 + len.max(0) as usize;
        }
        at += 8 + 4; // sequence header, type id
        at += 8 + 4 + 4 + 1 + 4 + 3; // response header
        assert_eq!(word(at + 4), channel, "the token's channel id");
        let token = word(at + 8);
        Ok(Self {
            stream,
            channel,
            token,
            sequence: 1,
            url: url.to_owned(),
        })
    }

    /// One message (its header included).
    async fn read_message(stream: &mut TcpStream) -> std::io::Result<Vec<u8>> {
        let mut message = vec![0u8; 8];
        stream.read_exact(&mut message).await?;
        let size = u32::from_le_bytes(message[4..8].try_into().unwrap()) as usize;
        message.resize(size.max(8), 0);
        stream.read_exact(&mut message[8..]).await?;
        Ok(message)
    }

    /// The next message the server sends, at most 10 s away.
    async fn answer(&mut self) -> std::io::Result<Vec<u8>> {
        tokio::time::timeout(
            Duration::from_secs(10),
            Self::read_message(&mut self.stream),
        )
        .await
        .map_err(std::io::Error::other)?
    }

    /// A GetEndpoints request on the channel.
    fn get_endpoints(&mut self) -> Vec<u8> {
        self.sequence += 1;
        let mut body = Vec::new();
        for word in [self.channel, self.token, self.sequence, self.sequence] {
            body.extend_from_slice(&word.to_le_bytes());
        }
        body.extend_from_slice(&[1, 0]);
        body.extend_from_slice(&428u16.to_le_bytes()); // GetEndpointsRequest
        request_header(&mut body, self.sequence);
        ua_string(&mut body, Some(self.url.as_bytes()));
        body.extend_from_slice(&(-1i32).to_le_bytes()); // localeIds
        body.extend_from_slice(&(-1i32).to_le_bytes()); // profileUris
        framed(b"MSGF", &body)
    }
}

/// opcua_abuse.py with `args`: its JSON lines; killed on drop.
fn abuse(args: &[&str]) -> (common::KillOnDrop, Receiver<Value>) {
    let (child, _stdin, lines) = common::json_peer(&common::peer("opcua_abuse.py"), args);
    (child, lines)
}

fn abuse_line(lines: &Receiver<Value>, limit: Duration) -> Value {
    lines
        .recv_timeout(limit)
        .unwrap_or_else(|error| panic!("no line from opcua_abuse.py within {limit:?}: {error}"))
}

/// The resident memory of process `pid`, KiB.
fn rss_kib(pid: u32) -> u64 {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap();
    let line = status.lines().find(|l| l.starts_with("VmRSS:")).unwrap();
    line.split_whitespace().nth(1).unwrap().parse().unwrap()
}

/// Finding 1: requests written without ever reading the answers. async-opcua reads
/// them on and queues the answers without bound (1.5 GB in 27 s in the audit); the
/// front door stops reading a client with 32 requests unanswered. Against `millgate
/// demo --opcua` (its own process, so its memory is the gateway's alone).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_client_that_never_reads_cannot_grow_the_server() {
    let folder = common::scratch("opcua-unread");
    // A kit port: one the kernel's `:0` gave could go to an outgoing connection
    // before the demo binds it.
    let address: std::net::SocketAddr = ([127, 0, 0, 1], common::free_port()).into();
    let history = folder.path().join("history.db");
    let demo = common::KillOnDrop(
        common::MILLGATE
            .command()
            .args(["demo", "--duration", "300", "--opcua", &address.to_string()])
            .args(["--history", history.to_str().unwrap()])
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::null())
            .spawn()
            .unwrap(),
    );
    let url = format!("opc.tcp://{address}/");
    let started = Instant::now();
    while TcpStream::connect(address).await.is_err() {
        assert!(
            started.elapsed() < Duration::from_secs(60),
            "the demo serves"
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    serving(address, &url).await;
    let mut raw = RawChannel::open(address, &url, [127, 0, 0, 1])
        .await
        .expect("a channel without security on a none endpoint");
    let before = rss_kib(demo.id());
    let started = Instant::now();
    let mut sent = 0usize;
    // In batches of 100 for 30 s, or until the socket stays blocked 10 s (a debug
    // build of async-opcua reads slowly: the socket blocks for seconds at a time
    // while it still reads on).
    let mut batch: Vec<u8> = Vec::new();
    let mut written = 0;
    let mut blocked_since: Option<Instant> = None;
    while started.elapsed() < Duration::from_secs(30) {
        if written == batch.len() {
            batch = (0..100).flat_map(|_| raw.get_endpoints()).collect();
            written = 0;
            sent += 100;
        }
        let write = raw.stream.write(&batch[written..]);
        match tokio::time::timeout(Duration::from_secs(1), write).await {
            Ok(Ok(n)) => {
                written += n;
                blocked_since = None;
            }
            Ok(Err(error)) => panic!("the server closed the connection: {error}"),
            Err(_) => {
                let since = *blocked_since.get_or_insert_with(Instant::now);
                if since.elapsed() >= Duration::from_secs(10) {
                    break;
                }
            }
        }
    }
    let elapsed = started.elapsed();
    // A fresh client is served while the stalled one holds its connection.
    let mut peer = Peer::connect(&url, &[]).expect("a fresh client");
    assert_eq!(peer.ask("read Gateway/state", "read")["value"], 1);
    let grown_mib = rss_kib(demo.id()).saturating_sub(before) / 1024;
    eprintln!("unread requests: {sent} written in {elapsed:?}; resident memory +{grown_mib} MiB");
    assert!(
        grown_mib < 32,
        "{sent} requests never read grew the gateway by {grown_mib} MiB"
    );
    peer.send("quit");
    drop((raw, demo));
}

/// Finding 1, hardened: where `none` is not a security mode, a channel without
/// security is for discovery: 4 requests, then an ERR and the connection closed.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_channel_without_security_carries_only_discovery_when_none_is_not_offered() {
    let rig = Rig::start("discovery", 20.0, |config, _| {
        let opcua = config.outputs.opcua.as_mut().unwrap();
        opcua.security_modes = vec![OpcUaSecurityMode::SignAndEncrypt];
        opcua.anonymous = false;
    })
    .await;
    let address = rig.gateway.bound().opcua.unwrap();
    let mut raw = RawChannel::open(address, &rig.url, [127, 0, 0, 1])
        .await
        .expect("discovery opens a channel without security");
    for request in 1..=4 {
        let message = raw.get_endpoints();
        raw.stream.write_all(&message).await.unwrap();
        let answer = raw.answer().await.unwrap();
        assert!(answer.starts_with(b"MSGF"), "request {request}: {answer:?}");
    }
    let message = raw.get_endpoints();
    raw.stream.write_all(&message).await.unwrap();
    let answer = raw.answer().await.expect("an ERR before the close");
    assert!(answer.starts_with(b"ERRF"), "the fifth request: {answer:?}");
    let status = u32::from_le_bytes(answer[8..12].try_into().unwrap());
    assert_eq!(
        opcua::types::StatusCode::from(status),
        opcua::types::StatusCode::BadSecurityPolicyRejected
    );
    let mut rest = Vec::new();
    let closed = tokio::time::timeout(Duration::from_secs(10), raw.stream.read_to_end(&mut rest));
    assert!(closed.await.is_ok(), "the connection is closed");
    assert_eq!(rig.gateway.opcua().unwrap().counts().discovery_closed, 1);
    rig.stop().await;
}

/// Finding 5: slots. A client (an address) holds at most half the connections, the
/// last free one is kept for a client with none, and a connection idle 10 s makes
/// room for a new client when all are taken.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn one_client_cannot_hold_every_connection() {
    let rig = Rig::start("slots", 60.0, |config, _| {
        config.outputs.opcua.as_mut().unwrap().max_connections = 4;
    })
    .await;
    let address = rig.gateway.bound().opcua.unwrap();
    let mut holder = Vec::new();
    for _ in 0..4 {
        if let Ok(channel) = RawChannel::open(address, &rig.url, [127, 0, 0, 2]).await {
            holder.push(channel);
        }
    }
    assert_eq!(holder.len(), 2, "a client holds half of 4 connections");
    let mut other = Vec::new();
    for _ in 0..2 {
        if let Ok(channel) = RawChannel::open(address, &rig.url, [127, 0, 0, 3]).await {
            other.push(channel);
        }
    }
    assert_eq!(
        other.len(),
        1,
        "the last free connection is kept for a new client"
    );
    let mut peer = Peer::connect(&rig.url, &[]).expect("a new client gets the last one");
    assert_eq!(peer.ask("read Gateway/state", "read")["value"], 1);
    // All four taken: a fifth client waits until the idlest connection (the
    // holder's first) has been silent 10 s, and takes its place.
    let started = Instant::now();
    let newcomer = loop {
        if let Ok(channel) = RawChannel::open(address, &rig.url, [127, 0, 0, 4]).await {
            break channel;
        }
        assert!(
            started.elapsed() < Duration::from_secs(30),
            "no room made for a new client in 30 s"
        );
        tokio::time::sleep(Duration::from_millis(500)).await;
    };
    let counts = rig.gateway.opcua().unwrap().counts();
    assert_eq!(counts.evicted, 1, "{counts:?}");
    assert!(counts.refused >= 3, "{counts:?}");
    let closing = holder[0].answer().await.expect("an ERR to the evicted one");
    assert!(closing.starts_with(b"ERRF"), "{closing:?}");
    assert_eq!(
        peer.ask("read Gateway/state", "read")["value"],
        1,
        "the active client stays"
    );
    peer.send("quit");
    drop((holder, other, newcomer));
    rig.stop().await;
}

/// Finding 5, sessions: a client that took every session and vanished without
/// CloseSession held them for the whole session timeout (60 s), then until a session
/// had been idle 10 s; a session whose connection closed makes room for a new one at
/// once (the holder's sockets dropped, a fresh client has its session within 5 s,
/// well before any session is idle 10 s).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sessions_of_a_vanished_client_make_room() {
    let rig = Rig::start("sessions", 90.0, |config, _| {
        let opcua = config.outputs.opcua.as_mut().unwrap();
        opcua.max_sessions = 2;
        // One client (an address) takes every session here: what is tested is how
        // they make room once it vanished.
        opcua.max_sessions_per_peer = 2;
    })
    .await;
    let (holder, lines) = abuse(&["hold-sessions", &rig.url, "2"]);
    let held = abuse_line(&lines, Duration::from_secs(60));
    assert_eq!(held["sessions"], 2, "{held}");
    drop(holder);
    let started = Instant::now();
    let mut peer = loop {
        match Peer::connect(&rig.url, &[]) {
            Ok(peer) => break peer,
            Err(refused) => assert!(
                started.elapsed() < Duration::from_secs(5),
                "no session 5 s after the holder vanished: {refused}"
            ),
        }
        tokio::time::sleep(Duration::from_millis(200)).await;
    };
    eprintln!("a session after {:?}", started.elapsed());
    assert_eq!(peer.ask("read Gateway/state", "read")["value"], 1);
    peer.send("quit");
    rig.stop().await;
}

/// Finding 5, sessions per client: OPC UA allows several sessions per connection and
/// a client several connections, so one address could hold every session over its
/// open connections (10 of 10 in the audit). An address holds at most
/// `max_sessions_per_peer` (by default half of `max_sessions`): its next
/// CreateSession is answered `Bad_TooManySessions` and counted, and a client from
/// another address still gets a session.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn one_client_cannot_hold_every_session() {
    // The defaults: 10 sessions, 5 per address.
    let rig = Rig::start("peer-sessions", 60.0, |config, _| {
        config.outputs.metrics = Some(MetricsOutput {
            bind: "127.0.0.1:0".parse().unwrap(),
        });
    })
    .await;
    let (_holder, lines) = abuse(&["hold-sessions", &rig.url, "6", "127.0.0.2"]);
    let held = abuse_line(&lines, Duration::from_secs(60));
    assert_eq!(held["sessions"], 5, "{held}");
    assert_eq!(held["refused"]["BadTooManySessions"], 1, "{held}");
    // Another address (the test's own, 127.0.0.1) still gets a session, though the
    // holder keeps its five open.
    let mut peer = Peer::connect(&rig.url, &[]).expect("a session for another address");
    assert_eq!(peer.ask("read Gateway/state", "read")["value"], 1);
    let counts = rig.gateway.opcua().unwrap().counts();
    assert_eq!(counts.sessions_refused, 1, "{counts:?}");
    let page = metrics_page(rig.gateway.bound().metrics.unwrap()).await;
    assert!(
        page.contains("\nmillgate_opcua_sessions_refused_total 1\n"),
        "{page}"
    );
    peer.send("quit");
    rig.stop().await;
}

/// Finding 2: subscriptions left behind by sessions closed with DeleteSubscriptions
/// = false, with a publishing interval of an hour: bounded in number (all sessions
/// together) and in monitored items, and revised to expire within 10 minutes.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn subscriptions_left_behind_are_bounded_and_expire() {
    let rig = Rig::start("orphans", 120.0, |config, _| {
        config.outputs.opcua.as_mut().unwrap().max_sessions = 3;
    })
    .await;
    let (_abuser, lines) = abuse(&["orphans", &rig.url, "4", "10", "1000"]);
    let done = abuse_line(&lines, Duration::from_secs(240));
    eprintln!("{done}");
    let revised = &done["revised"];
    let lifetime_ms =
        revised["interval_ms"].as_f64().unwrap() * revised["lifetime"].as_f64().unwrap();
    assert!(lifetime_ms <= 600_000.0, "revised {revised}");
    assert!(
        revised["lifetime"].as_u64().unwrap() >= 3 * revised["keep_alive"].as_u64().unwrap(),
        "{revised}"
    );
    assert_eq!(done["created"]["subscriptions"], 30, "{done}");
    assert_eq!(
        done["refused"]["subscription BadTooManySubscriptions"], 10,
        "{done}"
    );
    assert_eq!(done["created"]["items"], 20_000, "{done}");
    assert!(
        done["refused"]["items BadTooManyMonitoredItems"].as_u64() >= Some(1000),
        "{done}"
    );
    let counts = rig.gateway.opcua().unwrap().counts();
    assert_eq!((counts.subscriptions, counts.monitored_items), (30, 20_000));
    assert_eq!(
        counts.orphaned_subscriptions, 30,
        "every session was closed"
    );
    // The service goes on: bites reach the PLC, a client reads.
    let before = rig.bite_counter();
    common::wait_for("a bite after the orphans", Duration::from_secs(30), || {
        rig.bite_counter() > before
    })
    .await;
    rig.stop().await;
}

/// Finding 10: browse continuation points a session may hold (async-opcua allows
/// 5 000, each keeping the rest of a browse).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn continuation_points_are_bounded() {
    let rig = Rig::start("points", 20.0, |_, _| {}).await;
    let (_abuser, lines) = abuse(&["browse-points", &rig.url, "25"]);
    let done = abuse_line(&lines, Duration::from_secs(60));
    assert_eq!(done["results"]["continuation_points"], 10, "{done}");
    assert_eq!(done["results"]["BadNoContinuationPoints"], 15, "{done}");
    rig.stop().await;
}

/// Finding 6: a refused client certificate is kept in `pki_dir/rejected/` for the
/// operator; any client can send one, so only the newest 64 are kept.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn rejected_certificates_are_bounded() {
    let rig = Rig::start("rejected", 60.0, |config, _| {
        let opcua = config.outputs.opcua.as_mut().unwrap();
        opcua.security_modes = vec![OpcUaSecurityMode::SignAndEncrypt];
    })
    .await;
    let certs = rig.scratch.join("strangers");
    let (_abuser, lines) = abuse(&["rejected", &rig.url, "80", certs.to_str().unwrap()]);
    let done = abuse_line(&lines, Duration::from_secs(240));
    assert_eq!(done["results"]["BadCertificateUntrusted"], 80, "{done}");
    let rejected = rig.scratch.join("pki/rejected");
    let files = || std::fs::read_dir(&rejected).unwrap().count();
    let removed = || {
        let counts = rig.gateway.opcua().unwrap().counts();
        counts.rejected_certificates_removed
    };
    // The files go first, the count after them (when the trimming thread has
    // returned): wait for both (CI: the count read between the two).
    common::wait_for(
        "rejected/ trimmed to 64 and at least 16 removals counted",
        Duration::from_secs(10),
        || files() == 64 && removed() >= 16,
    )
    .await;
    assert_eq!(removed(), 16);
    rig.stop().await;
}

/// Finding 7: each acknowledge writes the PLC's HMI registers; one a second is
/// carried out, the others are refused with `Bad_TooManyOperations` and counted.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn acknowledges_are_paced() {
    let rig = Rig::start("paced", 20.0, |_, _| {}).await;
    let mut peer = Peer::connect(&rig.url, &[]).expect("anonymous on loopback");
    let started = Instant::now();
    let statuses: Vec<String> = (0..10)
        .map(|_| {
            peer.ask("ack", "ack")["status"]
                .as_str()
                .unwrap()
                .to_owned()
        })
        .collect();
    let elapsed = started.elapsed();
    let good = statuses.iter().filter(|s| *s == "Good").count();
    assert_eq!(statuses[0], "Good", "{statuses:?}");
    assert!(
        good as u64 <= elapsed.as_secs() + 1,
        "{good} acknowledges carried out in {elapsed:?}: {statuses:?}"
    );
    assert!(
        statuses
            .iter()
            .all(|s| s == "Good" || s == "BadTooManyOperations"),
        "{statuses:?}"
    );
    let counts = rig.gateway.opcua().unwrap().counts();
    assert_eq!(counts.acknowledgements, good as u64, "{counts:?}");
    assert_eq!(
        counts.acknowledgements_limited,
        10 - good as u64,
        "{counts:?}"
    );
    peer.send("quit");
    rig.stop().await;
}

/// The entries of `browse` below `Drivelines/<name>/` (variables and objects) with what
/// a client sees of each but its value: the path below the driveline, the node id
/// with the driveline's name as `{}`, the data type, type definition, description and
/// properties.
fn driveline_nodes(browse: &Value, name: &str) -> Vec<String> {
    let prefix = format!("Drivelines/{name}/");
    let mut nodes: Vec<String> = ["objects", "variables", "methods"]
        .iter()
        .flat_map(|kind| browse[kind].as_array().unwrap())
        .filter(|entry| entry["path"].as_str().unwrap().starts_with(&prefix))
        .map(|entry| {
            let mut entry = entry.clone();
            let fields = entry.as_object_mut().unwrap();
            for value_field in ["value", "variant", "status", "source", "server"] {
                fields.remove(value_field);
            }
            entry
                .to_string()
                .replace(&format!("/{name}/"), "/{}/")
                .replace(&format!("/{name}\""), "/{}\"")
        })
        .collect();
    nodes.sort_unstable();
    nodes
}

/// A driveline added by `SIGHUP` to the real `millgate run` within
/// `outputs.driveline_slots` (issue 41): the running OPC UA server adds its nodes, the
/// reload says so, and a client connected before the reload browses them without
/// reconnecting: the same node ids, browse names, types, properties and conditions as
/// the driveline configured at the start (its Machinery item too), its bite counter
/// moving with its bites while F1's nodes are unchanged.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_driveline_added_live_gets_its_nodes_while_clients_stay_connected() {
    let setup = common::Setup::new(common::MILLGATE, "opcua-live", "db").await;
    // The kit's PLC holds the demo's first layout with a reserved slot (as in
    // tests/reload.rs), not the extension blocks.
    let demo = std::fs::read_to_string(&setup.config).unwrap();
    let first_layout = demo.replace("extension_blocks = true", "extension_blocks = false");
    assert_ne!(first_layout, demo, "the demo writes the extension blocks");
    std::fs::write(&setup.config, first_layout).unwrap();
    let pki = setup.scratch.join("pki");
    copy_pki(&pki);
    let port = common::free_port();
    setup.append_config(&format!(
        "\n[outputs]\ndriveline_slots = 2\n\n[outputs.opcua]\nbind = \"127.0.0.1:{port}\"\n\
         pki_dir = \"{}\"\n",
        pki.display()
    ));
    let mut service = setup.spawn("run.log");
    let url = format!("opc.tcp://127.0.0.1:{port}/");
    let address = std::net::SocketAddr::from(([127, 0, 0, 1], port));
    common::wait_for("the OPC UA port", Duration::from_secs(60), || {
        std::net::TcpStream::connect(address).is_ok()
    })
    .await;
    serving(address, &url).await;
    keep_pki(&pki);
    setup.plc().bites_after_now(1).await;
    let mut peer = Peer::connect(&url, &[]).expect("anonymous on loopback");
    let before = peer.ask("browse", "browse");
    let f1 = driveline_nodes(&before, "F1");
    assert!(!f1.is_empty(), "{before}");
    assert!(driveline_nodes(&before, "F2").is_empty(), "{before}");
    let absent = peer.ask("read Drivelines/F2/bite_counter", "read");
    assert_eq!(absent["status"], "BadNodeIdUnknown", "{absent}");

    // F2 on the torque channel read for F1, added by a SIGHUP.
    setup.add_driveline("F2");
    common::hang_up(service.id());
    let said = "drivelines.F2 (added in the register block of driveline_slot2: no address \
                moves), outputs.opcua (the nodes of F2 added as the server runs)";
    common::wait_for(said, Duration::from_secs(20), || {
        setup.log_text("run.log").contains(said)
    })
    .await;
    let log = setup.log_text("run.log");
    assert!(!log.contains("needs a restart"), "{log}");

    // The client connected before browses F2's nodes: as F1's, F1's unchanged.
    let after = peer.ask("browse", "browse");
    assert_eq!(driveline_nodes(&after, "F1"), f1, "F1's nodes changed");
    assert_eq!(driveline_nodes(&after, "F2"), f1, "F2's nodes are not F1's");
    let ns = peer.ask("nsindex urn:millgate:results", "nsindex")["index"]
        .as_u64()
        .unwrap();
    let objects = |browse: &Value| -> Vec<String> {
        let objects = browse["objects"].as_array().unwrap();
        objects.iter().map(|o| o["path"].to_string()).collect()
    };
    assert!(objects(&after).contains(&"\"Drivelines/F2\"".to_owned()));
    let f2_node = after["objects"]
        .as_array()
        .unwrap()
        .iter()
        .find(|o| o["path"] == "Drivelines/F2")
        .unwrap();
    assert_eq!(f2_node["node"], format!("ns={ns};s=Millgate/Drivelines/F2"));
    assert_eq!(f2_node["events"], true, "{f2_node}");
    // Its bite counter moves with its bites, as the PLC's F2 block shows.
    let start = Instant::now();
    let mut seen = Vec::new();
    while seen.len() < 2 {
        let read = peer.ask("read Drivelines/F2/bite_counter", "read");
        let counter = read["value"].as_u64().filter(|_| read["status"] == "Good");
        if let Some(counter) = counter.filter(|c| seen.last() != Some(c)) {
            seen.push(counter);
        }
        assert!(
            start.elapsed() < Duration::from_secs(60),
            "F2's bite counter did not move: {seen:?}, last {read}"
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    assert!(seen[0] < seen[1], "{seen:?}");
    // Its Machinery item, executing.
    let machinery = peer.ask("nsindex http://opcfoundation.org/UA/Machinery/", "nsindex")["index"]
        .as_u64()
        .unwrap();
    let state = peer.ask(
        &format!(
            "readpath {machinery}:Machines {ns}:F2 {machinery}:MachineryItemState 0:CurrentState"
        ),
        "readpath",
    );
    assert_eq!(state["status"], "Good", "{state}");
    assert_eq!(
        state["node"],
        format!("ns={ns};s=Machines/Drivelines/F2/MachineryItemState/CurrentState"),
        "{state}"
    );
    let f1_counter = peer.ask("read Drivelines/F1/bite_counter", "read");
    assert_eq!(f1_counter["status"], "Good", "{f1_counter}");
    assert!(
        service.try_wait().unwrap().is_none(),
        "SIGHUP ended the service"
    );
    peer.send("quit");
    common::terminate(&mut service);
    setup.stop(service).await;
}
