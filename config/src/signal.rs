//! Where a CAN signal sits in a frame, resolved from a DBC file at load time.
//!
//! [`SignalLayout::decode`] turns frame bytes into an engineering value and
//! [`SignalLayout::encode`] does the reverse (used by the simulated CAN node and the
//! tests). Both handle Intel and Motorola byte order, signed and unsigned fields of
//! 1..=64 bits, anywhere in a frame of up to 64 bytes (CAN FD).

use core::fmt;

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
    /// DBC factor: physical value = raw * factor + offset.
    pub factor: f64,
    /// DBC offset.
    pub offset: f64,
}

/// A frame buffer is too short for the signal being written.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FrameTooShort {
    /// Bytes the signal needs, counted from the start of the frame.
    pub(crate) needed: usize,
    /// Bytes the buffer has.
    pub(crate) len: usize,
}

impl fmt::Display for FrameTooShort {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "frame too short for signal: needs {} bytes, has {}",
            self.needed, self.len
        )
    }
}

impl std::error::Error for FrameTooShort {}

/// The bytes a signal touches and where its least significant bit sits among them.
#[derive(Debug, Clone, Copy)]
struct BitWindow {
    /// Index of the first byte touched.
    first_byte: usize,
    /// Number of bytes touched, 1..=9.
    byte_count: usize,
    /// Right shift that brings the field's LSB to bit 0 of the window read as one
    /// integer (little-endian for Intel, big-endian for Motorola).
    shift: u32,
}

impl SignalLayout {
    /// Bytes a frame must have for this signal: one past the last byte it touches.
    ///
    /// Returns 0 for an invalid layout (size outside 1..=64), which no frame satisfies
    /// in [`Self::decode`].
    pub fn bytes_needed(&self) -> usize {
        self.window()
            .map_or(0, |window| window.first_byte + window.byte_count)
    }

    /// Decodes the signal from frame payload `data` into engineering units
    /// (raw * `factor` + `offset`).
    ///
    /// `data` may be longer than the DBC length; `None` when it is too short for the
    /// signal or the layout's `size` is outside 1..=64. Raw values beyond 2^53 lose
    /// precision in the `f64` result.
    ///
    /// ```
    /// use millgate_config::signal::SignalLayout;
    /// // SpindleTopTorque of config/examples/mill.dbc: Intel i16 at bit 0, 0.01 kN.m.
    /// let layout = SignalLayout {
    ///     frame_id: 0x101, extended: false, frame_len: 8, start_bit: 0, size: 16,
    ///     little_endian: true, signed: true, factor: 0.01, offset: 0.0,
    /// };
    /// let torque_knm = layout.decode(&[0x39, 0x30, 0, 0, 0, 0, 0, 0]).unwrap();
    /// assert!((torque_knm - 123.45).abs() < 1e-9);
    /// assert_eq!(layout.decode(&[0x39]), None);
    /// ```
    pub fn decode(&self, data: &[u8]) -> Option<f64> {
        Some(self.scaling().apply(self.decode_count(data)?))
    }

    /// Reads the signal's raw value (sign-extended when signed, not scaled), as the
    /// count [`Self::scaling`] turns into the physical value.
    ///
    /// `None` when `data` is too short or `size` is outside 1..=64.
    pub fn decode_count(&self, data: &[u8]) -> Option<f64> {
        let raw = self.decode_raw(data)?;
        Some(if self.signed {
            self.sign_extend(raw) as f64
        } else {
            raw as f64
        })
    }

    /// The DBC's factor and offset as a [`crate::Scaling`] (decimal-exact).
    pub fn scaling(&self) -> crate::Scaling {
        crate::Scaling::new(self.factor, self.offset)
    }

    /// Reads the signal's raw bits (not sign-extended, not scaled), right-aligned.
    ///
    /// `None` when `data` is too short or `size` is outside 1..=64.
    pub(crate) fn decode_raw(&self, data: &[u8]) -> Option<u64> {
        let window = self.window()?;
        let bytes = data.get(window.first_byte..window.first_byte + window.byte_count)?;
        let word = self.read_window(bytes);
        // The mask keeps at most 64 bits, so the narrowing cannot lose set bits.
        Some(((word >> window.shift) & self.mask()) as u64)
    }

