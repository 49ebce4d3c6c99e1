//! `millgate history`: export the event history as CSV, JSON or Markdown.
//!
//! ```text
//! millgate history --db FILE [--kind bites|wear|alarms|outages|chatter|runs]
//!                  [--driveline NAME] [--source NAME] [--since T] [--until T]
//!                  [--limit N] --format csv|json|md
//! ```
//!
//! Times are UTC: an ISO-8601 date or date and time, or Unix seconds
//! ([`UtcTime::parse`]); `--since` is inclusive, `--until` exclusive. The columns are
//! the table's ([`crate::history::query`]), in the same order in every format.
//!
//! The rows are written as they are read, so a year of bites (4 million rows) takes
//! the memory of one; progress goes to stderr when it is a terminal
//! (`cli::progress`).

use std::io::Write;
use std::path::PathBuf;

use crate::cli::progress::{percent, Progress};
use crate::cli::registers::csv_field;
use crate::history::query::{
    AlarmRow, BiteRow, ChatterRow, Filter, HistoryReader, OutageRow, Record, RunRow, WearRow,
};
use crate::state::time::UtcTime;

/// What to export.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Kind {
    /// Every bite: torques, TAF, periods, frequencies, quality, wear.
    Bites,
    /// Wear estimates and wear-trend resets.
    Wear,
    /// Alarms raised, cleared and acknowledged (and by whom).
    Alarms,
    /// Source outages.
    Outages,
    /// Chatter episodes of tandem mills.
    Chatter,
    /// Gateway starts and stops.
    Runs,
}

/// Output format of the export.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Format {
    /// CSV: a header line of the columns, then one line per row.
    Csv,
    /// A JSON array, one object per row with the columns as keys.
    Json,
    /// A Markdown table: a header of the columns, then one line per row.
    Md,
}

/// Arguments of `millgate history`.
#[derive(Debug, Clone, clap::Args)]
pub struct HistoryArgs {
    /// The history file (`history.path` of the configuration).
    #[arg(long)]
    pub db: PathBuf,
    /// What to export.
    #[arg(long, value_enum, default_value = "bites")]
    pub kind: Kind,
    /// Only this driveline (bites, wear, alarms; for alarms also a tandem mill; for
    /// chatter a tandem mill).
    #[arg(long)]
    pub driveline: Option<String>,
    /// Only this source (outages).
    #[arg(long)]
    pub source: Option<String>,
    /// From this time on (UTC, inclusive).
    #[arg(long)]
    pub since: Option<String>,
    /// Before this time (UTC, exclusive).
    #[arg(long)]
    pub until: Option<String>,
    /// At most this many rows (the oldest first).
    #[arg(long)]
    pub limit: Option<u32>,
    /// Only bites (or chatter episodes) of this product code (the context of their
    /// time; bites and chatter episodes only).
    #[arg(long)]
    pub product: Option<u32>,
    /// Only bites (or chatter episodes) of this coil or bar id, as the PLC gave it
    /// (a text id with its characters: `04711` is not `4711`; bites and chatter
    /// episodes only).
    #[arg(long)]
    pub coil: Option<String>,
    /// Output format.
    #[arg(long, value_enum, default_value = "csv")]
    pub format: Format,
}

/// `--since` / `--until` as a time, naming the option in the error.
pub(crate) fn parse_time(option: &str, text: Option<&str>) -> anyhow::Result<Option<UtcTime>> {
    text.map(|text| UtcTime::parse(text).map_err(|error| anyhow::anyhow!("{option}: {error}")))
        .transpose()
}

/// `--since` and `--until` as times, `--since` before `--until` when both are given
/// (a range with nothing in it is a mistake, not an empty answer).
pub(crate) fn parse_range(
    since: Option<&str>,
    until: Option<&str>,
) -> anyhow::Result<(Option<UtcTime>, Option<UtcTime>)> {
    let (since, until) = (parse_time("--since", since)?, parse_time("--until", until)?);
    if let (Some(since), Some(until)) = (since, until) {
        if since >= until {
            anyhow::bail!("--since ({since}) must be before --until ({until})");
        }
    }
    Ok((since, until))
}

