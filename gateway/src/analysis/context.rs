//! A mill's process context ([`ContextTracker`]): a driveline's at each bite, and
//! whether the bite is pooled into the wear trend ([`BiteGate`]); a tandem mill's at
//! each chatter episode and capture ([`ContextTracker::reading`]).
//!
//! - **Values**: the latest value of each context tag (`drivelines[].context`) and
//!   when it came; a value older than its source's stale time ([`max_age`]: a tag
//!   its PLC no longer delivers, its source stale) is left out, as if the tag were
//!   not configured.
//! - **At a bite** (when its window is complete) the fresh values are checked
//!   ([`RawContext::check`]): an impossible value (negative speed, a product not in
//!   `products`, an unknown state) makes the context invalid: not used for the
//!   gating (the bite is pooled as without context) and counted.
//! - **The gate**: a bite while the state is idle, threading or maintenance, or
//!   rolled outside `pool_speed_range_mpm`, is recorded with its figures but not
//!   folded into the wear trend (the gap, its growth and forecast) nor into the wear
//!   index's trend; a bite whose state or speed is unknown is pooled.

use std::time::{Duration, Instant};

use millgate_config::text::{AsciiText, TextError};
use millgate_config::{ChannelSource, Config, ContextTags};

use crate::state::context::{
    any_weld, BiteGate, ContextError, ContextReading, ProcessContext, RawContext, StaleTags,
};

/// Poll periods of its channel after which a context value is no longer used (at
/// least; see [`max_age`]).
pub(crate) const CONTEXT_POLLS: f64 = 3.0;

/// How long a value of `channel` of `config` is used: its source's stale time, three
/// poll periods or two timeouts of a Modbus source (whichever is longer), three
/// periods or 1 s of a CAN signal.
fn max_age(config: &Config, channel: usize) -> Duration {
    let channel = &config.channels[channel];
    let polls = Duration::from_secs_f64(CONTEXT_POLLS / channel.sample_rate_hz);
    match channel.source {
        ChannelSource::ModbusValue { source, .. }
        | ChannelSource::ModbusBlock { source, .. }
        | ChannelSource::ModbusText { source, .. } => {
            polls.max(config.modbus_sources[source].timeout * 2)
        }
        ChannelSource::Can { .. } => polls.max(Duration::from_secs(1)),
    }
}

/// The context of one bite: what was read, and the gate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BiteContext {
    /// The checked context; `Err` when a value was impossible (not used).
    pub context: Result<ProcessContext, ContextError>,
    /// Whether the bite was pooled, and if not why.
    pub gate: BiteGate,
    /// The configured tags left out as stale.
    pub stale: StaleTags,
}

impl BiteContext {
    /// The context as its bite's capture keeps it.
    pub fn reading(&self) -> ContextReading {
        ContextReading {
            context: self.context,
            stale: self.stale,
        }
    }
}

/// A context tag's value as read: a number, or a text channel's text (a coil id) or
/// why its registers held none.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum TagValue {
    /// A process value in engineering units.
    Number(f64),
    /// A `type = "ascii"` channel's text.
    Text(Result<AsciiText, TextError>),
}

/// The latest context values of a driveline, for its bites.
#[derive(Debug, Clone)]
pub(crate) struct ContextTracker {
    /// The configured tags: key, channel, the oldest value still used.
    tags: Vec<(&'static str, usize, Duration)>,
    /// Per tag, the latest value and when it came.
    latest: Vec<Option<(TagValue, Instant)>>,
    products: Vec<u32>,
    speed_range_mpm: Option<(f64, f64)>,
}

impl ContextTracker {
    /// The tracker of `tags` (channels of `config`), gating on `speed_range_mpm`;
    /// `None` without tags.
    pub(crate) fn new(
        tags: &ContextTags,
        config: &Config,
        speed_range_mpm: Option<(f64, f64)>,
    ) -> Option<Self> {
        // A tandem mill's per-stand weld bits make its `weld`: 1 while any stand has it.
        let configured: Vec<_> = tags
            .tags()
            .chain(tags.weld_stands.iter().map(|&channel| ("weld", channel)))
            .map(|(key, channel)| (key, channel, max_age(config, channel)))
            .collect();
        (!configured.is_empty()).then(|| Self {
            latest: vec![None; configured.len()],
            tags: configured,
            products: tags.products.clone(),
            speed_range_mpm,
        })
    }

    /// The latest value of tag `key`, however old; `None` before the first or
    /// without the tag.
    pub(crate) fn latest(&self, key: &str) -> Option<f64> {
        match self.latest_value(key)? {
            TagValue::Number(value) => Some(value),
            TagValue::Text(_) => None,
        }
    }

    /// [`Self::latest`], a number or a text.
    pub(crate) fn latest_value(&self, key: &str) -> Option<TagValue> {
        let position = self.tags.iter().position(|tag| tag.0 == key)?;
        self.latest[position].map(|(value, _)| value)
    }

    /// The channels of the tags.
    pub(crate) fn channels(&self) -> impl Iterator<Item = usize> + '_ {
        self.tags.iter().map(|&(_, channel, _)| channel)
    }

    /// A value of `channel` read at `now`.
    pub(crate) fn value(&mut self, channel: usize, value: TagValue, now: Instant) {
        for (tag, latest) in self.tags.iter().zip(&mut self.latest) {
            if tag.1 == channel {
                *latest = Some((value, now));
            }
        }
    }

