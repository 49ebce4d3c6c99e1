//! The millgate register map: one typed table, in one place, derived from the
//! [`catalogue`](crate::state::catalogue).
//!
//! Every register the gateway publishes is a [`Register`] built here: its address
//! (offset from the map's base), type, unit, scale, word order, access and meaning.
//! The global registers hold the gateway's figures (the heartbeat, its flags register
//! `gateway_status`), a register per source flag (bit i for source i: `sources_ok`,
//! `sources_stale`, `sources_lost`) and the command registers.
//! A block per driveline, tandem mill, rod mill and rod span holds its figures: the
//! block's `flags` register carries every flag figure at its catalogue bit, its
//! `quality` register the validity of every value figure at its catalogue bit, and each
//! value figure sits where the catalogue declares it (with its quality bit); names and
//! descriptions are the catalogue's. Files: `layout.rs` (where every register sits),
//! `encode.rs` ([`RegisterMap::encode`], a pure function of the results), `tests.rs`.
//! The PLC writer, the Modbus server and the `millgate registers` export all use this
//! table.
//!
//! Conventions: 32-bit values (u32, f32) are big-endian words and bytes (`ABCD`,
//! the Modbus default); physical value = register value * scale. A value whose
//! quality bit is 0 is not valid (never computed, or its source is stale: the stale
//! rule of the catalogue withholds every value a PLC could not tell from a fresh one):
//! the registers then hold 0 rather than a frozen old value.

use std::ops::Range;

use millgate_config::{ValueType, WordOrder};

use crate::state::catalogue::{Figure, Guard};

pub(crate) use layout::source_bits_name;

/// Whether clients may write a register.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Access {
    /// Read only (FC 03 / 04); a write gets exception 02.
    Read,
    /// A command register: readable and writable (FC 06 / 16).
    ReadWrite,
}

impl Access {
    /// `r` or `rw`.
    pub fn code(self) -> &'static str {
        match self {
            Access::Read => "r",
            Access::ReadWrite => "rw",
        }
    }
}

/// A block of figures: whose they are.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Block {
    /// The gateway: the global registers (its flags register is `gateway_status`).
    Gateway,
    /// Driveline k (config order).
    Driveline(usize),
    /// Tandem mill k (config order).
    TandemMill(usize),
    /// Rod mill k (config order).
    RodMill(usize),
    /// Span s (rolling order) of rod mill k.
    RodSpan(usize, usize),
}

/// What a register holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Field {
    /// Bit i: source i's flag at this index of [`SOURCE`](crate::state::catalogue::SOURCE) is set.
    SourceBits(usize),
    /// Command: write 1 to acknowledge latched alarms.
    AcknowledgeAlarms,
    /// Command: write a bitmask of the first 16 drivelines (bit k = driveline k) to
    /// reset their wear.
    ResetWearTrend,
    /// Command: write a driveline's number (1-based, config order) to reset its wear.
    ResetWear,
    /// Command: write seconds * 256 + a driveline's number (both 1..=255) to keep the
    /// next seconds of its torque as a manual capture.
    ManualCapture,
    /// Command: write a fatigue component's number * 256 + its driveline's number
    /// (both 1-based) to reset the component's life.
    ResetFatigue,
    /// A block's flag figures, each at its catalogue bit.
    Flags(Block),
    /// The quality bits of a block's page (0: the block, 1: its extension block): bit
    /// i set while the value figure on that page guarded by bit i is valid.
    Quality(Block, u8),
    /// The block's figure at this index of its catalogue table.
    Figure(Block, usize),
}

/// One register (or register pair) of the map.
#[derive(Debug, Clone, PartialEq)]
pub struct Register {
    /// Dotted name, e.g. `F1.taf`: the block's name and the figure's catalogue key.
    pub name: String,
    /// Offset from the map's base.
    pub address: u16,
    /// How the value is encoded (one register for 16-bit types, two for 32-bit).
    pub value_type: ValueType,
    /// Unit of the physical value (empty for counts and bits).
    pub unit: &'static str,
    /// Physical value = register value * scale.
    pub scale: f64,
    /// Order of the words and bytes of 32-bit values.
    pub word_order: WordOrder,
    /// Read only or a command.
    pub access: Access,
    /// One sentence for the documentation and exports.
    pub description: String,
    /// What the register holds.
    pub field: Field,
}

/// The gateway's flags register (its [`GATEWAY`](crate::state::catalogue::GATEWAY) flags at their bits):
/// address and name.
pub const GATEWAY_STATUS: (u16, &str) = (1, "gateway_status");

