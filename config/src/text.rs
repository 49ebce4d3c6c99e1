//! A short ASCII text in Modbus registers (`type = "ascii"`): a coil or bar id the PLC
//! keeps as characters rather than a number, two characters per register.
//!
//! - **Byte order** ([`ByteOrder`]): the first character in the high byte of the first
//!   register (`high_first`, the default: big-endian PLCs such as Siemens S7 copying a
//!   `CHAR` array into a holding-register area) or in the low byte (`low_first`:
//!   little-endian controllers that map their memory word by word). The register
//!   order is always the text's order.
//! - **End**: the text ends at its first NUL (a PLC that writes a shorter id over a
//!   longer one often leaves the old characters behind its terminator); trailing
//!   spaces (a space-padded field) are trimmed. Leading spaces are kept: they are the
//!   PLC's.
//! - **Junk**: any other byte outside printable ASCII (0x20..=0x7E), or no character
//!   left, is an error naming the position and the byte ([`TextError`]); such a text
//!   is never used as a value.
//!
//! Hand-rolled rather than a crate: the whole decoding is a byte swap and a check
//! per character, and the result must be `Copy` (an [`AsciiText`] travels inside the
//! process context, which is `Copy`).

/// Most registers a text may span: 32 characters.
pub const MAX_TEXT_REGISTERS: u16 = 16;

/// Most characters of a text (two per register).
pub const MAX_TEXT_LEN: usize = 2 * MAX_TEXT_REGISTERS as usize;

/// Where a text's characters sit in each register.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ByteOrder {
    /// `high_first`: the first character in the high byte (the Modbus byte order).
    #[default]
    HighFirst,
    /// `low_first`: the first character in the low byte.
    LowFirst,
}

impl ByteOrder {
    /// Every order.
    pub const ALL: [ByteOrder; 2] = [ByteOrder::HighFirst, ByteOrder::LowFirst];

    /// The spelling used in configuration files: `high_first`, `low_first`.
    pub fn name(self) -> &'static str {
        match self {
            ByteOrder::HighFirst => "high_first",
            ByteOrder::LowFirst => "low_first",
        }
    }

    /// The order spelled `name` ([`Self::name`]).
    pub fn from_name(name: &str) -> Option<ByteOrder> {
        Self::ALL.into_iter().find(|order| order.name() == name)
    }

    /// The two characters of `word`, in text order.
    fn chars(self, word: u16) -> [u8; 2] {
        match self {
            ByteOrder::HighFirst => word.to_be_bytes(),
            ByteOrder::LowFirst => word.to_le_bytes(),
        }
    }
}

/// A checked text of 1..=[`MAX_TEXT_LEN`] printable ASCII characters, inline (`Copy`).
#[derive(Clone, Copy, PartialEq, Eq, Hash)]
pub struct AsciiText {
    bytes: [u8; MAX_TEXT_LEN],
    len: u8,
}

impl AsciiText {
    /// The text.
    pub fn as_str(&self) -> &str {
        // Only printable ASCII is ever stored (`decode_ascii`, `new`).
        core::str::from_utf8(&self.bytes[..usize::from(self.len)]).unwrap_or_default()
    }

    /// `text` as an [`AsciiText`] if it is 1..=32 printable ASCII characters without
    /// trailing spaces (what [`decode_ascii`] can give).
    pub fn new(text: &str) -> Option<AsciiText> {
        let fits = (1..=MAX_TEXT_LEN).contains(&text.len())
            && text.bytes().all(printable)
            && !text.ends_with(' ');
        fits.then(|| {
            let mut bytes = [0; MAX_TEXT_LEN];
            bytes[..text.len()].copy_from_slice(text.as_bytes());
            AsciiText {
                bytes,
                len: text.len() as u8,
            }
        })
    }
}

impl core::fmt::Debug for AsciiText {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        core::fmt::Debug::fmt(self.as_str(), f)
    }
}

impl core::fmt::Display for AsciiText {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// Why registers do not hold a usable text.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TextError {
    /// A byte before the end is not printable ASCII.
    NotPrintable {
        /// Its position in the text, 0-based.
        position: usize,
        /// The byte.
        byte: u8,
    },
    /// No character before the first NUL, or only spaces.
    Empty,
    /// More than [`MAX_TEXT_REGISTERS`] registers.
    TooLong {
        /// Registers given.
        registers: usize,
    },
}

impl core::fmt::Display for TextError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            TextError::NotPrintable { position, byte } => write!(
                f,
                "character {position} is byte 0x{byte:02X} (must be printable ASCII \
                 0x20..=0x7E, the text ending at a NUL)"
            ),
            TextError::Empty => f.write_str("is empty (no character before the first NUL)"),
            TextError::TooLong { registers } => write!(
                f,
                "{registers} registers are too many (must be 1..={MAX_TEXT_REGISTERS})"
            ),
        }
    }
}

impl std::error::Error for TextError {}

fn printable(byte: u8) -> bool {
    (0x20..=0x7E).contains(&byte)
}

