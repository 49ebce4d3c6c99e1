//! `millgate rod ...`: parametric stability of a rod mill's passes (the Mathieu
//! equation of the rod between stands, domain notes 3).
//!
//! - `millgate rod check --mill MILL.toml --schedule PASSES.csv [--format text|json]
//!   [--plot DIR]`: every pass, span, bending mode and excitation source at the pass's
//!   finishing speed, and the finishing speeds to avoid per configuration; with
//!   `--plot`, `ince-strutt.svg` and `campbell-<pass>.svg` in DIR.
//! - `millgate rod mathieu --q Q [--order N] [--format json|text]`:
//!   `{"q": Q, "a": [a_0 .. a_N], "b": [b_1 .. b_N]}`.
//! - `millgate rod floquet --a A --q Q [--damping C] [--format json|text]`:
//!   `{"exponent": E, "stable": bool}`, E per unit Mathieu time of
//!   `x'' + 2C x' + (A - 2Q cos 2t) x = 0`.
//!
//! An unstable pass is a finding, not a failure: `check` exits 0 when it could check
//! every pass, non-zero (with the file, line or key) when it could not.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::Context as _;
use clap::{Args, Subcommand};
use millgate_dsp::mathieu::{Mathieu, MAX_ORDER};
use millgate_sim::rod::check::{check_schedule, PassSetup, ScheduleReport};
use millgate_sim::rod::mill::RodMill;
use millgate_sim::rod::plot::{campbell_svg, ince_strutt_svg};
use millgate_sim::rod::schedule::Pass;
use millgate_sim::rod::{report, schedule};

use super::OutputFormat;

/// Arguments of `millgate rod`.
#[derive(Debug, Args)]
pub struct RodArgs {
    /// What to compute.
    #[command(subcommand)]
    pub command: RodCommand,
}

/// The `millgate rod` subcommands.
#[derive(Debug, Subcommand)]
pub enum RodCommand {
    /// Check every pass of a schedule: stability, margins, speeds to avoid.
    Check {
        /// The mill file (TOML): drive, stands, spans, rod material.
        #[arg(long)]
        mill: PathBuf,
        /// The schedule (CSV): one pass per row.
        #[arg(long)]
        schedule: PathBuf,
        /// Output format.
        #[arg(long, value_enum, default_value_t = OutputFormat::Text)]
        format: OutputFormat,
        /// Write the Ince-Strutt diagram and a Campbell chart per pass (SVG) here.
        #[arg(long)]
        plot: Option<PathBuf>,
    },
    /// Mathieu characteristic values a_0..a_N and b_1..b_N at q.
    Mathieu {
        /// q, |q| <= 100.
        #[arg(long, allow_hyphen_values = true)]
        q: f64,
        /// Highest order N, 1..=10.
        #[arg(long, default_value_t = MAX_ORDER)]
        order: u8,
        /// Output format.
        #[arg(long, value_enum, default_value_t = OutputFormat::Json)]
        format: OutputFormat,
    },
    /// Floquet growth exponent of x'' + 2c x' + (a - 2q cos 2t) x = 0.
    Floquet {
        /// a, |a| <= 1e4.
        #[arg(long, allow_hyphen_values = true)]
        a: f64,
        /// q, |q| <= 100.
        #[arg(long, allow_hyphen_values = true)]
        q: f64,
        /// Damping c per unit Mathieu time, 0..=10.
        #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
        damping: f64,
        /// Output format.
        #[arg(long, value_enum, default_value_t = OutputFormat::Json)]
        format: OutputFormat,
    },
}

/// Runs one `millgate rod` subcommand and returns what to print.
pub fn run(args: RodArgs) -> anyhow::Result<String> {
    match args.command {
        RodCommand::Check {
            mill,
            schedule,
            format,
            plot,
        } => check(&mill, &schedule, format, plot.as_deref()),
        RodCommand::Mathieu { q, order, format } => mathieu(q, order, format),
        RodCommand::Floquet {
            a,
            q,
            damping,
            format,
        } => floquet(a, q, damping, format),
    }
}

