//! Load bench and soak: `millgate run` (the release binary, as a separate process,
//! optionally pinned to one core with `taskset`) watching N drivelines at 2 kHz and M
//! tandem-mill stands at 2.5 or 10 kHz streamed by virtual DAQs, with the history,
//! the web page, `/metrics`, the HMI server and a Sparkplug B node (into a local
//! Debian `mosquitto`) on; the history keeps every bite's capture (its default).
//!
//! - Drivelines: the demo's simulated bars (`millgate_sim::devices::demo`, the Table 2
//!   driveline with a growing spindle gap, a bite every 2.0 s), each driveline's
//!   copy started 0.2 s after the previous one's (so the bites fall on 10 phases of
//!   the bar: about N / 10 complete in the same block, a harsher case than a train
//!   whose stands bite one after another), the demo's model for the wear and gap
//!   diagnosis; 8 torque channels per DAQ (blocks of 100 samples, polled every 20 ms).
//! - Tandem mills of up to 5 stands, one accelerometer per stand: seeded Gaussian noise
//!   (2 m/s^2 RMS) looped, the band-gain chatter detector of
//!   `config/examples/tandem-5stand.toml`; 8 channels per DAQ, blocks of 120 samples
//!   polled at a third of the block period (at most 20 ms).
//! - Every sample period: an HMI reads the first 48 registers, a web client GETs `/`
//!   and `/api/overview`, a Prometheus scrape of `/metrics`.
//! - Bite -> PLC: the virtual PLC records the time of every write, the torque DAQs
//!   the time and sequence of every read. The latency of a bite is the write that first
//!   holds its bite counter less the answer that delivered the block completing its
//!   window: the last delivery of its channel before the write, when the window's last
//!   sample (the bite's time in the history plus the window after the trigger) is
//!   within a block period of it; otherwise (a write more than a block after) from
//!   that last sample, an upper bound. So the latency covers the gateway's reading of
//!   the answer, the analysis, the history commit the PLC writer waits for and the
//!   Modbus write, not the wait for the DAQ's block to fill and be polled (up to 50 +
//!   20 ms here), which is the DAQ's; the summary also gives the latency from the
//!   window's last sample, that wait included.
//!
//! Each load point prints its samples (RSS, descriptors, threads, CPU, bites, blocks
//! missed, answers) and a summary row; a load point passes with no block missed after
//! the warm-up, every bite in the history and at the PLC, the web page and `/metrics`
//! answering every time, and bite -> PLC p99 under `--p99-limit-ms` (5 ms). A sweep (`--drivelines
//! 4,8,16`: lists are stepped together, a single value is held) stops at the first
//! point that fails. The bench's own virtual DAQs publish on its tokio timers: the
//! `stall_ms` column is the bench's longest timer lateness in the sample period; a stall
//! near a block period (50 ms) makes a DAQ skip a block, which the gateway counts as
//! missed though it did not fall behind (run the bench pinned to the other core:
//! `taskset -c 0`); `bench_%` is the bench's own CPU (its DAQs, PLC and clients, not
//! mosquitto) in the sample period, of one core.
//!
//! ```sh
//! cargo build --release -p millgate --bin millgate --example soak
//! # the sweep: the gateway on core 1
//! target/release/examples/soak --cpu 1 --duration 60 --drivelines 4,8,16,32 --tandem-stands 0
//! # the soak: an hour at one load, a sample a minute
//! target/release/examples/soak --cpu 1 --duration 3600 --every 60 --drivelines 8 --tandem-stands 5
//! ```
//!
//! Options: `--duration` s per load point (default 600), `--every` s between samples
//! (10), `--warm-up` s not counted (15), `--drivelines` list (1), `--tandem-stands` list
//! (0), `--tandem-rate-hz` (2500), `--cpu` the core to pin the gateway to (none),
//! `--p99-limit-ms` (5), `--keep-going` (step on after a failed point), `--millgate`
//! the binary (the one beside this example's folder).

use std::collections::{BTreeMap, HashMap, VecDeque};
use std::io::{Read, Write};
use std::net::{SocketAddr, TcpListener as StdListener, TcpStream};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant, SystemTime};

use anyhow::{bail, Context as _};
use millgate::outputs::modbus::register_map::{decode_u32, RegisterMap};
use millgate::state::time::UtcTime;
use millgate_config::layout::BLOCK_REGISTERS;
use millgate_config::RegisterTable;
use millgate_sim::devices::demo::setup;
use millgate_sim::devices::modbus_bank::{ReadRecord, Running, ServeOptions, SharedBank};
use millgate_sim::devices::virtual_daq::{DaqChannel, Placement, Publish, VirtualDaq};
use millgate_sim::devices::virtual_plc::VirtualPlc;
use millgate_tests::kit::broker::Broker as Mosquitto;
use rand::SeedableRng as _;
use rand_distr::Distribution as _;
use tokio_modbus::client::Reader;

