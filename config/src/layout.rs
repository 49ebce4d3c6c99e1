//! The millgate acquisition layout over Modbus: block buffers and process values.
//!
//! Both the virtual DAQ in `millgate-sim` and the gateway's `DaqReader` follow this
//! module, and so can a third-party DAQ (the README documents it):
//!
//! | register        | content                                          |
//! |-----------------|--------------------------------------------------|
//! | `base + 0`      | block sequence number, u16, wraps 65535 -> 0     |
//! | `base + 1`      | n, samples in this block, 1..=120                |
//! | `base + 2 ..`   | n samples, i16; value = raw * scale + offset     |
//!
//! Process values are plain registers of type u16, i16, u32, i32 or f32 in one of
//! four word orders (see [`WordOrder`]).

use crate::{ValueType, WordOrder};

/// Registers before the samples in a block: sequence number and sample count.
pub const BLOCK_HEADER_REGISTERS: u16 = 2;

/// Largest number of samples in one block (keeps one block in one FC 03/04 read,
/// whose limit is 125 registers).
pub const MAX_BLOCK_SAMPLES: u16 = 120;

/// Registers one block buffer occupies: header plus the largest sample count.
pub const BLOCK_REGISTERS: u16 = BLOCK_HEADER_REGISTERS + MAX_BLOCK_SAMPLES;

/// Why a block read from a DAQ cannot be used.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BlockError {
    /// Fewer registers than the header.
    Truncated {
        /// Registers read.
        registers: usize,
    },
    /// The sample count is 0 or above [`MAX_BLOCK_SAMPLES`].
    BadCount {
        /// The block's sample count.
        count: u16,
    },
    /// The count says more samples than the registers read hold.
    CountBeyondData {
        /// The block's sample count.
        count: u16,
        /// Sample registers read.
        available: usize,
    },
}

impl core::fmt::Display for BlockError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            BlockError::Truncated { registers } => {
                write!(
                    f,
                    "block truncated: {registers} registers, header needs {BLOCK_HEADER_REGISTERS}"
                )
            }
            BlockError::BadCount { count } => {
                write!(
                    f,
                    "block sample count {count} outside 1..={MAX_BLOCK_SAMPLES}"
                )
            }
            BlockError::CountBeyondData { count, available } => write!(
                f,
                "block sample count {count} exceeds the {available} sample registers read"
            ),
        }
    }
}

impl std::error::Error for BlockError {}

/// A decoded block: its sequence number and raw samples.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Block<'a> {
    /// Block sequence number, wraps 65535 -> 0.
    pub sequence: u16,
    /// The samples as read: i16 two's complement in u16 registers.
    pub raw: &'a [u16],
}

impl Block<'_> {
    /// Samples in engineering units, decoded by `scaling`.
    pub fn values(&self, scaling: crate::Scaling) -> impl Iterator<Item = f64> + '_ {
        self.raw
            .iter()
            .map(move |&word| scaling.apply(f64::from(word as i16)))
    }
}

/// Decode the registers of one block buffer (header and samples).
pub fn decode_block(registers: &[u16]) -> Result<Block<'_>, BlockError> {
    let [sequence, count, samples @ ..] = registers else {
        return Err(BlockError::Truncated {
            registers: registers.len(),
        });
    };
    if *count == 0 || *count > MAX_BLOCK_SAMPLES {
        return Err(BlockError::BadCount { count: *count });
    }
    let raw = samples
        .get(..usize::from(*count))
        .ok_or(BlockError::CountBeyondData {
            count: *count,
            available: samples.len(),
        })?;
    Ok(Block {
        sequence: *sequence,
        raw,
    })
}

/// Write one block (header and samples) into `registers`, which must hold
/// [`BLOCK_HEADER_REGISTERS`] + `raw.len()` words; `raw.len()` must be 1..=120.
pub fn encode_block(sequence: u16, raw: &[i16], registers: &mut [u16]) {
    debug_assert!(!raw.is_empty() && raw.len() <= usize::from(MAX_BLOCK_SAMPLES));
    registers[0] = sequence;
    registers[1] = raw.len() as u16;
    for (word, &sample) in registers[2..].iter_mut().zip(raw) {
        *word = sample as u16;
    }
}

