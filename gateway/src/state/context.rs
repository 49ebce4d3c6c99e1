//! The process context of a mill at one time, as the PLC reports it (weld tracking,
//! speed, coil, product, thickness, pass, state): [`RawContext`] holds the values as
//! read (a CSV's columns offline, the context tags' registers in the service), and
//! [`RawContext::check`] turns them into a [`ProcessContext`] or says which value is
//! impossible. An invalid context is not used (no gating on it) and is counted; it
//! never stops the analysis.

use millgate_config::text::{AsciiText, TextError};

/// What the mill is doing, the PLC's state code (a `state` context value).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum MillState {
    /// 0: no strip in the mill.
    Idle,
    /// 1: a new strip is threaded through the stands.
    Threading,
    /// 2: rolling.
    Rolling,
    /// 3: maintenance (roll change, inspection).
    Maintenance,
}

impl MillState {
    /// Every state, in code order (the code is the index).
    pub const ALL: [MillState; 4] = [
        MillState::Idle,
        MillState::Threading,
        MillState::Rolling,
        MillState::Maintenance,
    ];

    /// The names, in code order (the history's text).
    pub const NAMES: [&'static str; 4] = ["idle", "threading", "rolling", "maintenance"];

    /// The state of PLC code `code` (0 idle, 1 threading, 2 rolling, 3 maintenance).
    pub fn from_code(code: u32) -> Option<MillState> {
        Self::ALL.get(usize::try_from(code).ok()?).copied()
    }

    /// Its name (`rolling`), as the history keeps it.
    pub fn name(self) -> &'static str {
        Self::NAMES[self as usize]
    }

    /// The state named `name` ([`Self::name`]).
    pub fn from_name(name: &str) -> Option<MillState> {
        let code = Self::NAMES.iter().position(|n| *n == name)?;
        Some(Self::ALL[code])
    }
}

/// Why a bite is (not) pooled into the wear trend: the value of `last_bite_gated`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BiteGate {
    /// Pooled: rolling (or the state unknown), inside the speed range (or unknown).
    Pooled,
    /// Not pooled: the mill was idle, threading or in maintenance.
    State,
    /// Not pooled: the mill speed was outside `pool_speed_range_mpm`.
    Speed,
}

impl BiteGate {
    /// Every gate, in value order.
    pub const ALL: [BiteGate; 3] = [BiteGate::Pooled, BiteGate::State, BiteGate::Speed];

    /// The names, in value order (the catalogue's state figure).
    pub const NAMES: &'static [&'static str] = &["pooled", "state", "speed"];

    /// The gate of a bite rolled in `context`, pooled only inside `speed_range_mpm`.
    pub fn of(context: &ProcessContext, speed_range_mpm: Option<(f64, f64)>) -> Self {
        let outside =
            |speed: f64| speed_range_mpm.is_some_and(|(low, high)| !(low..=high).contains(&speed));
        match (context.state, context.speed_mpm) {
            (Some(MillState::Idle | MillState::Threading | MillState::Maintenance), _) => {
                BiteGate::State
            }
            (_, Some(speed)) if outside(speed) => BiteGate::Speed,
            _ => BiteGate::Pooled,
        }
    }

    /// Whether the bite goes into the wear trend.
    pub fn pooled(self) -> bool {
        self == BiteGate::Pooled
    }
}

/// The context values as read, each `None` when not configured (or not recorded).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct RawContext {
    /// The weld-tracking bit: 1 while a weld is inside the mill (from the first stand
    /// until it has left the last), else 0.
    pub weld: Option<f64>,
    /// Mill speed, m/min, >= 0.
    pub speed_mpm: Option<f64>,
    /// Coil or bar id, a whole number 0..=u32::MAX.
    pub coil: Option<f64>,
    /// Coil or bar id as a text (a `type = "ascii"` channel), or why its registers
    /// held none; when given it is the coil (a channel is a number or a text).
    pub coil_text: Option<Result<AsciiText, TextError>>,
    /// Product (steel grade) code, a whole number 0..=u32::MAX.
    pub product: Option<f64>,
    /// Strip thickness, mm, > 0.
    pub thickness_mm: Option<f64>,
    /// Pass number, a whole number 0..=u32::MAX.
    pub pass: Option<f64>,
    /// The PLC's state code ([`MillState::from_code`]).
    pub state: Option<f64>,
}