/// The text in `registers` read in `order` (see the module's rules), or why not.
pub fn decode_ascii(registers: &[u16], order: ByteOrder) -> Result<AsciiText, TextError> {
    if registers.len() > usize::from(MAX_TEXT_REGISTERS) {
        return Err(TextError::TooLong {
            registers: registers.len(),
        });
    }
    let mut bytes = [0; MAX_TEXT_LEN];
    for (pair, &word) in bytes.chunks_exact_mut(2).zip(registers) {
        pair.copy_from_slice(&order.chars(word));
    }
    let read = &bytes[..2 * registers.len()];
    let text = read.split(|&b| b == 0).next().unwrap_or_default();
    let len = text
        .iter()
        .rposition(|&b| b != b' ')
        .map_or(0, |last| last + 1);
    if let Some(position) = text[..len].iter().position(|&b| !printable(b)) {
        return Err(TextError::NotPrintable {
            position,
            byte: text[position],
        });
    }
    if len == 0 {
        return Err(TextError::Empty);
    }
    bytes[len..].fill(0);
    Ok(AsciiText {
        bytes,
        len: len as u8,
    })
}

/// `text` in `registers` registers in `order`, NUL-padded (the virtual PLC's side;
/// bytes beyond `2 * registers` are cut).
pub fn encode_ascii(text: &[u8], registers: usize, order: ByteOrder) -> Vec<u16> {
    (0..registers)
        .map(|i| {
            let byte = |k: usize| text.get(2 * i + k).copied().unwrap_or(0);
            let chars = [byte(0), byte(1)];
            match order {
                ByteOrder::HighFirst => u16::from_be_bytes(chars),
                ByteOrder::LowFirst => u16::from_le_bytes(chars),
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    // "CH-4711" in 4 registers: 'C' = 0x43, 'H' = 0x48, '-' = 0x2D, '4' = 0x34,
    // '7' = 0x37, '1' = 0x31, '1' = 0x31, then a NUL.
    #[test]
    fn both_byte_orders_golden() {
        let high = [0x4348, 0x2D34, 0x3731, 0x3100];
        let low = [0x4843, 0x342D, 0x3137, 0x0031];
        for (order, words) in [(ByteOrder::HighFirst, high), (ByteOrder::LowFirst, low)] {
            assert_eq!(decode_ascii(&words, order).unwrap().as_str(), "CH-4711");
            assert_eq!(encode_ascii(b"CH-4711", 4, order), words, "{order:?}");
        }
        // Read in the other order the same words are another (printable) text: the
        // order is the configuration's business, not guessable.
        assert_eq!(
            decode_ascii(&high[..3], ByteOrder::LowFirst)
                .unwrap()
                .as_str(),
            "HC4-17"
        );
    }

    #[test]
    fn ends_at_the_first_nul_and_trims_trailing_spaces() {
        let order = ByteOrder::HighFirst;
        let decode = |text: &[u8]| decode_ascii(&encode_ascii(text, 6, order), order);
        assert_eq!(decode(b"AB12  ").unwrap().as_str(), "AB12");
        assert_eq!(decode(b" AB12").unwrap().as_str(), " AB12");
        // A shorter id written over a longer one: the old tail is behind the NUL.
        assert_eq!(decode(b"AB\0\xFFXYZ").unwrap().as_str(), "AB");
        assert_eq!(decode(b"").unwrap_err(), TextError::Empty);
        assert_eq!(decode(b"    \0").unwrap_err(), TextError::Empty);
        let full = b"0123456789ABCDEFGHIJKLMNOPQRSTUV";
        let words = encode_ascii(full, 16, order);
        assert_eq!(
            decode_ascii(&words, order).unwrap().as_str().as_bytes(),
            full
        );
    }

    #[test]
    fn junk_bytes_are_errors_naming_position_and_byte() {
        let order = ByteOrder::LowFirst;
        let decode = |text: &[u8]| decode_ascii(&encode_ascii(text, 4, order), order);
        let err = decode(b"C\xC3\xA9").unwrap_err();
        assert_eq!(
            err,
            TextError::NotPrintable {
                position: 1,
                byte: 0xC3
            }
        );
        assert_eq!(
            err.to_string(),
            "character 1 is byte 0xC3 (must be printable ASCII 0x20..=0x7E, the text \
             ending at a NUL)"
        );
        assert_eq!(
            decode(b"AB\tC").unwrap_err(),
            TextError::NotPrintable {
                position: 2,
                byte: b'\t'
            }
        );
        assert_eq!(
            decode(b"AB\x7F").unwrap_err(),
            TextError::NotPrintable {
                position: 2,
                byte: 0x7F
            }
        );
        assert_eq!(
            decode_ascii(&[0x4142; 17], order).unwrap_err(),
            TextError::TooLong { registers: 17 }
        );
    }

    #[test]
    fn new_takes_only_what_decoding_can_give() {
        assert_eq!(AsciiText::new("CH-4711").unwrap().to_string(), "CH-4711");
        assert_eq!(format!("{:?}", AsciiText::new("A1").unwrap()), "\"A1\"");
        for bad in ["", "A ", "é", "A\0", &"x".repeat(33)] {
            assert_eq!(AsciiText::new(bad), None, "{bad:?}");
        }
        assert!(AsciiText::new(&"x".repeat(32)).is_some());
    }
}
