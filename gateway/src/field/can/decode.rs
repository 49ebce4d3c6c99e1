//! [`CanDecoder`]: a data frame's payload -> the engineering values of the configured
//! channels it carries, from their DBC signal layouts (pure, host-testable); and the
//! bus state an error frame reports.

use std::collections::HashMap;

use millgate_config::signal::SignalLayout;
use millgate_config::{ChannelSource, Config, Scaling};

use crate::field::counters::BusState;
use crate::field::quality::{saturation_limits, SaturationLimits};

/// Error-frame class bits in the CAN id and controller status bits in `data[1]`
/// (linux/can/error.h).
mod error_bits {
    pub(super) const CRTL: u32 = 0x0004;
    pub(super) const BUSOFF: u32 = 0x0040;
    pub(super) const RESTARTED: u32 = 0x0100;
    pub(super) const CRTL_RX_PASSIVE: u8 = 0x10;
    pub(super) const CRTL_TX_PASSIVE: u8 = 0x20;
    pub(super) const CRTL_ACTIVE: u8 = 0x40;
}

/// The bus state an error frame reports, if it reports one: bus off, error passive,
/// or back to error active (controller restarted or recovered).
pub(crate) fn bus_state_of_error_frame(class_bits: u32, data: &[u8]) -> Option<BusState> {
    use error_bits::*;
    let controller = if class_bits & CRTL != 0 {
        data.get(1).copied().unwrap_or(0)
    } else {
        0
    };
    if class_bits & BUSOFF != 0 {
        Some(BusState::BusOff)
    } else if controller & (CRTL_RX_PASSIVE | CRTL_TX_PASSIVE) != 0 {
        Some(BusState::Passive)
    } else if class_bits & RESTARTED != 0 || controller & CRTL_ACTIVE != 0 {
        Some(BusState::Active)
    } else {
        None
    }
}

/// What [`CanDecoder::decode`] made of one data frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FrameOutcome {
    /// Every signal of the frame's channels was decoded.
    Decoded,
    /// No channel uses this id; nothing decoded.
    UnknownId,
    /// The frame is too short for at least one of its signals; nothing decoded, so
    /// the channels of one message stay sample-aligned.
    BadLength,
}

/// A configured channel carried by one CAN message.
#[derive(Debug, Clone, Copy, PartialEq)]
struct ChannelSignal {
    channel: usize,
    layout: SignalLayout,
    /// The DBC's factor and offset ([`SignalLayout::scaling`]).
    dbc: Scaling,
    /// The channel's own scale and offset, applied after the DBC's.
    scaling: Scaling,
}

/// Signals of one message and the length they need.
#[derive(Debug, Clone, PartialEq)]
struct MessageSignals {
    signals: Vec<ChannelSignal>,
    /// Largest [`SignalLayout::bytes_needed`] among `signals`.
    bytes_needed: usize,
}

/// Pure frame decoder: (id, extended, payload) -> samples of the configured channels.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct CanDecoder {
    /// Keyed by (identifier, extended).
    messages: HashMap<(u32, bool), MessageSignals>,
    /// Saturation limits of the measured channels (torque, acceleration).
    limits: Vec<(usize, SaturationLimits)>,
}

impl CanDecoder {
    /// Decoder for the channels of CAN source `source_index` of `config`.
    ///
    /// A source without channels gives a decoder that counts every frame as unknown.
    pub fn for_source(config: &Config, source_index: usize) -> Self {
        let mut decoder = CanDecoder::default();
        for (channel, settings) in config.channels.iter().enumerate() {
            if let ChannelSource::Can {
                source,
                signal_layout,
                ..
            } = &settings.source
            {
                if *source == source_index {
                    decoder.add(channel, *signal_layout, settings.scale, settings.offset);
                    let limits = saturation_limits(settings);
                    if limits != SaturationLimits::NONE {
                        decoder.limits.push((channel, limits));
                    }
                }
            }
        }
        decoder
    }

    /// Adds channel index `channel`, read from `layout` then scaled by the channel's
    /// `scale` and `offset` (1 and 0 for plain DBC values).
    pub fn add(&mut self, channel: usize, layout: SignalLayout, scale: f64, offset: f64) {
        let message = self
            .messages
            .entry((layout.frame_id, layout.extended))
            .or_insert_with(|| MessageSignals {
                signals: Vec::new(),
                bytes_needed: 0,
            });
        message.bytes_needed = message.bytes_needed.max(layout.bytes_needed());
        message.signals.push(ChannelSignal {
            channel,
            layout,
            dbc: layout.scaling(),
            scaling: Scaling::new(scale, offset),
        });
    }

    /// Indices of the channels the decoder fills, in configuration order.
    pub fn channels(&self) -> Vec<usize> {
        let mut channels: Vec<usize> = self
            .messages
            .values()
            .flat_map(|message| message.signals.iter().map(|signal| signal.channel))
            .collect();
        channels.sort_unstable();
        channels.dedup();
        channels
    }

