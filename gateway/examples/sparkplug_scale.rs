//! Many gateways into one broker: `--gateways N` `millgate run` processes, each
//! between its own virtual DAQ and PLC (the demo's, `sim::devices::demo`), publish
//! their Sparkplug B edge nodes into one Debian `mosquitto` on a loopback port; one
//! subscribing host (here, in this process) counts what arrives:
//!
//! - messages per second over the run;
//! - the end-to-end latency of every bite: the bite's trigger time (the DDATA's
//!   timestamp) to its arrival at the host, median, p95 and max. It includes the
//!   bite window the analysis waits for (`post_trigger_s` = 0.5 s after the trigger
//!   in the demo's configuration), the PLC-side analysis, the 20 ms bite poll of the
//!   edge node, and the broker;
//! - nothing lost: per node every `seq` is one more than the last (mod 256, from 0
//!   at each NBIRTH), the bite ids are contiguous from 1, and the last bite id equals
//!   the bite counter in the node's PLC.
//!
//! ```text
//! cargo build --release -p millgate --bin millgate --example sparkplug_scale
//! target/release/examples/sparkplug_scale --gateways 20 --seconds 60
//! ```
//!
//! Options: `--gateways N` (default 20), `--seconds S` of measurement after every node
//! is born (default 60), `--millgate PATH` (default: the `millgate` beside this
//! example's folder), `--data-period-ms` of the nodes (default 1000). The configs use
//! the demo's without its model (no wear maps: a small config, quick to start).

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use millgate::outputs::modbus::register_map::{decode_u32, RegisterMap};
use millgate::outputs::sparkplug::payload::{MetricValue, Payload};
use millgate_sim::devices::demo::{setup, DemoDevices};
use millgate_tests::kit::broker::Broker as Mosquitto;
use prost::Message as _;
use rumqttc::{AsyncClient, Event, MqttOptions, Packet, QoS};

const GROUP: &str = "scale";

struct Options {
    gateways: usize,
    seconds: u64,
    millgate: PathBuf,
    data_period_ms: u64,
}

fn options() -> Result<Options, String> {
    let mut options = Options {
        gateways: 20,
        seconds: 60,
        millgate: std::env::current_exe()
            .map_err(|e| e.to_string())?
            .parent()
            .and_then(Path::parent)
            .map(|dir| dir.join("millgate"))
            .ok_or("no folder for millgate")?,
        data_period_ms: 1000,
    };
    let mut args = std::env::args().skip(1);
    while let Some(arg) = args.next() {
        let mut value = || args.next().ok_or(format!("{arg} needs a value"));
        let number = |text: String| {
            text.parse::<u64>()
                .map_err(|_| format!("{arg}: {text:?} is not a whole number"))
        };
        match arg.as_str() {
            "--gateways" => options.gateways = number(value()?)? as usize,
            "--seconds" => options.seconds = number(value()?)?,
            "--millgate" => options.millgate = PathBuf::from(value()?),
            "--data-period-ms" => options.data_period_ms = number(value()?)?,
            other => return Err(format!("unknown option {other}")),
        }
    }
    if !options.millgate.is_file() {
        return Err(format!(
            "{} not found (cargo build --release -p millgate --bin millgate, or --millgate PATH)",
            options.millgate.display()
        ));
    }
    Ok(options)
}

fn now_ms() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_millis() as u64)
}

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .map(|a| a.port())
        .unwrap_or(0)
}

/// What the host saw of one edge node.
#[derive(Default)]
struct NodeSeen {
    births: u64,
    last_seq: Option<u64>,
    seq_breaks: u64,
    /// Alias of the bite id metric per device, from the DBIRTH.
    bite_alias: Option<u64>,
    bite_ids: Vec<u64>,
}

/// The host: everything it counts.
#[derive(Default)]
struct Host {
    nodes: HashMap<String, NodeSeen>,
    messages: u64,
    latencies_ms: Vec<i64>,
    undecodable: u64,
}

impl Host {
    fn take(&mut self, topic: &str, bytes: &[u8], received_ms: u64) {
        let parts: Vec<&str> = topic.split('/').collect();
        let (Some(kind), Some(node)) = (parts.get(2), parts.get(3)) else {
            return;
        };
        self.messages += 1;
        let Ok(payload) = Payload::decode(bytes) else {
            self.undecodable += 1;
            return;
        };
        let seen = self.nodes.entry((*node).to_owned()).or_default();
        match *kind {
            "NDEATH" => return,
            "NBIRTH" => {
                seen.births += 1;
                seen.last_seq = payload.seq;
                return;
            }
            _ => {}
        }
        if let (Some(seq), Some(last)) = (payload.seq, seen.last_seq) {
            if seq != (last + 1) % 256 {
                seen.seq_breaks += 1;
            }
        }
        seen.last_seq = payload.seq;
        if *kind == "DBIRTH" {
            seen.bite_alias = payload
                .metrics
                .iter()
                .find(|m| m.name.as_deref() == Some("bite_id"))
                .and_then(|m| m.alias);
        } else if *kind == "DDATA" {
            let bite = payload
                .metrics
                .iter()
                .find(|m| m.alias.is_some() && m.alias == seen.bite_alias);
            if let Some(MetricValue::LongValue(id)) = bite.and_then(|m| m.value.clone()) {
                seen.bite_ids.push(id);
                if let Some(bite_ms) = payload.timestamp {
                    self.latencies_ms.push(received_ms as i64 - bite_ms as i64);
                }
            }
        }
    }
}

