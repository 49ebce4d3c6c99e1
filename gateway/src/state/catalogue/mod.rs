//! The catalogue of published figures: every figure the gateway publishes exists here
//! once, with its key, unit, type, description, the bit that guards it and what a
//! stale source does to it. Every output is derived from it: the register map, the
//! Sparkplug births and data, the `/metrics` families, the web API and the OPC UA
//! address space name each figure by its key; the history keeps a figure in the
//! columns it names here and sets it back at a start through it (see
//! `mappings` for the generated table).
//!
//! # One declaration per figure
//!
//! A figure is declared once, in its subject's table ([`GATEWAY`], [`SOURCE`],
//! [`DRIVELINE`], [`TANDEM_MILL`], [`ROD_MILL`], [`ROD_SPAN`]): its key, unit and description; its [`Slot`] in the
//! register map together with the bit that guards it (`at`, `ext`, `counter_at`,
//! `unmapped`); the stale rule; how to read it from the results; and, when the
//! history keeps it, its [`Columns`] and how a start sets it back. The outputs iterate
//! the tables: adding a figure is its declaration, its computation, and a migration
//! when it gets a history column.
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

use millgate_config::ValueType;

use super::results::{
    DrivelineResults, GatewayResults, RodMillResults, RodSpanResults, SourceResults,
    TandemMillResults,
};

mod alarms;
mod declare;
mod driveline;
mod gateway;
mod rod_mill;
mod source;
mod tandem_mill;

pub use alarms::AlarmKind;
pub use driveline::DRIVELINE;
pub use gateway::GATEWAY;
pub use rod_mill::{ROD_MILL, ROD_SPAN};
pub use source::SOURCE;
pub use tandem_mill::TANDEM_MILL;

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
    /// One of these named states: the value is the index of its name (an
    /// [`Value::Index`]), the name is what a page shows and OPC UA's EnumStrings carry.
    State(&'static [&'static str]),
    /// A number that steps by one and wraps (the 16-bit heartbeat, a [`Value::Count`]):
    /// what matters is that it moves, not how far; not a count of events (a gauge on
    /// `/metrics`, whose counters would read each wrap as a restart).
    Sequence,
}

impl FigureType {
    /// `real`, `count`, `index`, `bool`, `time`, `state`, `sequence`.
    pub fn name(self) -> &'static str {
        match self {
            FigureType::Real => "real",
            FigureType::Count => "count",
            FigureType::Index => "index",
            FigureType::Bool => "bool",
            FigureType::Time => "time",
            FigureType::State(_) => "state",
            FigureType::Sequence => "sequence",
        }
    }

    /// A [`FigureType::State`]'s values with their names: `0 starting, 1 running, 2
    /// stopped`; `None` for another type.
    pub(crate) fn state_values(self) -> Option<String> {
        match self {
            FigureType::State(names) => {
                let values: Vec<String> = names
                    .iter()
                    .enumerate()
                    .map(|(value, name)| format!("{value} {name}"))
                    .collect();
                Some(values.join(", "))
            }
            _ => None,
        }
    }

    /// The name of state `index` of a [`FigureType::State`]; `None` for another type or
    /// an index past its names.
    pub(crate) fn state_name(self, index: u64) -> Option<&'static str> {
        match self {
            FigureType::State(names) => usize::try_from(index)
                .ok()
                .and_then(|index| names.get(index))
                .copied(),
            _ => None,
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
    /// Always valid (counters, the heartbeat).
    Always,
    /// Valid while it has a value; no quality or flags bit of a block (a figure the
    /// register map does not carry, or a source's flag: a bit of a global register by
    /// the source's index, [`Register::IndexBit`]).
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
    /// [`FigureType::Count`], [`FigureType::Sequence`].
    Count(u64),
    /// [`FigureType::Index`], [`FigureType::State`] (the index of its name).
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

    /// Whether this is a value of `figure_type` (a state's: an index of its names).
    fn fits(self, figure_type: FigureType) -> bool {
        match (self, figure_type) {
            (Value::Index(index), FigureType::State(names)) => {
                usize::try_from(index).is_ok_and(|index| index < names.len())
            }
            (Value::Count(_), FigureType::Sequence) => true,
            (Value::Real(_), FigureType::Real)
            | (Value::Count(_), FigureType::Count)
            | (Value::Index(_), FigureType::Index)
            | (Value::Bool(_), FigureType::Bool)
            | (Value::Time(_), FigureType::Time) => true,
            _ => false,
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
    /// The gateway itself (one).
    Gateway,
    /// A field source (a Modbus DAQ or PLC, a CAN interface), one per configured
    /// source in config order (Modbus, then CAN).
    Source,
}

impl SubjectKind {
    /// `driveline`, `tandem_mill`, `rod_mill`, `rod_span`, `gateway`, `source`: the
    /// `/metrics` prefix and label.
    pub fn name(self) -> &'static str {
        match self {
            SubjectKind::Driveline => "driveline",
            SubjectKind::TandemMill => "tandem_mill",
            SubjectKind::RodMill => "rod_mill",
            SubjectKind::RodSpan => "rod_span",
            SubjectKind::Gateway => "gateway",
            SubjectKind::Source => "source",
        }
    }
}

/// Results that figures are read from.
pub trait Subject: Default + 'static {
    /// What they describe.
    const KIND: SubjectKind;
    /// Their figures, in catalogue order.
    const FIGURES: &'static [Figure<Self>];
    /// Whether a source they are computed from is stale.
    fn source_stale(&self) -> bool;
}

