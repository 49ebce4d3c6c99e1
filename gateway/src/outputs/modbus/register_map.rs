//! The millgate register map: one typed table, in one place, derived from the
//! [`catalogue`].
//!
//! Every register the gateway publishes is a [`Register`] built here: its address
//! (offset from the map's base), type, unit, scale, word order, access and meaning.
//! The global registers hold the gateway's figures (the heartbeat, its flags register
//! `gateway_status`), a register per source flag (bit i for source i: `sources_ok`,
//! `sources_stale`, `sources_lost`) and the command registers.
//! A block per driveline, tandem mill, rod mill and rod span holds its figures: the
//! block's `flags` register carries every flag figure at its catalogue bit, its
//! `quality` register the validity of every value figure at its catalogue bit, and the
//! layout tables below place each value figure (key, offset, register type); names and
//! descriptions are the catalogue's. Encoding ([`RegisterMap::encode`]) is a pure
//! function of [`Results`]; the PLC writer, the Modbus server and the
//! `millgate registers` export all use this table.
//!
//! Conventions: 32-bit values (u32, f32) are big-endian words and bytes (`ABCD`,
//! the Modbus default); physical value = register value * scale. A value whose
//! quality bit is 0 is not valid (never computed, or its source is stale: the stale
//! rule of the catalogue withholds every value a PLC could not tell from a fresh one):
//! the registers then hold 0 rather than a frozen old value.

use std::ops::Range;

use millgate_config::layout::encode_value;
use millgate_config::{Config, ValueType, WordOrder};

use crate::state::catalogue::{self, Figure, FigureType, Guard, Subject, Value};
use crate::state::results::{Results, MAX_ROD_SPANS};

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
    /// Bit i: source i's flag at this index of [`catalogue::SOURCE`] is set.
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

/// The gateway's flags register (its [`catalogue::GATEWAY`] flags at their bits):
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

/// First register of the first driveline block.
const DRIVELINES_START: u16 = 16;
/// Registers reserved per driveline block.
const DRIVELINE_STRIDE: u16 = 32;
/// Registers reserved per tandem mill block.
const TANDEM_MILL_STRIDE: u16 = 16;
/// First register of a rod mill's first span, from the rod mill's block start.
const ROD_SPANS_START: u16 = 8;
/// Registers per rod span.
const ROD_SPAN_STRIDE: u16 = 8;
/// Registers reserved per rod mill block: the mill's own, then [`MAX_ROD_SPANS`] spans.
const ROD_MILL_STRIDE: u16 = ROD_SPANS_START + ROD_SPAN_STRIDE * MAX_ROD_SPANS as u16;

/// Registers per extension block, by subject (0: the subject has none): see
/// [`RegisterMap::base_len`].
struct ExtensionStrides {
    driveline: u16,
}

/// A driveline's extension block (page 1 of the catalogue's [`catalogue::Register`]):
/// its quality register at 1 and the figures declared on it.
const DRIVELINE_EXTENSION_STRIDE: u16 = 32;

fn extension_strides(_config: &Config) -> ExtensionStrides {
    ExtensionStrides {
        driveline: if has_extension(catalogue::DRIVELINE) {
            DRIVELINE_EXTENSION_STRIDE
        } else {
            0
        },
    }
}

/// Registers the map of `config` spans.
pub fn span_of(config: &Config) -> u64 {
    let extensions = extension_strides(config);
    u64::from(DRIVELINES_START)
        + u64::from(DRIVELINE_STRIDE + extensions.driveline) * config.drivelines.len() as u64
        + u64::from(TANDEM_MILL_STRIDE) * config.tandem_mills.len() as u64
        + u64::from(ROD_MILL_STRIDE) * config.rod_mills.len() as u64
}

