//! A capture as a file, as `millgate capture export` writes it and the maintenance
//! page's download serves it: CSV (the format `millgate analyze`, `wear` and
//! `discrepancy` read, the capture's header in its first comment) or Parquet
//! (`capture_parquet.rs`). One writer for both, so a download
//! is byte for byte the exported file.

use std::io::Write;

use serde::{Deserialize, Serialize};

use super::captures::{Capture, ChannelMeta};
use super::query::{Filter, HistoryReader};
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

/// The comment that opens a capture's CSV, before its JSON.
pub const CSV_HEADER_PREFIX: &str = "millgate capture ";

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
}

impl CaptureHeader {
    /// The header of `capture`.
    pub fn of(capture: &Capture, config_name: Option<String>) -> Self {
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
            config_name,
        }
    }

    /// The header in `comments` (a CSV's `#` lines), when one is a capture's.
    pub fn from_comments(comments: &[String]) -> Option<Result<Self, serde_json::Error>> {
        let json = comments
            .iter()
            .find_map(|comment| comment.strip_prefix(CSV_HEADER_PREFIX))?;
        Some(serde_json::from_str(json))
    }
}

/// The configuration name of run `run_id` (`gateway_runs.config_name`).
pub fn run_config_name(
    reader: &HistoryReader,
    run_id: i64,
) -> Result<Option<String>, HistoryError> {
    let runs = reader.runs(&Filter {
        after_id: Some(run_id - 1),
        limit: Some(1),
        ..Filter::default()
    })?;
    Ok(runs
        .into_iter()
        .find(|run| run.id == run_id)
        .map(|run| run.config_name))
}

/// Write `capture` with its `header` to `out` in `format`.
pub fn write<W: Write + Send>(
    capture: &Capture,
    header: &CaptureHeader,
    format: ExportFormat,
    out: W,
) -> Result<(), CaptureFileError> {
    match format {
        ExportFormat::Csv => write_csv(capture, header, out),
        ExportFormat::Parquet => {
            if let Some(channel) = capture
                .channels
                .iter()
                .find(|c| super::capture_parquet::TIME_COLUMNS.contains(&c.name.as_str()))
            {
                return Err(CaptureFileError::ChannelName(channel.name.clone()));
            }
            let json = serde_json::to_string(header).map_err(std::io::Error::other)?;
            Ok(super::capture_parquet::write(capture, &json, out)?)
        }
    }
}

/// Write `capture` with its `header` as CSV to `out`.
fn write_csv(
    capture: &Capture,
    header: &CaptureHeader,
    out: impl Write,
) -> Result<(), CaptureFileError> {
    let mut out = std::io::BufWriter::new(out);
    writeln!(
        out,
        "# {CSV_HEADER_PREFIX}{}",
        serde_json::to_string(header).map_err(std::io::Error::other)?
    )?;
    let names: Vec<&str> = capture.channels.iter().map(|c| c.name.as_str()).collect();
    writeln!(out, "t,{}", names.join(","))?;
    for index in 0..usize::try_from(capture.row.samples).unwrap_or(0) {
        write!(out, "{}", capture.time_s(index))?;
        for channel in &capture.channels {
            write!(out, ",{}", channel.samples[index])?;
        }
        writeln!(out)?;
    }
    out.flush()?;
    Ok(())
}
