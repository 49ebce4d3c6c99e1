//! Captures in the history file (table `captures`, schema v7): stored by the writer
//! thread in the same transaction as the bite they belong to, read back by
//! `millgate capture`, the web page and `millgate discrepancy`, and kept within
//! `history.captures_max_mb` by the retention's
//! [`super::retention::CaptureRetention`].
//!
//! **Blobs in the SQLite file, not a sibling store.** A bite's capture is a few KiB
//! (see the gateway's README for the measured size): well inside the sizes where
//! SQLite reads and writes blobs as fast as separate files or faster, and small enough
//! to sit beside the bite's row. One file then gives what the bites already have: the
//! capture commits in the bite's transaction (the PLC writer waits for that commit, so
//! a bite the PLC has seen has its capture in the file, even after a SIGKILL), one
//! `PRAGMA integrity_check` covers both, one backup copies both, and the retention
//! deletes a capture and frees its pages in the same steps as the events. A sibling
//! folder of files would need its own fsync ordering against the WAL and its own
//! cleanup of files orphaned by a kill.
//!
//! **Encoding** (`meta.format` 1): per channel either raw counts (when every sample
//! is its count decoded by the channel's [`Scaling`] bit for bit, as a Modbus DAQ's
//! are) as zigzag varints of the differences between successive counts, or the `f64`
//! values' little-endian bytes (CAN signals, NaN); the channels' bytes one after the
//! other, deflated. Decoding gives back the very samples the analysis used (counts
//! stored before the decimal-exact [`Scaling`] come back as their decimal, at most one
//! unit in the last place from the `count * scale + offset` then analysed).

use std::io::Read as _;

use millgate_config::Scaling;
use rusqlite::types::Value as SqlValue;
use rusqlite::{params, OptionalExtension, Transaction};
use serde::{Deserialize, Serialize};

use super::context_columns::{evidence_context_columns, evidence_context_values};
use super::query::{CaptureRow, HistoryReader};
use super::HistoryError;
use crate::state::captures::{
    BiteWindowAnalysis, CaptureChannel, CaptureGap, CaptureRecord, ChatterEpisode,
};
// The report's query of alarm bites (`alarm_bite_captures`) only.
#[cfg(feature = "plot")]
use crate::state::{captures::KeepClass, time::UtcTime};

/// The blob format this millgate writes (`meta.format`).
pub const FORMAT: u32 = 1;

/// How one channel's samples are stored.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Encoding {
    /// Raw counts, differences as zigzag varints.
    Counts,
    /// `f64` little-endian.
    Float64,
}

/// A channel's description in `meta`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ChannelMeta {
    /// The channel's name and unit, scale and offset.
    #[serde(flatten)]
    pub channel: CaptureChannel,
    /// How its samples are stored.
    pub encoding: Encoding,
}

/// The `meta` column: how to read a capture's samples.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CaptureMeta {
    /// Blob format ([`FORMAT`]).
    pub format: u32,
    /// The channels in blob order.
    pub channels: Vec<ChannelMeta>,
    /// Where data was lost.
    pub gaps: Vec<CaptureGap>,
    /// For a bite window: how the analysis read it.
    pub analysis: Option<BiteWindowAnalysis>,
    /// For a chatter episode: where the warning sits (absent in other kinds').
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub episode: Option<ChatterEpisode>,
    /// The millgate that stored it.
    pub version: String,
}

/// A capture read back: its row and its channels with their samples.
#[derive(Debug, Clone, PartialEq)]
pub struct Capture {
    /// The row (what, when, how large).
    pub row: CaptureRow,
    /// How to read it.
    pub meta: CaptureMeta,
    /// The channels with their samples, in order.
    pub channels: Vec<CaptureChannel>,
}

impl Capture {
    /// Seconds of sample `index` after the first sample.
    pub fn time_s(&self, index: usize) -> f64 {
        index as f64 / self.row.sample_rate_hz
    }
}

