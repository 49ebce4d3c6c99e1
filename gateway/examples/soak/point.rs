//! One load point's run: the broker, the field devices and the gateway started, the
//! samples taken, the final checks, its summary.

use std::collections::{BTreeMap, HashMap};
use std::process::{Command, Stdio};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant, SystemTime};

use anyhow::Context as _;
use millgate::outputs::modbus::register_map::RegisterMap;
use millgate_sim::devices::modbus_bank::{Running, ServeOptions, SharedBank};
use millgate_sim::devices::virtual_plc::VirtualPlc;
use millgate_tests::kit::broker::Broker as Mosquitto;
use tokio_modbus::client::Reader;

use crate::bites::{quantile, Bites};
use crate::daqs::{
    load_point, CHANNELS_PER_DAQ, DRIVELINE_BLOCK, DRIVELINE_RATE_HZ, POST_TRIGGER_S,
};
use crate::options::Options;
use crate::probe::{
    free_port, get, metric_sum, process_figures, watch_stalls, web_answers, Killed,
};
use crate::summary::Summary;

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
