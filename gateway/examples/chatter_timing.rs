//! Cost of the chatter monitor per window: five stands at 2500 Hz, 0.5 s windows
//! (1250 samples) every 0.25 s, fed in 120-sample blocks as a Modbus DAQ delivers them.
//!
//! `cargo run --release -p millgate --example chatter_timing [seconds]`
//!
//! Prints the time of the calls that completed a window (five forward and five
//! inverse FFTs, the peak search and the correlations) and of all calls (ring
//! buffer writes and the band gain's filters, which run on every sample, included),
//! per evaluated window.

use std::time::{Duration, Instant};

use millgate::analysis::chatter::{ChatterMonitor, ChatterUpdate};
use millgate_sim::tandem::simulate::{simulate, Accelerometer, Excitation, RunSettings, SpeedRamp};
use millgate_sim::tandem::{PassSchedule, TandemMill};

const FS: f64 = 2500.0;
const BLOCK: usize = 120;
const STANDS: usize = 5;

fn main() -> anyhow::Result<()> {
    let seconds: f64 = match std::env::args().nth(1) {
        Some(arg) => arg.parse()?,
        None => 60.0,
    };
    let mut text = String::from(
        "name = \"timing\"\n[[sources.modbus]]\nname = \"daq\"\naddress = \"127.0.0.1:1\"\npoll_period_ms = 20\n",
    );
    for s in 0..STANDS {
        text += &format!(
            "[[channels]]\nname = \"s{s}\"\nkind = \"acceleration\"\nunit = \"m/s^2\"\n\
             sample_rate_hz = {FS}\nsource = {{ modbus = \"daq\", table = \"input\", block = {} }}\n",
            s * 122
        );
    }
    let names: Vec<String> = (0..STANDS).map(|s| format!("\"s{s}\"")).collect();
    text += &format!(
        "[[tandem_mills]]\nname = \"TCM\"\nstands = [{}]\nchatter_band_hz = [100.0, 300.0]\n\
         window_s = 0.5\nk_max = 0.25\n\
         gain_thresholds = [1.187, 1.492, 2.209, 3.087, 3.327]\n",
        names.join(", ")
    );
    let config = millgate_config::from_toml_str(&text, "timing.toml", std::path::Path::new("."))
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    let mut monitor = ChatterMonitor::new(&config, 0)?;
    // The physical five-stand model: stable at the schedule's speed for half the run,
    // then a ramp into chatter (the DAQ's range would clip it; the cost is the same).
    let mill = TandemMill::new(&PassSchedule::example()?)?;
    let record = simulate(
        &mill,
        &RunSettings {
            ramp: SpeedRamp {
                start: 1.0,
                end: 1.3,
                hold_s: seconds / 2.0,
                accel_m_s2: 0.5,
            },
            excitation: Excitation::default(),
            sensor: Accelerometer {
                sample_rate_hz: FS,
                ..Accelerometer::default()
            },
            duration_s: seconds,
            seed: 1,
            internal_rate_hz: None,
        },
    )?;
    let signals = record.acceleration;
    let t0 = Instant::now();
    let period = Duration::from_secs_f64(BLOCK as f64 / FS);
    let (mut evaluating, mut all) = (Duration::ZERO, Duration::ZERO);
    let mut windows = 0u32;
    for (b, start) in (0..signals[0].len() - BLOCK).step_by(BLOCK).enumerate() {
        let arrival = t0 + period * b as u32;
        for (s, signal) in signals.iter().enumerate() {
            let values = &signal[start..start + BLOCK];
            let began = Instant::now();
            let update = monitor.samples(s, values, arrival);
            let took = began.elapsed();
            all += took;
            if let Some(ChatterUpdate::Evaluated(_)) = update {
                evaluating += took;
                windows += 1;
            }
        }
    }
    anyhow::ensure!(windows > 0, "no window evaluated in {seconds} s");
    println!(
        "{windows} windows of {} samples x {STANDS} stands (hop {}): {:.1} us per window \
         evaluation, {:.1} us per window for all calls",
        monitor.window_samples(),
        monitor.hop_samples(),
        evaluating.as_secs_f64() * 1e6 / f64::from(windows),
        all.as_secs_f64() * 1e6 / f64::from(windows)
    );
    Ok(())
}
