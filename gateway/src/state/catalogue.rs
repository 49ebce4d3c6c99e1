//! The catalogue of published figures: every figure the gateway publishes exists here
//! once, with its key, unit, type, description, the bit that guards it and what a
//! stale source does to it. Every output is derived from it: the register map, the
//! Sparkplug births and data, the `/metrics` families, the web API and the OPC UA
//! address space name each figure by its key; the history's bite columns are checked
//! against it (see [`mappings`](crate::outputs::figures) for the generated table).
//!
//! # The stale rule, decided once
//!
//! A source is *stale* when it has not answered for longer than its stale time (or is
//! lost). What that does to a figure depends on what the figure describes
//! ([`Stale`]):
//!
//! - a figure of **the mill now** (a tandem mill's chatter window, a rod mill's
//!   operating point and span margins) is **withdrawn**: no output shows a value for
//!   it until the source answers again;
//! - a figure of **the last bite** (its torques, TAF, periods, frequencies, the wear
//!   index and the gap pooled from past bites) stays true of that bite: it is its
//!   **last usable value**, shown as such where an output can say so (the web page
//!   beside a "source stale" mark, OPC UA as `Uncertain_LastUsableValue`) and
//!   withheld where it cannot (the PLC registers and the HMI read 0 with the quality
//!   bit clear, Sparkplug sends null, `/metrics` leaves the sample out): a PLC never
//!   acts on a value it cannot tell from a fresh one;
//! - counters and flags (bite counters, latched alarms, the stale flag itself) are
//!   **kept**: they say what happened, not what is measured.
//!
//! A figure that was never computed, or that its bite could not give (a degraded
//! window, no model, an undetermined coupling), has no value in any output.

use super::events::AlarmKind;
use super::results::{DrivelineResults, RodMillResults, RodSpanResults, TandemMillResults};

/// What a figure's value is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FigureType {
    /// A real number in the figure's unit.
    Real,
    /// A count of events (non-negative, only grows until a restart or wrap).
    Count,
    /// A small non-negative integer naming something (a coupling, a stand, a span, a
    /// pass, a configuration); 1-based where the description says so.
    Index,
    /// A flag.
    Bool,
    /// An instant: milliseconds since the Unix epoch, UTC.
    Time,
}

impl FigureType {
    /// `real`, `count`, `index`, `bool`, `time`.
    pub fn name(self) -> &'static str {
        match self {
            FigureType::Real => "real",
            FigureType::Count => "count",
            FigureType::Index => "index",
            FigureType::Bool => "bool",
            FigureType::Time => "time",
        }
    }
}

/// What says whether a figure's value may be used.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Guard {
    /// Bit `n` of the block's `quality` register is set while the value is valid.
    QualityBit(u8),
    /// The figure is bit `n` of the block's `flags` register.
    FlagBit(u8),
    /// Always valid (counters).
    Always,
    /// Valid while it has a value; no register bit (a figure the register map does not
    /// carry).
    Presence,
}

/// What a stale source does to a figure (see the module's documentation).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stale {
    /// A figure of the mill now: withdrawn while its source is stale.
    Withdrawn,
    /// A figure of the last bite: stays as its last usable value.
    LastUsable,
    /// A counter or a flag: unaffected.
    Kept,
}

impl Stale {
    /// `withdrawn`, `last usable`, `kept`.
    pub fn name(self) -> &'static str {
        match self {
            Stale::Withdrawn => "withdrawn",
            Stale::LastUsable => "last usable",
            Stale::Kept => "kept",
        }
    }
}

/// A figure's value.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Value {
    /// [`FigureType::Real`].
    Real(f64),
    /// [`FigureType::Count`].
    Count(u64),
    /// [`FigureType::Index`].
    Index(u64),
    /// [`FigureType::Bool`].
    Bool(bool),
    /// [`FigureType::Time`]: ms since the Unix epoch.
    Time(i64),
}

