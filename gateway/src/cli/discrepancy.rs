//! `millgate discrepancy --measured FILE.csv --model MODEL.toml [--channel NAME]
//! [--report DIR] [--format text|json]`: the model-discrepancy workflow of
//! [`millgate_sim::discrepancy`] on a recorded bite transient.

use std::path::PathBuf;

use anyhow::Context as _;
use millgate_sim::discrepancy::{self, report, Measured, Progress};
use millgate_sim::model::Model;

use super::{csv, OutputFormat};

/// Smallest load step, in multiples of the record's noise, that makes a bite transient.
const MIN_STEP_OVER_NOISE: f64 = 10.0;

/// Arguments of `millgate discrepancy`.
#[derive(Debug, Clone, clap::Args)]
pub struct DiscrepancyArgs {
    /// The measured bite transient: CSV with a header, first column `t` (s), other
    /// columns torque (kN*m), uniformly sampled.
    #[arg(long)]
    pub measured: PathBuf,
    /// The driveline model (TOML) without the effect to be found.
    #[arg(long)]
    pub model: PathBuf,
    /// Channel to use (default: the first after `t`).
    #[arg(long)]
    pub channel: Option<String>,
    /// Folder for the report: extended model TOML, SVG plot, Markdown summary, JSON.
    #[arg(long)]
    pub report: Option<PathBuf>,
    /// Output format.
    #[arg(long, value_enum, default_value_t = OutputFormat::Text)]
    pub format: OutputFormat,
}

/// Runs the workflow, printing progress to stderr; returns the text to print (the
/// report's Markdown summary, or its JSON).
pub fn run(args: &DiscrepancyArgs) -> anyhow::Result<String> {
    let table = csv::read(&args.measured).with_context(|| args.measured.display().to_string())?;
    let (_, torque) = table
        .pick(args.channel.as_deref())
        .map_err(|e| anyhow::anyhow!("{}: {e}", args.measured.display()))?;
    let sample_rate_hz = table
        .sample_rate_hz()
        .map_err(|e| anyhow::anyhow!("{}: {e}", args.measured.display()))?;
    check_transient(torque).map_err(|e| anyhow::anyhow!("{}: {e}", args.measured.display()))?;
    let model = Model::load(&args.model)?;
    let measured = Measured {
        t0_s: table.time_s[0],
        sample_rate_hz,
        torque_knm: torque,
    };
    let started = std::time::Instant::now();
    let report = discrepancy::run(&measured, &model, |progress| match progress {
        Progress::Step(step) => eprintln!(
            "discrepancy: {step} ({:.1} s)",
            started.elapsed().as_secs_f64()
        ),
        Progress::Candidate {
            done,
            total,
            effect,
            location,
            rmse,
        } => eprintln!(
            "discrepancy: [{done}/{total}] {}{}: rmse {rmse:.3} kN*m",
            effect.key(),
            location.map_or(String::new(), |i| format!(" in coupling {i}")),
        ),
    })?;
    eprintln!(
        "discrepancy: done in {:.1} s ({} simulations)",
        started.elapsed().as_secs_f64(),
        report.simulations
    );
    if let Some(dir) = &args.report {
        for path in report::write(&report, dir)? {
            eprintln!("discrepancy: wrote {}", path.display());
        }
    }
    Ok(match args.format {
        OutputFormat::Json => serde_json::to_string_pretty(&report)?,
        OutputFormat::Text => report::summary(&report),
    })
}

/// Fails unless `torque_knm` holds a bite transient: a load step from its first 5% to
/// its last 20% of at least [`MIN_STEP_OVER_NOISE`] times its noise (RMS of the first
/// differences / sqrt 2). A constant record would otherwise be "explained" by the
/// effect that best fits nothing (`extra_inertia` with a stiffness change of +17 000%).
fn check_transient(torque_knm: &[f64]) -> Result<(), String> {
    let n = torque_knm.len();
    if n < 20 {
        return Err(format!(
            "{n} samples; the workflow needs a bite transient (at least 20 samples)"
        ));
    }
    let mean = |values: &[f64]| values.iter().sum::<f64>() / values.len() as f64;
    let step_knm = mean(&torque_knm[n - n / 5..]) - mean(&torque_knm[..n / 20]);
    let noise_knm = (torque_knm
        .windows(2)
        .map(|pair| (pair[1] - pair[0]).powi(2))
        .sum::<f64>()
        / (2.0 * (n - 1) as f64))
        .sqrt();
    if step_knm.abs() > MIN_STEP_OVER_NOISE * noise_knm && step_knm.abs() > 0.0 {
        Ok(())
    } else {
        Err(format!(
            "the torque record has no transient: its last 20% lies {step_knm:.3} kN*m from \
             its first 5% (noise {noise_knm:.3} kN*m RMS); the workflow needs a bite, a load \
             step of more than {MIN_STEP_OVER_NOISE} times the noise"
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_record_without_a_load_step_is_no_transient() {
        let constant = vec![100.0; 1200];
        let error = check_transient(&constant).unwrap_err();
        assert!(
            error.starts_with("the torque record has no transient"),
            "{error}"
        );
        // Noise alone (a deterministic +-1 kN*m pattern) is no transient either.
        let noise: Vec<f64> = (0..1200).map(|i| 100.0 + f64::from(i % 7) - 3.0).collect();
        assert!(check_transient(&noise).is_err());
        // A bite: 0 before the onset, 112 kN*m after, with the same pattern on top.
        let bite: Vec<f64> = (0..1200)
            .map(|i| if i < 100 { 0.0 } else { 112.0 } + f64::from(i % 7) - 3.0)
            .collect();
        assert_eq!(check_transient(&bite), Ok(()));
    }
}
