//! A recording of a tandem mill's stands ([`Recording`]): the samples `millgate
//! chatter` and `millgate chatter commission` run through the mill's monitor, read
//! from a CSV (a column per stand channel, named as the channel) or from a capture the
//! history keeps.

use std::path::Path;

use millgate_config::Config;

use super::csv::{self, CsvError};
use crate::analysis::chatter::{ContextColumns, Recording};
use crate::history::captures::Capture;

/// Largest relative difference between a recording's and the channels' sample rate.
pub(crate) const RATE_TOLERANCE: f64 = 0.01;

/// A recording that does not fit the mill; every variant names the recording first.
#[derive(Debug, thiserror::Error)]
pub(crate) enum RecordingError {
    /// The CSV cannot be read.
    #[error("{recording}")]
    Csv {
        /// The file, as given.
        recording: String,
        /// Why.
        #[source]
        source: CsvError,
    },
    /// The CSV has no column for a stand.
    #[error(
        "{recording}: line 1: no column `{column}` for a stand of tandem mill \"{mill}\" \
         (columns: {columns})"
    )]
    NoStandColumn {
        /// The file, as given.
        recording: String,
        /// The stand channel's name.
        column: String,
        /// The tandem mill.
        mill: String,
        /// The CSV's columns, comma-separated.
        columns: String,
    },
    /// The CSV has no column of the asked-for speed.
    #[error("{recording}: line 1: no speed column `{column}` (columns: {columns})")]
    NoSpeedColumn {
        /// The file, as given.
        recording: String,
        /// The speed column asked for.
        column: String,
        /// The CSV's columns, comma-separated.
        columns: String,
    },
    /// The CSV has weld-bit columns for some stands, not all.
    #[error(
        "{recording}: line 1: no column `{column}`: weld-bit columns per stand (`weld_1` .. \
         `weld_{stands}`) must be given for every stand of tandem mill \"{mill}\" or none \
         (columns: {columns})"
    )]
    WeldStandColumns {
        /// The file, as given.
        recording: String,
        /// The first missing column.
        column: String,
        /// Stands of the mill.
        stands: usize,
        /// The tandem mill.
        mill: String,
        /// The CSV's columns, comma-separated.
        columns: String,
    },
    /// The CSV's time column is not uniform.
    #[error("{recording}: {error}")]
    Uneven {
        /// The file, as given.
        recording: String,
        /// Where and how.
        error: CsvError,
    },
    /// The CSV is sampled at another rate than the stand channels.
    #[error(
        "{recording}: sample rate {csv_rate_hz:.1} Hz from column t, the stand channels sample \
         at {rate_hz} Hz (must agree within {}%)",
        RATE_TOLERANCE * 100.0
    )]
    CsvRate {
        /// The file, as given.
        recording: String,
        /// The CSV's rate, Hz.
        csv_rate_hz: f64,
        /// The stand channels' rate, Hz.
        rate_hz: f64,
    },
    /// The capture is sampled at another rate than the stand channels.
    #[error(
        "{recording}: sampled at {capture_rate_hz} Hz, the stand channels sample at {rate_hz} Hz"
    )]
    CaptureRate {
        /// The capture.
        recording: String,
        /// The capture's rate, Hz.
        capture_rate_hz: f64,
        /// The stand channels' rate, Hz.
        rate_hz: f64,
    },
    /// The capture holds no channel of a stand.
    #[error("{recording}: no channel `{channel}` for a stand of \"{mill}\"")]
    NoStandChannel {
        /// The capture.
        recording: String,
        /// The stand channel's name.
        channel: String,
        /// The tandem mill.
        mill: String,
    },
}

