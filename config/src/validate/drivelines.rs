//! `[[drivelines]]`: torque and trigger channels, bite capture, TAF thresholds and the
//! driveline model file.

use crate::raw::RawDriveline;
use crate::{BiteSettings, ChannelKind, Driveline, DrivelineThresholds};

use super::{
    optional, ChannelFacts, Checker, DEFAULT_POST_TRIGGER_S, DEFAULT_PRE_TRIGGER_S, MAX_WINDOW_S,
};

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
        let model = optional(
            raw.model
                .as_ref()
                .map(|model| self.existing_file(&format!("{key}.model"), model)),
        );
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
        Some(Driveline {
            name: name?,
            torque: torque?,
            metal_in_stand: metal_in_stand?,
            model: model?,
            bite: BiteSettings {
                threshold_knm: threshold_knm?,
                pre_trigger_s: pre_trigger_s?,
                post_trigger_s: post_trigger_s?,
            },
            thresholds: DrivelineThresholds {
                taf_warning: taf_warning?,
                taf_alarm: taf_alarm?,
            },
        })
    }
}
