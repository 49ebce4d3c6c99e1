//! The gateway's latest results: what the analysis produced, what the outputs publish
//! (each figure named and described once in [`super::catalogue`]).

use crate::field::source_health::SourceStatus;
use crate::state::context::BiteGate;

/// Latest results of one driveline. `None` = not computed (yet), published with
/// its quality bit cleared.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct DrivelineResults {
    /// Bites analysed since start (wraps at u32).
    pub bite_counter: u32,
    /// Of those, degraded bites (gap, saturated or non-finite samples in the window),
    /// whose values were not published.
    pub degraded_bites: u32,
    /// Time of the last bite, ms since the Unix epoch.
    pub last_bite_unix_ms: Option<i64>,
    /// Static (settled) torque of the last bite, kN*m.
    pub static_torque_knm: Option<f64>,
    /// Peak torque of the last bite, kN*m.
    pub peak_torque_knm: Option<f64>,
    /// Torque amplification factor of the last bite.
    pub taf: Option<f64>,
    /// First oscillation period after the last bite's onset, s.
    pub first_period_s: Option<f64>,
    /// First minus second oscillation period of the last bite, s.
    pub first_period_shift_s: Option<f64>,
    /// First natural frequency identified from the last bite, Hz.
    pub beta1_hz: Option<f64>,
    /// Second natural frequency identified from the last bite, Hz.
    pub beta2_hz: Option<f64>,
    /// Damping ratio of the first mode identified from the last bite (with `beta1_hz`).
    pub first_mode_damping: Option<f64>,
    /// TAF-ratio wear index of the last bite (a secondary figure beside the gap):
    /// measured TAF / linear reference TAF - 1 (0 = like the linear reference; grows
    /// with opened backlash). `None` without a model.
    pub wear_index: Option<f64>,
    /// Wear trend: exponentially weighted mean of the wear index over bites
    /// ([`crate::analysis::wear::next_trend`]); `None` until the first index after start or reset.
    pub wear_trend: Option<f64>,
    /// The last bite's window had gaps, NaN or saturated samples: its values are `None`.
    pub last_bite_degraded: bool,
    /// TAF at or above the warning threshold at the last bite.
    pub taf_warning: bool,
    /// TAF reached the alarm threshold; latched until acknowledged.
    pub taf_alarm: bool,
    /// The pooled estimate of the opened gap; `None` without a model, until the gap
    /// maps are ready and a bite inside them was seen, after a reset.
    pub gap: Option<GapResults>,
    /// The estimated gap is at or above the gap warning threshold.
    pub gap_warning: bool,
    /// The gap's 90% interval lay at or above the gap alarm threshold; latched until
    /// acknowledged.
    pub gap_alarm: bool,
    /// The torque channel's source is stale or lost: every value is flagged.
    pub source_stale: bool,
    /// The values are from before the last restart (restored from the history);
    /// cleared by the next bite.
    pub restored: bool,
    /// The fatigue ledger's figures of the component that has used the most of its
    /// life; `None` without `drivelines[].fatigue` or before its first bite.
    pub fatigue: Option<FatigueFigures>,
    /// The fatigue ledger per component (config order), as of the last bite; empty
    /// without a ledger (the web API's and the history's, not the catalogue's: the
    /// registers carry [`Self::fatigue`]).
    pub fatigue_components: Vec<ComponentLife>,
    /// Times the fatigue ledger's torque stream was cut since start (lost or
    /// saturated samples, a stale source): the residue was counted as half cycles.
    pub fatigue_stream_cuts: u64,
    /// Whether the last bite was pooled into the wear trend, and if not why; `None`
    /// without `drivelines[].context` (every bite is pooled).
    pub last_bite_gated: Option<BiteGate>,
    /// Bites not pooled since start because the mill was idle, threading or in
    /// maintenance.
    pub bites_gated_state: u64,
    /// Bites not pooled since start because the mill speed was outside
    /// `pool_speed_range_mpm`.
    pub bites_gated_speed: u64,
    /// Bites since start whose context held an impossible value (not used for the
    /// gating: pooled as without context).
    pub bites_context_invalid: u64,
}

