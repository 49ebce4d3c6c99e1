//! What a page or a report plots over weeks and months: a driveline's gap estimate and
//! TAF in time buckets ([`HistoryReader::wear_series`]), its wear index in the same
//! buckets ([`HistoryReader::wear_index_series`]) and the gap's growth per week
//! ([`HistoryReader::gap_trend`]).
//!
//! Both are aggregated by SQLite (an aggregate per time bucket over its index range;
//! sums for the least-squares slope), so a year of bites (a million rows per driveline at
//! one bite every 30 s) never comes into memory: the answer is at most
//! [`MAX_SERIES_POINTS`] rows or one.
//!
//! The gap columns are the bites' own: every bite row carries the pooled estimate
//! after it (`bites.gap_mrad`, `gap_low_mrad`, `gap_high_mrad`, the same values as the
//! `wear_estimates` row the bite wrote), and the bites table is the one the page's
//! other queries read.

use std::time::Duration;

use rusqlite::{params, OptionalExtension};
use serde::Serialize;

use super::error::HistoryError;
use super::query::HistoryReader;
use crate::state::time::UtcTime;

/// Most buckets [`HistoryReader::wear_series`] returns.
pub const MAX_SERIES_POINTS: usize = 10_000;

/// The window before a driveline's last bite its gap trend is fitted to, on the page
/// and in the report: four weeks.
pub const TREND_WINDOW: Duration = Duration::from_secs(28 * 86_400);

/// Fewest bites with a gap estimate [`HistoryReader::gap_trend`] fits a slope to.
pub const MIN_TREND_BITES: u32 = 5;

/// One week, ms (the slope's time unit).
const WEEK_MS: f64 = 7.0 * 86_400_000.0;

/// The bites of one time bucket of a driveline: `[start, end)`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct WearPoint {
    /// The bucket's start (UTC), inclusive.
    pub start: UtcTime,
    /// The bucket's end (UTC), exclusive.
    pub end: UtcTime,
    /// Bites in the bucket (every bite, degraded ones too).
    pub bites: u32,
    /// The last gap estimate in the bucket (the pooled estimate after its last bite
    /// that had one), mrad; `None` when no bite in it had one.
    pub gap_mrad: Option<f64>,
    /// The lowest lower end of the gap's 90% interval in the bucket, mrad.
    pub gap_low_mrad: Option<f64>,
    /// The highest upper end of the gap's 90% interval in the bucket, mrad.
    pub gap_high_mrad: Option<f64>,
    /// Mean TAF of the bucket's bites that measured one in a clean window (degraded
    /// windows left out: their TAF is not trusted).
    pub taf_mean: Option<f64>,
    /// Smallest TAF of those bites.
    pub taf_min: Option<f64>,
    /// Largest TAF of those bites.
    pub taf_max: Option<f64>,
}

/// The wear index of the bites of one time bucket of a driveline: `[start, end)`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct WearIndexPoint {
    /// The bucket's start (UTC), inclusive.
    pub start: UtcTime,
    /// The bucket's end (UTC), exclusive.
    pub end: UtcTime,
    /// Bites in the bucket with a wear index.
    pub bites: u32,
    /// The smallest wear index of those bites.
    pub index_min: f64,
    /// The largest.
    pub index_max: f64,
    /// The wear trend after the bucket's last bite that had one.
    pub trend: Option<f64>,
    /// The smallest static torque of the bucket's bites (all of them), kN*m: the load
    /// the wear index was read at (and a TAF plot's torque range, read in the same
    /// pass).
    pub static_torque_min_knm: f64,
    /// The largest.
    pub static_torque_max_knm: f64,
}

/// The gap's growth: the least-squares slope of the pooled gap estimate over time.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct GapTrend {
    /// Slope, mrad per week (positive: the gap opens).
    pub mrad_per_week: f64,
    /// Bites fitted (those with a gap estimate in the window, after the last reset).
    pub bites: u32,
    /// The first fitted bite's time (UTC).
    pub since: UtcTime,
}

/// A bite's time in Unix ms from its ISO-8601 text, in SQL (rounded: `unixepoch`
/// gives seconds as a float).
const TIME_MS_SQL: &str = "CAST(round(unixepoch(time, 'subsec') * 1000) AS INTEGER)";

impl HistoryReader {
    /// Whether `driveline` is known to the file: configured in a recorded run or
    /// with bites.
    fn knows_driveline(&self, driveline: &str) -> Result<bool, HistoryError> {
        self.connection()
            .prepare_cached(
                "SELECT EXISTS (SELECT 1 FROM driveline_settings WHERE driveline = ?1)
                     OR EXISTS (SELECT 1 FROM bites WHERE driveline = ?1)",
            )
            .and_then(|mut statement| statement.query_row([driveline], |row| row.get(0)))
            .map_err(|e| self.error(e))
    }

