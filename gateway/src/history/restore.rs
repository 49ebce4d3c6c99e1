//! What a start restores from the history: per driveline every figure the catalogue
//! keeps in its state row (the bite counter, the last bite's values with their time,
//! the wear index and trend, the gap estimate and forecast, the warnings, the latched
//! TAF and gap alarms), the gap's wear trend in its saved form (the service continues
//! it) and the last bites since the wear reset (folded in again without a saved trend);
//! per tandem mill its state row's figures (the latched chatter alarm).
//!
//! Restored values are published with the driveline's `restored` flag (flags bit 6)
//! until the next bite replaces them: they are valid measurements, but from before
//! the restart, and `last_bite_time` says when.

use rusqlite::{params, Connection};

use super::figures::{read_state, read_states, restore_onto, StateRow};
use crate::state::events::PooledBite;
pub(crate) use crate::state::events::RestoredDriveline;
use crate::state::results::{DrivelineResults, Results, TandemMillResults};
use crate::state::time::UtcTime;

/// The most bites a start folds into a wear trend again when it has no saved form
/// ([`RestoredDriveline::gap_bites`]).
const MAX_GAP_BITES: i64 = 1000;

/// The last [`MAX_GAP_BITES`] bites `driveline`'s gap diagnosis saw since its last
/// wear reset, oldest first. By time (the `(driveline, time)` index walked back from
/// the newest), not by id: by id SQLite sorted every bite of the driveline first (2.8 s
/// at start on a year of bites).
fn gap_bites(connection: &Connection, driveline: &str) -> rusqlite::Result<Vec<(i64, PooledBite)>> {
    let mut bites = connection
        .prepare_cached(
            "SELECT time, static_torque_knm, taf, gap_taf_sigma, period_shift_s,
                 gap_period_shift_sigma_s
             FROM bites
             WHERE driveline = ?1 AND gap_taf_sigma IS NOT NULL AND taf IS NOT NULL
                 AND time > coalesce((SELECT max(time) FROM wear_estimates
                     WHERE driveline = ?1 AND event = 'reset'), '')
             ORDER BY time DESC, id DESC LIMIT ?2",
        )?
        .query_map(params![driveline, MAX_GAP_BITES], |row| {
            let time: String = row.get(0)?;
            let time = UtcTime::parse(&time).map_err(|error| {
                rusqlite::Error::FromSqlConversionFailure(
                    0,
                    rusqlite::types::Type::Text,
                    error.into(),
                )
            })?;
            Ok((
                time.unix_ms(),
                PooledBite {
                    static_torque_knm: row.get(1)?,
                    taf: row.get(2)?,
                    taf_sigma: row.get(3)?,
                    period_shift_s: row.get(4)?,
                    period_shift_sigma_s: row.get::<_, Option<f64>>(5)?.unwrap_or(0.0),
                },
            ))
        })?
        .collect::<rusqlite::Result<Vec<_>>>()?;
    bites.reverse();
    Ok(bites)
}

/// The saved wear trend of `driveline` (`None` when there is none).
fn gap_trend(connection: &Connection, driveline: &str) -> rusqlite::Result<Option<String>> {
    connection
        .prepare_cached("SELECT gap_trend FROM driveline_state WHERE driveline = ?1")?
        .query_row(params![driveline], |row| row.get(0))
}

/// The saved fatigue ledger of `driveline` (`None` when there is none).
fn fatigue_ledger(connection: &Connection, driveline: &str) -> rusqlite::Result<Option<String>> {
    connection
        .prepare_cached("SELECT fatigue_ledger FROM driveline_state WHERE driveline = ?1")?
        .query_row(params![driveline], |row| row.get(0))
}

/// Everything a start restores.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Restored {
    /// Per driveline found in the file.
    pub drivelines: Vec<RestoredDriveline>,
    /// Per tandem mill found in the file: its state row's figures.
    pub mills: Vec<StateRow<TandemMillResults>>,
}

/// Read the state tables of a migrated file.
pub(crate) fn read(connection: &Connection) -> rusqlite::Result<Restored> {
    let drivelines = read_states::<DrivelineResults>(connection)?
        .into_iter()
        .map(|row| restored_driveline(connection, row))
        .collect::<rusqlite::Result<Vec<_>>>()?;
    let mills = read_states::<TandemMillResults>(connection)?;
    Ok(Restored { drivelines, mills })
}

/// What a start would restore of driveline `name` alone (`None` when the file has no
/// state of it): a driveline a reload adds under a name the file knows resumes it.
pub(crate) fn read_driveline(
    connection: &Connection,
    name: &str,
) -> rusqlite::Result<Option<RestoredDriveline>> {
    read_state::<DrivelineResults>(connection, name)?
        .map(|row| restored_driveline(connection, row))
        .transpose()
}

