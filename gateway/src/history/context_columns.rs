//! The process context's columns as the history writes them: a bite's (schema v13,
//! [`CONTEXT_COLUMNS`]), and a capture's or chatter episode's with how far it can be
//! trusted (v14, [`evidence_context_columns`]).

use rusqlite::types::Value as SqlValue;

use super::bite_row::CONTEXT_COLUMNS;
use super::record::StoredCoil;
use crate::state::context::{Coil, ContextReading, ProcessContext};

/// A measured value, or `NULL`.
pub(super) fn real(value: Option<f64>) -> SqlValue {
    value.map_or(SqlValue::Null, SqlValue::Real)
}

/// The values of `context` in [`CONTEXT_COLUMNS`] order.
pub(super) fn context_values(context: &ProcessContext) -> [SqlValue; 6] {
    let code = |value: Option<u32>| value.map_or(SqlValue::Null, |v| SqlValue::Integer(v.into()));
    [
        real(context.speed_mpm),
        context.coil.map_or(SqlValue::Null, |coil| match coil {
            Coil::Number(number) => SqlValue::Integer(number.into()),
            Coil::Text(text) => StoredCoil::text_value(text.as_str()),
        }),
        code(context.product),
        real(context.thickness_mm),
        code(context.pass),
        context.state.map_or(SqlValue::Null, |state| {
            SqlValue::Text(state.name().to_owned())
        }),
    ]
}

/// The context columns of a capture or chatter episode (schema v14), comma-separated:
/// the context's values ([`CONTEXT_COLUMNS`]), then its status and why it is not
/// valid.
pub(super) fn evidence_context_columns() -> String {
    let status = ["context_status", "context_note"];
    CONTEXT_COLUMNS
        .into_iter()
        .chain(status)
        .collect::<Vec<_>>()
        .join(", ")
}

/// The values of `context` in [`evidence_context_columns`] order: only the values the
/// gateway trusts (none of an invalid context, no stale tag's); all `NULL` without
/// context tags.
pub(super) fn evidence_context_values(context: Option<&ContextReading>) -> Vec<SqlValue> {
    let values = context_values(&context.map(ContextReading::trusted).unwrap_or_default());
    let status = context.map_or(SqlValue::Null, |c| {
        SqlValue::Text(c.status().name().to_owned())
    });
    let note = context
        .and_then(ContextReading::note)
        .map_or(SqlValue::Null, SqlValue::Text);
    values.into_iter().chain([status, note]).collect()
}
