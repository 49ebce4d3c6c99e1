//! `millgate capture`: list the captures a history file keeps, and export them, one
//! file per capture.
//!
//! ```text
//! millgate capture list --db FILE [--driveline NAME] [--kind K] [--since T] [--until T]
//!                       [--format text|json]
//! millgate capture export --db FILE [--driveline NAME] [--kind K] [--since T] [--until T]
//!                         [--bite N] [--id N] --format csv|parquet --out DIR
//! ```
//!
//! A CSV export is the format `millgate analyze`, `wear` and `discrepancy` read, and
//! `pandas.read_csv(path)` or a spreadsheet as it is: a header `t,<channel>,...` (t in
//! s from the first sample, the sample's index over the sample rate), one line per
//! sample with the stored values written as the shortest text that reads back to the
//! same `f64`, nothing else. Beside it, `<name>.json` holds what the file cannot say
//! in columns (the capture's id, subject, bite, the first sample's UTC time in ns,
//! sample rate, channels' units, scale and offset, gaps, and for a bite how the
//! gateway read the window). `millgate analyze` reads a bite's window from that file
//! as the gateway did, so it prints the figures the gateway published for the bite.
//! An export written before the JSON file (the same JSON in a first comment line
//! `# millgate capture {...}`) is still read (deprecated, kept one release).
//!
//! Captures are read and written one at a time: an export of a year-scale file takes
//! the memory of one capture.

use std::fmt::Write as _;
use std::path::PathBuf;

use anyhow::Context as _;

use crate::cli::history::parse_range;
pub(crate) use crate::history::capture_files::CaptureHeader;
pub use crate::history::capture_files::{file_name, ExportFormat};
use crate::history::capture_files::{run_config, sidecar_path, write, write_sidecar};
use crate::history::captures::row_json;
use crate::history::query::{CaptureRow, Filter, HistoryReader};
use crate::history::HistoryError;

/// Which captured rows a command takes: `LAST:N` (the newest N) or numbers,
/// comma-separated (`12,15,19`): `discrepancy --bites` (bite counters) and
/// `chatter commission --captures` (capture ids).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Picked {
    /// The newest N.
    Last(u32),
    /// These numbers.
    Numbers(Vec<i64>),
}

impl Picked {
    /// `text` read as `LAST:N` or `numbers` (what the numbers are, for the error).
    fn parse(text: &str, numbers: &str) -> Result<Picked, String> {
        let wrong = || format!("`{text}`: expected LAST:N (N >= 1) or {numbers}");
        if let Some(count) = text
            .strip_prefix("LAST:")
            .or_else(|| text.strip_prefix("last:"))
        {
            return match count.trim().parse::<u32>() {
                Ok(n) if n >= 1 => Ok(Picked::Last(n)),
                _ => Err(wrong()),
            };
        }
        let listed: Result<Vec<i64>, _> =
            text.split(',').map(|c| c.trim().parse::<i64>()).collect();
        match listed {
            Ok(listed) if !listed.is_empty() => Ok(Picked::Numbers(listed)),
            _ => Err(wrong()),
        }
    }

    /// `--bites`: `LAST:N` or bite counters.
    pub fn bites(text: &str) -> Result<Picked, String> {
        Picked::parse(text, "bite counters such as 12,15,19")
    }

    /// `--captures`: `LAST:N` or capture ids.
    pub fn captures(text: &str) -> Result<Picked, String> {
        Picked::parse(text, "capture ids such as 12,15")
    }
}

/// What `millgate capture` does.
#[derive(Debug, Clone, clap::Subcommand)]
pub enum CaptureCommand {
    /// List the captures (one line, or one JSON object, per capture).
    List(ListArgs),
    /// Export captures, one file per capture, to a folder.
    Export(ExportArgs),
}

/// Which captures: the options `list` and `export` share.
#[derive(Debug, Clone, clap::Args)]
pub struct Selection {
    /// The history file (`history.path` of the configuration).
    #[arg(long)]
    pub db: PathBuf,
    /// Only this driveline's (or tandem mill's, or manual request's) captures.
    #[arg(long, visible_alias = "mill")]
    pub driveline: Option<String>,
    /// Only captures of this kind.
    #[arg(long, value_enum)]
    pub kind: Option<KindArg>,
    /// Captures whose first sample is at or after this time (UTC).
    #[arg(long)]
    pub since: Option<String>,
    /// Captures whose first sample is before this time (UTC).
    #[arg(long)]
    pub until: Option<String>,
    /// Only captures taken rolling this product code (the context of their time,
    /// schema v14; a capture whose product is unknown is left out).
    #[arg(long)]
    pub product: Option<u32>,
    /// Only captures taken rolling this coil or bar id, as the PLC gave it (a text id
    /// with its characters: `04711` is not `4711`; a capture whose coil is unknown is
    /// left out).
    #[arg(long)]
    pub coil: Option<String>,
}

