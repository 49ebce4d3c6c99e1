//! The declarations the subject tables are written with: a figure's register slot
//! with its guard, its history columns, its reader and setter, and the conversions
//! between a figure's [`Value`] and its results' fields.

use millgate_config::ValueType;

use super::{Columns, Figure, FigureType, Guard, Register, Slot, Spec, Stale, Value};
use crate::state::catalogue::AlarmKind;

/// At `offset` of the subject's block as `value_type`, valid while bit `quality_bit`
/// of the block's quality register is set.
pub(super) const fn at(offset: u16, value_type: ValueType, quality_bit: u8) -> Slot {
    Slot {
        register: Register::At {
            page: 0,
            offset,
            value_type,
        },
        guard: Guard::QualityBit(quality_bit),
    }
}

/// At `offset` of the subject's extension block as `value_type`, valid while bit
/// `quality_bit` of the extension block's quality register is set.
pub(super) const fn ext(offset: u16, value_type: ValueType, quality_bit: u8) -> Slot {
    Slot {
        register: Register::At {
            page: 1,
            offset,
            value_type,
        },
        guard: Guard::QualityBit(quality_bit),
    }
}

/// A counter at `offset` of the subject's block: always valid.
pub(super) const fn counter_at(offset: u16, value_type: ValueType) -> Slot {
    always_at(offset, value_type)
}

/// At `offset` of the subject's block (the gateway's: the global registers), always
/// valid: the heartbeat.
pub(super) const fn always_at(offset: u16, value_type: ValueType) -> Slot {
    Slot {
        register: Register::At {
            page: 0,
            offset,
            value_type,
        },
        guard: Guard::Always,
    }
}

/// Bit *i* of global register `address` for the subject of index *i*: valid while it
/// has a value.
pub(super) const fn index_bit(address: u16) -> Slot {
    Slot {
        register: Register::IndexBit { address },
        guard: Guard::Presence,
    }
}

/// Not in the register map (`why`): valid while it has a value.
pub(super) const fn unmapped(why: &'static str) -> Slot {
    Slot {
        register: Register::NotMapped(why),
        guard: Guard::Presence,
    }
}

/// A counter not in the register map (`why`): always valid.
pub(super) const fn unmapped_counter(why: &'static str) -> Slot {
    Slot {
        register: Register::NotMapped(why),
        guard: Guard::Always,
    }
}

impl Columns {
    /// Column `name` of the bite rows and of the state rows.
    pub(super) const fn both(name: &'static str) -> Self {
        Self {
            bite: Some(name),
            state: Some(name),
        }
    }

    /// Column `name` of the bite rows only (a mark of the bite, not restored).
    pub(super) const fn bite(name: &'static str) -> Self {
        Self {
            bite: Some(name),
            state: None,
        }
    }

    /// Column `name` of the state rows only (a flag a start restores).
    pub(super) const fn state(name: &'static str) -> Self {
        Self {
            bite: None,
            state: Some(name),
        }
    }
}

impl<R> Figure<R> {
    pub(super) const fn new(
        key: &'static str,
        unit: &'static str,
        figure_type: FigureType,
        slot: Slot,
        stale: Stale,
        description: &'static str,
        value: fn(&R) -> Option<Value>,
    ) -> Self {
        Figure {
            spec: Spec {
                key,
                unit,
                figure_type,
                description,
                guard: slot.guard,
                register: slot.register,
                stale,
                range: None,
                alarm: None,
                latched: false,
                metric: None,
                columns: Columns {
                    bite: None,
                    state: None,
                },
                from_window: false,
            },
            value,
            set: None,
        }
    }

    /// This figure with values of `figure_type` (a real figure that is an index, a
    /// count or a time).
    pub(super) const fn typed(mut self, figure_type: FigureType) -> Self {
        self.spec.figure_type = figure_type;
        self
    }

    /// This figure with its values in `low..=high`.
    pub(super) const fn range(mut self, low: f64, high: f64) -> Self {
        self.spec.range = Some((low, high));
        self
    }

    /// This figure named `name` on `/metrics`.
    pub(super) const fn metric(mut self, name: &'static str) -> Self {
        self.spec.metric = Some(name);
        self
    }

