//! `[[tandem_mills]]`: the stands' vibration channels, the chatter band, window and
//! correlation threshold.

use crate::raw::RawTandemMill;
use crate::{ChannelKind, TandemMill};

use super::{ChannelFacts, Checker, MAX_WINDOW_S, STANDS_RANGE};

impl Checker<'_> {
    pub(super) fn tandem_mill(
        &mut self,
        key: &str,
        raw: &RawTandemMill,
        facts: &ChannelFacts<'_>,
    ) -> Option<TandemMill> {
        let name = self.name(&format!("{key}.name"), &raw.name);
        let stands_key = format!("{key}.stands");
        let mut stands_ok = true;
        if !STANDS_RANGE.contains(&raw.stands.len()) {
            self.report.push(
                &stands_key,
                format!(
                    "{} stands is not allowed (must be {}..={} stand channels)",
                    raw.stands.len(),
                    STANDS_RANGE.start(),
                    STANDS_RANGE.end()
                ),
            );
            stands_ok = false;
        }
        let mut stands = Vec::with_capacity(raw.stands.len());
        for (position, stand) in raw.stands.iter().enumerate() {
            let stand_key = format!("{stands_key}[{position}]");
            if raw.stands[..position].contains(stand) {
                self.report
                    .push(stand_key, format!("channel \"{stand}\" is listed twice"));
                stands_ok = false;
                continue;
            }
            match self.channel_ref(&stand_key, stand, facts, ChannelKind::Acceleration) {
                Some(index) => stands.push(index),
                None => stands_ok = false,
            }
        }
        // One chatter window spans all stands sample for sample: one rate for all.
        let resolved = || {
            stands
                .iter()
                .filter_map(|&index| facts.channels[index].as_ref())
        };
        if let Some(first) = resolved().next() {
            if let Some(other) = resolved().find(|c| c.sample_rate_hz != first.sample_rate_hz) {
                self.report.push(
                    &stands_key,
                    format!(
                        "stand channels \"{}\" ({} Hz) and \"{}\" ({} Hz) sample at different \
                         rates (must share one: the stands are compared sample for sample)",
                        first.name, first.sample_rate_hz, other.name, other.sample_rate_hz
                    ),
                );
                stands_ok = false;
            }
        }
        let band_key = format!("{key}.chatter_band_hz");
        let band = match raw.chatter_band_hz[..] {
            [low, high] if low.is_finite() && high.is_finite() && 0.0 < low && low < high => {
                Some((low, high))
            }
            _ => {
                self.report.push(
                    &band_key,
                    format!(
                        "{:?} is not allowed (must be [low, high] with 0 < low < high, Hz)",
                        raw.chatter_band_hz
                    ),
                );
                None
            }
        };
        if let Some(((_, high), channel)) = band.zip(resolved().next()) {
            let nyquist_hz = channel.sample_rate_hz / 2.0;
            if high >= nyquist_hz {
                self.report.push(
                    &band_key,
                    format!(
                        "upper edge {high} Hz is not allowed (must be < {nyquist_hz} Hz, half \
                         the {} Hz sample rate of stand channel \"{}\")",
                        channel.sample_rate_hz, channel.name
                    ),
                );
            }
        }
        let window_s = self.float(
            &format!("{key}.window_s"),
            raw.window_s,
            raw.window_s > 0.0 && raw.window_s <= MAX_WINDOW_S,
            &format!("> 0 and <= {MAX_WINDOW_S} s"),
        );
        let k_max = self.float(
            &format!("{key}.k_max"),
            raw.k_max,
            raw.k_max > 0.0 && raw.k_max < 1.0,
            "> 0 and < 1, a correlation coefficient; typically 0.2..0.3",
        );
        Some(TandemMill {
            name: name?,
            stands: stands_ok.then_some(stands)?,
            chatter_band_hz: band?,
            window_s: window_s?,
            k_max: k_max?,
        })
    }
}