/// A capture kind on the command line.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum KindArg {
    /// Bite windows.
    Bite,
    /// Chatter episodes.
    Chatter,
    /// Manual captures.
    Manual,
}

impl KindArg {
    fn name(self) -> &'static str {
        match self {
            KindArg::Bite => "bite",
            KindArg::Chatter => "chatter",
            KindArg::Manual => "manual",
        }
    }
}

/// Arguments of `millgate capture list`.
#[derive(Debug, Clone, clap::Args)]
pub struct ListArgs {
    /// Which captures.
    #[command(flatten)]
    pub selection: Selection,
    /// Output format.
    #[arg(long, value_enum, default_value = "text")]
    pub format: super::OutputFormat,
}

/// Arguments of `millgate capture export`.
#[derive(Debug, Clone, clap::Args)]
pub struct ExportArgs {
    /// Which captures.
    #[command(flatten)]
    pub selection: Selection,
    /// Only the capture of this bite (the driveline's bite counter; with --driveline).
    #[arg(long)]
    pub bite: Option<i64>,
    /// Only the capture with this id (as `capture list` shows).
    #[arg(long)]
    pub id: Option<i64>,
    /// File format.
    #[arg(long, value_enum)]
    pub format: ExportFormat,
    /// The folder to write to (created when missing).
    #[arg(long)]
    pub out: PathBuf,
}

/// Runs `millgate capture`; returns what to print.
pub fn run(command: &CaptureCommand) -> anyhow::Result<String> {
    match command {
        CaptureCommand::List(args) => list(args),
        CaptureCommand::Export(args) => {
            let written = export(args)?;
            let mut out = String::new();
            for path in &written {
                writeln!(out, "{}", path.display())?;
            }
            Ok(out)
        }
    }
}

/// The selection as a filter, after checking its driveline names one in the file.
fn filter(reader: &HistoryReader, selection: &Selection) -> anyhow::Result<Filter> {
    if let Some(name) = &selection.driveline {
        let known = reader.drivelines()?;
        let captured = reader.count::<CaptureRow>(&Filter {
            name: Some(name.clone()),
            limit: Some(1),
            ..Filter::default()
        })?;
        if !known.contains(name) && captured == 0 {
            return Err(HistoryError::UnknownDriveline {
                path: reader.path().to_path_buf(),
                name: name.clone(),
            }
            .into());
        }
    }
    let (since, until) = parse_range(selection.since.as_deref(), selection.until.as_deref())?;
    Ok(Filter {
        name: selection.driveline.clone(),
        since,
        until,
        after_id: None,
        limit: None,
        product: selection.product,
        coil: selection.coil.clone(),
    })
}

/// Visit each capture row of `selection` (and `extra`'s test), in id order; returns
/// how many were visited.
fn for_each_row(
    reader: &HistoryReader,
    selection: &Selection,
    extra: impl Fn(&CaptureRow) -> bool,
    mut visit: impl FnMut(CaptureRow) -> anyhow::Result<()>,
) -> anyhow::Result<u64> {
    let filter = filter(reader, selection)?;
    let kind = selection.kind.map(KindArg::name);
    let mut visited = 0u64;
    reader.for_each(&filter, |row: CaptureRow| -> anyhow::Result<()> {
        if kind.is_none_or(|kind| row.kind == kind) && extra(&row) {
            visited += 1;
            visit(row)?;
        }
        Ok(())
    })?;
    Ok(visited)
}

/// The error for a selection without captures, with what the file holds.
fn nothing(reader: &HistoryReader, selection: &Selection) -> anyhow::Error {
    let (count, _) = reader.capture_totals().unwrap_or((0, 0));
    let mut what = String::from("no captures");
    if let Some(kind) = selection.kind {
        write!(what, " of kind {}", kind.name()).ok();
    }
    if let Some(name) = &selection.driveline {
        write!(what, " of {name}").ok();
    }
    if let Some(since) = &selection.since {
        write!(what, " since {since}").ok();
    }
    if let Some(until) = &selection.until {
        write!(what, " until {until}").ok();
    }
    if let Some(product) = selection.product {
        write!(what, " of product {product}").ok();
    }
    if let Some(coil) = &selection.coil {
        write!(what, " of coil {coil:?}").ok();
    }
    let range = reader
        .rows::<CaptureRow>(&Filter {
            limit: Some(1),
            ..Filter::default()
        })
        .ok()
        .and_then(|rows| rows.into_iter().next())
        .zip(
            reader
                .newest::<CaptureRow>(&Filter {
                    limit: Some(1),
                    ..Filter::default()
                })
                .ok()
                .and_then(|rows| rows.into_iter().next()),
        );
    let holds = match range {
        Some((first, last)) => format!(
            "the file holds {count} captures, from {} to {}",
            first.started_at, last.started_at
        ),
        None => "the file holds no captures".to_owned(),
    };
    anyhow::anyhow!("{}: {what} ({holds})", reader.path().display())
}