/// Channels per virtual DAQ (one Modbus source each).
const CHANNELS_PER_DAQ: usize = 8;
/// Stands per tandem mill.
const STANDS_PER_MILL: usize = 5;
/// Driveline torque sample rate, Hz, and samples per DAQ block (50 ms).
const DRIVELINE_RATE_HZ: f64 = 2000.0;
const DRIVELINE_BLOCK: u16 = 100;
/// Samples per block of the stands' DAQs.
const STAND_BLOCK: u16 = 120;
/// The drivelines' bite window after the trigger, s (as the demo's).
const POST_TRIGGER_S: f64 = 0.5;
/// Seconds of simulated bars each driveline's DAQ plays over and over.
const BARS_S: f64 = 60.0;
/// Delay between two drivelines' copies of the bars, s.
const STAGGER_S: f64 = 0.2;
/// Seconds of noise each stand's DAQ plays over and over.
const STAND_NOISE_S: f64 = 4.0;
/// RMS of the stands' noise, m/s^2.
const STAND_NOISE_RMS: f64 = 2.0;
/// The largest bite -> PLC p99 a load point passes with by default, ms.
const P99_LIMIT_MS: f64 = 5.0;
/// Clock ticks per second of `/proc/<pid>/stat` (USER_HZ, 100 on Linux).
const USER_HZ: f64 = 100.0;

struct Options {
    duration: Duration,
    every: Duration,
    warm_up: Duration,
    drivelines: Vec<usize>,
    tandem_stands: Vec<usize>,
    tandem_rate_hz: f64,
    cpu: Option<String>,
    p99_limit_ms: f64,
    keep_going: bool,
    millgate: PathBuf,
}

fn options() -> anyhow::Result<Options> {
    let mut options = Options {
        duration: Duration::from_secs(600),
        every: Duration::from_secs(10),
        warm_up: Duration::from_secs(15),
        drivelines: vec![1],
        tandem_stands: vec![0],
        tandem_rate_hz: 2500.0,
        cpu: None,
        p99_limit_ms: P99_LIMIT_MS,
        keep_going: false,
        millgate: std::env::current_exe()?
            .parent()
            .and_then(Path::parent)
            .map(|dir| dir.join("millgate"))
            .context("no folder above the example")?,
    };
    let mut args = std::env::args().skip(1);
    while let Some(arg) = args.next() {
        if arg == "--keep-going" {
            options.keep_going = true;
            continue;
        }
        let value = args
            .next()
            .with_context(|| format!("{arg} needs a value"))?;
        let seconds = |least: f64| -> anyhow::Result<Duration> {
            let s: f64 = value
                .parse()
                .with_context(|| format!("{arg}: {value:?} is not a number of seconds"))?;
            if !(s.is_finite() && s >= least) {
                bail!("{arg}: {value} is not allowed (must be >= {least} s)");
            }
            Ok(Duration::from_secs_f64(s))
        };
        let counts = || -> anyhow::Result<Vec<usize>> {
            value
                .split(',')
                .map(|count| {
                    count.trim().parse().with_context(|| {
                        format!("{arg}: {count:?} is not a count (a list like 4,8,16)")
                    })
                })
                .collect()
        };
        match arg.as_str() {
            "--duration" => options.duration = seconds(1.0)?,
            "--every" => options.every = seconds(1.0)?,
            "--warm-up" => options.warm_up = seconds(0.0)?,
            "--drivelines" => options.drivelines = counts()?,
            "--tandem-stands" => options.tandem_stands = counts()?,
            "--tandem-rate-hz" => {
                options.tandem_rate_hz = match value.as_str() {
                    "2500" => 2500.0,
                    "10000" => 10000.0,
                    _ => bail!("--tandem-rate-hz: {value} is not allowed (2500 or 10000)"),
                }
            }
            "--cpu" => options.cpu = Some(value),
            "--p99-limit-ms" => {
                options.p99_limit_ms = value
                    .parse()
                    .ok()
                    .filter(|ms: &f64| ms.is_finite() && *ms > 0.0)
                    .with_context(|| format!("--p99-limit-ms: {value:?} is not a time > 0 ms"))?
            }
            "--millgate" => options.millgate = PathBuf::from(&value),
            _ => bail!(
                "unknown option {arg} (allowed: --duration, --every, --warm-up, --drivelines, \
                 --tandem-stands, --tandem-rate-hz, --cpu, --p99-limit-ms, --keep-going, --millgate)"
            ),
        }
    }
    if !options.millgate.is_file() {
        bail!(
            "{}: no millgate binary (build it: cargo build --release -p millgate --bin millgate)",
            options.millgate.display()
        );
    }
    if options.warm_up >= options.duration {
        bail!("--warm-up must be shorter than --duration");
    }
    Ok(options)
}

/// The load points: the lists stepped together, a single value held.
fn load_points(options: &Options) -> anyhow::Result<Vec<(usize, usize)>> {
    let (n, m) = (&options.drivelines, &options.tandem_stands);
    let steps = n.len().max(m.len());
    let at = |list: &Vec<usize>, i: usize| if list.len() == 1 { list[0] } else { list[i] };
    if (n.len() != 1 && n.len() != steps) || (m.len() != 1 && m.len() != steps) {
        bail!("--drivelines and --tandem-stands: lists of equal length, or one value");
    }
    Ok((0..steps).map(|i| (at(n, i), at(m, i))).collect())
}

/// A free loopback port (released at once: the gateway binds it right after).
fn free_port() -> anyhow::Result<SocketAddr> {
    Ok(StdListener::bind("127.0.0.1:0")?.local_addr()?)
}

/// VmRSS (KiB), threads, open descriptors and CPU time (s, all threads) of `pid`.
fn process_figures(pid: u32) -> anyhow::Result<(u64, u64, usize, f64)> {
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
    // Fields after the command's closing parenthesis: utime and stime are the 12th
    // and 13th (fields 14 and 15 of proc(5)).
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat"))?;
    let after = stat
        .rsplit_once(')')
        .map(|(_, rest)| rest)
        .context("/proc/<pid>/stat without a command")?;
    let ticks: Vec<f64> = after
        .split_whitespace()
        .skip(11)
        .take(2)
        .map(str::parse)
        .collect::<Result<_, _>>()?;
    Ok((
        field("VmRSS:")?,
        field("Threads:")?,
        fds,
        ticks.iter().sum::<f64>() / USER_HZ,
    ))
}