impl Subject for DrivelineResults {
    const KIND: SubjectKind = SubjectKind::Driveline;
    const FIGURES: &'static [Figure<Self>] = DRIVELINE;
    fn source_stale(&self) -> bool {
        self.source_stale
    }
}

impl Subject for TandemMillResults {
    const KIND: SubjectKind = SubjectKind::TandemMill;
    const FIGURES: &'static [Figure<Self>] = TANDEM_MILL;
    fn source_stale(&self) -> bool {
        self.source_stale
    }
}

impl Subject for RodMillResults {
    const KIND: SubjectKind = SubjectKind::RodMill;
    const FIGURES: &'static [Figure<Self>] = ROD_MILL;
    fn source_stale(&self) -> bool {
        self.source_stale
    }
}

impl Subject for RodSpanResults {
    const KIND: SubjectKind = SubjectKind::RodSpan;
    const FIGURES: &'static [Figure<Self>] = ROD_SPAN;
    /// A span is read through [`RodMillResults::published_span`], which is empty (no
    /// values) while its mill's source is stale.
    fn source_stale(&self) -> bool {
        false
    }
}

impl Subject for GatewayResults {
    const KIND: SubjectKind = SubjectKind::Gateway;
    const FIGURES: &'static [Figure<Self>] = GATEWAY;
    /// The gateway's figures describe the gateway, which is never stale.
    fn source_stale(&self) -> bool {
        false
    }
}

impl Subject for SourceResults {
    const KIND: SubjectKind = SubjectKind::Source;
    const FIGURES: &'static [Figure<Self>] = SOURCE;
    /// A source's figures say how stale it is: they are never withdrawn for it.
    fn source_stale(&self) -> bool {
        false
    }
}

/// Where a figure sits in the register map.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Register {
    /// A value at `offset` of its subject's block (`page` 0) or of the subject's
    /// extension block (`page` 1, after every block: figures added since the map's
    /// first layout), as `value_type`.
    At {
        /// 0: the subject's block; 1: its extension block.
        page: u8,
        /// Offset from the page's first register (0 is the flags register, 1 the
        /// quality register).
        offset: u16,
        /// How it is encoded.
        value_type: ValueType,
    },
    /// A bit of the block's `flags` register (its [`Guard::FlagBit`]; the gateway's
    /// flags register is the global register `gateway_status`).
    Flag,
    /// Bit *i* of global register `address` for the subject of index *i* (a source's
    /// flag: source *i* in config order; sources past the 16th have no bit).
    IndexBit {
        /// The global register (below the first driveline block).
        address: u16,
    },
    /// Not in the register map, and why.
    NotMapped(&'static str),
}

/// A figure's register and the guard that says when its value may be used there:
/// declared together (`at`, `ext`, `counter_at`, `unmapped`, `unmapped_counter` in
/// the tables), so a value cannot lose its quality bit.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Slot {
    /// Where it sits.
    pub register: Register,
    /// What guards it.
    pub guard: Guard,
}

