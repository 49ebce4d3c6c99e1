//! Reading the history: a read-only connection of its own ([`HistoryReader`]) and
//! typed rows per table, filtered by name, time range and id, in id order (the order
//! events were stored), with a limit.
//!
//! This is the API the commands use (`millgate history`, `millgate report`) and the
//! one a web page or an MQTT store-and-forward replay builds on: page with
//! [`Filter::after_id`] and [`Filter::limit`] (ids grow with every stored row, so
//! the last id read is where to go on from). Each row type lists its columns in
//! [`Record::columns`] and gives its cells in that order ([`Record::cells`]); JSON
//! comes from its `Serialize` implementation with the same names.

use std::path::{Path, PathBuf};

use rusqlite::{Connection, OpenFlags};
use serde::Serialize;

pub use super::bite_row::{trusted, BiteRow};
use super::error::{check_file_owner, HistoryError};
pub use super::record::StoredCoil;
pub(crate) use super::record::ToCell;
pub use super::record::{Cell, Record};
use super::restore::{FatigueHistory, Restored, RestoredDriveline};
use super::schema::{current_version, SchemaError};
use crate::state::time::UtcTime;

/// SQLite virtual-machine instructions between two looks at a reader's stop
/// condition ([`HistoryReader::interrupt_when`]): well under a millisecond of work.
const QUERY_CHECK_OPS: std::ffi::c_int = 10_000;

/// SQLite's `quick_check` of the file at `path` open on `connection`.
pub(super) fn quick_check(connection: &Connection, path: &Path) -> Result<(), HistoryError> {
    let problems = connection
        .prepare("PRAGMA quick_check(10)")
        .and_then(|mut statement| {
            statement
                .query_map([], |row| row.get::<_, String>(0))?
                .collect::<rusqlite::Result<Vec<_>>>()
        })
        .map_err(|source| HistoryError::Sqlite {
            path: path.to_path_buf(),
            source,
        })?;
    if problems.len() == 1 && problems[0] == "ok" {
        return Ok(());
    }
    Err(HistoryError::Sqlite {
        path: path.to_path_buf(),
        source: rusqlite::Error::SqliteFailure(
            rusqlite::ffi::Error::new(rusqlite::ffi::SQLITE_CORRUPT),
            Some(format!("quick_check: {}", problems.join("; "))),
        ),
    })
}

/// Which rows to read.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Filter {
    /// Only rows of this driveline (bites, wear), subject (alarms: a driveline or
    /// mill), source (outages) or mill (chatter episodes).
    pub name: Option<String>,
    /// Rows at or after this time (a row's time, or its start).
    pub since: Option<UtcTime>,
    /// Rows before this time.
    pub until: Option<UtcTime>,
    /// Rows whose id is above this one (paging, replay).
    pub after_id: Option<i64>,
    /// At most this many rows.
    pub limit: Option<u32>,
    /// Only rows of this product code (bites: their `product` column, schema v13;
    /// captures and chatter episodes, v14; a table without a product has no row of
    /// any product).
    pub product: Option<u32>,
    /// Only rows of this coil or bar id, compared as text (`CAST(coil AS TEXT)`: a
    /// numeric coil 4711 is `4711`, a text coil its characters; `04711` is not
    /// `4711`); a table without the context's columns has no row of any coil.
    pub coil: Option<String>,
}

