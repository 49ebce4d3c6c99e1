//! Modbus RTU on a serial line: the character format, the inter-frame silence and the
//! time a poll's frames take on the line (what `millgate check` holds a poll plan
//! against, and what the RTU benchmark compares its measured poll period with).
//!
//! Figures follow the *Modbus over Serial Line Specification and Implementation Guide
//! V1.02* (modbus.org, 2006): a character is a start bit, 8 data bits, a parity bit
//! unless parity is none, and 1 or 2 stop bits (2.5.1); frames are separated by at
//! least 3.5 character times of silence, a fixed 1.75 ms above 19 200 Bd (2.5.1.1);
//! a read request (FC 03/04) is 8 bytes (unit, function, address, count, CRC) and its
//! response 5 bytes plus 2 per register (unit, function, byte count, data, CRC).

use std::fmt;
use std::time::Duration;

/// Above this rate the inter-frame silence is a fixed [`FIXED_INTER_FRAME_DELAY`].
pub(crate) const FIXED_DELAY_ABOVE_BAUD: u32 = 19_200;

/// The inter-frame silence above [`FIXED_DELAY_ABOVE_BAUD`]: 1.75 ms.
pub(crate) const FIXED_INTER_FRAME_DELAY: Duration = Duration::from_micros(1750);

/// Bytes of a read request (FC 03 or 04): unit, function, address (2), count (2), CRC (2).
pub const READ_REQUEST_BYTES: u32 = 8;

/// Bytes of the response to a read of `registers` registers: unit, function, byte
/// count, 2 per register, CRC (2).
pub const fn read_response_bytes(registers: u16) -> u32 {
    5 + 2 * registers as u32
}

/// The parity bit of each character.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Parity {
    /// No parity bit (the specification then asks for 2 stop bits).
    None,
    /// Even parity (the specification's default).
    Even,
    /// Odd parity.
    Odd,
}

impl Parity {
    /// Every parity, in the order the documentation lists them.
    pub(crate) const ALL: [Parity; 3] = [Parity::None, Parity::Even, Parity::Odd];

    /// The spelling in configuration files: `none`, `even`, `odd`.
    pub(crate) fn name(self) -> &'static str {
        match self {
            Parity::None => "none",
            Parity::Even => "even",
            Parity::Odd => "odd",
        }
    }

    /// The letter of the usual short form (`8E1`): `N`, `E`, `O`.
    fn letter(self) -> char {
        match self {
            Parity::None => 'N',
            Parity::Even => 'E',
            Parity::Odd => 'O',
        }
    }
}

/// The settings of a serial line to a Modbus RTU device.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SerialLine {
    /// Line rate, bits per second (300..=1 000 000).
    pub baud_rate: u32,
    /// Parity bit.
    pub parity: Parity,
    /// Data bits per character: 8 (RTU sends 8-bit bytes).
    pub data_bits: u8,
    /// Stop bits per character, 1 or 2.
    pub stop_bits: u8,
    /// Silence kept between the end of one frame and the start of the next: at least
    /// `SerialLine::min_inter_frame_delay`.
    pub inter_frame_delay: Duration,
}

impl SerialLine {
    /// Bits of one character on the line: start, data, parity, stop.
    pub(crate) fn character_bits(&self) -> u32 {
        character_bits(self.parity, self.data_bits, self.stop_bits)
    }

    /// Time `bytes` characters take on the line, back to back.
    pub fn frame_time(&self, bytes: u32) -> Duration {
        Duration::from_secs_f64(
            f64::from(bytes * self.character_bits()) / f64::from(self.baud_rate),
        )
    }

    /// The time one read of `registers` registers holds the line: the request, a
    /// silence, the response, a silence (the device's own turnaround not counted).
    pub fn read_time(&self, registers: u16) -> Duration {
        self.frame_time(READ_REQUEST_BYTES + read_response_bytes(registers))
            + 2 * self.inter_frame_delay
    }

    /// The short form of the character format: `8E1`, `8N2`.
    pub fn format(&self) -> String {
        format!(
            "{}{}{}",
            self.data_bits,
            self.parity.letter(),
            self.stop_bits
        )
    }