/// The counts of `channel`'s samples when every one is exactly its count decoded by
/// the channel's [`Scaling`] (so decoding gives the same `f64`), else `None`.
fn exact_counts(channel: &CaptureChannel) -> Option<Vec<i64>> {
    let (scale, offset) = (channel.scale, channel.offset);
    if !(scale.is_finite() && scale != 0.0 && offset.is_finite()) {
        return None;
    }
    let scaling = Scaling::new(scale, offset);
    channel
        .samples
        .iter()
        .map(|&value| {
            let count = ((value - offset) / scale).round();
            let exact = count.abs() <= 2f64.powi(52) && scaling.apply(count) == value;
            exact.then_some(count as i64)
        })
        .collect()
}

fn put_varint(out: &mut Vec<u8>, mut value: u64) {
    while value >= 0x80 {
        out.push((value as u8) | 0x80);
        value >>= 7;
    }
    out.push(value as u8);
}

fn get_varint(bytes: &[u8], at: &mut usize) -> Option<u64> {
    let mut value = 0u64;
    for shift in (0..64).step_by(7) {
        let byte = *bytes.get(*at)?;
        *at += 1;
        value |= u64::from(byte & 0x7f) << shift;
        if byte & 0x80 == 0 {
            return Some(value);
        }
    }
    None
}

/// `raw` deflated (fast level, no header) by this thread's compressor, reset for it:
/// a new one allocates and clears some 300 KiB of tables (miniz_oxide's dictionary,
/// hash chains and buffers), which cost several times what deflating a bite's capture
/// of a few KiB does (see docs/measured.md); the writer thread keeps one for its life.
/// The fast level (one probe, greedy matches): a bite capture's varints of noisy
/// differences have few long matches to find, and the default level's lazy search
/// took twice the time for a larger blob (the demo's 62 bite windows: 1 699 bytes at
/// the default level, 1 686 at the fast one; `cargo bench --bench captures`).
fn deflate(raw: &[u8]) -> std::io::Result<Vec<u8>> {
    thread_local! {
        static COMPRESSOR: std::cell::RefCell<flate2::Compress> =
            std::cell::RefCell::new(flate2::Compress::new(flate2::Compression::fast(), false));
    }
    COMPRESSOR.with_borrow_mut(|compress| {
        compress.reset();
        let mut blob = Vec::with_capacity(raw.len() / 2 + 64);
        loop {
            let taken = usize::try_from(compress.total_in()).unwrap_or(usize::MAX);
            let status = compress
                .compress_vec(
                    raw.get(taken..).unwrap_or_default(),
                    &mut blob,
                    flate2::FlushCompress::Finish,
                )
                .map_err(std::io::Error::other)?;
            if status == flate2::Status::StreamEnd {
                return Ok(blob);
            }
            // `compress_vec` fills the spare capacity only.
            blob.reserve(blob.capacity().max(64));
        }
    })
}

/// The blob and `meta` of `record`.
pub fn encode(record: &CaptureRecord) -> std::io::Result<(Vec<u8>, CaptureMeta)> {
    let mut raw = Vec::new();
    let mut channels = Vec::with_capacity(record.channels.len());
    for channel in &record.channels {
        let encoding = match exact_counts(channel) {
            Some(counts) => {
                let mut previous = 0i64;
                for count in counts {
                    let delta = count.wrapping_sub(previous);
                    put_varint(&mut raw, ((delta << 1) ^ (delta >> 63)) as u64);
                    previous = count;
                }
                Encoding::Counts
            }
            None => {
                for value in &channel.samples {
                    raw.extend_from_slice(&value.to_le_bytes());
                }
                Encoding::Float64
            }
        };
        channels.push(ChannelMeta {
            channel: CaptureChannel {
                samples: Vec::new(),
                ..channel.clone()
            },
            encoding,
        });
    }
    let blob = deflate(&raw)?;
    let meta = CaptureMeta {
        format: FORMAT,
        channels,
        gaps: record.gaps.clone(),
        analysis: record.analysis,
        episode: record.episode,
        version: env!("CARGO_PKG_VERSION").to_owned(),
    };
    Ok((blob, meta))
}

