//! Variable updates per second from the OPC UA server to a subscribed client, all
//! figures changing at each bite. The server (`OpcUaServer`, release build, security
//! none) runs in-process with a spec of `objects` drivelines of `variables` doubles
//! each; a bite every 100 ms changes every value; the client is Python asyncua
//! (`opcua_subscriber.py`, another process) subscribed to every variable (publishing
//! interval 100 ms, queue size 1), counting what it receives for 10 s.
//!
//! Prints per case: variables, updates offered per second (variables x bites/s),
//! changes received per second, the share received, changes the client saw out of
//! order (none expected), the gateway's CPU time per received change (this process's
//! user + system time over the run) and the client's CPU seconds. A client gets at
//! most one value per variable and publishing interval (queue size 1: a value changed
//! twice within one interval arrives once, the latest), so bites as often as the
//! publishing interval lose some changes to that alone; a client whose CPU seconds
//! near the run's is the bound.
//!
//! Run with (Python asyncua 2.1.0 installed):
//!
//!     cargo bench -p millgate --features opcua --bench opcua

use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::sync::Arc;
use std::time::{Duration, Instant, SystemTime};

use millgate::outputs::opcua::model::{
    AddressSpaceSpec, ObjectKind, ObjectSpec, Snapshot, Value, VariableSpec, VariableType,
    VariableUpdate,
};
use millgate::outputs::opcua::OpcUaServer;
use millgate_config::OpcUaOutput;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::sync::{mpsc, watch};

const BITE_PERIOD: Duration = Duration::from_millis(100);
const SECONDS: f64 = 10.0;
const VARIABLES: usize = 22;

fn spec(objects: usize) -> AddressSpaceSpec {
    AddressSpaceSpec {
        name: "bench".into(),
        objects: (0..objects)
            .map(|k| ObjectSpec {
                name: format!("D{k}"),
                kind: ObjectKind::Driveline,
                parent: None,
                description: String::new(),
                variables: (0..VARIABLES)
                    .map(|j| VariableSpec {
                        key: format!("v{j}"),
                        description: String::new(),
                        unit: None,
                        datatype: VariableType::Double,
                        range: None,
                        states: Vec::new(),
                    })
                    .collect(),
                conditions: Vec::new(),
            })
            .collect(),
        machines: Vec::new(),
    }
}

/// Every value `bite`, measured now.
fn snapshot(objects: usize, bite: u64) -> Snapshot {
    let update = VariableUpdate::good(Value::Double(bite as f64), Some(SystemTime::now()));
    Snapshot {
        objects: vec![vec![update; VARIABLES]; objects],
        machines: Vec::new(),
    }
}

/// This process's user + system CPU time (/proc/self/stat, in USER_HZ = 100 ticks).
fn cpu_time() -> Duration {
    let stat = std::fs::read_to_string("/proc/self/stat").unwrap();
    let fields: Vec<&str> = stat.rsplit_once(") ").unwrap().1.split(' ').collect();
    let ticks: u64 = fields[11].parse::<u64>().unwrap() + fields[12].parse::<u64>().unwrap();
    Duration::from_millis(ticks * 10)
}

/// Wait until the server answers a Hello.
async fn serving(address: std::net::SocketAddr, url: &str) {
    let mut body = Vec::new();
    for word in [0u32, 65_535, 65_535, 0, 0] {
        body.extend_from_slice(&word.to_le_bytes());
    }
    body.extend_from_slice(&(url.len() as u32).to_le_bytes());
    body.extend_from_slice(url.as_bytes());
    let mut hello = b"HELF".to_vec();
    hello.extend_from_slice(&(8 + body.len() as u32).to_le_bytes());
    hello.extend_from_slice(&body);
    let mut stream = tokio::net::TcpStream::connect(address).await.unwrap();
    stream.write_all(&hello).await.unwrap();
    let mut answer = [0u8; 4];
    tokio::time::timeout(Duration::from_secs(60), stream.read_exact(&mut answer))
        .await
        .expect("the server answers")
        .unwrap();
    assert_eq!(&answer, b"ACKF");
}