    /// Encodes engineering value `value` into frame payload `data`, leaving all other
    /// bits untouched.
    ///
    /// The raw value is `round((value - offset) / factor)`, saturated to the field's
    /// range (as a real transmitter clips); NaN encodes as raw 0. `factor` must be
    /// non-zero (the loader rejects zero). Fails without writing when `data` is
    /// shorter than [`Self::bytes_needed`] or `size` is outside 1..=64.
    pub fn encode(&self, value: f64, data: &mut [u8]) -> Result<(), FrameTooShort> {
        let too_short = FrameTooShort {
            needed: self.bytes_needed(),
            len: data.len(),
        };
        let window = self.window().ok_or(too_short)?;
        let bytes = data
            .get_mut(window.first_byte..window.first_byte + window.byte_count)
            .ok_or(too_short)?;
        let field = (self.raw_from_value(value) as u128) & self.mask();
        let word = self.read_window(bytes);
        let word = (word & !(self.mask() << window.shift)) | (field << window.shift);
        self.write_window(word, bytes);
        Ok(())
    }

    /// Raw integer for `value`, rounded and saturated to the field's range.
    fn raw_from_value(&self, value: f64) -> i128 {
        let (min_raw, max_raw) = if self.signed {
            (
                -(1_i128 << (self.size - 1)),
                (1_i128 << (self.size - 1)) - 1,
            )
        } else {
            (0, (1_i128 << self.size) - 1)
        };
        let raw = ((value - self.offset) / self.factor).round();
        // `as` saturates at the i128 bounds and maps NaN to 0; then clip to the field.
        (raw as i128).clamp(min_raw, max_raw)
    }

    /// Sign-extends the right-aligned `size`-bit `raw`.
    fn sign_extend(&self, raw: u64) -> i64 {
        let unused = 64 - u32::from(self.size);
        ((raw << unused) as i64) >> unused
    }

    /// `size` ones, right-aligned.
    fn mask(&self) -> u128 {
        (1_u128 << self.size) - 1
    }

    /// Where the field sits, or `None` when `size` is outside 1..=64.
    fn window(&self) -> Option<BitWindow> {
        if !(1..=64).contains(&self.size) {
            return None;
        }
        let size = usize::from(self.size);
        let start = usize::from(self.start_bit);
        if self.little_endian {
            // Intel: bit n is bit n % 8 of byte n / 8; the field runs upwards from its LSB.
            let first_byte = start / 8;
            let last_byte = (start + size - 1) / 8;
            Some(BitWindow {
                first_byte,
                byte_count: last_byte - first_byte + 1,
                shift: (start % 8) as u32,
            })
        } else {
            // Motorola: renumber so that bit k is the k-th bit in transmission order
            // (byte k / 8, bit 7 - k % 8); the field then runs from its MSB at `msb`
            // to its LSB at `msb + size - 1`.
            let msb = (start / 8) * 8 + (7 - start % 8);
            let lsb = msb + size - 1;
            let first_byte = msb / 8;
            let last_byte = lsb / 8;
            Some(BitWindow {
                first_byte,
                byte_count: last_byte - first_byte + 1,
                shift: (7 - lsb % 8) as u32,
            })
        }
    }

    /// Reads up to 9 bytes as one integer in the signal's byte order.
    fn read_window(&self, bytes: &[u8]) -> u128 {
        if self.little_endian {
            bytes
                .iter()
                .rev()
                .fold(0, |word, &byte| (word << 8) | u128::from(byte))
        } else {
            bytes
                .iter()
                .fold(0, |word, &byte| (word << 8) | u128::from(byte))
        }
    }