impl Value {
    /// As a number (a flag is 0 or 1; a time in ms since the epoch).
    pub fn as_f64(self) -> f64 {
        match self {
            Value::Real(v) => v,
            Value::Count(v) | Value::Index(v) => v as f64,
            Value::Bool(v) => f64::from(u8::from(v)),
            Value::Time(ms) => ms as f64,
        }
    }

    fn figure_type(self) -> FigureType {
        match self {
            Value::Real(_) => FigureType::Real,
            Value::Count(_) => FigureType::Count,
            Value::Index(_) => FigureType::Index,
            Value::Bool(_) => FigureType::Bool,
            Value::Time(_) => FigureType::Time,
        }
    }
}

/// Why a figure has no value.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NoValue {
    /// Never computed, or not given by its bite or window (degraded, no model,
    /// undetermined, inputs refused).
    NotAvailable,
    /// Withdrawn: its source is stale.
    SourceStale,
}

/// How far a figure's value may be trusted, by the stale rule.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Quality {
    /// Valid and current.
    Good,
    /// The last bite's value while the source is stale ([`Stale::LastUsable`]).
    LastUsable,
    /// No value.
    Bad(NoValue),
}

/// A figure read from the results with the stale rule applied.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Reading {
    /// The value, unless [`Quality::Bad`].
    pub value: Option<Value>,
    /// Its quality.
    pub quality: Quality,
}

impl Reading {
    /// The value while [`Quality::Good`]: what outputs that cannot mark a last usable
    /// value publish (the PLC registers, Sparkplug, `/metrics`).
    pub fn good(&self) -> Option<Value> {
        self.value.filter(|_| self.quality == Quality::Good)
    }

    /// The value while good or last usable: what the web page shows (beside the stale
    /// mark).
    pub fn usable(&self) -> Option<Value> {
        self.value
    }
}

/// The kinds of things figures describe.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SubjectKind {
    /// A driveline, analysed at each bite.
    Driveline,
    /// A tandem cold mill, watched for chatter.
    TandemMill,
    /// A rod mill, its spans checked against the Mathieu tongues.
    RodMill,
    /// One span (two stands) of a rod mill.
    RodSpan,
}

impl SubjectKind {
    /// `driveline`, `tandem_mill`, `rod_mill`, `rod_span`: the `/metrics` prefix and
    /// label.
    pub fn name(self) -> &'static str {
        match self {
            SubjectKind::Driveline => "driveline",
            SubjectKind::TandemMill => "tandem_mill",
            SubjectKind::RodMill => "rod_mill",
            SubjectKind::RodSpan => "rod_span",
        }
    }
}

/// Results that figures are read from.
pub trait Subject: Default {
    /// What they describe.
    const KIND: SubjectKind;
    /// Whether a source they are computed from is stale.
    fn source_stale(&self) -> bool;
}

impl Subject for DrivelineResults {
    const KIND: SubjectKind = SubjectKind::Driveline;
    fn source_stale(&self) -> bool {
        self.source_stale
    }
}

impl Subject for TandemMillResults {
    const KIND: SubjectKind = SubjectKind::TandemMill;
    fn source_stale(&self) -> bool {
        self.source_stale
    }
}

impl Subject for RodMillResults {
    const KIND: SubjectKind = SubjectKind::RodMill;
    fn source_stale(&self) -> bool {
        self.source_stale
    }
}

impl Subject for RodSpanResults {
    const KIND: SubjectKind = SubjectKind::RodSpan;
    /// A span is read through [`RodMillResults::published_span`], which is empty (no
    /// values) while its mill's source is stale.
    fn source_stale(&self) -> bool {
        false
    }
}