/// The restorable state of the driveline whose state row is `row`.
fn restored_driveline(
    connection: &Connection,
    row: StateRow<DrivelineResults>,
) -> rusqlite::Result<RestoredDriveline> {
    Ok(RestoredDriveline {
        gap_trend: gap_trend(connection, &row.name)?,
        gap_bites: gap_bites(connection, &row.name)?,
        fatigue_ledger: fatigue_ledger(connection, &row.name)?,
        name: row.name,
        updated_at: row.updated_at,
        results: DrivelineResults {
            restored: true,
            ..row.results
        },
    })
}

impl Restored {
    /// Put the restored state of the tandem mills named as in the file into
    /// `results`; returns how many were restored. (A driveline's state goes to the
    /// analysis, which continues its trends with it: `Analysis::resume_driveline`.)
    pub fn apply_mills(&self, results: &mut Results, mill_names: &[String]) -> usize {
        let mut applied = 0;
        for restored in &self.mills {
            if let Some(m) = mill_names.iter().position(|n| *n == restored.name) {
                restore_onto(&restored.results, &mut results.tandem_mills[m]);
                applied += 1;
            }
        }
        applied
    }
}

/// What the history keeps of a driveline's fatigue ledger beside its saved form.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct FatigueHistory {
    /// The resets, oldest first.
    pub resets: Vec<FatigueReset>,
    /// Damage per UTC day and component (days oldest first; untrusted bites' damage
    /// left out, as the outputs leave it out).
    pub days: Vec<FatigueDay>,
}

/// One reset of a fatigue component.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct FatigueReset {
    /// When (UTC, ISO-8601).
    pub time: String,
    /// The component's name.
    pub component: String,
    /// The life it had used until then.
    pub life_used: f64,
    /// Who: `plc`, `hmi`, `local`, `opcua`, `web`.
    pub origin: String,
    /// The client's address, when a client sent it.
    pub peer: Option<String>,
}

/// One component's damage on one UTC day, from its bites.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct FatigueDay {
    /// The day, `YYYY-MM-DD`.
    pub day: String,
    /// The component's name.
    pub component: String,
    /// The sum of its bites' damage that day.
    pub damage: f64,
    /// Its bites that day.
    pub bites: u64,
}

/// `driveline`'s fatigue resets and its damage per day over the last `days` days with
/// bites (by the `(driveline, time)` index: a year of bites is not read for a month).
pub(crate) fn fatigue_history(
    connection: &Connection,
    driveline: &str,
    days: u32,
) -> rusqlite::Result<FatigueHistory> {
    if !has_fatigue_tables(connection)? {
        return Ok(FatigueHistory::default());
    }
    let resets = fatigue_resets(connection, driveline)?;
    let days = connection
        .prepare_cached(
            "WITH last AS (SELECT max(time) AS time FROM bites WHERE driveline = ?1)
             SELECT substr(b.time, 1, 10) AS day, f.component, sum(f.damage), count(*)
             FROM bites b JOIN fatigue_bites f ON f.bite_id = b.id
             WHERE b.driveline = ?1
                 AND b.time >= strftime('%Y-%m-%d', (SELECT time FROM last), ?2)
             GROUP BY day, f.component_index ORDER BY day, f.component_index",
        )?
        .query_map(
            params![driveline, format!("-{} days", days.saturating_sub(1))],
            |row| {
                Ok(FatigueDay {
                    day: row.get(0)?,
                    component: row.get(1)?,
                    damage: row.get::<_, Option<f64>>(2)?.unwrap_or(0.0),
                    bites: u64::try_from(row.get::<_, i64>(3)?).unwrap_or(0),
                })
            },
        )?
        .collect::<rusqlite::Result<Vec<_>>>()?;
    Ok(FatigueHistory { resets, days })
}

/// Whether the file has the fatigue ledger's tables (schema version 12 on).
pub(crate) fn has_fatigue_tables(connection: &Connection) -> rusqlite::Result<bool> {
    connection.query_row(
        "SELECT count(*) > 0 FROM sqlite_schema WHERE name = 'fatigue_resets'",
        [],
        |row| row.get(0),
    )
}

