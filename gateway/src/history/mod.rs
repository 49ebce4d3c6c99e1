//! The event history: every bite, wear estimate, alarm, chatter episode, source
//! outage and gateway start and stop in one SQLite file per gateway
//! (`history.path`), and the state a restart restores.
//!
//! - **One writer.** [`History`](crate::state::history::History) is the handle the analysis, the board and the
//!   outage monitor record through: [`History::record`](crate::state::history::History::record) puts an event on a bounded
//!   queue with `try_send` and never waits (a full queue drops the event and counts
//!   it). The writer thread ([`writer`]) owns the only read-write connection (WAL,
//!   `synchronous` as `history.synchronous` sets it, NORMAL by default) and commits
//!   whatever is queued in one transaction (group commit); a thread of its own
//!   checkpoints the WAL (`checkpoint.rs`). An event counts as stored only once its transaction has committed:
//!   [`History::stored`](crate::state::history::History::stored) counts those, [`History::wait_settled`](crate::state::history::History::wait_settled) waits until every
//!   event recorded so far is committed or known dropped. The PLC writer waits for
//!   that (bounded) before each write, so a bite the PLC has seen is in the file.
//! - **Failures** (a full disk, a read-only folder, a corrupt file): the writer logs
//!   one clear error, drops what it cannot store (counted), shows the error on
//!   `/metrics` and tries again (a full disk at the next batch, a file it cannot open
//!   every [`writer::REOPEN_PERIOD`]); the analysis and the PLC writes go on. A file
//!   SQLite's `quick_check` finds damaged at an open is not written to. A lock another
//!   process holds past the busy timeout keeps the batch, tried again (the run keeps
//!   its row); a file deleted or replaced while open is noticed before each commit,
//!   and the events go to the file now at the path (a new one), not the unlinked one.
//! - **Start**: while the file exists but cannot be read (a lock, a file system
//!   error), the start waits for it (the writer thread hands the restored
//!   state once read), so no counter starts below what the file holds.
//! - **Rows from the catalogue** ([`rows`], `figures.rs`): a bite row keeps the
//!   catalogue's figures that name a bite column, a subject's state row those that
//!   name a state column, written and read back by those names; a figure added to the
//!   catalogue with a column (and the migration that adds it) is stored, exported and
//!   restored with no edit here.
//! - **Restart**: at start the file's per-driveline and per-mill state tables give
//!   every figure with a state column: the bite counters, the last bite's values with
//!   their time, the wear trend and the gap estimate, warnings and latched alarms
//!   (`restore`); restored values carry the driveline's "restored" flag until the
//!   next bite.
//! - **Retention** ([`retention`]): events older than `history.retention_days`, and the
//!   oldest events while the data passes `history.max_size_mb`, are deleted in chunks
//!   between batches; freed pages go back to the file system (incremental vacuum).
//! - **Reading** ([`query`]): [`query::HistoryReader`] opens its own read-only
//!   connection; `millgate history` and `millgate report` use it. [`series`] adds
//!   what a page plots over months: the gap and TAF in time buckets and the gap's
//!   trend per week, aggregated by SQLite; [`fatigue_series`] the fatigue
//!   components' life used in the same buckets and each bite's damage beside its
//!   TAF; `summary` what a report reads over a
//!   year without holding it (a driveline's TAF quantiles, its bites one by one, when
//!   a run without a recorded stop was last seen).
//!
//! - **Captures** ([`captures`]): the samples behind each bite (and chatter episode,
//!   and manual request), recorded right after their event and stored in the same
//!   transaction, deflated; their own budget and thinning in the retention steps.
//!
//! Schema: [`schema`]; times: [`crate::state::time`] (UTC ISO-8601 text). The handle
//! everything records through, [`History`](crate::state::history::History), is the state layer's
//! ([`crate::state::history`]): this folder is the writer's side and the readers.

mod bite_row;
pub mod capture_files;
mod capture_parquet;
pub mod captures;
mod checkpoint;
mod context_columns;
mod error;
pub mod fatigue_series;
pub(crate) mod figures;
mod metrics;
pub(crate) mod outages;
pub mod query;
mod record;
pub(crate) mod restore;
pub mod retention;
pub mod rows;
mod run;
pub mod schema;
pub mod series;
pub(crate) mod summary;
pub mod writer;

pub use error::HistoryError;
pub use restore::{FatigueDay, FatigueHistory, FatigueReset};
pub use run::{DrivelineSettings, RunInfo};
pub use writer::start;
