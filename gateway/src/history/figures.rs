//! The catalogue's figures in the history file: each figure's value as an SQL value and
//! back, the state table of each subject kind, and the statements derived from the
//! catalogue's [`Columns`](crate::state::catalogue::Columns): the state rows' upsert
//! and read-back (what a start restores), and the figure columns of a bite row.
//!
//! A figure the catalogue declares with a column is written, read back and restored
//! through here, by its column's name; a new one needs its declaration and a
//! migration that adds the column ([`super::schema`]), nothing here.

use std::sync::OnceLock;

use rusqlite::types::{Value as SqlValue, ValueRef};
use rusqlite::{Connection, Transaction};

use crate::state::catalogue::{Figure, FigureType, Subject, Value};
use crate::state::results::{DrivelineResults, TandemMillResults};
use crate::state::time::UtcTime;

/// A figure's value as stored: reals as REAL, counts, indices, states (their index)
/// and flags as INTEGER (flags 0/1), times as UTC ISO-8601 text; no value as NULL.
pub(crate) fn to_sql(value: Option<Value>) -> SqlValue {
    match value {
        None => SqlValue::Null,
        Some(Value::Real(v)) => SqlValue::Real(v),
        Some(Value::Count(v)) | Some(Value::Index(v)) => {
            i64::try_from(v).map_or(SqlValue::Null, SqlValue::Integer)
        }
        Some(Value::Bool(v)) => SqlValue::Integer(i64::from(v)),
        Some(Value::Time(ms)) => SqlValue::Text(UtcTime::from_unix_ms(ms).to_string()),
    }
}

/// A stored value as a figure of `figure_type`: `None` for NULL and for what does not
/// read as that type (a negative count, a time that is not one).
pub(crate) fn from_sql(figure_type: FigureType, value: ValueRef<'_>) -> Option<Value> {
    match (figure_type, value) {
        (_, ValueRef::Null) => None,
        (FigureType::Real, ValueRef::Real(v)) => Some(Value::Real(v)),
        (FigureType::Real, ValueRef::Integer(v)) => Some(Value::Real(v as f64)),
        (FigureType::Count | FigureType::Sequence, ValueRef::Integer(v)) => {
            u64::try_from(v).ok().map(Value::Count)
        }
        (FigureType::Index, ValueRef::Integer(v)) => u64::try_from(v).ok().map(Value::Index),
        (FigureType::State(names), ValueRef::Integer(v)) => usize::try_from(v)
            .ok()
            .filter(|&index| index < names.len())
            .map(|index| Value::Index(index as u64)),
        // The gap coupling was its decimal text before schema v6.
        (FigureType::Index, ValueRef::Text(text)) => std::str::from_utf8(text)
            .ok()
            .and_then(|text| text.trim().parse().ok())
            .map(Value::Index),
        (FigureType::Bool, ValueRef::Integer(v)) => Some(Value::Bool(v != 0)),
        (FigureType::Time, ValueRef::Text(text)) => std::str::from_utf8(text)
            .ok()
            .and_then(|text| UtcTime::parse(text).ok())
            .map(|time| Value::Time(time.unix_ms())),
        _ => None,
    }
}

/// Results whose figures the history keeps in a state row per subject: what a start
/// restores.
pub(crate) trait Kept: Subject + Clone {
    /// The state table.
    const STATE_TABLE: &'static str;
    /// Its key column: the subject's name.
    const KEY: &'static str;
    /// The state row's upsert ([`upsert_sql`]), built once: the writer runs it with
    /// every bite, and its text is the key of the connection's statement cache.
    fn upsert_sql() -> &'static str;
}

impl Kept for DrivelineResults {
    const STATE_TABLE: &'static str = "driveline_state";
    const KEY: &'static str = "driveline";
    fn upsert_sql() -> &'static str {
        static SQL: OnceLock<String> = OnceLock::new();
        SQL.get_or_init(upsert_sql::<Self>)
    }
}

impl Kept for TandemMillResults {
    const STATE_TABLE: &'static str = "mill_state";
    const KEY: &'static str = "mill";
    fn upsert_sql() -> &'static str {
        static SQL: OnceLock<String> = OnceLock::new();
        SQL.get_or_init(upsert_sql::<Self>)
    }
}