/// One HTTP/1.1 GET over a new connection: the status and the body.
fn get(address: SocketAddr, path: &str) -> anyhow::Result<(u16, String)> {
    let mut stream = TcpStream::connect_timeout(&address, Duration::from_secs(2))?;
    stream.set_read_timeout(Some(Duration::from_secs(5)))?;
    write!(
        stream,
        "GET {path} HTTP/1.1\r\nHost: {address}\r\nConnection: close\r\n\r\n"
    )?;
    let mut text = String::new();
    stream.read_to_string(&mut text)?;
    let status = text
        .split_whitespace()
        .nth(1)
        .and_then(|code| code.parse().ok())
        .with_context(|| format!("GET {path}: no status line"))?;
    let body = text
        .split_once("\r\n\r\n")
        .map_or(String::new(), |(_, body)| body.to_owned());
    Ok((status, body))
}

/// GETs `/` and `/api/overview` of the web page and `/metrics`: what did not answer
/// 200, and the metrics' text.
fn web_answers(web: SocketAddr, metrics: SocketAddr) -> (Vec<String>, Option<String>) {
    let mut failures = Vec::new();
    let mut metrics_text = None;
    for (address, path) in [(web, "/"), (web, "/api/overview"), (metrics, "/metrics")] {
        match get(address, path) {
            Ok((200, body)) => {
                if path == "/metrics" {
                    metrics_text = Some(body);
                }
            }
            Ok((status, _)) => failures.push(format!("{path}: {status}")),
            Err(error) => failures.push(format!("{path}: {error:#}")),
        }
    }
    (failures, metrics_text)
}

/// The sum of every sample of the Prometheus text whose name (before the labels) is
/// `metric`.
fn metric_sum(text: &str, metric: &str) -> f64 {
    text.lines()
        .filter(|line| {
            line.strip_prefix(metric)
                .is_some_and(|rest| rest.starts_with(['{', ' ']))
        })
        .filter_map(|line| line.rsplit_once(' ')?.1.parse::<f64>().ok())
        .fold(0.0, |sum, value| sum + value)
}

/// A child process killed and reaped when dropped (the gateway, even on an error).
struct Killed(Child);

