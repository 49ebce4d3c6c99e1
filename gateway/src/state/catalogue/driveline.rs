//! A driveline's figures: its last bite's and the gap diagnosis'.

use millgate_config::ValueType::{F32, U16, U32};

use super::declare::{
    at, counter_at, ext, index_of, real_of, to_count, to_flag, to_index, to_real, to_time,
    unmapped, unmapped_counter,
};
use super::{AlarmKind, DrivelineResults, Figure};
use super::{Columns, FigureType, Stale, Value};
use crate::state::context::BiteGate;
use crate::state::results::{FatigueFigures, ForecastState, GapForecast, GapGrowth, GapResults};

/// The table's figure type.
type F = Figure<DrivelineResults>;

/// A driveline's figures: its last bite's and the gap diagnosis'.
pub const DRIVELINE: &[Figure<DrivelineResults>] = &[
    // Prometheus refuses a type in a name (`_counter_total`).
    F::count(
        "bite_counter",
        counter_at(2, U32),
        "Bites analysed since start (continued across restarts with a history)",
        |d| Some(Value::Count(u64::from(d.bite_counter))),
    )
    .metric("millgate_driveline_bites_total")
    .kept(Columns::both("bite_counter"), |d, v| {
        d.bite_counter = u32::try_from(to_count(v)).unwrap_or(u32::MAX)
    }),
    F::count(
        "degraded_bites",
        counter_at(30, U32),
        "Of those, degraded bites: a gap, saturated or non-finite samples in the window (their values are not published)",
        |d| Some(Value::Count(u64::from(d.degraded_bites))),
    ),
    F::real(
        "last_bite_time",
        "",
        at(4, U32, 0),
        Stale::LastUsable,
        "Time of the last bite",
        |d| d.last_bite_unix_ms.map(Value::Time),
    )
    .typed(FigureType::Time)
    .kept(
        Columns {
            bite: Some("time"),
            state: Some("last_bite_time"),
        },
        |d, v| d.last_bite_unix_ms = to_time(v),
    ),
    F::real(
        "static_torque_knm",
        "kN*m",
        at(6, F32, 1),
        Stale::LastUsable,
        "Static (settled) rolling torque of the last bite",
        |d| real_of(d.static_torque_knm),
    )
    .measured_on_window()
    .kept(Columns::both("static_torque_knm"), |d, v| {
        d.static_torque_knm = to_real(v)
    }),
    F::real(
        "peak_torque_knm",
        "kN*m",
        at(8, F32, 2),
        Stale::LastUsable,
        "Peak torque of the last bite",
        |d| real_of(d.peak_torque_knm),
    )
    .measured_on_window()
    .kept(Columns::both("peak_torque_knm"), |d, v| {
        d.peak_torque_knm = to_real(v)
    }),
    F::real(
        "taf",
        "",
        at(10, F32, 3),
        Stale::LastUsable,
        "Torque amplification factor of the last bite (peak / static)",
        |d| real_of(d.taf),
    )
    .measured_on_window()
    .kept(Columns::both("taf"), |d, v| d.taf = to_real(v)),
    F::real(
        "period_shift_s",
        "s",
        at(12, F32, 4),
        Stale::LastUsable,
        "First minus second oscillation period of the last bite",
        |d| real_of(d.first_period_shift_s),
    )
    .measured_on_window()
    .kept(Columns::both("period_shift_s"), |d, v| {
        d.first_period_shift_s = to_real(v)
    }),
    F::real(
        "first_period_s",
        "s",
        ext(2, F32, 0),
        Stale::LastUsable,
        "First oscillation period after the last bite's onset (the paper's T1: it grows with the opened gap)",
        |d| real_of(d.first_period_s),
    )
    .measured_on_window()
    .kept(Columns::both("first_period_s"), |d, v| {
        d.first_period_s = to_real(v)
    }),
    F::real(
        "beta1_hz",
        "Hz",
        at(14, F32, 5),
        Stale::LastUsable,
        "First natural frequency identified from the last bite (eq. (1) fit)",
        |d| real_of(d.beta1_hz),
    )
    .measured_on_window()
    .kept(Columns::both("beta1_hz"), |d, v| d.beta1_hz = to_real(v)),
    F::real(
        "beta2_hz",
        "Hz",
        at(16, F32, 6),
        Stale::LastUsable,
        "Second natural frequency identified from the last bite (eq. (1) fit)",
        |d| real_of(d.beta2_hz),
    )
    .measured_on_window()
    .kept(Columns::both("beta2_hz"), |d, v| d.beta2_hz = to_real(v)),
    F::real(
        "first_mode_damping",
        "",
        ext(5, F32, 2),
        Stale::LastUsable,
        "Damping ratio of the first mode identified from the last bite (eq. (1) fit: decay / sqrt(decay^2 + (2 pi beta1)^2)), given with beta1_hz",
        |d| real_of(d.first_mode_damping),
    )
    .measured_on_window()
    .kept(Columns::both("first_mode_damping"), |d, v| {
        d.first_mode_damping = to_real(v)
    }),
    F::real(
        "wear_index",
        "",
        at(18, F32, 7),
        Stale::LastUsable,
        "Secondary figure: TAF-ratio wear index of the last bite, its TAF / the linear model's TAF - 1 (needs the driveline model)",
        |d| real_of(d.wear_index),
    )
    .measured_on_window()
    .kept(Columns::both("wear_index"), |d, v| d.wear_index = to_real(v)),
    F::real(
        "wear_trend",
        "",
        at(20, F32, 8),
        Stale::LastUsable,
        "Secondary figure: mean of the TAF-ratio wear index over bites (EWMA, weight 0.1) since start or the last wear reset",
        |d| real_of(d.wear_trend),
    )
    .kept(Columns::both("wear_trend"), |d, v| d.wear_trend = to_real(v)),
    // The gap's figures are set back in this order: the estimate, then what fills it.
    F::real(
        "gap_mrad",
        "mrad",
        at(22, F32, 9),
        Stale::LastUsable,
        "Opened gap (total dead-zone width, referred to the rolls) at the last bite, from the wear trend of the bites since the last wear reset (needs the driveline model)",
        |d| real_of(d.gap.map(|g| g.gap_mrad)),
    )
    .kept(Columns::both("gap_mrad"), |d, v| {
        d.gap = to_real(v).map(|gap_mrad| GapResults {
            gap_mrad,
            low_mrad: gap_mrad,
            high_mrad: gap_mrad,
            coupling: None,
            likeliest_coupling: None,
            bites_pooled: 0,
            growth: None,
            forecast: None,
        })
    }),
    F::real(
        "gap_low_mrad",
        "mrad",
        at(24, F32, 10),
        Stale::LastUsable,
        "Lower end of the gap's 90% interval",
        |d| real_of(d.gap.map(|g| g.low_mrad)),
    )
    .kept(Columns::both("gap_low_mrad"), |d, v| {
        if let (Some(gap), Some(low)) = (d.gap.as_mut(), to_real(v)) {
            gap.low_mrad = low;
        }
    }),
    F::real(
        "gap_high_mrad",
        "mrad",
        at(26, F32, 11),
        Stale::LastUsable,
        "Upper end of the gap's 90% interval",
        |d| real_of(d.gap.map(|g| g.high_mrad)),
    )
    .kept(Columns::both("gap_high_mrad"), |d, v| {
        if let (Some(gap), Some(high)) = (d.gap.as_mut(), to_real(v)) {
            gap.high_mrad = high;
        }
    }),
    F::real(
        "gap_coupling",
        "",
        at(28, U16, 12),
        Stale::LastUsable,
        "Coupling holding the gap (model index, 0 = motor side); no value while the bites cannot tell the couplings apart (gap_mrad is valid then)",
        |d| index_of(d.gap.and_then(|g| g.coupling)),
    )
    .typed(FigureType::Index)
    .kept(Columns::both("gap_coupling"), |d, v| {
        if let Some(gap) = d.gap.as_mut() {
            gap.coupling = to_index(v);
        }
    }),
    F::real(
        "likeliest_coupling",
        "",
        ext(4, U16, 1),
        Stale::LastUsable,
        "The likeliest coupling to hold the gap (model index), named whether or not the bites tell the couplings apart",
        |d| index_of(d.gap.and_then(|g| g.likeliest_coupling)),
    )
    .typed(FigureType::Index),
    F::real(
        "bites_pooled",
        "",
        at(29, U16, 13),
        Stale::LastUsable,
        "Bites in the gap's wear trend since the last wear reset (the name is from when the estimate pooled the last bites)",
        |d| d.gap.map(|g| Value::Count(g.bites_pooled as u64)),
    )
    .typed(FigureType::Count)
    .kept(Columns::both("bites_pooled"), |d, v| {
        if let Some(gap) = d.gap.as_mut() {
            gap.bites_pooled = usize::try_from(to_count(v)).unwrap_or(usize::MAX);
        }
    }),
    F::real(
        "gap_growth_mrad_per_day",
        "mrad/d",
        ext(7, F32, 3),
        Stale::LastUsable,
        "Growth of the gap (the wear trend's rate since the last wear reset), mrad per calendar day",
        |d| real_of(growth(d).map(|g| g.mrad_per_day)),
    )
    .kept(Columns::both("gap_growth_mrad_per_day"), |d, v| {
        if let (Some(gap), Some(rate)) = (d.gap.as_mut(), to_real(v)) {
            gap.growth = Some(GapGrowth {
                mrad_per_day: rate,
                low_mrad_per_day: rate,
                high_mrad_per_day: rate,
            });
        }
    }),
    F::real(
        "gap_growth_low_mrad_per_day",
        "mrad/d",
        ext(9, F32, 4),
        Stale::LastUsable,
        "Lower end of the growth's 90% interval",
        |d| real_of(growth(d).map(|g| g.low_mrad_per_day)),
    )
    .kept(Columns::both("gap_growth_low_mrad_per_day"), |d, v| {
        if let (Some(growth), Some(low)) = (growth_mut(d), to_real(v)) {
            growth.low_mrad_per_day = low;
        }
    }),
    F::real(
        "gap_growth_high_mrad_per_day",
        "mrad/d",
        ext(11, F32, 5),
        Stale::LastUsable,
        "Upper end of the growth's 90% interval",
        |d| real_of(growth(d).map(|g| g.high_mrad_per_day)),
    )
    .kept(Columns::both("gap_growth_high_mrad_per_day"), |d, v| {
        if let (Some(growth), Some(high)) = (growth_mut(d), to_real(v)) {
            growth.high_mrad_per_day = high;
        }
    }),
    F::state(
        "gap_forecast",
        ForecastState::NAMES,
        ext(21, U16, 10),
        "What the gap forecast says: forecast (days_to_gap_alarm given), at_alarm (the gap is at thresholds.gap_alarm_mrad), not_growing (the growth's interval holds 0), beyond_horizon (growing, the crossing beyond drivelines[].wear.horizon_days), too_few_bites (fewer than 5 bites since the last wear reset, or under 7 days of them while the growth is not 3 standard deviations clear of 0)",
        |d| forecast(d).map(|f| Value::Index(f.state as u64)),
    )
    .kept(Columns::both("gap_forecast"), |d, v| {
        if let (Some(gap), Some(state)) = (d.gap.as_mut(), to_index(v)) {
            gap.forecast = ForecastState::ALL.get(state).map(|&state| GapForecast {
                state,
                days: None,
                days_low: None,
                days_high: None,
                date_unix_ms: None,
                cone: None,
            });
        }
    }),
    F::real(
        "days_to_gap_alarm",
        "d",
        ext(13, F32, 6),
        Stale::LastUsable,
        "Calendar days from the last bite until the gap reaches thresholds.gap_alarm_mrad (the wear trend's point forecast); no value when no crossing is expected within the horizon (gap_forecast says why)",
        |d| real_of(forecast(d).and_then(|f| f.days)),
    )
    .kept(Columns::both("days_to_gap_alarm"), |d, v| {
        if let Some(forecast) = forecast_mut(d) {
            forecast.days = to_real(v);
        }
    }),
    F::real(
        "days_to_gap_alarm_low",
        "d",
        ext(15, F32, 7),
        Stale::LastUsable,
        "Early end of the 90% interval of days_to_gap_alarm (given also when the growth is not certain, if the gap may reach the alarm within the horizon)",
        |d| real_of(forecast(d).and_then(|f| f.days_low)),
    )
    .kept(Columns::both("days_to_gap_alarm_low"), |d, v| {
        if let Some(forecast) = forecast_mut(d) {
            forecast.days_low = to_real(v);
        }
    }),
    F::real(
        "days_to_gap_alarm_high",
        "d",
        ext(17, F32, 8),
        Stale::LastUsable,
        "Late end of the 90% interval of days_to_gap_alarm; no value beyond the horizon",
        |d| real_of(forecast(d).and_then(|f| f.days_high)),
    )
    .kept(Columns::both("days_to_gap_alarm_high"), |d, v| {
        if let Some(forecast) = forecast_mut(d) {
            forecast.days_high = to_real(v);
        }
    }),
    F::real(
        "gap_alarm_date",
        "",
        ext(19, U32, 9),
        Stale::LastUsable,
        "The date of days_to_gap_alarm: the last bite's time plus those days (UTC)",
        |d| forecast(d).and_then(|f| f.date_unix_ms).map(Value::Time),
    )
    .typed(FigureType::Time)
    .kept(Columns::both("gap_alarm_date"), |d, v| {
        if let Some(forecast) = forecast_mut(d) {
            forecast.date_unix_ms = to_time(v);
        }
    }),
    // The fatigue ledger's worst component (the most life used); the state first: it
    // makes the figures the others fill.
    F::state(
        "fatigue_forecast",
        ForecastState::NAMES,
        unmapped("the registers carry days_to_fatigue_limit (its quality bit clear when no date is expected); the state is in every other output"),
        "What the forecast of the worst fatigue component reaching drivelines[].fatigue.life_limit says: forecast (days_to_fatigue_limit given), at_alarm (at or over the limit), not_growing (not consuming: no damage in the rate's window), beyond_horizon (later than drivelines[].wear.horizon_days), too_few_bites (under a day counted since its installation or the ledger's start)",
        |d| d.fatigue.map(|f| Value::Index(f.forecast as u64)),
    )
    .kept(Columns::both("fatigue_forecast"), |d, v| {
        d.fatigue = to_index(v)
            .and_then(|state| ForecastState::ALL.get(state))
            .map(|&forecast| FatigueFigures {
                component: 0,
                life_used: 0.0,
                bite_damage: None,
                rate_per_day: None,
                forecast,
                days_to_limit: None,
                limit_date_unix_ms: None,
            })
    }),
    F::real(
        "fatigue_component",
        "",
        ext(22, U16, 11),
        Stale::LastUsable,
        "The fatigue component that has used the most of its life (index in drivelines[].fatigue.components): the one the fatigue figures are of",
        |d| index_of(d.fatigue.map(|f| f.component)),
    )
    .typed(FigureType::Index)
    .kept(Columns::both("fatigue_component"), |d, v| {
        if let (Some(f), Some(component)) = (d.fatigue.as_mut(), to_index(v)) {
            f.component = component;
        }
    }),
    F::real(
        "fatigue_life_used",
        "",
        ext(23, F32, 12),
        Stale::LastUsable,
        "Life used by that component since its installation (its last fatigue reset): Miner's sum of the rainflow cycles of the whole torque stream on its S-N curve, 1 = the curve's failure",
        |d| real_of(d.fatigue.map(|f| f.life_used)),
    )
    .kept(Columns::both("fatigue_life_used"), |d, v| {
        if let (Some(f), Some(used)) = (d.fatigue.as_mut(), to_real(v)) {
            f.life_used = used;
        }
    }),
    F::real(
        "fatigue_rate_per_day",
        "1/d",
        ext(25, F32, 13),
        Stale::LastUsable,
        "That component's consumption rate: its damage over the last 7 UTC days (today's part included) per day counted in them; no value under a day counted",
        |d| real_of(d.fatigue.and_then(|f| f.rate_per_day)),
    )
    .kept(Columns::both("fatigue_rate_per_day"), |d, v| {
        if let Some(f) = d.fatigue.as_mut() {
            f.rate_per_day = to_real(v);
        }
    }),
    F::real(
        "days_to_fatigue_limit",
        "d",
        ext(27, F32, 14),
        Stale::LastUsable,
        "Calendar days from the last bite until that component reaches drivelines[].fatigue.life_limit at its rate (0 at the limit); no value when no date is expected within the horizon (fatigue_forecast says why)",
        |d| real_of(d.fatigue.and_then(|f| f.days_to_limit)),
    )
    .kept(Columns::both("days_to_fatigue_limit"), |d, v| {
        if let Some(f) = d.fatigue.as_mut() {
            f.days_to_limit = to_real(v);
        }
    }),
    F::real(
        "fatigue_limit_date",
        "",
        unmapped("the registers carry days_to_fatigue_limit"),
        Stale::LastUsable,
        "The date of days_to_fatigue_limit: the last bite's time plus those days (UTC)",
        |d| d.fatigue.and_then(|f| f.limit_date_unix_ms).map(Value::Time),
    )
    .typed(FigureType::Time)
    .kept(Columns::both("fatigue_limit_date"), |d, v| {
        if let Some(f) = d.fatigue.as_mut() {
            f.limit_date_unix_ms = to_time(v);
        }
    }),
    F::real(
        "fatigue_bite_damage",
        "",
        ext(29, F32, 15),
        Stale::LastUsable,
        "That component's damage at the last bite: the cycles closed since the bite before, up to the end of its window; no value when that torque cannot be trusted (a cut stream, non-finite samples, a degraded window), counted in fatigue_life_used all the same",
        |d| real_of(d.fatigue.and_then(|f| f.bite_damage)),
    )
    .kept(Columns::both("fatigue_bite_damage"), |d, v| {
        if let Some(f) = d.fatigue.as_mut() {
            f.bite_damage = to_real(v);
        }
    }),
    F::count(
        "fatigue_stream_cuts",
        unmapped_counter("a diagnostic of the other outputs"),
        "Times the fatigue ledger's torque stream was cut since start (lost or saturated samples, a stale source): each time its rainflow residue was counted as half cycles and the count began afresh",
        |d| Some(Value::Count(d.fatigue_stream_cuts)),
    ),
    F::flag(
        "taf_warning",
        0,
        Stale::Kept,
        Some(AlarmKind::TafWarning),
        "TAF at or above the warning threshold at the last bite",
        |d| Some(Value::Bool(d.taf_warning)),
    )
    .kept(Columns::state("warning"), |d, v| d.taf_warning = to_flag(v)),
    F::flag(
        "taf_alarm",
        1,
        Stale::Kept,
        Some(AlarmKind::TafAlarm),
        "TAF reached the alarm threshold; latched until acknowledged",
        |d| Some(Value::Bool(d.taf_alarm)),
    )
    .latched()
    .kept(Columns::state("alarm_latched"), |d, v| {
        d.taf_alarm = to_flag(v)
    }),
    F::flag(
        "source_stale",
        2,
        Stale::Kept,
        None,
        "The torque channel's source is stale or lost: the last bite's values are only its last usable ones",
        |d| Some(Value::Bool(d.source_stale)),
    ),
    F::flag(
        "degraded",
        3,
        Stale::Kept,
        None,
        "The last bite's window had a gap, saturated or non-finite samples: its values are not valid",
        |d| Some(Value::Bool(d.last_bite_degraded)),
    )
    .kept(Columns::both("degraded"), |d, v| {
        d.last_bite_degraded = to_flag(v)
    }),
    F::flag(
        "gap_warning",
        4,
        Stale::Kept,
        Some(AlarmKind::GapWarning),
        "The estimated opened gap is at or above the gap warning threshold",
        |d| Some(Value::Bool(d.gap_warning)),
    )
    .kept(Columns::state("gap_warning"), |d, v| {
        d.gap_warning = to_flag(v)
    }),
    F::flag(
        "gap_alarm",
        5,
        Stale::Kept,
        Some(AlarmKind::GapAlarm),
        "The gap's 90% interval lay at or above the gap alarm threshold; latched until acknowledged",
        |d| Some(Value::Bool(d.gap_alarm)),
    )
    .latched()
    .kept(Columns::state("gap_alarm_latched"), |d, v| {
        d.gap_alarm = to_flag(v)
    }),
    F::flag(
        "restored",
        6,
        Stale::Kept,
        None,
        "The values are from before the gateway's last restart (restored from the history; last_bite_time says when); cleared by the next bite",
        |d| Some(Value::Bool(d.restored)),
    ),
    F::state(
        "last_bite_gated",
        BiteGate::NAMES,
        unmapped("a mark for the crew and the history of the wear trend; the PLC has the state and speed itself"),
        "Whether the last bite was pooled into the wear trend (with drivelines[].context): pooled, or not because of the mill's state (idle, threading, maintenance) or its speed (outside pool_speed_range_mpm); no value without a context",
        |d| d.last_bite_gated.map(|gate| Value::Index(gate as u64)),
    )
    .kept(Columns::bite("gated"), |d, v| {
        d.last_bite_gated = to_index(v).and_then(|i| BiteGate::ALL.get(i).copied())
    }),
    F::count(
        "bites_gated_state",
        unmapped_counter("a count of gating decisions for the crew; the PLC has the state itself"),
        "Bites recorded but not pooled into the wear trend since start: the mill was idle, threading or in maintenance (context.state)",
        |d| Some(Value::Count(d.bites_gated_state)),
    ),
    F::count(
        "bites_gated_speed",
        unmapped_counter("a count of gating decisions for the crew; the PLC has the speed itself"),
        "Bites recorded but not pooled into the wear trend since start: the mill speed was outside pool_speed_range_mpm",
        |d| Some(Value::Count(d.bites_gated_speed)),
    ),
    F::count(
        "bites_context_invalid",
        unmapped_counter("a count of the PLC's own bad context values, for the crew; the PLC knows its values"),
        "Bites since start whose context from the PLC held an impossible value (negative speed, unknown product or state): not used for the gating, the bite pooled as without context",
        |d| Some(Value::Count(d.bites_context_invalid)),
    ),
];

/// The gap's growth, when the trend has one.
fn growth(d: &DrivelineResults) -> Option<GapGrowth> {
    d.gap.and_then(|g| g.growth)
}

fn growth_mut(d: &mut DrivelineResults) -> Option<&mut GapGrowth> {
    d.gap.as_mut().and_then(|g| g.growth.as_mut())
}

/// The gap forecast, when there is one.
fn forecast(d: &DrivelineResults) -> Option<GapForecast> {
    d.gap.and_then(|g| g.forecast)
}

fn forecast_mut(d: &mut DrivelineResults) -> Option<&mut GapForecast> {
    d.gap.as_mut().and_then(|g| g.forecast.as_mut())
}
