//! Cost of the rod-mill monitor per PLC update: the example RSM block
//! (`sim/models/rod`), as the service calls it.
//!
//! `cargo run --release -p millgate --example rod_timing [updates]`
//!
//! Prints the time of the first evaluation of each (pass, configuration) (the pass
//! setup, `PassSetup::new`, then the status), of an evaluation whose setup is cached,
//! and of a speed change alone (`PassSetup::status` and the flags), per update.

use std::time::{Duration, Instant};

use millgate::analysis::rod_monitor::RodMonitor;

/// Channels: configuration, pass, finishing speed.
const CONFIGURATION: usize = 0;
const PASS: usize = 1;
const SPEED: usize = 2;

fn main() -> anyhow::Result<()> {
    let updates: u32 = match std::env::args().nth(1) {
        Some(arg) => arg.parse()?,
        None => 2000,
    };
    let models = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../sim/models/rod");
    let mut text = String::from(
        "name = \"timing\"\n[[sources.modbus]]\nname = \"plc\"\naddress = \"127.0.0.1:1\"\npoll_period_ms = 20\n",
    );
    for (address, name) in ["configuration", "pass", "speed"].iter().enumerate() {
        text += &format!(
            "[[channels]]\nname = \"{name}\"\nkind = \"process_value\"\nunit = \"1\"\n\
             source = {{ modbus = \"plc\", table = \"holding\", address = {address} }}\n"
        );
    }
    text += "[[rod_mills]]\nname = \"RSM\"\nmill = \"rsm-mill.toml\"\nschedule = \"rsm-schedule.csv\"\n\
             configuration = \"configuration\"\nconfigurations = [\"table3\", \"fast\"]\n\
             pass = \"pass\"\nfinishing_speed = \"speed\"\n";
    let config = millgate_config::from_toml_str(&text, "timing.toml", &models)
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    let mut monitor = RodMonitor::new(&config, 0).map_err(|e| anyhow::anyhow!("{e}"))?;

    // Passes 1-2 run in table3 (0), 3-4 in fast (1); speeds inside both ranges.
    let plan = [(0.0, 1.0), (0.0, 2.0), (1.0, 3.0), (1.0, 4.0)];
    let mut first = Vec::new();
    for &(configuration, pass) in &plan {
        monitor.process_value(SPEED, 60.0);
        monitor.process_value(CONFIGURATION, configuration);
        let started = Instant::now();
        let results = monitor.process_value(PASS, pass);
        first.push(started.elapsed());
        anyhow::ensure!(
            results.is_some_and(|r| !r.input_refused),
            "pass {pass} refused"
        );
    }
    let mut cached = Duration::ZERO;
    let mut speed_changes = Duration::ZERO;
    for update in 0..updates {
        let (configuration, pass) = plan[update as usize % plan.len()];
        monitor.process_value(CONFIGURATION, configuration);
        let started = Instant::now();
        let switched = monitor.process_value(PASS, pass);
        cached += started.elapsed();
        let speed = 50.0 + f64::from(update % 400) * 0.05;
        let started = Instant::now();
        let changed = monitor.process_value(SPEED, speed);
        speed_changes += started.elapsed();
        anyhow::ensure!(
            switched.is_some() && changed.is_some_and(|r| !r.input_refused),
            "update {update} not evaluated"
        );
    }
    let per = |total: Duration| total / updates;
    let first_ms: Vec<String> = first
        .iter()
        .map(|d| format!("{:.2}", d.as_secs_f64() * 1e3))
        .collect();
    println!(
        "first evaluation of a pass (setup + status), ms: {}",
        first_ms.join(", ")
    );
    println!(
        "pass or configuration change, setup cached: {:?} per update",
        per(cached)
    );
    println!(
        "finishing speed change: {:?} per update",
        per(speed_changes)
    );
    println!("setups cached: {}", monitor.cached_setups());
    Ok(())
}