    fn unknown(&self, driveline: &str) -> HistoryError {
        HistoryError::UnknownDriveline {
            path: self.path().to_path_buf(),
            name: driveline.to_owned(),
        }
    }

    /// The first and the last bite's time of `driveline`, `None` without bites (nor
    /// for a driveline the file does not know); two look-ups in an index.
    pub(crate) fn bite_span(
        &self,
        driveline: &str,
    ) -> Result<Option<(UtcTime, UtcTime)>, HistoryError> {
        let span: (Option<String>, Option<String>) = self
            .connection()
            .prepare_cached(
                "SELECT (SELECT min(time) FROM bites WHERE driveline = ?1),
                        (SELECT max(time) FROM bites WHERE driveline = ?1)",
            )
            .and_then(|mut statement| {
                statement.query_row([driveline], |row| Ok((row.get(0)?, row.get(1)?)))
            })
            .map_err(|e| self.error(e))?;
        match span {
            (Some(first), Some(last)) => Ok(Some((self.time(&first)?, self.time(&last)?))),
            _ => Ok(None),
        }
    }

    /// A time column's text as a time; a malformed one is a corrupt row.
    pub(super) fn time(&self, text: &str) -> Result<UtcTime, HistoryError> {
        UtcTime::parse(text).map_err(|e| {
            self.error(rusqlite::Error::FromSqlConversionFailure(
                0,
                rusqlite::types::Type::Text,
                Box::new(e),
            ))
        })
    }

    /// The time buckets of `driveline`'s series from `since` (inclusive; default its
    /// first bite) to `until` (exclusive; default just after its last bite): at most
    /// `points` of equal length (whole ms), oldest first; none when it has no bites
    /// there. Checks the arguments as [`Self::wear_series`] documents.
    pub(super) fn buckets(
        &self,
        driveline: &str,
        since: Option<UtcTime>,
        until: Option<UtcTime>,
        points: usize,
    ) -> Result<Vec<(UtcTime, UtcTime)>, HistoryError> {
        if !(1..=MAX_SERIES_POINTS).contains(&points) {
            return Err(HistoryError::Argument {
                name: "points",
                value: points.to_string(),
                allowed: format!("1..={MAX_SERIES_POINTS}"),
            });
        }
        if let (Some(since), Some(until)) = (since, until) {
            if since > until {
                return Err(HistoryError::Argument {
                    name: "since",
                    value: since.to_string(),
                    allowed: format!("at or before until = {until}"),
                });
            }
        }
        if !self.knows_driveline(driveline)? {
            return Err(self.unknown(driveline));
        }
        let Some((first, last)) = self.bite_span(driveline)? else {
            return Ok(Vec::new());
        };
        let since = since.unwrap_or(first);
        let until = until.unwrap_or(UtcTime::from_unix_ms(last.unix_ms() + 1));
        if since >= until {
            return Ok(Vec::new());
        }
        let span_ms = until.unix_ms() - since.unix_ms();
        // points >= 1 and <= 10 000: the cast is exact.
        let points = points as i64;
        let width_ms = ((span_ms + points - 1) / points).max(1);
        Ok((0..points)
            .map(|k| since.unix_ms() + k * width_ms)
            .take_while(|start_ms| *start_ms < until.unix_ms())
            .map(|start_ms| {
                (
                    UtcTime::from_unix_ms(start_ms),
                    UtcTime::from_unix_ms((start_ms + width_ms).min(until.unix_ms())),
                )
            })
            .collect())
    }

