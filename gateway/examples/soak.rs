//! Soak benchmark: `millgate run` (the release binary, as a separate process) against
//! the demo's virtual DAQ and PLC for a set time, bites streaming (one bar about every
//! 2 s), an HMI client reading the whole register map and a Prometheus scrape every
//! sample period. Every sample prints the process's resident memory (VmRSS), its open
//! descriptors, its threads, the bites counted (degraded ones apart), the DAQ blocks
//! missed and the PLC writes; the summary gives the growth of RSS and descriptors
//! after the warm-up. Not a test: a leak shows as a steady growth over minutes.
//!
//! ```sh
//! cargo build --release -p millgate --bin millgate --example soak
//! target/release/examples/soak [--duration 600] [--every 10] [--millgate target/release/millgate]
//! ```

use std::io::{Read, Write};
use std::net::{SocketAddr, TcpListener as StdListener, TcpStream};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::{bail, Context as _};
use millgate_sim::devices::demo::{demo_daq, setup};
use millgate_sim::devices::modbus_bank::ServeOptions;
use millgate_sim::devices::virtual_plc::VirtualPlc;
use tokio_modbus::client::Reader;

/// Samples taken before the warm-up is over (listeners bound, first bites analysed).
const WARM_UP_SAMPLES: usize = 2;

struct Options {
    duration: Duration,
    every: Duration,
    millgate: PathBuf,
}

fn options() -> anyhow::Result<Options> {
    let mut options = Options {
        duration: Duration::from_secs(600),
        every: Duration::from_secs(10),
        millgate: std::env::current_exe()?
            .parent()
            .and_then(Path::parent)
            .map(|dir| dir.join("millgate"))
            .context("no folder above the example")?,
    };
    let mut args = std::env::args().skip(1);
    while let Some(arg) = args.next() {
        let value = args
            .next()
            .with_context(|| format!("{arg} needs a value"))?;
        let seconds = || -> anyhow::Result<Duration> {
            let s: f64 = value
                .parse()
                .with_context(|| format!("{arg}: {value:?} is not a number of seconds"))?;
            if !(s.is_finite() && s >= 1.0) {
                bail!("{arg}: {value} is not allowed (must be >= 1 s)");
            }
            Ok(Duration::from_secs_f64(s))
        };
        match arg.as_str() {
            "--duration" => options.duration = seconds()?,
            "--every" => options.every = seconds()?,
            "--millgate" => options.millgate = PathBuf::from(&value),
            _ => bail!("unknown option {arg} (allowed: --duration, --every, --millgate)"),
        }
    }
    if !options.millgate.is_file() {
        bail!(
            "{}: no millgate binary (build it: cargo build --release -p millgate --bin millgate)",
            options.millgate.display()
        );
    }
    Ok(options)
}

/// A free loopback port (released at once: the gateway binds it right after).
fn free_port() -> anyhow::Result<SocketAddr> {
    Ok(StdListener::bind("127.0.0.1:0")?.local_addr()?)
}

/// VmRSS (KiB) and thread count of `pid`, and its open descriptors.
fn process_figures(pid: u32) -> anyhow::Result<(u64, u64, usize)> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status"))?;
    let field = |name: &str| -> anyhow::Result<u64> {
        let line = status
            .lines()
            .find(|line| line.starts_with(name))
            .with_context(|| format!("no {name} in /proc/{pid}/status"))?;
        Ok(line[name.len()..]
            .split_whitespace()
            .next()
            .unwrap_or("")
            .parse()?)
    };
    let fds = std::fs::read_dir(format!("/proc/{pid}/fd"))?.count();
    Ok((field("VmRSS:")?, field("Threads:")?, fds))
}

/// The value of the first line of the Prometheus text at `address` starting with
/// `metric` (a whole name with its labels).
fn scrape(address: SocketAddr, metrics: &[&str]) -> anyhow::Result<Vec<f64>> {
    let mut stream = TcpStream::connect_timeout(&address, Duration::from_secs(2))?;
    stream.set_read_timeout(Some(Duration::from_secs(2)))?;
    stream.write_all(b"GET /metrics HTTP/1.1\r\nHost: soak\r\nConnection: close\r\n\r\n")?;
    let mut text = String::new();
    stream.read_to_string(&mut text)?;
    metrics
        .iter()
        .map(|metric| {
            text.lines()
                .find_map(|line| line.strip_prefix(metric)?.strip_prefix(' '))
                .with_context(|| format!("no {metric} in the scrape"))?
                .trim()
                .parse()
                .with_context(|| format!("{metric}: not a number"))
        })
        .collect()
}

struct Killed(Child);