    /// The context at `now`, from the values no older than their tag's bound (an
    /// older one is left out and named stale), checked.
    pub(crate) fn reading(&self, now: Instant) -> ContextReading {
        let mut raw = RawContext::default();
        let mut stale = StaleTags::default();
        for (&(key, _, max_age), latest) in self.tags.iter().zip(&self.latest) {
            let fresh = latest
                .filter(|&(_, at)| now.saturating_duration_since(at) <= max_age)
                .map(|(value, _)| value);
            if fresh.is_none() {
                stale.insert(key);
            }
            // Only a coil can be a text (`check` refuses a text channel elsewhere).
            let fresh = match fresh {
                Some(TagValue::Text(text)) => {
                    raw.coil_text = Some(text);
                    continue;
                }
                Some(TagValue::Number(value)) => Some(value),
                None => None,
            };
            let field = match key {
                "weld" => {
                    raw.weld = any_weld(raw.weld, fresh);
                    continue;
                }
                "speed_mpm" => &mut raw.speed_mpm,
                "coil" => &mut raw.coil,
                "product" => &mut raw.product,
                "thickness_mm" => &mut raw.thickness_mm,
                "pass" => &mut raw.pass,
                _ => &mut raw.state,
            };
            *field = fresh;
        }
        ContextReading {
            context: raw.check(&self.products),
            stale,
        }
    }

    /// The context of a bite whose window completed at `now` ([`Self::reading`]),
    /// and its gate.
    pub(crate) fn at(&self, now: Instant) -> BiteContext {
        let ContextReading { context, stale } = self.reading(now);
        let gate = match &context {
            Ok(context) => BiteGate::of(context, self.speed_range_mpm),
            Err(_) => BiteGate::Pooled,
        };
        BiteContext {
            context,
            gate,
            stale,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::state::context::{Coil, ContextStatus};

    /// A coil and a product tag (channels 0 and 1) used for 300 ms, product 205 the
    /// only one known.
    fn tracker() -> ContextTracker {
        let bound = Duration::from_millis(300);
        ContextTracker {
            tags: vec![("coil", 0, bound), ("product", 1, bound)],
            latest: vec![None; 2],
            products: vec![205],
            speed_range_mpm: None,
        }
    }

    /// A value past its bound is left out and named stale (the other kept); an
    /// impossible one makes the whole reading invalid; a tag never read is stale.
    #[test]
    fn a_reading_leaves_out_and_names_a_stale_tag_and_keeps_nothing_invalid() {
        let t0 = Instant::now();
        let mut tracker = tracker();
        let never = tracker.reading(t0);
        assert_eq!(never.status(), ContextStatus::Stale);
        assert_eq!(never.stale.keys().collect::<Vec<_>>(), ["coil", "product"]);
        tracker.value(0, TagValue::Number(4711.0), t0);
        tracker.value(1, TagValue::Number(205.0), t0 + Duration::from_millis(200));
        let fresh = tracker.reading(t0 + Duration::from_millis(300));
        assert_eq!(fresh.status(), ContextStatus::Valid);
        assert_eq!(
            (fresh.trusted().coil, fresh.trusted().product),
            (Some(Coil::Number(4711)), Some(205))
        );
        let later = tracker.reading(t0 + Duration::from_millis(450));
        assert_eq!(later.status(), ContextStatus::Stale);
        assert_eq!(later.stale.keys().collect::<Vec<_>>(), ["coil"]);
        assert_eq!(
            (later.trusted().coil, later.trusted().product),
            (None, Some(205))
        );
        tracker.value(1, TagValue::Number(7.0), t0 + Duration::from_millis(400));
        let invalid = tracker.reading(t0 + Duration::from_millis(450));
        assert_eq!(invalid.status(), ContextStatus::Invalid);
        assert_eq!(invalid.trusted(), ProcessContext::default());
        // The bite's context says the same.
        let bite = tracker.at(t0 + Duration::from_millis(450));
        assert_eq!(bite.reading(), invalid);
        assert_eq!(bite.gate, BiteGate::Pooled);
    }

    /// A text coil (`type = "ascii"`) is the coil; junk in its registers makes the
    /// reading invalid, saying why, and keeps nothing.
    #[test]
    fn a_text_coil_is_the_coil_and_junk_makes_the_reading_invalid() {
        let t0 = Instant::now();
        let mut tracker = tracker();
        let text = AsciiText::new("CH-4711").unwrap();
        tracker.value(0, TagValue::Text(Ok(text)), t0);
        tracker.value(1, TagValue::Number(205.0), t0);
        let reading = tracker.reading(t0);
        assert_eq!(reading.status(), ContextStatus::Valid);
        assert_eq!(reading.trusted().coil, Some(Coil::Text(text)));
        assert_eq!(tracker.latest("coil"), None, "a text is no number");
        let junk = TextError::NotPrintable {
            position: 2,
            byte: 0xFF,
        };
        tracker.value(0, TagValue::Text(Err(junk)), t0);
        let reading = tracker.reading(t0);
        assert_eq!(reading.context, Err(ContextError::CoilText(junk)));
        assert_eq!(reading.trusted(), ProcessContext::default());
        assert_eq!(
            reading.context.unwrap_err().to_string(),
            "coil text character 2 is byte 0xFF (must be printable ASCII 0x20..=0x7E, the \
             text ending at a NUL)"
        );
    }
}