/// A checked context ([`RawContext::check`]).
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct ProcessContext {
    /// A weld is inside the mill.
    pub weld: Option<bool>,
    /// Mill speed, m/min.
    pub speed_mpm: Option<f64>,
    /// Coil or bar id.
    pub coil: Option<Coil>,
    /// Product code.
    pub product: Option<u32>,
    /// Strip thickness, mm.
    pub thickness_mm: Option<f64>,
    /// Pass number.
    pub pass: Option<u32>,
    /// What the mill is doing.
    pub state: Option<MillState>,
}

/// A coil or bar id: a whole number (u32 registers) or a text (`type = "ascii"`
/// registers). As JSON a number stays a number and a text is a string.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(untagged)]
pub enum Coil {
    /// A whole number.
    Number(u32),
    /// 1..=32 printable ASCII characters.
    Text(#[serde(serialize_with = "text_str")] AsciiText),
}

fn text_str<S: serde::Serializer>(text: &AsciiText, serializer: S) -> Result<S::Ok, S::Error> {
    serializer.serialize_str(text.as_str())
}

impl core::fmt::Display for Coil {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Coil::Number(number) => number.fmt(f),
            Coil::Text(text) => text.fmt(f),
        }
    }
}

/// An impossible context value: the context is invalid (not used, counted).
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum ContextError {
    /// The weld bit is neither 0 nor 1.
    #[error("weld {0} is not allowed (must be 0 or 1, the PLC's weld-tracking bit)")]
    Weld(f64),
    /// The speed is negative or not a number.
    #[error("speed_mpm {0} is not allowed (must be >= 0 m/min)")]
    Speed(f64),
    /// The thickness is not positive or not a number.
    #[error("thickness_mm {0} is not allowed (must be > 0 mm)")]
    Thickness(f64),
    /// A code is not a whole number in 0..=u32::MAX.
    #[error("{key} {value} is not allowed (must be a whole number 0..=4294967295)")]
    Code {
        /// `coil`, `product` or `pass`.
        key: &'static str,
        /// The value read.
        value: f64,
    },
    /// The coil's text registers hold no usable text (junk bytes, empty).
    #[error("coil text {0}")]
    CoilText(TextError),
    /// The product code is not one of the configured products.
    #[error("product {0} is not one of the configured products")]
    UnknownProduct(u32),
    /// The state code is not a known state.
    #[error("state {0} is not allowed (must be 0 idle, 1 threading, 2 rolling or 3 maintenance)")]
    State(f64),
}

/// `value` as a whole number 0..=u32::MAX, or why not.
fn code(key: &'static str, value: f64) -> Result<u32, ContextError> {
    if value.fract() == 0.0 && (0.0..=f64::from(u32::MAX)).contains(&value) {
        Ok(value as u32)
    } else {
        Err(ContextError::Code { key, value })
    }
}

