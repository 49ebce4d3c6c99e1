//! The samples of a load point: every `--every` s the HMI's read, the web page's and
//! `/metrics`' answers, the process figures of the gateway and of the bench, and the
//! new bites, each sample a printed row.

use std::collections::{BTreeMap, HashMap};
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant, SystemTime};

use anyhow::Context as _;
use millgate_sim::devices::modbus_bank::SharedBank;
use millgate_sim::devices::virtual_plc::VirtualPlc;
use tokio_modbus::client::Reader;

use crate::bites::{quantile, Bites};
use crate::options::Options;
use crate::probe::{
    get, machine_ticks, metric_sum, process_figures, runnable_waits, web_answers, ProcessFigures,
};

/// What the samples read: the gateway's process and addresses, the sources of the
/// bite bookkeeping and the bench's timer stall.
pub(crate) struct Watched {
    pub(crate) pid: u32,
    /// The HMI (Modbus) server, the web page and `/metrics`.
    pub(crate) server: SocketAddr,
    pub(crate) web: SocketAddr,
    pub(crate) metrics: SocketAddr,
    /// The history file (created by the gateway).
    pub(crate) history: PathBuf,
    /// The virtual PLC, logging its writes.
    pub(crate) plc: VirtualPlc,
    /// The torque DAQs' banks, logging their reads.
    pub(crate) torque_banks: Vec<SharedBank>,
    /// Per driveline: the register of its bite counter.
    pub(crate) counters: Vec<usize>,
    /// Driveline name -> its number.
    pub(crate) names: HashMap<String, usize>,
    /// The bench's longest timer lateness since the last sample, us.
    pub(crate) stall: Arc<AtomicU64>,
}

impl Watched {
    /// Takes the torque DAQs' reads, the PLC's writes and the history's new bites into
    /// `bites`; a history not yet created is skipped unless `history_required`.
    fn collect(&self, bites: &mut Bites, history_required: bool) -> anyhow::Result<()> {
        for (daq, bank) in self.torque_banks.iter().enumerate() {
            bites.daq_reads(daq, bank.take_read_log());
        }
        bites.plc_writes(&self.plc, &self.counters);
        if history_required || self.history.exists() {
            bites.history(&self.history, &self.names)?;
        }
        Ok(())
    }
}

/// The end of the warm-up: when, and the gateway's figures then.
#[derive(Clone, Copy)]
pub(crate) struct WarmUpEnd {
    pub(crate) time: SystemTime,
    /// The gateway's CPU time, s.
    pub(crate) cpu_s: f64,
    /// The blocks the gateway had missed.
    pub(crate) missed: f64,
}

/// What the samples gathered, and what one sample compares with the last.
pub(crate) struct Sampler {
    started: Instant,
    /// The HMI's connection, made again after a failed read.
    hmi: Option<tokio_modbus::client::Context>,
    pub(crate) warm_up_end: Option<WarmUpEnd>,
    /// The gateway's and the bench's CPU time at the last sample (s), and when.
    last_cpu: (Instant, f64),
    bench_cpu: (Instant, f64),
    /// The machine's ticks, all and stolen, at the last sample ([`machine_ticks`]).
    machine: (u64, u64),
    /// The gateway's threads' waits for a CPU at the last sample, ns, and when.
    waits: (Instant, BTreeMap<u32, u64>),
    /// RSS (KiB) and descriptors of each sample after the warm-up.
    pub(crate) samples: Vec<(u64, usize)>,
    /// After the warm-up: the web page's and `/metrics`' answers asked, and failed.
    pub(crate) answers: usize,
    pub(crate) answers_failed: usize,
    /// The last `/metrics` text that answered.
    last_metrics: String,
    /// The largest RSS after the warm-up, KiB.
    pub(crate) rss_max: u64,
    /// The gateway's CPU time at the last sample after the warm-up, s.
    pub(crate) cpu_end: f64,
    pub(crate) bites: Bites,
}

/// One sample's readings, taken off the runtime's workers.
struct Reading {
    gateway: anyhow::Result<ProcessFigures>,
    bench: anyhow::Result<ProcessFigures>,
    machine: anyhow::Result<(u64, u64)>,
    /// The gateway's threads' waits for a CPU ([`runnable_waits`]).
    waits: anyhow::Result<BTreeMap<u32, u64>>,
    /// The GETs that did not answer 200.
    failures: Vec<String>,
    metrics_text: Option<String>,
}