/// One gateway: its devices, its `millgate run`, its register map.
struct Gateway {
    node: String,
    devices: DemoDevices,
    map: RegisterMap,
    child: Child,
}

fn percentile(sorted: &[i64], p: f64) -> i64 {
    if sorted.is_empty() {
        return 0;
    }
    let rank = ((p / 100.0) * (sorted.len() - 1) as f64).round() as usize;
    sorted[rank.min(sorted.len() - 1)]
}

#[tokio::main]
async fn main() -> Result<(), String> {
    let options = options()?;
    let scratch = std::env::temp_dir().join(format!("millgate-scale-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&scratch);
    std::fs::create_dir_all(&scratch).map_err(|e| e.to_string())?;
    let port = free_port();
    let broker = Mosquitto::try_start(&scratch, port)?;
    println!(
        "mosquitto on 127.0.0.1:{port}; {} gateways; {} s after every node is born",
        options.gateways, options.seconds
    );

    // The host subscribes first, so it sees every birth.
    let mut mqtt = MqttOptions::new("scale-host", "127.0.0.1", port);
    mqtt.set_keep_alive(Duration::from_secs(30));
    mqtt.set_max_packet_size(1 << 20, 1 << 20);
    let (client, mut events) = AsyncClient::new(mqtt, 1024);
    client
        .subscribe(format!("spBv1.0/{GROUP}/#"), QoS::AtMostOnce)
        .await
        .map_err(|e| e.to_string())?;
    let (tx, mut rx) = tokio::sync::mpsc::unbounded_channel();
    let host_task = tokio::spawn(async move {
        loop {
            match events.poll().await {
                Ok(Event::Incoming(Packet::Publish(message))) => {
                    let _ = tx.send((message.topic, message.payload.to_vec(), now_ms()));
                }
                Ok(_) => {}
                Err(error) => {
                    eprintln!("host: {error}");
                    tokio::time::sleep(Duration::from_millis(200)).await;
                }
            }
        }
    });
    let mut host = Host::default();

    // The devices play the demo's bars for the whole run (and some start-up time).
    let schedule_s = options.seconds as f64 + 30.0 + options.gateways as f64;
    let demo = setup(schedule_s, 0.5, 1).map_err(|e| e.to_string())?;
    let template = std::fs::read_to_string(
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../config/examples/demo.toml"),
    )
    .map_err(|e| e.to_string())?;
    let started = Instant::now();
    let mut gateways = Vec::new();
    for index in 0..options.gateways {
        let node = format!("gw{:02}", index + 1);
        let folder = scratch.join(&node);
        std::fs::create_dir_all(&folder).map_err(|e| e.to_string())?;
        let mut config = demo.config.clone();
        let map = RegisterMap::new(&config);
        let devices = DemoDevices::start(&mut config, &demo.schedule, usize::from(map.len()) + 16)
            .await
            .map_err(|e| e.to_string())?;
        let plc = config.outputs.plc.as_ref().map(|p| p.address.clone());
        let text: String = template
            .lines()
            .filter(|line| !line.starts_with("model =") && !line.starts_with("wear ="))
            .map(|line| format!("{line}\n"))
            .collect::<String>()
            .replace("127.0.0.1:5020", &config.modbus_sources[0].address)
            .replace("127.0.0.1:5502", &plc.unwrap_or_default())
            .replace("127.0.0.1:5503", "127.0.0.1:0")
            + &format!(
                "\n[outputs.mqtt]\nbroker = \"127.0.0.1:{port}\"\ngroup_id = \"{GROUP}\"\n\
                 node_id = \"{node}\"\ndata_period_ms = {}\n\n[history]\npath = \"history.db\"\n",
                options.data_period_ms
            );
        let config_path = folder.join("mill.toml");
        std::fs::write(&config_path, text).map_err(|e| e.to_string())?;
        let log = std::fs::File::create(folder.join("run.log")).map_err(|e| e.to_string())?;
        let child = Command::new(&options.millgate)
            .args(["run", "--config"])
            .arg(&config_path)
            .env("RUST_LOG", "warn")
            .stdout(Stdio::null())
            .stderr(log)
            .spawn()
            .map_err(|e| format!("{}: {e}", options.millgate.display()))?;
        gateways.push(Gateway {
            node,
            devices,
            map,
            child,
        });
    }

    // Until every node is born, then the measured run.
    let mut measuring: Option<(Instant, u64, usize)> = None;
    let mut next_report = Instant::now() + Duration::from_secs(5);
    loop {
        let wait = tokio::time::sleep(Duration::from_millis(100));
        tokio::select! {
            message = rx.recv() => {
                let Some((topic, bytes, received)) = message else { break };
                host.take(&topic, &bytes, received);
            }
            () = wait => {}
        }
        let born = host.nodes.values().filter(|n| n.births > 0).count();
        if measuring.is_none() && born == options.gateways {
            println!(
                "all {born} nodes born after {:.1} s; measuring for {} s",
                started.elapsed().as_secs_f64(),
                options.seconds
            );
            measuring = Some((Instant::now(), host.messages, host.latencies_ms.len()));
        }
        if measuring.is_none() && started.elapsed() > Duration::from_secs(120) {
            return Err(format!(
                "only {born} of {} nodes born in 120 s",
                options.gateways
            ));
        }
        if Instant::now() >= next_report {
            next_report += Duration::from_secs(5);
            let since = measuring.map_or(0.0, |(at, _, _)| at.elapsed().as_secs_f64());
            let rate = measuring.map_or(0.0, |(_, before, _)| {
                (host.messages - before) as f64 / since.max(1e-9)
            });
            println!(
                "t={:5.1} s  born {born}/{}  messages {}  bites {}  {rate:.1} msg/s",
                started.elapsed().as_secs_f64(),
                options.gateways,
                host.messages,
                host.latencies_ms.len()
            );
        }
        if let Some((at, _, _)) = measuring {
            if at.elapsed() >= Duration::from_secs(options.seconds) {
                break;
            }
        }
    }
    let (at, messages_before, bites_before) = measuring.ok_or("no measurement")?;
    let window_s = at.elapsed().as_secs_f64();
    let measured_messages = host.messages - messages_before;
    let measured_bites = host.latencies_ms.len() - bites_before;

    // Stop the gateways (each sends its NDEATH), let the host drain, compare with the
    // PLCs.
    for gateway in &gateways {
        let _ = Command::new("kill")
            .args(["-TERM", &gateway.child.id().to_string()])
            .status();
    }
    let mut exits = Vec::new();
    for gateway in &mut gateways {
        exits.push(gateway.child.wait().map(|s| s.success()).unwrap_or(false));
    }
    let drain = Instant::now() + Duration::from_secs(2);
    while let Ok(Some((topic, bytes, received))) =
        tokio::time::timeout_at(drain.into(), rx.recv()).await
    {
        host.take(&topic, &bytes, received);
    }
    host_task.abort();

    let mut lost_bites = 0u64;
    let mut seq_breaks = 0u64;
    let mut unpublished = 0i64;
    for gateway in &gateways {
        let words = gateway.devices.plc.holding();
        let at = gateway
            .map
            .registers()
            .iter()
            .find(|r| r.name == "F1.bite_counter")
            .map(|r| usize::from(r.address))
            .ok_or("no F1.bite_counter register")?;
        let plc = decode_u32(&words[at..]).unwrap_or(0);
        let seen = host.nodes.get(&gateway.node);
        let ids = seen.map_or(&[][..], |s| s.bite_ids.as_slice());
        let gaps = ids.windows(2).filter(|w| w[1] != w[0] + 1).count() as u64
            + u64::from(ids.first().is_some_and(|&first| first != 1));
        lost_bites += gaps;
        seq_breaks += seen.map_or(0, |s| s.seq_breaks);
        unpublished += i64::from(plc) - ids.last().copied().unwrap_or(0) as i64;
        println!(
            "{}: births {}, bites {} (ids {}..={}), PLC bite counter {plc}, seq breaks {}, id gaps {gaps}",
            gateway.node,
            seen.map_or(0, |s| s.births),
            ids.len(),
            ids.first().copied().unwrap_or(0),
            ids.last().copied().unwrap_or(0),
            seen.map_or(0, |s| s.seq_breaks),
        );
    }
    for gateway in gateways {
        let _ = gateway.devices.stop().await;
    }
    drop(broker);

    let mut sorted = host.latencies_ms.clone();
    sorted.sort_unstable();
    println!("--- summary ---");
    println!(
        "gateways {}  (clean exits {})",
        exits.len(),
        exits.iter().filter(|&&ok| ok).count()
    );
    println!(
        "messages {measured_messages} in {window_s:.1} s = {:.1} msg/s (all: {}, undecodable {})",
        measured_messages as f64 / window_s,
        host.messages,
        host.undecodable
    );
    println!(
        "bites {measured_bites} in the window = {:.1} bites/s; all {}",
        measured_bites as f64 / window_s,
        sorted.len()
    );
    println!(
        "latency bite trigger -> host, ms: median {}  p95 {}  max {}  min {}",
        percentile(&sorted, 50.0),
        percentile(&sorted, 95.0),
        sorted.last().copied().unwrap_or(0),
        sorted.first().copied().unwrap_or(0)
    );
    println!(
        "lost: bite id gaps {lost_bites}, seq breaks {seq_breaks}, bites in the PLCs but not at the host {unpublished}"
    );
    let _ = std::fs::remove_dir_all(&scratch);
    if lost_bites + seq_breaks > 0 || unpublished != 0 || host.undecodable > 0 {
        return Err("messages were lost".into());
    }
    Ok(())
}