impl RawContext {
    /// The checked context; `products` the known product codes (empty: any code).
    /// The first impossible value makes the whole context invalid.
    pub fn check(&self, products: &[u32]) -> Result<ProcessContext, ContextError> {
        let weld = self
            .weld
            .map(|w| match w {
                0.0 => Ok(false),
                1.0 => Ok(true),
                other => Err(ContextError::Weld(other)),
            })
            .transpose()?;
        let speed_mpm = self
            .speed_mpm
            .map(|v| {
                if v >= 0.0 {
                    Ok(v)
                } else {
                    Err(ContextError::Speed(v))
                }
            })
            .transpose()?;
        let thickness_mm = self
            .thickness_mm
            .map(|v| {
                if v > 0.0 && v.is_finite() {
                    Ok(v)
                } else {
                    Err(ContextError::Thickness(v))
                }
            })
            .transpose()?;
        let coil = match self.coil_text {
            Some(Ok(text)) => Some(Coil::Text(text)),
            Some(Err(error)) => return Err(ContextError::CoilText(error)),
            None => self
                .coil
                .map(|v| code("coil", v))
                .transpose()?
                .map(Coil::Number),
        };
        let pass = self.pass.map(|v| code("pass", v)).transpose()?;
        let product = self.product.map(|v| code("product", v)).transpose()?;
        if let Some(p) = product.filter(|p| !products.is_empty() && !products.contains(p)) {
            return Err(ContextError::UnknownProduct(p));
        }
        let state = self
            .state
            .map(|v| {
                code("state", v)
                    .ok()
                    .and_then(MillState::from_code)
                    .ok_or(ContextError::State(v))
            })
            .transpose()?;
        Ok(ProcessContext {
            weld,
            speed_mpm,
            coil,
            product,
            thickness_mm,
            pass,
            state,
        })
    }
}

/// The mill's weld bit from `so_far` (the bits combined before) and `next` (a
/// stand's, `weld_stands`): 1 when any is 1, an impossible value kept (it makes the
/// context invalid); a missing value is left out.
pub fn any_weld(so_far: Option<f64>, next: Option<f64>) -> Option<f64> {
    let bit = |value: f64| value == 0.0 || value == 1.0;
    match (so_far, next) {
        (Some(a), Some(b)) if bit(a) && bit(b) => Some(a.max(b)),
        (Some(a), Some(b)) => Some(if bit(a) { b } else { a }),
        (a, b) => a.or(b),
    }
}

/// The context tags' keys, in the configuration's order ([`StaleTags`] bit `i` is
/// key `i`).
pub const CONTEXT_KEYS: [&str; 7] = [
    "weld",
    "speed_mpm",
    "coil",
    "product",
    "thickness_mm",
    "pass",
    "state",
];

/// Configured context tags whose latest value was too old to use (its source stale,
/// or the PLC no longer delivering it): a set of [`CONTEXT_KEYS`].
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct StaleTags(u8);

impl StaleTags {
    /// Add the tag `key` (one of [`CONTEXT_KEYS`]; another key is ignored).
    pub fn insert(&mut self, key: &str) {
        if let Some(bit) = CONTEXT_KEYS.iter().position(|k| *k == key) {
            self.0 |= 1 << bit;
        }
    }

    /// No tag was stale.
    pub fn is_empty(self) -> bool {
        self.0 == 0
    }

    /// The stale tags' keys, in [`CONTEXT_KEYS`] order.
    pub fn keys(self) -> impl Iterator<Item = &'static str> {
        CONTEXT_KEYS
            .into_iter()
            .enumerate()
            .filter(move |(bit, _)| self.0 & (1 << bit) != 0)
            .map(|(_, key)| key)
    }
}

/// How far a context kept with evidence (a capture, a chatter episode) can be trusted
/// (the history's `context_status`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ContextStatus {
    /// Every configured tag had a fresh, possible value.
    Valid,
    /// At least one configured tag had no fresh value: those are unknown, the others
    /// kept.
    Stale,
    /// A value was impossible ([`ContextError`]): every value is unknown.
    Invalid,
}

impl ContextStatus {
    /// As stored: `valid`, `stale`, `invalid`.
    pub fn name(self) -> &'static str {
        match self {
            ContextStatus::Valid => "valid",
            ContextStatus::Stale => "stale",
            ContextStatus::Invalid => "invalid",
        }
    }
}