/// Prints the header of the samples' rows.
pub(crate) fn print_columns() {
    println!(
        "{:>6} {:>8} {:>4} {:>4} {:>6} {:>6} {:>6} {:>5} {:>6} {:>5} {:>6} {:>7} {:>8} {:>7} {:>7}",
        "t_s",
        "rss_kib",
        "fds",
        "thr",
        "cpu_%",
        "wait_%",
        "bites",
        "degr",
        "missed",
        "fails",
        "p99_ms",
        "mqtt",
        "stall_ms",
        "bench_%",
        "steal_%"
    );
}

/// Samples the load point every `--every` s for `--duration` s, a row each, and once at
/// the end of the warm-up whatever `--every` is: the figures after the warm-up (p99,
/// CPU, blocks missed) count from that sample.
pub(crate) async fn sample(options: &Options, watched: &Arc<Watched>) -> anyhow::Result<Sampler> {
    let mut sampler = Sampler::new();
    while sampler.started.elapsed() < options.duration {
        let elapsed = sampler.started.elapsed();
        let mut next = options.every.min(options.duration.saturating_sub(elapsed));
        if let Some(to_warm) = options
            .warm_up
            .checked_sub(elapsed)
            .filter(|d| !d.is_zero())
        {
            next = next.min(to_warm);
        }
        tokio::time::sleep(next).await;
        let warm = sampler.started.elapsed() >= options.warm_up;
        sampler.read_hmi(watched.server).await;
        let reading = sampler.read(watched).await?;
        sampler.record(reading, warm, &watched.stall)?;
    }
    Ok(sampler)
}

impl Sampler {
    fn new() -> Sampler {
        Sampler {
            started: Instant::now(),
            hmi: None,
            warm_up_end: None,
            last_cpu: (Instant::now(), 0.0),
            bench_cpu: (Instant::now(), 0.0),
            machine: machine_ticks().unwrap_or_default(),
            waits: (Instant::now(), BTreeMap::new()),
            samples: Vec::new(),
            answers: 0,
            answers_failed: 0,
            last_metrics: String::new(),
            rss_max: 0,
            cpu_end: 0.0,
            bites: Bites::default(),
        }
    }

    /// The HMI reads the first 48 registers (connecting first if it is not).
    async fn read_hmi(&mut self, server: SocketAddr) {
        if self.hmi.is_none() {
            self.hmi = tokio_modbus::client::tcp::connect(server).await.ok();
        }
        if let Some(context) = self.hmi.as_mut() {
            if !matches!(context.read_holding_registers(0, 48).await, Ok(Ok(_))) {
                self.hmi = None;
            }
        }
    }

    /// The process figures, the web answers and the new bites. The blocking work
    /// (HTTP, /proc, the history file) off the runtime's workers, which the virtual
    /// DAQs publish on: a stalled DAQ skips blocks.
    async fn read(&mut self, watched: &Arc<Watched>) -> anyhow::Result<Reading> {
        let watched = Arc::clone(watched);
        let mut bites = std::mem::take(&mut self.bites);
        let (returned, reading) = tokio::task::spawn_blocking(move || -> anyhow::Result<_> {
            let gateway = process_figures(watched.pid);
            let bench = process_figures(std::process::id());
            let machine = machine_ticks();
            let waits = runnable_waits(watched.pid);
            let (failures, metrics_text) = web_answers(watched.web, watched.metrics);
            watched.collect(&mut bites, false)?;
            let reading = Reading {
                gateway,
                bench,
                machine,
                waits,
                failures,
                metrics_text,
            };
            Ok((bites, reading))
        })
        .await??;
        self.bites = returned;
        Ok(reading)
    }

