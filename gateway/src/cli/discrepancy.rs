//! `millgate discrepancy --measured FILE.csv [--measured FILE.csv ...] --model MODEL.toml
//! [--channel NAME] [--report DIR] [--format text|json]`: the model-discrepancy workflow
//! of [`millgate_sim::discrepancy`] on one or more recorded bites of one driveline.

use std::path::PathBuf;

use anyhow::Context as _;
use millgate_sim::discrepancy::{self, report, split_bites, DiscrepancyError, Measured, Progress};
use millgate_sim::model::Model;

use super::{csv, OutputFormat};

/// Largest relative departure of one time step from the mean step.
const UNIFORM_TOLERANCE: f64 = 0.01;

/// Arguments of `millgate discrepancy`.
#[derive(Debug, Clone, clap::Args)]
pub struct DiscrepancyArgs {
    /// A measured record: CSV with a header, first column `t` (s), other columns torque
    /// (kN*m), uniformly sampled. Give it once per record; a record holding several
    /// bites (idle torque between them) is split into its bites. One model is fitted to
    /// every bite.
    #[arg(long, required = true)]
    pub measured: Vec<PathBuf>,
    /// The driveline model (TOML) without the effect to be found; its stiffness may be
    /// from drawings.
    #[arg(long)]
    pub model: PathBuf,
    /// Channel to use in every record (default: the first after `t`).
    #[arg(long)]
    pub channel: Option<String>,
    /// Folder for the report: extended and calibrated model TOML, SVG plot, Markdown
    /// summary, JSON.
    #[arg(long)]
    pub report: Option<PathBuf>,
    /// Output format.
    #[arg(long, value_enum, default_value_t = OutputFormat::Text)]
    pub format: OutputFormat,
}

/// One CSV read: its time column's first value, rate and the chosen channel.
struct Recorded {
    path: PathBuf,
    t0_s: f64,
    sample_rate_hz: f64,
    torque_knm: Vec<f64>,
}

/// Runs the workflow, printing progress to stderr; returns the text to print (the
/// report's Markdown summary, or its JSON).
pub fn run(args: &DiscrepancyArgs) -> anyhow::Result<String> {
    let mut recorded = Vec::with_capacity(args.measured.len());
    for path in &args.measured {
        let table = csv::read(path).with_context(|| path.display().to_string())?;
        let (_, torque) = table
            .pick(args.channel.as_deref())
            .map_err(anyhow::Error::msg)
            .with_context(|| path.display().to_string())?;
        check_uniform(&table.time_s)
            .map_err(anyhow::Error::msg)
            .with_context(|| path.display().to_string())?;
        recorded.push(Recorded {
            path: path.clone(),
            t0_s: table.time_s[0],
            sample_rate_hz: table.sample_rate_hz(),
            torque_knm: torque.to_vec(),
        });
    }
    let model = Model::load(&args.model)?;
    // Every bite and the file it came from.
    let mut bites = Vec::new();
    let mut sources = Vec::new();
    for record in &recorded {
        let whole = Measured {
            t0_s: record.t0_s,
            sample_rate_hz: record.sample_rate_hz,
            torque_knm: &record.torque_knm,
        };
        let found = split_bites(&whole);
        if found.len() > 1 {
            eprintln!(
                "discrepancy: {}: {} bites, from t = {}",
                record.path.display(),
                found.len(),
                found
                    .iter()
                    .map(|b| format!("{:.3} s", b.t0_s))
                    .collect::<Vec<_>>()
                    .join(", ")
            );
        }
        sources.extend(std::iter::repeat_n(&record.path, found.len()));
        bites.extend(found);
    }
    let started = std::time::Instant::now();
    let outcome = discrepancy::run(&bites, &model, |progress| match progress {
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
            "discrepancy: [{done}/{total}] {effect}{}: rmse {rmse:.3} kN*m",
            location.map_or(String::new(), |i| format!(" in coupling {i}")),
        ),
    });
    let report = match outcome {
        Ok(report) => report,
        // Name the file the bite came from.
        Err(error @ DiscrepancyError::Bite { bite, .. }) => {
            let path = sources
                .get(bite)
                .map_or(String::new(), |p| p.display().to_string());
            return Err(anyhow::Error::new(error).context(path));
        }
        Err(error) => return Err(error.into()),
    };
    eprintln!(
        "discrepancy: done in {:.1} s ({} simulations of one bite)",
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