/// Why a stored capture cannot be read.
#[derive(Debug, thiserror::Error)]
pub enum DecodeError {
    /// The `meta` JSON is not a capture's.
    #[error("capture {id}: its meta is not readable ({0})", id = .1)]
    Meta(serde_json::Error, i64),
    /// A format this millgate does not know.
    #[error("capture {id}: blob format {format}, this millgate reads {FORMAT}")]
    Format {
        /// The capture.
        id: i64,
        /// Its format.
        format: u32,
    },
    /// The blob ends early or does not inflate.
    #[error("capture {id}: the samples are damaged ({why})")]
    Damaged {
        /// The capture.
        id: i64,
        /// What is wrong.
        why: String,
    },
}

/// Most values (samples of all channels together) a stored capture may hold: 2^27,
/// 1 GiB as `f64`, above the largest capture the configuration allows (a tandem mill's
/// `capture_max_s` of 600 s of 40 stands at 2.5 kHz is 60 M values; 8 stands at
/// 10 kHz, 48 M). A row that claims more is damaged: decoding refuses it before
/// allocating anything.
pub const MAX_CAPTURE_VALUES: u64 = 1 << 27;

/// Longest zigzag varint of a count difference, bytes (64 bits, 7 per byte).
const MAX_VARINT_BYTES: u64 = 10;

/// The fewest and the most bytes `meta`'s channels take before deflating with
/// `samples` samples each; `None` when the row claims more than
/// [`MAX_CAPTURE_VALUES`].
fn raw_size_bounds(meta: &CaptureMeta, samples: usize) -> Option<(u64, u64)> {
    let samples = u64::try_from(samples).ok()?;
    let channels = u64::try_from(meta.channels.len()).ok()?;
    if samples.checked_mul(channels)? > MAX_CAPTURE_VALUES {
        return None;
    }
    Some(meta.channels.iter().fold((0, 0), |(least, most), channel| {
        let (low, high) = match channel.encoding {
            Encoding::Counts => (1, MAX_VARINT_BYTES),
            Encoding::Float64 => (8, 8),
        };
        (least + low * samples, most + high * samples)
    }))
}

/// The channels of a capture stored as `blob` with `meta`, `samples` per channel.
///
/// A damaged row costs no more memory than a sound one of its size: `samples` is
/// checked against [`MAX_CAPTURE_VALUES`] and the blob inflates at most to the bytes
/// that many samples can take (a deflate bomb stops there), and nothing is sized
/// from `samples` before the inflated bytes are known to hold them.
pub fn decode(
    id: i64,
    meta: &CaptureMeta,
    samples: usize,
    blob: &[u8],
) -> Result<Vec<CaptureChannel>, DecodeError> {
    if meta.format != FORMAT {
        return Err(DecodeError::Format {
            id,
            format: meta.format,
        });
    }
    let damaged = |why: &str| DecodeError::Damaged {
        id,
        why: why.to_owned(),
    };
    let (least, most) = raw_size_bounds(meta, samples).ok_or_else(|| {
        damaged(&format!(
            "{samples} samples of {} channels claimed, over the {MAX_CAPTURE_VALUES} values \
             a capture can hold",
            meta.channels.len()
        ))
    })?;
    let mut raw = Vec::new();
    flate2::read::DeflateDecoder::new(blob)
        .take(most + 1)
        .read_to_end(&mut raw)
        .map_err(|e| damaged(&e.to_string()))?;
    if raw.len() as u64 > most {
        return Err(damaged(&format!(
            "it inflates past the {most} bytes {samples} samples can take"
        )));
    }
    if (raw.len() as u64) < least {
        return Err(damaged("ends early"));
    }
    let mut at = 0usize;
    let mut channels = Vec::with_capacity(meta.channels.len());
    for channel in &meta.channels {
        let mut values = Vec::with_capacity(samples);
        match channel.encoding {
            Encoding::Counts => {
                let scaling = Scaling::new(channel.channel.scale, channel.channel.offset);
                let mut count = 0i64;
                for _ in 0..samples {
                    let zigzag = get_varint(&raw, &mut at).ok_or_else(|| damaged("ends early"))?;
                    let delta = ((zigzag >> 1) as i64) ^ -((zigzag & 1) as i64);
                    count = count.wrapping_add(delta);
                    values.push(scaling.apply(count as f64));
                }
            }
            Encoding::Float64 => {
                for _ in 0..samples {
                    let bytes = raw.get(at..at + 8).ok_or_else(|| damaged("ends early"))?;
                    at += 8;
                    values.push(f64::from_le_bytes(bytes.try_into().expect("8 bytes")));
                }
            }
        }
        channels.push(CaptureChannel {
            samples: values,
            ..channel.channel.clone()
        });
    }
    if at != raw.len() {
        return Err(damaged("bytes left after the last channel"));
    }
    Ok(channels)
}