/// A configuration whose register map does not fit the 65 536 registers of a table.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error(
    "the register map of {drivelines} drivelines, {tandem_mills} tandem mills and \
     {rod_mills} rod mills spans {span} registers, more than the 65535 a Modbus table \
     can address from 0"
)]
pub struct MapTooLarge {
    /// Drivelines configured.
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

/// Registers as they are added.
struct Builder {
    registers: Vec<Register>,
}

/// The name of a source flag's register: `sources_<key>`.
pub(crate) fn source_bits_name(key: &str) -> String {
    format!("sources_{key}")
}

impl Builder {
    /// The global registers of the catalogue: the gateway's figures at their offsets
    /// (its block is the global registers, from 0), its flags register
    /// [`GATEWAY_STATUS`], and a register per source flag, bit i for source i.
    fn gateway_and_sources(&mut self) {
        let figures = catalogue::GATEWAY;
        let (address, name) = GATEWAY_STATUS;
        let description = flags_description(figures);
        let flags = Field::Flags(Block::Gateway);
        let word = (address, ValueType::U16);
        self.global(word, name, "bits", Access::Read, &description, flags);
        for (index, figure) in figures.iter().enumerate() {
            if let Some(slot) = slot_on(figure, 0) {
                let field = Field::Figure(Block::Gateway, index);
                let description = figure.description;
                self.global(
                    slot,
                    figure.key,
                    figure.unit,
                    Access::Read,
                    description,
                    field,
                );
            }
        }
        for (index, figure) in catalogue::SOURCE.iter().enumerate() {
            if let catalogue::Register::IndexBit { address } = figure.register {
                self.global(
                    (address, ValueType::U16),
                    &source_bits_name(figure.key),
                    "bits",
                    Access::Read,
                    &format!(
                        "bit i for source i in config order (Modbus, then CAN; the first 16): {}",
                        figure.description
                    ),
                    Field::SourceBits(index),
                );
            }
        }
    }

    /// A register of the global block at `address` as `value_type`.
    fn global(
        &mut self,
        (address, value_type): (u16, ValueType),
        name: &str,
        unit: &'static str,
        access: Access,
        description: &str,
        field: Field,
    ) {
        self.registers.push(Register {
            name: name.into(),
            address,
            value_type,
            unit,
            scale: 1.0,
            word_order: WordOrder::Abcd,
            access,
            description: description.into(),
            field,
        });
    }

    /// Page `page` of a block of `figures` at `base` named `prefix.<key>`, its
    /// descriptions prefixed by `context`: page 0 holds the flags and quality
    /// registers and the figures declared [`Register::At`] page 0; page 1 (the
    /// extension block) its own quality register and the figures declared on it.
    #[allow(clippy::too_many_arguments)]
    fn block<R: Subject>(
        &mut self,
        base: u16,
        prefix: &str,
        context: &str,
        block: Block,
        figures: &[Figure<R>],
        page: u8,
    ) {
        let mut add = |offset: u16, key: &str, value_type, unit, description: String, field| {
            self.registers.push(Register {
                name: format!("{prefix}.{key}"),
                address: base + offset,
                value_type,
                unit,
                scale: 1.0,
                word_order: WordOrder::Abcd,
                access: Access::Read,
                description: format!("{context}{description}"),
                field,
            });
        };
        if page == 0 {
            add(
                0,
                "flags",
                ValueType::U16,
                "bits",
                flags_description(figures),
                Field::Flags(block),
            );
        }
        add(
            1,
            QUALITY[usize::from(page)],
            ValueType::U16,
            "bits",
            quality_description(figures, page),
            Field::Quality(block, page),
        );
        for (index, figure) in figures.iter().enumerate() {
            let Some((offset, value_type)) = slot_on(figure, page) else {
                continue;
            };
            let unit = match figure.figure_type {
                FigureType::Time => "s",
                _ => figure.unit,
            };
            let description = match figure.figure_type {
                FigureType::Time => format!("{}, Unix seconds", figure.description),
                _ => figure.description.to_owned(),
            };
            add(
                offset,
                figure.key,
                value_type,
                unit,
                description,
                Field::Figure(block, index),
            );
        }
    }
}

/// The name of each page's quality register.
const QUALITY: [&str; 2] = ["quality", "extension_quality"];

/// Where `figure` sits on page `page` of its block: offset and type.
fn slot_on<R>(figure: &Figure<R>, page: u8) -> Option<(u16, ValueType)> {
    match figure.register {
        catalogue::Register::At {
            page: on,
            offset,
            value_type,
        } if on == page => Some((offset, value_type)),
        _ => None,
    }
}

/// Whether any of `figures` sits on the extension block (page 1).
fn has_extension<R>(figures: &[Figure<R>]) -> bool {
    figures.iter().any(|figure| slot_on(figure, 1).is_some())
}

/// `bit0 <key> (<description>), ...` of the flag figures, by bit.
fn flags_description<R>(figures: &[Figure<R>]) -> String {
    let mut flags: Vec<(u8, &Figure<R>)> = figures
        .iter()
        .filter_map(|f| match f.guard {
            Guard::FlagBit(bit) => Some((bit, f)),
            _ => None,
        })
        .collect();
    flags.sort_by_key(|(bit, _)| *bit);
    flags
        .iter()
        .map(|(bit, f)| format!("bit{bit} {}: {}", f.key, f.description))
        .collect::<Vec<_>>()
        .join("; ")
}

/// `bit i set: value i of this block is valid (0 <key>, ...)` for the values of
/// page `page`.
fn quality_description<R>(figures: &[Figure<R>], page: u8) -> String {
    let mut bits: Vec<(u8, &str)> = figures
        .iter()
        .filter(|figure| slot_on(figure, page).is_some())
        .filter_map(|figure| match figure.guard {
            Guard::QualityBit(bit) => Some((bit, figure.key)),
            _ => None,
        })
        .collect();
    bits.sort_by_key(|(bit, _)| *bit);
    let list: Vec<String> = bits
        .iter()
        .map(|(bit, key)| format!("{bit} {key}"))
        .collect();
    format!(
        "bit i set: value i of this block is valid ({}); counters are always valid",
        list.join(", ")
    )
}

impl RegisterMap {
    /// The map for `config`, when it fits a Modbus table.
    pub fn try_new(config: &Config) -> Result<Self, MapTooLarge> {
        let span = span_of(config);
        if span > u64::from(u16::MAX) {
            return Err(MapTooLarge {
                drivelines: config.drivelines.len(),
                tandem_mills: config.tandem_mills.len(),
                rod_mills: config.rod_mills.len(),
                span,
            });
        }
        Ok(Self::new(config))
    }