/// What the catalogue says of a figure, whatever its subject.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Spec {
    /// The name every output uses: `taf`, `gap_mrad`, ...
    pub key: &'static str,
    /// Unit of a real value (`kN*m`, `Hz`, `s`, `mrad`, `m/s`, `1/s`, `degC`), empty
    /// for ratios, counts, indices, flags and times.
    pub unit: &'static str,
    /// Its type.
    pub figure_type: FigureType,
    /// One or two sentences for the documentation and every output's description.
    pub description: &'static str,
    /// The bit that guards it.
    pub guard: Guard,
    /// What a stale source does to it.
    pub stale: Stale,
    /// The range the value lies in, where one is known (OPC UA's EURange).
    pub range: Option<(f64, f64)>,
    /// For a warning or alarm flag: the alarm kind the history records its changes as.
    pub alarm: Option<AlarmKind>,
    /// The name on `/metrics` when the rule (`millgate_<subject>_<key>`) gives a
    /// name Prometheus' conventions refuse.
    pub metric: Option<&'static str>,
}

impl Spec {
    /// Whether the figure only grows (until a restart without a history, or a wrap):
    /// a Prometheus counter. A count that can fall (the bites pooled) is not.
    pub fn is_counter(&self) -> bool {
        self.figure_type == FigureType::Count && self.guard == Guard::Always
    }
}

/// One published figure of results `R`: its [`Spec`] (reached through `Deref`) and
/// how to read it.
#[derive(Debug)]
pub struct Figure<R> {
    /// What the catalogue says of it.
    pub spec: Spec,
    value: fn(&R) -> Option<Value>,
}

impl<R> std::ops::Deref for Figure<R> {
    type Target = Spec;
    fn deref(&self) -> &Spec {
        &self.spec
    }
}

impl<R: Subject> Figure<R> {
    /// The figure of `subject` with the stale rule applied.
    pub fn read(&self, subject: &R) -> Reading {
        let value = (self.value)(subject);
        debug_assert!(value.is_none_or(|v| v.figure_type() == self.figure_type));
        let stale = subject.source_stale();
        match value {
            None => Reading {
                value: None,
                quality: Quality::Bad(if stale {
                    NoValue::SourceStale
                } else {
                    NoValue::NotAvailable
                }),
            },
            Some(value) if !stale || self.stale == Stale::Kept => Reading {
                value: Some(value),
                quality: Quality::Good,
            },
            Some(value) if self.stale == Stale::LastUsable => Reading {
                value: Some(value),
                quality: Quality::LastUsable,
            },
            Some(_) => Reading {
                value: None,
                quality: Quality::Bad(NoValue::SourceStale),
            },
        }
    }

    /// The figure with its subject, without its reader.
    pub fn info(&self) -> FigureInfo {
        FigureInfo {
            subject: R::KIND,
            spec: self.spec,
        }
    }
}

/// A figure with its subject and without its reader, for tables that span subjects
/// (its [`Spec`] reached through `Deref`).
#[derive(Debug, Clone, Copy)]
pub struct FigureInfo {
    /// What it describes.
    pub subject: SubjectKind,
    /// What the catalogue says of it.
    pub spec: Spec,
}

impl std::ops::Deref for FigureInfo {
    type Target = Spec;
    fn deref(&self) -> &Spec {
        &self.spec
    }
}

/// Every figure of every subject, in catalogue order: drivelines, tandem mills, rod
/// mills, rod spans.
pub fn all() -> Vec<FigureInfo> {
    DRIVELINE
        .iter()
        .map(Figure::info)
        .chain(TANDEM_MILL.iter().map(Figure::info))
        .chain(ROD_MILL.iter().map(Figure::info))
        .chain(ROD_SPAN.iter().map(Figure::info))
        .collect()
}

/// The figure of `R` called `key`.
pub fn find<R: Subject + 'static>(figures: &'static [Figure<R>], key: &str) -> &'static Figure<R> {
    figures
        .iter()
        .find(|figure| figure.key == key)
        .unwrap_or_else(|| panic!("no {} figure {key}", R::KIND.name()))
}

