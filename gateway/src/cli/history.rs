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
//! the table's ([`crate::outputs::history::query`]), in the same order in every format.

use std::path::PathBuf;

use crate::cli::registers::csv_field;
use crate::outputs::history::query::{
    AlarmRow, BiteRow, ChatterRow, Filter, HistoryReader, OutageRow, Record, RunRow, WearRow,
};
use crate::outputs::history::time::UtcTime;

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
    /// Output format.
    #[arg(long, value_enum, default_value = "csv")]
    pub format: Format,
}

/// `--since` / `--until` as a time, naming the option in the error.
pub fn parse_time(option: &str, text: Option<&str>) -> anyhow::Result<Option<UtcTime>> {
    text.map(|text| UtcTime::parse(text).map_err(|error| anyhow::anyhow!("{option}: {error}")))
        .transpose()
}

/// The export `args` ask for.
pub fn run(args: &HistoryArgs) -> anyhow::Result<String> {
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
    let filter = Filter {
        name,
        since: parse_time("--since", args.since.as_deref())?,
        until: parse_time("--until", args.until.as_deref())?,
        after_id: None,
        limit: args.limit,
    };
    let reader = HistoryReader::open(&args.db)?;
    Ok(match args.kind {
        Kind::Bites => export::<BiteRow>(&reader, &filter, args.format)?,
        Kind::Wear => export::<WearRow>(&reader, &filter, args.format)?,
        Kind::Alarms => export::<AlarmRow>(&reader, &filter, args.format)?,
        Kind::Outages => export::<OutageRow>(&reader, &filter, args.format)?,
        Kind::Chatter => export::<ChatterRow>(&reader, &filter, args.format)?,
        Kind::Runs => export::<RunRow>(&reader, &filter, args.format)?,
    })
}

fn export<R: Record>(
    reader: &HistoryReader,
    filter: &Filter,
    format: Format,
) -> anyhow::Result<String> {
    let rows: Vec<R> = reader.rows(filter)?;
    Ok(format_rows(&rows, format))
}

/// `rows` as a CSV (header line first), a JSON array of objects, or a Markdown table.
pub fn format_rows<R: Record>(rows: &[R], format: Format) -> String {
    match format {
        Format::Json => serde_json::to_string_pretty(rows).unwrap_or_default() + "\n",
        Format::Csv => {
            let mut out = R::COLUMNS.join(",") + "\n";
            for row in rows {
                let cells: Vec<String> = row
                    .cells()
                    .iter()
                    .map(|cell| csv_field(&cell.to_string()))
                    .collect();
                out += &cells.join(",");
                out.push('\n');
            }
            out
        }
        Format::Md => {
            let mut out = format!(
                "| {} |\n|{}\n",
                R::COLUMNS.join(" | "),
                "---|".repeat(R::COLUMNS.len())
            );
            for row in rows {
                let cells: Vec<String> = row
                    .cells()
                    .iter()
                    .map(|cell| cell.to_string().replace('|', "\\|"))
                    .collect();
                out += &format!("| {} |\n", cells.join(" | "));
            }
            out
        }
    }
}
