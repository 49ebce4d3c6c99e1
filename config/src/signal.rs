//! Where a CAN signal sits in a frame, resolved from a DBC file at load time.

/// Bit layout and scaling of one DBC signal inside one CAN (or CAN FD) frame.
///
/// Physical value = raw * `factor` + `offset`, raw being the `size`-bit field at
/// `start_bit` in DBC numbering (Intel: LSB position; Motorola: MSB position in the
/// DBC "sawtooth" numbering), sign-extended when `signed`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SignalLayout {
    /// CAN identifier of the message (11- or 29-bit).
    pub frame_id: u32,
    /// True for a 29-bit (extended) identifier.
    pub extended: bool,
    /// Data length of the message in bytes as declared in the DBC (0..=64).
    pub frame_len: u8,
    /// DBC start bit.
    pub start_bit: u16,
    /// Width in bits, 1..=64.
    pub size: u8,
    /// Intel (little-endian) byte order when true, Motorola (big-endian) otherwise.
    pub little_endian: bool,
    /// Two's-complement signed raw value.
    pub signed: bool,
    pub factor: f64,
    pub offset: f64,
}
