//! Runs the seeded hidden-effect suite of the model-discrepancy workflow (or the cases
//! given by index) and prints per case the verdict, the residuals, the simulations and
//! the wall time, then the slowest single-bite and multi-bite runs.
//!
//! ```text
//! cargo run --release -p millgate-sim --example discrepancy_cases [-- [--verbose] [--seed N] [INDEX ...]]
//! ```
//!
//! The workflow runs as the command line runs it: candidate search on every core.
//! `--verbose` adds the identifications, stiffness starts and best candidates; `--seed`
//! draws another suite (the test's is 1).

use std::time::Instant;

use millgate_sim::discrepancy::cases::suite;
use millgate_sim::discrepancy::{run, Progress, Report};

fn details(report: &Report) {
    for id in &report.calibration.identified {
        println!(
            "   bite {} {} part from {:.3} s: {:.3} Hz, {:.3} Hz",
            id.bite, id.window, id.t_start_s, id.beta1_hz, id.beta2_hz
        );
    }
    for t in &report.calibration.stiffness_trials {
        println!(
            "   start {} {:?}: {:.4?} rmse {:.3}",
            t.source, t.identification, t.start, t.rmse
        );
    }
    for c in report.candidates.iter().take(4) {
        println!(
            "   candidate {} {:?} {:.4e} rmse {:.3} BIC {:.1}",
            c.effect, c.location, c.value, c.rmse, c.bic
        );
    }
    println!("   linear BIC {:.1}", report.bic_linear);
}

fn main() -> anyhow::Result<()> {
    let arguments: Vec<String> = std::env::args().skip(1).collect();
    let verbose = arguments.iter().any(|a| a == "--verbose");
    let seed_at = arguments.iter().position(|a| a == "--seed");
    let seed = match seed_at {
        Some(at) => arguments
            .get(at + 1)
            .and_then(|s| s.parse().ok())
            .ok_or_else(|| anyhow::anyhow!("--seed needs a number"))?,
        None => 1,
    };
    let wanted: Vec<usize> = arguments
        .iter()
        .enumerate()
        .filter(|&(i, _)| seed_at.is_none_or(|at| i != at + 1))
        .filter_map(|(_, a)| a.parse().ok())
        .collect();
    let mut slowest = [(0.0_f64, String::new()), (0.0, String::new())];
    let mut failures = 0;
    for (index, case) in suite(seed)?.into_iter().enumerate() {
        if !wanted.is_empty() && !wanted.contains(&index) {
            continue;
        }
        let records = case.records()?;
        let measured: Vec<_> = records.iter().map(|r| r.measured()).collect();
        let started = Instant::now();
        let mut steps = String::new();
        let report = run(&measured, &case.handed, |progress| {
            if let Progress::Step(step) = progress {
                steps += &format!(" {step} {:.1}", started.elapsed().as_secs_f64());
            }
        })?;
        let seconds = started.elapsed().as_secs_f64();
        let outcome = case.check(&report);
        failures += usize::from(outcome.is_err());
        println!(
            "{:40} {:11} {:16} {:?} rmse {:.3} -> {:.3} (noise {:.2}) {:6} sims {seconds:5.1} s {}",
            case.name,
            report.verdict,
            report.effect.map_or("none", |e| e.key()),
            report.location,
            report.rmse_before,
            report.rmse_after,
            case.noise_rms,
            report.simulations,
            outcome.as_ref().err().map_or("ok", String::as_str),
        );
        if verbose {
            println!("   steps (s from start):{steps}");
            println!(
                "   hidden {:?}, static {:?} kN*m, truth {:.4?}, handed {:.4?}",
                case.hidden,
                case.loads
                    .iter()
                    .map(|l| l.static_torque)
                    .collect::<Vec<_>>(),
                case.truth
                    .couplings
                    .iter()
                    .map(|c| c.stiffness)
                    .collect::<Vec<_>>(),
                case.handed
                    .couplings
                    .iter()
                    .map(|c| c.stiffness)
                    .collect::<Vec<_>>(),
            );
            details(&report);
        }
        let slot = &mut slowest[usize::from(measured.len() > 1)];
        if seconds > slot.0 {
            *slot = (seconds, case.name.clone());
        }
    }
    println!(
        "slowest single bite: {:.1} s ({}); slowest several bites: {:.1} s ({}); {failures} failed",
        slowest[0].0, slowest[0].1, slowest[1].0, slowest[1].1
    );
    Ok(())
}