    /// The map for `config`: global registers, then one block per driveline, one per
    /// tandem mill and one per rod mill (with its spans). The map must fit a Modbus
    /// table ([`Self::try_new`] checks; `Service::new` refuses a configuration whose
    /// map does not).
    pub fn new(config: &Config) -> Self {
        let mut b = Builder {
            registers: Vec::new(),
        };
        b.gateway_and_sources();
        b.global(
            (8, ValueType::U16),
            "command.acknowledge_alarms",
            "",
            Access::ReadWrite,
            "Command: write 1 to clear latched alarm bits; reads back 0",
            Field::AcknowledgeAlarms,
        );
        b.global(
            (9, ValueType::U16),
            "command.reset_wear_trend",
            "bits",
            Access::ReadWrite,
            "Command: write a bitmask of the first 16 drivelines (bit k = k-th driveline in \
             config order; 1 with a single driveline) to restart their wear trend and gap \
             estimate (after a coupling is replaced); reads back 0. Drivelines past the 16th: \
             command.reset_wear",
            Field::ResetWearTrend,
        );
        b.global(
            (10, ValueType::U16),
            "command.reset_wear",
            "",
            Access::ReadWrite,
            "Command: write a driveline's number (1-based, config order) to restart its wear \
             trend and gap estimate; reads back 0",
            Field::ResetWear,
        );
        b.global(
            (11, ValueType::U16),
            "command.manual_capture",
            "",
            Access::ReadWrite,
            "Command: write seconds * 256 + a driveline's number (both 1..=255; 0 in the \
             high byte: 10 s) to keep the next seconds of its torque as a capture of kind \
             manual (with [history]); numbers after the drivelines' name the tandem mills \
             in order (all their stands); reads back 0",
            Field::ManualCapture,
        );
        for (k, driveline) in config.drivelines.iter().enumerate() {
            let base = DRIVELINES_START + DRIVELINE_STRIDE * k as u16;
            b.block(
                base,
                &driveline.name,
                "",
                Block::Driveline(k),
                catalogue::DRIVELINE,
                0,
            );
        }
        let mills_start = DRIVELINES_START + DRIVELINE_STRIDE * config.drivelines.len() as u16;
        for (m, mill) in config.tandem_mills.iter().enumerate() {
            let base = mills_start + TANDEM_MILL_STRIDE * m as u16;
            b.block(
                base,
                &mill.name,
                "",
                Block::TandemMill(m),
                catalogue::TANDEM_MILL,
                0,
            );
        }
        let rods_start = mills_start + TANDEM_MILL_STRIDE * config.tandem_mills.len() as u16;
        for (k, mill) in config.rod_mills.iter().enumerate() {
            let base = rods_start + ROD_MILL_STRIDE * k as u16;
            b.block(
                base,
                &mill.name,
                "",
                Block::RodMill(k),
                catalogue::ROD_MILL,
                0,
            );
            for span in 0..MAX_ROD_SPANS {
                let span_base = base + ROD_SPANS_START + ROD_SPAN_STRIDE * span as u16;
                b.block(
                    span_base,
                    &format!("{}.span{}", mill.name, span + 1),
                    &format!(
                        "Span {} (stand {} to {} in rolling order): ",
                        span + 1,
                        span + 1,
                        span + 2
                    ),
                    Block::RodSpan(k, span),
                    catalogue::ROD_SPAN,
                    0,
                );
            }
        }
        let base_len = rods_start + ROD_MILL_STRIDE * config.rod_mills.len() as u16;
        let extensions = extension_strides(config);
        for (k, driveline) in config.drivelines.iter().enumerate() {
            if extensions.driveline > 0 {
                b.block(
                    base_len + extensions.driveline * k as u16,
                    &driveline.name,
                    "",
                    Block::Driveline(k),
                    catalogue::DRIVELINE,
                    1,
                );
            }
        }
        let strides = std::iter::once(DRIVELINES_START)
            .chain(std::iter::repeat_n(
                DRIVELINE_STRIDE,
                config.drivelines.len(),
            ))
            .chain(std::iter::repeat_n(
                TANDEM_MILL_STRIDE,
                config.tandem_mills.len(),
            ))
            .chain(std::iter::repeat_n(ROD_MILL_STRIDE, config.rod_mills.len()))
            .chain(std::iter::repeat_n(
                extensions.driveline,
                config.drivelines.len(),
            ))
            .filter(|stride| *stride > 0);
        let mut blocks: Vec<Range<u16>> = Vec::new();
        for stride in strides {
            let start = blocks.last().map_or(0, |b| b.end);
            blocks.push(start..start + stride);
        }
        let len = blocks.last().map_or(0, |b| b.end);
        let base_blocks = blocks.iter().filter(|b| b.end <= base_len).count();
        debug_assert_eq!(u64::from(len), span_of(config));
        let mut registers = b.registers;
        registers.sort_by_key(|register| register.address);
        Self {
            registers,
            len,
            base_len,
            base_blocks,
            blocks,
        }
    }

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
    /// [`catalogue::Register::At`]), after every other block, so that no address of
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