impl Drop for Killed {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// A channel of the generated configuration on a virtual DAQ.
struct GeneratedChannel {
    toml: String,
    daq_channel: DaqChannel,
}

/// The virtual DAQs of one rate and their `[[sources.modbus]]` tables.
fn daqs(
    prefix: &str,
    rate_hz: f64,
    block: u16,
    channels: Vec<GeneratedChannel>,
    log_reads: bool,
    config: &mut String,
    listeners: &mut Vec<(VirtualDaq, std::net::TcpListener)>,
) -> anyhow::Result<()> {
    let block_ms = f64::from(block) / rate_hz * 1e3;
    let poll_ms = (block_ms / 3.0).floor().min(20.0);
    let mut channels = channels.into_iter().peekable();
    let mut daq = 0;
    while channels.peek().is_some() {
        let listener = StdListener::bind("127.0.0.1:0")?;
        let name = format!("{prefix}{daq}");
        config.push_str(&format!(
            "[[sources.modbus]]\nname = \"{name}\"\naddress = \"{}\"\n\
             poll_period_ms = {poll_ms}\ntimeout_ms = 500\n\n",
            listener.local_addr()?
        ));
        let mut played = Vec::new();
        for (slot, channel) in channels.by_ref().take(CHANNELS_PER_DAQ).enumerate() {
            let base = slot as u16 * BLOCK_REGISTERS;
            config.push_str(&channel.toml.replace(
                "SOURCE",
                &format!("{{ modbus = \"{name}\", table = \"input\", block = {base} }}"),
            ));
            let mut daq_channel = channel.daq_channel;
            daq_channel.placement.address = base;
            played.push(daq_channel);
        }
        let device = VirtualDaq::new(rate_hz, block, played).looped();
        let device = if log_reads {
            device.logging_reads()
        } else {
            device
        };
        listeners.push((device, listener));
        daq += 1;
    }
    Ok(())
}

/// A block channel placed at 0 (its DAQ places it), scaled 0.01 per LSB.
fn block_channel(signal: Vec<f64>) -> DaqChannel {
    DaqChannel {
        placement: Placement {
            table: RegisterTable::Input,
            address: 0,
            scale: 0.01,
            offset: 0.0,
        },
        publish: Publish::Block,
        signal,
    }
}

/// The configuration of a load point (in `folder`, beside a copy of the demo's
/// model) and the DAQs it reads, bound but not yet serving.
struct LoadPoint {
    config: millgate_config::Config,
    config_path: PathBuf,
    daqs: Vec<(VirtualDaq, std::net::TcpListener)>,
    plc_listener: std::net::TcpListener,
    server: SocketAddr,
    metrics: SocketAddr,
    web: SocketAddr,
}

fn load_point(
    folder: &Path,
    drivelines: usize,
    stands: usize,
    tandem_rate_hz: f64,
    broker_port: u16,
) -> anyhow::Result<LoadPoint> {
    let model = Path::new(env!("CARGO_MANIFEST_DIR")).join("../sim/models/table2-adjusted.toml");
    std::fs::copy(&model, folder.join("table2-adjusted.toml"))
        .with_context(|| format!("copying {}", model.display()))?;
    let mut config = format!("name = \"load bench: {drivelines} drivelines, {stands} stands\"\n\n");
    let mut listeners = Vec::new();

    let bars = setup(BARS_S, 0.5, 1)?.schedule.torque_knm;
    let stagger = (STAGGER_S * DRIVELINE_RATE_HZ) as usize;
    let mut torque_channels = Vec::new();
    let mut driveline_tables = String::new();
    for k in 0..drivelines {
        let mut signal = bars.clone();
        signal.rotate_right((k * stagger) % bars.len());
        torque_channels.push(GeneratedChannel {
            toml: format!(
                "[[channels]]\nname = \"d{k}_torque\"\nkind = \"torque\"\nunit = \"kN*m\"\n\
                 scale = 0.01\nsample_rate_hz = {DRIVELINE_RATE_HZ:.1}\nsource = SOURCE\n\n"
            ),
            daq_channel: block_channel(signal),
        });
        driveline_tables.push_str(&format!(
            "[[drivelines]]\nname = \"D{k}\"\ntorque = \"d{k}_torque\"\n\
             model = \"table2-adjusted.toml\"\n\
             bite = {{ threshold_knm = 20.0, pre_trigger_s = 0.1, post_trigger_s = {POST_TRIGGER_S} }}\n\
             thresholds = {{ taf_warning = 2.2, taf_alarm = 2.6, gap_warning_mrad = 2.0, gap_alarm_mrad = 4.0 }}\n\
             wear = {{ pool_bites = 5, gap_step_mrad = 0.25, torque_points = 12 }}\n\n"
        ));
    }
    daqs(
        "torque_daq",
        DRIVELINE_RATE_HZ,
        DRIVELINE_BLOCK,
        torque_channels,
        true,
        &mut config,
        &mut listeners,
    )?;

    let noise = rand_distr::Normal::new(0.0, STAND_NOISE_RMS)?;
    let mut stand_channels = Vec::new();
    for s in 0..stands {
        let mut rng = rand::rngs::StdRng::seed_from_u64(1000 + s as u64);
        let length = (STAND_NOISE_S * tandem_rate_hz) as usize;
        stand_channels.push(GeneratedChannel {
            toml: format!(
                "[[channels]]\nname = \"s{s}_vib\"\nkind = \"acceleration\"\nunit = \"m/s^2\"\n\
                 scale = 0.01\nsample_rate_hz = {tandem_rate_hz:.1}\nsource = SOURCE\n\n"
            ),
            daq_channel: block_channel((0..length).map(|_| noise.sample(&mut rng)).collect()),
        });
    }
    daqs(
        "stand_daq",
        tandem_rate_hz,
        STAND_BLOCK,
        stand_channels,
        false,
        &mut config,
        &mut listeners,
    )?;
    config.push_str(&driveline_tables);
    for (mill, first) in (0..stands).step_by(STANDS_PER_MILL).enumerate() {
        let names: Vec<String> = (first..stands.min(first + STANDS_PER_MILL))
            .map(|s| format!("\"s{s}_vib\""))
            .collect();
        let thresholds = vec!["3.0"; names.len()].join(", ");
        config.push_str(&format!(
            "[[tandem_mills]]\nname = \"TCM{mill}\"\nstands = [{}]\n\
             chatter_band_hz = [100.0, 300.0]\nwindow_s = 0.5\nk_max = 0.25\n\
             detector = \"band_gain\"\nreference_band_hz = [450.0, 900.0]\n\
             gain_window_s = 2.0\ngain_thresholds = [{thresholds}]\n\
             slow_down_release = 0.8\nslow_down_hold_s = 5.0\n\n",
            names.join(", ")
        ));
    }

    let plc_listener = StdListener::bind("127.0.0.1:0")?;
    let (server, metrics, web) = (free_port()?, free_port()?, free_port()?);
    config.push_str(&format!(
        "[outputs.plc]\naddress = \"{}\"\nregister_base = 0\nwrite_period_ms = 100\n\
         timeout_ms = 500\n\n[outputs.server]\nbind = \"{server}\"\n\n\
         [outputs.metrics]\nbind = \"{metrics}\"\n\n[outputs.web]\nbind = \"{web}\"\n\n\
         [history]\npath = \"history.db\"\n\n\
         [outputs.mqtt]\nbroker = \"127.0.0.1:{broker_port}\"\ngroup_id = \"load\"\n\
         node_id = \"bench\"\n",
        plc_listener.local_addr()?
    ));
    let config_path = folder.join("mill.toml");
    std::fs::write(&config_path, &config)?;
    let config = millgate_config::load(&config_path)
        .map_err(|error| anyhow::anyhow!("the generated configuration: {error}"))?;
    Ok(LoadPoint {
        config,
        config_path,
        daqs: listeners,
        plc_listener,
        server,
        metrics,
        web,
    })
}

/// Bite counters seen at the PLC and in the history, and the latencies between them.
#[derive(Default)]
struct Bites {
    /// The PLC's holding registers as the writes left them.
    plc_registers: Vec<u16>,
    /// Per driveline: the last bite counter the PLC held.
    plc_counter: Vec<u32>,
    /// (driveline, bite counter) -> the first write holding it.
    at_plc: HashMap<(usize, u32), SystemTime>,
    /// (driveline, bite counter) -> the bite's time and whether it is degraded.
    in_history: HashMap<(usize, u32), (UtcTime, bool)>,
    last_history_id: i64,
    /// Per driveline: the last block sequence its DAQ answered a read of its channel
    /// with, and the times of the answers that brought a new block (its deliveries),
    /// oldest first, those of the last [`Bites::DELIVERIES_KEPT`].
    deliveries: Vec<(Option<u16>, VecDeque<SystemTime>)>,
    /// Latencies of the bites after the warm-up, from the delivery of the block that
    /// completed the window, ms.
    latencies_ms: Vec<f64>,
    /// The same bites' latencies from their window's last sample, ms: an upper bound
    /// that includes the wait for the rest of the block and for the poll.
    from_sample_ms: Vec<f64>,
    /// Bites whose block could not be told from the deliveries (a write more than a
    /// block period after it): their latency is the upper bound.
    unattributed: usize,
    measured: std::collections::HashSet<(usize, u32)>,
}

impl Bites {
    /// How long block deliveries are kept: past the sample period that measures the
    /// bites they completed.
    const DELIVERIES_KEPT: Duration = Duration::from_secs(300);