/// Where the history keeps a figure: its column in the `bites` table (a figure of
/// each bite) and in its subject's state table (what a start restores), by name.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Columns {
    /// The column of table `bites` (drivelines).
    pub bite: Option<&'static str>,
    /// The column of the subject's state table (`driveline_state`, `mill_state`).
    pub state: Option<&'static str>,
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
    /// Where it sits in the register map (declared with its guard: [`Slot`]).
    pub register: Register,
    /// What a stale source does to it.
    pub stale: Stale,
    /// The range the value lies in, where one is known (OPC UA's EURange).
    pub range: Option<(f64, f64)>,
    /// For a warning or alarm flag: the alarm kind the history records its changes as.
    pub alarm: Option<AlarmKind>,
    /// An alarm flag that stays set until acknowledged (the PLC's or HMI's command,
    /// the page, OPC UA); else it follows the analysis.
    pub latched: bool,
    /// The name on `/metrics` when the rule (`millgate_<subject>_<key>`) gives a
    /// name Prometheus' conventions refuse.
    pub metric: Option<&'static str>,
    /// Where the history keeps it (none: a flag or count of the moment).
    pub columns: Columns,
    /// Measured on the bite's window: not a result when the window is degraded (a
    /// bite row keeps what a degraded window measured, flagged `degraded`; nothing
    /// publishes it).
    pub from_window: bool,
}

impl Spec {
    /// Whether the figure only grows (until a restart without a history, or a wrap):
    /// a Prometheus counter. A count that can fall (the bites pooled) is not.
    pub(crate) fn is_counter(&self) -> bool {
        self.figure_type == FigureType::Count && self.guard == Guard::Always
    }
}

/// One published figure of results `R`: its [`Spec`] (reached through `Deref`), how
/// to read it and, when the history keeps it, how to set it back.
#[derive(Debug)]
pub struct Figure<R> {
    /// What the catalogue says of it.
    pub spec: Spec,
    value: fn(&R) -> Option<Value>,
    set: Option<fn(&mut R, Option<Value>)>,
}

impl<R> std::ops::Deref for Figure<R> {
    type Target = Spec;
    fn deref(&self) -> &Spec {
        &self.spec
    }
}

impl<R> Figure<R> {
    /// The value of `subject` as it is, without the stale rule: what the history
    /// stores.
    pub fn value(&self, subject: &R) -> Option<Value> {
        (self.value)(subject)
    }

    /// Set the figure of `subject` to `value` (from the history); `false` when the
    /// history does not keep it (nothing changed).
    pub fn set(&self, subject: &mut R, value: Option<Value>) -> bool {
        match self.set {
            Some(set) => {
                set(subject, value);
                true
            }
            None => false,
        }
    }
}

