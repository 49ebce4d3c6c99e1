//! Variable updates per second from the OPC UA server to a subscribed client, all
//! figures changing at each bite. The server (`OpcUaServer`, release build, security
//! none) runs in-process with a spec of `objects` drivelines of `variables` doubles
//! each; a bite every 100 ms changes every value; the client, another process,
//! subscribes to every variable (publishing interval 100 ms) and counts what it
//! receives for 10 s. Two clients that are not ours, one after the other: Python
//! asyncua (`opcua_subscriber.py`, one Publish request in flight) and node-opcua
//! (`opcua_subscriber.mjs`, several in flight), each with queue size 1 and 4.
//!
//! Prints per case: the client and queue size, variables, updates offered per second
//! (variables x bites/s), changes received per second, the share received, the changes
//! that carried the Overflow bit (a value of that variable was dropped from the server's
//! queue before it), changes the client saw out of order (none expected), the gateway's
//! CPU time per received change (this process's user + system time over the run) and
//! the client's CPU seconds. A client gets at most `queue` values per variable and
//! Publish response; a client whose CPU seconds near the run's is the bound.
//!
//! Run with (Python asyncua 2.1.0 installed, and `npm ci --prefix tests/peers`):
//!
//!     cargo bench -p millgate --features opcua --bench opcua [-- 400]
//!
//! (a number: only that many drivelines of 22 variables, as the last case).

use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::sync::Arc;
use std::time::{Duration, Instant};

use millgate::outputs::opcua::OpcUaServer;
use millgate_config::OpcUaOutput;
use tokio::sync::{mpsc, watch};

const BITE_PERIOD: Duration = Duration::from_millis(100);
const SECONDS: f64 = 10.0;
const VARIABLES: usize = 22;

#[path = "../tests/common/opcua_space.rs"]
mod opcua_space;

/// This process's user + system CPU time (/proc/self/stat, in USER_HZ = 100 ticks).
fn cpu_time() -> Duration {
    let stat = std::fs::read_to_string("/proc/self/stat").unwrap();
    let fields: Vec<&str> = stat.rsplit_once(") ").unwrap().1.split(' ').collect();
    let ticks: u64 = fields[11].parse::<u64>().unwrap() + fields[12].parse::<u64>().unwrap();
    Duration::from_millis(ticks * 10)
}

/// A subscribed client that is not ours.
#[derive(Clone, Copy)]
enum Subscriber {
    Asyncua,
    NodeOpcua,
}

impl Subscriber {
    fn name(self) -> &'static str {
        match self {
            Subscriber::Asyncua => "asyncua",
            Subscriber::NodeOpcua => "node-opcua",
        }
    }

    fn command(self) -> Command {
        let benches = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("benches");
        match self {
            Subscriber::Asyncua => {
                let mut command = Command::new("python3");
                command.arg(benches.join("opcua_subscriber.py"));
                command
            }
            Subscriber::NodeOpcua => {
                let mut command = Command::new("node");
                command.arg(benches.join("opcua_subscriber.mjs"));
                command
            }
        }
    }
}

async fn case(objects: usize, pki: &std::path::Path, subscriber: Subscriber, queue: u32) {
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let address = listener.local_addr().unwrap();
    let mut settings = OpcUaOutput::on(address, pki.to_path_buf());
    settings.max_monitored_items_per_subscription = 100_000;
    let url = settings.endpoint_url();
    let (updates, updates_rx) = watch::channel(opcua_space::snapshot(objects, VARIABLES, 0));
    let (_events, events_rx) = mpsc::channel(1);
    let (_grown, grown_rx) = mpsc::channel(1);
    let (stop, shutdown) = millgate::shutdown::channel();
    let server = OpcUaServer::new(
        settings,
        opcua_space::spec(objects, VARIABLES),
        Arc::new(|_| {}),
    )
    .unwrap();
    let status = server.status();
    let served = tokio::spawn(server.run(listener, updates_rx, events_rx, grown_rx, shutdown));
    opcua_space::serving(address, &url).await;

    let mut client = subscriber
        .command()
        .args([
            url.as_str(),
            &objects.to_string(),
            &VARIABLES.to_string(),
            &SECONDS.to_string(),
            &queue.to_string(),
        ])
        .stdout(Stdio::piped())
        .spawn()
        .expect("the subscriber starts");
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
        updates.send_replace(opcua_space::snapshot(objects, VARIABLES, bite));
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
        "{:>10} queue {queue}: {variables:>6} variables: offered {offered:>8.0} updates/s, \
         received {received:>8.0} changes/s ({:.1}%), with Overflow {}, out of order {}, \
         values written {written}, gateway CPU {:.1} us per received change ({:.2} s over \
         the run), client CPU {:.1} s of {SECONDS} s",
        subscriber.name(),
        100.0 * received / offered,
        result["overflow"],
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
         publishing) for {SECONDS} s",
        BITE_PERIOD.as_millis()
    );
    // `cargo bench` passes `--bench`; a number picks one size.
    let sizes: Vec<usize> = match std::env::args().skip(1).find_map(|a| a.parse().ok()) {
        Some(objects) => vec![objects],
        None => vec![20, 100, 400],
    };
    for objects in sizes {
        for subscriber in [Subscriber::Asyncua, Subscriber::NodeOpcua] {
            for queue in [1, 4] {
                case(objects, &pki, subscriber, queue).await;
            }
        }
    }
    let _ = std::fs::remove_dir_all(&pki);
}