    /// `driveline`'s bites from `since` (inclusive; default its first bite) to `until`
    /// (exclusive; default just after its last bite) in at most `points` buckets of
    /// equal length (whole ms), oldest first; buckets without bites are left out.
    ///
    /// `points`: 1..=[`MAX_SERIES_POINTS`]. An empty driveline (configured, no bites
    /// in the range) gives an empty series; a driveline the file does not know is
    /// [`HistoryError::UnknownDriveline`]; `since` after `until` is an argument error.
    ///
    /// Cost: one pass over the range's entries of the `(driveline, time, ...)` index,
    /// aggregated by SQLite bucket by bucket, plus one index probe per bucket for its
    /// last gap; no row comes into memory but the buckets'.
    pub fn wear_series(
        &self,
        driveline: &str,
        since: Option<UtcTime>,
        until: Option<UtcTime>,
        points: usize,
    ) -> Result<Vec<WearPoint>, HistoryError> {
        let buckets = self.buckets(driveline, since, until, points)?;
        let connection = self.connection();
        // One aggregate per bucket over its range of the (driveline, time) index,
        // which holds the columns aggregated (schema version 5): no table page is
        // read. A single GROUP BY of the bucket number (computed from the time text
        // by `unixepoch`) gave the same rows but sorted every bite of the range first:
        // a year at 500 points took 2.3 s against 0.56 s this way (median,
        // examples/history_web_queries on the year fixture, a loaded 2-core machine).
        let mut bucket = connection
            .prepare_cached(
                "SELECT count(*), min(gap_low_mrad), max(gap_high_mrad),
                     avg(CASE WHEN degraded = 0 THEN taf END),
                     min(CASE WHEN degraded = 0 THEN taf END),
                     max(CASE WHEN degraded = 0 THEN taf END)
                 FROM bites
                 WHERE driveline = ?1 AND time >= ?2 AND time < ?3",
            )
            .map_err(|e| self.error(e))?;
        let mut last_gap = connection
            .prepare_cached(
                "SELECT gap_mrad FROM bites
                 WHERE driveline = ?1 AND time >= ?2 AND time < ?3 AND gap_mrad IS NOT NULL
                 ORDER BY time DESC, id DESC LIMIT 1",
            )
            .map_err(|e| self.error(e))?;
        let mut series = Vec::new();
        for (start, end) in buckets {
            let (start_text, end_text) = (start.to_string(), end.to_string());
            let range = params![driveline, start_text, end_text];
            let (bites, gap_low_mrad, gap_high_mrad, taf_mean, taf_min, taf_max) = bucket
                .query_row(range, |row| {
                    Ok((
                        row.get::<_, i64>(0)?,
                        row.get::<_, Option<f64>>(1)?,
                        row.get::<_, Option<f64>>(2)?,
                        row.get::<_, Option<f64>>(3)?,
                        row.get::<_, Option<f64>>(4)?,
                        row.get::<_, Option<f64>>(5)?,
                    ))
                })
                .map_err(|e| self.error(e))?;
            if bites == 0 {
                continue;
            }
            // The interval's ends exist exactly when some bite had an estimate.
            let gap_mrad = if gap_low_mrad.is_some() {
                last_gap
                    .query_row(range, |row| row.get(0))
                    .optional()
                    .map_err(|e| self.error(e))?
            } else {
                None
            };
            series.push(WearPoint {
                start,
                end,
                bites: u32::try_from(bites).unwrap_or(u32::MAX),
                gap_mrad,
                gap_low_mrad,
                gap_high_mrad,
                taf_mean,
                taf_min,
                taf_max,
            });
        }
        Ok(series)
    }

    /// `driveline`'s wear index (TAF / the linear reference's TAF - 1) in the buckets
    /// of [`Self::wear_series`] (same arguments, same errors): per bucket its range
    /// over the bites that have one, the wear trend after the last, and the range of
    /// static torque; buckets without a wear index are left out.
    ///
    /// Cost: the wear index is not in the `(driveline, time, ...)` index, so each
    /// bucket reads its bites' table rows (a year of one driveline: a million).
    pub fn wear_index_series(
        &self,
        driveline: &str,
        since: Option<UtcTime>,
        until: Option<UtcTime>,
        points: usize,
    ) -> Result<Vec<WearIndexPoint>, HistoryError> {
        let buckets = self.buckets(driveline, since, until, points)?;
        let connection = self.connection();
        let mut bucket = connection
            .prepare_cached(
                "SELECT count(wear_index), min(wear_index), max(wear_index),
                     min(static_torque_knm), max(static_torque_knm)
                 FROM bites WHERE driveline = ?1 AND time >= ?2 AND time < ?3",
            )
            .map_err(|e| self.error(e))?;
        let mut last_trend = connection
            .prepare_cached(
                "SELECT wear_trend FROM bites
                 WHERE driveline = ?1 AND time >= ?2 AND time < ?3 AND wear_trend IS NOT NULL
                 ORDER BY time DESC, id DESC LIMIT 1",
            )
            .map_err(|e| self.error(e))?;
        let mut series = Vec::new();
        for (start, end) in buckets {
            let (start_text, end_text) = (start.to_string(), end.to_string());
            let range = params![driveline, start_text, end_text];
            let (bites, low, high, torque_low, torque_high) = bucket
                .query_row(range, |row| {
                    Ok((
                        row.get::<_, i64>(0)?,
                        row.get::<_, Option<f64>>(1)?,
                        row.get::<_, Option<f64>>(2)?,
                        row.get::<_, Option<f64>>(3)?,
                        row.get::<_, Option<f64>>(4)?,
                    ))
                })
                .map_err(|e| self.error(e))?;
            let (Some(index_min), Some(index_max), Some(torque_low), Some(torque_high)) =
                (low, high, torque_low, torque_high)
            else {
                continue;
            };
            series.push(WearIndexPoint {
                start,
                end,
                bites: u32::try_from(bites).unwrap_or(u32::MAX),
                index_min,
                index_max,
                trend: last_trend
                    .query_row(range, |row| row.get(0))
                    .optional()
                    .map_err(|e| self.error(e))?,
                static_torque_min_knm: torque_low,
                static_torque_max_knm: torque_high,
            });
        }
        Ok(series)
    }

