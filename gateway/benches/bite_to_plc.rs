//! Latency from the end of a bite window to the PLC register write.
//!
//! The real analysis task code (`Analysis::handle`), the real `PlcWriter` and a
//! virtual PLC on loopback Modbus TCP. Samples are fed to the analysis directly, as
//! fast as it takes them, instead of streaming 1 000 bars in real time (40 min): the
//! clock starts when a bite window completes, and stops when the PLC holds the new
//! bite counter. Prints p50, p99 and max over 1 000 bites.
//!
//! With `--history`: the board records into a real history file (the PLC writer then
//! waits for each bite's commit, as in the service), and the bars alternate between
//! two analyses of the same driveline, one keeping captures and one not: the same run
//! gives the latency with the capture on and off (500 bites each). The history's
//! commits are as `history.synchronous`'s default (`normal`) sets them, or with
//! `--synchronous full` synced to disk each.
//!
//! With `--extra-channels` (implies `--history`): the first analysis's driveline also
//! names an extra channel (a motor current, a second block channel at the torque's
//! rate, its block handed to the analysis right after the torque's, as a DAQ polled
//! for both gives them), so each bite is held until the current's block covers its
//! window; the second analysis keeps captures without it: the latency the hold adds.
//!
//!     cargo bench -p millgate --bench bite_to_plc
//!     cargo bench -p millgate --bench bite_to_plc -- --history
//!     cargo bench -p millgate --bench bite_to_plc -- --history --synchronous full
//!     cargo bench -p millgate --bench bite_to_plc -- --extra-channels

use std::sync::Arc;
use std::time::{Duration, Instant};

use millgate::analysis::Analysis;
use millgate::field::acquired::Acquired;
use millgate::field::source_health::SourceHealth;
use millgate::outputs::modbus::plc_writer::PlcWriter;
use millgate::outputs::modbus::register_map::{decode_u32, RegisterMap};
use millgate::state::board::Board;
use millgate_sim::devices::modbus_bank::ServeOptions;
use millgate_sim::devices::virtual_plc::VirtualPlc;

const BITES: usize = 1000;

