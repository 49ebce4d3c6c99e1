//! A capture as an Apache Parquet file (`millgate capture export --format parquet`):
//! one row per sample, columns `time` (UTC, ns, a Parquet timestamp), `t` (s from the
//! first sample) and one `DOUBLE` column per channel with the stored values, in
//! row groups of 65 536 rows, snappy-compressed. The file's key-value metadata holds what a data
//! scientist needs without the gateway: `millgate.capture` (the same JSON as a CSV
//! export's first line: driveline, bite, channels with units, scale and offset,
//! sample rate, first sample time, gaps, the window's analysis settings, the gateway's
//! version), and the most asked of it under keys of their own (`millgate.subject`,
//! `millgate.kind`, `millgate.bite_counter`, `millgate.sample_rate_hz`,
//! `millgate.started_at`, `millgate.units`, `millgate.gateway_version`, and
//! `millgate.config_hash` when the run recorded it), and the process context of its
//! time (schema v14): `millgate.context_status` (`valid`, `stale`, `invalid`),
//! `millgate.context_note` when it is not valid, and each value the gateway trusted
//! (`millgate.coil`, `millgate.product`, `millgate.speed_mpm`,
//! `millgate.thickness_mm`, `millgate.pass`, `millgate.mill_state`): an unknown
//! value has no key.
//!
//! Written with arrow-rs' `parquet` crate without its `arrow` feature (the column
//! writers alone: the samples are plain `f64` columns, and arrow's array crates would
//! double the build for no use here).

use std::io::Write;
use std::sync::Arc;

use parquet::basic::{Compression, LogicalType, Repetition, TimeUnit, Type as PhysicalType};
use parquet::data_type::{DoubleType, Int64Type};
use parquet::file::metadata::KeyValue;
use parquet::file::properties::WriterProperties;
use parquet::file::writer::SerializedFileWriter;
use parquet::schema::types::Type;

use super::captures::Capture;
use parquet::errors::ParquetError;

/// Rows of one row group: 2^16, a few MiB of columns for the largest captures (a
/// bite window, about 1 300 samples, is one group).
const ROW_GROUP_ROWS: usize = 1 << 16;

/// The time columns before the channels.
pub(super) const TIME_COLUMNS: [&str; 2] = ["time", "t"];

fn column(name: &str, physical: PhysicalType) -> Result<Arc<Type>, ParquetError> {
    Ok(Arc::new(
        Type::primitive_type_builder(name, physical)
            .with_repetition(Repetition::REQUIRED)
            .build()?,
    ))
}

/// Write `capture` to `out` as Parquet, with `header` (its header as JSON, as a CSV
/// export's sidecar has it) and `more` (key without `millgate.`, value: its run's
/// configuration hash when known, its context) in the metadata. Its channels' names
/// are not the time columns' (`time`, `t`): [`TIME_COLUMNS`].
pub(super) fn write<W: Write + Send>(
    capture: &Capture,
    header: &str,
    more: Vec<(&str, String)>,
    out: W,
) -> Result<(), ParquetError> {
    let row = &capture.row;
    let mut fields = vec![
        Arc::new(
            Type::primitive_type_builder(TIME_COLUMNS[0], PhysicalType::INT64)
                .with_repetition(Repetition::REQUIRED)
                .with_logical_type(Some(LogicalType::timestamp(true, TimeUnit::NANOS)))
                .build()?,
        ),
        column(TIME_COLUMNS[1], PhysicalType::DOUBLE)?,
    ];
    for channel in &capture.channels {
        fields.push(column(&channel.name, PhysicalType::DOUBLE)?);
    }
    let schema = Arc::new(
        Type::group_type_builder("capture")
            .with_fields(fields)
            .build()?,
    );
    let units: serde_json::Map<String, serde_json::Value> = capture
        .channels
        .iter()
        .map(|c| (c.name.clone(), c.unit.clone().into()))
        .collect();
    let key = |key: &str, value: String| KeyValue::new(format!("millgate.{key}"), value);
    let mut metadata = vec![
        key("capture", header.to_owned()),
        key("subject", row.subject.clone()),
        key("kind", row.kind.clone()),
        key(
            "bite_counter",
            row.bite_counter.map_or(String::new(), |b| b.to_string()),
        ),
        key("sample_rate_hz", row.sample_rate_hz.to_string()),
        key("started_at", row.started_at.clone()),
        key("units", serde_json::Value::Object(units).to_string()),
        key("gateway_version", capture.meta.version.clone()),
    ];
    metadata.extend(more.into_iter().map(|(name, value)| key(name, value)));
    let properties = WriterProperties::builder()
        .set_compression(Compression::SNAPPY)
        .set_key_value_metadata(Some(metadata))
        .build();
    let mut writer = SerializedFileWriter::new(out, schema, Arc::new(properties))?;
    let samples = usize::try_from(capture.row.samples).unwrap_or(0);
    let first_ns = capture.row.first_sample_unix_ns;
    let rate = capture.row.sample_rate_hz;
    // Row groups of ROW_GROUP_ROWS: the writer holds one group's columns (and the
    // time columns are made one group at a time), not the whole capture's again.
    for start in (0..samples).step_by(ROW_GROUP_ROWS) {
        let rows = start..samples.min(start + ROW_GROUP_ROWS);
        let times_ns: Vec<i64> = rows
            .clone()
            .map(|k| first_ns + (k as f64 * 1e9 / rate).round() as i64)
            .collect();
        let times_s: Vec<f64> = rows.clone().map(|k| capture.time_s(k)).collect();
        let mut group = writer.next_row_group()?;
        let mut index = 0usize;
        while let Some(mut column) = group.next_column()? {
            match index {
                0 => {
                    column
                        .typed::<Int64Type>()
                        .write_batch(&times_ns, None, None)?;
                }
                1 => {
                    column
                        .typed::<DoubleType>()
                        .write_batch(&times_s, None, None)?;
                }
                channel => {
                    column.typed::<DoubleType>().write_batch(
                        &capture.channels[channel - 2].samples[rows.clone()],
                        None,
                        None,
                    )?;
                }
            }
            column.close()?;
            index += 1;
        }
        group.close()?;
    }
    writer.close()?;
    Ok(())
}