const fn real<R>(
    key: &'static str,
    unit: &'static str,
    quality_bit: u8,
    stale: Stale,
    description: &'static str,
    value: fn(&R) -> Option<Value>,
) -> Figure<R> {
    Figure {
        spec: Spec {
            key,
            unit,
            figure_type: FigureType::Real,
            description,
            guard: Guard::QualityBit(quality_bit),
            stale,
            range: None,
            alarm: None,
            metric: None,
        },
        value,
    }
}

const fn flag<R>(
    key: &'static str,
    bit: u8,
    stale: Stale,
    alarm: Option<AlarmKind>,
    description: &'static str,
    value: fn(&R) -> Option<Value>,
) -> Figure<R> {
    Figure {
        spec: Spec {
            key,
            unit: "",
            figure_type: FigureType::Bool,
            description,
            guard: Guard::FlagBit(bit),
            stale,
            range: Some((0.0, 1.0)),
            alarm,
            metric: None,
        },
        value,
    }
}

const fn count<R>(
    key: &'static str,
    description: &'static str,
    value: fn(&R) -> Option<Value>,
) -> Figure<R> {
    Figure {
        spec: Spec {
            key,
            unit: "",
            figure_type: FigureType::Count,
            description,
            guard: Guard::Always,
            stale: Stale::Kept,
            range: None,
            alarm: None,
            metric: None,
        },
        value,
    }
}

const fn with_range<R>(mut figure: Figure<R>, low: f64, high: f64) -> Figure<R> {
    figure.spec.range = Some((low, high));
    figure
}

const fn metric_named<R>(mut figure: Figure<R>, name: &'static str) -> Figure<R> {
    figure.spec.metric = Some(name);
    figure
}

const fn presence<R>(mut figure: Figure<R>) -> Figure<R> {
    figure.spec.guard = Guard::Presence;
    figure
}

const fn typed<R>(mut figure: Figure<R>, figure_type: FigureType) -> Figure<R> {
    figure.spec.figure_type = figure_type;
    figure
}

fn real_of(value: Option<f64>) -> Option<Value> {
    value.map(Value::Real)
}

fn index_of(value: Option<usize>) -> Option<Value> {
    value.map(|v| Value::Index(v as u64))
}

