//! One load point's run: the broker, the field devices and the gateway started, the
//! samples taken, everything stopped, the final checks in its summary.

use std::collections::{BTreeMap, HashMap};
use std::net::TcpListener as StdListener;
use std::path::Path;
use std::process::{Command, Stdio};
use std::sync::atomic::AtomicU64;
use std::sync::Arc;

use anyhow::Context as _;
use millgate::outputs::modbus::register_map::RegisterMap;
use millgate_config::Config;
use millgate_sim::devices::modbus_bank::{Running, ServeOptions, SharedBank};
use millgate_sim::devices::virtual_daq::VirtualDaq;
use millgate_sim::devices::virtual_plc::VirtualPlc;
use millgate_tests::kit::broker::Broker as Mosquitto;

use crate::daqs::{load_point, CHANNELS_PER_DAQ, DRIVELINE_RATE_HZ};
use crate::options::Options;
use crate::probe::{free_port, metric_sum, watch_stalls, Killed, Removed};
use crate::samples::{print_columns, sample, Sampler, WarmUpEnd, Watched};
use crate::summary::Summary;

/// Runs one load point for `--duration` s and checks it.
pub(crate) async fn run_point(
    options: &Options,
    drivelines: usize,
    stands: usize,
) -> anyhow::Result<Summary> {
    let folder = std::env::temp_dir().join(format!(
        "millgate-soak-{}-{drivelines}-{stands}",
        std::process::id()
    ));
    let _ = std::fs::remove_dir_all(&folder);
    std::fs::create_dir_all(&folder)?;
    // Dropped last: the folder goes after the processes that write in it, also when
    // the point ends early (an error, a signal).
    let _removed = Removed(folder.clone());
    let broker_port = free_port()?.port();
    let broker = Mosquitto::try_start(&folder, broker_port).map_err(anyhow::Error::msg)?;
    let point = load_point(&folder, (drivelines, stands), options, broker_port)?;
    let map = RegisterMap::new(&point.config);
    let counters = bite_counters(&point.config, &map)?;
    let names: HashMap<String, usize> = point
        .config
        .drivelines
        .iter()
        .enumerate()
        .map(|(i, d)| (d.name.clone(), i))
        .collect();

    let plc = VirtualPlc::new(usize::from(map.len())).logging_writes();
    let (devices, torque_banks) =
        start_field_devices(point.daqs, &plc, point.plc_listener, drivelines)?;
    let gateway = start_gateway(options, &point.config_path)?;
    let pid = gateway.0.id();
    let stall = Arc::new(AtomicU64::new(0));
    let stall_watch = tokio::spawn(watch_stalls(Arc::clone(&stall)));
    print_load_point(options, drivelines, stands, &point.config, pid);
    print_columns();
    let watched = Arc::new(Watched {
        pid,
        server: point.server,
        web: point.web,
        metrics: point.metrics,
        history: folder.join("history.db"),
        plc,
        torque_banks,
        counters,
        names,
        stall,
    });
    let mut sampler = sample(options, &watched).await?;
    let (final_metrics, warm_up_end) = sampler.finish(&watched).await?;
    print_gateway_latency(&final_metrics);

    drop(gateway);
    stall_watch.abort();
    for device in devices {
        device.stop().await?;
    }
    drop(broker);
    std::fs::remove_dir_all(&folder)?;
    Ok(summarize(
        &point.config,
        (drivelines, stands),
        sampler,
        &final_metrics,
        warm_up_end,
    ))
}

/// Per driveline: the register of its bite counter in the map.
fn bite_counters(config: &Config, map: &RegisterMap) -> anyhow::Result<Vec<usize>> {
    config
        .drivelines
        .iter()
        .map(|d| {
            map.named(&format!("{}.bite_counter", d.name))
                .map(|r| usize::from(r.address))
                .context("no bite counter register")
        })
        .collect()
}

