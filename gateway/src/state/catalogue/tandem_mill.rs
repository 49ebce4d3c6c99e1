//! A tandem mill's chatter figures, of its last window.

use millgate_config::ValueType::{F32, U16};

use super::declare::{at, index_of, real_of, to_flag, unmapped, unmapped_counter};
use super::{AlarmKind, Figure, TandemMillResults};
use super::{Columns, FigureType, Stale, Value};

/// The table's figure type.
type F = Figure<TandemMillResults>;

/// A tandem mill's chatter figures, of its last window.
pub const TANDEM_MILL: &[Figure<TandemMillResults>] = &[
    F::count(
        "evaluations",
        unmapped_counter("a count of windows the PLC does not act on (the heartbeat shows the gateway alive); no free register in the block"),
        "Chatter windows evaluated since start",
        |m| Some(Value::Count(m.evaluations)),
    ),
    F::count(
        "weld_held_off",
        unmapped_counter("a count of gating decisions for the crew and the history of the slow-down request; the PLC has the weld bit itself"),
        "Windows whose alarm and slow-down request the weld hold kept off since start (gain ratio >= 1 but below weld_alarm_factor while a weld was in the mill or for weld_settle_s after)",
        |m| Some(Value::Count(m.weld_held_off)),
    ),
    F::count(
        "context_invalid",
        unmapped_counter("a count of the PLC's own bad context values, for the crew; the PLC knows its values"),
        "Context values from the PLC read with an impossible value since start (weld not 0/1, a product that is not a known code): not used for the gating",
        |m| Some(Value::Count(m.context_invalid)),
    ),
    F::count(
        "window_restarts_gap",
        unmapped_counter("a count of restarts for the crew and plant IT; the PLC has source_stale"),
        "Chatter windows restarted since start because samples were lost on a stand (the DAQ's blocks missed, a restart of its sequence, a gap in a CAN stream)",
        |m| Some(Value::Count(m.window_restarts_gap)),
    ),
    F::count(
        "window_restarts_lagging",
        unmapped_counter("a count of restarts for the crew and plant IT; the PLC has source_stale"),
        "Chatter windows restarted since start because a stand fell more than 0.5 s behind the others (its source stopped delivering)",
        |m| Some(Value::Count(m.window_restarts_lagging)),
    ),
    F::count(
        "window_restarts_realigned",
        unmapped_counter("a count of restarts for the crew and plant IT; the PLC has source_stale"),
        "Chatter windows restarted since start because a stand moved on the mill's common sample axis (re-anchored against the arrival times: a first block one newer than the other stands', after a gap of unknown length, or reads that jitter by half a block)",
        |m| Some(Value::Count(m.window_restarts_realigned)),
    ),
    F::real(
            "thresholds_group",
            "",
            unmapped("a mark for the crew and the history of the thresholds in use; the PLC has the product itself"),
            Stale::Kept,
            "The thresholds that judged the last window: 0 the mill's gain_thresholds (no product group, or no valid fresh product), k the product_groups[k-1]'s (the product the PLC reported)",
            |m| index_of(m.thresholds_group),
        )
    .typed(FigureType::Index),
    F::count(
        "product_fallback",
        unmapped_counter("a count of gating decisions for the crew; the PLC knows its product values"),
        "Windows judged by the mill's gain_thresholds since start because the product context was missing, invalid or stale while the mill has product_groups",
        |m| Some(Value::Count(m.product_fallback)),
    ),
    F::real(
        "sigma_n_hz",
        "Hz",
        at(2, F32, 0),
        Stale::Withdrawn,
        "RMS deviation of the adjacent stands' principal chatter-band frequencies",
        |m| real_of(m.sigma_n_hz),
    ),
    F::real(
            "k_mean",
            "",
            at(4, F32, 1),
            Stale::Withdrawn,
            "Mean correlation of adjacent stands' chatter-band vibration over the window",
            |m| real_of(m.k_mean),
        )
    .range(-1.0, 1.0),
    F::real(
        "chatter_frequency_hz",
        "Hz",
        at(6, F32, 2),
        Stale::Withdrawn,
        "Mean principal frequency of the stands in the chatter band",
        |m| real_of(m.chatter_frequency_hz),
    ),
    F::real(
        "chatter_gain",
        "",
        at(8, F32, 3),
        Stale::Withdrawn,
        "Largest chatter-band gain of any stand: chatter-band RMS / reference-band RMS over gain_window_s",
        |m| real_of(m.chatter_gain),
    ),
    F::real(
        "gain_ratio",
        "",
        at(10, F32, 4),
        Stale::Withdrawn,
        "Largest gain / gain_thresholds[stand] of any stand: the early-warning figure, >= 1 is the band-gain alarm",
        |m| real_of(m.gain_ratio),
    ),
    F::real(
        "band_rms_max",
        "",
        at(12, F32, 5),
        Stale::Withdrawn,
        "Largest chatter-band RMS of any stand over gain_window_s, in the stand channels' unit",
        |m| real_of(m.band_rms_max),
    ),
    F::real(
            "worst_stand",
            "",
            at(14, U16, 6),
            Stale::Withdrawn,
            "Stand of gain_ratio, 1-based in the mill's stands order",
            |m| index_of(m.worst_stand.map(|stand| stand + 1)),
        )
    .typed(FigureType::Index),
    F::flag(
        "chatter_warning",
        0,
        Stale::Kept,
        Some(AlarmKind::ChatterWarning),
        "The configured detector's warning in the last window (band gain: gain_ratio >= slow_down_release; paper: sigma_n <= sigma_min)",
        |m| Some(Value::Bool(m.chatter_warning)),
    ),
    F::flag(
        "chatter_alarm",
        1,
        Stale::Kept,
        Some(AlarmKind::ChatterAlarm),
        "The configured detector's alarm held in a window (band gain: gain_ratio >= 1; paper: both conditions); latched until acknowledged",
        |m| Some(Value::Bool(m.chatter_alarm)),
    )
    .latched()
    .kept(Columns::state("alarm_latched"), |m, v| {
        m.chatter_alarm = to_flag(v)
    }),
    F::flag(
        "source_stale",
        2,
        Stale::Kept,
        None,
        "A stand's source is stale or lost, or the window restarted after a gap: the window's figures are withdrawn",
        |m| Some(Value::Bool(m.source_stale)),
    ),
    F::flag(
        "slow_down_request",
        3,
        Stale::Kept,
        Some(AlarmKind::SlowDownRequest),
        "Slow-down request to the PLC, with hysteresis (set by the alarm condition, cleared after slow_down_hold_s below slow_down_release; held while stale): the PLC decides the speed drop",
        |m| Some(Value::Bool(m.slow_down_request)),
    ),
];
