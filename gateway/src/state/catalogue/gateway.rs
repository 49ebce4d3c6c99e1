//! The gateway's own figures: its state, its heartbeat and whether every source
//! answers, in the global registers (the heartbeat, `gateway_status`).

use millgate_config::ValueType::U16;

use super::declare::{always_at, unmapped};
use super::{Figure, FigureType, GatewayResults, Stale, Value};
use crate::state::results::GatewayState;

/// The table's figure type.
type F = Figure<GatewayResults>;

/// The gateway's states, by value.
const STATES: &[&str] = &["starting", "running", "stopped"];

/// The gateway's own figures.
pub const GATEWAY: &[Figure<GatewayResults>] = &[
    F::state(
        "state",
        STATES,
        unmapped("the register map carries it as gateway_status' running and stopped bits"),
        "The gateway's state: starting (built, its tasks not started yet), running (readers, analysis and outputs running), stopped (an orderly stop: every other value, source bits and flags included, keeps its last running value and will not change)",
        |g| {
            Some(Value::Index(match g.state {
                GatewayState::Starting => 0,
                GatewayState::Running => 1,
                GatewayState::Stopped => 2,
            }))
        },
    ),
    // A sequence, not a count: a gauge on /metrics (under its first name), UInt32 on
    // OPC UA; it wraps at 65535.
    F::count(
        "heartbeat",
        always_at(0, U16),
        "Incremented every PLC write period (every second without a PLC output), whether or not the PLC answers, wrapping at 65535; a PLC or HMI watchdog checks it moves",
        |g| Some(Value::Count(u64::from(g.heartbeat))),
    )
    .typed(FigureType::Sequence)
    .metric("millgate_heartbeat"),
    F::flag_at(
        "sources_ok",
        unmapped("the negation of gateway_status' source_problem bit; each source's is a bit of sources_ok"),
        Stale::Kept,
        "Every source answers (true without sources)",
        |g| Some(Value::Bool(g.sources_ok)),
    ),
    F::flag(
        "running",
        0,
        Stale::Kept,
        None,
        "The gateway is running and publishing fresh results",
        |g| Some(Value::Bool(g.state == GatewayState::Running)),
    ),
    F::flag(
        "stopped",
        1,
        Stale::Kept,
        None,
        "The gateway has stopped in order: every other value, source bits and flags included, keeps its last running value and will not change",
        |g| Some(Value::Bool(g.state == GatewayState::Stopped)),
    ),
    F::flag(
        "source_problem",
        2,
        Stale::Kept,
        None,
        "A source is stale or lost (not ok)",
        |g| Some(Value::Bool(!g.sources_ok)),
    ),
];