/// Number of blocks between two sequence numbers (1 when `current` follows
/// `previous`; 0 when nothing new), modulo the u16 wrap.
pub fn sequence_advance(previous: u16, current: u16) -> u16 {
    current.wrapping_sub(previous)
}

/// Convert an engineering value to the raw i16 of a block sample, saturating.
pub fn to_raw_sample(value: f64, scale: f64, offset: f64) -> i16 {
    let raw = ((value - offset) / scale).round();
    raw.clamp(f64::from(i16::MIN), f64::from(i16::MAX)) as i16
}

/// Order the four bytes A (most significant) .. D of a 32-bit value into two
/// registers, or the two bytes A, B of a 16-bit value into one (`BADC` and `DCBA`
/// swap the bytes of each register, `CDAB` and `DCBA` swap the registers).
fn order_words(bytes: [u8; 4], order: WordOrder) -> [u16; 2] {
    let [a, b, c, d] = bytes;
    let (first, second) = match order {
        WordOrder::Abcd => ([a, b], [c, d]),
        WordOrder::Cdab => ([c, d], [a, b]),
        WordOrder::Badc => ([b, a], [d, c]),
        WordOrder::Dcba => ([d, c], [b, a]),
    };
    [u16::from_be_bytes(first), u16::from_be_bytes(second)]
}

fn unorder_words(words: [u16; 2], order: WordOrder) -> [u8; 4] {
    let [first, second] = [words[0].to_be_bytes(), words[1].to_be_bytes()];
    match order {
        WordOrder::Abcd => [first[0], first[1], second[0], second[1]],
        WordOrder::Cdab => [second[0], second[1], first[0], first[1]],
        WordOrder::Badc => [first[1], first[0], second[1], second[0]],
        WordOrder::Dcba => [second[1], second[0], first[1], first[0]],
    }
}

fn swaps_bytes(order: WordOrder) -> bool {
    matches!(order, WordOrder::Badc | WordOrder::Dcba)
}

/// Decode a process value from its registers (1 for 16-bit types, 2 for 32-bit
/// ones) into its raw numeric value, before scale and offset (a float32 as its
/// shortest decimal, [`crate::f32_decimal`]). `None` when fewer registers than the
/// type needs.
pub fn decode_value(registers: &[u16], value_type: ValueType, order: WordOrder) -> Option<f64> {
    let word = |i: usize| registers.get(i).copied();
    let single = || {
        word(0).map(|w| {
            if swaps_bytes(order) {
                w.swap_bytes()
            } else {
                w
            }
        })
    };
    let double = || {
        Some(u32::from_be_bytes(unorder_words(
            [word(0)?, word(1)?],
            order,
        )))
    };
    Some(match value_type {
        ValueType::U16 => f64::from(single()?),
        ValueType::I16 => f64::from(single()? as i16),
        ValueType::U32 => f64::from(double()?),
        ValueType::I32 => f64::from(double()? as i32),
        ValueType::F32 => crate::f32_decimal(f32::from_bits(double()?)),
    })
}