/// A driveline's figures: its last bite's and the gap diagnosis'.
pub const DRIVELINE: &[Figure<DrivelineResults>] = &[
    // Prometheus refuses a type in a name (`_counter_total`).
    metric_named(
        count(
            "bite_counter",
            "Bites analysed since start (continued across restarts with a history)",
            |d| Some(Value::Count(u64::from(d.bite_counter))),
        ),
        "millgate_driveline_bites_total",
    ),
    count(
        "degraded_bites",
        "Of those, degraded bites: a gap, saturated or non-finite samples in the window (their values are not published)",
        |d| Some(Value::Count(u64::from(d.degraded_bites))),
    ),
    typed(
        real(
            "last_bite_time",
            "",
            0,
            Stale::LastUsable,
            "Time of the last bite",
            |d| d.last_bite_unix_ms.map(Value::Time),
        ),
        FigureType::Time,
    ),
    real(
        "static_torque_knm",
        "kN*m",
        1,
        Stale::LastUsable,
        "Static (settled) rolling torque of the last bite",
        |d| real_of(d.static_torque_knm),
    ),
    real(
        "peak_torque_knm",
        "kN*m",
        2,
        Stale::LastUsable,
        "Peak torque of the last bite",
        |d| real_of(d.peak_torque_knm),
    ),
    real(
        "taf",
        "",
        3,
        Stale::LastUsable,
        "Torque amplification factor of the last bite (peak / static)",
        |d| real_of(d.taf),
    ),
    real(
        "period_shift_s",
        "s",
        4,
        Stale::LastUsable,
        "First minus second oscillation period of the last bite",
        |d| real_of(d.first_period_shift_s),
    ),
    real(
        "beta1_hz",
        "Hz",
        5,
        Stale::LastUsable,
        "First natural frequency identified from the last bite (eq. (1) fit)",
        |d| real_of(d.beta1_hz),
    ),
    real(
        "beta2_hz",
        "Hz",
        6,
        Stale::LastUsable,
        "Second natural frequency identified from the last bite (eq. (1) fit)",
        |d| real_of(d.beta2_hz),
    ),
    real(
        "wear_index",
        "",
        7,
        Stale::LastUsable,
        "Secondary figure: TAF-ratio wear index of the last bite, its TAF / the linear model's TAF - 1 (needs the driveline model)",
        |d| real_of(d.wear_index),
    ),
    real(
        "wear_trend",
        "",
        8,
        Stale::LastUsable,
        "Secondary figure: mean of the TAF-ratio wear index over bites (EWMA, weight 0.1) since start or the last wear reset",
        |d| real_of(d.wear_trend),
    ),
    real(
        "gap_mrad",
        "mrad",
        9,
        Stale::LastUsable,
        "Opened gap (total dead-zone width, referred to the rolls), maximum likelihood over the pooled bites (needs the driveline model)",
        |d| real_of(d.gap.map(|g| g.gap_mrad)),
    ),
    real(
        "gap_low_mrad",
        "mrad",
        10,
        Stale::LastUsable,
        "Lower end of the gap's 90% interval",
        |d| real_of(d.gap.map(|g| g.low_mrad)),
    ),
    real(
        "gap_high_mrad",
        "mrad",
        11,
        Stale::LastUsable,
        "Upper end of the gap's 90% interval",
        |d| real_of(d.gap.map(|g| g.high_mrad)),
    ),
    typed(
        real(
            "gap_coupling",
            "",
            12,
            Stale::LastUsable,
            "Coupling holding the gap (model index, 0 = motor side); no value while the bites cannot tell the couplings apart (gap_mrad is valid then)",
            |d| index_of(d.gap.and_then(|g| g.coupling)),
        ),
        FigureType::Index,
    ),
    presence(typed(
        real(
            "likeliest_coupling",
            "",
            0,
            Stale::LastUsable,
            "The likeliest coupling to hold the gap (model index), named whether or not the bites tell the couplings apart",
            |d| index_of(d.gap.and_then(|g| g.likeliest_coupling)),
        ),
        FigureType::Index,
    )),
    typed(
        real(
            "bites_pooled",
            "",
            13,
            Stale::LastUsable,
            "Bites pooled into the gap estimate (the last drivelines[].wear.pool_bites since the last wear reset)",
            |d| d.gap.map(|g| Value::Count(g.bites_pooled as u64)),
        ),
        FigureType::Count,
    ),
    flag(
        "taf_warning",
        0,
        Stale::Kept,
        Some(AlarmKind::TafWarning),
        "TAF at or above the warning threshold at the last bite",
        |d| Some(Value::Bool(d.taf_warning)),
    ),
    flag(
        "taf_alarm",
        1,
        Stale::Kept,
        Some(AlarmKind::TafAlarm),
        "TAF reached the alarm threshold; latched until acknowledged",
        |d| Some(Value::Bool(d.taf_alarm)),
    ),
    flag(
        "source_stale",
        2,
        Stale::Kept,
        None,
        "The torque channel's source is stale or lost: the last bite's values are only its last usable ones",
        |d| Some(Value::Bool(d.source_stale)),
    ),
    flag(
        "degraded",
        3,
        Stale::Kept,
        None,
        "The last bite's window had a gap, saturated or non-finite samples: its values are not valid",
        |d| Some(Value::Bool(d.last_bite_degraded)),
    ),
    flag(
        "gap_warning",
        4,
        Stale::Kept,
        Some(AlarmKind::GapWarning),
        "The estimated opened gap is at or above the gap warning threshold",
        |d| Some(Value::Bool(d.gap_warning)),
    ),
    flag(
        "gap_alarm",
        5,
        Stale::Kept,
        Some(AlarmKind::GapAlarm),
        "The gap's 90% interval lay at or above the gap alarm threshold; latched until acknowledged",
        |d| Some(Value::Bool(d.gap_alarm)),
    ),
    flag(
        "restored",
        6,
        Stale::Kept,
        None,
        "The values are from before the gateway's last restart (restored from the history; last_bite_time says when); cleared by the next bite",
        |d| Some(Value::Bool(d.restored)),
    ),
];

