//! `[[rod_mills]]`: the rod-mill and schedule files, the PLC process values that carry
//! the drive configuration, the pass, the finishing speed and the rod temperature, and
//! the flag thresholds. The mill file's content (its configurations, spans, modulus
//! table) is checked when the service is built, which also checks the configuration
//! names listed here against the mill's drive.

use std::ops::RangeInclusive;

use crate::raw::RawRodMill;
use crate::{ChannelKind, RodMill};

use super::{optional, ChannelFacts, Checker};

/// Near-tongue speed margin when none is given, m/s.
pub(crate) const DEFAULT_NEAR_TONGUE_M_S: f64 = 2.0;
/// Flag hysteresis when none is given, m/s.
pub(crate) const DEFAULT_HYSTERESIS_M_S: f64 = 0.5;
/// Rod temperature rounding step when none is given, deg C.
pub(crate) const DEFAULT_TEMPERATURE_STEP_C: f64 = 10.0;
/// Configuration names a rod mill may map PLC values to.
const CONFIGURATIONS_RANGE: RangeInclusive<usize> = 1..=64;

impl Checker<'_> {
    pub(super) fn rod_mill(
        &mut self,
        key: &str,
        raw: &RawRodMill,
        facts: &ChannelFacts<'_>,
    ) -> Option<RodMill> {
        let name = self.name(&format!("{key}.name"), &raw.name);
        let mill = self.existing_file(&format!("{key}.mill"), &raw.mill);
        let schedule = self.existing_file(&format!("{key}.schedule"), &raw.schedule);
        let process_value = |checker: &mut Self, field: &str, channel: &str| {
            checker.channel_ref(
                &format!("{key}.{field}"),
                channel,
                facts,
                ChannelKind::ProcessValue,
            )
        };
        let configuration = process_value(self, "configuration", &raw.configuration);
        let pass = process_value(self, "pass", &raw.pass);
        let finishing_speed = process_value(self, "finishing_speed", &raw.finishing_speed);
        let temperature = optional(
            raw.temperature
                .as_ref()
                .map(|channel| process_value(self, "temperature", channel)),
        );
        let configurations = self.configuration_names(key, &raw.configurations);
        let near_tongue_m_s = raw.near_tongue_m_s.unwrap_or(DEFAULT_NEAR_TONGUE_M_S);
        let near_tongue_m_s = self.float(
            &format!("{key}.near_tongue_m_s"),
            near_tongue_m_s,
            near_tongue_m_s > 0.0,
            "> 0 m/s",
        );
        let hysteresis_m_s = raw.hysteresis_m_s.unwrap_or(DEFAULT_HYSTERESIS_M_S);
        let hysteresis_m_s = self.float(
            &format!("{key}.hysteresis_m_s"),
            hysteresis_m_s,
            hysteresis_m_s >= 0.0,
            ">= 0 m/s",
        );
        let temperature_step_c = raw.temperature_step_c.unwrap_or(DEFAULT_TEMPERATURE_STEP_C);
        let temperature_step_c = self.float(
            &format!("{key}.temperature_step_c"),
            temperature_step_c,
            temperature_step_c > 0.0,
            "> 0 deg C",
        );
        let identification = self.identification(
            &format!("{key}.identification"),
            raw.identification.as_ref(),
        );
        Some(RodMill {
            name: name?,
            mill: mill?,
            schedule: schedule?,
            configuration: configuration?,
            configurations: configurations?,
            pass: pass?,
            finishing_speed: finishing_speed?,
            temperature: temperature?,
            near_tongue_m_s: near_tongue_m_s?,
            hysteresis_m_s: hysteresis_m_s?,
            temperature_step_c: temperature_step_c?,
            identification: identification?,
        })
    }

    /// `configurations`: 1..=64 distinct, non-empty names.
    fn configuration_names(&mut self, key: &str, names: &[String]) -> Option<Vec<String>> {
        let list_key = format!("{key}.configurations");
        if !CONFIGURATIONS_RANGE.contains(&names.len()) {
            self.report.push(
                list_key,
                format!(
                    "{} names is not allowed (must be {}..={} drive configuration names, \
                     the k-th is selected by PLC value k, from 0)",
                    names.len(),
                    CONFIGURATIONS_RANGE.start(),
                    CONFIGURATIONS_RANGE.end()
                ),
            );
            return None;
        }
        let mut valid = true;
        for (position, name) in names.iter().enumerate() {
            let item_key = format!("{list_key}[{position}]");
            if self.name(&item_key, name).is_none() {
                valid = false;
            } else if names[..position].contains(name) {
                self.report.push(
                    item_key,
                    format!("configuration \"{name}\" is listed twice"),
                );
                valid = false;
            }
        }
        valid.then(|| names.to_vec())
    }
}
