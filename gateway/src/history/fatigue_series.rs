//! A driveline's fatigue ledger over time, as the page and the report draw it (issue
//! 38): each component's life used in time buckets
//! ([`HistoryReader::fatigue_series`]) and each bite's damage beside its TAF
//! ([`HistoryReader::for_each_fatigue_damage`], handed over as read, for binning).
//!
//! A year of bites is a million per driveline: the series reads one bite per bucket
//! (the bucket's last with a ledger, by the `(driveline, time)` index) and its
//! components' rows (by `fatigue_bites`' primary key), so its memory and time are
//! those of the buckets, not of the bites.

use rusqlite::{params, OptionalExtension};
use serde::Serialize;

use super::error::HistoryError;
use super::query::HistoryReader;
use super::restore::{fatigue_resets, has_fatigue_tables, FatigueReset};
use crate::state::time::UtcTime;

/// The life used of a driveline's fatigue components over time.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct FatigueSeries {
    /// The components' names, in the order of `life_used`: in configuration order,
    /// by name (a component renamed in the configuration is another one).
    pub components: Vec<String>,
    /// The time buckets with a bite of the ledger, oldest first.
    pub points: Vec<FatigueLifePoint>,
    /// The resets in the range, oldest first: where a component's life starts again.
    pub resets: Vec<FatigueReset>,
}

/// One time bucket of [`FatigueSeries`]: `[start, end)`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FatigueLifePoint {
    /// The bucket's start (UTC), inclusive.
    pub start: UtcTime,
    /// The bucket's end (UTC), exclusive.
    pub end: UtcTime,
    /// The time of the bucket's last bite with a ledger: the one its values are of.
    pub time: UtcTime,
    /// Each component's life used after that bite (Miner's sum since its
    /// installation; 1 is its S-N curve's failure), in the order of
    /// [`FatigueSeries::components`]; `None` for a component that bite did not count.
    pub life_used: Vec<Option<f64>>,
}

/// A bite's damage of one component, beside the bite's TAF.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FatigueDamagePoint {
    /// The component (index in `drivelines[].fatigue.components` when counted).
    pub component_index: usize,
    /// The bite's TAF (peak / static torque).
    pub taf: f64,
    /// The component's damage at the bite: the cycles closed since the bite before.
    pub damage: f64,
}

impl HistoryReader {
    /// `driveline`'s fatigue components' life used in at most `points` time buckets
    /// from `since` to `until` (the buckets and the errors of
    /// [`Self::wear_series`]), with the resets in that range; empty for a file
    /// without a ledger of it.
    ///
    /// Cost: per bucket, a probe of the `(driveline, time)` index from the bucket's end
    /// backwards to its last bite with a ledger, and that bite's component rows.
    pub fn fatigue_series(
        &self,
        driveline: &str,
        since: Option<UtcTime>,
        until: Option<UtcTime>,
        points: usize,
    ) -> Result<FatigueSeries, HistoryError> {
        let buckets = self.buckets(driveline, since, until, points)?;
        let connection = self.connection();
        if !has_fatigue_tables(connection).map_err(|e| self.error(e))? {
            return Ok(FatigueSeries::default());
        }
        let mut last = connection
            .prepare_cached(
                "SELECT b.id, b.time FROM bites b
                 WHERE b.driveline = ?1 AND b.time >= ?2 AND b.time < ?3
                     AND EXISTS (SELECT 1 FROM fatigue_bites f WHERE f.bite_id = b.id)
                 ORDER BY b.time DESC, b.id DESC LIMIT 1",
            )
            .map_err(|e| self.error(e))?;
        let mut lives = connection
            .prepare_cached(
                "SELECT component, life_used FROM fatigue_bites
                 WHERE bite_id = ?1 ORDER BY component_index",
            )
            .map_err(|e| self.error(e))?;
        let mut series = FatigueSeries::default();
        for (start, end) in buckets {
            let range = params![driveline, start.to_string(), end.to_string()];
            let Some((id, time)) = last
                .query_row(range, |row| {
                    Ok((row.get::<_, i64>(0)?, row.get::<_, String>(1)?))
                })
                .optional()
                .map_err(|e| self.error(e))?
            else {
                continue;
            };
            let time = self.time(&time)?;
            let mut life_used = vec![None; series.components.len()];
            let mut rows = lives.query(params![id]).map_err(|e| self.error(e))?;
            while let Some(row) = rows.next().map_err(|e| self.error(e))? {
                let name: String = row.get(0).map_err(|e| self.error(e))?;
                let used: f64 = row.get(1).map_err(|e| self.error(e))?;
                let k = match series.components.iter().position(|c| *c == name) {
                    Some(k) => k,
                    None => {
                        series.components.push(name);
                        life_used.push(None);
                        series.components.len() - 1
                    }
                };
                life_used[k] = Some(used);
            }
            series.points.push(FatigueLifePoint {
                start,
                end,
                time,
                life_used,
            });
        }
        // Points before a component was first met lack its value: pad them.
        for point in &mut series.points {
            point.life_used.resize(series.components.len(), None);
        }
        let (from, to) = (since.map(|t| t.to_string()), until.map(|t| t.to_string()));
        series.resets = fatigue_resets(connection, driveline)
            .map_err(|e| self.error(e))?
            .into_iter()
            .filter(|r| from.as_ref().is_none_or(|f| r.time >= *f))
            .filter(|r| to.as_ref().is_none_or(|t| r.time < *t))
            .collect();
        Ok(series)
    }

    /// Hands `visit` each component's damage at each of `driveline`'s bites at or
    /// after `since` and before `until` that can be trusted (a clean window with a
    /// TAF, the damage recorded: untrusted torque has none), as it is read; `visit`'s
    /// error ends the reading. Nothing for a file without a ledger.
    ///
    /// Cost: the driveline's range of the `(driveline, time)` index, each bite's row
    /// (its TAF) and its component rows; nothing is held.
    pub fn for_each_fatigue_damage<E: From<HistoryError>>(
        &self,
        driveline: &str,
        since: Option<UtcTime>,
        until: Option<UtcTime>,
        mut visit: impl FnMut(FatigueDamagePoint) -> Result<(), E>,
    ) -> Result<(), E> {
        let connection = self.connection();
        if !has_fatigue_tables(connection).map_err(|e| self.error(e))? {
            return Ok(());
        }
        let since = since.map_or_else(String::new, |t| t.to_string());
        let until = until.map_or_else(|| "9999".to_owned(), |t| t.to_string());
        let mut statement = connection
            .prepare_cached(
                "SELECT f.component_index, b.taf, f.damage
                 FROM bites b JOIN fatigue_bites f ON f.bite_id = b.id
                 WHERE b.driveline = ?1 AND b.time >= ?2 AND b.time < ?3
                     AND b.degraded = 0 AND b.taf IS NOT NULL AND f.damage IS NOT NULL",
            )
            .map_err(|e| self.error(e))?;
        let mut rows = statement
            .query(params![driveline, since, until])
            .map_err(|e| self.error(e))?;
        while let Some(row) = rows.next().map_err(|e| self.error(e))? {
            let point = (|| {
                Ok(FatigueDamagePoint {
                    component_index: usize::try_from(row.get::<_, i64>(0)?).unwrap_or(0),
                    taf: row.get(1)?,
                    damage: row.get(2)?,
                })
            })()
            .map_err(|e| self.error(e))?;
            visit(point)?;
        }
        Ok(())
    }
}