/// A tandem mill's chatter figures, of its last window.
pub const TANDEM_MILL: &[Figure<TandemMillResults>] = &[
    count("evaluations", "Chatter windows evaluated since start", |m| {
        Some(Value::Count(m.evaluations))
    }),
    real(
        "sigma_n_hz",
        "Hz",
        0,
        Stale::Withdrawn,
        "RMS deviation of the adjacent stands' principal chatter-band frequencies",
        |m| real_of(m.sigma_n_hz),
    ),
    with_range(
        real(
            "k_mean",
            "",
            1,
            Stale::Withdrawn,
            "Mean correlation of adjacent stands' chatter-band vibration over the window",
            |m| real_of(m.k_mean),
        ),
        -1.0,
        1.0,
    ),
    real(
        "chatter_frequency_hz",
        "Hz",
        2,
        Stale::Withdrawn,
        "Mean principal frequency of the stands in the chatter band",
        |m| real_of(m.chatter_frequency_hz),
    ),
    real(
        "chatter_gain",
        "",
        3,
        Stale::Withdrawn,
        "Largest chatter-band gain of any stand: chatter-band RMS / reference-band RMS over gain_window_s",
        |m| real_of(m.chatter_gain),
    ),
    real(
        "gain_ratio",
        "",
        4,
        Stale::Withdrawn,
        "Largest gain / gain_thresholds[stand] of any stand: the early-warning figure, >= 1 is the band-gain alarm",
        |m| real_of(m.gain_ratio),
    ),
    real(
        "band_rms_max",
        "",
        5,
        Stale::Withdrawn,
        "Largest chatter-band RMS of any stand over gain_window_s, in the stand channels' unit",
        |m| real_of(m.band_rms_max),
    ),
    typed(
        real(
            "worst_stand",
            "",
            6,
            Stale::Withdrawn,
            "Stand of gain_ratio, 1-based in the mill's stands order",
            |m| index_of(m.worst_stand.map(|stand| stand + 1)),
        ),
        FigureType::Index,
    ),
    flag(
        "chatter_warning",
        0,
        Stale::Kept,
        Some(AlarmKind::ChatterWarning),
        "The configured detector's warning in the last window (band gain: gain_ratio >= slow_down_release; paper: sigma_n <= sigma_min)",
        |m| Some(Value::Bool(m.chatter_warning)),
    ),
    flag(
        "chatter_alarm",
        1,
        Stale::Kept,
        Some(AlarmKind::ChatterAlarm),
        "The configured detector's alarm held in a window (band gain: gain_ratio >= 1; paper: both conditions); latched until acknowledged",
        |m| Some(Value::Bool(m.chatter_alarm)),
    ),
    flag(
        "source_stale",
        2,
        Stale::Kept,
        None,
        "A stand's source is stale or lost, or the window restarted after a gap: the window's figures are withdrawn",
        |m| Some(Value::Bool(m.source_stale)),
    ),
    flag(
        "slow_down_request",
        3,
        Stale::Kept,
        None,
        "Slow-down request to the PLC, with hysteresis (set by the alarm condition, cleared after slow_down_hold_s below slow_down_release; held while stale): the PLC decides the speed drop",
        |m| Some(Value::Bool(m.slow_down_request)),
    ),
];

fn rod_value(mill: &RodMillResults, value: Option<Value>) -> Option<Value> {
    value.filter(|_| mill.valid())
}