    /// Takes the reads torque DAQ `daq` answered: a read of a channel's block with a
    /// sequence not read before delivered that block.
    fn daq_reads(&mut self, daq: usize, reads: Vec<ReadRecord>) {
        for read in reads {
            let driveline = daq * CHANNELS_PER_DAQ + usize::from(read.address / BLOCK_REGISTERS);
            if self.deliveries.len() <= driveline {
                self.deliveries
                    .resize(driveline + 1, (None, VecDeque::new()));
            }
            let (last, times) = &mut self.deliveries[driveline];
            if *last != Some(read.first_word) {
                *last = Some(read.first_word);
                times.push_back(read.time);
            }
        }
        let Some(keep) = SystemTime::now().checked_sub(Self::DELIVERIES_KEPT) else {
            return;
        };
        for (_, times) in &mut self.deliveries {
            while times.front().is_some_and(|&time| time < keep) {
                times.pop_front();
            }
        }
    }

    /// Takes the PLC's new writes into a copy of its registers (a map longer than
    /// one request is written in several, and a counter may straddle two): where a
    /// driveline's bite counter rises, every counter up to the new one is at the PLC
    /// from that write on.
    fn plc_writes(&mut self, plc: &VirtualPlc, counters: &[usize]) {
        self.plc_counter.resize(counters.len(), 0);
        for write in plc.take_write_log() {
            let start = usize::from(write.address);
            let end = start + write.words.len();
            if self.plc_registers.len() < end {
                self.plc_registers.resize(end, 0);
            }
            self.plc_registers[start..end].copy_from_slice(&write.words);
            for (driveline, &register) in counters.iter().enumerate() {
                if register + 2 <= start || register >= end {
                    continue;
                }
                let Some(counter) = self
                    .plc_registers
                    .get(register..register + 2)
                    .and_then(decode_u32)
                else {
                    continue;
                };
                for bite in self.plc_counter[driveline] + 1..=counter {
                    self.at_plc.insert((driveline, bite), write.time);
                }
                self.plc_counter[driveline] = self.plc_counter[driveline].max(counter);
            }
        }
    }

    /// Reads the bites the history has stored since the last call.
    fn history(&mut self, path: &Path, names: &HashMap<String, usize>) -> anyhow::Result<()> {
        let db = rusqlite::Connection::open_with_flags(
            path,
            rusqlite::OpenFlags::SQLITE_OPEN_READ_ONLY,
        )?;
        db.busy_timeout(Duration::from_secs(2))?;
        let mut query = db.prepare(
            "SELECT id, driveline, bite_counter, time, degraded FROM bites WHERE id > ?1 ORDER BY id",
        )?;
        let mut rows = query.query([self.last_history_id])?;
        while let Some(row) = rows.next()? {
            let id: i64 = row.get(0)?;
            let name: String = row.get(1)?;
            let counter: u32 = row.get(2)?;
            let time: String = row.get(3)?;
            let degraded: bool = row.get(4)?;
            let driveline = *names
                .get(&name)
                .with_context(|| format!("the history names an unknown driveline {name}"))?;
            let time = UtcTime::parse(&time)
                .map_err(|error| anyhow::anyhow!("history time {time:?}: {error}"))?;
            self.in_history
                .insert((driveline, counter), (time, degraded));
            self.last_history_id = id;
        }
        Ok(())
    }

