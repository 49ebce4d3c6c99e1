//! Retention: events older than `history.retention_days`, and the oldest events while
//! the file's data passes `history.max_size_mb`, are deleted in chunks; freed pages
//! are handed back to the file system.
//!
//! The writer runs one [`Retention::step`] between batches when it is due: at most
//! [`Retention::chunk_rows`] rows per table in one transaction, then at most
//! [`Retention::vacuum_pages`] free pages released (`PRAGMA incremental_vacuum`; new
//! files are created with `auto_vacuum=INCREMENTAL`). A step takes milliseconds, so
//! the events queued meanwhile wait at most that long. While a step leaves work (more
//! old rows, still too large, free pages left) the next one follows after
//! [`BUSY_PERIOD`]; otherwise after [`CHECK_PERIOD`].
//!
//! Size: the data are the file's pages less its free pages. Past the limit, the
//! oldest rows are deleted until the data are below [`SHRINK_TO`] of it, so a full
//! file is not trimmed again at every step.

use std::time::{Duration, Instant};

use rusqlite::{params, Connection, OptionalExtension};

use crate::state::time::UtcTime;

/// Time between retention checks while there is nothing to delete.
pub const CHECK_PERIOD: Duration = Duration::from_secs(10);
/// Time between steps while there is work left (the writer commits events between).
pub const BUSY_PERIOD: Duration = Duration::from_millis(20);
/// After passing the size limit, rows are deleted until the data are this fraction of it.
pub const SHRINK_TO: f64 = 0.9;
/// Time to wait after a failed step.
const FAILED_PERIOD: Duration = Duration::from_secs(60);

/// Each table with the column that dates its rows and a condition: `gateway_runs`
/// and `driveline_settings` only of runs that ended (never this one's), and a run
/// only once no row refers to it (see [`UNREFERENCED_RUN`]).
const TABLES: [(&str, &str, &str); 7] = [
    ("bites", "time", ""),
    (
        "driveline_settings",
        "time",
        "AND run_id IN (SELECT id FROM gateway_runs WHERE ended IS NOT NULL)",
    ),
    ("wear_estimates", "time", ""),
    ("alarms", "time", ""),
    ("chatter_episodes", "started_at", ""),
    ("source_outages", "started_at", ""),
    ("gateway_runs", "started_at", UNREFERENCED_RUN),
];

/// A run's row may go only when no row of another table refers to it: the rows of a
/// long run outlive its start by the run's length, and a size step deletes at most a
/// chunk per table, so dating the run by its start alone deleted runs whose bites were
/// still there (the foreign key refused it and retention stopped). Each table's rows
/// are inserted in run order and its row ids only grow while it holds rows, so the row
/// with the lowest id carries the lowest run id left: one index lookup per table
/// instead of a search of a year of bites for the run's id.
const UNREFERENCED_RUN: &str = "AND ended IS NOT NULL
     AND id < coalesce((SELECT run_id FROM bites ORDER BY rowid LIMIT 1), id + 1)
     AND id < coalesce((SELECT run_id FROM wear_estimates ORDER BY rowid LIMIT 1), id + 1)
     AND id < coalesce((SELECT run_id FROM alarms ORDER BY rowid LIMIT 1), id + 1)
     AND id < coalesce((SELECT run_id FROM chatter_episodes ORDER BY rowid LIMIT 1), id + 1)
     AND id < coalesce((SELECT run_id FROM source_outages ORDER BY rowid LIMIT 1), id + 1)
     AND id < coalesce((SELECT run_id FROM driveline_settings ORDER BY rowid LIMIT 1), id + 1)
     AND id < coalesce((SELECT min(run_id) FROM captures), id + 1)";

/// Retention settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Retention {
    /// Rows older than this are deleted.
    pub max_age: Duration,
    /// Largest data size, bytes.
    pub max_bytes: u64,
    /// Most rows deleted per table in one step.
    pub chunk_rows: u32,
    /// Most free pages released in one step.
    pub vacuum_pages: u32,
    /// The captures' thinning and budget (`None`: captures off). Captures are not
    /// among the events the size limit deletes: they have a budget of their own
    /// within it, and the important ones are kept longest.
    pub captures: Option<CaptureRetention>,
}

/// What one step did.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Step {
    /// Rows deleted.
    pub deleted: u64,
    /// Pages handed back to the file system.
    pub released_pages: u64,
    /// File size after the step (pages times page size; the WAL not included), bytes.
    pub file_bytes: u64,
    /// Data (pages in use) after the step, bytes.
    pub data_bytes: u64,
    /// Work is left for another step.
    pub more: bool,
}