    /// The least-squares slope of `driveline`'s pooled gap estimate (the bites'
    /// `gap_mrad`) over time, mrad/week, fitted to the bites of the `window` before
    /// `until` (default: just after its last bite) and after its last wear reset
    /// (a reset starts a new trend: a new coupling). `None` with fewer than
    /// [`MIN_TREND_BITES`] such bites or when they all share one time.
    ///
    /// `window` > 0 (e.g. four weeks); a driveline the file does not know is
    /// [`HistoryError::UnknownDriveline`].
    pub fn gap_trend(
        &self,
        driveline: &str,
        until: Option<UtcTime>,
        window: Duration,
    ) -> Result<Option<GapTrend>, HistoryError> {
        let window_ms = i64::try_from(window.as_millis()).unwrap_or(i64::MAX);
        if window_ms < 1 {
            return Err(HistoryError::Argument {
                name: "window",
                value: format!("{} s", window.as_secs_f64()),
                allowed: "at least 1 ms".into(),
            });
        }
        if !self.knows_driveline(driveline)? {
            return Err(self.unknown(driveline));
        }
        let until = match until {
            Some(until) => until,
            None => match self.bite_span(driveline)? {
                Some((_, last)) => UtcTime::from_unix_ms(last.unix_ms() + 1),
                None => return Ok(None),
            },
        };
        let window_start = UtcTime::from_unix_ms(until.unix_ms().saturating_sub(window_ms));
        let connection = self.connection();
        let last_reset: Option<String> = connection
            .prepare_cached(
                "SELECT max(time) FROM wear_estimates
                 WHERE driveline = ?1 AND event = 'reset' AND time < ?2",
            )
            .and_then(|mut statement| {
                statement.query_row(params![driveline, until.to_string()], |row| row.get(0))
            })
            .map_err(|e| self.error(e))?;
        // x: weeks since the window's start (small numbers keep the sums exact
        // enough); y: mrad.
        // [sum x, sum y, sum x^2, sum x*y] (0 without bites).
        let (count, [sx, sy, sxx, sxy], first): (i64, [f64; 4], Option<String>) = connection
            .prepare_cached(&format!(
                "SELECT count(*), total(x), total(gap_mrad), total(x * x),
                     total(x * gap_mrad), min(time)
                 FROM (SELECT ({TIME_MS_SQL} - ?2) / ?3 AS x, gap_mrad, time
                     FROM bites
                     WHERE driveline = ?1 AND time >= ?4 AND time < ?5 AND time > ?6
                         AND gap_mrad IS NOT NULL)"
            ))
            .and_then(|mut statement| {
                statement.query_row(
                    params![
                        driveline,
                        window_start.unix_ms(),
                        WEEK_MS,
                        window_start.to_string(),
                        until.to_string(),
                        last_reset.unwrap_or_default()
                    ],
                    |row| {
                        let sums = [row.get(1)?, row.get(2)?, row.get(3)?, row.get(4)?];
                        Ok((row.get(0)?, sums, row.get(5)?))
                    },
                )
            })
            .map_err(|e| self.error(e))?;
        let Some(first) = first else {
            return Ok(None);
        };
        let bites = u32::try_from(count).unwrap_or(u32::MAX);
        if bites < MIN_TREND_BITES {
            return Ok(None);
        }
        let n = count as f64;
        let spread = n * sxx - sx * sx;
        // All bites at one time (or rounding leaves no spread): no slope.
        if spread <= f64::EPSILON * n * sxx {
            return Ok(None);
        }
        Ok(Some(GapTrend {
            mrad_per_week: (n * sxy - sx * sy) / spread,
            bites,
            since: self.time(&first)?,
        }))
    }
}
