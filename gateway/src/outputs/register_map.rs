//! The millgate register map: one typed table, in one place.
//!
//! Every register the gateway publishes is a [`Register`] built here: its address
//! (offset from the map's base), type, unit, scale, word order, access and meaning.
//! Encoding ([`RegisterMap::encode`]) is a pure function of [`Results`]; the PLC
//! writer, the Modbus server and the `millgate registers` export all use this table.
//!
//! Conventions: 32-bit values (u32, f32) are big-endian words and bytes (`ABCD`,
//! the Modbus default); physical value = register value * scale. A value whose
//! quality bit is 0 is not valid (never computed, or its source is stale): the
//! registers then hold 0 rather than a frozen old value.

use millgate_config::layout::encode_value;
use millgate_config::{Config, ValueType, WordOrder};

use crate::analysis::rod_monitor::MAX_ROD_SPANS;
use crate::outputs::results::{
    DrivelineResults, GatewayState, MillResults, Results, RodMillResults, RodSpanResults,
};

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

/// Per-driveline quantities, in register order.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DrivelineField {
    /// Warning, alarm, stale and degraded bits ([`driveline_flags`]).
    Flags,
    /// Bit i set: value i of the block is valid.
    Quality,
    /// Bites analysed since start.
    BiteCounter,
    /// Time of the last bite, Unix seconds.
    LastBiteTime,
    /// Static torque of the last bite, kN*m.
    StaticTorque,
    /// Peak torque of the last bite, kN*m.
    PeakTorque,
    /// Torque amplification factor of the last bite.
    Taf,
    /// First minus second oscillation period of the last bite, s.
    PeriodShift,
    /// First natural frequency from the eq. (1) fit, Hz.
    Beta1,
    /// Second natural frequency from the eq. (1) fit, Hz.
    Beta2,
    /// TAF-ratio wear index of the last bite (secondary to the gap).
    WearIndex,
    /// Wear trend (EWMA of the wear index).
    WearTrend,
    /// Opened gap, maximum likelihood, mrad.
    Gap,
    /// Lower end of the gap's 90% interval, mrad.
    GapLow,
    /// Upper end of the gap's 90% interval, mrad.
    GapHigh,
    /// Coupling holding the gap, [`GAP_COUPLING_UNDETERMINED`] when undetermined.
    GapCoupling,
    /// Bites pooled into the gap estimate.
    BitesPooled,
}

/// `gap_coupling` when the bites cannot tell which coupling holds the gap.
pub const GAP_COUPLING_UNDETERMINED: u16 = u16::MAX;

/// Per-mill chatter quantities, in register order.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MillField {
    /// Warning, alarm and stale bits.
    Flags,
    /// Bit i set: value i of the block is valid.
    Quality,
    /// RMS difference of adjacent stands' principal frequencies, Hz.
    SigmaN,
    /// Mean correlation of adjacent stands' chatter-band vibration.
    KMean,
    /// Mean of the stands' principal frequencies in the chatter band, Hz.
    ChatterFrequency,
    /// Largest chatter-band gain of any stand.
    ChatterGain,
    /// Largest gain / threshold of any stand (>= 1: band-gain alarm).
    GainRatio,
    /// Largest chatter-band RMS of any stand.
    BandRmsMax,
    /// 1-based stand of the gain ratio.
    WorstStand,
}

/// Flag bits of a tandem mill's `flags` register.
pub mod mill_flags {
    /// The configured detector's warning in the last window.
    pub const WARNING: u16 = 1 << 0;
    /// The configured detector's alarm; latched until acknowledged.
    pub const ALARM: u16 = 1 << 1;
    /// A stand's source is stale or the window restarted: values invalid.
    pub const SOURCE_STALE: u16 = 1 << 2;
    /// Slow-down request with hysteresis (the PLC decides the speed drop).
    pub const SLOW_DOWN_REQUEST: u16 = 1 << 3;
}