/// Declares a row struct of `table` with its [`Record`] implementation: one place
/// names each column, its type and its meaning. `with context`: the row also has the
/// process context's columns (schema v14), and its product is `product`.
macro_rules! record {
    (
        $(#[$meta:meta])* $name:ident, $table:literal, name $name_column:literal,
        time $time_column:literal, with context {
            $($(#[$field_meta:meta])* $field:ident: $ty:ty,)*
        }
    ) => {
        record! {
            $(#[$meta])* $name, $table, name $name_column, time $time_column,
            product "product" {
                $($(#[$field_meta])* $field: $ty,)*
                /// Line speed then, m/min (schema v14: the process context of its time; every
                /// value `None` without context tags, for a stale tag, for an invalid
                /// context and before v14).
                speed_mpm: Option<f64>,
                /// Coil or bar id.
                coil: Option<StoredCoil>,
                /// Product code.
                product: Option<i64>,
                /// Strip thickness, mm.
                thickness_mm: Option<f64>,
                /// Pass number.
                pass: Option<i64>,
                /// `idle`, `threading`, `rolling`, `maintenance`.
                mill_state: Option<String>,
                /// `valid`, `stale` (a tag without a fresh value: that value `None`),
                /// `invalid` (an impossible value: every value `None`); `None` without
                /// context tags and before v14.
                context_status: Option<String>,
                /// Why the context is not valid.
                context_note: Option<String>,
            }
        }
    };
    (
        $(#[$meta:meta])* $name:ident, $table:literal, name $name_column:literal,
        time $time_column:literal $(, product $product_column:literal)? {
            $($(#[$field_meta:meta])* $field:ident: $ty:ty,)*
        }
    ) => {
        $(#[$meta])*
        #[derive(Debug, Clone, PartialEq, Serialize)]
        pub struct $name {
            $($(#[$field_meta])* pub $field: $ty,)*
        }

        impl Record for $name {
            const TABLE: &'static str = $table;
            fn columns() -> &'static [&'static str] {
                &[$(stringify!($field)),*]
            }
            const NAME_COLUMN: &'static str = $name_column;
            const TIME_COLUMN: &'static str = $time_column;
            $(const PRODUCT_COLUMN: Option<&'static str> = Some($product_column);)?

            fn from_row(row: &rusqlite::Row<'_>) -> rusqlite::Result<Self> {
                Ok(Self { $($field: row.get(stringify!($field))?,)* })
            }

            fn cells(&self) -> Vec<Cell> {
                vec![$(self.$field.to_cell()),*]
            }
        }
    };
}

record! {
    /// A wear estimate or a trend reset (table `wear_estimates`).
    WearRow, "wear_estimates", name "driveline", time "time" {
        /// Row id.
        id: i64,
        /// Driveline name.
        driveline: String,
        /// UTC, ISO-8601.
        time: String,
        /// `bite` or `reset`.
        event: String,
        /// `analysis`, or who reset: `hmi`, `plc`, `local`.
        origin: String,
        /// The Modbus client that reset.
        peer: Option<String>,
        /// Wear index of the bite.
        wear_index: Option<f64>,
        /// Wear trend after it.
        wear_trend: Option<f64>,
        /// The linear reference's TAF.
        reference_taf: Option<f64>,
        /// Static torque level of the reference, kN*m.
        reference_level_knm: Option<f64>,
        /// Measured minus reference first-period shift, s.
        shift_over_linear_s: Option<f64>,
        /// Pooled gap estimate, mrad.
        gap_mrad: Option<f64>,
        /// Its interval's lower end, mrad.
        gap_low_mrad: Option<f64>,
        /// Its interval's upper end, mrad.
        gap_high_mrad: Option<f64>,
        /// The coupling holding the gap (model index, 0 = motor side); `None` when
        /// the bites cannot tell.
        gap_coupling: Option<i64>,
        /// Bites pooled.
        bites_pooled: Option<i64>,
        /// `ok`, `warning`, `alarm`.
        state: Option<String>,
        /// The wear alarm was latched.
        alarm_latched: Option<bool>,
    }
}

record! {
    /// An alarm raised, cleared or acknowledged (table `alarms`).
    AlarmRow, "alarms", name "subject", time "time" {
        /// Row id.
        id: i64,
        /// UTC, ISO-8601.
        time: String,
        /// The driveline or mill.
        subject: String,
        /// The flag's key: `taf_warning`, `taf_alarm`, `gap_warning`, `gap_alarm`,
        /// `chatter_warning`, `chatter_alarm`.
        kind: String,
        /// `raised`, `cleared`, `acknowledged`.
        event: String,
        /// `analysis`, `hmi`, `plc`, `local`.
        origin: String,
        /// The Modbus client that acknowledged.
        peer: Option<String>,
        /// The value that raised it.
        value: Option<f64>,
        /// The threshold.
        threshold: Option<f64>,
    }
}

record! {
    /// A source outage (table `source_outages`).
    OutageRow, "source_outages", name "source", time "started_at" {
        /// Row id.
        id: i64,
        /// The source.
        source: String,
        /// UTC, ISO-8601.
        started_at: String,
        /// UTC, ISO-8601; empty while it lasts.
        ended_at: Option<String>,
        /// `recovered` (analysis), `stop`, `restart`.
        ended_by: Option<String>,
        /// `stale` or `lost`.
        worst_status: String,
        /// Blocks lost on its channels.
        blocks_missed: i64,
    }
}

record! {
    /// A chatter episode (table `chatter_episodes`).
    ChatterRow, "chatter_episodes", name "mill", time "started_at", with context {
        /// Row id.
        id: i64,
        /// The tandem mill.
        mill: String,
        /// UTC, ISO-8601.
        started_at: String,
        /// UTC, ISO-8601.
        ended_at: Option<String>,
        /// `analysis`, `window_restart`, `stop`, `restart`.
        ended_by: Option<String>,
        /// Windows evaluated in it.
        windows: i64,
        /// Smallest sigma_n, Hz.
        min_sigma_n_hz: Option<f64>,
        /// Largest K_mean.
        max_k_mean: Option<f64>,
        /// Chatter frequency of its last window, Hz.
        frequency_hz: Option<f64>,
        /// The alarm condition held in a window.
        alarm: bool,
        /// The product group whose `gain_thresholds` judged the window that raised
        /// its warning (its name in the mill's `product_groups`); `None`: the mill's
        /// own thresholds, and every episode before schema v15.
        thresholds_group: Option<String>,
    }
}

record! {
    /// A gateway run (table `gateway_runs`).
    RunRow, "gateway_runs", name "config_name", time "started_at" {
        /// Row id.
        id: i64,
        /// UTC, ISO-8601.
        started_at: String,
        /// UTC, ISO-8601; empty while running or after a kill.
        stopped_at: Option<String>,
        /// `stopped`, `unclean`; empty while running.
        ended: Option<String>,
        /// millgate version.
        version: String,
        /// The configuration's name.
        config_name: String,
    }
}

record! {
    /// A run's driveline settings (table `driveline_settings`).
    SettingsRow, "driveline_settings", name "driveline", time "time" {
        /// Row id.
        id: i64,
        /// The run.
        run_id: i64,
        /// The run's start, or the reload that applied these thresholds, UTC,
        /// ISO-8601.
        time: String,
        /// Driveline name.
        driveline: String,
        /// TAF warning threshold.
        taf_warning: f64,
        /// TAF alarm threshold.
        taf_alarm: f64,
        /// The driveline model file, as configured.
        model: Option<String>,
        /// The gap diagnosis' warning threshold, mrad.
        gap_warning_mrad: Option<f64>,
        /// The gap diagnosis' alarm threshold, mrad.
        gap_alarm_mrad: Option<f64>,
    }
}

record! {
    /// A capture (table `captures`, schema v7): what, when and how large; its
    /// samples are read with [`HistoryReader::capture_of`].
    CaptureRow, "captures", name "subject", time "started_at", with context {
        /// Row id: the capture's id.
        id: i64,
        /// The gateway run that stored it.
        run_id: i64,
        /// `bite`, `chatter`, `manual`.
        kind: String,
        /// The driveline, tandem mill or manual request's name.
        subject: String,
        /// `bites.id` of its bite (a bite capture, while the bite row is kept).
        bite_id: Option<i64>,
        /// The driveline's bite counter after its bite.
        bite_counter: Option<i64>,
        /// Its bite's time, UTC, ISO-8601.
        bite_time: Option<String>,
        /// The first sample, UTC, ISO-8601 (ms).
        started_at: String,
        /// The first sample, ns since the Unix epoch.
        first_sample_unix_ns: i64,
        /// Times from the CAN kernel's receive timestamps.
        kernel_time: bool,
        /// Sample rate, Hz.
        sample_rate_hz: f64,
        /// Samples per channel.
        samples: i64,
        /// Length, s.
        duration_s: f64,
        /// 0 ordinary bite, 1 warning bite, 2 alarm bite, chatter episode or manual.
        keep: i64,
        /// JSON: channels (name, unit, scale, offset, encoding), gaps, analysis.
        meta: String,
        /// Size of the stored samples, bytes.
        bytes: i64,
    }
}

/// A read-only connection to a history file.
#[derive(Debug)]
pub struct HistoryReader {
    path: PathBuf,
    connection: Connection,
}

impl HistoryReader {
    /// Open `path` read-only; refuses a file that is not a millgate history (another
    /// application's SQLite file, or one without a millgate schema) or is newer than
    /// this millgate.
    pub fn open(path: &Path) -> Result<Self, HistoryError> {
        let sqlite = |source| HistoryError::Sqlite {
            path: path.to_path_buf(),
            source,
        };
        if path.is_dir() {
            // SQLite opens a folder and fails at the first read ("disk I/O error").
            return Err(HistoryError::Folder {
                path: path.to_path_buf(),
            });
        }
        let connection = Connection::open_with_flags(
            path,
            OpenFlags::SQLITE_OPEN_READ_ONLY | OpenFlags::SQLITE_OPEN_NO_MUTEX,
        )
        .map_err(sqlite)?;
        check_file_owner(&connection, path)?;
        let version: i64 = connection
            .pragma_query_value(None, "user_version", |row| row.get(0))
            .map_err(sqlite)?;
        let known = current_version();
        if version > known {
            return Err(HistoryError::Schema {
                path: path.to_path_buf(),
                source: SchemaError::TooNew {
                    found: version,
                    known,
                },
            });
        }
        if version == 0 {
            return Err(sqlite(rusqlite::Error::SqliteFailure(
                rusqlite::ffi::Error::new(rusqlite::ffi::SQLITE_NOTADB),
                Some("not a millgate history (no schema version)".into()),
            )));
        }
        Ok(Self {
            path: path.to_path_buf(),
            connection,
        })
    }

    /// The file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Interrupt every statement of this reader once `stop` returns true (checked
    /// every few thousand SQLite instructions): a statement then fails with
    /// `SQLITE_INTERRUPT` instead of running to its end.
    pub fn interrupt_when(&mut self, stop: impl FnMut() -> bool + Send + 'static) {
        // Only fails on a closed connection, which a reader never holds.
        let _ = self
            .connection
            .progress_handler(QUERY_CHECK_OPS, Some(stop));
    }

    /// SQLite's `quick_check` of the whole file (every page's structure, no index
    /// contents): `Ok` for a sound file, else the problems SQLite found (at most ten).
    pub fn quick_check(&self) -> Result<(), HistoryError> {
        quick_check(&self.connection, &self.path)
    }

    /// The read-only connection, for the queries of sibling modules ([`super::series`]).
    pub(super) fn connection(&self) -> &Connection {
        &self.connection
    }

    /// `source` as this file's error.
    pub(super) fn error(&self, source: rusqlite::Error) -> HistoryError {
        HistoryError::Sqlite {
            path: self.path.clone(),
            source,
        }
    }

    /// The rows of `R`'s table that pass `filter`, in id order.
    pub fn rows<R: Record>(&self, filter: &Filter) -> Result<Vec<R>, HistoryError> {
        self.select(filter, false)
    }

    /// The newest rows of `R`'s table that pass `filter` (the last [`Filter::limit`]
    /// of them by time, then id), oldest first: "the last 20 bites".
    pub fn newest<R: Record>(&self, filter: &Filter) -> Result<Vec<R>, HistoryError> {
        let mut rows = self.select(filter, true)?;
        rows.reverse();
        Ok(rows)
    }

    /// The rows that pass `filter` in id order, or newest first by time (`newest`).
    fn select<R: Record>(&self, filter: &Filter, newest: bool) -> Result<Vec<R>, HistoryError> {
        let mut rows = Vec::new();
        self.visit(filter, newest, |row| {
            rows.push(row);
            Ok::<_, HistoryError>(())
        })?;
        Ok(rows)
    }

    /// Hands each row of `R`'s table that passes `filter` to `visit`, in id order, as
    /// it is read: nothing is kept, so an export of a year of bites needs the memory
    /// of one row. `visit`'s error ends the reading and is returned.
    pub fn for_each<R: Record, E: From<HistoryError>>(
        &self,
        filter: &Filter,
        visit: impl FnMut(R) -> Result<(), E>,
    ) -> Result<(), E> {
        self.visit(filter, false, visit)
    }

    /// How many rows of `R`'s table pass `filter` (at most its limit).
    pub fn count<R: Record>(&self, filter: &Filter) -> Result<u64, HistoryError> {
        let (conditions, values) = Self::conditions::<R>(filter);
        let sql = format!("SELECT count(*) FROM {}{conditions}", R::TABLE);
        let count: i64 = self
            .connection
            .query_row(&sql, rusqlite::params_from_iter(values), |row| row.get(0))
            .map_err(|e| self.error(e))?;
        let count = u64::try_from(count).unwrap_or(0);
        Ok(filter
            .limit
            .map_or(count, |limit| count.min(u64::from(limit))))
    }

    /// The `WHERE` clause (empty, or starting with a space) of `filter` on `R`'s
    /// table, and its values.
    fn conditions<R: Record>(filter: &Filter) -> (String, Vec<rusqlite::types::Value>) {
        let mut conditions = Vec::new();
        let mut values: Vec<rusqlite::types::Value> = Vec::new();
        // A filter on a column the table does not have: no row.
        let mut no_row = false;
        let mut condition = |sql: String, value: rusqlite::types::Value| {
            values.push(value);
            conditions.push(format!("{sql} ?{}", values.len()));
        };
        if let Some(name) = &filter.name {
            condition(format!("{} =", R::NAME_COLUMN), name.clone().into());
        }
        if let Some(since) = filter.since {
            condition(format!("{} >=", R::TIME_COLUMN), since.to_string().into());
        }
        if let Some(until) = filter.until {
            condition(format!("{} <", R::TIME_COLUMN), until.to_string().into());
        }
        if let Some(after) = filter.after_id {
            condition("id >".into(), after.into());
        }
        if let Some(product) = filter.product {
            match R::PRODUCT_COLUMN {
                Some(column) => condition(format!("{column} ="), i64::from(product).into()),
                None => no_row = true,
            }
        }
        if let Some(coil) = &filter.coil {
            // The tables with a product column are those with the context's columns.
            match R::PRODUCT_COLUMN {
                Some(_) => condition("CAST(coil AS TEXT) =".into(), coil.clone().into()),
                None => no_row = true,
            }
        }
        if no_row {
            conditions.push("0".to_owned());
        }
        if conditions.is_empty() {
            (String::new(), values)
        } else {
            (format!(" WHERE {}", conditions.join(" AND ")), values)
        }
    }

    /// Hands the rows that pass `filter` to `visit` as they are read, in id order, or
    /// newest first by time (`newest`).
    fn visit<R: Record, E: From<HistoryError>>(
        &self,
        filter: &Filter,
        newest: bool,
        mut visit: impl FnMut(R) -> Result<(), E>,
    ) -> Result<(), E> {
        let (conditions, values) = Self::conditions::<R>(filter);
        let mut sql = format!(
            "SELECT {} FROM {}{conditions}",
            R::columns().join(", "),
            R::TABLE
        );
        // Newest by time (then id, for rows of one millisecond): the time indexes
        // give those in order; by id alone SQLite sorted every row of a driveline
        // (a million in a year) to return the last 100.
        if newest {
            sql.push_str(&format!(" ORDER BY {} DESC, id DESC", R::TIME_COLUMN));
        } else {
            sql.push_str(" ORDER BY id");
        }
        if let Some(limit) = filter.limit {
            sql.push_str(&format!(" LIMIT {limit}"));
        }
        let mut statement = self.connection.prepare(&sql).map_err(|e| self.error(e))?;
        let mut rows = statement
            .query(rusqlite::params_from_iter(values))
            .map_err(|e| self.error(e))?;
        while let Some(row) = rows.next().map_err(|e| self.error(e))? {
            visit(R::from_row(row).map_err(|e| self.error(e))?)?;
        }
        Ok(())
    }

    /// The id of the last bite in the file (0 when there is none).
    pub(crate) fn last_bite_id(&self) -> Result<i64, HistoryError> {
        self.connection
            .query_row("SELECT coalesce(max(id), 0) FROM bites", [], |row| {
                row.get(0)
            })
            .map_err(|e| self.error(e))
    }

    /// How many bites have an id above `id`.
    pub(crate) fn bites_after(&self, id: i64) -> Result<u64, HistoryError> {
        let count: i64 = self
            .connection
            .query_row("SELECT count(*) FROM bites WHERE id > ?1", [id], |row| {
                row.get(0)
            })
            .map_err(|e| self.error(e))?;
        Ok(u64::try_from(count).unwrap_or(0))
    }

    /// Bites by driveline and time range.
    pub fn bites(&self, filter: &Filter) -> Result<Vec<BiteRow>, HistoryError> {
        self.rows(filter)
    }

    /// Wear estimates and trend resets.
    pub fn wear(&self, filter: &Filter) -> Result<Vec<WearRow>, HistoryError> {
        self.rows(filter)
    }

    /// Alarms raised, cleared and acknowledged.
    pub fn alarms(&self, filter: &Filter) -> Result<Vec<AlarmRow>, HistoryError> {
        self.rows(filter)
    }

    /// Source outages.
    pub fn outages(&self, filter: &Filter) -> Result<Vec<OutageRow>, HistoryError> {
        self.rows(filter)
    }

    /// Chatter episodes.
    pub fn chatter(&self, filter: &Filter) -> Result<Vec<ChatterRow>, HistoryError> {
        self.rows(filter)
    }

    /// Gateway runs (starts and stops).
    pub fn runs(&self, filter: &Filter) -> Result<Vec<RunRow>, HistoryError> {
        self.rows(filter)
    }

    /// Driveline settings of each run.
    pub fn settings(&self, filter: &Filter) -> Result<Vec<SettingsRow>, HistoryError> {
        self.rows(filter)
    }

    /// The drivelines that have bites, by name.
    pub fn drivelines(&self) -> Result<Vec<String>, HistoryError> {
        let mut statement = self
            .connection
            .prepare("SELECT DISTINCT driveline FROM bites ORDER BY driveline")
            .map_err(|e| self.error(e))?;
        let names = statement
            .query_map([], |row| row.get(0))
            .map_err(|e| self.error(e))?;
        names
            .collect::<rusqlite::Result<Vec<String>>>()
            .map_err(|e| self.error(e))
    }

    /// `driveline`'s fatigue resets, oldest first, and its components' damage per UTC
    /// day over the last `days` days that have bites (the `fatigue_bites` rows; empty
    /// for a file from before version 12).
    pub fn fatigue(&self, driveline: &str, days: u32) -> Result<FatigueHistory, HistoryError> {
        super::restore::fatigue_history(&self.connection, driveline, days)
            .map_err(|e| self.error(e))
    }

    /// The state the next start would restore.
    pub fn state(&self) -> Result<Restored, HistoryError> {
        super::restore::read(&self.connection).map_err(|e| self.error(e))
    }

    /// What the next start would restore of driveline `name` (`None` when the file
    /// has no state of it): what a driveline a reload adds under that name resumes.
    pub fn driveline_state(&self, name: &str) -> Result<Option<RestoredDriveline>, HistoryError> {
        super::restore::read_driveline(&self.connection, name).map_err(|e| self.error(e))
    }
}