/// The context of a mill at one time as its tags gave it: the checked values (or
/// why not) and the tags left out as stale.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ContextReading {
    /// The checked context of the fresh values; `Err` when one was impossible.
    pub context: Result<ProcessContext, ContextError>,
    /// The configured tags whose value was too old (left out of `context`).
    pub stale: StaleTags,
}

impl ContextReading {
    /// The values the gateway can trust: none of an invalid context.
    pub fn trusted(&self) -> ProcessContext {
        self.context.unwrap_or_default()
    }

    /// Valid, stale or invalid.
    pub fn status(&self) -> ContextStatus {
        match (&self.context, self.stale.is_empty()) {
            (Err(_), _) => ContextStatus::Invalid,
            (Ok(_), false) => ContextStatus::Stale,
            (Ok(_), true) => ContextStatus::Valid,
        }
    }

    /// Why it is not valid (the impossible value, or the stale tags); `None` when it
    /// is.
    pub fn note(&self) -> Option<String> {
        match &self.context {
            Err(error) => Some(error.to_string()),
            Ok(_) if !self.stale.is_empty() => Some(format!(
                "no fresh value of {} (source stale or tag not delivered)",
                self.stale.keys().collect::<Vec<_>>().join(", ")
            )),
            Ok(_) => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_gate_follows_the_state_and_the_speed_range() {
        let context = |state, speed_mpm| ProcessContext {
            state,
            speed_mpm,
            ..ProcessContext::default()
        };
        let range = Some((100.0, 400.0));
        for (state, speed, gate) in [
            (None, None, BiteGate::Pooled),
            (Some(MillState::Rolling), Some(250.0), BiteGate::Pooled),
            (Some(MillState::Rolling), Some(100.0), BiteGate::Pooled),
            (Some(MillState::Rolling), Some(400.0), BiteGate::Pooled),
            (Some(MillState::Rolling), Some(99.9), BiteGate::Speed),
            (None, Some(400.1), BiteGate::Speed),
            (Some(MillState::Threading), Some(250.0), BiteGate::State),
            (Some(MillState::Maintenance), None, BiteGate::State),
            (Some(MillState::Idle), Some(0.0), BiteGate::State),
        ] {
            assert_eq!(
                BiteGate::of(&context(state, speed), range),
                gate,
                "{state:?} {speed:?}"
            );
        }
        // Without a range any speed is pooled.
        assert_eq!(
            BiteGate::of(&context(Some(MillState::Rolling), Some(9999.0)), None),
            BiteGate::Pooled
        );
    }

    #[test]
    fn a_text_coil_is_the_coil_and_serializes_as_a_string_a_number_as_a_number() {
        let text = AsciiText::new("CH-4711").unwrap();
        let raw = RawContext {
            coil_text: Some(Ok(text)),
            product: Some(205.0),
            ..RawContext::default()
        };
        let checked = raw.check(&[]).unwrap();
        assert_eq!(checked.coil, Some(Coil::Text(text)));
        let json = |coil| serde_json::to_value(ProcessContext { coil, ..checked }).unwrap();
        assert_eq!(
            json(Some(Coil::Text(text)))["coil"],
            serde_json::json!("CH-4711")
        );
        assert_eq!(json(Some(Coil::Number(42)))["coil"], serde_json::json!(42));
        assert_eq!(Coil::Text(text).to_string(), "CH-4711");
    }

    #[test]
    fn possible_values_pass_and_each_impossible_one_invalidates_the_context() {
        let raw = RawContext {
            weld: Some(1.0),
            speed_mpm: Some(1200.0),
            coil: Some(4_000_000_123.0),
            coil_text: None,
            product: Some(205.0),
            thickness_mm: Some(0.25),
            pass: Some(3.0),
            state: Some(2.0),
        };
        let checked = raw.check(&[101, 205]).unwrap();
        assert_eq!(checked.weld, Some(true));
        assert_eq!(checked.coil, Some(Coil::Number(4_000_000_123)));
        assert_eq!(checked.state, Some(MillState::Rolling));
        assert_eq!(
            RawContext::default().check(&[]),
            Ok(ProcessContext::default())
        );
        let bad = |change: fn(&mut RawContext)| {
            let mut r = raw;
            change(&mut r);
            r.check(&[101, 205]).unwrap_err().to_string()
        };
        assert!(bad(|r| r.weld = Some(0.5)).starts_with("weld 0.5 is not allowed"));
        assert!(bad(|r| r.speed_mpm = Some(-3.0)).starts_with("speed_mpm -3 is not"));
        assert!(bad(|r| r.speed_mpm = Some(f64::NAN)).starts_with("speed_mpm NaN"));
        assert!(bad(|r| r.thickness_mm = Some(0.0)).starts_with("thickness_mm 0 is"));
        assert!(bad(|r| r.coil = Some(-1.0)).starts_with("coil -1 is not allowed"));
        assert!(bad(|r| r.pass = Some(2.5)).starts_with("pass 2.5 is not allowed"));
        assert_eq!(
            bad(|r| r.coil_text = Some(Err(TextError::Empty))),
            "coil text is empty (no character before the first NUL)"
        );
        assert_eq!(
            bad(|r| r.product = Some(7.0)),
            "product 7 is not one of the configured products"
        );
        assert!(bad(|r| r.state = Some(4.0)).starts_with("state 4 is not allowed"));
        // Without a product list any code is a product.
        let mut any = raw;
        any.product = Some(7.0);
        assert_eq!(any.check(&[]).unwrap().product, Some(7));
    }

    #[test]
    fn the_stands_weld_bits_make_the_mills_and_keep_an_impossible_one() {
        assert_eq!(any_weld(Some(0.0), Some(1.0)), Some(1.0));
        assert_eq!(any_weld(Some(0.0), Some(0.0)), Some(0.0));
        assert_eq!(any_weld(None, Some(0.0)), Some(0.0));
        assert_eq!(any_weld(Some(1.0), None), Some(1.0));
        assert_eq!(any_weld(Some(1.0), Some(0.5)), Some(0.5));
        assert_eq!(any_weld(Some(2.0), Some(1.0)), Some(2.0));
        let raw = RawContext {
            weld: any_weld(Some(1.0), Some(3.0)),
            ..RawContext::default()
        };
        assert_eq!(raw.check(&[]), Err(ContextError::Weld(3.0)));
    }

    #[test]
    fn a_reading_says_whether_it_is_valid_stale_or_invalid_and_trusts_no_invalid_value() {
        let fresh = ProcessContext {
            coil: Some(Coil::Number(42)),
            product: Some(205),
            ..ProcessContext::default()
        };
        let valid = ContextReading {
            context: Ok(fresh),
            stale: StaleTags::default(),
        };
        assert_eq!(
            (valid.status(), valid.note(), valid.trusted()),
            (ContextStatus::Valid, None, fresh)
        );
        let mut stale_tags = StaleTags::default();
        stale_tags.insert("product");
        stale_tags.insert("coil");
        stale_tags.insert("no_such_tag");
        assert_eq!(stale_tags.keys().collect::<Vec<_>>(), ["coil", "product"]);
        let stale = ContextReading {
            context: Ok(ProcessContext::default()),
            stale: stale_tags,
        };
        assert_eq!(stale.status().name(), "stale");
        assert_eq!(
            stale.note().as_deref(),
            Some("no fresh value of coil, product (source stale or tag not delivered)")
        );
        let invalid = ContextReading {
            context: Err(ContextError::UnknownProduct(7)),
            stale: StaleTags::default(),
        };
        assert_eq!(invalid.status().name(), "invalid");
        assert_eq!(invalid.trusted(), ProcessContext::default());
        assert_eq!(
            invalid.note().as_deref(),
            Some("product 7 is not one of the configured products")
        );
    }
}