/// The fatigue figures of one component, as the registers carry them for the worst
/// one (see [`crate::analysis::fatigue_ledger`]).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct FatigueFigures {
    /// The component (index in `drivelines[].fatigue.components`).
    pub component: usize,
    /// Miner's sum since its installation (its last reset): 1 is the S-N curve's failure.
    pub life_used: f64,
    /// Its damage at the last bite (the cycles closed since the bite before); `None`
    /// when the torque since that bite cannot be trusted (a cut stream, non-finite
    /// samples, a degraded window): counted in `life_used` all the same.
    pub bite_damage: Option<f64>,
    /// Consumption rate, life per calendar day, over the last
    /// [`crate::analysis::fatigue_ledger::RATE_WINDOW_DAYS`] days; `None` until a day of
    /// it is known.
    pub rate_per_day: Option<f64>,
    /// What the forecast of reaching `fatigue.life_limit` says: `forecast`,
    /// `at_alarm` (at the limit), `not_growing` (not consuming), `beyond_horizon`,
    /// `too_few_bites` (under a day counted since installation or the start).
    pub forecast: ForecastState,
    /// Days from the last bite until the life limit is reached (0 at it).
    pub days_to_limit: Option<f64>,
    /// The date of `days_to_limit`, ms since the Unix epoch.
    pub limit_date_unix_ms: Option<i64>,
}

/// One component's fatigue account, as the web API and the history show it.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct ComponentLife {
    /// Its name (`drivelines[].fatigue.components[].name`).
    pub name: String,
    /// Since when it is counted (its last reset; or when the ledger began), ms since
    /// the Unix epoch.
    pub installed_unix_ms: i64,
    /// Its figures.
    #[serde(flatten)]
    pub figures: FatigueFigures,
}

/// The gap estimate of a driveline (its wear trend), as published (see
/// [`crate::analysis::gap_estimate`]); serialized as the web API's `gap`.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct GapResults {
    /// Opened gap, maximum likelihood, mrad.
    pub gap_mrad: f64,
    /// Lower end of the 90% interval, mrad.
    pub low_mrad: f64,
    /// Upper end of the 90% interval, mrad.
    pub high_mrad: f64,
    /// Coupling holding the gap (model index, 0 = motor side), `None` when
    /// undetermined.
    pub coupling: Option<usize>,
    /// The likeliest coupling (model index), named or not; `None` where it is not
    /// known (a bite replayed from the history, which keeps only `coupling`).
    pub likeliest_coupling: Option<usize>,
    /// Bites in the wear trend since the last wear reset (the key keeps its old
    /// name: the bites were once pooled).
    pub bites_pooled: usize,
    /// Growth of the gap, mrad/day, with its 90% interval; `None` until the trend
    /// has bites at two distinct times.
    pub growth: Option<GapGrowth>,
    /// When the gap reaches its alarm threshold; `None` where it is not known (a
    /// bite replayed from the history).
    pub forecast: Option<GapForecast>,
}

/// The gap's growth, mrad/day (calendar days), with its 90% interval.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct GapGrowth {
    /// Growth, mrad/day.
    pub mrad_per_day: f64,
    /// Lower end of its 90% interval, mrad/day.
    pub low_mrad_per_day: f64,
    /// Upper end of its 90% interval, mrad/day.
    pub high_mrad_per_day: f64,
}

