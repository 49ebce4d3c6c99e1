//! What a report reads over months of bites without holding them: a driveline's bite
//! counts and TAF quantiles ([`HistoryReader::bite_summary`]), the same by product
//! ([`HistoryReader::product_summaries`]), its bites one by one for
//! a plot that bins them ([`HistoryReader::for_each_taf_point`]), and when a run
//! without a recorded stop was last seen ([`HistoryReader::last_event`]).
//!
//! Memory stays that of one row: counts are SQLite's, the quantiles come from one
//! pass in TAF order (SQLite's sorter, which spills to a temporary file past its
//! cache), the bites are handed over as they are read.

use rusqlite::{params, OptionalExtension};

use super::query::{HistoryReader, RunRow};
use super::HistoryError;
use crate::state::time::UtcTime;

/// A driveline's bites in a time range.
#[derive(Debug, Clone, PartialEq)]
pub struct BiteSummary {
    /// Bites (degraded ones too).
    pub bites: u64,
    /// Bites whose window had gaps, NaN or saturation.
    pub degraded: u64,
    /// The TAF of the clean bites that measured one at quantiles 0.5, 0.95 and 1
    /// (nearest rank: the value at rank round(q (n - 1)) of the n sorted); `None`
    /// without such bites.
    pub taf_median: Option<f64>,
    /// See [`Self::taf_median`].
    pub taf_p95: Option<f64>,
    /// See [`Self::taf_median`].
    pub taf_max: Option<f64>,
}

/// A driveline's bites of one product in a time range (the context they were rolled
/// in, schema v13).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct ProductSummary {
    /// The product code.
    pub product: u32,
    /// Bites (degraded ones too).
    pub bites: u64,
    /// Of those, bites not pooled into the wear trend (`gated` 1 or 2).
    pub not_pooled: u64,
    /// Mean TAF of the clean bites that measured one; `None` without such bites.
    pub taf_mean: Option<f64>,
    /// Largest TAF of those.
    pub taf_max: Option<f64>,
    /// Mean static torque of the clean bites, kN*m.
    pub static_torque_mean_knm: Option<f64>,
    /// Mean opened gap (the wear trend's estimate after each pooled bite of the
    /// product), mrad; `None` without a gap estimate.
    pub gap_mean_mrad: Option<f64>,
}

/// Most products a [`HistoryReader::product_summaries`] lists (those with the most
/// bites): the answer's memory is bounded whatever the file holds.
pub(crate) const MAX_PRODUCTS: usize = 200;

/// One bite as a TAF-over-static-torque plot needs it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TafPoint {
    /// Static torque, kN*m.
    pub static_torque_knm: f64,
    /// Peak / static, when measured.
    pub taf: Option<f64>,
    /// The window had gaps, NaN or saturation.
    pub degraded: bool,
}

/// `since`, `until` as the text bounds of a time range (open ends as bounds no time
/// passes).
fn bounds(since: Option<UtcTime>, until: Option<UtcTime>) -> (String, String) {
    (
        since.map_or_else(String::new, |t| t.to_string()),
        until.map_or_else(|| "9999".to_owned(), |t| t.to_string()),
    )
}

impl HistoryReader {
    /// `driveline`'s bites at or after `since` and before `until` (open ends: all):
    /// counts and TAF quantiles (`BiteSummary`). Unknown drivelines have no bites.
    ///
    /// Cost: the `(driveline, time, degraded, taf, ...)` index alone, one pass for the
    /// counts and one in TAF order.
    pub fn bite_summary(
        &self,
        driveline: &str,
        since: Option<UtcTime>,
        until: Option<UtcTime>,
    ) -> Result<BiteSummary, HistoryError> {
        let (since, until) = bounds(since, until);
        let range = params![driveline, since, until];
        let connection = self.connection();
        let (bites, degraded, clean): (i64, i64, i64) = connection
            .prepare_cached(
                "SELECT count(*), total(degraded),
                     count(CASE WHEN degraded = 0 THEN taf END)
                 FROM bites WHERE driveline = ?1 AND time >= ?2 AND time < ?3",
            )
            .and_then(|mut statement| {
                statement.query_row(range, |row| {
                    // total() is a float: the count of degraded bites, exact.
                    Ok((row.get(0)?, row.get::<_, f64>(1)? as i64, row.get(2)?))
                })
            })
            .map_err(|e| self.error(e))?;
        let count = |value: i64| u64::try_from(value).unwrap_or(0);
        let mut summary = BiteSummary {
            bites: count(bites),
            degraded: count(degraded),
            taf_median: None,
            taf_p95: None,
            taf_max: None,
        };
        let Some(last) = count(clean).checked_sub(1) else {
            return Ok(summary);
        };
        let rank = |q: f64| (last as f64 * q).round() as u64;
        let (median, p95) = (rank(0.5), rank(0.95));
        let mut statement = connection
            .prepare_cached(
                "SELECT taf FROM bites
                 WHERE driveline = ?1 AND time >= ?2 AND time < ?3 AND degraded = 0
                     AND taf IS NOT NULL
                 ORDER BY taf",
            )
            .map_err(|e| self.error(e))?;
        let mut rows = statement.query(range).map_err(|e| self.error(e))?;
        let mut index = 0;
        while let Some(row) = rows.next().map_err(|e| self.error(e))? {
            let taf: f64 = row.get(0).map_err(|e| self.error(e))?;
            if index == median {
                summary.taf_median = Some(taf);
            }
            if index == p95 {
                summary.taf_p95 = Some(taf);
            }
            summary.taf_max = Some(taf);
            index += 1;
        }
        Ok(summary)
    }

