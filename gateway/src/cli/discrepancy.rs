//! `millgate discrepancy --measured FILE.csv [--measured FILE.csv ...] --model MODEL.toml
//! [--channel NAME] [--report DIR] [--format text|json]`: the model-discrepancy workflow
//! of [`millgate_sim::discrepancy`] on one or more recorded bites of one driveline.
//!
//! `--db history.db --driveline F1 --bites LAST:3` (or `--bites 12,15,19`, the
//! driveline's bite counters) takes the bites from the captures the gateway kept
//! instead of CSV files: commissioning from the gateway's own recordings.

use std::path::{Path, PathBuf};

use anyhow::Context as _;
use millgate_sim::discrepancy::{
    self, report, split_bites, DiscrepancyError, Measured, Progress, Report,
};
use millgate_sim::model::Model;

use super::capture::Picked;
use super::OutputFormat;
use crate::records::csv;

/// Smallest load step, in multiples of the record's noise, that makes a bite transient.
const MIN_STEP_OVER_NOISE: f64 = 10.0;
/// Smallest load step that is a bite of a mill, kN*m (1 N*m): a record scaled far
/// below it (1e-223 kN*m) is a unit error, and the fits would run in subnormal numbers.
const MIN_STEP_KNM: f64 = 1.0e-3;