/// The forecast of the gap reaching `thresholds.gap_alarm_mrad`: calendar days from the
/// last bite, a point value and a 90% interval, and the date of the point value.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct GapForecast {
    /// What the forecast says (and why days are missing when they are).
    pub state: ForecastState,
    /// Days from the last bite until the gap reaches the alarm; `None` when no
    /// crossing is expected within the horizon (`state` says why).
    pub days: Option<f64>,
    /// Early end of the 90% interval of `days` (the gap may reach the alarm this soon).
    pub days_low: Option<f64>,
    /// Late end of the 90% interval of `days`; `None` beyond the horizon.
    pub days_high: Option<f64>,
    /// The date of `days`, ms since the Unix epoch (UTC).
    pub date_unix_ms: Option<i64>,
    /// The forecast's cone for drawing: the gap band from the last bite on, and the
    /// fitted growth back over the last weeks; `None` where it is not known (restored
    /// from the history until the trend is continued).
    pub cone: Option<GapCone>,
}

/// Points of a forecast's cone.
pub const CONE_POINTS: usize = 16;

/// The forecast's cone as the page and the report draw it.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct GapCone {
    /// The gap band at evenly spaced days from the last bite (0) to beyond the late
    /// end of the forecast (or the horizon).
    pub points: [ConePoint; CONE_POINTS],
    /// How far back from the last bite the fitted growth line is drawn, days (at most
    /// four weeks, not before the first bite since the last wear reset).
    pub back_days: f64,
}

/// The gap band `days` after the last bite: the trend's mean, the early (high) and the
/// late (low) end of its 90% band, mrad.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct ConePoint {
    /// Days after the last bite.
    pub days: f64,
    /// The trend's gap, mrad.
    pub mean_mrad: f64,
    /// The late (low) end of the band, mrad.
    pub low_mrad: f64,
    /// The early (high) end of the band, mrad.
    pub high_mrad: f64,
}

/// What a gap forecast says: `forecast` (days given), `at_alarm` (the gap is at the
/// threshold), `not_growing` (no crossing expected: the growth's interval holds 0),
/// `beyond_horizon` (growing, but not within the horizon), `too_few_bites` (not enough
/// bites since the last wear reset for a trend).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ForecastState {
    /// A crossing within the horizon: days given.
    Forecast,
    /// The gap is at or above the threshold already: days 0.
    AtAlarm,
    /// The growth's interval holds 0: no crossing expected.
    NotGrowing,
    /// Growing, but the crossing is beyond the horizon.
    BeyondHorizon,
    /// Too few bites since the last wear reset for a trend.
    TooFewBites,
}

impl ForecastState {
    /// The states by value, as the registers and OPC UA carry them.
    pub const NAMES: &'static [&'static str] = &[
        "forecast",
        "at_alarm",
        "not_growing",
        "beyond_horizon",
        "too_few_bites",
    ];

    /// Every state, by value.
    pub const ALL: [Self; 5] = [
        Self::Forecast,
        Self::AtAlarm,
        Self::NotGrowing,
        Self::BeyondHorizon,
        Self::TooFewBites,
    ];

    /// Its name.
    pub fn name(self) -> &'static str {
        Self::NAMES[self as usize]
    }
}