impl Drop for Killed {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

#[tokio::main]
async fn main() -> anyhow::Result<()> {
    let options = options()?;
    // One more bar than the soak lasts, so bites stream to the end.
    let demo = setup(options.duration.as_secs_f64() + 10.0, 0.5, 1)?;
    let daq_listener = tokio::net::TcpListener::bind("127.0.0.1:0").await?;
    let daq_address = daq_listener.local_addr()?;
    let daq = demo_daq(&demo.config, &demo.schedule)?.spawn(daq_listener, ServeOptions::default());
    let plc = VirtualPlc::new(64);
    let plc_listener = tokio::net::TcpListener::bind("127.0.0.1:0").await?;
    let plc_address = plc_listener.local_addr()?;
    let running_plc = plc.spawn(plc_listener, ServeOptions::default());
    let server = free_port()?;
    let metrics = free_port()?;

    let dir = std::env::temp_dir().join(format!("millgate-soak-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let config_path = dir.join("mill.toml");
    let demo_toml = Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/examples/demo.toml");
    let text = std::fs::read_to_string(&demo_toml)?
        .replace("127.0.0.1:5020", &daq_address.to_string())
        .replace("127.0.0.1:5502", &plc_address.to_string())
        .replace("127.0.0.1:5503", &server.to_string())
        + &format!("\n[outputs.metrics]\nbind = \"{metrics}\"\n");
    std::fs::write(&config_path, text)?;

    let gateway = Killed(
        Command::new(&options.millgate)
            .args(["run", "--config"])
            .arg(&config_path)
            .env("RUST_LOG", "warn")
            .stdout(Stdio::null())
            .stderr(Stdio::inherit())
            .spawn()
            .with_context(|| format!("cannot start {}", options.millgate.display()))?,
    );
    let pid = gateway.0.id();
    println!(
        "soak: {} for {:.0} s, sampled every {:.0} s (pid {pid})",
        options.millgate.display(),
        options.duration.as_secs_f64(),
        options.every.as_secs_f64()
    );
    println!(
        "{:>7} {:>9} {:>4} {:>7} {:>6} {:>8} {:>6} {:>9}",
        "t_s", "rss_kib", "fds", "threads", "bites", "degraded", "missed", "plc_writes"
    );

    let mut hmi: Option<tokio_modbus::client::Context> = None;
    let started = Instant::now();
    let mut samples: Vec<(u64, usize)> = Vec::new();
    let mut hmi_reads = 0u64;
    while started.elapsed() < options.duration {
        tokio::time::sleep(options.every).await;
        // An HMI reading the whole map once a sample period, on one connection.
        if hmi.is_none() {
            hmi = tokio_modbus::client::tcp::connect(server).await.ok();
        }
        if let Some(context) = hmi.as_mut() {
            match context.read_holding_registers(0, 48).await {
                Ok(Ok(_)) => hmi_reads += 1,
                _ => hmi = None,
            }
        }
        let (rss, threads, fds) =
            process_figures(pid).context("the gateway is gone (it exited during the soak)")?;
        let [bites, degraded, missed] = scrape(
            metrics,
            &[
                "millgate_bites_total{driveline=\"F1\"}",
                "millgate_degraded_bites_total{driveline=\"F1\"}",
                "millgate_channel_blocks_missed_total{channel=\"spindle_top\"}",
            ],
        )?[..] else {
            unreachable!("three metrics asked for")
        };
        println!(
            "{:>7.0} {:>9} {:>4} {:>7} {:>6} {:>8} {:>6} {:>9}",
            started.elapsed().as_secs_f64(),
            rss,
            fds,
            threads,
            bites,
            degraded,
            missed,
            plc.writes()
        );
        samples.push((rss, fds));
    }
    drop(gateway);
    running_plc.stop().await?;
    daq.stop().await?;
    std::fs::remove_dir_all(&dir)?;

    let after_warm_up = samples.get(WARM_UP_SAMPLES..).unwrap_or(&[]);
    let (Some(first), Some(last)) = (after_warm_up.first(), after_warm_up.last()) else {
        bail!(
            "too short a soak: fewer than {} samples",
            WARM_UP_SAMPLES + 1
        );
    };
    let max_rss = after_warm_up.iter().map(|s| s.0).max().unwrap_or(0);
    let (min_fds, max_fds) = after_warm_up
        .iter()
        .fold((usize::MAX, 0), |(lo, hi), s| (lo.min(s.1), hi.max(s.1)));
    println!(
        "after warm-up ({} samples): RSS {} -> {} KiB (max {max_rss}, growth {:+} KiB), \
         descriptors {min_fds}..={max_fds}, HMI reads {hmi_reads}",
        after_warm_up.len(),
        first.0,
        last.0,
        last.0 as i64 - first.0 as i64
    );
    Ok(())
}