/// A capture row as JSON, its `meta` as an object (the list `millgate capture list
/// --format json` and the web API give).
pub(crate) fn row_json(row: &CaptureRow) -> serde_json::Value {
    let mut value = serde_json::to_value(row).unwrap_or_default();
    if let Ok(meta) = serde_json::from_str::<serde_json::Value>(&row.meta) {
        value["meta"] = meta;
    }
    value
}

/// Insert `record` under run `run_id` in `transaction` (the writer's turn): its bite,
/// if it has one, is the driveline's latest row at the bite's time, inserted before it
/// in the same transaction or an earlier one.
pub fn insert(
    transaction: &Transaction<'_>,
    run_id: i64,
    record: &CaptureRecord,
) -> rusqlite::Result<()> {
    let bite_id: Option<i64> = match &record.bite {
        Some(bite) => transaction
            .prepare_cached(
                "SELECT id FROM bites WHERE driveline = ?1 AND time = ?2
                 ORDER BY id DESC LIMIT 1",
            )?
            .query_row(params![record.subject, bite.time.to_string()], |row| {
                row.get(0)
            })
            .optional()?,
        None => None,
    };
    insert_row(transaction, run_id, record, bite_id)
}

/// Insert `record`, the capture of the bite whose row `bite_id` was just inserted
/// ([`super::rows::insert`] of a captured bite): no look-up of the row. The look-up
/// cost more than the rest of the capture's rows: SQLite prepared its statement
/// again at every run (perf on the history's writer thread at 128 drivelines: 17% of
/// its time).
pub(super) fn insert_of_bite(
    transaction: &Transaction<'_>,
    run_id: i64,
    record: &CaptureRecord,
    bite_id: i64,
) -> rusqlite::Result<()> {
    insert_row(transaction, run_id, record, Some(bite_id))
}

/// The columns of a capture's row before its context columns, in the order
/// [`insert_row`] gives their values.
const CAPTURE_FACTS: [&str; 15] = [
    "run_id",
    "kind",
    "subject",
    "bite_id",
    "bite_counter",
    "bite_time",
    "started_at",
    "first_sample_unix_ns",
    "kernel_time",
    "sample_rate_hz",
    "samples",
    "duration_s",
    "keep",
    "meta",
    "bytes",
];

/// The statement that inserts a capture's row, its context columns included. Built
/// once: its text is the key of the connection's statement cache.
fn insert_sql() -> &'static str {
    static SQL: std::sync::OnceLock<String> = std::sync::OnceLock::new();
    SQL.get_or_init(|| {
        let context = evidence_context_columns();
        let columns: Vec<&str> = CAPTURE_FACTS
            .into_iter()
            .chain(context.split(", "))
            .collect();
        let placeholders: Vec<String> = (1..=columns.len()).map(|i| format!("?{i}")).collect();
        format!(
            "INSERT INTO captures ({}) VALUES ({})",
            columns.join(", "),
            placeholders.join(", ")
        )
    })
}

