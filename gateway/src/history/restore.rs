//! What a start restores from the history: per driveline the bite counter, the last
//! bite's values with their time, the wear index and trend, the warning, the latched
//! TAF and gap alarms, and the bites last put into the gap pool (the service pools
//! them again); per tandem mill the latched chatter alarm.
//!
//! Restored values are published with the driveline's `restored` flag (flags bit 6)
//! until the next bite replaces them: they are valid measurements, but from before
//! the restart, and `last_bite_time` says when.

use rusqlite::{params, Connection};

use crate::state::results::{DrivelineResults, Results};

use crate::state::events::PooledBite;
use crate::state::time::UtcTime;

/// The restorable state of one driveline, as last recorded.
#[derive(Debug, Clone, PartialEq)]
pub struct RestoredDriveline {
    /// The driveline's name (matched against the configuration's).
    pub name: String,
    /// When the state was last recorded.
    pub updated_at: Option<UtcTime>,
    /// The published results as they were, with `restored` set.
    pub results: DrivelineResults,
    /// The JSON of [`crate::state::events::BiteRecord::extra_state`], when one was stored.
    pub extra: Option<serde_json::Value>,
    /// The bites last put into the gap pool since the last wear reset, oldest first
    /// (at most the largest pool allowed; empty without a gap diagnosis).
    pub gap_pool: Vec<PooledBite>,
}

/// The most bites a gap pool holds (the largest `drivelines[].wear.pool_bites`
/// allowed): the pool keeps the last `pool_bites` of those restored.
const MAX_POOL_BITES: i64 = 1000;

/// The last [`MAX_POOL_BITES`] bites `driveline` put into its gap pool since its last
/// wear reset, oldest first. By time (the `(driveline, time)` index walked back from
/// the newest), not by id: by id SQLite sorted every bite of the driveline first (2.8 s
/// at start on a year of bites).
fn gap_pool(connection: &Connection, driveline: &str) -> rusqlite::Result<Vec<PooledBite>> {
    let mut pool = connection
        .prepare_cached(
            "SELECT static_torque_knm, taf, gap_taf_sigma, period_shift_s,
                 gap_period_shift_sigma_s
             FROM bites
             WHERE driveline = ?1 AND gap_taf_sigma IS NOT NULL AND taf IS NOT NULL
                 AND time > coalesce((SELECT max(time) FROM wear_estimates
                     WHERE driveline = ?1 AND event = 'reset'), '')
             ORDER BY time DESC, id DESC LIMIT ?2",
        )?
        .query_map(params![driveline, MAX_POOL_BITES], |row| {
            Ok(PooledBite {
                static_torque_knm: row.get(0)?,
                taf: row.get(1)?,
                taf_sigma: row.get(2)?,
                period_shift_s: row.get(3)?,
                period_shift_sigma_s: row.get::<_, Option<f64>>(4)?.unwrap_or(0.0),
            })
        })?
        .collect::<rusqlite::Result<Vec<_>>>()?;
    pool.reverse();
    Ok(pool)
}

/// The restorable state of one tandem mill.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RestoredMill {
    /// The mill's name.
    pub name: String,
    /// The chatter alarm was latched.
    pub alarm_latched: bool,
}

/// Everything a start restores.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Restored {
    /// Per driveline found in the file.
    pub drivelines: Vec<RestoredDriveline>,
    /// Per tandem mill found in the file.
    pub mills: Vec<RestoredMill>,
}

fn time(text: Option<String>) -> Option<UtcTime> {
    text.and_then(|text| UtcTime::parse(&text).ok())
}

/// Read the state tables of a migrated file.
pub(crate) fn read(connection: &Connection) -> rusqlite::Result<Restored> {
    let mut statement = connection.prepare(
        "SELECT driveline, updated_at, bite_counter, last_bite_time, static_torque_knm,
             peak_torque_knm, taf, period_shift_s, beta1_hz, beta2_hz, wear_index, wear_trend,
             degraded, warning, alarm_latched, extra, gap_alarm_latched, gap_warning
         FROM driveline_state ORDER BY driveline",
    )?;
    let drivelines = statement
        .query_map([], |row| {
            let last_bite = time(row.get(3)?);
            let extra: Option<String> = row.get(15)?;
            Ok(RestoredDriveline {
                name: row.get(0)?,
                updated_at: time(row.get(1)?),
                results: DrivelineResults {
                    bite_counter: row.get::<_, i64>(2)?.clamp(0, i64::from(u32::MAX)) as u32,
                    last_bite_unix_ms: last_bite.map(|t| t.unix_ms()),
                    static_torque_knm: row.get(4)?,
                    peak_torque_knm: row.get(5)?,
                    taf: row.get(6)?,
                    first_period_shift_s: row.get(7)?,
                    beta1_hz: row.get(8)?,
                    beta2_hz: row.get(9)?,
                    wear_index: row.get(10)?,
                    wear_trend: row.get(11)?,
                    last_bite_degraded: row.get(12)?,
                    taf_warning: row.get(13)?,
                    taf_alarm: row.get(14)?,
                    gap_alarm: row.get(16)?,
                    gap_warning: row.get(17)?,
                    source_stale: false,
                    restored: true,
                    ..DrivelineResults::default()
                },
                extra: extra.and_then(|text| serde_json::from_str(&text).ok()),
                gap_pool: Vec::new(),
            })
        })?
        .collect::<rusqlite::Result<Vec<_>>>()?;
    let mut drivelines = drivelines;
    for driveline in &mut drivelines {
        driveline.gap_pool = gap_pool(connection, &driveline.name)?;
    }
    let mills = connection
        .prepare("SELECT mill, alarm_latched FROM mill_state ORDER BY mill")?
        .query_map([], |row| {
            Ok(RestoredMill {
                name: row.get(0)?,
                alarm_latched: row.get(1)?,
            })
        })?
        .collect::<rusqlite::Result<Vec<_>>>()?;
    Ok(Restored { drivelines, mills })
}

impl Restored {
    /// Put the restored state into `results` for the drivelines and mills named as in
    /// the file (a renamed driveline starts afresh); returns how many were restored.
    pub fn apply(
        &self,
        results: &mut Results,
        driveline_names: &[String],
        mill_names: &[String],
    ) -> usize {
        let mut applied = 0;
        for restored in &self.drivelines {
            if let Some(k) = driveline_names.iter().position(|n| *n == restored.name) {
                results.drivelines[k] = restored.results.clone();
                applied += 1;
            }
        }
        for restored in &self.mills {
            if let Some(m) = mill_names.iter().position(|n| *n == restored.name) {
                results.tandem_mills[m].chatter_alarm = restored.alarm_latched;
                applied += 1;
            }
        }
        applied
    }
}