/// Starts the virtual DAQs and the PLC serving: the devices, and the banks of the
/// torque DAQs (the first ones), which log their reads (the deliveries of the blocks).
fn start_field_devices(
    daqs: Vec<(VirtualDaq, StdListener)>,
    plc: &VirtualPlc,
    plc_listener: StdListener,
    drivelines: usize,
) -> anyhow::Result<(Vec<Running>, Vec<SharedBank>)> {
    let mut devices: Vec<Running> = Vec::new();
    let torque_banks: Vec<SharedBank> = daqs
        .iter()
        .take(drivelines.div_ceil(CHANNELS_PER_DAQ))
        .map(|(daq, _)| daq.bank())
        .collect();
    for (daq, listener) in daqs {
        listener.set_nonblocking(true)?;
        devices.push(daq.spawn(
            tokio::net::TcpListener::from_std(listener)?,
            ServeOptions::default(),
        ));
    }
    plc_listener.set_nonblocking(true)?;
    devices.push(plc.spawn(
        tokio::net::TcpListener::from_std(plc_listener)?,
        ServeOptions::default(),
    ));
    Ok((devices, torque_banks))
}

/// Starts `millgate run` on the load point's configuration (pinned with `taskset` to
/// `--cpu`), killed when the guard drops.
fn start_gateway(options: &Options, config_path: &Path) -> anyhow::Result<Killed> {
    let mut command = match &options.cpu {
        Some(cpu) => {
            let mut taskset = Command::new("taskset");
            taskset.args(["-c", cpu]).arg(&options.millgate);
            taskset
        }
        None => Command::new(&options.millgate),
    };
    Ok(Killed(
        command
            .args(["run", "--config"])
            .arg(config_path)
            .env("RUST_LOG", "warn")
            .stdout(Stdio::null())
            .stderr(Stdio::inherit())
            .spawn()
            .with_context(|| format!("cannot start {}", options.millgate.display()))?,
    ))
}

/// The channels of a configuration, and their samples per second.
fn channel_load(config: &Config) -> (usize, f64) {
    let samples_per_s = config.channels.iter().map(|c| c.sample_rate_hz).sum();
    (config.channels.len(), samples_per_s)
}

/// Prints what the load point runs.
fn print_load_point(
    options: &Options,
    drivelines: usize,
    stands: usize,
    config: &Config,
    pid: u32,
) {
    let (channels, samples_per_s) = channel_load(config);
    println!(
        "load point: {drivelines} drivelines at {DRIVELINE_RATE_HZ} Hz, {stands} stands at {} Hz \
         ({channels} channels, {samples_per_s:.0} samples/s), {:.0} s (warm-up {:.0} s), \
         pid {pid}{}{}{}",
        options.tandem_rate_hz,
        options.duration.as_secs_f64(),
        options.warm_up.as_secs_f64(),
        options
            .cpu
            .as_ref()
            .map_or(String::new(), |cpu| format!(" on core {cpu}")),
        options
            .plc_requests_in_flight
            .map_or(String::new(), |n| format!(", {n} PLC requests in flight")),
        options
            .daq_requests_in_flight
            .map_or(String::new(), |n| format!(", {n} DAQ requests in flight"))
    );
}