/// Insert `record`'s rows (the capture and its data) with its bite's row id.
fn insert_row(
    transaction: &Transaction<'_>,
    run_id: i64,
    record: &CaptureRecord,
    bite_id: Option<i64>,
) -> rusqlite::Result<()> {
    let (blob, meta) =
        encode(record).map_err(|e| rusqlite::Error::ToSqlConversionFailure(Box::new(e)))?;
    let meta = serde_json::to_string(&meta)
        .map_err(|e| rusqlite::Error::ToSqlConversionFailure(Box::new(e)))?;
    let samples = record.samples();
    let mut values: Vec<SqlValue> = vec![
        run_id.into(),
        record.kind.name().to_owned().into(),
        record.subject.clone().into(),
        bite_id.into(),
        record
            .bite
            .as_ref()
            .map(|bite| i64::from(bite.counter))
            .into(),
        record
            .bite
            .as_ref()
            .map(|bite| bite.time.to_string())
            .into(),
        record.started_at().to_string().into(),
        record.first_sample_unix_ns.into(),
        i64::from(record.kernel_time).into(),
        record.sample_rate_hz.into(),
        i64::try_from(samples).unwrap_or(i64::MAX).into(),
        (samples as f64 / record.sample_rate_hz).into(),
        record.keep.code().into(),
        meta.into(),
        i64::try_from(blob.len()).unwrap_or(i64::MAX).into(),
    ];
    values.extend(evidence_context_values(record.context.as_ref()));
    transaction
        .prepare_cached(insert_sql())?
        .execute(rusqlite::params_from_iter(values))?;
    transaction
        .prepare_cached("INSERT INTO capture_data (id, data) VALUES (?1, ?2)")?
        .execute(params![transaction.last_insert_rowid(), blob])?;
    Ok(())
}

impl HistoryReader {
    /// The capture with row id `id`, its samples decoded; `None` when there is none.
    pub fn capture(&self, id: i64) -> Result<Option<Capture>, HistoryError> {
        let filter = super::query::Filter {
            after_id: Some(id - 1),
            limit: Some(1),
            ..Default::default()
        };
        match self.rows::<CaptureRow>(&filter)?.into_iter().next() {
            Some(row) if row.id == id => self.capture_of(row).map(Some),
            _ => Ok(None),
        }
    }

    /// The captures of the bites with row ids `first..=last` (`bites.id`), in id order.
    pub(crate) fn bite_captures(
        &self,
        first: i64,
        last: i64,
    ) -> Result<Vec<CaptureRow>, HistoryError> {
        use super::query::Record as _;
        let sql = format!(
            "SELECT {} FROM captures WHERE bite_id BETWEEN ?1 AND ?2 ORDER BY id",
            CaptureRow::columns().join(", ")
        );
        let read = || -> rusqlite::Result<Vec<CaptureRow>> {
            let mut statement = self.connection().prepare_cached(&sql)?;
            let rows = statement.query_map([first, last], CaptureRow::from_row)?;
            rows.collect()
        };
        read().map_err(|e| self.error(e))
    }

    /// The newest `limit` captures of `subject`'s alarm bites (kind `bite`, kept
    /// longest: a TAF alarm, or the bite that raised the gap alarm) whose first sample
    /// is in `since..until` (either open), newest first. (For the report's plots.)
    #[cfg(feature = "plot")]
    pub(crate) fn alarm_bite_captures(
        &self,
        subject: &str,
        since: Option<UtcTime>,
        until: Option<UtcTime>,
        limit: u32,
    ) -> Result<Vec<CaptureRow>, HistoryError> {
        use super::query::Record as _;
        let sql = format!(
            "SELECT {} FROM captures
             WHERE subject = ?1 AND kind = 'bite' AND keep = ?2
                 AND started_at >= ?3 AND (?4 IS NULL OR started_at < ?4)
             ORDER BY started_at DESC, id DESC LIMIT ?5",
            CaptureRow::columns().join(", ")
        );
        let read = || -> rusqlite::Result<Vec<CaptureRow>> {
            let mut statement = self.connection().prepare_cached(&sql)?;
            let rows = statement.query_map(
                params![
                    subject,
                    KeepClass::Important.code(),
                    since.map_or(String::new(), |t| t.to_string()),
                    until.map(|t| t.to_string()),
                    limit
                ],
                CaptureRow::from_row,
            )?;
            rows.collect()
        };
        read().map_err(|e| self.error(e))
    }

