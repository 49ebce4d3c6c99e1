//! `[[drivelines]]`: torque and trigger channels, bite capture, TAF thresholds and the
//! driveline model file.

use millgate_dsp::miner::{EnduranceRule, MeanCorrection, SnCurve, SnCurveError, SnCurveSettings};

use crate::raw::{RawContextTags, RawDriveline, RawFatigue, RawFatigueComponent, RawWear};
use crate::{
    BiteSettings, Channel, ChannelKind, ChannelSource, ContextTags, Driveline, DrivelineThresholds,
    FatigueComponent, FatigueSettings, WearSettings,
};

use super::{
    optional, ChannelFacts, Checker, DEFAULT_POST_TRIGGER_S, DEFAULT_PRE_TRIGGER_S, MAX_WINDOW_S,
};

/// Gap warning threshold when none is given, mrad.
const DEFAULT_GAP_WARNING_MRAD: f64 = DrivelineThresholds::DEFAULT_GAP_WARNING_MRAD;
/// Gap alarm threshold when none is given, mrad.
const DEFAULT_GAP_ALARM_MRAD: f64 = DrivelineThresholds::DEFAULT_GAP_ALARM_MRAD;
/// Longest forecast horizon allowed, days (ten years).
const MAX_HORIZON_DAYS: f64 = 3650.0;
/// Longest `drivelines[].wear.growth_span_s`, s: the wear trend's longest span (30 days).
const MAX_GROWTH_SPAN_S: f64 = millgate_dsp::wear_trend::MAX_GROWTH_SPAN_DAYS * 86_400.0;
/// Largest `max_gap_mrad` allowed, mrad.
const MAX_MAX_GAP_MRAD: f64 = 100.0;
/// Most gap steps of a wear map.
const MAX_GAP_STEPS: f64 = 400.0;
/// The fatigue gate when none is given, as a fraction of the torque channel's range.
const DEFAULT_GATE_OF_RANGE: f64 = 0.01;
/// The fatigue gate when none is given and the channel's range is not bounded, as a
/// fraction of the bite threshold.
const DEFAULT_GATE_OF_THRESHOLD: f64 = 0.1;
/// The fatigue life limit when none is given.
const DEFAULT_LIFE_LIMIT: f64 = 0.8;

/// The range of engineering values the channel's encoding can carry, kN*m: a block
/// channel's i16 counts, a CAN signal's raw range; `None` for a plain-register value
/// (floats and 32-bit integers: no useful bound).
fn channel_range(channel: &Channel) -> Option<f64> {
    let range = match &channel.source {
        ChannelSource::ModbusBlock { .. } => f64::from(u16::MAX) * channel.scale.abs(),
        ChannelSource::Can { signal_layout, .. } => {
            let counts = (2.0_f64).powi(i32::from(signal_layout.size)) - 1.0;
            counts * (signal_layout.factor * channel.scale).abs()
        }
        ChannelSource::ModbusValue { .. } | ChannelSource::ModbusText { .. } => return None,
    };
    (range.is_finite() && range > 0.0).then_some(range)
}

