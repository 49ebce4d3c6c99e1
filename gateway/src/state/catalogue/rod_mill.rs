//! A rod mill's figures (its operating point and its worst span) and a rod span's.

use millgate_config::ValueType::{F32, U16};

use super::declare::{at, real_of, unmapped, unmapped_counter};
use super::{AlarmKind, Figure, RodMillResults, RodSpanResults};
use super::{FigureType, Stale, Value};

/// The rod mill table's figure type.
type Mill = Figure<RodMillResults>;
/// The rod span table's figure type.
type Span = Figure<RodSpanResults>;

fn rod_value(mill: &RodMillResults, value: Option<Value>) -> Option<Value> {
    value.filter(|_| mill.valid())
}

/// A rod mill's own figures: its operating point and its worst span.
pub const ROD_MILL: &[Figure<RodMillResults>] = &[
    Mill::count(
        "evaluations",
        unmapped_counter("a count of evaluations the PLC does not act on; no free register in the block"),
        "Evaluations since start (one per change of the inputs)",
        |r| Some(Value::Count(r.evaluations)),
    ),
    Mill::real(
        "configuration",
        "",
        at(2, U16, 0),
        Stale::Withdrawn,
        "Drive configuration in use: the PLC's value, an index into the rod mill's configurations",
        |r| rod_value(r, r.configuration.map(|c| Value::Index(u64::from(c)))),
    )
    .typed(FigureType::Index),
    Mill::real(
        "pass",
        "",
        at(3, U16, 1),
        Stale::Withdrawn,
        "Pass in use: the PLC's pass number (1-based row of the schedule)",
        |r| rod_value(r, r.pass.map(|p| Value::Index(u64::from(p)))),
    )
    .typed(FigureType::Index),
    Mill::real(
        "finishing_speed_m_s",
        "m/s",
        at(4, F32, 2),
        Stale::Withdrawn,
        "Finishing speed the spans were evaluated at",
        |r| rod_value(r, real_of(r.finishing_speed_m_s)),
    ),
    Mill::real(
        "rod_temperature_c",
        "degC",
        at(6, F32, 3),
        Stale::Withdrawn,
        "Rod temperature of the pass setup in use (rounded to temperature_step_c, or the schedule's)",
        |r| rod_value(r, real_of(r.temperature_c)),
    ),
    Mill::real(
        "worst_margin_m_s",
        "m/s",
        unmapped("the smallest speed_margin_m_s of the span blocks; no free register in the block"),
        Stale::Withdrawn,
        "The smallest finishing-speed margin of the valid spans (negative: a span is unstable)",
        |r| r.worst_span().map(|(_, margin)| Value::Real(margin)),
    ),
    Mill::real(
        "worst_span",
        "",
        unmapped("the span of the smallest speed_margin_m_s of the span blocks; no free register in the block"),
        Stale::Withdrawn,
        "Span of worst_margin_m_s, 1-based in rolling order",
        |r| r.worst_span().map(|(span, _)| Value::Index(span as u64 + 1)),
    )
    .typed(FigureType::Index),
    Mill::flag(
        "unstable",
        0,
        Stale::Withdrawn,
        Some(AlarmKind::Unstable),
        "A span is unstable (with hysteresis)",
        |r| rod_value(r, Some(Value::Bool(r.spans.iter().any(|s| s.unstable)))),
    ),
    Mill::flag(
        "near_tongue",
        1,
        Stale::Withdrawn,
        Some(AlarmKind::NearTongue),
        "A span is stable but near a tongue (speed margin < near_tongue_m_s, with hysteresis)",
        |r| rod_value(r, Some(Value::Bool(r.spans.iter().any(|s| s.near_tongue)))),
    ),
    Mill::flag(
        "invalid",
        2,
        Stale::Kept,
        None,
        "No valid result: not evaluated yet, an input's source stale or lost, or an input out of range",
        |r| Some(Value::Bool(!r.valid())),
    ),
    Mill::flag(
        "input_refused",
        3,
        Stale::Kept,
        None,
        "The last inputs were refused (configuration, pass, speed or temperature out of range)",
        |r| Some(Value::Bool(r.input_refused)),
    ),
    Mill::flag(
        "source_stale",
        4,
        Stale::Kept,
        None,
        "An input's source is stale or lost: the figures of the mill are withdrawn",
        |r| Some(Value::Bool(r.source_stale)),
    ),
];

/// A rod span's figures (span `i`, stands `i` and `i + 1` in rolling order), read from
/// [`RodMillResults::published_span`].
pub const ROD_SPAN: &[Figure<RodSpanResults>] = &[
    Span::real(
        "speed_margin_m_s",
        "m/s",
        at(2, F32, 0),
        Stale::Withdrawn,
        "Finishing-speed change to the nearest unstable band edge: > 0 stable, < 0 unstable (the change that stabilises it); none when no band lies in the speed range",
        |s| real_of(s.speed_margin_m_s),
    ),
    Span::real(
        "worst_exponent_per_s",
        "1/s",
        at(4, F32, 1),
        Stale::Withdrawn,
        "Largest growth exponent of the span's points (< 0 decaying)",
        |s| real_of(s.worst_exponent_per_s),
    ),
    Span::real(
        "configuration",
        "",
        at(6, U16, 2),
        Stale::Withdrawn,
        "Drive configuration the span was evaluated in (index into the rod mill's configurations)",
        |s| s.configuration.map(|c| Value::Index(u64::from(c))),
    )
    .typed(FigureType::Index),
    Span::flag(
        "unstable",
        0,
        Stale::Withdrawn,
        None,
        "The span is unstable (with hysteresis)",
        |s| s.valid.then_some(Value::Bool(s.unstable)),
    ),
    Span::flag(
        "near_tongue",
        1,
        Stale::Withdrawn,
        None,
        "The span is stable but near a tongue (speed margin < near_tongue_m_s, with hysteresis)",
        |s| s.valid.then_some(Value::Bool(s.near_tongue)),
    ),
    Span::flag(
        "invalid",
        2,
        Stale::Kept,
        None,
        "No valid result for the span: its mill is invalid, or the mill file has fewer spans",
        |s| Some(Value::Bool(!s.valid)),
    ),
];
