//! A capture as a file, as `millgate capture export` writes it and the maintenance
//! page's download serves it: CSV (the format `millgate analyze`, `wear` and
//! `discrepancy` read, and `pandas.read_csv(path)` or a spreadsheet as it is: a header
//! line and numbers; the capture's header in the JSON file beside it, [`sidecar_path`])
//! or Parquet (`capture_parquet.rs`). One writer for both, so a download is byte for
//! byte the exported file.
//!
//! A CSV written before the sidecar opens with a comment line `# millgate capture
//! {json}` instead; the readers take either (deprecated, kept one release:
//! `CaptureHeader::from_comments`, `CaptureHeader::from_sidecar`).

use std::io::Write;
use std::path::{Path, PathBuf};

use rusqlite::OptionalExtension;
use serde::{Deserialize, Serialize};

use super::captures::{Capture, ChannelMeta};
use super::query::{CaptureRow, HistoryReader, StoredCoil};
use super::HistoryError;
use crate::state::captures::{BiteWindowAnalysis, CaptureGap, ChatterEpisode};

/// Why a capture could not be written as a file.
#[derive(Debug, thiserror::Error)]
pub enum CaptureFileError {
    /// Writing failed.
    #[error("cannot write: {0}")]
    Io(#[from] std::io::Error),
    /// The Parquet writer refused.
    #[error("cannot write Parquet: {0}")]
    Parquet(#[from] parquet::errors::ParquetError),
    /// A channel has the name of a time column.
    #[error("channel `{0}` has the name of a time column")]
    ChannelName(String),
}

/// The comment that opened a capture's CSV before its JSON, in files written before
/// the sidecar (read for one release; no longer written).
pub(crate) const CSV_HEADER_PREFIX: &str = "millgate capture ";

/// The file holding the header of the capture CSV `csv`: `<name>.json` beside
/// `<name>.csv`.
pub fn sidecar_path(csv: &Path) -> PathBuf {
    csv.with_extension("json")
}

/// File format of an export.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum ExportFormat {
    /// CSV, as `millgate analyze`, `wear` and `discrepancy` read.
    Csv,
    /// Apache Parquet, the metadata in the file's key-value metadata.
    Parquet,
}

/// `capture-<id>-<subject>-<kind>[-bite<N>].<ext>`.
pub fn file_name(capture: &Capture, format: ExportFormat) -> String {
    let row = &capture.row;
    let subject: String = row
        .subject
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' || c == '_' {
                c
            } else {
                '_'
            }
        })
        .collect();
    let bite = row
        .bite_counter
        .map_or(String::new(), |bite| format!("-bite{bite}"));
    let ext = match format {
        ExportFormat::Csv => "csv",
        ExportFormat::Parquet => "parquet",
    };
    format!("capture-{}-{subject}-{}{bite}.{ext}", row.id, row.kind)
}

/// What a capture's file says about it besides its samples: the CSV's first comment
/// and the Parquet file's key-value metadata (`millgate.capture`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CaptureHeader {
    /// The capture's id in its history file.
    pub id: i64,
    /// `bite`, `chatter`, `manual`.
    pub kind: String,
    /// The driveline, tandem mill or request name.
    pub subject: String,
    /// The driveline's bite counter after its bite.
    pub bite_counter: Option<i64>,
    /// Its bite's time, UTC.
    pub bite_time: Option<String>,
    /// The first sample, UTC (ms).
    pub started_at: String,
    /// The first sample, ns since the Unix epoch.
    pub first_sample_unix_ns: i64,
    /// Times from the CAN kernel's receive timestamps.
    pub kernel_time: bool,
    /// Sample rate, Hz.
    pub sample_rate_hz: f64,
    /// Channels in column order: name, unit, scale, offset, how stored.
    pub channels: Vec<ChannelMeta>,
    /// Where data was lost.
    pub gaps: Vec<CaptureGap>,
    /// For a bite: how the gateway read its window.
    pub analysis: Option<BiteWindowAnalysis>,
    /// For a chatter episode: where the warning sits (absent in other kinds').
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub episode: Option<ChatterEpisode>,
    /// The millgate that stored the capture.
    pub gateway_version: String,
    /// The gateway's configuration name (`name`) in the run that stored it.
    pub config_name: Option<String>,
    /// That configuration's hash ([`millgate_config::Config::hash`]); `None` for a
    /// run recorded before schema version 8.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub config_hash: Option<String>,
    /// The process context of its time (schema v14); absent without context tags
    /// and for a capture stored before.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub context: Option<CaptureContext>,
}

/// The process context a capture was taken in, as its files say it: only values the
/// gateway trusted (an unknown value is `null` in JSON and absent from the Parquet
/// metadata), and how far it could be trusted.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CaptureContext {
    /// `valid`, `stale` (a tag without a fresh value: that value unknown) or
    /// `invalid` (an impossible value: every value unknown).
    pub status: String,
    /// Why it is not valid.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub note: Option<String>,
    /// Mill speed, m/min.
    pub speed_mpm: Option<f64>,
    /// Coil or bar id: a number, or a text (`type = "ascii"`).
    pub coil: Option<StoredCoil>,
    /// Product code.
    pub product: Option<i64>,
    /// Strip thickness, mm.
    pub thickness_mm: Option<f64>,
    /// Pass number.
    pub pass: Option<i64>,
    /// `idle`, `threading`, `rolling`, `maintenance`.
    pub mill_state: Option<String>,
}