/// Latest chatter figures of one tandem mill (see [`crate::analysis::chatter`]).
/// `None` = not valid: not computed yet, or the window restarted after a gap or a
/// stale stand.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TandemMillResults {
    /// Windows evaluated since start.
    pub evaluations: u64,
    /// RMS difference of adjacent stands' principal frequencies, Hz.
    pub sigma_n_hz: Option<f64>,
    /// Mean correlation of adjacent stands' chatter-band vibration, -1..=1.
    pub k_mean: Option<f64>,
    /// Mean of the stands' principal frequencies in the chatter band, Hz.
    pub chatter_frequency_hz: Option<f64>,
    /// Largest chatter-band gain of any stand (chatter-band RMS / reference-band RMS).
    pub chatter_gain: Option<f64>,
    /// Largest gain / threshold of any stand: >= 1 is the band-gain alarm.
    pub gain_ratio: Option<f64>,
    /// Largest chatter-band RMS of any stand, in the stand channels' unit.
    pub band_rms_max: Option<f64>,
    /// Stand (index in the mill's `stands`) of the gain ratio.
    pub worst_stand: Option<usize>,
    /// The configured detector's warning in the last window (band gain: gain ratio >=
    /// `slow_down_release`; paper: sigma_n <= sigma_min).
    pub chatter_warning: bool,
    /// The configured detector's alarm held in a window (band gain: gain ratio >= 1;
    /// paper: both conditions); latched until acknowledged.
    pub chatter_alarm: bool,
    /// Slow-down request to the PLC, with hysteresis (set by the alarm condition,
    /// cleared after `slow_down_hold_s` below `slow_down_release`); not latched, and
    /// held while the values are stale.
    pub slow_down_request: bool,
    /// A stand's source is stale or lost, or the window restarted after a gap:
    /// every value is flagged.
    pub source_stale: bool,
    /// Windows whose alarm (and slow-down request) the weld hold kept off since start:
    /// the gain ratio reached 1 but not `weld_alarm_factor` while a weld was in the
    /// mill or settling.
    pub weld_held_off: u64,
    /// Context values read with an impossible value since start (not used for the
    /// gating).
    pub context_invalid: u64,
    /// Restarts of the window since start because samples were lost on a stand.
    pub window_restarts_gap: u64,
    /// Restarts of the window since start because a stand fell more than
    /// `MAX_STAND_LAG_S` behind the others.
    pub window_restarts_lagging: u64,
    /// Restarts of the window since start because a stand's place on the common
    /// sample axis was re-anchored against the arrival times.
    pub window_restarts_realigned: u64,
    /// The thresholds that judged the last window: 0 the mill's `gain_thresholds`, k
    /// its `product_groups[k - 1]`'s (the product the PLC reported); `None` before the
    /// first window.
    pub thresholds_group: Option<usize>,
    /// The name of the product group whose thresholds judged the last window; `None`
    /// for the mill's own.
    pub thresholds_group_name: Option<String>,
    /// The `gain_thresholds` that judged the last window, per stand (the group's or
    /// the mill's); `None` before the first window. Shared: a window whose thresholds
    /// did not change copies no figure.
    pub gain_thresholds_in_use: Option<std::sync::Arc<[f64]>>,
    /// Windows judged by the mill's thresholds since start because the product context
    /// was missing, invalid or stale while the mill has product groups.
    pub product_fallback: u64,
}

/// Spans of one rod mill the outputs have room for (a 12-stand block): the register
/// map reserves this many span blocks per rod mill.
pub const MAX_ROD_SPANS: usize = 11;

/// Latest stability of one rod-mill span (see [`crate::analysis::rod_monitor`]).
/// `valid == false`: no result (inputs missing or refused); published as invalid.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RodSpanResults {
    /// The span was evaluated at the current inputs.
    pub valid: bool,
    /// Unstable (with hysteresis).
    pub unstable: bool,
    /// Stable but near a tongue (with hysteresis).
    pub near_tongue: bool,
    /// Finishing-speed change to the nearest band edge, m/s: positive when stable,
    /// negative (minus the change that stabilises it) when not; `None` without an edge
    /// in the configuration's speed range.
    pub speed_margin_m_s: Option<f64>,
    /// Largest growth exponent of the span's points, 1/s (negative: decaying).
    pub worst_exponent_per_s: Option<f64>,
    /// The configuration input's value (index into the rod mill's `configurations`)
    /// the span was evaluated in.
    pub configuration: Option<u16>,
}

/// Latest results of one rod mill. `None` values and invalid spans are published
/// with their quality bits cleared.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RodMillResults {
    /// Evaluations since start (one per change of the inputs).
    pub evaluations: u64,
    /// The last inputs were refused (configuration, pass, speed or temperature out of
    /// range): the spans are invalid.
    pub input_refused: bool,
    /// Configuration input in use (index into `configurations`).
    pub configuration: Option<u16>,
    /// Pass number in use, 1-based.
    pub pass: Option<u16>,
    /// Finishing speed evaluated, m/s.
    pub finishing_speed_m_s: Option<f64>,
    /// Rod temperature of the setup in use, deg C.
    pub temperature_c: Option<f64>,
    /// The source of an input is stale or lost: every value is invalid.
    pub source_stale: bool,
    /// Per span, in rolling order (empty until the first evaluation).
    pub spans: Vec<RodSpanResults>,
}