/// `driveline`'s fatigue resets, oldest first (a few per component replaced: read
/// whole).
pub(crate) fn fatigue_resets(
    connection: &Connection,
    driveline: &str,
) -> rusqlite::Result<Vec<FatigueReset>> {
    connection
        .prepare_cached(
            "SELECT time, component, life_used, origin, peer FROM fatigue_resets
             WHERE driveline = ?1 ORDER BY time, id",
        )?
        .query_map(params![driveline], |row| {
            Ok(FatigueReset {
                time: row.get(0)?,
                component: row.get(1)?,
                life_used: row.get(2)?,
                origin: row.get(3)?,
                peer: row.get(4)?,
            })
        })?
        .collect()
}

#[cfg(test)]
mod tests {
    use super::super::figures::upsert_state;
    use super::*;
    use crate::state::results::GapResults;

    /// A migrated file in memory with the state of F1 and F2, F2's saved trend and
    /// ledger, and bites of both: F2's first two before its wear reset.
    fn two_drivelines() -> Connection {
        let mut connection = Connection::open_in_memory().unwrap();
        super::super::schema::migrate(&mut connection).unwrap();
        let transaction = connection.transaction().unwrap();
        for (name, counter) in [("F1", 11), ("F2", 7)] {
            let results = DrivelineResults {
                bite_counter: counter,
                last_bite_unix_ms: Some(1_777_939_198_250),
                wear_trend: Some(0.125),
                taf_alarm: true,
                gap: Some(GapResults {
                    gap_mrad: 1.5,
                    low_mrad: 1.0,
                    high_mrad: 2.0,
                    coupling: Some(1),
                    likeliest_coupling: None,
                    bites_pooled: 5,
                    growth: None,
                    forecast: None,
                }),
                ..DrivelineResults::default()
            };
            upsert_state(&transaction, name, UtcTime::from_unix_ms(9), &results).unwrap();
        }
        transaction
            .execute_batch(
                "UPDATE driveline_state SET gap_trend = '{\"trend\": 2}',
                     fatigue_ledger = '{\"ledger\": 2}' WHERE driveline = 'F2';
                 INSERT INTO gateway_runs (id, started_at, version, config_name)
                     VALUES (1, '2026-11-30T04:00:00Z', 'test', 'test');
                 INSERT INTO wear_estimates (run_id, driveline, time, event, origin)
                     VALUES (1, 'F2', '2026-11-30T04:00:02.500Z', 'reset', 'local');
                 WITH RECURSIVE n(i) AS (SELECT 1 UNION ALL SELECT i + 1 FROM n WHERE i < 7)
                 INSERT INTO bites (run_id, driveline, time, bite_counter, channel,
                     static_torque_knm, peak_torque_knm, taf, quality, degraded,
                     gap_taf_sigma, period_shift_s)
                 SELECT 1, d.name, strftime('%Y-%m-%dT%H:%M:%fZ', '2026-11-30T04:00:00Z',
                     '+' || i || ' seconds'), i, 'torque', 100.0 + i, 200.0, 1.5 + i / 100.0,
                     'good', 0, 0.01, NULL
                 FROM n, (SELECT 'F1' AS name UNION ALL SELECT 'F2') AS d;",
            )
            .unwrap();
        transaction.commit().unwrap();
        connection
    }

    #[test]
    fn one_driveline_restores_as_a_start_restores_it() {
        let connection = two_drivelines();
        let start = read(&connection).unwrap();
        for name in ["F1", "F2"] {
            let alone = read_driveline(&connection, name).unwrap();
            let at_start = start.drivelines.iter().find(|d| d.name == name);
            assert_eq!(alone.as_ref(), at_start, "{name}");
        }
        let f2 = read_driveline(&connection, "F2").unwrap().unwrap();
        assert_eq!(f2.results.bite_counter, 7);
        assert!(f2.results.restored && f2.results.taf_alarm);
        assert_eq!(f2.results.wear_trend, Some(0.125));
        assert_eq!(f2.results.gap.map(|gap| gap.bites_pooled), Some(5));
        assert_eq!(f2.gap_trend.as_deref(), Some("{\"trend\": 2}"));
        assert_eq!(f2.fatigue_ledger.as_deref(), Some("{\"ledger\": 2}"));
        // Its own bites since its wear reset (bites 3 to 7), oldest first; F1's not.
        let torques: Vec<f64> = f2
            .gap_bites
            .iter()
            .map(|(_, bite)| bite.static_torque_knm)
            .collect();
        assert_eq!(torques, [103.0, 104.0, 105.0, 106.0, 107.0]);
        let f1 = read_driveline(&connection, "F1").unwrap().unwrap();
        assert_eq!((f1.results.bite_counter, f1.gap_bites.len()), (11, 7));
        assert_eq!(read_driveline(&connection, "F9").unwrap(), None);
    }
}
