//! Simulated seconds per wall-clock second of the torsional chain (target >= 1000x real
//! time for the 3-mass model with backlash at 2 kHz output).
//!
//! ```text
//! cargo bench -p millgate-sim --bench realtime [-- --model M.toml] [--substeps N]
//!     [--csv OUT.csv] [--json]
//! ```
//! Defaults to `models/table2-adjusted-backlash.toml`. `--csv` also writes the transient
//! (`t,torque`), `--json` prints one JSON line for `compare_solve_ivp.py`.

use std::time::{Duration, Instant};

use millgate_sim::chain::Simulator;
use millgate_sim::model::Model;

/// Wall-clock time spent measuring, per batch.
const BATCH: Duration = Duration::from_millis(300);
/// Batches; the median is reported.
const BATCHES: usize = 7;

fn main() -> anyhow::Result<()> {
    let mut model_path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/models/table2-adjusted-backlash.toml"
    )
    .to_owned();
    let mut substeps: Option<usize> = None;
    let mut csv_path: Option<String> = None;
    let mut json = false;
    let mut args = std::env::args().skip(1);
    while let Some(arg) = args.next() {
        match arg.as_str() {
            "--model" => model_path = args.next().ok_or_else(|| anyhow::anyhow!("--model PATH"))?,
            "--substeps" => {
                substeps = Some(
                    args.next()
                        .ok_or_else(|| anyhow::anyhow!("--substeps N"))?
                        .parse()?,
                )
            }
            "--csv" => csv_path = Some(args.next().ok_or_else(|| anyhow::anyhow!("--csv PATH"))?),
            "--json" => json = true,
            // cargo bench passes --bench; ignore it and any filter.
            _ => {}
        }
    }
    let model = Model::load(&model_path)?;
    let mut simulator = Simulator::new(&model)?;
    if let Some(substeps) = substeps {
        simulator = simulator.with_substeps_per_sample(substeps);
    }
    let mut torque = vec![0.0; simulator.sample_count()];
    let mut events = 0;

    let mut per_run = Vec::with_capacity(BATCHES);
    for _ in 0..BATCHES {
        let start = Instant::now();
        let mut runs = 0_u32;
        while start.elapsed() < BATCH {
            let mut state = simulator.initial_state();
            events = simulator.run_into(&mut state, &mut torque);
            std::hint::black_box(&torque);
            runs += 1;
        }
        per_run.push(start.elapsed().as_secs_f64() / f64::from(runs));
    }
    per_run.sort_by(f64::total_cmp);
    let median_s = per_run[BATCHES / 2];
    let simulated_s = model.sample_count() as f64 / model.measurement.sample_rate;
    let speed = simulated_s / median_s;

    if let Some(path) = csv_path {
        let mut text = String::from("t,torque\n");
        for (k, value) in torque.iter().enumerate() {
            text.push_str(&format!(
                "{},{}\n",
                k as f64 / model.measurement.sample_rate,
                value
            ));
        }
        std::fs::write(&path, text)?;
    }
    if json {
        println!(
            "{{\"wall_s_per_run\": {median_s:e}, \"simulated_s\": {simulated_s}, \"realtime_factor\": {speed:.1}, \"substeps\": {}, \"gap_crossings\": {events}}}",
            simulator.substeps_per_sample()
        );
    } else {
        println!("model:            {model_path}");
        println!(
            "record:           {simulated_s} s at {} Hz, {} RK4 steps per sample (h = {:.3e} s), {events} gap crossings",
            model.measurement.sample_rate,
            simulator.substeps_per_sample(),
            simulator.step_s()
        );
        println!(
            "wall time / run:  {:.2} us (median of {BATCHES} batches)",
            median_s * 1e6
        );
        println!("speed:            {speed:.0}x real time");
    }
    Ok(())
}
