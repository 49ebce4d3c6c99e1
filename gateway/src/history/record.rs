//! What a row type of the history's tables is ([`Record`]): its table, columns and
//! filters, and its values as export cells ([`Cell`]).

use serde::Serialize;

/// One value of a row, for CSV and Markdown exports.
#[derive(Debug, Clone, PartialEq)]
pub enum Cell {
    /// No value (`NULL`).
    Null,
    /// An integer (counts, ids, booleans as 0/1).
    Integer(i64),
    /// A measured value.
    Real(f64),
    /// Text (names, times).
    Text(String),
}

impl std::fmt::Display for Cell {
    /// Empty for `Null`; reals as the shortest text that reads back to the same f64.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Cell::Null => Ok(()),
            Cell::Integer(value) => write!(f, "{value}"),
            Cell::Real(value) => write!(f, "{value}"),
            Cell::Text(text) => f.write_str(text),
        }
    }
}

/// A coil or bar id as the history keeps it in its `coil` column: an integer for a
/// numeric coil, text for a text coil (`type = "ascii"`; SQLite keeps TEXT in the
/// INTEGER-affinity column), and a BLOB of the text's bytes for a text coil that the
/// column's affinity would turn into a number. As JSON a number stays a number, a text
/// is a string.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, serde::Deserialize)]
#[serde(untagged)]
pub enum StoredCoil {
    /// A whole number.
    Number(i64),
    /// A text.
    Text(String),
}

impl std::fmt::Display for StoredCoil {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            StoredCoil::Number(number) => write!(f, "{number}"),
            StoredCoil::Text(text) => f.write_str(text),
        }
    }
}

impl StoredCoil {
    /// The value a text coil is stored as: TEXT, or, for a text SQLite would take for a
    /// number ([`numeric_looking`]), a BLOB of its bytes, which the column's INTEGER
    /// affinity leaves as it is (TEXT `'04711'` would be stored as the integer 4711,
    /// `'24E0123'` as the real 2.4e124).
    pub(crate) fn text_value(text: &str) -> rusqlite::types::Value {
        if numeric_looking(text) {
            rusqlite::types::Value::Blob(text.as_bytes().to_vec())
        } else {
            rusqlite::types::Value::Text(text.to_owned())
        }
    }
}

/// Whether SQLite's INTEGER (or NUMERIC) affinity could store `text` as a number: a
/// well-formed integer or real literal, with white space around it (`"04711"`,
/// `" 42"`, `"12.5"`, `"24E0123"`, `"1e400"`). A superset of SQLite's rule (any text
/// of digits, signs, points and exponent letters with a digit among them), so that no
/// such text is turned into a number; a text it takes in that SQLite would have kept
/// is stored as a BLOB all the same and reads back alike.
fn numeric_looking(text: &str) -> bool {
    let core = text.trim_matches(|c: char| c == ' ' || ('\t'..='\r').contains(&c));
    core.bytes().any(|b| b.is_ascii_digit())
        && core
            .bytes()
            .all(|b| b.is_ascii_digit() || matches!(b, b'+' | b'-' | b'.' | b'e' | b'E'))
}

impl rusqlite::types::FromSql for StoredCoil {
    fn column_result(value: rusqlite::types::ValueRef<'_>) -> rusqlite::types::FromSqlResult<Self> {
        match value {
            rusqlite::types::ValueRef::Integer(number) => Ok(StoredCoil::Number(number)),
            rusqlite::types::ValueRef::Text(_) => {
                String::column_result(value).map(StoredCoil::Text)
            }
            // A text coil SQLite would have taken for a number ([`StoredCoil::text_value`]).
            rusqlite::types::ValueRef::Blob(bytes) => std::str::from_utf8(bytes)
                .map(|text| StoredCoil::Text(text.to_owned()))
                .map_err(|error| rusqlite::types::FromSqlError::Other(Box::new(error))),
            // A text coil written before the BLOB, which SQLite stored as a real
            // ('12.5', '24E0123'): its digits are what SQLite kept, read rather than
            // refused (an error here made every query of its row fail).
            rusqlite::types::ValueRef::Real(real) => Ok(StoredCoil::Text(if real.abs() < 1e16 {
                real.to_string()
            } else {
                format!("{real:e}")
            })),
            rusqlite::types::ValueRef::Null => Err(rusqlite::types::FromSqlError::InvalidType),
        }
    }
}

impl ToCell for StoredCoil {
    fn to_cell(&self) -> Cell {
        match self {
            StoredCoil::Number(number) => Cell::Integer(*number),
            StoredCoil::Text(text) => Cell::Text(text.clone()),
        }
    }
}

/// Conversion of a row field to a [`Cell`].
pub(crate) trait ToCell {
    /// The cell.
    fn to_cell(&self) -> Cell;
}

impl ToCell for i64 {
    fn to_cell(&self) -> Cell {
        Cell::Integer(*self)
    }
}

impl ToCell for f64 {
    fn to_cell(&self) -> Cell {
        Cell::Real(*self)
    }
}

impl ToCell for bool {
    fn to_cell(&self) -> Cell {
        Cell::Integer(i64::from(*self))
    }
}

impl ToCell for String {
    fn to_cell(&self) -> Cell {
        Cell::Text(self.clone())
    }
}

impl<T: ToCell> ToCell for Option<T> {
    fn to_cell(&self) -> Cell {
        self.as_ref().map_or(Cell::Null, ToCell::to_cell)
    }
}

/// A row type of one table.
pub trait Record: Sized + Serialize {
    /// The table.
    const TABLE: &'static str;
    /// The columns read, in order (the struct's fields).
    fn columns() -> &'static [&'static str];
    /// The column [`Filter::name`](super::query::Filter::name) matches.
    const NAME_COLUMN: &'static str;
    /// The column [`Filter::since`](super::query::Filter::since) and [`Filter::until`](super::query::Filter::until) compare.
    const TIME_COLUMN: &'static str;
    /// The column [`Filter::product`](super::query::Filter::product) matches; `None`:
    /// the table has no product (a product filter leaves no row).
    const PRODUCT_COLUMN: Option<&'static str> = None;
    /// The row from a result row of [`Self::columns`].
    fn from_row(row: &rusqlite::Row<'_>) -> rusqlite::Result<Self>;
    /// The values, in [`Self::columns`] order.
    fn cells(&self) -> Vec<Cell>;
}