/// The figures of `R` with a state column, and the column.
fn state_columns<R: Kept>() -> impl Iterator<Item = (&'static Figure<R>, &'static str)> {
    R::FIGURES
        .iter()
        .filter_map(|figure| Some((figure, figure.columns.state?)))
}

/// The figures of a driveline with a bite column, and the column.
pub(crate) fn bite_columns(
) -> impl Iterator<Item = (&'static Figure<DrivelineResults>, &'static str)> {
    DrivelineResults::FIGURES
        .iter()
        .filter_map(|figure| Some((figure, figure.columns.bite?)))
}

/// The statement that writes a subject's state row: inserted, or its kept columns
/// replaced; the name and the time are `?1` and `?2`, the kept figures follow.
fn upsert_sql<R: Kept>() -> String {
    let columns: Vec<&str> = state_columns::<R>().map(|(_, column)| column).collect();
    let placeholders: Vec<String> = (3..3 + columns.len()).map(|i| format!("?{i}")).collect();
    let updates: Vec<String> = columns
        .iter()
        .map(|column| format!("{column} = excluded.{column}"))
        .collect();
    format!(
        "INSERT INTO {table} ({key}, updated_at, {columns}) VALUES (?1, ?2, {placeholders})
         ON CONFLICT ({key}) DO UPDATE SET updated_at = excluded.updated_at, {updates}",
        table = R::STATE_TABLE,
        key = R::KEY,
        columns = columns.join(", "),
        placeholders = placeholders.join(", "),
        updates = updates.join(", "),
    )
}

/// Write `results` as subject `name`'s state row at `time` (inserted, or its kept
/// columns replaced).
pub(crate) fn upsert_state<R: Kept>(
    transaction: &Transaction<'_>,
    name: &str,
    time: UtcTime,
    results: &R,
) -> rusqlite::Result<()> {
    let mut values = vec![
        SqlValue::Text(name.to_owned()),
        SqlValue::Text(time.to_string()),
    ];
    values.extend(state_columns::<R>().map(|(figure, _)| to_sql(figure.value(results))));
    transaction
        .prepare_cached(R::upsert_sql())?
        .execute(rusqlite::params_from_iter(values))?;
    Ok(())
}

/// One subject's state row as read back.
#[derive(Debug, Clone, PartialEq)]
pub struct StateRow<R> {
    /// The subject's name (matched against the configuration's).
    pub name: String,
    /// When the row was last written.
    pub updated_at: Option<UtcTime>,
    /// The kept figures set back, every other at its default.
    pub results: R,
}

/// Every state row of `R`'s table, by name, with each kept figure set back.
pub(crate) fn read_states<R: Kept>(connection: &Connection) -> rusqlite::Result<Vec<StateRow<R>>> {
    let sql = format!("{} ORDER BY {key}", select_states::<R>(), key = R::KEY);
    let mut statement = connection.prepare(&sql)?;
    let rows = statement.query_map([], state_row)?;
    rows.collect()
}

/// The state row of subject `name` in `R`'s table, with each kept figure set back
/// (`None` when it has none): one subject's [`read_states`], by the table's key.
pub(crate) fn read_state<R: Kept>(
    connection: &Connection,
    name: &str,
) -> rusqlite::Result<Option<StateRow<R>>> {
    let sql = format!("{} WHERE {key} = ?1", select_states::<R>(), key = R::KEY);
    let mut statement = connection.prepare_cached(&sql)?;
    let mut rows = statement.query_map([name], state_row)?;
    rows.next().transpose()
}

/// `SELECT` of `R`'s state rows: the key, `updated_at`, then the kept columns.
fn select_states<R: Kept>() -> String {
    let columns: Vec<&str> = state_columns::<R>().map(|(_, column)| column).collect();
    format!(
        "SELECT {key}, updated_at, {columns} FROM {table}",
        key = R::KEY,
        columns = columns.join(", "),
        table = R::STATE_TABLE,
    )
}

/// A row of [`select_states`] read back.
fn state_row<R: Kept>(row: &rusqlite::Row<'_>) -> rusqlite::Result<StateRow<R>> {
    let mut results = R::default();
    for (i, (figure, _)) in state_columns::<R>().enumerate() {
        figure.set(
            &mut results,
            from_sql(figure.figure_type, row.get_ref(2 + i)?),
        );
    }
    let updated_at: Option<String> = row.get(1)?;
    Ok(StateRow {
        name: row.get(0)?,
        updated_at: updated_at.and_then(|text| UtcTime::parse(&text).ok()),
        results,
    })
}