impl Checker<'_> {
    pub(super) fn driveline(
        &mut self,
        key: &str,
        raw: &RawDriveline,
        facts: &ChannelFacts<'_>,
    ) -> Option<Driveline> {
        let name = self.name(&format!("{key}.name"), &raw.name);
        let torque = self.channel_ref(
            &format!("{key}.torque"),
            &raw.torque,
            facts,
            ChannelKind::Torque,
        );
        let metal_in_stand = optional(raw.metal_in_stand.as_ref().map(|channel| {
            self.channel_ref(
                &format!("{key}.metal_in_stand"),
                channel,
                facts,
                ChannelKind::ProcessValue,
            )
        }));
        let extra_channels = self.extra_channels(key, raw, facts, torque);
        let model = optional(
            raw.model
                .as_ref()
                .map(|model| self.existing_file(&format!("{key}.model"), model)),
        );
        let bite = self.bite(key, raw);
        let thresholds = self.thresholds(key, raw);
        let wear = self.wear(&format!("{key}.wear"), raw.wear.as_ref());
        if let (Some(_), Some(thresholds), Some(wear)) = (&raw.model, &thresholds, &wear) {
            // The maps end at max_gap_mrad: the likelihood is flat beyond, so neither
            // the alarm nor its forecast could be told there.
            if thresholds.gap_alarm_mrad >= wear.max_gap_mrad {
                self.report.push(
                    format!("{key}.thresholds.gap_alarm_mrad"),
                    format!(
                        "{} mrad is not allowed (must be < {key}.wear.max_gap_mrad = {} mrad: the gap maps end there)",
                        thresholds.gap_alarm_mrad, wear.max_gap_mrad
                    ),
                );
                return None;
            }
        }
        let fatigue = match (&raw.fatigue, torque, bite) {
            (None, ..) => Some(None),
            (Some(fatigue), Some(torque), Some(bite)) => {
                let channel = facts.channels[torque].as_ref();
                self.fatigue(&format!("{key}.fatigue"), fatigue, channel, &bite)
                    .map(Some)
            }
            // The torque channel or the bite settings are reported already.
            (Some(_), ..) => None,
        };
        let identification = self.identification(
            &format!("{key}.identification"),
            raw.identification.as_ref(),
        );
        let context = match &raw.context {
            Some(tags) => self.driveline_context(&format!("{key}.context"), tags, facts),
            None => Some(ContextTags::default()),
        };
        let pool_speed_range_mpm = self.pool_speed_range(key, raw);
        Some(Driveline {
            context: context?,
            pool_speed_range_mpm: pool_speed_range_mpm?,
            name: name?,
            torque: torque?,
            metal_in_stand: metal_in_stand?,
            extra_channels: extra_channels?,
            model: model?,
            bite: bite?,
            thresholds: thresholds?,
            wear: wear?,
            fatigue: fatigue?,
            identification: identification?,
        })
    }

    /// The context tags of the driveline at `key` (`drivelines[0].context`): the
    /// tandem mill's tags but the weld bit (no detector of a driveline holds off at
    /// a weld).
    fn driveline_context(
        &mut self,
        key: &str,
        raw: &RawContextTags,
        facts: &ChannelFacts<'_>,
    ) -> Option<ContextTags> {
        let tags = self.context_tags(key, raw, facts);
        let weld_key = if raw.weld.is_some() {
            Some("weld")
        } else {
            raw.weld_stands.as_ref().map(|_| "weld_stands")
        };
        if let Some(weld_key) = weld_key {
            self.report.push(
                format!("{key}.{weld_key}"),
                "is not allowed on a driveline (the weld bit holds a tandem mill's chatter \
                 alarm off; a driveline's bites are gated by state and speed)",
            );
            return None;
        }
        tags
    }

    /// `drivelines[i].pool_speed_range_mpm`: `[low, high]` m/min with `0 <= low <
    /// high`, and a `speed_mpm` context tag to compare with.
    fn pool_speed_range(&mut self, key: &str, raw: &RawDriveline) -> Option<Option<(f64, f64)>> {
        let Some(values) = &raw.pool_speed_range_mpm else {
            return Some(None);
        };
        let range_key = format!("{key}.pool_speed_range_mpm");
        let range = match values.as_slice() {
            [low, high] if low.is_finite() && high.is_finite() && *low >= 0.0 && low < high => {
                (*low, *high)
            }
            _ => {
                self.report.push(
                    range_key,
                    format!(
                        "{values:?} is not allowed (must be [low, high] in m/min with 0 <= low < high)"
                    ),
                );
                return None;
            }
        };
        if raw
            .context
            .as_ref()
            .is_none_or(|tags| tags.speed_mpm.is_none())
        {
            self.report.push(
                range_key,
                format!(
                    "needs the speed tag (`{key}.context = {{ speed_mpm = \"<process value>\" }}`): \
                     the range is checked against what it reads"
                ),
            );
            return None;
        }
        Some(Some(range))
    }

    /// `drivelines[i].bite`: the rise that marks a bite and the capture around it.
    fn bite(&mut self, key: &str, raw: &RawDriveline) -> Option<BiteSettings> {
        let bite_key = format!("{key}.bite");
        let threshold_knm = self.float(
            &format!("{bite_key}.threshold_knm"),
            raw.bite.threshold_knm,
            raw.bite.threshold_knm > 0.0,
            "> 0 kN*m",
        );
        let pre_trigger_s = raw.bite.pre_trigger_s.unwrap_or(DEFAULT_PRE_TRIGGER_S);
        let pre_trigger_s = self.float(
            &format!("{bite_key}.pre_trigger_s"),
            pre_trigger_s,
            (0.0..=MAX_WINDOW_S).contains(&pre_trigger_s),
            &format!("0..={MAX_WINDOW_S} s"),
        );
        let post_trigger_s = raw.bite.post_trigger_s.unwrap_or(DEFAULT_POST_TRIGGER_S);
        let post_trigger_s = self.float(
            &format!("{bite_key}.post_trigger_s"),
            post_trigger_s,
            post_trigger_s > 0.0 && post_trigger_s <= MAX_WINDOW_S,
            &format!("> 0 and <= {MAX_WINDOW_S} s"),
        );
        Some(BiteSettings {
            threshold_knm: threshold_knm?,
            pre_trigger_s: pre_trigger_s?,
            post_trigger_s: post_trigger_s?,
        })
    }

    /// `drivelines[i].thresholds`: TAF and gap warning and alarm levels, each alarm at
    /// least its warning.
    fn thresholds(&mut self, key: &str, raw: &RawDriveline) -> Option<DrivelineThresholds> {
        let thresholds_key = format!("{key}.thresholds");
        let taf_warning = raw.thresholds.taf_warning;
        let taf_warning = self.float(
            &format!("{thresholds_key}.taf_warning"),
            taf_warning,
            taf_warning > 1.0,
            "> 1: TAF is peak over static torque",
        );
        let taf_alarm = raw.thresholds.taf_alarm;
        let taf_alarm = self.float(
            &format!("{thresholds_key}.taf_alarm"),
            taf_alarm,
            taf_warning.is_none_or(|warning| taf_alarm >= warning),
            &format!(">= taf_warning = {}", raw.thresholds.taf_warning),
        );
        let gap_warning = raw
            .thresholds
            .gap_warning_mrad
            .unwrap_or(DEFAULT_GAP_WARNING_MRAD);
        let gap_warning = self.float(
            &format!("{thresholds_key}.gap_warning_mrad"),
            gap_warning,
            gap_warning > 0.0,
            "> 0 mrad",
        );
        let gap_alarm = raw
            .thresholds
            .gap_alarm_mrad
            .unwrap_or(DEFAULT_GAP_ALARM_MRAD.max(gap_warning.unwrap_or(0.0)));
        let gap_alarm = self.float(
            &format!("{thresholds_key}.gap_alarm_mrad"),
            gap_alarm,
            gap_warning.is_none_or(|warning| gap_alarm >= warning),
            &format!(
                ">= gap_warning_mrad = {} mrad",
                gap_warning.unwrap_or(DEFAULT_GAP_WARNING_MRAD)
            ),
        );
        Some(DrivelineThresholds {
            taf_warning: taf_warning?,
            taf_alarm: taf_alarm?,
            gap_warning_mrad: gap_warning?,
            gap_alarm_mrad: gap_alarm?,
        })
    }

    /// `drivelines[i].extra_channels`: each a known sampled channel (a Modbus block or
    /// CAN signal, any kind) other than the torque channel, named once, at the torque
    /// channel's sample rate (a capture's rows are the torque's samples).
    fn extra_channels(
        &mut self,
        key: &str,
        raw: &RawDriveline,
        facts: &ChannelFacts<'_>,
        torque: Option<usize>,
    ) -> Option<Vec<usize>> {
        let mut indices = Vec::new();
        let mut valid = true;
        for (position, name) in raw.extra_channels.iter().flatten().enumerate() {
            let entry = format!("{key}.extra_channels[{position}]");
            let Some(index) = facts.names.iter().position(|known| known == name) else {
                self.report.push(
                    &entry,
                    format!(
                        "unknown channel \"{name}\" ({})",
                        super::known_list(&facts.names)
                    ),
                );
                valid = false;
                continue;
            };
            if Some(index) == torque || *name == raw.torque {
                self.report.push(
                    &entry,
                    format!("\"{name}\" is the driveline's torque channel, captured already"),
                );
                valid = false;
                continue;
            }
            if let Some(first) = raw.extra_channels.iter().flatten().position(|n| n == name) {
                if first < position {
                    self.report.push(
                        &entry,
                        format!("\"{name}\" is named already at extra_channels[{first}]"),
                    );
                    valid = false;
                    continue;
                }
            }
            // A channel that failed validation has been reported already.
            let Some(channel) = facts.channels[index].as_ref() else {
                valid = false;
                continue;
            };
            if matches!(channel.source, ChannelSource::ModbusValue { .. }) {
                self.report.push(
                    &entry,
                    format!(
                        "channel \"{name}\" is a register value (one value per poll): name a \
                         Modbus block or CAN channel"
                    ),
                );
                valid = false;
                continue;
            }
            let torque_rate = torque
                .and_then(|torque| facts.channels[torque].as_ref())
                .map(|torque| torque.sample_rate_hz);
            if let Some(rate) = torque_rate.filter(|&rate| rate != channel.sample_rate_hz) {
                self.report.push(
                    &entry,
                    format!(
                        "channel \"{name}\" samples at {} Hz, the torque channel at {rate} Hz \
                         (extra channels must share the torque's sample rate)",
                        channel.sample_rate_hz
                    ),
                );
                valid = false;
                continue;
            }
            indices.push(index);
        }
        valid.then_some(indices)
    }

    /// `drivelines[i].wear`, every key optional.
    fn wear(&mut self, key: &str, raw: Option<&RawWear>) -> Option<WearSettings> {
        let defaults = WearSettings::default();
        let empty = RawWear {
            couplings: None,
            max_gap_mrad: None,
            gap_step_mrad: None,
            static_torque_knm: None,
            torque_points: None,
            pool_bites: None,
            horizon_days: None,
            growth_span_s: None,
        };
        let raw = raw.unwrap_or(&empty);
        let couplings = match &raw.couplings {
            None => Some(None),
            Some(list) => self
                .coupling_list(&format!("{key}.couplings"), list)
                .map(Some),
        };
        let max_gap = raw.max_gap_mrad.unwrap_or(defaults.max_gap_mrad);
        let max_gap = self.float(
            &format!("{key}.max_gap_mrad"),
            max_gap,
            max_gap > 0.0 && max_gap <= MAX_MAX_GAP_MRAD,
            &format!("> 0 and <= {MAX_MAX_GAP_MRAD} mrad"),
        );
        let step = raw.gap_step_mrad.unwrap_or(defaults.gap_step_mrad);
        let step = self.float(
            &format!("{key}.gap_step_mrad"),
            step,
            step > 0.0 && max_gap.is_none_or(|max| max / step <= MAX_GAP_STEPS && step <= max),
            &format!("> 0 mrad, at most max_gap_mrad, and at least max_gap_mrad / {MAX_GAP_STEPS}"),
        );
        let range = match &raw.static_torque_knm {
            None => Some(None),
            Some(values) => match values.as_slice() {
                [low, high] if low.is_finite() && high.is_finite() && *low > 0.0 && low < high => {
                    Some(Some((*low, *high)))
                }
                _ => {
                    self.report.push(
                        format!("{key}.static_torque_knm"),
                        format!(
                            "{values:?} is not allowed (must be [low, high] in kN*m with 0 < low < high)"
                        ),
                    );
                    None
                }
            },
        };
        let points = self.int_in(
            &format!("{key}.torque_points"),
            raw.torque_points.unwrap_or(defaults.torque_points as i64),
            3..=64,
            "",
        );
        // Deprecated, without effect: checked as before so a configuration that loaded
        // still loads, and a wrong value is still named.
        let pool = match raw.pool_bites {
            Some(bites) => self.int_in(&format!("{key}.pool_bites"), bites, 1..=1000, " bites"),
            None => Some(0),
        };
        let horizon = raw.horizon_days.unwrap_or(defaults.horizon_days);
        let horizon = self.float(
            &format!("{key}.horizon_days"),
            horizon,
            (1.0..=MAX_HORIZON_DAYS).contains(&horizon),
            &format!(">= 1 and <= {MAX_HORIZON_DAYS} days"),
        );
        let span = raw.growth_span_s.unwrap_or(defaults.growth_span_s);
        let span = self.float(
            &format!("{key}.growth_span_s"),
            span,
            (0.0..=MAX_GROWTH_SPAN_S).contains(&span),
            &format!(">= 0 and <= {MAX_GROWTH_SPAN_S} s (30 days)"),
        );
        Some(WearSettings {
            couplings: couplings?,
            max_gap_mrad: max_gap?,
            gap_step_mrad: step?,
            static_torque_knm: range?,
            torque_points: usize::try_from(points?).ok()?,
            horizon_days: pool.and(horizon)?,
            growth_span_s: span?,
        })
    }

    /// `drivelines[i].fatigue`: the gate (below the torque channel's range), the life
    /// limit and at least one component with distinct names.
    fn fatigue(
        &mut self,
        key: &str,
        raw: &RawFatigue,
        channel: Option<&Channel>,
        bite: &BiteSettings,
    ) -> Option<FatigueSettings> {
        let range_knm = channel.and_then(channel_range);
        let default_gate = range_knm
            .map_or(DEFAULT_GATE_OF_THRESHOLD * bite.threshold_knm, |range| {
                DEFAULT_GATE_OF_RANGE * range
            });
        let gate = raw.gate_knm.unwrap_or(default_gate);
        let gate = match range_knm {
            Some(range) => self.float(
                &format!("{key}.gate_knm"),
                gate,
                gate >= 0.0 && gate < range,
                &format!(">= 0 and below the torque channel's range, {range} kN*m"),
            ),
            None => self.float(&format!("{key}.gate_knm"), gate, gate >= 0.0, ">= 0 kN*m"),
        };
        let limit = raw.life_limit.unwrap_or(DEFAULT_LIFE_LIMIT);
        let limit = self.float(
            &format!("{key}.life_limit"),
            limit,
            limit > 0.0 && limit <= 1.0,
            "in (0, 1], a fraction of the life",
        );
        if raw.components.is_empty() {
            self.report.push(
                format!("{key}.components"),
                "no component (a ledger needs at least one [[...components]])",
            );
            return None;
        }
        let mut components = Vec::with_capacity(raw.components.len());
        let mut valid = true;
        for (index, component) in raw.components.iter().enumerate() {
            let key = format!("{key}.components[{index}]");
            if raw.components[..index]
                .iter()
                .any(|c| c.name == component.name)
            {
                self.report.push(
                    format!("{key}.name"),
                    format!("\"{}\" is used twice in this driveline", component.name),
                );
                valid = false;
            }
            match self.component(&key, component) {
                Some(component) => components.push(component),
                None => valid = false,
            }
        }
        Some(FatigueSettings {
            gate_knm: gate?,
            life_limit: limit?,
            components: valid.then_some(components)?,
        })
    }

    /// One component's S-N curve; an error names its key and the allowed range.
    fn component(&mut self, key: &str, raw: &RawFatigueComponent) -> Option<FatigueComponent> {
        let name = self.name(&format!("{key}.name"), &raw.name);
        let rule = match raw.endurance_rule.as_deref() {
            None => Some(EnduranceRule::Cutoff),
            Some(text) => self.choice(
                &format!("{key}.endurance_rule"),
                "endurance rule",
                text,
                &[EnduranceRule::Cutoff, EnduranceRule::Haibach],
                |rule| match rule {
                    EnduranceRule::Cutoff => "cutoff",
                    EnduranceRule::Haibach => "haibach",
                },
            ),
        };
        let settings = SnCurveSettings {
            m: raw.m,
            ref_cycles: raw.ref_cycles,
            ref_range_knm: raw.ref_range_knm,
            torque_share: raw.torque_share.unwrap_or(1.0),
            endurance_knm: raw.endurance_knm,
            endurance_rule: rule?,
            mean_correction: raw
                .ultimate_knm
                .map_or(MeanCorrection::None, |ultimate_knm| {
                    MeanCorrection::Goodman { ultimate_knm }
                }),
        };
        let curve = match SnCurve::new(settings) {
            Ok(curve) => Some(curve),
            Err(error) => {
                let (field, value) = match error {
                    SnCurveError::M => ("m", raw.m),
                    SnCurveError::RefCycles => ("ref_cycles", raw.ref_cycles),
                    SnCurveError::RefRangeKnm => ("ref_range_knm", raw.ref_range_knm),
                    SnCurveError::TorqueShare => ("torque_share", settings.torque_share),
                    SnCurveError::EnduranceKnm => {
                        ("endurance_knm", raw.endurance_knm.unwrap_or_default())
                    }
                    SnCurveError::UltimateKnm => {
                        ("ultimate_knm", raw.ultimate_knm.unwrap_or_default())
                    }
                };
                self.report.push(
                    format!("{key}.{field}"),
                    format!("{value} is not allowed ({error})"),
                );
                None
            }
        };
        Some(FatigueComponent {
            name: name?,
            curve: curve?,
        })
    }

    /// A non-empty list of distinct coupling indices (>= 0); whether the model has
    /// them is checked where the model is loaded.
    fn coupling_list(&mut self, key: &str, list: &[i64]) -> Option<Vec<usize>> {
        let mut couplings = Vec::with_capacity(list.len());
        for (index, &coupling) in list.iter().enumerate() {
            match usize::try_from(coupling) {
                Ok(value) if !couplings.contains(&value) => couplings.push(value),
                Ok(_) => {
                    self.report.push(
                        format!("{key}[{index}]"),
                        format!("{coupling} is listed twice"),
                    );
                    return None;
                }
                Err(_) => {
                    self.report.push(
                        format!("{key}[{index}]"),
                        format!(
                            "{coupling} is not allowed (must be a coupling index of the model, >= 0)"
                        ),
                    );
                    return None;
                }
            }
        }
        if couplings.is_empty() {
            self.report.push(
                key,
                "must name at least one coupling (leave the key out for all of them)",
            );
            return None;
        }
        Some(couplings)
    }
}