/// Per-rod-mill quantities, in register order.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RodMillField {
    /// Any span unstable, any near a tongue, inputs invalid ([`rod_flags`]).
    Flags,
    /// Bit i set: value i of the block is valid.
    Quality,
    /// Configuration input in use (index into the rod mill's `configurations`).
    Configuration,
    /// Pass number in use, 1-based.
    Pass,
    /// Finishing speed evaluated, m/s.
    FinishingSpeed,
    /// Rod temperature of the setup in use, deg C.
    Temperature,
}

/// Per-span quantities of a rod mill, in register order.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RodSpanField {
    /// Unstable, near tongue, invalid bits ([`rod_flags`]).
    Flags,
    /// Bit i set: value i is valid.
    Quality,
    /// Finishing-speed margin to the nearest band edge, m/s.
    SpeedMargin,
    /// Worst growth exponent of the span's points, 1/s.
    WorstExponent,
    /// Configuration input the span was evaluated in.
    Configuration,
}

/// What a register holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Field {
    /// Incremented every write period.
    Heartbeat,
    /// Running, stopped, source problem bits ([`status_bits`]).
    GatewayStatus,
    /// Bit i: source i answers.
    SourcesOk,
    /// Bit i: source i is stale.
    SourcesStale,
    /// Bit i: source i is lost.
    SourcesLost,
    /// Command: write 1 to acknowledge latched alarms.
    AcknowledgeAlarms,
    /// Command: write a bitmask of drivelines (bit k = driveline k) to reset their
    /// wear trend.
    ResetWearTrend,
    /// A quantity of driveline k (config order).
    Driveline(usize, DrivelineField),
    /// A quantity of tandem mill k (config order).
    Mill(usize, MillField),
    /// A quantity of rod mill k (config order).
    RodMill(usize, RodMillField),
    /// A quantity of span s (rolling order) of rod mill k.
    RodSpan(usize, usize, RodSpanField),
}

/// One register (or register pair) of the map.
#[derive(Debug, Clone, PartialEq)]
pub struct Register {
    /// Dotted name, e.g. `F1.taf`.
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

/// Flag bits of a driveline's `flags` register.
pub mod driveline_flags {
    /// TAF above the warning threshold at the last bite.
    pub const WARNING: u16 = 1 << 0;
    /// TAF above the alarm threshold; latched until acknowledged.
    pub const ALARM: u16 = 1 << 1;
    /// The torque channel's source is stale or lost.
    pub const SOURCE_STALE: u16 = 1 << 2;
    /// The last bite's window had gaps, NaN or saturated samples: its values are not
    /// valid (quality bits clear).
    pub const DEGRADED: u16 = 1 << 3;
    /// The estimated opened gap is at or above the gap warning threshold.
    pub const GAP_WARNING: u16 = 1 << 4;
    /// The gap's 90% interval lay at or above the gap alarm threshold; latched until
    /// acknowledged.
    pub const GAP_ALARM: u16 = 1 << 5;
    /// The values are from before the gateway's last restart (restored from the
    /// history; `last_bite_time` says when); cleared by the next bite.
    pub const RESTORED: u16 = 1 << 6;
}

/// Flag bits of a rod mill's and a rod span's `flags` register.
pub mod rod_flags {
    /// The span is unstable (mill: any span), with hysteresis.
    pub const UNSTABLE: u16 = 1 << 0;
    /// The span is stable but near a tongue (mill: any span), with hysteresis.
    pub const NEAR_TONGUE: u16 = 1 << 1;
    /// No valid result: an input's source is stale or lost, or an input was refused
    /// (out of range); the other bits are then 0.
    pub const INVALID: u16 = 1 << 2;
}

/// Bits of the gateway status register.
pub mod status_bits {
    /// The gateway is running and publishing fresh results.
    pub const RUNNING: u16 = 1 << 0;
    /// The gateway has stopped in order; every other register keeps its last running
    /// value (source bits included) and will not change.
    pub const STOPPED: u16 = 1 << 1;
    /// At least one source is stale or lost.
    pub const SOURCE_PROBLEM: u16 = 1 << 2;
}

/// First register of the first driveline block.
const DRIVELINES_START: u16 = 16;
/// Registers reserved per driveline block.
const DRIVELINE_STRIDE: u16 = 32;
/// Registers reserved per mill block.
const MILL_STRIDE: u16 = 16;
/// First register of a rod mill's first span, from the rod mill's block start.
const ROD_SPANS_START: u16 = 8;
/// Registers per rod span.
const ROD_SPAN_STRIDE: u16 = 8;
/// Registers reserved per rod mill block: the mill's own, then [`MAX_ROD_SPANS`] spans.
const ROD_MILL_STRIDE: u16 = ROD_SPANS_START + ROD_SPAN_STRIDE * MAX_ROD_SPANS as u16;

/// Registers the map of `drivelines` drivelines and `mills` tandem mills spans.
pub fn span(drivelines: usize, mills: usize) -> u64 {
    u64::from(DRIVELINES_START)
        + u64::from(DRIVELINE_STRIDE) * drivelines as u64
        + u64::from(MILL_STRIDE) * mills as u64
}

/// A configuration whose register map does not fit the 65 536 registers of a table.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error(
    "the register map of {drivelines} drivelines and {mills} tandem mills spans {span} \
     registers, more than the 65535 a Modbus table can address from 0"
)]
pub struct MapTooLarge {
    /// Drivelines configured.
    pub drivelines: usize,
    /// Tandem mills configured.
    pub mills: usize,
    /// Registers the map would span.
    pub span: u64,
}