    /// This flag, latched until acknowledged.
    pub(super) const fn latched(mut self) -> Self {
        self.spec.latched = true;
        self
    }

    /// This figure, measured on the bite's window.
    pub(super) const fn measured_on_window(mut self) -> Self {
        self.spec.from_window = true;
        self
    }

    /// This figure kept in the history's `columns`, set back by `set` (setters run in
    /// catalogue order: a figure that makes a value others fill comes first).
    pub(super) const fn kept(mut self, columns: Columns, set: fn(&mut R, Option<Value>)) -> Self {
        self.spec.columns = columns;
        self.set = Some(set);
        self
    }
}

impl<R> Figure<R> {
    /// A real figure in `unit`, at `slot`.
    pub(super) const fn real(
        key: &'static str,
        unit: &'static str,
        slot: Slot,
        stale: Stale,
        description: &'static str,
        value: fn(&R) -> Option<Value>,
    ) -> Self {
        Self::new(key, unit, FigureType::Real, slot, stale, description, value)
    }

    /// A flag at bit `bit` of its block's flags register.
    pub(super) const fn flag(
        key: &'static str,
        bit: u8,
        stale: Stale,
        alarm: Option<AlarmKind>,
        description: &'static str,
        value: fn(&R) -> Option<Value>,
    ) -> Self {
        let slot = Slot {
            register: Register::Flag,
            guard: Guard::FlagBit(bit),
        };
        let mut figure = Self::flag_at(key, slot, stale, description, value);
        figure.spec.alarm = alarm;
        figure
    }

    /// A flag at `slot` that is not a bit of its block's flags register (a source's:
    /// [`index_bit`]).
    pub(super) const fn flag_at(
        key: &'static str,
        slot: Slot,
        stale: Stale,
        description: &'static str,
        value: fn(&R) -> Option<Value>,
    ) -> Self {
        let mut figure = Self::new(key, "", FigureType::Bool, slot, stale, description, value);
        figure.spec.range = Some((0.0, 1.0));
        figure
    }

    /// One of the named `states` (its value the index of its name, in `0..states.len()`),
    /// at `slot`; kept while a source is stale.
    pub(super) const fn state(
        key: &'static str,
        states: &'static [&'static str],
        slot: Slot,
        description: &'static str,
        value: fn(&R) -> Option<Value>,
    ) -> Self {
        let figure_type = FigureType::State(states);
        let mut figure = Self::new(key, "", figure_type, slot, Stale::Kept, description, value);
        figure.spec.range = Some((0.0, (states.len() - 1) as f64));
        figure
    }

    /// A count of events at `slot` (a counter's: [`counter_at`], [`unmapped_counter`]).
    pub(super) const fn count(
        key: &'static str,
        slot: Slot,
        description: &'static str,
        value: fn(&R) -> Option<Value>,
    ) -> Self {
        Self::new(
            key,
            "",
            FigureType::Count,
            slot,
            Stale::Kept,
            description,
            value,
        )
    }
}

pub(super) fn real_of(value: Option<f64>) -> Option<Value> {
    value.map(Value::Real)
}

pub(super) fn index_of(value: Option<usize>) -> Option<Value> {
    value.map(|v| Value::Index(v as u64))
}

/// A stored value as a real number.
pub(super) fn to_real(value: Option<Value>) -> Option<f64> {
    match value {
        Some(Value::Real(v)) => Some(v),
        _ => None,
    }
}

/// A stored value as an index.
pub(super) fn to_index(value: Option<Value>) -> Option<usize> {
    match value {
        Some(Value::Index(v)) => usize::try_from(v).ok(),
        _ => None,
    }
}

/// A stored value as a count (0 without one).
pub(super) fn to_count(value: Option<Value>) -> u64 {
    match value {
        Some(Value::Count(v)) => v,
        _ => 0,
    }
}

/// A stored value as a flag (clear without one).
pub(super) fn to_flag(value: Option<Value>) -> bool {
    value == Some(Value::Bool(true))
}

/// A stored value as a time, ms since the Unix epoch.
pub(super) fn to_time(value: Option<Value>) -> Option<i64> {
    match value {
        Some(Value::Time(ms)) => Some(ms),
        _ => None,
    }
}