impl RodMillResults {
    /// Whether the values may be published: evaluated, inputs accepted, fresh.
    pub fn valid(&self) -> bool {
        self.evaluations > 0 && !self.input_refused && !self.source_stale
    }

    /// The span nearest to a band edge: the valid span with the smallest speed margin
    /// (the most negative when unstable), `(index in rolling order, margin in m/s)`;
    /// `None` while the mill is not [`Self::valid`] or no span has a margin.
    pub fn worst_span(&self) -> Option<(usize, f64)> {
        if !self.valid() {
            return None;
        }
        self.spans
            .iter()
            .enumerate()
            .filter(|(_, span)| span.valid)
            .filter_map(|(index, span)| Some((index, span.speed_margin_m_s?)))
            .min_by(|a, b| a.1.total_cmp(&b.1))
    }

    /// Span `index` as published: its results while it and the mill are valid, else an
    /// empty span (not valid, flags clear, no values), also for spans the mill file
    /// does not have.
    pub fn published_span(&self, index: usize) -> RodSpanResults {
        self.spans
            .get(index)
            .filter(|span| span.valid && self.valid())
            .cloned()
            .unwrap_or_default()
    }
}

/// The gateway's own state as published in the status register.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum GatewayState {
    /// Built, tasks not started yet.
    #[default]
    Starting,
    /// Readers, analysis and outputs running.
    Running,
    /// Shut down: the values are the last ones and will not change.
    Stopped,
}

/// The gateway's own figures, as [`Results`] holds them ([`Results::gateway`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct GatewayResults {
    /// Starting, running or stopped.
    pub state: GatewayState,
    /// Incremented on every write to the PLC (every second without a PLC output).
    pub heartbeat: u16,
    /// Every source answers (ok); also true without sources.
    pub sources_ok: bool,
}

/// One source's figures, as [`Results`] holds them ([`Results::source`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct SourceResults {
    /// Its status; `None` before the first.
    pub status: Option<SourceStatus>,
}

/// Everything the outputs publish.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Results {
    /// Starting, running or stopped.
    pub state: GatewayState,
    /// Incremented on every write to the PLC.
    pub heartbeat: u16,
    /// Per source, in the order of [`millgate_config::Config::sources`].
    pub sources: Vec<Option<SourceStatus>>,
    /// Per driveline, in config order.
    pub drivelines: Vec<DrivelineResults>,
    /// Per tandem mill, in config order.
    pub tandem_mills: Vec<TandemMillResults>,
    /// Per rod mill, in config order (sized by [`crate::state::board::Board::new`]).
    pub rod_mills: Vec<RodMillResults>,
}

impl Results {
    /// The gateway's own figures ([`super::catalogue::GATEWAY`]).
    pub fn gateway(&self) -> GatewayResults {
        GatewayResults {
            state: self.state,
            heartbeat: self.heartbeat,
            sources_ok: self.sources.iter().all(|s| *s == Some(SourceStatus::Ok)),
        }
    }

    /// Source `index`'s figures ([`super::catalogue::SOURCE`]); no status for a source
    /// the results do not have.
    pub fn source(&self, index: usize) -> SourceResults {
        SourceResults {
            status: self.sources.get(index).copied().flatten(),
        }
    }

    /// Empty results for `sources` sources, `drivelines` drivelines and `tandem_mills`
    /// tandem mills.
    pub fn new(sources: usize, drivelines: usize, tandem_mills: usize) -> Self {
        Self {
            state: GatewayState::Starting,
            heartbeat: 0,
            sources: vec![None; sources],
            drivelines: vec![DrivelineResults::default(); drivelines],
            tandem_mills: vec![TandemMillResults::default(); tandem_mills],
            rod_mills: Vec::new(),
        }
    }
}