/// The bit of flag figure `key` of `figures` in its block's `flags` register, as a
/// mask: what a PLC program tests.
///
/// ```
/// use millgate::outputs::modbus::register_map::flag_mask;
/// use millgate::state::catalogue::DRIVELINE;
/// assert_eq!(flag_mask(DRIVELINE, "gap_warning"), 1 << 4);
/// ```
pub fn flag_mask<R>(figures: &[Figure<R>], key: &str) -> u16 {
    match figures
        .iter()
        .find(|figure| figure.key == key)
        .map(|f| f.guard)
    {
        Some(Guard::FlagBit(bit)) => 1 << bit,
        _ => panic!("{key} is not a flag"),
    }
}

/// A configuration whose register map does not fit the 65 536 registers of a table.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error(
    "the register map of {drivelines} driveline blocks (the drivelines, or \
     outputs.driveline_slots), {tandem_mills} tandem mills and \
     {rod_mills} rod mills spans {span} registers, more than the 65535 a Modbus table \
     can address from 0"
)]
pub struct MapTooLarge {
    /// Driveline blocks: the drivelines configured, or `outputs.driveline_slots`.
    pub drivelines: usize,
    /// Tandem mills configured.
    pub tandem_mills: usize,
    /// Rod mills configured.
    pub rod_mills: usize,
    /// Registers the map would span.
    pub span: u64,
}

/// The register map of one configuration.
#[derive(Debug, Clone, PartialEq)]
pub struct RegisterMap {
    registers: Vec<Register>,
    len: u16,
    /// Where the extension blocks start ([`Self::plc_blocks`]).
    base_len: u16,
    /// How many of [`Self::blocks`] come before the extension blocks.
    base_blocks: usize,
    /// The global registers, then each subject's block: see [`RegisterMap::blocks`].
    blocks: Vec<Range<u16>>,
}

impl RegisterMap {
    /// The registers, by address.
    pub fn registers(&self) -> &[Register] {
        &self.registers
    }

    /// The map's blocks in address order, contiguous from 0 to [`Self::len`]: the
    /// global registers, then each driveline's, tandem mill's and rod mill's block (a
    /// rod mill's with its spans), at most 96 registers each. A block is what one
    /// subject's figures, flags and quality occupy, so the PLC writer never splits one
    /// across two requests.
    pub fn blocks(&self) -> &[Range<u16>] {
        &self.blocks
    }

    /// The blocks written to a PLC: every block with `extension` (the
    /// `outputs.plc.extension_blocks` key), else those of the map's first layout,
    /// which end where the extension blocks start ([`Self::plc_span`]). The extension
    /// blocks hold the figures declared on a subject's extension page (page 1 of
    /// [`Register::At`](crate::state::catalogue::Register::At)), after every other block, so that no address of
    /// the first layout moves and a PLC sized for it gets what it got before.
    pub fn plc_blocks(&self, extension: bool) -> &[Range<u16>] {
        match extension {
            true => &self.blocks,
            false => &self.blocks[..self.base_blocks],
        }
    }

    /// The registers written to a PLC: [`Self::len`] with `extension`, else the first
    /// layout's.
    pub fn plc_span(&self, extension: bool) -> u16 {
        match extension {
            true => self.len,
            false => self.base_len,
        }
    }

    /// Number of registers the map spans (including reserved ones, which read 0).
    pub fn len(&self) -> u16 {
        self.len
    }

    /// Whether the map is empty (it never is: the global registers are always there).
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The register at `address`, if one starts there.
    pub fn find(&self, address: u16) -> Option<&Register> {
        self.registers.iter().find(|r| r.address == address)
    }

    /// The register named `name` (`F1.taf`).
    pub fn named(&self, name: &str) -> Option<&Register> {
        self.registers.iter().find(|r| r.name == name)
    }

    /// The register covering `address` (either word of a 32-bit value).
    pub fn covering(&self, address: u16) -> Option<&Register> {
        self.registers
            .iter()
            .find(|r| (r.address..r.address + r.value_type.register_count()).contains(&address))
    }
}

/// Decode an f32 (ABCD) from two registers: what a PLC or HMI does.
pub fn decode_f32(words: &[u16]) -> Option<f32> {
    millgate_config::layout::decode_value(words, ValueType::F32, WordOrder::Abcd).map(|v| v as f32)
}

/// Decode a u32 (ABCD) from two registers.
pub fn decode_u32(words: &[u16]) -> Option<u32> {
    millgate_config::layout::decode_value(words, ValueType::U32, WordOrder::Abcd).map(|v| v as u32)
}

mod encode;
mod layout;

#[cfg(test)]
mod tests;
