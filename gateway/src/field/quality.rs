//! Data quality by content, at the boundary: samples pinned at the converter's limits
//! (saturation) never reach the analysis as values. The readers replace every
//! saturated sample by a gap ([`split_saturated`]), so a bite window never holds one
//! (its capture ends there, marked as a gap: its values are not published as valid),
//! the detector's baseline never follows one, and coming back from full scale is the
//! end of a gap, not a rise to detect.
//!
//! The limits ([`saturation_limits`]) are the ends of the raw range of the channel's
//! encoding: raw i16 -32767 and below or 32767 for a Modbus block sample (a 16-bit
//! converter clips there; -32768 and -32767 are both its negative end, as many DAQs
//! clip symmetrically), and for a CAN torque or acceleration signal of 8 bits or more
//! the ends of its raw range (signed: as i16; unsigned: all ones, which J1939 and most
//! DBCs reserve for "not available", see [`can_signal_limits`]). Process values
//! (register values, and CAN counters, speeds, flags) have none.

use std::time::{Instant, SystemTime};

use millgate_config::signal::SignalLayout;
use millgate_config::{Channel, ChannelKind, ChannelSource, Scaling};

use crate::field::acquired::Acquired;

/// Engineering values at or beyond which a channel's samples are saturated.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SaturationLimits {
    /// At or below: saturated (may be -inf).
    pub low: f64,
    /// At or above: saturated (may be +inf).
    pub high: f64,
}

impl SaturationLimits {
    /// No limits: nothing is saturated.
    pub(crate) const NONE: Self = Self {
        low: f64::NEG_INFINITY,
        high: f64::INFINITY,
    };

    /// Whether `value` lies at or beyond a limit.
    pub fn saturated(&self, value: f64) -> bool {
        value <= self.low || value >= self.high
    }
}

/// The engineering values a raw i16 sample takes at the converter's ends (decoded as
/// the reader decodes a sample, so a raw end compares equal).
fn i16_limits(scaling: Scaling) -> SaturationLimits {
    let at = |raw: i16| scaling.apply(f64::from(raw));
    // A negative scale swaps the ends.
    let (a, b) = (at(i16::MIN + 1), at(i16::MAX));
    SaturationLimits {
        low: a.min(b),
        high: a.max(b),
    }
}

/// The saturation limits of `channel`'s samples in engineering units.
pub fn saturation_limits(channel: &Channel) -> SaturationLimits {
    match &channel.source {
        ChannelSource::ModbusBlock { .. } => i16_limits(channel.scaling()),
        // A process value on CAN (a counter, a speed, a flag) may use its whole range.
        ChannelSource::Can { .. } if channel.kind == ChannelKind::ProcessValue => {
            SaturationLimits::NONE
        }
        ChannelSource::Can { signal_layout, .. } => {
            can_signal_limits(signal_layout, channel.scale, channel.offset)
        }
        ChannelSource::ModbusValue { .. } | ChannelSource::ModbusText { .. } => {
            SaturationLimits::NONE
        }
    }
}

/// The saturation limits of a CAN signal of `layout` whose DBC value is then scaled by
/// the channel's `scale` and `offset`: for 8 bits or more, the ends of its raw range
/// (signed: as i16, at or beyond -(2^(n-1) - 1) or at 2^(n-1) - 1; unsigned: all ones,
/// which J1939 and most DBCs reserve for "not available"; an unsigned 0 is an ordinary
/// value). Narrower signals (flags, states) have none. The ends are computed as the
/// decoder computes a value, so a raw end compares equal.
pub fn can_signal_limits(layout: &SignalLayout, scale: f64, offset: f64) -> SaturationLimits {
    if !(8..=64).contains(&layout.size) {
        return SaturationLimits::NONE;
    }
    let (dbc, scaling) = (layout.scaling(), Scaling::new(scale, offset));
    let engineering = |raw: f64| scaling.apply(dbc.apply(raw));
    let (a, b) = if layout.signed {
        let max = ((1u64 << (layout.size - 1)) - 1) as f64;
        (engineering(-max), engineering(max))
    } else {
        let top = engineering((u64::MAX >> (64 - u32::from(layout.size))) as f64);
        if layout.factor * scale >= 0.0 {
            (f64::NEG_INFINITY, top)
        } else {
            (top, f64::INFINITY)
        }
    };
    SaturationLimits {
        low: a.min(b),
        high: a.max(b),
    }
}