/// Encode a raw numeric value (after removing scale and offset) into registers;
/// integers are rounded and saturated to the type's range. Returns the words and
/// how many of them the type uses.
pub fn encode_value(raw: f64, value_type: ValueType, order: WordOrder) -> ([u16; 2], usize) {
    let single = |w: u16| {
        let w = if swaps_bytes(order) {
            w.swap_bytes()
        } else {
            w
        };
        ([w, 0], 1)
    };
    let double = |bits: u32| (order_words(bits.to_be_bytes(), order), 2);
    let round = |lo: f64, hi: f64| raw.round().clamp(lo, hi);
    match value_type {
        ValueType::U16 => single(round(0.0, f64::from(u16::MAX)) as u16),
        ValueType::I16 => single(round(f64::from(i16::MIN), f64::from(i16::MAX)) as i16 as u16),
        ValueType::U32 => double(round(0.0, f64::from(u32::MAX)) as u32),
        ValueType::I32 => double(round(f64::from(i32::MIN), f64::from(i32::MAX)) as i32 as u32),
        ValueType::F32 => double((raw as f32).to_bits()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    // 0x41200000 is 10.0_f32; bytes A=0x41 B=0x20 C=0x00 D=0x00.
    #[test]
    fn f32_word_orders_golden() {
        let golden = [
            (WordOrder::Abcd, [0x4120, 0x0000]),
            (WordOrder::Cdab, [0x0000, 0x4120]),
            (WordOrder::Badc, [0x2041, 0x0000]),
            (WordOrder::Dcba, [0x0000, 0x2041]),
        ];
        for (order, words) in golden {
            assert_eq!(
                encode_value(10.0, ValueType::F32, order),
                (words, 2),
                "{order:?}"
            );
            assert_eq!(
                decode_value(&words, ValueType::F32, order),
                Some(10.0),
                "{order:?}"
            );
        }
    }

    // 0x12345678: A=0x12 B=0x34 C=0x56 D=0x78.
    #[test]
    fn u32_word_orders_golden() {
        let golden = [
            (WordOrder::Abcd, [0x1234, 0x5678]),
            (WordOrder::Cdab, [0x5678, 0x1234]),
            (WordOrder::Badc, [0x3412, 0x7856]),
            (WordOrder::Dcba, [0x7856, 0x3412]),
        ];
        for (order, words) in golden {
            assert_eq!(
                encode_value(f64::from(0x1234_5678_u32), ValueType::U32, order).0,
                words
            );
            assert_eq!(
                decode_value(&words, ValueType::U32, order),
                Some(f64::from(0x1234_5678_u32))
            );
        }
    }

    #[test]
    fn sixteen_bit_types_sign_and_byte_swap() {
        assert_eq!(
            decode_value(&[0xFFFE], ValueType::I16, WordOrder::Abcd),
            Some(-2.0)
        );
        assert_eq!(
            decode_value(&[0xFFFE], ValueType::U16, WordOrder::Abcd),
            Some(65534.0)
        );
        assert_eq!(
            decode_value(&[0x0100], ValueType::U16, WordOrder::Badc),
            Some(1.0)
        );
        assert_eq!(
            encode_value(-2.0, ValueType::I16, WordOrder::Dcba).0[0],
            0xFEFF
        );
        assert_eq!(
            decode_value(&[0x0000, 0x8000], ValueType::I32, WordOrder::Cdab),
            Some(-2147483648.0)
        );
        assert_eq!(
            decode_value(&[0x0001], ValueType::U32, WordOrder::Abcd),
            None
        );
    }

    #[test]
    fn integer_encoding_saturates() {
        assert_eq!(
            encode_value(1e9, ValueType::I16, WordOrder::Abcd).0[0],
            0x7FFF
        );
        assert_eq!(encode_value(-5.0, ValueType::U16, WordOrder::Abcd).0[0], 0);
        assert_eq!(to_raw_sample(1e9, 0.01, 0.0), i16::MAX);
        assert_eq!(to_raw_sample(112.34, 0.01, 0.0), 11234);
    }

    #[test]
    fn blocks_round_trip_and_reject_bad_headers() {
        let mut registers = [0u16; 5];
        encode_block(65535, &[-1, 2, 300], &mut registers);
        let block = decode_block(&registers).unwrap();
        assert_eq!(block.sequence, 65535);
        let values: Vec<f64> = block.values(crate::Scaling::new(0.5, 1.0)).collect();
        assert_eq!(values, vec![0.5, 2.0, 151.0]);
        assert_eq!(sequence_advance(65535, 1), 2);
        assert_eq!(
            decode_block(&[7]),
            Err(BlockError::Truncated { registers: 1 })
        );
        assert_eq!(
            decode_block(&[7, 0, 1]),
            Err(BlockError::BadCount { count: 0 })
        );
        assert_eq!(
            decode_block(&[7, 121]),
            Err(BlockError::BadCount { count: 121 })
        );
        assert_eq!(
            decode_block(&[7, 3, 1]),
            Err(BlockError::CountBeyondData {
                count: 3,
                available: 1
            })
        );
    }
}
