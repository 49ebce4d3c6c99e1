//! The process context's columns as the history writes them: a bite's (schema v13,
//! [`CONTEXT_COLUMNS`]), and a capture's or chatter episode's with how far it can be
//! trusted (v14, [`EVIDENCE_CONTEXT_COLUMNS`]).

use rusqlite::types::Value as SqlValue;

use super::bite_row::CONTEXT_COLUMNS;
use crate::state::context::{ContextReading, ProcessContext};

/// A measured value, or `NULL`.
pub(super) fn real(value: Option<f64>) -> SqlValue {
    value.map_or(SqlValue::Null, SqlValue::Real)
}

/// The values of `context` in [`CONTEXT_COLUMNS`] order.
pub(super) fn context_values(context: &ProcessContext) -> [SqlValue; 6] {
    let code = |value: Option<u32>| value.map_or(SqlValue::Null, |v| SqlValue::Integer(v.into()));
    [
        real(context.speed_mpm),
        code(context.coil),
        code(context.product),
        real(context.thickness_mm),
        code(context.pass),
        context.state.map_or(SqlValue::Null, |state| {
            SqlValue::Text(state.name().to_owned())
        }),
    ]
}

/// The context columns of a capture or chatter episode (schema v14): the context's
/// values, then its status and why it is not valid.
pub(super) const EVIDENCE_CONTEXT_COLUMNS: [&str; 8] = [
    CONTEXT_COLUMNS[0],
    CONTEXT_COLUMNS[1],
    CONTEXT_COLUMNS[2],
    CONTEXT_COLUMNS[3],
    CONTEXT_COLUMNS[4],
    CONTEXT_COLUMNS[5],
    "context_status",
    "context_note",
];

/// The values of `context` in [`EVIDENCE_CONTEXT_COLUMNS`] order: only the values the
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