    /// Takes one sample's readings (counted after the warm-up), measures the bites
    /// so far and prints the row.
    fn record(&mut self, reading: Reading, warm: bool, stall: &AtomicU64) -> anyhow::Result<()> {
        let gateway = reading
            .gateway
            .context("the gateway is gone (it exited during the run)")?;
        if let Some(text) = reading.metrics_text {
            self.last_metrics = text;
        }
        if warm {
            self.answers += 3;
            self.answers_failed += reading.failures.len();
        }
        if !reading.failures.is_empty() {
            println!("       no answer: {}", reading.failures.join("; "));
        }
        let missed = metric_sum(&self.last_metrics, "millgate_channel_blocks_missed_total");
        let bite_total = metric_sum(&self.last_metrics, "millgate_driveline_bites_total");
        let cpu_percent =
            (gateway.cpu_s - self.last_cpu.1) / self.last_cpu.0.elapsed().as_secs_f64() * 100.0;
        self.last_cpu = (Instant::now(), gateway.cpu_s);
        let bench_s = reading.bench.map_or(f64::NAN, |figures| figures.cpu_s);
        let bench_percent =
            (bench_s - self.bench_cpu.1) / self.bench_cpu.0.elapsed().as_secs_f64() * 100.0;
        self.bench_cpu = (Instant::now(), bench_s);
        let steal_percent = match reading.machine {
            Ok((all, stolen)) => {
                let (last_all, last_stolen) = std::mem::replace(&mut self.machine, (all, stolen));
                100.0 * stolen.saturating_sub(last_stolen) as f64
                    / all.saturating_sub(last_all).max(1) as f64
            }
            Err(_) => f64::NAN,
        };
        let wait_percent = match reading.waits {
            Ok(waits) => {
                let (since, last) = &self.waits;
                // A thread started since the last sample counts its whole wait.
                let waited: u64 = waits
                    .iter()
                    .map(|(tid, &now)| now.saturating_sub(last.get(tid).copied().unwrap_or(0)))
                    .sum();
                let percent = waited as f64 / 1e9 / since.elapsed().as_secs_f64() * 100.0;
                self.waits = (Instant::now(), waits);
                percent
            }
            Err(_) => f64::NAN,
        };
        if warm && self.warm_up_end.is_none() {
            self.warm_up_end = Some(WarmUpEnd {
                time: SystemTime::now(),
                cpu_s: gateway.cpu_s,
                missed,
            });
        }
        if let Some(warm_up_end) = self.warm_up_end {
            self.bites.measure(warm_up_end.time);
        }
        let mut sorted = self.bites.latencies_ms.clone();
        sorted.sort_by(f64::total_cmp);
        println!(
            "{:>6.0} {:>8} {:>4} {:>4} {:>6.1} {:>6.1} {:>6} {:>5} {:>6} {:>5} {:>6.2} {:>7} {:>8.1} {:>7.1} {:>7.1}",
            self.started.elapsed().as_secs_f64(),
            gateway.rss_kib,
            gateway.fds,
            gateway.threads,
            cpu_percent,
            wait_percent,
            bite_total,
            self.bites.degraded(),
            missed,
            reading.failures.len(),
            quantile(&sorted, 0.99),
            metric_sum(&self.last_metrics, "millgate_sparkplug_bites_published_total"),
            stall.swap(0, Ordering::Relaxed) as f64 / 1e3,
            bench_percent,
            steal_percent,
        );
        if warm {
            self.samples.push((gateway.rss_kib, gateway.fds));
            self.rss_max = self.rss_max.max(gateway.rss_kib);
            self.cpu_end = gateway.cpu_s;
        }
        Ok(())
    }

    /// Measures the last bites a second after the last sample: what the gateway counted
    /// is in the history and at the PLC once the writer has written them (at most a
    /// write period and a commit later). Returns the final `/metrics` text (the last
    /// that answered if this GET fails) and the end of the warm-up.
    pub(crate) async fn finish(
        &mut self,
        watched: &Watched,
    ) -> anyhow::Result<(String, WarmUpEnd)> {
        tokio::time::sleep(Duration::from_secs(1)).await;
        let final_metrics = get(watched.metrics, "/metrics")
            .map(|(_, body)| body)
            .unwrap_or_else(|_| std::mem::take(&mut self.last_metrics));
        watched.collect(&mut self.bites, true)?;
        let warm_up_end = self.warm_up_end.context("no sample after the warm-up")?;
        self.bites.measure(warm_up_end.time);
        Ok((final_metrics, warm_up_end))
    }
}
