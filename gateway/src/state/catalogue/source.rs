//! A field source's figures: its status and the status as flags, each flag a bit of a
//! global register by the source's index (`sources_ok`, `sources_stale`,
//! `sources_lost`).

use super::declare::{index_bit, unmapped};
use super::{Figure, SourceResults, Stale, Value};
use crate::field::source_health::SourceStatus;

/// The table's figure type.
type F = Figure<SourceResults>;

/// A source's statuses, by value ([`SourceStatus::code`]).
const STATUSES: &[&str] = &["ok", "stale", "lost"];

/// Whether `results` has a status and it is `status`; no value before the first.
fn is(results: &SourceResults, status: SourceStatus) -> Option<Value> {
    results.status.map(|s| Value::Bool(s == status))
}

/// A field source's figures, one source per configured source in config order
/// (Modbus, then CAN).
pub const SOURCE: &[Figure<SourceResults>] = &[
    F::state(
        "status",
        STATUSES,
        unmapped("the register map carries it as the source's bit of sources_ok, sources_stale and sources_lost"),
        "The source's status: ok (connected and answering), stale (no good answer for longer than its stale time), lost (never answered, or silent past its lost time); none before the first",
        |s| s.status.map(|status| Value::Index(u64::from(status.code()))),
    ),
    F::flag_at(
        "ok",
        index_bit(2),
        Stale::Kept,
        "The source answers: connected, with a good answer within its stale time",
        |s| is(s, SourceStatus::Ok),
    ),
    F::flag_at(
        "stale",
        index_bit(3),
        Stale::Kept,
        "The source has not answered for longer than its stale time",
        |s| is(s, SourceStatus::Stale),
    ),
    F::flag_at(
        "lost",
        index_bit(4),
        Stale::Kept,
        "The source is lost (never answered, or silent past its lost time)",
        |s| is(s, SourceStatus::Lost),
    ),
];

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_status_names_are_the_sources_by_code() {
        for status in [SourceStatus::Ok, SourceStatus::Stale, SourceStatus::Lost] {
            assert_eq!(STATUSES[usize::from(status.code())], status.name());
        }
    }
}