/// The register map of one configuration.
#[derive(Debug, Clone, PartialEq)]
pub struct RegisterMap {
    registers: Vec<Register>,
    len: u16,
}

struct Builder {
    registers: Vec<Register>,
}

impl Builder {
    #[allow(clippy::too_many_arguments)]
    fn add(
        &mut self,
        address: u16,
        name: String,
        value_type: ValueType,
        unit: &'static str,
        scale: f64,
        access: Access,
        description: String,
        field: Field,
    ) {
        self.registers.push(Register {
            name,
            address,
            value_type,
            unit,
            scale,
            word_order: WordOrder::Abcd,
            access,
            description,
            field,
        });
    }
}

impl RegisterMap {
    /// The map for `config`, when it fits a Modbus table.
    pub fn try_new(config: &Config) -> Result<Self, MapTooLarge> {
        let (drivelines, mills) = (config.drivelines.len(), config.tandem_mills.len());
        let span = span(drivelines, mills);
        if span > u64::from(u16::MAX) {
            return Err(MapTooLarge {
                drivelines,
                mills,
                span,
            });
        }
        Ok(Self::new(config))
    }

    /// The map for `config`: global registers, then one block per driveline, then
    /// one per tandem mill. The map must fit a Modbus table ([`Self::try_new`] checks;
    /// `Service::new` refuses a configuration whose map does not).
    pub fn new(config: &Config) -> Self {
        use DrivelineField as D;
        use ValueType::{F32, U16, U32};
        let mut b = Builder {
            registers: Vec::new(),
        };
        let read = Access::Read;
        b.add(
            0,
            "heartbeat".into(),
            U16,
            "",
            1.0,
            read,
            "Incremented every PLC write period (every second without a PLC output), whether or not the PLC answers; a PLC or HMI watchdog checks it moves".into(),
            Field::Heartbeat,
        );
        b.add(
            1,
            "gateway_status".into(),
            U16,
            "bits",
            1.0,
            read,
            "bit0 running, bit1 stopped (an orderly stop: every other register, source bits and flags included, keeps its last running value), bit2 a source is stale or lost".into(),
            Field::GatewayStatus,
        );
        b.add(
            2,
            "sources_ok".into(),
            U16,
            "bits",
            1.0,
            read,
            "bit i: source i answers (sources in config order: Modbus, then CAN)".into(),
            Field::SourcesOk,
        );
        b.add(
            3,
            "sources_stale".into(),
            U16,
            "bits",
            1.0,
            read,
            "bit i: source i has not answered for longer than its stale time".into(),
            Field::SourcesStale,
        );
        b.add(
            4,
            "sources_lost".into(),
            U16,
            "bits",
            1.0,
            read,
            "bit i: source i is lost (never answered, or silent past its lost time)".into(),
            Field::SourcesLost,
        );
        b.add(
            8,
            "command.acknowledge_alarms".into(),
            U16,
            "",
            1.0,
            Access::ReadWrite,
            "Command: write 1 to clear latched alarm bits; reads back 0".into(),
            Field::AcknowledgeAlarms,
        );
        b.add(
            9,
            "command.reset_wear_trend".into(),
            U16,
            "bits",
            1.0,
            Access::ReadWrite,
            "Command: write a bitmask of drivelines (bit k = k-th driveline in config order; \
             1 with a single driveline) to restart their wear trend and gap estimate (after \
             a coupling is replaced); reads back 0"
                .into(),
            Field::ResetWearTrend,
        );
        for (k, driveline) in config.drivelines.iter().enumerate() {
            let base = DRIVELINES_START + DRIVELINE_STRIDE * k as u16;
            let n = |field: &str| format!("{}.{field}", driveline.name);
            let f = |field| Field::Driveline(k, field);
            let fields: [(u16, &str, ValueType, &'static str, &str, DrivelineField); 17] = [
                (0, "flags", U16, "bits", "bit0 TAF warning, bit1 TAF alarm (latched), bit2 source stale, bit3 last bite degraded (a gap, saturated or non-finite samples in its window: its values are not valid, their quality bits clear), bit4 gap warning, bit5 gap alarm (latched), bit6 values restored from before the last restart (last_bite_time says when; cleared by the next bite)", D::Flags),
                (1, "quality", U16, "bits", "bit i set: value i of this block is valid (0 last_bite_time, 1 static_torque, 2 peak_torque, 3 taf, 4 period_shift, 5 beta1, 6 beta2, 7 wear_index, 8 wear_trend, 9 gap_mrad, 10 gap_low_mrad, 11 gap_high_mrad, 12 gap_coupling, 13 bites_pooled)", D::Quality),
                (2, "bite_counter", U32, "", "Bites analysed since start (continued across restarts with a history)", D::BiteCounter),
                (4, "last_bite_time", U32, "s", "Time of the last bite, Unix seconds", D::LastBiteTime),
                (6, "static_torque", F32, "kN*m", "Static (settled) rolling torque of the last bite", D::StaticTorque),
                (8, "peak_torque", F32, "kN*m", "Peak torque of the last bite", D::PeakTorque),
                (10, "taf", F32, "", "Torque amplification factor of the last bite (peak / static)", D::Taf),
                (12, "period_shift", F32, "s", "First minus second oscillation period of the last bite", D::PeriodShift),
                (14, "beta1", F32, "Hz", "First natural frequency identified from the last bite", D::Beta1),
                (16, "beta2", F32, "Hz", "Second natural frequency identified from the last bite", D::Beta2),
                (18, "wear_index", F32, "", "Secondary figure: TAF-ratio wear index of the last bite, its TAF / the linear model's TAF - 1 (needs the driveline model)", D::WearIndex),
                (20, "wear_trend", F32, "", "Secondary figure: mean of the TAF-ratio wear index over bites (EWMA, weight 0.1), reset by command.reset_wear_trend", D::WearTrend),
                (22, "gap_mrad", F32, "mrad", "Opened gap (total dead-zone width, referred to the rolls), maximum likelihood over the pooled bites (needs the driveline model)", D::Gap),
                (24, "gap_low_mrad", F32, "mrad", "Lower end of the gap's 90% interval", D::GapLow),
                (26, "gap_high_mrad", F32, "mrad", "Upper end of the gap's 90% interval", D::GapHigh),
                (28, "gap_coupling", U16, "", "Coupling holding the gap (model index, 0 = motor side); 65535 = undetermined (the bites cannot tell)", D::GapCoupling),
                (29, "bites_pooled", U16, "", "Bites pooled into the gap estimate (the last drivelines[].wear.pool_bites; reset by command.reset_wear_trend)", D::BitesPooled),
            ];
            for (offset, name, value_type, unit, description, field) in fields {
                b.add(
                    base + offset,
                    n(name),
                    value_type,
                    unit,
                    1.0,
                    read,
                    description.into(),
                    f(field),
                );
            }
        }
        let mills_start = DRIVELINES_START + DRIVELINE_STRIDE * config.drivelines.len() as u16;
        for (m, mill) in config.tandem_mills.iter().enumerate() {
            use MillField as M;
            let base = mills_start + MILL_STRIDE * m as u16;
            let fields: [(u16, &str, ValueType, &'static str, &str, MillField); 9] = [
                (0, "flags", U16, "bits", "Bits of the configured detector (detector key; band gain by default): bit0 chatter warning (band gain: gain_ratio >= slow_down_release; paper: sigma_n <= sigma_min), bit1 chatter alarm (gain_ratio >= 1; paper: both conditions; latched until acknowledged), bit2 source stale or window restarted, bit3 slow-down request (hysteresis: set by the alarm condition, cleared after slow_down_hold_s below slow_down_release; held while stale)", M::Flags),
                (1, "quality", U16, "bits", "bit i set: value i is valid (0 sigma_n, 1 k_mean, 2 chatter_frequency, 3 chatter_gain, 4 gain_ratio, 5 band_rms_max, 6 worst_stand)", M::Quality),
                (2, "sigma_n", F32, "Hz", "RMS deviation of the adjacent stands' principal chatter-band frequencies", M::SigmaN),
                (4, "k_mean", F32, "", "Mean correlation of adjacent stands over the window", M::KMean),
                (6, "chatter_frequency", F32, "Hz", "Mean principal frequency in the chatter band", M::ChatterFrequency),
                (8, "chatter_gain", F32, "", "Largest chatter-band gain of any stand: chatter-band RMS / reference-band RMS over gain_window_s", M::ChatterGain),
                (10, "gain_ratio", F32, "", "Largest gain / gain_thresholds[stand] of any stand: the early-warning figure, >= 1 is the band-gain alarm", M::GainRatio),
                (12, "band_rms_max", F32, "", "Largest chatter-band RMS of any stand over gain_window_s, in the stand channels' unit", M::BandRmsMax),
                (14, "worst_stand", U16, "", "Stand of gain_ratio, 1-based in the mill's stands order (0 when not valid)", M::WorstStand),
            ];
            for (offset, name, value_type, unit, description, field) in fields {
                b.add(
                    base + offset,
                    format!("{}.{name}", mill.name),
                    value_type,
                    unit,
                    1.0,
                    read,
                    description.into(),
                    Field::Mill(m, field),
                );
            }
        }
        let rods_start = mills_start + MILL_STRIDE * config.tandem_mills.len() as u16;
        for (k, mill) in config.rod_mills.iter().enumerate() {
            use RodMillField as R;
            use RodSpanField as S;
            let base = rods_start + ROD_MILL_STRIDE * k as u16;
            let fields: [(u16, &str, ValueType, &'static str, &str, RodMillField); 6] = [
                (0, "flags", U16, "bits", "bit0 a span is unstable, bit1 a span is near a tongue, bit2 invalid (an input's source is stale or lost, or an input is out of range)", R::Flags),
                (1, "quality", U16, "bits", "bit i set: value i is valid (0 configuration, 1 pass, 2 finishing_speed, 3 rod_temperature)", R::Quality),
                (2, "configuration", U16, "", "Drive configuration in use: the PLC's value, an index into the rod mill's configurations", R::Configuration),
                (3, "pass", U16, "", "Pass in use: the PLC's pass number (1-based row of the schedule)", R::Pass),
                (4, "finishing_speed", F32, "m/s", "Finishing speed the spans were evaluated at", R::FinishingSpeed),
                (6, "rod_temperature", F32, "degC", "Rod temperature of the pass setup in use (rounded to temperature_step_c, or the schedule's)", R::Temperature),
            ];
            for (offset, name, value_type, unit, description, field) in fields {
                b.add(
                    base + offset,
                    format!("{}.{name}", mill.name),
                    value_type,
                    unit,
                    1.0,
                    read,
                    description.into(),
                    Field::RodMill(k, field),
                );
            }
            for span in 0..MAX_ROD_SPANS {
                let span_base = base + ROD_SPANS_START + ROD_SPAN_STRIDE * span as u16;
                let fields: [(u16, &str, ValueType, &'static str, &str, RodSpanField); 5] = [
                    (0, "flags", U16, "bits", "bit0 unstable, bit1 near a tongue (stable, speed margin < near_tongue_m_s), both with hysteresis; bit2 invalid (stale or refused input, or the mill has fewer spans)", S::Flags),
                    (1, "quality", U16, "bits", "bit i set: value i is valid (0 speed_margin, 1 worst_exponent, 2 configuration)", S::Quality),
                    (2, "speed_margin", F32, "m/s", "Finishing-speed change to the nearest unstable band edge: > 0 stable, < 0 unstable (the change that stabilises it); invalid when no band lies in the speed range", S::SpeedMargin),
                    (4, "worst_exponent", F32, "1/s", "Largest growth exponent of the span's points (< 0 decaying)", S::WorstExponent),
                    (6, "configuration", U16, "", "Drive configuration the span was evaluated in (index into the rod mill's configurations)", S::Configuration),
                ];
                for (offset, name, value_type, unit, description, field) in fields {
                    b.add(
                        span_base + offset,
                        format!("{}.span{}.{name}", mill.name, span + 1),
                        value_type,
                        unit,
                        1.0,
                        read,
                        format!(
                            "Span {} (stand {} to {} in rolling order): {description}",
                            span + 1,
                            span + 1,
                            span + 2
                        ),
                        Field::RodSpan(k, span, field),
                    );
                }
            }
        }
        let len = rods_start + ROD_MILL_STRIDE * config.rod_mills.len() as u16;
        Self {
            registers: b.registers,
            len,
        }
    }

    /// The registers, by address.
    pub fn registers(&self) -> &[Register] {
        &self.registers
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

fn bits(
    results: &Results,
    pick: impl Fn(crate::field::source_health::SourceStatus) -> bool,
) -> f64 {
    let mask = results
        .sources
        .iter()
        .enumerate()
        .take(16)
        .filter(|(_, status)| status.is_some_and(&pick))
        .fold(0u16, |mask, (i, _)| mask | (1 << i));
    f64::from(mask)
}

fn value_of(field: Field, results: &Results) -> Option<f64> {
    use crate::field::source_health::SourceStatus as S;
    match field {
        Field::Heartbeat => Some(f64::from(results.heartbeat)),
        Field::GatewayStatus => {
            let mut status = match results.state {
                GatewayState::Starting => 0,
                GatewayState::Running => status_bits::RUNNING,
                GatewayState::Stopped => status_bits::STOPPED,
            };
            if results.sources.iter().any(|s| *s != Some(S::Ok)) {
                status |= status_bits::SOURCE_PROBLEM;
            }
            Some(f64::from(status))
        }
        Field::SourcesOk => Some(bits(results, |s| s == S::Ok)),
        Field::SourcesStale => Some(bits(results, |s| s == S::Stale)),
        Field::SourcesLost => Some(bits(results, |s| s == S::Lost)),
        Field::AcknowledgeAlarms | Field::ResetWearTrend => Some(0.0),
        Field::Driveline(k, field) => results
            .drivelines
            .get(k)
            .and_then(|d| driveline_value(d, field)),
        Field::Mill(m, field) => results
            .mills
            .get(m)
            .and_then(|mill| mill_value(mill, field)),
        Field::RodMill(k, field) => results
            .rod_mills
            .get(k)
            .and_then(|mill| rod_mill_value(mill, field)),
        Field::RodSpan(k, span, field) => results
            .rod_mills
            .get(k)
            .and_then(|mill| rod_span_value(mill, span, field)),
    }
}

/// Values of a driveline block in quality-bit order.
fn driveline_quality_values(d: &DrivelineResults) -> [Option<f64>; 14] {
    let gap = d.gap.as_ref();
    [
        d.last_bite_unix_s.map(f64::from),
        d.static_torque_knm,
        d.peak_torque_knm,
        d.taf,
        d.first_period_shift_s,
        d.beta1_hz,
        d.beta2_hz,
        d.wear_index,
        d.wear_trend,
        gap.map(|g| g.gap_mrad),
        gap.map(|g| g.low_mrad),
        gap.map(|g| g.high_mrad),
        gap.map(|g| {
            g.coupling
                .and_then(|c| u16::try_from(c).ok())
                .filter(|&c| c != GAP_COUPLING_UNDETERMINED)
                .map_or(f64::from(GAP_COUPLING_UNDETERMINED), f64::from)
        }),
        gap.map(|g| g.bites_pooled.min(usize::from(u16::MAX)) as f64),
    ]
}

fn quality_mask(values: &[Option<f64>]) -> f64 {
    let mask = values
        .iter()
        .enumerate()
        .filter(|(_, v)| v.is_some_and(f64::is_finite))
        .fold(0u16, |mask, (i, _)| mask | (1 << i));
    f64::from(mask)
}

fn driveline_value(d: &DrivelineResults, field: DrivelineField) -> Option<f64> {
    use driveline_flags as fl;
    use DrivelineField as D;
    let fresh = |v: Option<f64>| v.filter(|_| !d.source_stale);
    match field {
        D::Flags => {
            let flags = [
                (d.warning, fl::WARNING),
                (d.alarm, fl::ALARM),
                (d.source_stale, fl::SOURCE_STALE),
                (d.last_bite_degraded, fl::DEGRADED),
                (d.gap_warning, fl::GAP_WARNING),
                (d.gap_alarm, fl::GAP_ALARM),
                (d.restored, fl::RESTORED),
            ]
            .iter()
            .filter(|(set, _)| *set)
            .fold(0, |flags, (_, bit)| flags | bit);
            Some(f64::from(flags))
        }
        D::Quality => {
            if d.source_stale {
                Some(0.0)
            } else {
                Some(quality_mask(&driveline_quality_values(d)))
            }
        }
        D::BiteCounter => Some(f64::from(d.bite_counter)),
        D::LastBiteTime => fresh(driveline_quality_values(d)[0]),
        D::StaticTorque => fresh(d.static_torque_knm),
        D::PeakTorque => fresh(d.peak_torque_knm),
        D::Taf => fresh(d.taf),
        D::PeriodShift => fresh(d.first_period_shift_s),
        D::Beta1 => fresh(d.beta1_hz),
        D::Beta2 => fresh(d.beta2_hz),
        D::WearIndex => fresh(d.wear_index),
        D::WearTrend => fresh(d.wear_trend),
        D::Gap => fresh(driveline_quality_values(d)[9]),
        D::GapLow => fresh(driveline_quality_values(d)[10]),
        D::GapHigh => fresh(driveline_quality_values(d)[11]),
        D::GapCoupling => fresh(driveline_quality_values(d)[12]),
        D::BitesPooled => fresh(driveline_quality_values(d)[13]),
    }
}

/// Values of a mill block in quality-bit order.
fn mill_quality_values(m: &MillResults) -> [Option<f64>; 7] {
    [
        m.sigma_n_hz,
        m.k_mean,
        m.chatter_frequency_hz,
        m.chatter_gain,
        m.gain_ratio,
        m.band_rms_max,
        m.worst_stand.map(|stand| stand as f64 + 1.0),
    ]
}

fn mill_value(m: &MillResults, field: MillField) -> Option<f64> {
    use mill_flags as fl;
    let fresh = |v: Option<f64>| v.filter(|_| !m.source_stale);
    match field {
        MillField::Flags => {
            let flags = [
                (m.warning, fl::WARNING),
                (m.alarm, fl::ALARM),
                (m.source_stale, fl::SOURCE_STALE),
                (m.slow_down_request, fl::SLOW_DOWN_REQUEST),
            ]
            .iter()
            .filter(|(set, _)| *set)
            .fold(0, |flags, (_, bit)| flags | bit);
            Some(f64::from(flags))
        }
        MillField::Quality => {
            if m.source_stale {
                Some(0.0)
            } else {
                Some(quality_mask(&mill_quality_values(m)))
            }
        }
        MillField::SigmaN => fresh(m.sigma_n_hz),
        MillField::KMean => fresh(m.k_mean),
        MillField::ChatterFrequency => fresh(m.chatter_frequency_hz),
        MillField::ChatterGain => fresh(m.chatter_gain),
        MillField::GainRatio => fresh(m.gain_ratio),
        MillField::BandRmsMax => fresh(m.band_rms_max),
        MillField::WorstStand => fresh(mill_quality_values(m)[6]),
    }
}

/// The unstable and near-tongue bits of a rod `flags` register.
fn rod_flag_bits(unstable: bool, near_tongue: bool) -> u16 {
    let bit = |set: bool, bit: u16| if set { bit } else { 0 };
    bit(unstable, rod_flags::UNSTABLE) | bit(near_tongue, rod_flags::NEAR_TONGUE)
}

fn rod_mill_value(m: &RodMillResults, field: RodMillField) -> Option<f64> {
    use RodMillField as R;
    let valid = m.valid();
    let values = [
        m.configuration.map(f64::from),
        m.pass.map(f64::from),
        m.finishing_speed_m_s,
        m.temperature_c,
    ];
    let fresh = |v: Option<f64>| v.filter(|_| valid);
    match field {
        R::Flags => {
            let any = |pick: fn(&RodSpanResults) -> bool| m.spans.iter().any(pick);
            Some(f64::from(if valid {
                rod_flag_bits(any(|s| s.unstable), any(|s| s.near_tongue))
            } else {
                rod_flags::INVALID
            }))
        }
        R::Quality => Some(if valid { quality_mask(&values) } else { 0.0 }),
        R::Configuration => fresh(values[0]),
        R::Pass => fresh(values[1]),
        R::FinishingSpeed => fresh(values[2]),
        R::Temperature => fresh(values[3]),
    }
}

fn rod_span_value(m: &RodMillResults, span: usize, field: RodSpanField) -> Option<f64> {
    use RodSpanField as S;
    let result = m.spans.get(span).filter(|s| s.valid && m.valid());
    let values = result.map(|s| {
        [
            s.speed_margin_m_s,
            s.worst_exponent_per_s,
            s.configuration.map(f64::from),
        ]
    });
    match field {
        S::Flags => Some(f64::from(match result {
            Some(s) => rod_flag_bits(s.unstable, s.near_tongue),
            None => rod_flags::INVALID,
        })),
        S::Quality => Some(values.map_or(0.0, |v| quality_mask(&v))),
        S::SpeedMargin => values.and_then(|v| v[0]),
        S::WorstExponent => values.and_then(|v| v[1]),
        S::Configuration => values.and_then(|v| v[2]),
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

    /// The map of the tandem example and the address of its mill block.
    fn tandem_map() -> (RegisterMap, usize) {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../config/examples/tandem-5stand.toml");
        let config = millgate_config::load(&path).expect("the tandem example loads");
        let map = RegisterMap::new(&config);
        let flags = map
            .registers()
            .iter()
            .find(|r| r.name == "TCM 2030.flags")
            .expect("mill block");
        let base = usize::from(flags.address);
        (map, base)
    }

    #[test]
    fn mill_block_golden_words() {
        let (map, base) = tandem_map();
        let mut results = Results::new(2, 0, 1);
        results.mills[0] = MillResults {
            evaluations: 9,
            sigma_n_hz: Some(0.5),
            k_mean: Some(0.25),
            chatter_frequency_hz: Some(200.0),
            chatter_gain: Some(3.5),
            gain_ratio: Some(1.25),
            band_rms_max: Some(2.0),
            worst_stand: Some(3),
            warning: true,
            alarm: true,
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
        results.mills[0].chatter_gain = None;
        results.mills[0].gain_ratio = None;
        results.mills[0].band_rms_max = None;
        results.mills[0].worst_stand = None;
        let words = map.encode(&results);
        assert_eq!(words[base + 1], 0b000_0111);
        assert_eq!(words[base + 8..base + 15], [0; 7]);

        // Stale: every value reads 0 with its quality bit clear; the request holds.
        results.mills[0].gain_ratio = Some(1.25);
        results.mills[0].source_stale = true;
        results.mills[0].warning = false;
        let words = map.encode(&results);
        assert_eq!(
            words[base], 0b1110,
            "alarm (latched), stale, slow-down held"
        );
        assert_eq!(words[base + 1], 0);
        assert_eq!(words[base + 2..base + 15], [0; 13]);
    }
}