/// The export `args` ask for, written to stdout as the rows are read (the memory of
/// one row, whatever the file's size), with progress on stderr when it is a terminal
/// (`Progress`). A closed stdout (`millgate history ... | head`) ends the export
/// with an error `main` ends quietly ([`super::shell::is_broken_pipe`]).
pub fn run(args: &HistoryArgs) -> anyhow::Result<()> {
    let stdout = std::io::stdout().lock();
    export(args, std::io::BufWriter::with_capacity(1 << 16, stdout))
}

/// The export `args` ask for, written to `out`.
pub fn export(args: &HistoryArgs, out: impl Write) -> anyhow::Result<()> {
    let name = match (args.kind, &args.driveline, &args.source) {
        (Kind::Outages, Some(_), _) => {
            anyhow::bail!("--driveline does not apply to outages (use --source NAME)")
        }
        (Kind::Outages, None, source) => source.clone(),
        (_, _, Some(_)) => anyhow::bail!("--source applies to outages only (--kind outages)"),
        (Kind::Runs, Some(_), None) => {
            anyhow::bail!("--driveline does not apply to runs")
        }
        (_, driveline, None) => driveline.clone(),
    };
    for (option, given) in [
        ("--product", args.product.is_some()),
        ("--coil", args.coil.is_some()),
    ] {
        if given && !matches!(args.kind, Kind::Bites | Kind::Chatter) {
            anyhow::bail!(
                "{option} applies to bites and chatter episodes only (--kind bites, --kind chatter)"
            );
        }
    }
    let filter = Filter {
        name,
        since: parse_time("--since", args.since.as_deref())?,
        until: parse_time("--until", args.until.as_deref())?,
        after_id: None,
        limit: args.limit,
        product: args.product,
        coil: args.coil.clone(),
    };
    let reader = HistoryReader::open(&args.db)?;
    match args.kind {
        Kind::Bites => write_rows::<BiteRow>(&reader, &filter, args.format, out),
        Kind::Wear => write_rows::<WearRow>(&reader, &filter, args.format, out),
        Kind::Alarms => write_rows::<AlarmRow>(&reader, &filter, args.format, out),
        Kind::Outages => write_rows::<OutageRow>(&reader, &filter, args.format, out),
        Kind::Chatter => write_rows::<ChatterRow>(&reader, &filter, args.format, out),
        Kind::Runs => write_rows::<RunRow>(&reader, &filter, args.format, out),
    }
}

/// The rows of `R` that pass `filter`, as read, in `format` to `out`: a CSV (header
/// line first), a JSON array (one object per line) or a Markdown table.
fn write_rows<R: Record>(
    reader: &HistoryReader,
    filter: &Filter,
    format: Format,
    mut out: impl Write,
) -> anyhow::Result<()> {
    let mut progress = Progress::on_terminal();
    let total = reader.count::<R>(filter)?;
    match format {
        Format::Json => out.write_all(b"[")?,
        Format::Csv => writeln!(out, "{}", R::columns().join(","))?,
        Format::Md => writeln!(
            out,
            "| {} |\n|{}",
            R::columns().join(" | "),
            "---|".repeat(R::columns().len())
        )?,
    }
    let mut written: u64 = 0;
    reader.for_each(filter, |row: R| -> anyhow::Result<()> {
        match format {
            Format::Json => {
                out.write_all(if written == 0 { b"\n" } else { b",\n" })?;
                serde_json::to_writer(&mut out, &row)?;
            }
            Format::Csv => {
                let cells: Vec<String> = row
                    .cells()
                    .iter()
                    .map(|cell| csv_field(&cell.to_string()))
                    .collect();
                writeln!(out, "{}", cells.join(","))?;
            }
            Format::Md => {
                let cells: Vec<String> = row
                    .cells()
                    .iter()
                    .map(|cell| cell.to_string().replace('|', "\\|"))
                    .collect();
                writeln!(out, "| {} |", cells.join(" | "))?;
            }
        }
        written += 1;
        progress.update(|| {
            format!(
                "history: {written} of {total} rows of {} ({:.0}%)",
                R::TABLE,
                percent(written, total)
            )
        });
        Ok(())
    })?;
    if format == Format::Json {
        out.write_all(if written == 0 { b"]\n" } else { b"\n]\n" })?;
    }
    out.flush()?;
    progress.finish(&format!(
        "history: {written} rows of {} in {:.1} s",
        R::TABLE,
        progress.elapsed_s()
    ));
    Ok(())
}