fn list(args: &ListArgs) -> anyhow::Result<String> {
    let reader = HistoryReader::open(&args.selection.db)?;
    let mut out = String::new();
    // JSON is written row by row as text: the list of 20 000 captures as JSON values
    // took 133 MB, as text it is its own size.
    if args.format == super::OutputFormat::Json {
        out.push('[');
    }
    if args.format == super::OutputFormat::Text {
        writeln!(
            out,
            "{:>6} {:<8} {:<12} {:>6} {:<24} {:>8} {:>7} {:>9} {:>4} {:>8} {:>10} {:>7} {:<8}  channels",
            "id",
            "kind",
            "subject",
            "bite",
            "first sample (UTC)",
            "span_s",
            "rate_hz",
            "samples",
            "keep",
            "bytes",
            "coil",
            "product",
            "context"
        )?;
    }
    for_each_row(
        &reader,
        &args.selection,
        |_| true,
        |row| {
            match args.format {
                super::OutputFormat::Text => {
                    let channels = serde_json::from_str::<serde_json::Value>(&row.meta)
                        .ok()
                        .and_then(|meta| {
                            meta["channels"].as_array().map(|channels| {
                                channels
                                    .iter()
                                    .filter_map(|c| c["name"].as_str().map(str::to_owned))
                                    .collect::<Vec<_>>()
                                    .join(",")
                            })
                        })
                        .unwrap_or_default();
                    writeln!(
                    out,
                    "{:>6} {:<8} {:<12} {:>6} {:<24} {:>8.3} {:>7} {:>9} {:>4} {:>8} {:>10} {:>7} {:<8}  {channels}",
                    row.id,
                    row.kind,
                    row.subject,
                    row.bite_counter.map_or("-".to_owned(), |b| b.to_string()),
                    row.started_at,
                    row.duration_s,
                    row.sample_rate_hz,
                    row.samples,
                    row.keep,
                    row.bytes,
                    row.coil.map_or("-".to_owned(), |c| c.to_string()),
                    row.product.map_or("-".to_owned(), |p| p.to_string()),
                    row.context_status.as_deref().unwrap_or("-")
                )?;
                }
                super::OutputFormat::Json => {
                    if out.len() > 1 {
                        out.push(',');
                    }
                    out.push_str(&row_json(&row).to_string());
                }
            }
            Ok(())
        },
    )?;
    if args.format == super::OutputFormat::Json {
        out.push(']');
    }
    Ok(out)
}

/// Export the captures `args` select; returns the files written.
pub fn export(args: &ExportArgs) -> anyhow::Result<Vec<PathBuf>> {
    if args.bite.is_some() && args.selection.driveline.is_none() {
        anyhow::bail!("--bite N needs --driveline NAME (bite counters are per driveline)");
    }
    let reader = HistoryReader::open(&args.selection.db)?;
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("--out {}: cannot create the folder", args.out.display()))?;
    let mut written = Vec::new();
    let matches = |row: &CaptureRow| {
        args.bite.is_none_or(|bite| row.bite_counter == Some(bite))
            && args.id.is_none_or(|id| row.id == id)
    };
    for_each_row(&reader, &args.selection, matches, |row| {
        let run = run_config(&reader, row.run_id)?;
        let capture = reader.capture_of(row)?;
        let header = CaptureHeader::of(&capture, run);
        let path = args.out.join(file_name(&capture, args.format));
        let mut files = vec![path.clone()];
        let mut result = std::fs::File::create(&path)
            .map_err(Into::into)
            .and_then(|file| write(&capture, &header, args.format, file));
        if result.is_ok() && args.format == ExportFormat::Csv {
            let sidecar = sidecar_path(&path);
            files.push(sidecar.clone());
            result = std::fs::File::create(&sidecar)
                .map_err(Into::into)
                .and_then(|file| write_sidecar(&header, file));
        }
        if let Err(error) = result {
            // No half-written file left behind (a full disk): only whole captures.
            for file in &files {
                let _ = std::fs::remove_file(file);
            }
            return Err(anyhow::Error::new(error).context(format!(
                "{}: capture {} not exported (the part written was removed)",
                path.display(),
                capture.row.id
            )));
        }
        written.extend(files);
        Ok(())
    })?;
    if written.is_empty() {
        let mut error = nothing(&reader, &args.selection);
        if let Some(bite) = args.bite {
            error = error.context(format!("--bite {bite}: no capture of that bite"));
        }
        if let Some(id) = args.id {
            error = error.context(format!("--id {id}: no such capture in the selection"));
        }
        return Err(error);
    }
    Ok(written)
}