    /// Writes `word` back over `bytes` in the signal's byte order.
    fn write_window(&self, word: u128, bytes: &mut [u8]) {
        let count = bytes.len();
        for (index, byte) in bytes.iter_mut().enumerate() {
            let byte_shift = if self.little_endian {
                8 * index
            } else {
                8 * (count - 1 - index)
            };
            *byte = (word >> byte_shift) as u8;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use millgate_dsp::testing::assert_isclose;

    fn layout(
        start_bit: u16,
        size: u8,
        little_endian: bool,
        signed: bool,
        factor: f64,
        offset: f64,
    ) -> SignalLayout {
        SignalLayout {
            frame_id: 0x101,
            extended: false,
            frame_len: 8,
            start_bit,
            size,
            little_endian,
            signed,
            factor,
            offset,
        }
    }

    // Golden frames below were produced by python `cantools` 45.1.0
    // (`db.get_message_by_name(..).encode(values, scaling=True)`) from
    // config/examples/mill.dbc, and for the `Wide` message from this DBC:
    //   BO_ 1 Wide: 16 A
    //    SG_ MotoWide : 3|64@0- (1,0) [0|0] "" A
    //    SG_ IntelOdd : 76|13@1- (0.5,1) [0|0] "" A
    //    SG_ MotoOdd : 97|10@0+ (1,0) [0|0] "" A

    /// SpindleTorque {Top: 123.45, Bottom: -87.65, Seq: 201}, Intel.
    const SPINDLE_TORQUE: [u8; 8] = [0x39, 0x30, 0xc3, 0xdd, 0xc9, 0x00, 0x00, 0x00];
    /// StandStatus {RollSpeed: 512.3, StripTension: -1234.5, RollForce: 12340,
    /// MetalInStand: 1, Seq: 77}, Motorola.
    const STAND_STATUS: [u8; 8] = [0x14, 0x03, 0xcf, 0xc7, 0x06, 0xc6, 0x80, 0x4d];
    /// GearboxTemp {OilTemp: 65.3, BearingTemp: -12.5}.
    const GEARBOX_TEMP: [u8; 8] = [0x1d, 0x04, 0x13, 0x01, 0x00, 0x00, 0x00, 0x00];
    /// Wide {MotoWide: -81985529216486896, IntelOdd: -1500.5, MotoOdd: 1000}.
    const WIDE: [u8; 16] = [
        0x0f, 0xed, 0xcb, 0xa9, 0x87, 0x65, 0x43, 0x21, 0x00, 0x50, 0x44, 0x01, 0x03, 0xe8, 0x00,
        0x00,
    ];

    fn accel_burst() -> [u8; 64] {
        // AccelBurst {Seq: 9, Acc0: 1.234, Acc1: -0.5, Acc2: -32.768, Acc3: 32.767,
        // TimestampUs: 1234567890123456768 (exact in f64)}: bytes 0..9 and 56..64,
        // zeros between.
        let mut frame = [0_u8; 64];
        frame[..9].copy_from_slice(&[0x09, 0xd2, 0x04, 0x0c, 0xfe, 0x00, 0x80, 0xff, 0x7f]);
        frame[56..].copy_from_slice(&[0x00, 0x81, 0xe9, 0x7d, 0xf4, 0x10, 0x22, 0x11]);
        frame
    }

    fn spindle_signals() -> [(SignalLayout, f64); 3] {
        [
            (layout(0, 16, true, true, 0.01, 0.0), 123.45),
            (layout(16, 16, true, true, 0.01, 0.0), -87.65),
            (layout(32, 8, true, false, 1.0, 0.0), 201.0),
        ]
    }

    fn stand_signals() -> [(SignalLayout, f64); 5] {
        [
            (layout(7, 16, false, false, 0.1, 0.0), 512.3),
            (layout(23, 16, false, true, 0.1, 0.0), -1234.5),
            (layout(35, 12, false, false, 10.0, -5000.0), 12340.0),
            (layout(55, 1, false, false, 1.0, 0.0), 1.0),
            (layout(63, 8, false, false, 1.0, 0.0), 77.0),
        ]
    }

    fn accel_signals() -> [(SignalLayout, f64); 6] {
        [
            (layout(0, 8, true, false, 1.0, 0.0), 9.0),
            (layout(8, 16, true, true, 0.001, 0.0), 1.234),
            (layout(24, 16, true, true, 0.001, 0.0), -0.5),
            (layout(40, 16, true, true, 0.001, 0.0), -32.768),
            (layout(56, 16, true, true, 0.001, 0.0), 32.767),
            (
                layout(448, 64, true, false, 1.0, 0.0),
                1234567890123456768.0,
            ),
        ]
    }

    fn gearbox_signals() -> [(SignalLayout, f64); 2] {
        [
            (layout(0, 16, true, false, 0.1, -40.0), 65.3),
            (layout(16, 16, true, false, 0.1, -40.0), -12.5),
        ]
    }

    fn wide_signals() -> [(SignalLayout, f64); 3] {
        [
            (layout(3, 64, false, true, 1.0, 0.0), -81985529216486896.0),
            (layout(76, 13, true, true, 0.5, 1.0), -1500.5),
            (layout(97, 10, false, false, 1.0, 0.0), 1000.0),
        ]
    }

    fn check_decode(frame: &[u8], signals: &[(SignalLayout, f64)]) {
        for (signal, expected) in signals {
            assert_isclose(
                signal.decode(frame).expect("fits the frame"),
                *expected,
                1e-9,
                1e-9,
                "signal",
            );
        }
    }

    fn check_encode(frame: &[u8], signals: &[(SignalLayout, f64)]) {
        let mut encoded = vec![0_u8; frame.len()];
        for (signal, value) in signals {
            signal
                .encode(*value, &mut encoded)
                .expect("frame is long enough");
        }
        assert_eq!(encoded, frame);
    }

    #[test]
    fn decodes_cantools_golden_frames() {
        check_decode(&SPINDLE_TORQUE, &spindle_signals());
        check_decode(&STAND_STATUS, &stand_signals());
        check_decode(&accel_burst(), &accel_signals());
        check_decode(&GEARBOX_TEMP, &gearbox_signals());
        check_decode(&WIDE, &wide_signals());
    }

    #[test]
    fn encodes_cantools_golden_frames() {
        check_encode(&SPINDLE_TORQUE, &spindle_signals());
        check_encode(&STAND_STATUS, &stand_signals());
        check_encode(&accel_burst(), &accel_signals());
        check_encode(&GEARBOX_TEMP, &gearbox_signals());
        check_encode(&WIDE, &wide_signals());
    }

    #[test]
    fn decodes_all_ones_like_cantools() {
        // cantools decodes 16 bytes of 0xff in `Wide` as MotoWide -1, IntelOdd 0.5,
        // MotoOdd 1023; and bytes 0x11..=0x20 as 1234321929484202369, 217.5, 286.
        let ones = [0xff_u8; 16];
        let [moto_wide, intel_odd, moto_odd] = wide_signals().map(|(signal, _)| signal);
        assert_isclose(
            moto_wide.decode(&ones).expect("fits the frame"),
            -1.0,
            1e-9,
            1e-9,
            "moto_wide",
        );
        assert_isclose(
            intel_odd.decode(&ones).expect("fits the frame"),
            0.5,
            1e-9,
            1e-9,
            "intel_odd",
        );
        assert_isclose(
            moto_odd.decode(&ones).expect("fits the frame"),
            1023.0,
            1e-9,
            1e-9,
            "moto_odd",
        );
        let counting: Vec<u8> = (0x11..=0x20).collect();
        assert_eq!(moto_wide.decode_raw(&counting), Some(1234321929484202369));
        assert_isclose(
            intel_odd.decode(&counting).expect("fits the frame"),
            217.5,
            1e-9,
            1e-9,
            "intel_odd",
        );
        assert_isclose(
            moto_odd.decode(&counting).expect("fits the frame"),
            286.0,
            1e-9,
            1e-9,
            "moto_odd",
        );
    }

    #[test]
    fn bytes_needed_counts_to_last_byte_touched() {
        assert_eq!(layout(0, 16, true, true, 1.0, 0.0).bytes_needed(), 2);
        assert_eq!(layout(32, 8, true, false, 1.0, 0.0).bytes_needed(), 5);
        assert_eq!(layout(7, 16, false, false, 1.0, 0.0).bytes_needed(), 2);
        assert_eq!(layout(35, 12, false, false, 1.0, 0.0).bytes_needed(), 6);
        assert_eq!(layout(3, 64, false, true, 1.0, 0.0).bytes_needed(), 9);
        assert_eq!(layout(448, 64, true, false, 1.0, 0.0).bytes_needed(), 64);
        assert_eq!(layout(0, 0, true, false, 1.0, 0.0).bytes_needed(), 0);
    }

    #[test]
    fn short_frame_decodes_to_none_and_refuses_encode() {
        let seq = layout(32, 8, true, false, 1.0, 0.0);
        assert_eq!(seq.decode(&[0; 4]), None);
        assert_eq!(seq.decode(&[]), None);
        let mut short = [0xaa_u8; 4];
        assert_eq!(
            seq.encode(3.0, &mut short),
            Err(FrameTooShort { needed: 5, len: 4 })
        );
        assert_eq!(short, [0xaa; 4], "a refused encode must not write");
        let moto = layout(35, 12, false, false, 1.0, 0.0);
        assert_eq!(moto.decode(&[0; 5]), None);
        assert!(moto.decode(&[0; 6]).is_some());
    }

    #[test]
    fn invalid_size_never_panics() {
        for size in [0_u8, 65, 255] {
            let signal = layout(0, size, true, true, 1.0, 0.0);
            assert_eq!(signal.decode(&[0xff; 64]), None);
            assert!(signal.encode(1.0, &mut [0; 64]).is_err());
        }
    }

    #[test]
    fn encode_keeps_neighbouring_bits() {
        let mut frame = [0xff_u8; 8];
        let roll_force = layout(35, 12, false, false, 1.0, 0.0);
        roll_force.encode(0.0, &mut frame).expect("fits");
        assert_eq!(frame, [0xff, 0xff, 0xff, 0xff, 0xf0, 0x00, 0xff, 0xff]);
        let mut frame = [0xff_u8; 8];
        let intel_odd = layout(3, 7, true, false, 1.0, 0.0);
        intel_odd.encode(0.0, &mut frame).expect("fits");
        assert_eq!(
            frame,
            [0b0000_0111, 0xfc, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff]
        );
    }

    #[test]
    fn encode_saturates_and_maps_nan_to_zero() {
        let torque = layout(0, 16, true, true, 0.01, 0.0);
        let mut frame = [0_u8; 2];
        torque.encode(1.0e6, &mut frame).expect("fits");
        assert_eq!(frame, i16::MAX.to_le_bytes());
        torque.encode(-1.0e6, &mut frame).expect("fits");
        assert_eq!(frame, i16::MIN.to_le_bytes());
        torque.encode(f64::NAN, &mut frame).expect("fits");
        assert_eq!(frame, [0, 0]);
        let seq = layout(0, 8, true, false, 1.0, 0.0);
        let mut frame = [0_u8; 1];
        seq.encode(-5.0, &mut frame).expect("fits");
        assert_eq!(frame, [0]);
        seq.encode(300.0, &mut frame).expect("fits");
        assert_eq!(frame, [255]);
    }

    #[test]
    fn round_trips_every_width_order_and_sign() {
        // Walk the whole parameter space with a cheap deterministic generator: every
        // width, both orders, both signs, many start bits, extreme and middle values.
        let mut state = 0x9e37_79b9_7f4a_7c15_u64;
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state
        };
        for size in 1..=64_u8 {
            for little_endian in [true, false] {
                for signed in [false, true] {
                    for _ in 0..20 {
                        let start_bit = (next() % 440) as u16;
                        let signal = layout(start_bit, size, little_endian, signed, 1.0, 0.0);
                        let mut raw = next() >> (64 - u32::from(size));
                        if signed {
                            raw = signal.sign_extend(raw) as u64;
                        }
                        // Keep raw exactly representable in f64 for the value check.
                        let excess = u32::from(size).saturating_sub(53);
                        let raw_value = if signed {
                            (raw as i64 >> excess) as f64
                        } else {
                            (raw >> excess) as f64
                        };
                        let background = (next() & 0xff) as u8;
                        let mut frame = [background; 64];
                        signal
                            .encode(raw_value, &mut frame)
                            .expect("fits in 64 bytes");
                        assert_eq!(
                            signal.decode(&frame),
                            Some(raw_value),
                            "size {size} start {start_bit} le {little_endian} signed {signed}"
                        );
                        // Only bytes inside the window may change.
                        let needed = signal.bytes_needed();
                        assert!(frame[needed..].iter().all(|&byte| byte == background));
                    }
                }
            }
        }
    }
}
