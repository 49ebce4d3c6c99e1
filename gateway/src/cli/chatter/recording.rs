//! What `millgate chatter` and `millgate chatter commission` share: the mill chosen
//! from the configuration, a recording of its stands (CSV, or samples in memory), and
//! the recording through the service's own monitor, window by window.

use std::path::Path;

use anyhow::{bail, Context};
use millgate_config::Config;

pub use crate::analysis::chatter::Window;

/// Samples per block fed to the monitor, as a Modbus DAQ delivers them (the largest
/// block; a chatter capture starts one such block before its whole hops, so its
/// windows here fall on the gateway's).
pub const BLOCK: usize = crate::analysis::chatter::ANCHOR_BLOCK;
/// Largest relative difference between a recording's and the channels' sample rate.
pub const RATE_TOLERANCE: f64 = 0.01;

/// The index of the tandem mill called `name` in `config` (the first without a
/// name); the error names the file and the mills there are.
pub fn mill_index(
    config: &Config,
    name: Option<&str>,
    config_path: &Path,
) -> anyhow::Result<usize> {
    match name {
        None if config.tandem_mills.is_empty() => {
            bail!("{}: no [[tandem_mills]]", config_path.display())
        }
        None => Ok(0),
        Some(name) => config
            .tandem_mills
            .iter()
            .position(|m| m.name == name)
            .with_context(|| {
                let names: Vec<_> = config
                    .tandem_mills
                    .iter()
                    .map(|m| m.name.as_str())
                    .collect();
                format!(
                    "--mill {name}: no such tandem mill in {} (mills: {})",
                    config_path.display(),
                    names.join(", ")
                )
            }),
    }
}

/// One recording of a mill's stands.
#[derive(Debug, Clone, PartialEq)]
pub struct Recording {
    /// Where it comes from (the file, as given), for messages.
    pub name: String,
    /// Time of each sample, s.
    pub time_s: Vec<f64>,
    /// Per stand of the mill, in its order, the samples (the channels' unit).
    pub stands: Vec<Vec<f64>>,
    /// The speed column's name and values, when one was asked for.
    pub speed: Option<(String, Vec<f64>)>,
}

impl Recording {
    /// Reads the CSV at `path` for mill `index` of `config`: a column per stand channel
    /// (named as the channel), sampled at the channels' rate, and `speed_column` when
    /// given. Errors name the file and why.
    pub fn read(
        path: &Path,
        config: &Config,
        index: usize,
        speed_column: Option<&str>,
    ) -> anyhow::Result<Recording> {
        let mill = &config.tandem_mills[index];
        let input = path.display();
        let table = super::super::csv::read(path).with_context(|| format!("{input}"))?;
        let mut stands = Vec::new();
        for &channel in &mill.stands {
            let name = &config.channels[channel].name;
            let values = table.channel(name).with_context(|| {
                format!(
                    "{input}: line 1: no column `{name}` for a stand of tandem mill \"{}\" (columns: {})",
                    mill.name,
                    table.names.join(", ")
                )
            })?;
            stands.push(values.to_vec());
        }
        let speed = match speed_column {
            None => None,
            Some(name) => {
                let values = table.channel(name).with_context(|| {
                    format!(
                        "{input}: line 1: no speed column `{name}` (columns: {})",
                        table.names.join(", ")
                    )
                })?;
                Some((name.to_owned(), values.to_vec()))
            }
        };
        let rate_hz = config.channels[mill.stands[0]].sample_rate_hz;
        let csv_rate_hz = table
            .sample_rate_hz()
            .map_err(|e| anyhow::anyhow!("{input}: {e}"))?;
        if (csv_rate_hz / rate_hz - 1.0).abs() > RATE_TOLERANCE {
            bail!(
                "{input}: sample rate {csv_rate_hz:.1} Hz from column t, the stand channels sample at \
                 {rate_hz} Hz (must agree within {}%)",
                RATE_TOLERANCE * 100.0
            );
        }
        Ok(Recording {
            name: input.to_string(),
            time_s: table.time_s,
            stands,
            speed,
        })
    }

    /// Samples in the recording (per stand).
    pub fn len(&self) -> usize {
        self.time_s.len()
    }

    /// True when the recording holds no sample.
    pub fn is_empty(&self) -> bool {
        self.time_s.is_empty()
    }

    /// Length, s (first to last sample).
    pub fn duration_s(&self) -> f64 {
        match (self.time_s.first(), self.time_s.last()) {
            (Some(first), Some(last)) => last - first,
            _ => 0.0,
        }
    }
}

/// `recording` through the monitor of mill `index` of `config` in 120-sample blocks
/// (a Modbus DAQ's), each stamped with its own sample time, every window judged as the
/// service judges it ([`crate::analysis::chatter::windows`]).
pub fn windows(
    config: &Config,
    index: usize,
    recording: &Recording,
) -> anyhow::Result<Vec<Window>> {
    Ok(crate::analysis::chatter::windows(
        config,
        index,
        &recording.time_s,
        &recording.stands,
    )?)
}