/// `millgate rod check`: the passes of `schedule_path` on the mill of `mill_path`, in
/// `format`; with `plot`, the plots written into that folder (and listed in text).
fn check(
    mill_path: &Path,
    schedule_path: &Path,
    format: OutputFormat,
    plot: Option<&Path>,
) -> anyhow::Result<String> {
    let mill = Arc::new(RodMill::load(mill_path)?);
    let passes = schedule::load(schedule_path)?;
    let checked = check_schedule(&mill, &passes)?;
    let mut text = match format {
        OutputFormat::Json => serde_json::to_string_pretty(&checked)? + "\n",
        OutputFormat::Text => report::text(&checked),
    };
    if let Some(directory) = plot {
        let written = write_plots(directory, &mill, &passes, &checked)?;
        if format == OutputFormat::Text {
            for path in written {
                writeln!(text, "wrote {}", path.display())?;
            }
        }
    }
    Ok(text)
}

/// Into `directory` (created when missing), the Ince-Strutt chart of the `checked`
/// passes and each pass's Campbell diagram; returns the files written.
fn write_plots(
    directory: &Path,
    mill: &Arc<RodMill>,
    passes: &[Pass],
    checked: &ScheduleReport,
) -> anyhow::Result<Vec<PathBuf>> {
    std::fs::create_dir_all(directory)
        .with_context(|| format!("creating {}", directory.display()))?;
    let mut written = vec![directory.join("ince-strutt.svg")];
    std::fs::write(&written[0], ince_strutt_svg(mill, &checked.passes)?)
        .with_context(|| format!("writing {}", written[0].display()))?;
    for pass in passes {
        let setup = PassSetup::new(mill, pass)?;
        let name: String = pass
            .name
            .chars()
            .map(|c| {
                if c.is_ascii_alphanumeric() || c == '-' {
                    c
                } else {
                    '_'
                }
            })
            .collect();
        let path = directory.join(format!("campbell-{name}.svg"));
        std::fs::write(&path, campbell_svg(&setup)?)
            .with_context(|| format!("writing {}", path.display()))?;
        written.push(path);
    }
    Ok(written)
}

/// `millgate rod mathieu`: the characteristic values a_0..a_order and b_1..b_order at
/// `q`, in `format`.
fn mathieu(q: f64, order: u8, format: OutputFormat) -> anyhow::Result<String> {
    if !(1..=MAX_ORDER).contains(&order) {
        anyhow::bail!("--order: {order} is not allowed (must be 1 ..= {MAX_ORDER})");
    }
    let mathieu = Mathieu::default();
    let flag = |error| anyhow::anyhow!("--q {q}: {error}");
    let a = (0..=order)
        .map(|n| mathieu.characteristic_a(n, q))
        .collect::<Result<Vec<f64>, _>>()
        .map_err(flag)?;
    let b = (1..=order)
        .map(|n| mathieu.characteristic_b(n, q))
        .collect::<Result<Vec<f64>, _>>()
        .map_err(flag)?;
    Ok(match format {
        OutputFormat::Json => format!("{}\n", serde_json::json!({"q": q, "a": a, "b": b})),
        OutputFormat::Text => {
            let mut text = format!("q = {q}\n");
            for (n, value) in a.iter().enumerate() {
                writeln!(text, "a_{n} = {value:.12}")?;
            }
            for (n, value) in b.iter().enumerate() {
                writeln!(text, "b_{} = {value:.12}", n + 1)?;
            }
            text
        }
    })
}

/// `millgate rod floquet`: the growth exponent of the damped Mathieu equation at
/// `a`, `q` and `damping`, and whether it is stable, in `format`.
fn floquet(a: f64, q: f64, damping: f64, format: OutputFormat) -> anyhow::Result<String> {
    let exponent = Mathieu::default()
        .exponent(a, q, damping)
        .map_err(|error| anyhow::anyhow!("--a {a} --q {q} --damping {damping}: {error}"))?;
    let stable = exponent <= 0.0;
    Ok(match format {
        OutputFormat::Json => {
            format!(
                "{}\n",
                serde_json::json!({"exponent": exponent, "stable": stable})
            )
        }
        OutputFormat::Text => format!(
            "growth exponent {exponent:.12} per unit Mathieu time: {}\n",
            if stable { "stable" } else { "unstable" }
        ),
    })
}
