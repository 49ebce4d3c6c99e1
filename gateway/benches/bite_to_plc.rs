//! Latency from the end of a bite window to the PLC register write.
//!
//! The real analysis task code (`Analysis::handle`), the real `PlcWriter` and a
//! virtual PLC on loopback Modbus TCP. Samples are fed to the analysis directly, as
//! fast as it takes them, instead of streaming 1 000 bars in real time (40 min): the
//! clock starts when a bite window completes, and stops when the PLC holds the new
//! bite counter. Prints p50, p99 and max over 1 000 bites.
//!
//!     cargo bench -p millgate --bench bite_to_plc

use std::sync::Arc;
use std::time::Duration;

use millgate::analysis::Analysis;
use millgate::field::acquired::Acquired;
use millgate::field::source_health::SourceHealth;
use millgate::outputs::plc_writer::PlcWriter;
use millgate::outputs::register_map::{decode_u32, RegisterMap};
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
    let board = Arc::new(Board::new(&config, vec![health]));
    let (bites, _) = tokio::sync::broadcast::channel(16);
    let mut analysis = Analysis::new(&config, Arc::clone(&board), bites)?;
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

    let mut latencies = Vec::with_capacity(BITES);
    let mut seen = 0u32;
    while latencies.len() < BITES {
        for block in bar.chunks(100) {
            let reports = analysis.handle(Acquired::Samples {
                channel: 0,
                values: block.to_vec(),
                received: None,
            });
            for report in reports {
                seen += 1;
                while decode_u32(&plc.bank().lock().holding[counter..]) != Some(seen) {
                    tokio::task::yield_now().await;
                    assert!(
                        report.window_complete.elapsed() < Duration::from_secs(5),
                        "no write"
                    );
                }
                latencies.push(report.window_complete.elapsed());
            }
        }
    }
    stop_writer.trigger();
    writer.await?;
    running_plc.stop().await?;

    latencies.sort();
    let at = |q: f64| latencies[((latencies.len() - 1) as f64 * q).round() as usize];
    println!(
        "bite window complete -> PLC register written, {} bites: p50 {:.3} ms, p99 {:.3} ms, max {:.3} ms",
        latencies.len(),
        at(0.50).as_secs_f64() * 1e3,
        at(0.99).as_secs_f64() * 1e3,
        latencies.last().unwrap().as_secs_f64() * 1e3
    );
    Ok(())
}