/// The retention's progress between steps.
#[derive(Debug)]
pub struct RetentionState {
    next: Instant,
    shrinking: bool,
}

impl Default for RetentionState {
    fn default() -> Self {
        Self {
            // The first check soon after start: a file left too large by a run with a
            // larger limit is trimmed at once.
            next: Instant::now() + BUSY_PERIOD,
            shrinking: false,
        }
    }
}

impl RetentionState {
    /// Whether a step is due now.
    pub fn due(&self) -> bool {
        Instant::now() >= self.next
    }

    /// How long the writer may wait for events before the next step is due.
    pub fn wait(&self) -> Duration {
        self.next.saturating_duration_since(Instant::now())
    }

    pub(crate) fn failed(&mut self) {
        self.next = Instant::now() + FAILED_PERIOD;
    }
}

impl Retention {
    /// The settings of `[history]`: 500 rows and 256 pages (1 MiB at 4 KiB pages)
    /// per step.
    pub(crate) fn from_config(config: &millgate_config::History) -> Self {
        Self {
            max_age: Duration::from_secs(u64::from(config.retention_days) * 86_400),
            max_bytes: u64::from(config.max_size_mb) * 1024 * 1024,
            chunk_rows: 500,
            vacuum_pages: 256,
            captures: CaptureRetention::from_config(config),
        }
    }

    /// One bounded step at `now`; updates `state` (when the next is due).
    pub fn step(
        &self,
        connection: &Connection,
        now: UtcTime,
        state: &mut RetentionState,
    ) -> rusqlite::Result<Step> {
        let before = sizes(connection)?;
        if before.data > self.max_bytes {
            state.shrinking = true;
        } else if (before.data as f64) < SHRINK_TO * self.max_bytes as f64 {
            state.shrinking = false;
        }
        let mut cutoff = now.minus(self.max_age).to_string();
        if state.shrinking {
            // The time of the chunk-th oldest bite (or now, when there are fewer):
            // every table loses its rows older than that, at most a chunk each.
            let oldest: Option<String> = connection
                .query_row(
                    "SELECT time FROM bites ORDER BY time LIMIT 1 OFFSET ?1",
                    [self.chunk_rows],
                    |row| row.get(0),
                )
                .optional()?;
            cutoff = cutoff.max(oldest.unwrap_or_else(|| now.to_string()));
        }
        let mut deleted = 0u64;
        let mut full_chunk = false;
        let transaction = connection.unchecked_transaction()?;
        for (table, column, condition) in TABLES {
            let rows = transaction.execute(
                &format!(
                    "DELETE FROM {table} WHERE rowid IN (SELECT rowid FROM {table}
                     WHERE {column} < ?1 {condition} ORDER BY {column} LIMIT ?2)"
                ),
                rusqlite::params![cutoff, self.chunk_rows],
            )?;
            deleted += rows as u64;
            full_chunk |= rows as u64 >= u64::from(self.chunk_rows);
        }
        transaction.commit()?;
        if let Some(captures) = &self.captures {
            let age_cutoff = now.minus(self.max_age).to_string();
            let step = captures.step(connection, now, &age_cutoff, self.chunk_rows)?;
            deleted += step.deleted;
            full_chunk |= step.more;
        } else {
            // Captures off: those of earlier runs go with age alone.
            let age_cutoff = now.minus(self.max_age).to_string();
            let rows = connection.execute(
                "DELETE FROM captures WHERE id IN (SELECT id FROM captures
                 WHERE started_at < ?1 ORDER BY started_at LIMIT ?2)",
                rusqlite::params![age_cutoff, self.chunk_rows],
            )?;
            deleted += rows as u64;
            full_chunk |= rows as u64 >= u64::from(self.chunk_rows);
        }
        // A file without incremental auto-vacuum (made by another tool) keeps its
        // free pages and reuses them for new rows: it stops growing, but does not shrink.
        let incremental =
            connection.pragma_query_value(None, "auto_vacuum", |row| row.get::<_, i64>(0))? == 2;
        if incremental && sizes(connection)?.free_pages > 0 {
            // The pragma releases one page per step of its statement: run it to the
            // end (`execute_batch` steps once, which released a single page).
            let mut vacuum =
                connection.prepare(&format!("PRAGMA incremental_vacuum({})", self.vacuum_pages))?;
            let mut rows = vacuum.raw_query();
            while rows.next()?.is_some() {}
        }
        let after = sizes(connection)?;
        let more =
            full_chunk || (incremental && after.free_pages > 0) || (state.shrinking && deleted > 0);
        state.next = Instant::now() + if more { BUSY_PERIOD } else { CHECK_PERIOD };
        Ok(Step {
            deleted,
            released_pages: before.pages.saturating_sub(after.pages),
            file_bytes: after.pages * after.page_size,
            data_bytes: after.data,
            more,
        })
    }
}

