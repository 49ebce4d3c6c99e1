//! DBC files: reading them and resolving a message and signal into a [`SignalLayout`].

use std::path::Path;

use can_dbc::{ByteOrder, Dbc, MessageId, MultiplexIndicator, SignalExtendedValueType, ValueType};

use crate::signal::SignalLayout;

/// Why a message/signal pair cannot be used; turned into a message by the validator,
/// which knows the key path.
#[derive(Debug, Clone, PartialEq)]
pub(crate) enum SignalLookupError {
    /// No message of that name; the names the DBC has.
    UnknownMessage { known: Vec<String> },
    /// No signal of that name in the message; the names the message has.
    UnknownSignal { known: Vec<String> },
    /// The signal exists but millgate cannot decode it (why).
    Unsupported(String),
}

/// Reads and parses the DBC file at `path`. Windows-1252 files (common from DBC
/// editors) are accepted as well as UTF-8. The error is a one-line message.
pub(crate) fn read_dbc(path: &Path) -> Result<Dbc, String> {
    let bytes = std::fs::read(path).map_err(|error| format!("cannot read: {error}"))?;
    let text = match std::str::from_utf8(&bytes) {
        Ok(text) => std::borrow::Cow::Borrowed(text),
        Err(_) => can_dbc::decode_cp1252(&bytes)
            .ok_or_else(|| "cannot read: neither UTF-8 nor Windows-1252 text".to_owned())?,
    };
    Dbc::try_from(text.as_ref())
        .map_err(|error| format!("cannot parse: {}", one_line(&error.to_string())))
}

/// Squeezes a parser message that spans several lines (pest draws the offending
/// line with a caret) into `line:column: expectation`.
fn one_line(message: &str) -> String {
    let position = message
        .lines()
        .find_map(|line| line.trim().strip_prefix("-->"))
        .map(str::trim);
    let expectation = message
        .lines()
        .rev()
        .find_map(|line| line.trim().strip_prefix('='))
        .map(str::trim);
    match (position, expectation) {
        (Some(position), Some(expectation)) => format!("line:column {position}: {expectation}"),
        _ => message.split_whitespace().collect::<Vec<_>>().join(" "),
    }
}

/// Finds `message_name`/`signal_name` in `dbc` and returns its bit layout.
///
/// Rejects what [`SignalLayout`] cannot express: multiplexed signals, IEEE float
/// signals, a zero factor, a signal that does not fit in its frame, frames above 64
/// bytes.
pub(crate) fn signal_layout(
    dbc: &Dbc,
    message_name: &str,
    signal_name: &str,
) -> Result<SignalLayout, SignalLookupError> {
    let message = dbc
        .messages
        .iter()
        .find(|message| message.name == message_name)
        .ok_or_else(|| SignalLookupError::UnknownMessage {
            known: dbc
                .messages
                .iter()
                .map(|message| message.name.clone())
                .collect(),
        })?;
    let signal = message
        .signals
        .iter()
        .find(|signal| signal.name == signal_name)
        .ok_or_else(|| SignalLookupError::UnknownSignal {
            known: message
                .signals
                .iter()
                .map(|signal| signal.name.clone())
                .collect(),
        })?;
    let unsupported = |why: String| Err(SignalLookupError::Unsupported(why));
    if signal.multiplexer_indicator != MultiplexIndicator::Plain {
        return unsupported("multiplexed signals are not supported".to_owned());
    }
    match dbc.extended_value_type_for_signal(message.id, signal_name) {
        Some(
            SignalExtendedValueType::IEEEfloat32Bit | SignalExtendedValueType::IEEEdouble64bit,
        ) => {
            return unsupported("IEEE float signals are not supported".to_owned());
        }
        Some(SignalExtendedValueType::SignedOrUnsignedInteger) | None => {}
    }
    let (frame_id, extended) = match message.id {
        MessageId::Standard(id) => (u32::from(id), false),
        MessageId::Extended(id) => (id, true),
    };
    let Ok(frame_len @ 0..=64) = u8::try_from(message.size) else {
        return unsupported(format!(
            "message is {} bytes long (at most 64, the CAN FD maximum)",
            message.size
        ));
    };
    let Ok(size @ 1..=64) = u8::try_from(signal.size) else {
        return unsupported(format!(
            "signal is {} bits wide (must be 1..=64)",
            signal.size
        ));
    };
    let Ok(start_bit) = u16::try_from(signal.start_bit) else {
        return unsupported(format!(
            "start bit {} is beyond any frame",
            signal.start_bit
        ));
    };
    if signal.factor == 0.0 || !signal.factor.is_finite() || !signal.offset.is_finite() {
        return unsupported(format!(
            "factor {} and offset {} must be finite and the factor non-zero",
            signal.factor, signal.offset
        ));
    }
    let layout = SignalLayout {
        frame_id,
        extended,
        frame_len,
        start_bit,
        size,
        little_endian: signal.byte_order == ByteOrder::LittleEndian,
        signed: signal.value_type == ValueType::Signed,
        factor: signal.factor,
        offset: signal.offset,
    };
    if layout.bytes_needed() > usize::from(frame_len) {
        return unsupported(format!(
            "signal needs {} bytes but the message is {frame_len} bytes long",
            layout.bytes_needed()
        ));
    }
    Ok(layout)
}