/// Reads the CSV at `path` for mill `index` of `config`: a column per stand channel
/// (named as the channel), sampled at the channels' rate, and `speed_column` when
/// given; the context columns ([`ContextColumns::NAMES`]: `weld`, `speed_mpm`,
/// `coil`, `product`, and the per-stand weld bits `weld_1` .. `weld_N` for all stands
/// or none) when present. Errors name the file and why.
pub(crate) fn read(
    path: &Path,
    config: &Config,
    index: usize,
    speed_column: Option<&str>,
) -> Result<Recording, RecordingError> {
    let mill = &config.tandem_mills[index];
    let recording = path.display().to_string();
    let table = csv::read(path).map_err(|source| RecordingError::Csv {
        recording: recording.clone(),
        source,
    })?;
    let mut stands = Vec::new();
    for &channel in &mill.stands {
        let name = &config.channels[channel].name;
        let values = table
            .channel(name)
            .ok_or_else(|| RecordingError::NoStandColumn {
                recording: recording.clone(),
                column: name.clone(),
                mill: mill.name.clone(),
                columns: table.names.join(", "),
            })?;
        stands.push(values.to_vec());
    }
    let speed = match speed_column {
        None => None,
        Some(name) => {
            let values = table
                .channel(name)
                .ok_or_else(|| RecordingError::NoSpeedColumn {
                    recording: recording.clone(),
                    column: name.to_owned(),
                    columns: table.names.join(", "),
                })?;
            Some((name.to_owned(), values.to_vec()))
        }
    };
    let column = |name: &str| table.channel(name).map(<[f64]>::to_vec);
    let stand_welds: Vec<Option<Vec<f64>>> = (0..mill.stands.len())
        .map(|stand| column(&ContextColumns::weld_stand_column(stand)))
        .collect();
    let weld_stands = if stand_welds.iter().all(Option::is_none) {
        None
    } else if let Some(missing) = stand_welds.iter().position(Option::is_none) {
        return Err(RecordingError::WeldStandColumns {
            recording,
            column: ContextColumns::weld_stand_column(missing),
            stands: mill.stands.len(),
            mill: mill.name.clone(),
            columns: table.names.join(", "),
        });
    } else {
        Some(stand_welds.into_iter().flatten().collect())
    };
    let mut context = ContextColumns {
        weld: column("weld"),
        weld_stands,
        speed_mpm: column("speed_mpm"),
        coil: column("coil"),
        product: column("product"),
        lines: None,
    };
    if !context.is_empty() {
        context.lines = Some(table.lines.clone());
    }
    let rate_hz = config.channels[mill.stands[0]].sample_rate_hz;
    let csv_rate_hz = table
        .sample_rate_hz()
        .map_err(|error| RecordingError::Uneven {
            recording: recording.clone(),
            error,
        })?;
    if (csv_rate_hz / rate_hz - 1.0).abs() > RATE_TOLERANCE {
        return Err(RecordingError::CsvRate {
            recording,
            csv_rate_hz,
            rate_hz,
        });
    }
    Ok(Recording {
        name: recording,
        time_s: table.time_s,
        stands,
        speed,
        context,
    })
}

/// The stands of mill `index` of `config` in `capture`, named `name`: a channel per
/// stand channel (named as the channel), sampled at the channels' rate. Errors
/// name the capture and why.
pub(crate) fn from_capture(
    name: String,
    capture: &Capture,
    config: &Config,
    index: usize,
) -> Result<Recording, RecordingError> {
    let mill = &config.tandem_mills[index];
    let rate_hz = config.channels[mill.stands[0]].sample_rate_hz;
    if (capture.row.sample_rate_hz / rate_hz - 1.0).abs() > RATE_TOLERANCE {
        return Err(RecordingError::CaptureRate {
            recording: name,
            capture_rate_hz: capture.row.sample_rate_hz,
            rate_hz,
        });
    }
    let mut stands = Vec::with_capacity(mill.stands.len());
    for &channel in &mill.stands {
        let wanted = &config.channels[channel].name;
        let found = capture
            .channels
            .iter()
            .find(|c| c.name == *wanted)
            .ok_or_else(|| RecordingError::NoStandChannel {
                recording: name.clone(),
                channel: wanted.clone(),
                mill: mill.name.clone(),
            })?;
        stands.push(found.samples.clone());
    }
    Ok(Recording {
        name,
        time_s: (0..stands[0].len()).map(|k| capture.time_s(k)).collect(),
        stands,
        speed: None,
        context: Default::default(),
    })
}
