//! `millgate report`: a maintenance report from the event history.
//!
//! ```text
//! millgate report --db FILE --out DIR [--since T] [--until T]
//! ```
//!
//! Writes into `DIR`: `report.md` (plots linked), `report.html` (one file that opens
//! offline, plots inline) and the SVG plots, each reduced to what a reader can see
//! (a year of bites is a million per driveline):
//! - per driveline `<name>-time.svg`: in 450 time buckets (the web page's
//!   [`wear_series`]), the TAF's range and mean with its warning and alarm
//!   thresholds; the wear index's range and the wear trend;
//! - per driveline `<name>-gap.svg`, when the history holds the gap diagnosis: the
//!   gap estimate in the same buckets with its interval and thresholds and, after
//!   the last bite, the forecast recomputed from the wear trend the history saved
//!   (the fitted growth line, the cone's mean and 90% band, the expected date of the
//!   gap alarm written at it), the time axis reaching the cone's end;
//! - per driveline `<name>-taf.svg`: TAF over static torque, the bites binned into
//!   180 x 90 cells shaded by count (degraded windows grey), with the thresholds and,
//!   when the driveline's model file (as configured) can be read, the wear map's
//!   curves for gaps of 0..4 mrad over the measured torque range;
//! - per driveline `<name>-capture-<id>.svg`: the captured torque of each of its last
//!   [`ALARM_TRACES`] alarm bites in the period (newest first; the history keeps
//!   alarm bites' captures longest), reduced to 450 columns of lowest and highest
//!   samples with the trigger marked, each with the capture's id and the
//!   `millgate capture export` command that writes its samples;
//! - per driveline with a fatigue ledger `<name>-fatigue-life.svg`: each component's
//!   life used after the last bite of each of the same time buckets, with the life
//!   limit the ledger was saved with and the resets marked; and
//!   `<name>-fatigue-damage.svg`: each component's damage per trusted bite over the
//!   bite's TAF (logarithmic), binned into 180 x 90 cells as the bites are read;
//! - `alarms.svg`: the alarm timeline (raised, cleared, acknowledged; latched spans);
//! - `availability.svg`: when the gateway ran (and, for a run without a recorded
//!   stop, from its last recorded event on, that the file cannot tell), each
//!   source's outages.
//!
//! The Markdown and the HTML come from one document model ([`Block`]). Bites are
//! never held: counted and aggregated by SQLite or binned as they are read, so the
//! memory is that of the buckets and cells; progress goes to stderr when it is a
//! terminal.
//!
//! The module's files follow its jobs: `period` (what is read of the whole history
//! for the period), `data` (what is read of a driveline), `drivelines` (the summary
//! table and each driveline's section), `timeline` (the alarm timeline),
//! `availability` (the gateway's runs and the sources' outages), `document` (the
//! document model, Markdown and HTML), `plots` (the SVG plots and the binning of
//! bites), `spans` (run and alarm spans on the time axis); this file assembles the
//! report and writes it.
//!
//! [`wear_series`]: crate::history::query::HistoryReader::wear_series

mod availability;
mod data;
mod document;
mod drivelines;
mod period;
mod plots;
mod spans;
mod timeline;

use std::path::{Path, PathBuf};

pub use document::{html, markdown, Block};
pub use drivelines::ALARM_TRACES;
use period::Period;

use crate::cli::history::parse_time;
use crate::cli::progress::Progress;
use crate::history::query::HistoryReader;
use crate::state::time::UtcTime;

/// Arguments of `millgate report`.
#[derive(Debug, Clone, clap::Args)]
pub struct ReportArgs {
    /// The history file.
    #[arg(long)]
    pub db: PathBuf,
    /// Folder for report.md, report.html and the plots (created when missing).
    #[arg(long)]
    pub out: PathBuf,
    /// From this time on (UTC; default: the first event).
    #[arg(long)]
    pub since: Option<String>,
    /// Up to this time (UTC; default: now).
    #[arg(long)]
    pub until: Option<String>,
}

/// Write the report of `args`; returns what was written.
///
/// Memory: the report holds the alarms, runs and outages of the period (a few
/// thousand rows a year) and, per driveline, its buckets and cells, never its bites:
/// those are counted, aggregated and binned by SQLite or as they are read.
pub fn run(args: &ReportArgs) -> anyhow::Result<String> {
    let reader = HistoryReader::open(&args.db)?;
    let since = parse_time("--since", args.since.as_deref())?;
    let until = parse_time("--until", args.until.as_deref())?;
    let mut progress = Progress::on_terminal();
    let period = Period::read(&reader, since, until)?;
    let read = drivelines::read(&reader, &period, &mut progress)?;
    let mut blocks = title(&args.db, &period);
    drivelines::summary(&period, &read, &mut blocks);
    drivelines::products(&period, &read, &mut blocks);
    for (name, data) in period.drivelines.iter().zip(&read) {
        drivelines::section(&reader, &args.db, &period, (name, data), &mut blocks)?;
    }
    timeline::alarms(&period, &mut blocks)?;
    availability::sources(&reader, &period, &mut blocks)?;
    let written = write(&args.out, &period.config_name, &blocks)?;
    let bites: u64 = read.iter().map(|d| d.summary.bites).sum();
    progress.finish(&format!(
        "report: {} drivelines, {bites} bites in {:.1} s",
        period.drivelines.len(),
        progress.elapsed_s()
    ));
    Ok(format!(
        "report written to {}: report.md, report.html, {} ({bites} bites, {} alarm events, {} outages)",
        args.out.display(),
        written.join(", "),
        period.alarms.len(),
        period.outages.len()
    ))
}

/// The report's title and what it covers of the history `db`.
fn title(db: &Path, period: &Period) -> Vec<Block> {
    vec![
        Block::Heading(1, format!("Maintenance report: {}", period.config_name)),
        Block::Text(format!(
            "History {}, {} to {} (UTC); generated {} by millgate {}.",
            db.display(),
            period.start,
            period.end,
            UtcTime::now(),
            env!("CARGO_PKG_VERSION")
        )),
    ]
}

/// Write `blocks`, the report of configuration `config_name`, into the folder `out`
/// (created when missing): each figure's SVG, report.md and report.html; returns the
/// figures' files.
fn write(out: &Path, config_name: &str, blocks: &[Block]) -> anyhow::Result<Vec<String>> {
    std::fs::create_dir_all(out)
        .map_err(|e| anyhow::anyhow!("{}: cannot create the folder: {e}", out.display()))?;
    let write = |name: &str, text: &str| {
        let path = out.join(name);
        std::fs::write(&path, text)
            .map_err(|e| anyhow::anyhow!("{}: cannot write: {e}", path.display()))
    };
    let mut written = Vec::new();
    for block in blocks {
        if let Block::Figure { file, svg, .. } = block {
            write(file, svg)?;
            written.push(file.clone());
        }
    }
    write("report.md", &markdown(blocks))?;
    write(
        "report.html",
        &html(&format!("Maintenance report: {config_name}"), blocks),
    )?;
    Ok(written)
}