    /// Latencies of the bites both at the PLC and in the history, timed after
    /// `measured_from`, not yet measured.
    fn measure(
        &mut self,
        measured_from: SystemTime,
        after_trigger: Duration,
        block_period: Duration,
    ) {
        for (key, (time, _)) in &self.in_history {
            if self.measured.contains(key) {
                continue;
            }
            let Some(written) = self.at_plc.get(key) else {
                continue;
            };
            self.measured.insert(*key);
            let complete = time.to_system() + after_trigger;
            if complete < measured_from {
                continue;
            }
            let ms_since = |from: SystemTime| {
                written
                    .duration_since(from)
                    .map_or_else(|early| -early.duration().as_secs_f64(), |d| d.as_secs_f64())
                    * 1e3
            };
            self.from_sample_ms.push(ms_since(complete));
            // The block that completed the window: the last delivered before the write,
            // when the window's last sample is in it. The gateway dates a block's last
            // sample at its arrival and the others back from it, so the window's last
            // sample is at most a block period (and the history's rounding down to the
            // ms) before the delivery; an earlier one was in an earlier block.
            let block = self
                .deliveries
                .get(key.0)
                .and_then(|(_, times)| times.iter().rev().find(|&&time| time <= *written))
                .filter(|&&delivered| {
                    complete + block_period + Duration::from_millis(1) >= delivered
                });
            match block {
                Some(&delivered) => self.latencies_ms.push(ms_since(delivered)),
                None => {
                    self.unattributed += 1;
                    self.latencies_ms.push(ms_since(complete));
                }
            }
        }
    }
}

/// Records in `stall` (us) the longest lateness of a 5 ms timer of the bench's runtime,
/// the one its virtual DAQs publish on, until aborted.
async fn watch_stalls(stall: Arc<AtomicU64>) {
    let period = Duration::from_millis(5);
    let mut ticks = tokio::time::interval(period);
    ticks.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let mut expected = tokio::time::Instant::now();
    loop {
        ticks.tick().await;
        let now = tokio::time::Instant::now();
        let late = now.saturating_duration_since(expected).as_micros() as u64;
        stall.fetch_max(late, Ordering::Relaxed);
        expected = now + period;
    }
}

/// Whether the quantile `q` of `sorted` is below `limit` (true without a value: no
/// bite measured, as at a load point without drivelines).
fn quantile_below(sorted: &[f64], q: f64, limit: f64) -> bool {
    let value = quantile(sorted, q);
    value.is_nan() || value < limit
}

fn quantile(sorted: &[f64], q: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    sorted[((sorted.len() - 1) as f64 * q).round() as usize]
}

/// What one load point measured.
struct Summary {
    drivelines: usize,
    stands: usize,
    channels: usize,
    samples_per_s: f64,
    cpu_percent: f64,
    rss_max_kib: u64,
    rss_growth_kib: i64,
    fds: (usize, usize),
    missed: f64,
    bites: u64,
    degraded: usize,
    not_in_history: usize,
    not_at_plc: usize,
    answers_failed: usize,
    answers: usize,
    sparkplug_bites: f64,
    /// Sorted, from the delivery of the block that completed the window.
    latencies_ms: Vec<f64>,
    /// Sorted, from the window's last sample (upper bounds).
    from_sample_ms: Vec<f64>,
    unattributed: usize,
}

impl Summary {
    fn passed(&self, p99_limit_ms: f64) -> bool {
        self.missed == 0.0
            && self.not_in_history == 0
            && self.not_at_plc == 0
            && self.answers_failed == 0
            && quantile_below(&self.latencies_ms, 0.99, p99_limit_ms)
    }
}

async fn run_point(options: &Options, drivelines: usize, stands: usize) -> anyhow::Result<Summary> {
    let folder = std::env::temp_dir().join(format!(
        "millgate-soak-{}-{drivelines}-{stands}",
        std::process::id()
    ));
    let _ = std::fs::remove_dir_all(&folder);
    std::fs::create_dir_all(&folder)?;
    let broker_port = free_port()?.port();
    let broker = Mosquitto::try_start(&folder, broker_port).map_err(anyhow::Error::msg)?;
    let point = load_point(
        &folder,
        drivelines,
        stands,
        options.tandem_rate_hz,
        broker_port,
    )?;
    let map = RegisterMap::new(&point.config);
    let counters: Vec<usize> = point
        .config
        .drivelines
        .iter()
        .map(|d| {
            map.named(&format!("{}.bite_counter", d.name))
                .map(|r| usize::from(r.address))
                .context("no bite counter register")
        })
        .collect::<anyhow::Result<_>>()?;
    let names: HashMap<String, usize> = point
        .config
        .drivelines
        .iter()
        .enumerate()
        .map(|(i, d)| (d.name.clone(), i))
        .collect();
    let channels = point.config.channels.len();
    let samples_per_s: f64 = point.config.channels.iter().map(|c| c.sample_rate_hz).sum();

    let plc = VirtualPlc::new(usize::from(map.len())).logging_writes();
    let mut devices: Vec<Running> = Vec::new();
    // The torque DAQs (the first ones) log their reads: the deliveries of the blocks.
    let torque_banks: Vec<SharedBank> = point
        .daqs
        .iter()
        .take(drivelines.div_ceil(CHANNELS_PER_DAQ))
        .map(|(daq, _)| daq.bank())
        .collect();
    for (daq, listener) in point.daqs {
        listener.set_nonblocking(true)?;
        devices.push(daq.spawn(
            tokio::net::TcpListener::from_std(listener)?,
            ServeOptions::default(),
        ));
    }
    point.plc_listener.set_nonblocking(true)?;
    devices.push(plc.spawn(
        tokio::net::TcpListener::from_std(point.plc_listener)?,
        ServeOptions::default(),
    ));

    let mut command = match &options.cpu {
        Some(cpu) => {
            let mut taskset = Command::new("taskset");
            taskset.args(["-c", cpu]).arg(&options.millgate);
            taskset
        }
        None => Command::new(&options.millgate),
    };
    let gateway = Killed(
        command
            .args(["run", "--config"])
            .arg(&point.config_path)
            .env("RUST_LOG", "warn")
            .stdout(Stdio::null())
            .stderr(Stdio::inherit())
            .spawn()
            .with_context(|| format!("cannot start {}", options.millgate.display()))?,
    );
    let pid = gateway.0.id();
    let stall = Arc::new(AtomicU64::new(0));
    let stall_watch = tokio::spawn(watch_stalls(Arc::clone(&stall)));
    println!(
        "load point: {drivelines} drivelines at {DRIVELINE_RATE_HZ} Hz, {stands} stands at {} Hz \
         ({channels} channels, {samples_per_s:.0} samples/s), {:.0} s (warm-up {:.0} s), \
         pid {pid}{}",
        options.tandem_rate_hz,
        options.duration.as_secs_f64(),
        options.warm_up.as_secs_f64(),
        options
            .cpu
            .as_ref()
            .map_or(String::new(), |cpu| format!(" on core {cpu}"))
    );
    println!(
        "{:>6} {:>8} {:>4} {:>4} {:>6} {:>6} {:>5} {:>6} {:>5} {:>6} {:>7} {:>8} {:>7}",
        "t_s",
        "rss_kib",
        "fds",
        "thr",
        "cpu_%",
        "bites",
        "degr",
        "missed",
        "fails",
        "p99_ms",
        "mqtt",
        "stall_ms",
        "bench_%"
    );

    let history = folder.join("history.db");
    let after_trigger = Duration::from_secs_f64(
        ((POST_TRIGGER_S * DRIVELINE_RATE_HZ).round() - 1.0) / DRIVELINE_RATE_HZ,
    );
    let block_period = Duration::from_secs_f64(f64::from(DRIVELINE_BLOCK) / DRIVELINE_RATE_HZ);
    let mut bites = Bites::default();
    let mut hmi: Option<tokio_modbus::client::Context> = None;
    let started = Instant::now();
    let mut measured_from: Option<(SystemTime, f64, f64)> = None;
    let mut last_cpu = (Instant::now(), 0.0);
    let mut bench_cpu = (Instant::now(), 0.0);
    let mut samples: Vec<(u64, usize)> = Vec::new();
    let (mut answers, mut answers_failed) = (0, 0);
    let mut last_metrics = String::new();
    let mut rss_max = 0;
    let mut cpu_end = 0.0;
    while started.elapsed() < options.duration {
        let next = options
            .every
            .min(options.duration.saturating_sub(started.elapsed()));
        tokio::time::sleep(next).await;
        let warm = started.elapsed() >= options.warm_up;
        if hmi.is_none() {
            hmi = tokio_modbus::client::tcp::connect(point.server).await.ok();
        }
        if let Some(context) = hmi.as_mut() {
            if !matches!(context.read_holding_registers(0, 48).await, Ok(Ok(_))) {
                hmi = None;
            }
        }
        // The blocking work (HTTP, /proc, the history file) off the runtime's workers,
        // which the virtual DAQs publish on: a stalled DAQ skips blocks.
        let (web, metrics) = (point.web, point.metrics);
        let (history_path, plc_now, counters_now, names_now, banks_now) = (
            history.clone(),
            plc.clone(),
            counters.clone(),
            names.clone(),
            torque_banks.clone(),
        );
        let (returned, (figures, bench), failures, metrics_text) =
            tokio::task::spawn_blocking(move || -> anyhow::Result<_> {
                let figures = process_figures(pid);
                let bench = process_figures(std::process::id());
                let (failures, metrics_text) = web_answers(web, metrics);
                for (daq, bank) in banks_now.iter().enumerate() {
                    bites.daq_reads(daq, bank.take_read_log());
                }
                bites.plc_writes(&plc_now, &counters_now);
                if history_path.exists() {
                    bites.history(&history_path, &names_now)?;
                }
                Ok((bites, (figures, bench), failures, metrics_text))
            })
            .await??;
        bites = returned;
        let (rss, threads, fds, cpu_s) =
            figures.context("the gateway is gone (it exited during the run)")?;
        if let Some(text) = metrics_text {
            last_metrics = text;
        }
        if warm {
            answers += 3;
            answers_failed += failures.len();
        }
        if !failures.is_empty() {
            println!("       no answer: {}", failures.join("; "));
        }
        let missed = metric_sum(&last_metrics, "millgate_channel_blocks_missed_total");
        let bite_total = metric_sum(&last_metrics, "millgate_driveline_bites_total");
        let cpu_percent = (cpu_s - last_cpu.1) / last_cpu.0.elapsed().as_secs_f64() * 100.0;
        last_cpu = (Instant::now(), cpu_s);
        let bench_s = bench.map_or(f64::NAN, |figures| figures.3);
        let bench_percent = (bench_s - bench_cpu.1) / bench_cpu.0.elapsed().as_secs_f64() * 100.0;
        bench_cpu = (Instant::now(), bench_s);
        if warm && measured_from.is_none() {
            measured_from = Some((SystemTime::now(), cpu_s, missed));
        }
        if let Some((from, _, _)) = measured_from {
            bites.measure(from, after_trigger, block_period);
        }
        let mut sorted = bites.latencies_ms.clone();
        sorted.sort_by(f64::total_cmp);
        println!(
            "{:>6.0} {:>8} {:>4} {:>4} {:>6.1} {:>6} {:>5} {:>6} {:>5} {:>6.2} {:>7} {:>8.1} {:>7.1}",
            started.elapsed().as_secs_f64(),
            rss,
            fds,
            threads,
            cpu_percent,
            bite_total,
            bites.in_history.values().filter(|(_, d)| *d).count(),
            missed,
            failures.len(),
            quantile(&sorted, 0.99),
            metric_sum(&last_metrics, "millgate_sparkplug_bites_published_total"),
            stall.swap(0, Ordering::Relaxed) as f64 / 1e3,
            bench_percent,
        );
        if warm {
            samples.push((rss, fds));
            rss_max = rss_max.max(rss);
            cpu_end = cpu_s;
        }
    }
    // The last bites: what the gateway counted is in the history and at the PLC once
    // the writer has written them (at most a write period and a commit later).
    tokio::time::sleep(Duration::from_secs(1)).await;
    let final_metrics = get(point.metrics, "/metrics")
        .map(|(_, body)| body)
        .unwrap_or(last_metrics);
    for (daq, bank) in torque_banks.iter().enumerate() {
        bites.daq_reads(daq, bank.take_read_log());
    }
    bites.plc_writes(&plc, &counters);
    bites.history(&history, &names)?;
    let (from, cpu_from, missed_from) = measured_from.context("no sample after the warm-up")?;
    bites.measure(from, after_trigger, block_period);
    drop(gateway);
    stall_watch.abort();
    for device in devices {
        device.stop().await?;
    }
    drop(broker);
    std::fs::remove_dir_all(&folder)?;

    let counted: BTreeMap<usize, u32> = point
        .config
        .drivelines
        .iter()
        .enumerate()
        .map(|(i, d)| {
            let line = format!("millgate_driveline_bites_total{{driveline=\"{}\"}}", d.name);
            (i, metric_sum(&final_metrics, &line) as u32)
        })
        .collect();
    let mut not_in_history = 0;
    let mut not_at_plc = 0;
    for (&driveline, &count) in &counted {
        for bite in 1..=count {
            not_in_history += usize::from(!bites.in_history.contains_key(&(driveline, bite)));
            not_at_plc += usize::from(!bites.at_plc.contains_key(&(driveline, bite)));
        }
    }
    let measured_s = from.elapsed().map_or(0.0, |d| d.as_secs_f64());
    let (first, last) = (
        samples.first().copied().unwrap_or_default(),
        samples.last().copied().unwrap_or_default(),
    );
    let mut latencies_ms = bites.latencies_ms;
    latencies_ms.sort_by(f64::total_cmp);
    let mut from_sample_ms = bites.from_sample_ms;
    from_sample_ms.sort_by(f64::total_cmp);
    Ok(Summary {
        drivelines,
        stands,
        channels,
        samples_per_s,
        cpu_percent: (cpu_end - cpu_from) / measured_s * 100.0,
        rss_max_kib: rss_max,
        rss_growth_kib: last.0 as i64 - first.0 as i64,
        fds: samples
            .iter()
            .fold((usize::MAX, 0), |(lo, hi), s| (lo.min(s.1), hi.max(s.1))),
        missed: metric_sum(&final_metrics, "millgate_channel_blocks_missed_total") - missed_from,
        bites: counted.values().map(|&c| u64::from(c)).sum(),
        degraded: bites.in_history.values().filter(|(_, d)| *d).count(),
        not_in_history,
        not_at_plc,
        answers_failed,
        answers,
        sparkplug_bites: metric_sum(&final_metrics, "millgate_sparkplug_bites_published_total"),
        latencies_ms,
        from_sample_ms,
        unattributed: bites.unattributed,
    })
}

// Two workers whatever the bench is pinned to: the DAQs publish on one while the
// other waits on the gateway.
#[tokio::main(flavor = "multi_thread", worker_threads = 2)]
async fn main() -> anyhow::Result<()> {
    let options = options()?;
    let mut summaries = Vec::new();
    for (drivelines, stands) in load_points(&options)? {
        let summary = run_point(&options, drivelines, stands).await?;
        let passed = summary.passed(options.p99_limit_ms);
        summaries.push(summary);
        print_table(&summaries, options.p99_limit_ms);
        if !passed && !options.keep_going {
            println!("stopped: this load point failed");
            break;
        }
    }
    Ok(())
}

fn print_table(summaries: &[Summary], p99_limit_ms: f64) {
    println!(
        "{:>3} {:>3} {:>4} {:>7} {:>6} {:>8} {:>8} {:>7} {:>7} {:>6} {:>5} {:>7} {:>7} {:>7} \
         {:>7} {:>6} {:>5} {:>4}",
        "N",
        "M",
        "ch",
        "samp/s",
        "cpu_%",
        "%/ch",
        "rss_kib",
        "rss_+",
        "fds",
        "missed",
        "bites",
        "p50_ms",
        "p99_ms",
        "max_ms",
        "no_hist",
        "no_plc",
        "fails",
        "pass"
    );
    for s in summaries {
        let l = &s.latencies_ms;
        println!(
            "{:>3} {:>3} {:>4} {:>7.0} {:>6.1} {:>8.3} {:>8} {:>7} {:>7} {:>6} {:>5} {:>7.2} \
             {:>7.2} {:>7.2} {:>7} {:>6} {:>5} {:>4}",
            s.drivelines,
            s.stands,
            s.channels,
            s.samples_per_s,
            s.cpu_percent,
            s.cpu_percent / s.channels as f64,
            s.rss_max_kib,
            s.rss_growth_kib,
            format!("{}..{}", s.fds.0, s.fds.1),
            s.missed,
            s.bites,
            quantile(l, 0.5),
            quantile(l, 0.99),
            l.last().copied().unwrap_or(f64::NAN),
            s.not_in_history,
            s.not_at_plc,
            format!("{}/{}", s.answers_failed, s.answers),
            if s.passed(p99_limit_ms) { "yes" } else { "no" },
        );
        println!(
            "    {} bites measured, {} degraded, {} Sparkplug bite DDATAs; from the window's \
             last sample (block and poll wait included) p50 {:.2} ms, p99 {:.2} ms, max {:.2} \
             ms; {} bites not told from their block (measured from the last sample)",
            l.len(),
            s.degraded,
            s.sparkplug_bites,
            quantile(&s.from_sample_ms, 0.5),
            quantile(&s.from_sample_ms, 0.99),
            s.from_sample_ms.last().copied().unwrap_or(f64::NAN),
            s.unattributed,
        );
    }
}