#[tokio::main(flavor = "multi_thread", worker_threads = 2)]
async fn main() -> anyhow::Result<()> {
    let demo = millgate_sim::devices::demo::setup(1.0, 0.5, 5)?;
    let mut config = demo.config;
    // One bar: idle, bite, rolling, tail-out.
    let bar_end = demo.schedule.bites[1].onset_sample - demo.schedule.bites[0].onset_sample;
    let bar = demo.schedule.torque_knm[..bar_end].to_vec();

    let plc = VirtualPlc::new(usize::from(RegisterMap::new(&config).len()));
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await?;
    let output = config.outputs.plc.as_mut().unwrap();
    output.address = listener.local_addr()?.to_string();
    output.register_base = 0;
    // A slow periodic write, so every measured write is the one the bite caused.
    output.write_period = Duration::from_secs(10);
    let output = output.clone();
    let running_plc = plc.spawn(listener, ServeOptions::default());

    let health = Arc::new(SourceHealth::new(
        Duration::from_secs(3600),
        Duration::from_secs(3600),
    ));
    let args: Vec<String> = std::env::args().collect();
    let with_extra = args.iter().any(|a| a == "--extra-channels");
    let with_history = with_extra || args.iter().any(|a| a == "--history");
    let synchronous = match args.iter().position(|a| a == "--synchronous") {
        Some(at) => {
            let text = args.get(at + 1).map(String::as_str).unwrap_or_default();
            *millgate_config::Synchronous::ALL
                .iter()
                .find(|s| s.name() == text)
                .ok_or_else(|| anyhow::anyhow!("--synchronous: normal or full, not {text:?}"))?
        }
        None => millgate_config::Synchronous::default(),
    };
    let current_channel = config.channels.len();
    let mut extra_config = config.clone();
    if with_extra {
        let mut current = config.channels[0].clone();
        current.name = "motor_current".into();
        current.unit = "A".into();
        current.kind = millgate_config::ChannelKind::ProcessValue;
        if let millgate_config::ChannelSource::ModbusBlock { base, .. } = &mut current.source {
            *base = 122;
        }
        extra_config.channels.push(current);
        extra_config.drivelines[0].extra_channels = vec![current_channel];
    }
    let scratch = std::env::temp_dir().join(format!("millgate-bench-plc-{}", std::process::id()));
    let history = if with_history {
        std::fs::create_dir_all(&scratch)?;
        let settings = millgate_config::History {
            path: scratch.join("history.db"),
            retention_days: 400,
            max_size_mb: 1024,
            captures: millgate_config::CaptureSettings::defaults(1024),
            synchronous,
        };
        config.history = Some(settings.clone());
        extra_config.history = Some(settings.clone());
        let history = millgate::state::history::History::new(Some(&settings));
        millgate::history::start(&history, millgate::history::RunInfo::of(&config));
        history
    } else {
        millgate::state::history::History::disabled()
    };
    let board = Arc::new(Board::new(&extra_config, vec![health]).with_history(history.clone()));
    let (bites, _) = tokio::sync::broadcast::channel(16);
    // Analyses of the same driveline: [captures on, captures off] with a history,
    // [captures with the extra channel, captures without] with extra channels, one
    // (captures on only when a history is configured) without.
    let mut analyses = vec![Analysis::new(
        &extra_config,
        Arc::clone(&board),
        bites.clone(),
    )?];
    if let Some(settings) = config.history.as_mut() {
        settings.captures.enabled = with_extra;
        analyses.push(Analysis::new(&config, Arc::clone(&board), bites)?);
    }
    let (stop_writer, writer_shutdown) = millgate::shutdown::channel();
    let map = Arc::new(RegisterMap::new(&config));
    let writer = tokio::spawn(
        PlcWriter::new(
            output,
            (Arc::clone(&map), Arc::clone(&board)),
            Arc::default(),
        )
        .run(writer_shutdown),
    );
    let counter = usize::from(map.named("F1.bite_counter").unwrap().address);
    // Let the writer connect.
    tokio::time::sleep(Duration::from_millis(300)).await;

    let mut latencies: Vec<Vec<Duration>> = vec![Vec::new(); analyses.len()];
    let mut seen = 0u32;
    let mut bar_index = 0usize;
    while latencies.iter().map(Vec::len).sum::<usize>() < BITES {
        let which = bar_index % analyses.len();
        bar_index += 1;
        let analysis = &mut analyses[which];
        for block in bar.chunks(100) {
            let mut reports = analysis.handle(Acquired::Samples {
                channel: 0,
                values: block.to_vec(),
                received: None,
                handed: Instant::now(),
            });
            if with_extra && which == 0 {
                reports.extend(analysis.handle(Acquired::Samples {
                    channel: current_channel,
                    values: block.iter().map(|t| 80.0 + 3.2 * t).collect(),
                    received: None,
                    handed: Instant::now(),
                }));
            }
            for report in reports {
                seen += 1;
                while decode_u32(&plc.bank().lock().holding[counter..]) != Some(seen) {
                    tokio::task::yield_now().await;
                    assert!(
                        report.window_complete.elapsed() < Duration::from_secs(5),
                        "no write"
                    );
                }
                latencies[which].push(report.window_complete.elapsed());
            }
        }
    }
    stop_writer.trigger();
    writer.await?;
    running_plc.stop().await?;

    let status = history.status();
    if with_history {
        println!(
            "history commits: {}, mean {:.3} ms, max {:.3} ms (BEGIN to COMMIT on the writer thread)",
            status.commits,
            status.commit_seconds_sum * 1e3 / status.commits.max(1) as f64,
            status.commit_seconds_max * 1e3
        );
    }
    tokio::task::spawn_blocking(move || history.close()).await?;
    let _ = std::fs::remove_dir_all(&scratch);
    for (which, mut latencies) in latencies.into_iter().enumerate() {
        latencies.sort();
        let at = |q: f64| latencies[((latencies.len() - 1) as f64 * q).round() as usize];
        let what = match (with_history, which) {
            (false, _) => String::new(),
            (true, 0) if with_extra => format!(
                ", history ({}), captures with an extra channel",
                synchronous.name()
            ),
            (true, _) if with_extra => format!(
                ", history ({}), captures without extra channels",
                synchronous.name()
            ),
            (true, 0) => format!(", history ({}), captures on", synchronous.name()),
            (true, _) => format!(", history ({}), captures off", synchronous.name()),
        };
        println!(
            "bite window complete -> PLC register written{what}, {} bites: p50 {:.3} ms, p99 {:.3} ms, max {:.3} ms",
            latencies.len(),
            at(0.50).as_secs_f64() * 1e3,
            at(0.99).as_secs_f64() * 1e3,
            latencies.last().unwrap().as_secs_f64() * 1e3
        );
    }
    Ok(())
}
