//! `millgate discrepancy --measured FILE.csv --model MODEL.toml [--channel NAME]
//! [--report DIR] [--format text|json]`: the model-discrepancy workflow of
//! [`millgate_sim::discrepancy`] on a recorded bite transient.

use std::path::PathBuf;

use anyhow::Context as _;
use millgate_sim::discrepancy::{self, report, Measured, Progress};
use millgate_sim::model::Model;

use super::{csv, OutputFormat};

/// Largest relative departure of one time step from the mean step.
const UNIFORM_TOLERANCE: f64 = 0.01;

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
    check_uniform(&table.time_s)
        .map_err(|e| anyhow::anyhow!("{}: {e}", args.measured.display()))?;
    let model = Model::load(&args.model)?;
    let measured = Measured {
        t0_s: table.time_s[0],
        sample_rate_hz: table.sample_rate_hz(),
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

/// Fails with the line of the first sample whose time step departs from the mean step
/// by more than [`UNIFORM_TOLERANCE`].
fn check_uniform(time_s: &[f64]) -> Result<(), String> {
    if time_s.len() < 3 {
        return Err(format!(
            "{} samples; the workflow needs a transient",
            time_s.len()
        ));
    }
    let step = (time_s[time_s.len() - 1] - time_s[0]) / (time_s.len() - 1) as f64;
    match time_s
        .windows(2)
        .position(|w| ((w[1] - w[0]) / step - 1.0).abs() > UNIFORM_TOLERANCE)
    {
        // Line 1 is the header, sample k is on line k + 2.
        Some(k) => Err(format!(
            "line {}: t steps by {:.6} s, the record's mean step is {step:.6} s; \
             the workflow needs uniform sampling",
            k + 3,
            time_s[k + 1] - time_s[k]
        )),
        None => Ok(()),
    }
}
