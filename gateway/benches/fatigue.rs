//! Cost of the fatigue ledger in the service path: the demo's two minutes of bars
//! (2 kHz, 0.5 kN*m RMS noise, as the DAQ quantises them) handed to the real analysis
//! task code (`Analysis::handle`, 120-sample blocks) of a driveline without and with a
//! `fatigue` section of three components, gate 2 kN*m (4 noise RMS) and 0 (every
//! wiggle a reversal). Prints the median time per sample over the rounds and what it
//! is of one core for a 2 kHz channel; the ledger's cost is the difference.
//!
//!     cargo bench -p millgate --bench fatigue

use std::sync::Arc;
use std::time::{Duration, Instant};

use millgate::analysis::Analysis;
use millgate::field::acquired::Acquired;
use millgate::field::source_health::SourceHealth;
use millgate::state::board::Board;
use millgate_config::{FatigueComponent, FatigueSettings};
use millgate_dsp::miner::{EnduranceRule, MeanCorrection, SnCurve, SnCurveSettings};

/// Rounds per case (the median is printed).
const ROUNDS: usize = 7;
/// Samples per block, as the demo's DAQ gives them.
const BLOCK: usize = 120;

fn ledger(gate_knm: f64) -> anyhow::Result<FatigueSettings> {
    let component = |name: &str, m: f64, share: f64| -> anyhow::Result<FatigueComponent> {
        Ok(FatigueComponent {
            name: name.into(),
            curve: SnCurve::new(SnCurveSettings {
                m,
                ref_cycles: 2e6,
                ref_range_knm: 150.0,
                torque_share: share,
                endurance_knm: Some(20.0),
                endurance_rule: EnduranceRule::Haibach,
                mean_correction: MeanCorrection::None,
            })
            .map_err(|e| anyhow::anyhow!("{e}"))?,
        })
    };
    Ok(FatigueSettings {
        gate_knm,
        life_limit: 0.8,
        components: vec![
            component("spindle top", 6.0, 0.5)?,
            component("spindle bottom", 6.0, 0.5)?,
            component("motor coupling", 5.0, 1.0)?,
        ],
    })
}

/// Median seconds per sample of `samples` through an analysis of `config`.
fn per_sample(config: &millgate_config::Config, samples: &[f64]) -> anyhow::Result<f64> {
    let mut times = Vec::new();
    for _ in 0..ROUNDS {
        let health = Arc::new(SourceHealth::new(
            Duration::from_secs(3600),
            Duration::from_secs(3600),
        ));
        let board = Arc::new(Board::new(config, vec![health]));
        let (bites, _reports) = tokio::sync::broadcast::channel(4096);
        let mut analysis = Analysis::new(config, board, bites)?;
        let channel = config.drivelines[0].torque;
        let start = Instant::now();
        for block in samples.chunks(BLOCK) {
            analysis.handle(Acquired::Samples {
                channel,
                values: block.to_vec(),
                received: None,
                handed: Instant::now(),
            });
        }
        times.push(start.elapsed().as_secs_f64() / samples.len() as f64);
    }
    times.sort_by(f64::total_cmp);
    Ok(times[ROUNDS / 2])
}

fn main() -> anyhow::Result<()> {
    let demo = millgate_sim::devices::demo::setup(120.0, 0.5, 7)?;
    let mut config = demo.config;
    config.drivelines[0].model = None;
    let torque = config.channels[config.drivelines[0].torque].clone();
    let samples = millgate_tests::kit::as_daq_sends(&demo.schedule, &torque);
    let rate = torque.sample_rate_hz;
    println!(
        "{} samples at {rate} Hz through Analysis::handle, median of {ROUNDS} rounds",
        samples.len()
    );
    let without = per_sample(&config, &samples)?;
    let row = |name: &str, seconds: f64| {
        println!(
            "{name:<32} {:>8.1} ns/sample  {:>7.4}% of a core at {rate} Hz",
            seconds * 1e9,
            seconds * rate * 100.0
        )
    };
    row("without a ledger", without);
    for gate in [2.0, 0.0] {
        config.drivelines[0].fatigue = Some(ledger(gate)?);
        let with = per_sample(&config, &samples)?;
        row(&format!("with a ledger, gate {gate} kN*m"), with);
        row("  the ledger's cost", with - without);
    }
    Ok(())
}