/// Page counts of the main file.
struct Sizes {
    pages: u64,
    free_pages: u64,
    page_size: u64,
    data: u64,
}

fn sizes(connection: &Connection) -> rusqlite::Result<Sizes> {
    let pragma = |name| connection.pragma_query_value(None, name, |row| row.get::<_, i64>(0));
    let pages = pragma("page_count")?.max(0) as u64;
    let free_pages = pragma("freelist_count")?.max(0) as u64;
    let page_size = pragma("page_size")?.max(0) as u64;
    Ok(Sizes {
        pages,
        free_pages,
        page_size,
        data: pages.saturating_sub(free_pages) * page_size,
    })
}

/// The captures' retention: age (`history.retention_days`), thinning of ordinary
/// bites' captures after `thin_after_days` to every `keep_every`-th bite, and the
/// budget `max_bytes`, kept by deleting the lowest [`KeepClass`](crate::state::captures::KeepClass) first, oldest first.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CaptureRetention {
    /// Ordinary bites' captures older than this are thinned.
    pub thin_after: Duration,
    /// After that, an ordinary bite's capture stays when its counter is a multiple.
    pub keep_every: u32,
    /// Largest size of the captures' blobs, bytes.
    pub max_bytes: u64,
}

/// What one capture retention step did.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct CaptureStep {
    /// Captures deleted.
    pub deleted: u64,
    /// Work is left for another step.
    pub more: bool,
}

impl CaptureRetention {
    /// The settings of `[history]`, or `None` when captures are off.
    pub(crate) fn from_config(config: &millgate_config::History) -> Option<Self> {
        let captures = &config.captures;
        captures.enabled.then(|| Self {
            thin_after: Duration::from_secs(u64::from(captures.thin_after_days) * 86_400),
            keep_every: captures.keep_every,
            max_bytes: u64::from(captures.max_mb) * 1024 * 1024,
        })
    }

    /// One bounded step at `now`: at most `chunk` captures deleted by each rule, the
    /// ones older than `age_cutoff` first.
    pub fn step(
        &self,
        connection: &rusqlite::Connection,
        now: UtcTime,
        age_cutoff: &str,
        chunk: u32,
    ) -> rusqlite::Result<CaptureStep> {
        let transaction = connection.unchecked_transaction()?;
        let mut deleted = transaction.execute(
            "DELETE FROM captures WHERE id IN (SELECT id FROM captures
             WHERE started_at < ?1 ORDER BY started_at LIMIT ?2)",
            params![age_cutoff, chunk],
        )? as u64;
        let mut more = deleted >= u64::from(chunk);
        if self.keep_every > 1 {
            let thin_cutoff = now.minus(self.thin_after).to_string();
            let thinned = transaction.execute(
                "DELETE FROM captures WHERE id IN (SELECT id FROM captures
                 WHERE keep = 0 AND kind = 'bite' AND started_at < ?1
                     AND coalesce(bite_counter, 0) % ?2 != 0
                 ORDER BY keep, id LIMIT ?3)",
                params![thin_cutoff, self.keep_every, chunk],
            )? as u64;
            more |= thinned >= u64::from(chunk);
            deleted += thinned;
        }
        let total: i64 =
            transaction.query_row("SELECT bytes FROM capture_totals WHERE id = 1", [], |row| {
                row.get(0)
            })?;
        let total = total.max(0) as u64;
        if total > self.max_bytes {
            // Delete, lowest class and oldest first, until the captures are at 90% of
            // the budget (so a full budget is not trimmed again at every capture).
            let target = (SHRINK_TO * self.max_bytes as f64) as u64;
            let mut excess = total - target;
            let mut victims = Vec::new();
            {
                let mut select = transaction
                    .prepare_cached("SELECT id, bytes FROM captures ORDER BY keep, id LIMIT ?1")?;
                let mut rows = select.query([chunk])?;
                while let Some(row) = rows.next()? {
                    if excess == 0 {
                        break;
                    }
                    let (id, bytes): (i64, i64) = (row.get(0)?, row.get(1)?);
                    victims.push(id);
                    excess = excess.saturating_sub(bytes.max(0) as u64);
                }
            }
            let mut delete = transaction.prepare_cached("DELETE FROM captures WHERE id = ?1")?;
            for id in &victims {
                deleted += delete.execute([id])? as u64;
            }
            more |= excess > 0;
        }
        transaction.commit()?;
        Ok(CaptureStep { deleted, more })
    }
}