impl<R: Subject> Figure<R> {
    /// The figure of `subject` with the stale rule applied.
    pub fn read(&self, subject: &R) -> Reading {
        let value = (self.value)(subject);
        debug_assert!(value.is_none_or(|v| v.fits(self.figure_type)));
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

    /// The name of a [`FigureType::State`] figure's state in `subject` (while it has a
    /// usable value): what a page shows.
    pub(crate) fn state_name(&self, subject: &R) -> Option<&'static str> {
        match self.read(subject).usable()? {
            Value::Index(index) => self.figure_type.state_name(index),
            _ => None,
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

/// Every figure of every subject, in catalogue order: the gateway, the sources,
/// drivelines, tandem mills, rod mills, rod spans.
pub fn all() -> Vec<FigureInfo> {
    GATEWAY
        .iter()
        .map(Figure::info)
        .chain(SOURCE.iter().map(Figure::info))
        .chain(DRIVELINE.iter().map(Figure::info))
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

/// An alarm kind's name and latching are its flag's ([`Spec::alarm`]).
impl AlarmKind {
    /// The flag that carries it, and its subject.
    fn flag(self) -> (SubjectKind, &'static Spec) {
        DRIVELINE
            .iter()
            .map(|figure| (SubjectKind::Driveline, &figure.spec))
            .chain(
                TANDEM_MILL
                    .iter()
                    .map(|f| (SubjectKind::TandemMill, &f.spec)),
            )
            .chain(ROD_MILL.iter().map(|f| (SubjectKind::RodMill, &f.spec)))
            .find(|(_, spec)| spec.alarm == Some(self))
            .unwrap_or_else(|| panic!("no catalogue flag carries {self:?}"))
    }

    /// As stored and published: the key of its flag.
    pub fn name(self) -> &'static str {
        self.flag().1.key
    }

    /// Whether the alarm latches until acknowledged (else it follows the analysis).
    pub fn latched(self) -> bool {
        self.flag().1.latched
    }

    /// What it is about: a driveline, a tandem mill or a rod mill.
    pub fn subject(self) -> SubjectKind {
        self.flag().0
    }
}

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
        let page = |figure: &Figure<R>| match figure.register {
            Register::At { page, .. } => page,
            _ => 0,
        };
        for on in 0..2 {
            for pick in [
                |g: Guard| matches!(g, Guard::QualityBit(_)).then_some(g),
                |g: Guard| matches!(g, Guard::FlagBit(_)).then_some(g),
            ] {
                let mut bits: Vec<Guard> = figures
                    .iter()
                    .filter(|f| page(f) == on)
                    .filter_map(|f| pick(f.guard))
                    .collect();
                bits.sort_by_key(|guard| format!("{guard:?}"));
                let before = bits.len();
                bits.dedup();
                assert_eq!(bits.len(), before, "a bit guards two figures");
                assert!(bits.len() <= 16, "more than a register's bits");
            }
        }
    }

    #[test]
    fn keys_and_bits_are_unique_per_subject() {
        keys_unique(GATEWAY);
        keys_unique(SOURCE);
        keys_unique(DRIVELINE);
        keys_unique(TANDEM_MILL);
        keys_unique(ROD_MILL);
        keys_unique(ROD_SPAN);
        bits_unique(GATEWAY);
        bits_unique(SOURCE);
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
                "mrad/d" => "_mrad_per_day",
                "1/d" => "_per_day",
                // Days read best first: `days_to_gap_alarm`.
                "d" => {
                    assert!(figure.key.starts_with("days_"), "{}", figure.key);
                    continue;
                }
                other => panic!("unit {other} has no key suffix"),
            };
            assert!(figure.key.ends_with(suffix), "{}", figure.key);
        }
    }

    #[test]
    fn the_gateway_and_each_source_read_from_the_results() {
        use crate::field::source_health::SourceStatus;
        use crate::state::results::{GatewayState, Results};
        let mut results = Results::new(3, 0, 0);
        results.state = GatewayState::Running;
        results.heartbeat = 65_535;
        results.sources = vec![Some(SourceStatus::Ok), Some(SourceStatus::Stale), None];
        let gateway = results.gateway();
        let state = find(GATEWAY, "state");
        assert_eq!(state.read(&gateway).good(), Some(Value::Index(1)));
        assert_eq!(state.state_name(&gateway), Some("running"));
        assert_eq!(state.range, Some((0.0, 2.0)));
        let read = |key| find(GATEWAY, key).read(&gateway).good();
        assert_eq!(read("heartbeat"), Some(Value::Count(65_535)));
        assert_eq!(read("running"), Some(Value::Bool(true)));
        assert_eq!(read("stopped"), Some(Value::Bool(false)));
        assert_eq!(read("sources_ok"), Some(Value::Bool(false)));
        assert_eq!(read("source_problem"), Some(Value::Bool(true)));

        let status = find(SOURCE, "status");
        let stale = results.source(1);
        assert_eq!(status.read(&stale).good(), Some(Value::Index(1)));
        assert_eq!(status.state_name(&stale), Some("stale"));
        assert_eq!(
            find(SOURCE, "stale").read(&stale).good(),
            Some(Value::Bool(true))
        );
        assert_eq!(
            find(SOURCE, "ok").read(&stale).good(),
            Some(Value::Bool(false))
        );
        // Before its first status, and past the sources: no value at all.
        for unknown in [results.source(2), results.source(3)] {
            for figure in SOURCE {
                let reading = figure.read(&unknown);
                assert_eq!(reading.quality, Quality::Bad(NoValue::NotAvailable));
            }
            assert_eq!(status.state_name(&unknown), None);
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