impl CaptureContext {
    /// The context of capture row `row`; `None` when it has none.
    pub fn of(row: &CaptureRow) -> Option<Self> {
        Some(Self {
            status: row.context_status.clone()?,
            note: row.context_note.clone(),
            speed_mpm: row.speed_mpm,
            coil: row.coil.clone(),
            product: row.product,
            thickness_mm: row.thickness_mm,
            pass: row.pass,
            mill_state: row.mill_state.clone(),
        })
    }

    /// The Parquet metadata entries (key without the `millgate.` prefix, value): the
    /// status, the note when there is one, and each known value.
    pub(super) fn metadata(&self) -> Vec<(&'static str, String)> {
        [
            ("context_status", Some(self.status.clone())),
            ("context_note", self.note.clone()),
            ("speed_mpm", self.speed_mpm.map(|v| v.to_string())),
            ("coil", self.coil.as_ref().map(ToString::to_string)),
            ("product", self.product.map(|v| v.to_string())),
            ("thickness_mm", self.thickness_mm.map(|v| v.to_string())),
            ("pass", self.pass.map(|v| v.to_string())),
            ("mill_state", self.mill_state.clone()),
        ]
        .into_iter()
        .filter_map(|(key, value)| value.map(|value| (key, value)))
        .collect()
    }
}

/// The configuration a run was started with, as its history row keeps it.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct RunConfig {
    /// The configuration's `name`.
    pub name: Option<String>,
    /// Its hash; `None` before schema version 8.
    pub hash: Option<String>,
}

impl CaptureHeader {
    /// The header of `capture`.
    pub fn of(capture: &Capture, run: RunConfig) -> Self {
        let row = &capture.row;
        Self {
            id: row.id,
            kind: row.kind.clone(),
            subject: row.subject.clone(),
            bite_counter: row.bite_counter,
            bite_time: row.bite_time.clone(),
            started_at: row.started_at.clone(),
            first_sample_unix_ns: row.first_sample_unix_ns,
            kernel_time: row.kernel_time,
            sample_rate_hz: row.sample_rate_hz,
            channels: capture.meta.channels.clone(),
            gaps: capture.meta.gaps.clone(),
            analysis: capture.meta.analysis,
            episode: capture.meta.episode,
            gateway_version: capture.meta.version.clone(),
            config_name: run.name,
            config_hash: run.hash,
            context: CaptureContext::of(row),
        }
    }

    /// The header in `comments` (a CSV's `#` lines) of a file written before the
    /// sidecar, when one is a capture's; the error says where.
    pub(crate) fn from_comments(comments: &[String]) -> Option<Result<Self, String>> {
        let json = comments
            .iter()
            .find_map(|comment| comment.strip_prefix(CSV_HEADER_PREFIX))?;
        Some(serde_json::from_str(json).map_err(|error| {
            format!("the `# {CSV_HEADER_PREFIX}` line is not a capture's header: {error}")
        }))
    }

    /// The header in the sidecar of the CSV `csv` ([`sidecar_path`]), when there is
    /// one; the error names the file and why.
    pub(crate) fn from_sidecar(csv: &Path) -> Option<Result<Self, String>> {
        let path = sidecar_path(csv);
        let text = match std::fs::read_to_string(&path) {
            Ok(text) => text,
            Err(error) if error.kind() == std::io::ErrorKind::NotFound => return None,
            Err(error) => return Some(Err(format!("{}: cannot read: {error}", path.display()))),
        };
        Some(serde_json::from_str(&text).map_err(|error| {
            format!(
                "{}: not a capture's header (the JSON `millgate capture export` writes \
                 beside its CSV): {error}",
                path.display()
            )
        }))
    }
}

/// The configuration name and hash of run `run_id` (`gateway_runs`).
pub(crate) fn run_config(reader: &HistoryReader, run_id: i64) -> Result<RunConfig, HistoryError> {
    let connection = reader.connection();
    let sqlite = |source| HistoryError::Sqlite {
        path: reader.path().to_path_buf(),
        source,
    };
    // A file of schema version 7 or older, read as it is, has no hash column.
    let has_hash: bool = connection
        .query_row(
            "SELECT count(*) > 0 FROM pragma_table_info('gateway_runs')
             WHERE name = 'config_hash'",
            [],
            |row| row.get(0),
        )
        .map_err(sqlite)?;
    let query = if has_hash {
        "SELECT config_name, config_hash FROM gateway_runs WHERE id = ?1"
    } else {
        "SELECT config_name, NULL FROM gateway_runs WHERE id = ?1"
    };
    let found = connection
        .query_row(query, [run_id], |row| {
            Ok(RunConfig {
                name: row.get(0)?,
                hash: row.get(1)?,
            })
        })
        .optional()
        .map_err(sqlite)?;
    Ok(found.unwrap_or_default())
}