/// A rod mill's own figures: its operating point and its worst span.
pub const ROD_MILL: &[Figure<RodMillResults>] = &[
    count(
        "evaluations",
        "Evaluations since start (one per change of the inputs)",
        |r| Some(Value::Count(r.evaluations)),
    ),
    typed(
        real(
            "configuration",
            "",
            0,
            Stale::Withdrawn,
            "Drive configuration in use: the PLC's value, an index into the rod mill's configurations",
            |r| rod_value(r, r.configuration.map(|c| Value::Index(u64::from(c)))),
        ),
        FigureType::Index,
    ),
    typed(
        real(
            "pass",
            "",
            1,
            Stale::Withdrawn,
            "Pass in use: the PLC's pass number (1-based row of the schedule)",
            |r| rod_value(r, r.pass.map(|p| Value::Index(u64::from(p)))),
        ),
        FigureType::Index,
    ),
    real(
        "finishing_speed_m_s",
        "m/s",
        2,
        Stale::Withdrawn,
        "Finishing speed the spans were evaluated at",
        |r| rod_value(r, real_of(r.finishing_speed_m_s)),
    ),
    real(
        "rod_temperature_c",
        "degC",
        3,
        Stale::Withdrawn,
        "Rod temperature of the pass setup in use (rounded to temperature_step_c, or the schedule's)",
        |r| rod_value(r, real_of(r.temperature_c)),
    ),
    presence(real(
        "worst_margin_m_s",
        "m/s",
        0,
        Stale::Withdrawn,
        "The smallest finishing-speed margin of the valid spans (negative: a span is unstable)",
        |r| r.worst_span().map(|(_, margin)| Value::Real(margin)),
    )),
    presence(typed(
        real(
            "worst_span",
            "",
            0,
            Stale::Withdrawn,
            "Span of worst_margin_m_s, 1-based in rolling order",
            |r| r.worst_span().map(|(span, _)| Value::Index(span as u64 + 1)),
        ),
        FigureType::Index,
    )),
    flag(
        "unstable",
        0,
        Stale::Withdrawn,
        None,
        "A span is unstable (with hysteresis)",
        |r| rod_value(r, Some(Value::Bool(r.spans.iter().any(|s| s.unstable)))),
    ),
    flag(
        "near_tongue",
        1,
        Stale::Withdrawn,
        None,
        "A span is stable but near a tongue (speed margin < near_tongue_m_s, with hysteresis)",
        |r| rod_value(r, Some(Value::Bool(r.spans.iter().any(|s| s.near_tongue)))),
    ),
    flag(
        "invalid",
        2,
        Stale::Kept,
        None,
        "No valid result: not evaluated yet, an input's source stale or lost, or an input out of range",
        |r| Some(Value::Bool(!r.valid())),
    ),
    flag(
        "input_refused",
        3,
        Stale::Kept,
        None,
        "The last inputs were refused (configuration, pass, speed or temperature out of range)",
        |r| Some(Value::Bool(r.input_refused)),
    ),
    flag(
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
    real(
        "speed_margin_m_s",
        "m/s",
        0,
        Stale::Withdrawn,
        "Finishing-speed change to the nearest unstable band edge: > 0 stable, < 0 unstable (the change that stabilises it); none when no band lies in the speed range",
        |s| real_of(s.speed_margin_m_s),
    ),
    real(
        "worst_exponent_per_s",
        "1/s",
        1,
        Stale::Withdrawn,
        "Largest growth exponent of the span's points (< 0 decaying)",
        |s| real_of(s.worst_exponent_per_s),
    ),
    typed(
        real(
            "configuration",
            "",
            2,
            Stale::Withdrawn,
            "Drive configuration the span was evaluated in (index into the rod mill's configurations)",
            |s| s.configuration.map(|c| Value::Index(u64::from(c))),
        ),
        FigureType::Index,
    ),
    flag(
        "unstable",
        0,
        Stale::Withdrawn,
        None,
        "The span is unstable (with hysteresis)",
        |s| s.valid.then_some(Value::Bool(s.unstable)),
    ),
    flag(
        "near_tongue",
        1,
        Stale::Withdrawn,
        None,
        "The span is stable but near a tongue (speed margin < near_tongue_m_s, with hysteresis)",
        |s| s.valid.then_some(Value::Bool(s.near_tongue)),
    ),
    flag(
        "invalid",
        2,
        Stale::Kept,
        None,
        "No valid result for the span: its mill is invalid, or the mill file has fewer spans",
        |s| Some(Value::Bool(!s.valid)),
    ),
];

#[cfg(test)]
mod tests {
    use super::*;

    fn keys_unique<R>(figures: &[Figure<R>]) {
        let mut keys: Vec<&str> = figures.iter().map(|f| f.key).collect();
        keys.sort_unstable();
        let before = keys.len();
        keys.dedup();
        assert_eq!(keys.len(), before, "duplicate keys");
    }

    fn bits_unique<R>(figures: &[Figure<R>]) {
        for pick in [
            |g: Guard| matches!(g, Guard::QualityBit(_)).then_some(g),
            |g: Guard| matches!(g, Guard::FlagBit(_)).then_some(g),
        ] {
            let mut bits: Vec<Guard> = figures.iter().filter_map(|f| pick(f.guard)).collect();
            let before = bits.len();
            bits.dedup();
            assert_eq!(bits.len(), before, "a bit guards two figures");
            assert!(bits.len() <= 16, "more than a register's bits");
        }
    }

    #[test]
    fn keys_and_bits_are_unique_per_subject() {
        keys_unique(DRIVELINE);
        keys_unique(TANDEM_MILL);
        keys_unique(ROD_MILL);
        keys_unique(ROD_SPAN);
        bits_unique(DRIVELINE);
        bits_unique(TANDEM_MILL);
        bits_unique(ROD_MILL);
        bits_unique(ROD_SPAN);
    }

    #[test]
    fn a_real_figure_names_its_unit_in_its_key() {
        // Habit 15: units in names where a mix-up is likely.
        for figure in all() {
            if figure.unit.is_empty() {
                continue;
            }
            let suffix = match figure.unit {
                "kN*m" => "_knm",
                "Hz" => "_hz",
                "s" => "_s",
                "mrad" => "_mrad",
                "m/s" => "_m_s",
                "1/s" => "_per_s",
                "degC" => "_c",
                other => panic!("unit {other} has no key suffix"),
            };
            assert!(figure.key.ends_with(suffix), "{}", figure.key);
        }
    }

    #[test]
    fn the_stale_rule_withdraws_keeps_or_marks_last_usable() {
        let mut driveline = DrivelineResults {
            taf: Some(1.4),
            bite_counter: 3,
            taf_alarm: true,
            ..DrivelineResults::default()
        };
        let taf = find(DRIVELINE, "taf");
        assert_eq!(taf.read(&driveline).good(), Some(Value::Real(1.4)));
        driveline.source_stale = true;
        let reading = taf.read(&driveline);
        assert_eq!(reading.quality, Quality::LastUsable);
        assert_eq!(reading.good(), None);
        assert_eq!(reading.usable(), Some(Value::Real(1.4)));
        let counter = find(DRIVELINE, "bite_counter").read(&driveline);
        assert_eq!(counter.good(), Some(Value::Count(3)));
        let alarm = find(DRIVELINE, "taf_alarm").read(&driveline);
        assert_eq!(alarm.good(), Some(Value::Bool(true)));
        let gap = find(DRIVELINE, "gap_mrad").read(&driveline);
        assert_eq!(gap.quality, Quality::Bad(NoValue::SourceStale));

        let mut mill = TandemMillResults {
            sigma_n_hz: Some(0.5),
            ..TandemMillResults::default()
        };
        let sigma = find(TANDEM_MILL, "sigma_n_hz");
        assert_eq!(sigma.read(&mill).quality, Quality::Good);
        mill.source_stale = true;
        let reading = sigma.read(&mill);
        assert_eq!(reading.quality, Quality::Bad(NoValue::SourceStale));
        assert_eq!(
            reading.usable(),
            None,
            "a window of a stale mill is withdrawn"
        );
    }
}