async fn case(objects: usize, pki: &std::path::Path) {
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let address = listener.local_addr().unwrap();
    let mut settings = OpcUaOutput::on(address, pki.to_path_buf());
    settings.max_monitored_items_per_subscription = 100_000;
    let url = settings.endpoint_url();
    let (updates, updates_rx) = watch::channel(snapshot(objects, 0));
    let (_events, events_rx) = mpsc::channel(1);
    let (stop, shutdown) = millgate::shutdown::channel();
    let server = OpcUaServer::new(settings, spec(objects), Arc::new(|_| {})).unwrap();
    let status = server.status();
    let served = tokio::spawn(server.run(listener, updates_rx, events_rx, shutdown));
    serving(address, &url).await;

    let script = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("benches/opcua_subscriber.py");
    let mut client = Command::new("python3")
        .arg(script)
        .args([
            url.as_str(),
            &objects.to_string(),
            &VARIABLES.to_string(),
            &SECONDS.to_string(),
        ])
        .stdout(Stdio::piped())
        .spawn()
        .expect("python3");
    let (tx, lines) = std::sync::mpsc::channel::<serde_json::Value>();
    let stdout = client.stdout.take().unwrap();
    std::thread::spawn(move || {
        for line in BufReader::new(stdout).lines().map_while(Result::ok) {
            let _ = tx.send(serde_json::from_str(&line).unwrap());
        }
    });
    let mut bite = 0u64;
    let mut tick = tokio::time::interval(BITE_PERIOD);
    let mut ready = false;
    let mut measured = None;
    let mut cpu_start = cpu_time();
    let mut changes_start = status.counts().value_changes;
    let started = Instant::now();
    while measured.is_none() {
        tick.tick().await;
        bite += 1;
        updates.send_replace(snapshot(objects, bite));
        if let Ok(line) = lines.try_recv() {
            if line["ready"] == true {
                ready = true;
                cpu_start = cpu_time();
                changes_start = status.counts().value_changes;
            } else if ready {
                measured = Some(line);
            }
        }
        assert!(
            started.elapsed() < Duration::from_secs(180),
            "the client did not report"
        );
    }
    let cpu = cpu_time() - cpu_start;
    let written = status.counts().value_changes - changes_start;
    let result = measured.unwrap();
    let _ = client.wait();
    stop.trigger();
    let _ = served.await;

    let variables = objects * VARIABLES;
    let offered = variables as f64 / BITE_PERIOD.as_secs_f64();
    let changes = result["changes"].as_u64().unwrap();
    let seconds = result["seconds"].as_f64().unwrap();
    let received = changes as f64 / seconds;
    println!(
        "{variables:>6} variables: offered {offered:>8.0} updates/s, received {received:>8.0} \
         changes/s ({:.1}%), out of order {}, values written {written}, gateway CPU {:.1} us \
         per received change ({:.2} s over the run), client CPU {:.1} s of {SECONDS} s",
        100.0 * received / offered,
        result["out_of_order"],
        cpu.as_secs_f64() * 1e6 / changes.max(1) as f64,
        cpu.as_secs_f64(),
        result["client_cpu"].as_f64().unwrap_or(f64::NAN)
    );
}

#[tokio::main(flavor = "multi_thread", worker_threads = 2)]
async fn main() {
    let pki = std::env::temp_dir().join(format!("millgate-opcua-bench-{}", std::process::id()));
    println!(
        "OPC UA: every variable changes every {} ms; a client subscribed to all (100 ms \
         publishing, queue 1) for {SECONDS} s",
        BITE_PERIOD.as_millis()
    );
    for objects in [20, 100, 400] {
        case(objects, &pki).await;
    }
    let _ = std::fs::remove_dir_all(&pki);
}
