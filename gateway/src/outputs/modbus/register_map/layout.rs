//! Where every register sits: the global registers (the gateway's and the sources'
//! figures, the commands), a block per subject and each driveline's extension block,
//! placed as the catalogue declares them.

use std::ops::Range;

use millgate_config::{Config, ValueType, WordOrder};

use super::{Access, Block, Field, MapTooLarge, Register, RegisterMap, GATEWAY_STATUS};
use crate::state::catalogue::{self, Figure, FigureType, Guard, Subject};
use crate::state::results::MAX_ROD_SPANS;

/// First register of the first driveline block.
pub(super) const DRIVELINES_START: u16 = 16;
/// Registers reserved per driveline block.
pub(super) const DRIVELINE_STRIDE: u16 = 32;
/// Registers reserved per tandem mill block.
pub(super) const TANDEM_MILL_STRIDE: u16 = 16;
/// First register of a rod mill's first span, from the rod mill's block start.
pub(super) const ROD_SPANS_START: u16 = 8;
/// Registers per rod span.
pub(super) const ROD_SPAN_STRIDE: u16 = 8;
/// Registers reserved per rod mill block: the mill's own, then [`MAX_ROD_SPANS`] spans.
pub(super) const ROD_MILL_STRIDE: u16 = ROD_SPANS_START + ROD_SPAN_STRIDE * MAX_ROD_SPANS as u16;

/// Registers per extension block, by subject (0: the subject has none): see
/// [`RegisterMap::base_len`].
struct ExtensionStrides {
    driveline: u16,
}

/// A driveline's extension block (page 1 of the catalogue's [`catalogue::Register`]):
/// its quality register at 1 and the figures declared on it.
pub(super) const DRIVELINE_EXTENSION_STRIDE: u16 = 32;

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
pub(super) fn span_of(config: &Config) -> u64 {
    let extensions = extension_strides(config);
    u64::from(DRIVELINES_START)
        + u64::from(DRIVELINE_STRIDE + extensions.driveline) * config.driveline_slots() as u64
        + u64::from(TANDEM_MILL_STRIDE) * config.tandem_mills.len() as u64
        + u64::from(ROD_MILL_STRIDE) * config.rod_mills.len() as u64
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

    /// Page `page` of each driveline slot's block from `start`, `stride` apart: the
    /// driveline's block, or past the drivelines the slot's reserved one
    /// ([`Self::reserved`]).
    fn driveline_slots(&mut self, config: &Config, start: u16, stride: u16, page: u8) {
        let slots = config.driveline_slots();
        for k in 0..slots {
            let base = start + stride * k as u16;
            match config.drivelines.get(k) {
                Some(driveline) => self.block(
                    base,
                    &driveline.name,
                    "",
                    Block::Driveline(k),
                    catalogue::DRIVELINE,
                    page,
                ),
                None => self.reserved(base, (k, slots), stride, page),
            }
        }
    }

    /// The quality register (register 1) of page `page` of the driveline block at
    /// `base` that slot `k` of `slots` (`outputs.driveline_slots`) reserves for a
    /// driveline added later: `driveline_slot<k+1>.quality` (or `.extension_quality`),
    /// which reads 0 like the rest of the block until a driveline takes it. Listed so
    /// that `millgate registers` and the docs show where the reserved blocks are.
    fn reserved(&mut self, base: u16, (k, slots): (usize, usize), stride: u16, page: u8) {
        let page_name = ["block", "extension block"][usize::from(page)];
        self.registers.push(Register {
            name: format!("driveline_slot{}.{}", k + 1, QUALITY[usize::from(page)]),
            address: base + 1,
            value_type: ValueType::U16,
            unit: "bits",
            scale: 1.0,
            word_order: WordOrder::Abcd,
            access: Access::Read,
            description: format!(
                "Reserved by outputs.driveline_slots ({slots}): the {page_name} {base}..={} of \
                 the driveline numbered {} in config order once one is added; reads 0 (quality \
                 0: no value valid) until then",
                base + stride - 1,
                k + 1,
            ),
            field: Field::Quality(Block::Driveline(k), page),
        });
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
    /// registers and the figures declared [`Register::At`](crate::state::catalogue::Register::At) page 0; page 1 (the
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
pub(super) const QUALITY: [&str; 2] = ["quality", "extension_quality"];

/// Where `figure` sits on page `page` of its block: offset and type.
pub(super) fn slot_on<R>(figure: &Figure<R>, page: u8) -> Option<(u16, ValueType)> {
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
                drivelines: config.driveline_slots(),
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
        build(config)
    }
}

/// The map of `config` (see [`RegisterMap::new`]).
fn build(config: &Config) -> RegisterMap {
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
    b.global(
        (12, ValueType::U16),
        "command.reset_fatigue",
        "",
        Access::ReadWrite,
        "Command: write a fatigue component's number * 256 + its driveline's number (both \
             1-based, config order: drivelines[].fatigue.components) to start the \
             component's life used at 0 (after it was replaced; recorded in the history); \
             reads back 0",
        Field::ResetFatigue,
    );
    let slots = config.driveline_slots();
    b.driveline_slots(config, DRIVELINES_START, DRIVELINE_STRIDE, 0);
    let mills_start = DRIVELINES_START + DRIVELINE_STRIDE * slots as u16;
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
    if extensions.driveline > 0 {
        b.driveline_slots(config, base_len, extensions.driveline, 1);
    }
    let strides = std::iter::once(DRIVELINES_START)
        .chain(std::iter::repeat_n(DRIVELINE_STRIDE, slots))
        .chain(std::iter::repeat_n(
            TANDEM_MILL_STRIDE,
            config.tandem_mills.len(),
        ))
        .chain(std::iter::repeat_n(ROD_MILL_STRIDE, config.rod_mills.len()))
        .chain(std::iter::repeat_n(extensions.driveline, slots))
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
    RegisterMap {
        registers,
        len,
        base_len,
        base_blocks,
        blocks,
    }
}