/// Split `values` (consecutive samples of `channel`, the last received at `received`,
/// handed over at `handed`) at the saturated ones: each run of good samples becomes a
/// `Samples` message and each run of saturated ones a `Gap` of its length, in order,
/// appended to `out`. Returns the number of saturated samples. `received` stays with
/// the last message only when it is samples (the others' receive times are not known).
pub fn split_saturated(
    limits: &SaturationLimits,
    channel: usize,
    values: Vec<f64>,
    (received, handed): (Option<SystemTime>, Instant),
    out: &mut Vec<Acquired>,
) -> u64 {
    if !values.iter().any(|&v| limits.saturated(v)) {
        out.push(Acquired::Samples {
            channel,
            values,
            received,
            handed,
        });
        return 0;
    }
    let mut saturated = 0;
    let mut start = 0;
    while start < values.len() {
        let is_saturated = limits.saturated(values[start]);
        let end = values[start..]
            .iter()
            .position(|&v| limits.saturated(v) != is_saturated)
            .map_or(values.len(), |run| start + run);
        if is_saturated {
            saturated += (end - start) as u64;
            out.push(Acquired::Gap {
                channel,
                missed_samples: Some((end - start) as u64),
            });
        } else {
            out.push(Acquired::Samples {
                channel,
                values: values[start..end].to_vec(),
                received: if end == values.len() { received } else { None },
                handed,
            });
        }
        start = end;
    }
    saturated
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn modbus_limits_are_the_ends_of_raw_i16() {
        let limits = i16_limits(Scaling::new(0.01, 0.0));
        assert!(limits.saturated(327.67) && limits.saturated(-327.67) && limits.saturated(-327.68));
        assert!(!limits.saturated(327.66) && !limits.saturated(-327.66));
        let inverted = i16_limits(Scaling::new(-0.01, 5.0));
        assert!(inverted.saturated(5.0 - 327.67) && inverted.saturated(5.0 + 327.67));
        assert!(!inverted.saturated(5.0));
    }

    fn layout(size: u8, signed: bool) -> SignalLayout {
        SignalLayout {
            frame_id: 1,
            extended: false,
            frame_len: 8,
            start_bit: 0,
            size,
            little_endian: true,
            signed,
            factor: 1.0,
            offset: 0.0,
        }
    }

    #[test]
    fn can_limits_are_the_ends_of_the_raw_range_from_8_bits() {
        let i16_signal = can_signal_limits(&layout(16, true), 0.01, 0.0);
        for raw in [-32768, -32767, 32767] {
            assert!(i16_signal.saturated(f64::from(raw) * 0.01), "{raw}");
        }
        for raw in [-32766, 0, 32766] {
            assert!(!i16_signal.saturated(f64::from(raw) * 0.01), "{raw}");
        }
        let u8_signal = can_signal_limits(&layout(8, false), 1.0, 0.0);
        assert!(u8_signal.saturated(255.0));
        assert!(!u8_signal.saturated(0.0) && !u8_signal.saturated(254.0));
        assert_eq!(
            can_signal_limits(&layout(1, false), 1.0, 0.0),
            SaturationLimits::NONE,
            "a flag has no invalid value"
        );
        let inverted = can_signal_limits(&layout(8, false), -1.0, 0.0);
        assert!(inverted.saturated(-255.0) && !inverted.saturated(0.0));
    }

    #[test]
    fn only_measured_can_channels_have_limits() {
        // hot-mill.toml: RollForce and OilTemp are CAN process values (a force, a
        // temperature: their whole range is theirs); a torque on the same signal is
        // a measured channel whose raw ends mean saturated or not available.
        let config = millgate_config::load(
            &std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
                .join("../config/examples/hot-mill.toml"),
        )
        .expect("the example loads");
        let mut can_channels = config
            .channels
            .iter()
            .filter(|c| matches!(c.source, ChannelSource::Can { .. }))
            .peekable();
        assert!(
            can_channels.peek().is_some(),
            "hot-mill.toml has CAN channels"
        );
        for channel in can_channels {
            assert_eq!(channel.kind, ChannelKind::ProcessValue, "{}", channel.name);
            assert_eq!(
                saturation_limits(channel),
                SaturationLimits::NONE,
                "{}",
                channel.name
            );
            let mut torque = channel.clone();
            torque.kind = ChannelKind::Torque;
            assert_ne!(
                saturation_limits(&torque),
                SaturationLimits::NONE,
                "{}",
                channel.name
            );
        }
    }

    #[test]
    fn saturated_runs_become_gaps_of_their_length() {
        let limits = SaturationLimits {
            low: -10.0,
            high: 10.0,
        };
        let mut out = Vec::new();
        let handed = Instant::now();
        let count = split_saturated(
            &limits,
            2,
            vec![1.0, 10.0, 11.0, 2.0, 3.0, -10.0],
            (None, handed),
            &mut out,
        );
        assert_eq!(count, 3);
        assert_eq!(
            out,
            [
                Acquired::Samples {
                    channel: 2,
                    values: vec![1.0],
                    received: None,
                    handed
                },
                Acquired::Gap {
                    channel: 2,
                    missed_samples: Some(2)
                },
                Acquired::Samples {
                    channel: 2,
                    values: vec![2.0, 3.0],
                    received: None,
                    handed
                },
                Acquired::Gap {
                    channel: 2,
                    missed_samples: Some(1)
                },
            ]
        );
        out.clear();
        let t = SystemTime::UNIX_EPOCH;
        assert_eq!(
            split_saturated(&limits, 2, vec![1.0, 2.0], (Some(t), handed), &mut out),
            0
        );
        assert_eq!(
            out,
            [Acquired::Samples {
                channel: 2,
                values: vec![1.0, 2.0],
                received: Some(t),
                handed
            }]
        );
    }
}