    /// The specification's shortest inter-frame silence at `baud_rate` for characters
    /// of `character_bits` bits: 3.5 character times, 1.75 ms above 19 200 Bd.
    pub(crate) fn min_inter_frame_delay(baud_rate: u32, character_bits: u32) -> Duration {
        if baud_rate > FIXED_DELAY_ABOVE_BAUD {
            FIXED_INTER_FRAME_DELAY
        } else {
            Duration::from_secs_f64(3.5 * f64::from(character_bits) / f64::from(baud_rate))
        }
    }
}

/// Bits of one character: a start bit, `data_bits`, a parity bit unless none,
/// `stop_bits`.
pub(crate) fn character_bits(parity: Parity, data_bits: u8, stop_bits: u8) -> u32 {
    1 + u32::from(data_bits) + u32::from(parity != Parity::None) + u32::from(stop_bits)
}

/// What one poll of an RTU source asks of its line: the reads (registers each), at
/// the line's character format and silences, repeated every poll period.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct PollLoad {
    /// The line.
    pub(crate) line: SerialLine,
    /// Registers of each read of one poll (a block channel reads the whole block).
    pub(crate) reads: Vec<u16>,
    /// Time between polls.
    pub(crate) poll_period: Duration,
}

impl PollLoad {
    /// Bytes of one poll's frames: each read's request and response.
    pub(crate) fn frame_bytes(&self) -> u32 {
        self.reads
            .iter()
            .map(|&registers| READ_REQUEST_BYTES + read_response_bytes(registers))
            .sum()
    }

    /// Silences of one poll: one after each request and after each response.
    pub(crate) fn silences(&self) -> u32 {
        2 * self.reads.len() as u32
    }

    /// One silence in bit times (fractional: 4.0104 ms at 9600 Bd is 38.5 bits).
    pub(crate) fn silence_bits(&self) -> f64 {
        self.line.inter_frame_delay.as_secs_f64() * f64::from(self.line.baud_rate)
    }

    /// Bit times one poll holds the line: frames plus silences.
    pub(crate) fn bits_per_poll(&self) -> f64 {
        f64::from(self.frame_bytes() * self.line.character_bits())
            + f64::from(self.silences()) * self.silence_bits()
    }

    /// Polls per second.
    pub(crate) fn polls_per_second(&self) -> f64 {
        1.0 / self.poll_period.as_secs_f64()
    }

    /// Bit times per second the plan needs; the line carries `baud_rate`.
    pub(crate) fn bits_per_second(&self) -> f64 {
        self.bits_per_poll() * self.polls_per_second()
    }

    /// Whether the line can carry the plan.
    pub(crate) fn fits(&self) -> bool {
        self.bits_per_second() <= f64::from(self.line.baud_rate)
    }

    /// Time one poll holds the line: the shortest poll period the line allows.
    pub(crate) fn poll_time(&self) -> Duration {
        Duration::from_secs_f64(self.bits_per_poll() / f64::from(self.line.baud_rate))
    }
}

impl fmt::Display for PollLoad {
    /// The arithmetic, e.g. "one poll = 2 reads: 8 + 249 + 8 + 9 = 274 bytes x 11 bits
    /// (8E1) = 3014 bits, plus 4 silences x 38.5 bits (4.011 ms) = 154 bits: 3168 bits
    /// per poll x 20 polls/s = 63360 bit/s against 9600 Bd".
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let frames: Vec<String> = self
            .reads
            .iter()
            .map(|&registers| format!("{READ_REQUEST_BYTES} + {}", read_response_bytes(registers)))
            .collect();
        let character_bits = self.line.character_bits();
        let frame_bits = self.frame_bytes() * character_bits;
        write!(
            f,
            "one poll = {} read{} ({} registers): request + response {} = {} bytes x {} bits ({}) \
             = {} bits, plus {} silences x {} bits ({} ms) = {} bits: {} bits per poll x {} polls/s \
             = {} bit/s against {} Bd",
            self.reads.len(),
            if self.reads.len() == 1 { "" } else { "s" },
            self.reads
                .iter()
                .map(u16::to_string)
                .collect::<Vec<_>>()
                .join(" + "),
            frames.join(" + "),
            self.frame_bytes(),
            character_bits,
            self.line.format(),
            frame_bits,
            self.silences(),
            round(self.silence_bits(), 1),
            round(self.line.inter_frame_delay.as_secs_f64() * 1e3, 3),
            round(f64::from(self.silences()) * self.silence_bits(), 0),
            round(self.bits_per_poll(), 0),
            round(self.polls_per_second(), 2),
            round(self.bits_per_second(), 0),
            self.line.baud_rate,
        )
    }
}