/// Whether `capture` can be written in `format` (a Parquet file's channel may not
/// have a time column's name): checked before anything is written.
pub(crate) fn check_writable(
    capture: &Capture,
    format: ExportFormat,
) -> Result<(), CaptureFileError> {
    let time_column = |name: &str| super::capture_parquet::TIME_COLUMNS.contains(&name);
    match capture.channels.iter().find(|c| time_column(&c.name)) {
        Some(channel) if format == ExportFormat::Parquet => {
            Err(CaptureFileError::ChannelName(channel.name.clone()))
        }
        _ => Ok(()),
    }
}

/// Write `capture` to `out` in `format`: a Parquet file with its `header` in the
/// key-value metadata; a CSV without it (the header goes to the sidecar,
/// [`write_sidecar`]).
pub fn write<W: Write + Send>(
    capture: &Capture,
    header: &CaptureHeader,
    format: ExportFormat,
    out: W,
) -> Result<(), CaptureFileError> {
    check_writable(capture, format)?;
    match format {
        ExportFormat::Csv => write_csv(capture, out),
        ExportFormat::Parquet => {
            let json = serde_json::to_string(header).map_err(std::io::Error::other)?;
            let hash = header
                .config_hash
                .iter()
                .map(|h| ("config_hash", h.clone()));
            let context = header.context.iter().flat_map(CaptureContext::metadata);
            let more = hash.chain(context).collect();
            Ok(super::capture_parquet::write(capture, &json, more, out)?)
        }
    }
}

/// Write `header` as the sidecar of a capture's CSV (pretty JSON, one trailing
/// newline) to `out`.
pub fn write_sidecar(header: &CaptureHeader, mut out: impl Write) -> Result<(), CaptureFileError> {
    serde_json::to_writer_pretty(&mut out, header).map_err(std::io::Error::other)?;
    writeln!(out)?;
    out.flush()?;
    Ok(())
}

/// Write `capture` as CSV to `out`: the header line `t,<channel>,...` and a line per
/// sample, nothing else (its header goes to the sidecar, [`write_sidecar`]).
fn write_csv(capture: &Capture, out: impl Write) -> Result<(), CaptureFileError> {
    let mut out = std::io::BufWriter::new(out);
    let names: Vec<&str> = capture.channels.iter().map(|c| c.name.as_str()).collect();
    writeln!(out, "t,{}", names.join(","))?;
    for index in 0..usize::try_from(capture.row.samples).unwrap_or(0) {
        write!(out, "{}", capture.time_s(index))?;
        for channel in &capture.channels {
            let sample = channel.samples[index];
            if sample.is_nan() && channel.timing.is_some() {
                // An extra channel's row without a sample: an empty cell.
                write!(out, ",")?;
            } else {
                write!(out, ",{sample}")?;
            }
        }
        writeln!(out)?;
    }
    out.flush()?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use rusqlite::Connection;

    use super::{run_config, RunConfig};
    use crate::history::query::HistoryReader;
    use crate::history::schema::{migrate, APPLICATION_ID, MIGRATIONS};

    /// A file left at schema version 7 (no `config_hash`) is read as it is: the run's
    /// name, no hash; migrated to version 8, a run recorded with its hash gives it.
    #[test]
    fn a_run_s_configuration_hash_is_read_from_version_8_on() {
        let folder = std::env::temp_dir().join(format!(
            "millgate-run-config-{}-{}",
            std::process::id(),
            crate::state::time::UtcTime::now().unix_ms()
        ));
        std::fs::create_dir_all(&folder).unwrap();
        let path = folder.join("history.db");
        let mut connection = Connection::open(&path).unwrap();
        for step in &MIGRATIONS[..7] {
            connection.execute_batch(step).unwrap();
        }
        connection.pragma_update(None, "user_version", 7).unwrap();
        connection
            .pragma_update(None, "application_id", APPLICATION_ID)
            .unwrap();
        connection
            .execute_batch(
                "INSERT INTO gateway_runs (started_at, version, config_name)
                     VALUES ('2026-01-01T00:00:00.000Z', 'old', 'F mill');",
            )
            .unwrap();
        let old = |path| run_config(&HistoryReader::open(path).unwrap(), 1).unwrap();
        assert_eq!(
            old(&path),
            RunConfig {
                name: Some("F mill".into()),
                hash: None
            }
        );
        assert_eq!(migrate(&mut connection).unwrap(), 7);
        connection
            .execute_batch(
                "INSERT INTO gateway_runs (started_at, version, config_name, config_hash)
                     VALUES ('2026-01-02T00:00:00.000Z', 'new', 'F mill', 'abc123');",
            )
            .unwrap();
        let reader = HistoryReader::open(&path).unwrap();
        assert_eq!(run_config(&reader, 1).unwrap().hash, None);
        assert_eq!(
            run_config(&reader, 2).unwrap().hash.as_deref(),
            Some("abc123")
        );
        assert_eq!(run_config(&reader, 3).unwrap(), RunConfig::default());
        drop((reader, connection));
        let _ = std::fs::remove_dir_all(&folder);
    }
}
