//! Latency of the chatter slow-down bit through the gateway: from the end of a window
//! (the analysis handed the block that completes it) to the PLC register written.
//!
//! The real analysis task code (`Analysis::handle`), the real `PlcWriter` and a virtual
//! PLC on loopback Modbus TCP, as `bite_to_plc` measures the bite path. The five stands
//! of the physical tandem model (`sim::tandem`: 120 s at 90% of the critical speed, then
//! a 2 m/s^2 ramp into chatter) are fed block by block at their own pace (48 ms per
//! 120-sample block: the monitor anchors blocks by their arrival, so they come in real
//! time). Every evaluated window publishes the mill's block, the slow-down bit with it;
//! the clock starts when the block completing the window (the last stand's) is handed
//! to the analysis, and stops when the PLC holds that window's encoded values. Printed: p50, p99 and max over
//! every window, and the same for the windows where the bit rose. About 2.5 min.
//!
//!     cargo bench -p millgate --bench chatter_to_plc

use std::sync::Arc;
use std::time::{Duration, Instant};

use millgate::analysis::Analysis;
use millgate::field::acquired::Acquired;
use millgate::field::source_health::SourceHealth;
use millgate::outputs::modbus::plc_writer::PlcWriter;
use millgate::outputs::modbus::register_map::RegisterMap;
use millgate::state::board::Board;
use millgate_sim::devices::modbus_bank::ServeOptions;
use millgate_sim::devices::virtual_plc::VirtualPlc;
use millgate_sim::tandem::simulate::{simulate, Accelerometer, RunSettings};
use millgate_sim::tandem::truth::mill_critical_speed;
use millgate_sim::tandem::{PassSchedule, TandemMill};

const FS: f64 = 2500.0;
const BLOCK: usize = 120;
/// Stable rolling before the ramp, s.
const HOLD_S: f64 = 120.0;
/// The whole run, s.
const DURATION_S: f64 = 135.0;

fn config() -> anyhow::Result<millgate_config::Config> {
    let mut text = String::from(
        "name = \"chatter to plc\"\n[[sources.modbus]]\nname = \"daq\"\naddress = \"127.0.0.1:1\"\npoll_period_ms = 20\n",
    );
    for stand in 0..5 {
        text += &format!(
            "[[channels]]\nname = \"s{stand}\"\nkind = \"acceleration\"\nunit = \"m/s^2\"\n\
             sample_rate_hz = {FS}\nsource = {{ modbus = \"daq\", table = \"input\", block = {} }}\n",
            stand * 122
        );
    }
    text += "[[tandem_mills]]\nname = \"TCM\"\nstands = [\"s0\", \"s1\", \"s2\", \"s3\", \"s4\"]\n\
             chatter_band_hz = [100.0, 300.0]\nwindow_s = 0.5\nk_max = 0.25\n\
             gain_thresholds = [1.187, 1.492, 2.209, 3.087, 3.327]\n\
             [outputs.plc]\naddress = \"127.0.0.1:1\"\nwrite_period_ms = 10000\n";
    Ok(millgate_config::from_toml_str(
        &text,
        "chatter-to-plc.toml",
        std::path::Path::new("."),
    )?)
}

fn percentiles(mut values: Vec<Duration>) -> String {
    if values.is_empty() {
        return "none".to_owned();
    }
    values.sort();
    let at = |q: f64| values[((values.len() - 1) as f64 * q).round() as usize];
    format!(
        "{} windows: p50 {:.3} ms, p99 {:.3} ms, max {:.3} ms",
        values.len(),
        at(0.50).as_secs_f64() * 1e3,
        at(0.99).as_secs_f64() * 1e3,
        values[values.len() - 1].as_secs_f64() * 1e3
    )
}

#[tokio::main(flavor = "multi_thread", worker_threads = 2)]
async fn main() -> anyhow::Result<()> {
    let mill = TandemMill::new(&PassSchedule::example()?)?;
    let critical = mill_critical_speed(&mill)?.speed;
    let rate_hz = Accelerometer::default().sample_rate_hz;
    let settings = RunSettings::reference_ramp(critical, 0.9, HOLD_S, DURATION_S, rate_hz, 9);
    let record = simulate(&mill, &settings)?;

    let mut config = config()?;
    let map = Arc::new(RegisterMap::new(&config));
    let plc = VirtualPlc::new(usize::from(map.len()));
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await?;
    let output = config.outputs.plc.as_mut().expect("a PLC output");
    output.address = listener.local_addr()?.to_string();
    output.register_base = 0;
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
    let writer = tokio::spawn(
        PlcWriter::new(
            output,
            (Arc::clone(&map), Arc::clone(&board)),
            Arc::default(),
        )
        .run(writer_shutdown),
    );
    // The mill's block (flags .. worst stand), what each window changes.
    let block = |name: &str| usize::from(map.named(name).expect("register").address);
    let (first, last) = (block("TCM.flags"), block("TCM.worst_stand"));
    tokio::time::sleep(Duration::from_millis(300)).await;

    let period = Duration::from_secs_f64(BLOCK as f64 / FS);
    let start = Instant::now();
    let mut every = Vec::new();
    let mut rises = Vec::new();
    let mut requested = false;
    for (b, from) in (0..record.len() - BLOCK).step_by(BLOCK).enumerate() {
        tokio::time::sleep_until((start + period * b as u32).into()).await;
        let evaluations = board.results().tandem_mills[0].evaluations;
        // The last stand's block completes a window: the clock starts as it is handed
        // to the analysis (the spectra, the gain and the verdict are in the latency).
        let mut window_end = Instant::now();
        for (stand, signal) in record.acceleration.iter().enumerate() {
            if stand + 1 == record.acceleration.len() {
                window_end = Instant::now();
            }
            analysis.handle(Acquired::Samples {
                channel: stand,
                values: signal[from..from + BLOCK].to_vec(),
                received: None,
                handed: Instant::now(),
            });
        }
        let results = board.results();
        if results.tandem_mills[0].evaluations == evaluations {
            continue;
        }
        let expected = map.encode(&results)[first..=last].to_vec();
        while plc.holding()[first..=last] != expected[..] {
            tokio::task::yield_now().await;
            anyhow::ensure!(window_end.elapsed() < Duration::from_secs(5), "no write");
        }
        let latency = window_end.elapsed();
        every.push(latency);
        let request = results.tandem_mills[0].slow_down_request;
        if request && !requested {
            rises.push(latency);
        }
        requested = request;
    }
    stop_writer.trigger();
    writer.await?;
    running_plc.stop().await?;
    println!(
        "chatter window end -> PLC register written: {}; where the slow-down bit rose: {}",
        percentiles(every),
        percentiles(rises)
    );
    Ok(())
}