    /// Encode `results` into the whole map.
    pub fn encode(&self, results: &Results) -> Vec<u16> {
        let mut words = vec![0u16; usize::from(self.len)];
        for register in &self.registers {
            let Some(value) = value_of(register.field, results) else {
                continue;
            };
            let (encoded, used) = encode_value(
                value / register.scale,
                register.value_type,
                register.word_order,
            );
            let start = usize::from(register.address);
            words[start..start + used].copy_from_slice(&encoded[..used]);
        }
        words
    }
}

/// Bit i for source i (the first 16) while its flag `index` of [`catalogue::SOURCE`]
/// is set.
fn source_bits(results: &Results, index: usize) -> f64 {
    let flag = &catalogue::SOURCE[index];
    let mask = (0..results.sources.len().min(16))
        .filter(|&i| flag.read(&results.source(i)).good() == Some(Value::Bool(true)))
        .fold(0u16, |mask, i| mask | (1 << i));
    f64::from(mask)
}

/// A good figure as a register value: a time as Unix seconds, everything else as its
/// number.
fn register_value(value: Value) -> f64 {
    match value {
        Value::Time(ms) => ms.div_euclid(1000) as f64,
        other => other.as_f64(),
    }
}

/// The flags register of `subject`: every flag figure that is set, at its bit.
fn flags_of<R: Subject>(figures: &[Figure<R>], subject: &R) -> f64 {
    let flags = figures
        .iter()
        .filter_map(|f| match f.guard {
            Guard::FlagBit(bit) => Some((bit, f.read(subject).good())),
            _ => None,
        })
        .filter(|(_, value)| *value == Some(Value::Bool(true)))
        .fold(0u16, |flags, (bit, _)| flags | (1 << bit));
    f64::from(flags)
}

/// The quality register of page `page` of `subject`'s block: the bit of every value
/// figure on that page that is good (and finite).
fn quality_of<R: Subject>(figures: &[Figure<R>], page: u8, subject: &R) -> f64 {
    let mask = figures
        .iter()
        .filter(|figure| slot_on(figure, page).is_some())
        .filter_map(|f| match f.guard {
            Guard::QualityBit(bit) => Some((bit, f.read(subject).good())),
            _ => None,
        })
        .filter(|(_, value)| value.is_some_and(|v| v.as_f64().is_finite()))
        .fold(0u16, |mask, (bit, _)| mask | (1 << bit));
    f64::from(mask)
}

/// The value of a figure register: the good value, else nothing (the words stay 0).
fn figure_of<R: Subject>(figures: &[Figure<R>], index: usize, subject: &R) -> Option<f64> {
    figures[index]
        .read(subject)
        .good()
        .map(register_value)
        .filter(|v| v.is_finite())
}

/// What `field` of a block reads, with its subject and tables.
fn block_value<R: Subject>(field: Field, figures: &[Figure<R>], subject: &R) -> Option<f64> {
    match field {
        Field::Flags(_) => Some(flags_of(figures, subject)),
        Field::Quality(_, page) => Some(quality_of(figures, page, subject)),
        Field::Figure(_, index) => figure_of(figures, index, subject),
        _ => None,
    }
}

fn value_of(field: Field, results: &Results) -> Option<f64> {
    let block = match field {
        Field::SourceBits(index) => return Some(source_bits(results, index)),
        Field::AcknowledgeAlarms
        | Field::ResetWearTrend
        | Field::ResetWear
        | Field::ManualCapture => return Some(0.0),
        Field::Flags(block) | Field::Quality(block, _) | Field::Figure(block, _) => block,
    };
    match block {
        Block::Gateway => block_value(field, catalogue::GATEWAY, &results.gateway()),
        Block::Driveline(k) => block_value(field, catalogue::DRIVELINE, results.drivelines.get(k)?),
        Block::TandemMill(m) => {
            block_value(field, catalogue::TANDEM_MILL, results.tandem_mills.get(m)?)
        }
        Block::RodMill(k) => block_value(field, catalogue::ROD_MILL, results.rod_mills.get(k)?),
        Block::RodSpan(k, span) => block_value(
            field,
            catalogue::ROD_SPAN,
            &results.rod_mills.get(k)?.published_span(span),
        ),
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::field::source_health::SourceStatus;
    use crate::state::catalogue::Figure;
    use crate::state::results::{DrivelineResults, TandemMillResults};

    use crate::testing::example_config as example;

    /// The map of the tandem example and the address of its mill block.
    fn tandem_map() -> (RegisterMap, usize) {
        let map = RegisterMap::new(&example("tandem-5stand.toml"));
        let flags = map.named("TCM 2030.flags").expect("mill block");
        let base = usize::from(flags.address);
        (map, base)
    }

    #[test]
    fn blocks_tile_the_map_and_each_holds_one_subject_within_a_request() {
        let mut config = example("hot-mill.toml");
        config.drivelines.extend(example("demo.toml").drivelines);
        config.tandem_mills = example("tandem-5stand.toml").tandem_mills;
        config.rod_mills = example("rod-mill.toml").rod_mills;
        let map = RegisterMap::new(&config);
        let blocks = map.blocks();
        // The first layout's blocks, then each driveline's extension block.
        let first =
            1 + config.drivelines.len() + config.tandem_mills.len() + config.rod_mills.len();
        assert_eq!(blocks.len(), first + config.drivelines.len());
        assert_eq!(map.plc_blocks(false), &blocks[..first]);
        assert_eq!(map.plc_blocks(true), blocks);
        assert_eq!(map.plc_span(false), blocks[first - 1].end);
        assert_eq!(blocks[0].start, 0);
        assert_eq!(blocks.last().unwrap().end, map.len());
        for pair in blocks.windows(2) {
            assert_eq!(pair[0].end, pair[1].start, "contiguous: {blocks:?}");
        }
        // 123: the most one FC 16 request writes.
        assert!(blocks.iter().all(|b| b.len() <= 123), "{blocks:?}");
        for register in map.registers() {
            let end = register.address + register.value_type.register_count();
            let block = blocks
                .iter()
                .position(|b| b.contains(&register.address))
                .unwrap_or_else(|| panic!("{} in no block", register.name));
            assert!(
                end <= blocks[block].end,
                "{} straddles two blocks",
                register.name
            );
            // One subject per block: the globals in the first, a subject's registers
            // (a rod mill's spans with it) in its own.
            let subject = register.name.split('.').next().unwrap();
            let owner = match block {
                0 => None,
                k if k <= config.drivelines.len() => Some(&config.drivelines[k - 1].name),
                k if k <= config.drivelines.len() + config.tandem_mills.len() => {
                    Some(&config.tandem_mills[k - 1 - config.drivelines.len()].name)
                }
                k if k < first => Some(
                    &config.rod_mills[k - 1 - config.drivelines.len() - config.tandem_mills.len()]
                        .name,
                ),
                k => Some(&config.drivelines[k - first].name),
            };
            match owner {
                Some(name) => assert_eq!(subject, name.as_str(), "{}", register.name),
                None => assert!(
                    register.address < DRIVELINES_START,
                    "{} among the globals",
                    register.name
                ),
            }
        }
    }

    #[test]
    fn mill_block_golden_words() {
        let (map, base) = tandem_map();
        let mut results = Results::new(2, 0, 1);
        results.tandem_mills[0] = TandemMillResults {
            evaluations: 9,
            sigma_n_hz: Some(0.5),
            k_mean: Some(0.25),
            chatter_frequency_hz: Some(200.0),
            chatter_gain: Some(3.5),
            gain_ratio: Some(1.25),
            band_rms_max: Some(2.0),
            worst_stand: Some(3),
            chatter_warning: true,
            chatter_alarm: true,
            source_stale: false,
            slow_down_request: true,
        };
        let words = map.encode(&results);
        assert_eq!(words[base], 0b1011, "warning, alarm, slow-down");
        assert_eq!(words[base + 1], 0b111_1111, "every value valid");
        // f32 ABCD: 0.5 = 0x3F000000, 0.25 = 0x3E800000, 200 = 0x43480000,
        // 3.5 = 0x40600000, 1.25 = 0x3FA00000, 2 = 0x40000000; stand 3 is the 4th.
        assert_eq!(
            words[base + 2..base + 15],
            [0x3F00, 0, 0x3E80, 0, 0x4348, 0, 0x4060, 0, 0x3FA0, 0, 0x4000, 0, 4]
        );

        // Before the gain's window is full: its values invalid, the spectra's valid.
        let mill = &mut results.tandem_mills[0];
        mill.chatter_gain = None;
        mill.gain_ratio = None;
        mill.band_rms_max = None;
        mill.worst_stand = None;
        let words = map.encode(&results);
        assert_eq!(words[base + 1], 0b000_0111);
        assert_eq!(words[base + 8..base + 15], [0; 7]);

        // Stale: every value reads 0 with its quality bit clear; the request holds.
        let mill = &mut results.tandem_mills[0];
        mill.gain_ratio = Some(1.25);
        mill.source_stale = true;
        mill.chatter_warning = false;
        let words = map.encode(&results);
        assert_eq!(
            words[base], 0b1110,
            "alarm (latched), stale, slow-down held"
        );
        assert_eq!(words[base + 1], 0);
        assert_eq!(words[base + 2..base + 15], [0; 13]);
    }

    #[test]
    fn driveline_block_golden_words_and_the_stale_rule() {
        let config = example("hot-mill.toml");
        let map = RegisterMap::new(&config);
        let base = usize::from(
            map.named("F1 main drive.flags")
                .expect("driveline block")
                .address,
        );
        let mut results = Results::new(config.sources().count(), config.drivelines.len(), 0);
        let driveline = DrivelineResults {
            bite_counter: 70_000,
            degraded_bites: 2,
            last_bite_unix_ms: Some(1_800_000_000_999),
            taf: Some(1.5),
            gap: Some(crate::state::results::GapResults {
                gap_mrad: 2.5,
                low_mrad: 2.0,
                high_mrad: 3.0,
                coupling: None,
                likeliest_coupling: Some(1),
                bites_pooled: 12,
            }),
            taf_warning: true,
            restored: true,
            ..DrivelineResults::default()
        };
        results.drivelines[0] = driveline.clone();
        let words = map.encode(&results);
        assert_eq!(words[base], 0b100_0001, "taf_warning, restored");
        // last_bite_time (bit 0), taf (3), gap, interval (9-11), bites_pooled (13): the
        // coupling is undetermined, bit 12 clear.
        assert_eq!(words[base + 1], 0b10_1110_0000_1001);
        assert_eq!(words[base + 2..base + 4], [0x0001, 0x1170], "70 000");
        // 1 800 000 000 s = 0x6B49D200, whole seconds.
        assert_eq!(words[base + 4..base + 6], [0x6B49, 0xD200]);
        assert_eq!(words[base + 10..base + 12], [0x3FC0, 0], "TAF 1.5");
        assert_eq!(words[base + 22..base + 24], [0x4020, 0], "gap 2.5 mrad");
        assert_eq!(words[base + 28], 0, "undetermined coupling: no value");
        assert_eq!(words[base + 29], 12);
        assert_eq!(words[base + 30..base + 32], [0, 2], "degraded bites");

        // Stale: the last bite's values are withheld (last usable only), counters and
        // flags stay.
        results.drivelines[0].source_stale = true;
        let words = map.encode(&results);
        assert_eq!(
            words[base], 0b100_0101,
            "taf_warning, source_stale, restored"
        );
        assert_eq!(words[base + 1], 0);
        assert_eq!(words[base + 2..base + 4], [0x0001, 0x1170]);
        assert!(words[base + 4..base + 30].iter().all(|&w| w == 0));
        assert_eq!(words[base + 30..base + 32], [0, 2]);
    }

    #[test]
    fn the_extension_block_holds_the_figures_declared_on_it_after_every_block() {
        let config = example("hot-mill.toml");
        let map = RegisterMap::new(&config);
        let quality = map
            .named("F1 main drive.extension_quality")
            .expect("the driveline's extension block")
            .address;
        assert_eq!(quality, map.plc_span(false) + 1, "after the first layout");
        let q = usize::from(quality);
        let mut results = Results::new(config.sources().count(), config.drivelines.len(), 0);
        results.drivelines[0] = DrivelineResults {
            first_period_s: Some(0.0625),
            gap: Some(crate::state::results::GapResults {
                gap_mrad: 2.5,
                low_mrad: 2.0,
                high_mrad: 3.0,
                coupling: None,
                likeliest_coupling: Some(2),
                bites_pooled: 12,
            }),
            ..DrivelineResults::default()
        };
        let words = map.encode(&results);
        assert_eq!(words[q], 0b11, "first_period_s, likeliest_coupling valid");
        // 0.0625 = 0x3D800000 (f32 ABCD).
        assert_eq!(words[q + 1..q + 4], [0x3D80, 0, 2]);
        results.drivelines[0].source_stale = true;
        let words = map.encode(&results);
        assert_eq!(words[q..q + 4], [0; 4], "withheld while stale");
    }

    /// Every figure of `figures` has a register with a guard that fits it, or a
    /// reason; each page's registers fit `strides[page]` (after its flags and quality
    /// registers) and overlap nothing; a quality bit guards one value of its page.
    fn covers<R: Subject>(figures: &[Figure<R>], strides: &[u16]) {
        let kind = R::KIND;
        let mut used: Vec<Vec<bool>> = strides
            .iter()
            .map(|&stride| {
                let mut used = vec![false; usize::from(stride)];
                used[0] = true;
                used[1] = true;
                used
            })
            .collect();
        let mut bits: Vec<Vec<u8>> = vec![Vec::new(); strides.len()];
        for figure in figures {
            match (figure.register, figure.guard) {
                (
                    catalogue::Register::At {
                        page,
                        offset,
                        value_type,
                    },
                    guard,
                ) => {
                    let page = usize::from(page);
                    let words = used
                        .get_mut(page)
                        .unwrap_or_else(|| panic!("{}: no page {page}", figure.key));
                    for word in offset..offset + value_type.register_count() {
                        let slot = words
                            .get_mut(usize::from(word))
                            .unwrap_or_else(|| panic!("{} runs past the block", figure.key));
                        assert!(!*slot, "{} overlaps another register", figure.key);
                        *slot = true;
                    }
                    match guard {
                        Guard::QualityBit(bit) => {
                            assert!(bit < 16, "{}", figure.key);
                            assert!(
                                !bits[page].contains(&bit),
                                "{}: bit {bit} twice",
                                figure.key
                            );
                            bits[page].push(bit);
                        }
                        Guard::Always => assert!(figure.is_counter(), "{}", figure.key),
                        other => panic!("{}: a register value guarded by {other:?}", figure.key),
                    }
                }
                (catalogue::Register::Flag, guard) => {
                    assert!(matches!(guard, Guard::FlagBit(_)), "{}", figure.key)
                }
                (catalogue::Register::IndexBit { .. }, _) => {
                    panic!(
                        "{}: a block's figure as a global register's bit",
                        figure.key
                    )
                }
                (catalogue::Register::NotMapped(why), guard) => {
                    assert!(
                        !why.is_empty(),
                        "{} {} needs a reason",
                        kind.name(),
                        figure.key
                    );
                    assert!(
                        matches!(guard, Guard::Presence | Guard::Always),
                        "{}: unmapped, guarded by {guard:?}",
                        figure.key
                    );
                }
            }
        }
    }

    #[test]
    fn every_catalogue_figure_has_a_register_or_a_reason() {
        covers(
            catalogue::DRIVELINE,
            &[DRIVELINE_STRIDE, DRIVELINE_EXTENSION_STRIDE],
        );
        covers(catalogue::TANDEM_MILL, &[TANDEM_MILL_STRIDE]);
        covers(catalogue::ROD_MILL, &[ROD_SPANS_START]);
        covers(catalogue::ROD_SPAN, &[ROD_SPAN_STRIDE]);
    }

    #[test]
    fn register_names_are_block_names_and_catalogue_keys() {
        let map = RegisterMap::new(&example("rod-mill.toml"));
        let keys: Vec<&str> = catalogue::all().iter().map(|f| f.key).collect();
        for register in map.registers() {
            let key = register.name.rsplit('.').next().unwrap_or_default();
            let named = match register.field {
                Field::AcknowledgeAlarms
                | Field::ResetWearTrend
                | Field::ResetWear
                | Field::ManualCapture => register.name.starts_with("command."),
                Field::Flags(Block::Gateway) => register.name == GATEWAY_STATUS.1,
                Field::SourceBits(index) => {
                    register.name == source_bits_name(catalogue::SOURCE[index].key)
                }
                _ => key == "flags" || QUALITY.contains(&key) || keys.contains(&key),
            };
            assert!(named, "{} is not named by a catalogue key", register.name);
        }
    }

    /// The global registers, as a PLC has always read them: heartbeat 0,
    /// `gateway_status` 1 (bit0 running, bit1 stopped, bit2 a source not ok),
    /// `sources_ok` 2, `sources_stale` 3, `sources_lost` 4 (bit i: source i), the
    /// commands at 8..=11; nothing else below the first block.
    #[test]
    fn the_global_registers_golden_words() {
        let map = RegisterMap::new(&example("hot-mill.toml"));
        let globals: Vec<(u16, &str, &str)> = map
            .registers()
            .iter()
            .filter(|r| r.address < DRIVELINES_START)
            .map(|r| (r.address, r.name.as_str(), r.unit))
            .collect();
        assert_eq!(
            globals,
            [
                (0, "heartbeat", ""),
                (1, "gateway_status", "bits"),
                (2, "sources_ok", "bits"),
                (3, "sources_stale", "bits"),
                (4, "sources_lost", "bits"),
                (8, "command.acknowledge_alarms", ""),
                (9, "command.reset_wear_trend", "bits"),
                (10, "command.reset_wear", ""),
                (11, "command.manual_capture", ""),
            ]
        );
        assert!(map
            .registers()
            .iter()
            .filter(|r| r.address < DRIVELINES_START)
            .all(|r| r.value_type == ValueType::U16));
        let mut results = Results::new(5, 1, 0);
        assert_eq!(map.encode(&results)[..5], [0, 0b100, 0, 0, 0], "starting");
        results.state = crate::state::results::GatewayState::Running;
        results.heartbeat = 65_535;
        let (ok, stale, lost) = (SourceStatus::Ok, SourceStatus::Stale, SourceStatus::Lost);
        results.sources = [ok, stale, lost, ok, ok].map(Some).to_vec();
        let words = map.encode(&results);
        assert_eq!(words[..5], [65_535, 0b101, 0b11001, 0b10, 0b100]);
        results.sources = vec![Some(ok); 5];
        results.state = crate::state::results::GatewayState::Stopped;
        assert_eq!(map.encode(&results)[..5], [65_535, 0b010, 0b11111, 0, 0]);
        assert_eq!(
            flag_mask(catalogue::GATEWAY, "source_problem"),
            0b100,
            "as PLC programs test it"
        );
    }

    /// The gateway's and the sources' figures are the global registers': each has a
    /// register (the gateway's block from 0, its flags in `gateway_status`, a source's
    /// flag a bit of a global register) or a reason, below the first block and apart
    /// from the command registers.
    #[test]
    fn every_gateway_and_source_figure_has_a_global_register_or_a_reason() {
        let commands = 8..12;
        let mut used = vec![GATEWAY_STATUS.0];
        for figure in catalogue::GATEWAY {
            match (figure.register, figure.guard) {
                (catalogue::Register::At { page, offset, .. }, Guard::Always) => {
                    assert_eq!(page, 0, "{}", figure.key);
                    used.push(offset);
                }
                (catalogue::Register::Flag, Guard::FlagBit(bit)) => {
                    assert!(bit < 16, "{}", figure.key)
                }
                (catalogue::Register::NotMapped(why), Guard::Presence) => {
                    assert!(!why.is_empty(), "gateway {} needs a reason", figure.key)
                }
                other => panic!("gateway {}: {other:?}", figure.key),
            }
        }
        for figure in catalogue::SOURCE {
            match (figure.register, figure.guard) {
                (catalogue::Register::IndexBit { address }, Guard::Presence) => {
                    assert_eq!(figure.figure_type, FigureType::Bool, "{}", figure.key);
                    used.push(address);
                }
                (catalogue::Register::NotMapped(why), Guard::Presence) => {
                    assert!(!why.is_empty(), "source {} needs a reason", figure.key)
                }
                other => panic!("source {}: {other:?}", figure.key),
            }
        }
        let mut unique = used.clone();
        unique.sort_unstable();
        unique.dedup();
        assert_eq!(
            unique.len(),
            used.len(),
            "two figures at one address: {used:?}"
        );
        for address in used {
            assert!(address < DRIVELINES_START && !commands.contains(&address));
        }
        let map = RegisterMap::new(&example("hot-mill.toml"));
        for (index, figure) in catalogue::SOURCE.iter().enumerate() {
            if let catalogue::Register::IndexBit { address } = figure.register {
                let register = map.find(address).expect("a register");
                assert_eq!(register.field, Field::SourceBits(index));
            }
        }
    }
}