    /// Indices of the channels message `frame_id`/`extended` carries (none for an id no
    /// channel uses), in configuration order.
    pub(crate) fn channels_of(
        &self,
        frame_id: u32,
        extended: bool,
    ) -> impl Iterator<Item = usize> + '_ {
        self.messages
            .get(&(frame_id, extended))
            .into_iter()
            .flat_map(|message| message.signals.iter().map(|signal| signal.channel))
    }

    /// The saturation limits of the measured channels of the source (torque and
    /// acceleration: [`crate::field::quality::saturation_limits`]); channels added with
    /// [`Self::add`] have none.
    pub fn saturation_limits(&self) -> Vec<(usize, SaturationLimits)> {
        self.limits.clone()
    }

    /// Number of channels the decoder fills.
    #[cfg(test)]
    fn channel_count(&self) -> usize {
        self.messages
            .values()
            .map(|message| message.signals.len())
            .sum()
    }

    /// Decodes data frame `frame_id`/`extended` with payload `data`, appending
    /// `(channel index, engineering value)` pairs to `samples` in configuration order.
    ///
    /// Appends nothing unless the outcome is [`FrameOutcome::Decoded`].
    pub fn decode(
        &self,
        frame_id: u32,
        extended: bool,
        data: &[u8],
        samples: &mut Vec<(usize, f64)>,
    ) -> FrameOutcome {
        let Some(message) = self.messages.get(&(frame_id, extended)) else {
            return FrameOutcome::UnknownId;
        };
        if data.len() < message.bytes_needed {
            return FrameOutcome::BadLength;
        }
        let start = samples.len();
        for signal in &message.signals {
            match signal.layout.decode_count(data) {
                Some(count) => samples.push((
                    signal.channel,
                    signal.scaling.apply(signal.dbc.apply(count)),
                )),
                None => {
                    // Unreachable once `bytes_needed` passed, unless a layout has an
                    // invalid size; then drop the whole frame, as for a short one.
                    samples.truncate(start);
                    return FrameOutcome::BadLength;
                }
            }
        }
        FrameOutcome::Decoded
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    #[test]
    fn error_frames_tell_the_bus_state() {
        // Class bits and data[1] as in linux/can/error.h.
        assert_eq!(
            bus_state_of_error_frame(0x04, &[0, 0x10, 0, 0, 0, 0, 0, 0]),
            Some(BusState::Passive)
        );
        assert_eq!(
            bus_state_of_error_frame(0x04, &[0, 0x20, 0, 0, 0, 0, 0, 0]),
            Some(BusState::Passive)
        );
        assert_eq!(
            bus_state_of_error_frame(0x40, &[0; 8]),
            Some(BusState::BusOff)
        );
        assert_eq!(
            bus_state_of_error_frame(0x44, &[0, 0x10, 0, 0, 0, 0, 0, 0]),
            Some(BusState::BusOff)
        );
        assert_eq!(
            bus_state_of_error_frame(0x100, &[0; 8]),
            Some(BusState::Active)
        );
        assert_eq!(
            bus_state_of_error_frame(0x04, &[0, 0x40, 0, 0, 0, 0, 0, 0]),
            Some(BusState::Active)
        );
        assert_eq!(
            bus_state_of_error_frame(0x04, &[0, 0x04, 0, 0, 0, 0, 0, 0]),
            None,
            "RX warning only"
        );
        assert_eq!(
            bus_state_of_error_frame(0x08, &[0; 8]),
            None,
            "protocol violation"
        );
    }

    /// Message 0x101's Intel i16 at `start_bit`, 0.01 a count (shared with the batch's
    /// tests).
    pub(crate) fn torque_layout(start_bit: u16) -> SignalLayout {
        SignalLayout {
            frame_id: 0x101,
            extended: false,
            frame_len: 8,
            start_bit,
            size: 16,
            little_endian: true,
            signed: true,
            factor: 0.01,
            offset: 0.0,
        }
    }

    fn decoder() -> CanDecoder {
        let mut decoder = CanDecoder::default();
        decoder.add(3, torque_layout(0), 1.0, 0.0);
        decoder.add(5, torque_layout(16), 2.0, 1.0);
        let oil_temp = SignalLayout {
            frame_id: 0x18ff_5a01,
            extended: true,
            frame_len: 8,
            start_bit: 0,
            size: 16,
            little_endian: true,
            signed: false,
            factor: 0.1,
            offset: -40.0,
        };
        decoder.add(7, oil_temp, 1.0, 0.0);
        decoder
    }

    #[test]
    fn decodes_channels_of_a_frame_in_order() {
        let mut samples = Vec::new();
        let outcome = decoder().decode(0x101, false, &[0x39, 0x30, 0xc3, 0xdd], &mut samples);
        assert_eq!(outcome, FrameOutcome::Decoded);
        assert_eq!(samples.len(), 2);
        assert_eq!(samples[0].0, 3);
        assert!((samples[0].1 - 123.45).abs() < 1e-9);
        assert_eq!(samples[1].0, 5);
        assert!((samples[1].1 - (-87.65 * 2.0 + 1.0)).abs() < 1e-9);
    }

    #[test]
    fn standard_and_extended_ids_are_distinct() {
        let decoder = decoder();
        let mut samples = Vec::new();
        let frame = [0x1d, 0x04, 0, 0, 0, 0, 0, 0];
        assert_eq!(
            decoder.decode(0x18ff_5a01, false, &frame, &mut samples),
            FrameOutcome::UnknownId
        );
        assert_eq!(
            decoder.decode(0x101, true, &frame, &mut samples),
            FrameOutcome::UnknownId
        );
        assert!(samples.is_empty());
        assert_eq!(
            decoder.decode(0x18ff_5a01, true, &frame, &mut samples),
            FrameOutcome::Decoded
        );
        assert_eq!(samples.len(), 1);
        assert!((samples[0].1 - 65.3).abs() < 1e-9);
    }

    #[test]
    fn short_frame_decodes_nothing() {
        let mut samples = vec![(9, 9.0)];
        // Long enough for channel 3 (bytes 0..2) but not channel 5 (bytes 2..4).
        let outcome = decoder().decode(0x101, false, &[0x39, 0x30, 0xc3], &mut samples);
        assert_eq!(outcome, FrameOutcome::BadLength);
        assert_eq!(samples, vec![(9, 9.0)], "earlier samples stay, none added");
    }

    #[test]
    fn counts_channels() {
        assert_eq!(decoder().channel_count(), 3);
        assert_eq!(CanDecoder::default().channel_count(), 0);
    }
}