    /// The samples of the capture `row` describes.
    pub fn capture_of(&self, row: CaptureRow) -> Result<Capture, HistoryError> {
        let blob: Vec<u8> = self
            .connection()
            .query_row(
                "SELECT data FROM capture_data WHERE id = ?1",
                [row.id],
                |r| r.get(0),
            )
            .map_err(|e| self.error(e))?;
        let damaged = |error: DecodeError| HistoryError::Capture {
            path: self.path().to_path_buf(),
            message: error.to_string(),
        };
        let meta: CaptureMeta =
            serde_json::from_str(&row.meta).map_err(|e| damaged(DecodeError::Meta(e, row.id)))?;
        let samples = usize::try_from(row.samples).unwrap_or(0);
        let channels = decode(row.id, &meta, samples, &blob).map_err(damaged)?;
        Ok(Capture {
            row,
            meta,
            channels,
        })
    }

    /// The captures' count and bytes (their blobs), from `capture_totals`.
    pub fn capture_totals(&self) -> Result<(u64, u64), HistoryError> {
        self.connection()
            .query_row(
                "SELECT captures, bytes FROM capture_totals WHERE id = 1",
                [],
                |row| Ok((row.get::<_, i64>(0)?, row.get::<_, i64>(1)?)),
            )
            .map(|(count, bytes)| (count.max(0) as u64, bytes.max(0) as u64))
            .map_err(|e| self.error(e))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::state::captures::{CaptureKind, KeepClass};
    use std::io::Write as _;

    fn record(channels: Vec<CaptureChannel>) -> CaptureRecord {
        CaptureRecord {
            kind: CaptureKind::Bite,
            subject: "F1".into(),
            bite: None,
            first_sample_unix_ns: 1_700_000_000_123_456_789,
            kernel_time: false,
            sample_rate_hz: 2000.0,
            channels,
            gaps: vec![],
            analysis: None,
            episode: None,
            keep: KeepClass::Ordinary,
            context: None,
        }
    }

    fn channel(scale: f64, offset: f64, samples: Vec<f64>) -> CaptureChannel {
        CaptureChannel {
            name: "torque".into(),
            unit: "kN*m".into(),
            scale,
            offset,
            samples,
            timing: None,
        }
    }

    #[test]
    fn counts_and_floats_come_back_bit_for_bit() {
        // Counts as a Modbus DAQ gives them (raw decoded by the channel's scaling),
        // and values that are not counts of the channel's scale (a CAN signal, a NaN).
        let scaling = Scaling::new(0.1, 3.0);
        let counts: Vec<f64> = (0..1400)
            .map(|i| scaling.apply(f64::from(((i as f64 * 0.05).sin() * 9000.0) as i16)))
            .collect();
        let floats: Vec<f64> = (0..1400)
            .map(|i| (i as f64 * 0.013).cos() * 123.456_789)
            .chain([f64::NAN, f64::INFINITY])
            .collect();
        for (samples, encoding) in [(counts, Encoding::Counts), (floats, Encoding::Float64)] {
            let record = record(vec![channel(0.1, 3.0, samples.clone())]);
            let (blob, meta) = encode(&record).unwrap();
            assert_eq!(meta.channels[0].encoding, encoding);
            let back = decode(1, &meta, samples.len(), &blob).unwrap();
            let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&back[0].samples), bits(&samples));
        }
    }

    #[test]
    fn a_damaged_blob_is_an_error_naming_the_capture() {
        let record = record(vec![channel(1.0, 0.0, vec![1.0, 2.0, 3.0])]);
        let (blob, meta) = encode(&record).unwrap();
        let error = decode(7, &meta, 4, &blob).unwrap_err();
        assert_eq!(
            error.to_string(),
            "capture 7: the samples are damaged (ends early)"
        );
        let error = decode(7, &meta, 3, &blob[..blob.len() / 2]).unwrap_err();
        assert!(error
            .to_string()
            .starts_with("capture 7: the samples are damaged"));
    }

    /// A row whose `samples` says 2^40 (the audit's damaged copy aborted the gateway
    /// allocating 8 TiB for it) is refused before anything is sized from it.
    #[test]
    fn a_row_claiming_more_samples_than_a_capture_holds_is_refused_before_allocating() {
        let record = record(vec![channel(1.0, 0.0, vec![1.0, 2.0, 3.0])]);
        let (blob, meta) = encode(&record).unwrap();
        let error = decode(7, &meta, 1 << 40, &blob).unwrap_err();
        assert_eq!(
            error.to_string(),
            "capture 7: the samples are damaged (1099511627776 samples of 1 channels \
             claimed, over the 134217728 values a capture can hold)"
        );
        // Within the bound but more than the blob holds: ends early, before the
        // channel's buffer is sized.
        let error = decode(7, &meta, 100_000_000, &blob).unwrap_err();
        assert_eq!(
            error.to_string(),
            "capture 7: the samples are damaged (ends early)"
        );
    }

    /// Captures deflated one after the other by the thread's one compressor come back
    /// whole, among them one whose blob outgrows the room first given (values that do
    /// not deflate: `f64`s of a seeded random walk).
    #[test]
    fn captures_deflated_in_turn_by_one_compressor_decode_to_their_samples() {
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        let mut walk = 0.0;
        let noisy: Vec<f64> = (0..20_000)
            .map(|_| {
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                walk += (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5;
                walk
            })
            .collect();
        let scaling = Scaling::new(0.05, 0.0);
        let counts: Vec<f64> = (0..3000)
            .map(|i| scaling.apply(f64::from(i % 97)))
            .collect();
        let records = [
            record(vec![channel(0.05, 0.0, counts)]),
            record(vec![channel(1.0, 0.0, noisy)]),
            record(vec![channel(0.05, 0.0, vec![scaling.apply(3.0); 10])]),
        ];
        for record in &records {
            let (blob, meta) = encode(record).unwrap();
            let decoded = decode(1, &meta, record.samples(), &blob).unwrap();
            assert_eq!(decoded.len(), 1);
            let (back, sent) = (&decoded[0].samples, &record.channels[0].samples);
            assert_eq!(back.len(), sent.len());
            assert!(
                back.iter()
                    .zip(sent)
                    .all(|(b, s)| b.to_bits() == s.to_bits()),
                "the samples come back bit for bit"
            );
        }
    }

    /// A deflate bomb (64 MiB of zeros, 64 KiB deflated) under a row of 1 000 samples
    /// stops inflating at the 10 000 bytes 1 000 count samples can take.
    #[test]
    fn a_deflate_bomb_stops_inflating_at_what_its_samples_can_take() {
        let record = record(vec![channel(1.0, 0.0, vec![0.0; 1000])]);
        let (_, meta) = encode(&record).unwrap();
        let mut bomb = flate2::write::DeflateEncoder::new(Vec::new(), flate2::Compression::best());
        let zeros = vec![0u8; 1 << 20];
        for _ in 0..64 {
            bomb.write_all(&zeros).unwrap();
        }
        let bomb = bomb.finish().unwrap();
        assert!(bomb.len() < 100_000, "{} bytes deflated", bomb.len());
        let error = decode(7, &meta, 1000, &bomb).unwrap_err();
        assert_eq!(
            error.to_string(),
            "capture 7: the samples are damaged (it inflates past the 10000 bytes 1000 \
             samples can take)"
        );
    }
}