/// Arguments of `millgate discrepancy`.
#[derive(Debug, Clone, clap::Args)]
pub struct DiscrepancyArgs {
    /// A measured record: CSV with a header, first column `t` (s), other columns torque
    /// (kN*m), uniformly sampled. Give it once per record; a record holding several
    /// bites (idle torque between them) is split into its bites. One model is fitted to
    /// every bite.
    #[arg(long, required_unless_present = "db", conflicts_with = "db")]
    pub measured: Vec<PathBuf>,
    /// Take the bites from this history file's captures (with --driveline, --bites).
    #[arg(long, requires_all = ["driveline", "bites"])]
    pub db: Option<PathBuf>,
    /// The driveline whose captured bites to use (with --db).
    #[arg(long, requires = "db")]
    pub driveline: Option<String>,
    /// Which captured bites (with --db): `LAST:N` (the newest N) or the driveline's
    /// bite counters, comma-separated (`12,15,19`).
    #[arg(long, requires = "db", value_parser = Picked::bites)]
    pub bites: Option<Picked>,
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

/// The captured bites `selection` names of `driveline` in the history `db`, oldest
/// first, read as the files would be (the channel `channel`, or the torque).
fn captured(
    db: &std::path::Path,
    driveline: &str,
    selection: &Picked,
    channel: Option<&str>,
) -> anyhow::Result<Vec<Recorded>> {
    use crate::history::query::{CaptureRow, Filter, HistoryReader};
    let reader = HistoryReader::open(db)?;
    let filter = Filter {
        name: Some(driveline.to_owned()),
        ..Filter::default()
    };
    let mut rows: Vec<CaptureRow> = Vec::new();
    reader.for_each(&filter, |row: CaptureRow| -> anyhow::Result<()> {
        let wanted = match selection {
            Picked::Last(_) => true,
            Picked::Numbers(counters) => row
                .bite_counter
                .is_some_and(|counter| counters.contains(&counter)),
        };
        if row.kind == "bite" && wanted {
            rows.push(row);
        }
        Ok(())
    })?;
    match selection {
        Picked::Last(n) => {
            let keep = rows.len().saturating_sub(*n as usize);
            rows.drain(..keep);
            if rows.len() < *n as usize {
                anyhow::bail!(
                    "{}: --bites LAST:{n}: {driveline} has {} captured bites",
                    db.display(),
                    rows.len()
                );
            }
        }
        Picked::Numbers(counters) => {
            for counter in counters {
                if !rows.iter().any(|r| r.bite_counter == Some(*counter)) {
                    anyhow::bail!(
                        "{}: --bites: no capture of bite {counter} of {driveline} (see `millgate \
                         capture list --db {} --driveline {driveline}`)",
                        db.display(),
                        db.display()
                    );
                }
            }
        }
    }
    let mut recorded = Vec::with_capacity(rows.len());
    for row in rows {
        let capture = reader.capture_of(row)?;
        let name = format!(
            "{}#capture {} (bite {} of {driveline})",
            db.display(),
            capture.row.id,
            capture.row.bite_counter.unwrap_or_default()
        );
        let torque = match channel {
            Some(wanted) => capture.channels.iter().find(|c| c.name == wanted),
            None => capture.channels.first(),
        }
        .ok_or_else(|| anyhow::anyhow!("{name}: no channel {}", channel.unwrap_or("")))?;
        check_transient(&torque.samples).map_err(|e| anyhow::anyhow!("{name}: {e}"))?;
        recorded.push(Recorded {
            path: PathBuf::from(name),
            t0_s: 0.0,
            sample_rate_hz: capture.row.sample_rate_hz,
            torque_knm: torque.samples.clone(),
        });
    }
    Ok(recorded)
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
    let mut recorded = match (&args.db, &args.driveline, &args.bites) {
        (Some(db), Some(driveline), Some(bites)) => {
            captured(db, driveline, bites, args.channel.as_deref())?
        }
        _ => Vec::with_capacity(args.measured.len()),
    };
    for path in &args.measured {
        recorded.push(Recorded::read(path, args.channel.as_deref())?);
    }
    let model = Model::load(&args.model)?;
    let (bites, sources) = split(&recorded);
    let report = explain(&bites, &sources, &model)?;
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

impl Recorded {
    /// The CSV at `path`, its torque in `channel` (the first without one): uniform
    /// time (the shared reader's check) and a load step to explain.
    fn read(path: &Path, channel: Option<&str>) -> anyhow::Result<Self> {
        let table = csv::read(path).with_context(|| path.display().to_string())?;
        let (_, torque) = table
            .pick_torque(channel)
            .map_err(anyhow::Error::msg)
            .with_context(|| path.display().to_string())?;
        let sample_rate_hz = table
            .sample_rate_hz()
            .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
        check_transient(torque).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
        Ok(Self {
            path: path.to_path_buf(),
            t0_s: table.time_s[0],
            sample_rate_hz,
            torque_knm: torque.to_vec(),
        })
    }
}

/// Every bite of the `recorded` files, and the file each came from; a file of more
/// than one bite is said on stderr.
fn split(recorded: &[Recorded]) -> (Vec<Measured<'_>>, Vec<&PathBuf>) {
    let mut bites = Vec::new();
    let mut sources = Vec::new();
    for record in recorded {
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
    (bites, sources)
}

/// The discrepancy workflow on `bites` (from the files `sources`) against `model`,
/// its progress on stderr; an error about a bite names its file.
fn explain(bites: &[Measured<'_>], sources: &[&PathBuf], model: &Model) -> anyhow::Result<Report> {
    let started = std::time::Instant::now();
    let outcome = discrepancy::run(bites, model, |progress| match progress {
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
    Ok(report)
}

/// Fails unless `torque_knm` holds a bite transient: a load step from its first 5% to
/// its last 20% of at least [`MIN_STEP_OVER_NOISE`] times its noise (RMS of the first
/// differences / sqrt 2), and of at least [`MIN_STEP_KNM`]. A constant record would
/// otherwise be "explained" by the effect that best fits nothing (`extra_inertia` with
/// a stiffness change of +17 000%).
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
    let stepped = step_knm.abs() > MIN_STEP_OVER_NOISE * noise_knm && step_knm.abs() > 0.0;
    if !stepped {
        Err(format!(
            "the torque record has no transient: its last 20% lies {step_knm:.3} kN*m from \
             its first 5% (noise {noise_knm:.3} kN*m RMS); the workflow needs a bite, a load \
             step of more than {MIN_STEP_OVER_NOISE} times the noise"
        ))
    } else if step_knm.abs() < MIN_STEP_KNM {
        Err(format!(
            "the torque record's load step is {step_knm:e} kN*m, less than {MIN_STEP_KNM:e} \
             kN*m: no mill's bite (a unit or scaling error?)"
        ))
    } else {
        Ok(())
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
        // The same bite scaled to 1e-223 kN*m: noise-free enough, but no mill's.
        let tiny: Vec<f64> = bite.iter().map(|v| v * 1.0e-225).collect();
        let error = check_transient(&tiny).unwrap_err();
        assert!(error.contains("less than 1e-3 kN*m"), "{error}");
    }
}