    /// `driveline`'s bites at or after `since` and before `until` grouped by the
    /// product they were rolled in (bites without a product left out), the products
    /// with the most bites first, at most 200 (`MAX_PRODUCTS`).
    ///
    /// Cost: one pass over the driveline's range (SQLite's grouping: memory per
    /// product, not per bite).
    pub fn product_summaries(
        &self,
        driveline: &str,
        since: Option<UtcTime>,
        until: Option<UtcTime>,
    ) -> Result<Vec<ProductSummary>, HistoryError> {
        let (since, until) = bounds(since, until);
        let mut statement = self
            .connection()
            .prepare_cached(
                "SELECT product, count(*), count(CASE WHEN gated IN (1, 2) THEN 1 END),
                     avg(CASE WHEN degraded = 0 THEN taf END),
                     max(CASE WHEN degraded = 0 THEN taf END),
                     avg(CASE WHEN degraded = 0 THEN static_torque_knm END),
                     avg(CASE WHEN gated IS NULL OR gated = 0 THEN gap_mrad END)
                 FROM bites
                 WHERE driveline = ?1 AND time >= ?2 AND time < ?3 AND product IS NOT NULL
                 GROUP BY product ORDER BY count(*) DESC, product LIMIT ?4",
            )
            .map_err(|e| self.error(e))?;
        let count = |value: i64| u64::try_from(value).unwrap_or(0);
        let rows = statement
            .query_map(
                params![driveline, since, until, MAX_PRODUCTS as i64],
                |row| {
                    Ok(ProductSummary {
                        product: u32::try_from(row.get::<_, i64>(0)?).unwrap_or(u32::MAX),
                        bites: count(row.get(1)?),
                        not_pooled: count(row.get(2)?),
                        taf_mean: row.get(3)?,
                        taf_max: row.get(4)?,
                        static_torque_mean_knm: row.get(5)?,
                        gap_mean_mrad: row.get(6)?,
                    })
                },
            )
            .map_err(|e| self.error(e))?;
        rows.collect::<Result<_, _>>().map_err(|e| self.error(e))
    }

    /// Hands each of `driveline`'s bites at or after `since` and before `until` to
    /// `visit`, in time order, as it is read; `visit`'s error ends the reading.
    ///
    /// Cost: the driveline's range of the `(driveline, time, ...)` index and each
    /// bite's table row (the static torque is not in the index).
    pub fn for_each_taf_point<E: From<HistoryError>>(
        &self,
        driveline: &str,
        since: Option<UtcTime>,
        until: Option<UtcTime>,
        mut visit: impl FnMut(TafPoint) -> Result<(), E>,
    ) -> Result<(), E> {
        let (since, until) = bounds(since, until);
        let mut statement = self
            .connection()
            .prepare_cached(
                "SELECT static_torque_knm, taf, degraded FROM bites
                 WHERE driveline = ?1 AND time >= ?2 AND time < ?3
                 ORDER BY time",
            )
            .map_err(|e| self.error(e))?;
        let mut rows = statement
            .query(params![driveline, since, until])
            .map_err(|e| self.error(e))?;
        while let Some(row) = rows.next().map_err(|e| self.error(e))? {
            let point = (|| {
                Ok(TafPoint {
                    static_torque_knm: row.get(0)?,
                    taf: row.get(1)?,
                    degraded: row.get(2)?,
                })
            })()
            .map_err(|e| self.error(e))?;
            visit(point)?;
        }
        Ok(())
    }

    /// When `run` was last seen working: the time of its last recorded event (a bite,
    /// a wear estimate or reset, an alarm, the start or end of a source outage or a
    /// chatter episode) before `before` (the next run's start: runs do not overlap);
    /// `None` when it recorded nothing. An outage or episode the next start closed
    /// (`ended_by = 'restart'`) counts by its start only: its end is the next run's.
    ///
    /// A run without a recorded stop (killed, its power cut, or still running) ran at
    /// least until then; whether it ran longer, the file cannot tell.
    ///
    /// Cost: a probe of each table's time index from `before` backwards (the run's
    /// rows are the last ones there), and a scan of the small outage and chatter
    /// tables.
    pub fn last_event(
        &self,
        run: &RunRow,
        before: Option<UtcTime>,
    ) -> Result<Option<UtcTime>, HistoryError> {
        let before = bounds(None, before).1;
        let mut last: Option<String> = None;
        for table in ["bites", "wear_estimates", "alarms"] {
            let time: Option<String> = self
                .connection()
                .prepare_cached(&format!(
                    "SELECT time FROM {table}
                     WHERE time >= ?1 AND time < ?2 AND run_id = ?3
                     ORDER BY time DESC LIMIT 1"
                ))
                .and_then(|mut statement| {
                    statement
                        .query_row(params![run.started_at, before, run.id], |row| row.get(0))
                        .optional()
                })
                .map_err(|e| self.error(e))?;
            last = last.max(time);
        }
        for table in ["source_outages", "chatter_episodes"] {
            let time: Option<String> = self
                .connection()
                .prepare_cached(&format!(
                    "SELECT max(CASE WHEN ended_by = 'restart' OR ended_at IS NULL
                                THEN started_at ELSE ended_at END)
                     FROM {table} WHERE run_id = ?1"
                ))
                .and_then(|mut statement| statement.query_row([run.id], |row| row.get(0)))
                .map_err(|e| self.error(e))?;
            last = last.max(time);
        }
        last.map(|text| {
            UtcTime::parse(&text).map_err(|e| {
                self.error(rusqlite::Error::FromSqlConversionFailure(
                    0,
                    rusqlite::types::Type::Text,
                    Box::new(e),
                ))
            })
        })
        .transpose()
    }
}