/// `value` with at most `decimals` decimals and no trailing zeros.
fn round(value: f64, decimals: usize) -> String {
    let text = format!("{value:.decimals$}");
    if text.contains('.') {
        text.trim_end_matches('0').trim_end_matches('.').to_owned()
    } else {
        text
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn line(baud_rate: u32, parity: Parity, stop_bits: u8) -> SerialLine {
        let bits = character_bits(parity, 8, stop_bits);
        SerialLine {
            baud_rate,
            parity,
            data_bits: 8,
            stop_bits,
            inter_frame_delay: SerialLine::min_inter_frame_delay(baud_rate, bits),
        }
    }

    #[test]
    fn character_format_and_silence_follow_the_specification() {
        let even = line(9600, Parity::Even, 1);
        assert_eq!((even.character_bits(), even.format().as_str()), (11, "8E1"));
        // 3.5 x 11 bits / 9600 Bd = 4.010 416 7 ms, to the nearest nanosecond.
        assert_eq!(even.inter_frame_delay.as_nanos(), 4_010_417);
        let none = line(19_200, Parity::None, 1);
        assert_eq!(none.character_bits(), 10);
        assert_eq!(none.inter_frame_delay.as_nanos(), 1_822_917);
        // Above 19 200 Bd the silence is fixed, whatever the format.
        assert_eq!(
            line(115_200, Parity::Odd, 2).inter_frame_delay,
            FIXED_INTER_FRAME_DELAY
        );
        assert_eq!(
            line(19_201, Parity::None, 2).inter_frame_delay,
            FIXED_INTER_FRAME_DELAY
        );
    }

    #[test]
    fn a_block_read_at_9600_baud_takes_the_line_for_a_third_of_a_second() {
        let even = line(9600, Parity::Even, 1);
        // 8 + 249 bytes x 11 bits = 2827 bits = 294.48 ms, plus 2 x 4.0104 ms.
        let expected_ms = 2827.0 / 9.6 + 2.0 * 3.5 * 11.0 / 9.6;
        assert!((even.read_time(122).as_secs_f64() * 1e3 - expected_ms).abs() < 1e-6);
    }

    #[test]
    fn the_load_counts_frames_and_silences_per_second() {
        let load = PollLoad {
            line: line(9600, Parity::Even, 1),
            reads: vec![122, 2],
            poll_period: Duration::from_millis(50),
        };
        assert_eq!(load.frame_bytes(), 8 + 249 + 8 + 9);
        assert_eq!(load.silences(), 4);
        assert!((load.silence_bits() - 38.5).abs() < 1e-3);
        assert!((load.bits_per_poll() - (274.0 * 11.0 + 4.0 * 38.5)).abs() < 1e-2);
        assert!((load.bits_per_second() - 20.0 * 3168.0).abs() < 0.5);
        assert!(!load.fits());
        let text = load.to_string();
        assert!(
            text.contains("= 274 bytes x 11 bits (8E1) = 3014 bits, plus 4 silences x 38.5 bits"),
            "{text}"
        );
        assert!(
            text.ends_with("3168 bits per poll x 20 polls/s = 63360 bit/s against 9600 Bd"),
            "{text}"
        );
        let slow = PollLoad {
            poll_period: Duration::from_millis(400),
            ..load
        };
        assert!(slow.fits(), "{slow}");
        assert!((slow.poll_time().as_secs_f64() - 3168.0 / 9600.0).abs() < 1e-6);
    }
}