/// The gateway's own latency histograms on its last `/metrics` (the whole run, the
/// warm-up included; bucket bounds, so shares, not quantiles): beside the bench's
/// figures, which the bench stamps on its own devices; then a bite's stages
/// (`millgate_bite_stage_seconds`), which add up to its bite -> PLC time.
fn print_gateway_latency(final_metrics: &str) {
    let stages = ["analysis", "to_writer", "history", "write"]
        .map(|stage| ("millgate_bite_stage_seconds", format!("stage=\"{stage}\"")));
    let series = [
        ("millgate_bite_to_plc_seconds", String::new()),
        ("millgate_block_wait_seconds", String::new()),
    ]
    .into_iter()
    .chain(stages);
    for (name, labels) in series {
        let with = |suffix: &str, le: Option<&str>| {
            let labels = match (labels.is_empty(), le) {
                (true, None) => String::new(),
                (true, Some(le)) => format!("{{le=\"{le}\"}}"),
                (false, None) => format!("{{{labels}}}"),
                (false, Some(le)) => format!("{{{labels},le=\"{le}\"}}"),
            };
            metric_sum(final_metrics, &format!("{name}_{suffix}{labels}"))
        };
        let count = with("count", None);
        let sum = with("sum", None);
        let within = |le: &str| 100.0 * with("bucket", Some(le)) / count.max(1.0);
        println!(
            "# the gateway's {name}{}: {count} observed, mean {:.2} ms, {:.1}% <= 1 ms, \
             {:.1}% <= 2 ms, {:.1}% <= 5 ms, {:.1}% <= 10 ms, {:.1}% <= 20 ms \
             (whole run, warm-up included)",
            if labels.is_empty() {
                String::new()
            } else {
                format!("{{{labels}}}")
            },
            1000.0 * sum / count.max(1.0),
            within("0.001"),
            within("0.002"),
            within("0.005"),
            within("0.01"),
            within("0.02"),
        );
    }
    let commits = metric_sum(final_metrics, "millgate_history_commits_total");
    println!(
        "# the gateway's history: {commits} commits, mean {:.2} ms, max {:.2} ms; PLC: {} writes \
         (whole run, warm-up included)",
        1000.0 * metric_sum(final_metrics, "millgate_history_commit_seconds_total")
            / commits.max(1.0),
        1000.0 * metric_sum(final_metrics, "millgate_history_commit_max_seconds"),
        metric_sum(final_metrics, "millgate_plc_writes_total"),
    );
}

/// The final checks: every bite the gateway counted (by the final `/metrics`) in the
/// history and at the PLC; the figures after the warm-up.
fn summarize(
    config: &Config,
    (drivelines, stands): (usize, usize),
    sampler: Sampler,
    final_metrics: &str,
    warm_up_end: WarmUpEnd,
) -> Summary {
    let counted: BTreeMap<usize, u32> = config
        .drivelines
        .iter()
        .enumerate()
        .map(|(i, d)| {
            let line = format!("millgate_driveline_bites_total{{driveline=\"{}\"}}", d.name);
            (i, metric_sum(final_metrics, &line) as u32)
        })
        .collect();
    let (not_in_history, not_at_plc) = sampler.bites.missing(&counted);
    let degraded = sampler.bites.degraded();
    let measured_s = warm_up_end.time.elapsed().map_or(0.0, |d| d.as_secs_f64());
    let samples = &sampler.samples;
    let (first, last) = (
        samples.first().copied().unwrap_or_default(),
        samples.last().copied().unwrap_or_default(),
    );
    let (channels, samples_per_s) = channel_load(config);
    let mut latencies_ms = sampler.bites.latencies_ms;
    latencies_ms.sort_by(f64::total_cmp);
    let mut from_sample_ms = sampler.bites.from_sample_ms;
    from_sample_ms.sort_by(f64::total_cmp);
    Summary {
        drivelines,
        stands,
        channels,
        samples_per_s,
        cpu_percent: (sampler.cpu_end - warm_up_end.cpu_s) / measured_s * 100.0,
        rss_max_kib: sampler.rss_max,
        rss_growth_kib: last.0 as i64 - first.0 as i64,
        fds: samples
            .iter()
            .fold((usize::MAX, 0), |(lo, hi), s| (lo.min(s.1), hi.max(s.1))),
        missed: metric_sum(final_metrics, "millgate_channel_blocks_missed_total")
            - warm_up_end.missed,
        bites: counted.values().map(|&c| u64::from(c)).sum(),
        degraded,
        not_in_history,
        not_at_plc,
        answers_failed: sampler.answers_failed,
        answers: sampler.answers,
        sparkplug_bites: metric_sum(final_metrics, "millgate_sparkplug_bites_published_total"),
        latencies_ms,
        from_sample_ms,
        unattributed: sampler.bites.unattributed,
    }
}