/// Copy the kept figures of `from` onto `to` (what a start restores of a subject whose
/// other figures are its own).
pub(crate) fn restore_onto<R: Kept>(from: &R, to: &mut R) {
    for (figure, _) in state_columns::<R>() {
        figure.set(to, figure.value(from));
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::state::catalogue::DRIVELINE;

    #[test]
    fn every_figure_type_reads_back_as_it_was_written() {
        let values = [
            (FigureType::Real, Value::Real(1.25)),
            (FigureType::Count, Value::Count(70_000)),
            (FigureType::Index, Value::Index(2)),
            (FigureType::Bool, Value::Bool(true)),
            (FigureType::Bool, Value::Bool(false)),
            (FigureType::Time, Value::Time(1_777_939_198_250)),
            (FigureType::State(&["off", "on"]), Value::Index(1)),
            (FigureType::Sequence, Value::Count(65_535)),
        ];
        for (figure_type, value) in values {
            let stored = to_sql(Some(value));
            let back = from_sql(figure_type, ValueRef::from(&stored));
            assert_eq!(back, Some(value), "{figure_type:?}");
        }
        assert_eq!(from_sql(FigureType::Real, ValueRef::Null), None);
        assert_eq!(
            from_sql(FigureType::Count, ValueRef::Integer(-1)),
            None,
            "a negative count is no count"
        );
        assert_eq!(
            from_sql(FigureType::Time, ValueRef::Text(b"yesterday")),
            None,
            "text that is no time is no time"
        );
        assert_eq!(
            from_sql(FigureType::State(&["off", "on"]), ValueRef::Integer(2)),
            None,
            "a state past the names is no state"
        );
    }

    /// A value of each figure of `R` that the history keeps, unlike its default, set
    /// in catalogue order (as a start sets them back).
    pub(crate) fn every_kept_figure_set<R: Subject>(kept: impl Fn(&Figure<R>) -> bool) -> R {
        let mut results = R::default();
        for (i, figure) in R::FIGURES.iter().filter(|f| kept(f)).enumerate() {
            let i = i as u64 + 1;
            let value = match figure.figure_type {
                FigureType::Real => Value::Real(0.25 + i as f64),
                FigureType::Count => Value::Count(40 + i),
                FigureType::Index => Value::Index(i),
                FigureType::Bool => Value::Bool(true),
                FigureType::Time => Value::Time(1_777_939_198_250 + i as i64),
                FigureType::State(names) => Value::Index(i % names.len() as u64),
                FigureType::Sequence => Value::Count(i),
            };
            assert!(figure.set(&mut results, Some(value)), "{}", figure.key);
        }
        results
    }

    #[test]
    fn a_state_row_restores_every_kept_figure() {
        let mut connection = Connection::open_in_memory().unwrap();
        super::super::schema::migrate(&mut connection).unwrap();
        let written: DrivelineResults = every_kept_figure_set(|f| f.columns.state.is_some());
        let transaction = connection.transaction().unwrap();
        upsert_state(&transaction, "F1", UtcTime::from_unix_ms(5), &written).unwrap();
        transaction.commit().unwrap();
        let rows = read_states::<DrivelineResults>(&connection).unwrap();
        assert_eq!(rows.len(), 1);
        assert_eq!(rows[0].name, "F1");
        assert_eq!(rows[0].updated_at, Some(UtcTime::from_unix_ms(5)));
        for figure in DRIVELINE.iter().filter(|f| f.columns.state.is_some()) {
            assert_eq!(
                figure.value(&rows[0].results),
                figure.value(&written),
                "{} is restored",
                figure.key
            );
            assert_ne!(
                figure.value(&written),
                figure.value(&DrivelineResults::default()),
                "{}: the test sets it",
                figure.key
            );
        }
        // A mill's too.
        let mill: TandemMillResults = every_kept_figure_set(|f| f.columns.state.is_some());
        let transaction = connection.transaction().unwrap();
        upsert_state(&transaction, "TCM", UtcTime::from_unix_ms(6), &mill).unwrap();
        transaction.commit().unwrap();
        let rows = read_states::<TandemMillResults>(&connection).unwrap();
        assert_eq!(rows[0].results, mill);
    }
}
