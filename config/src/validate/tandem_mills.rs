//! `[[tandem_mills]]`: the stands' vibration channels, the chatter band, window and
//! correlation threshold.

use crate::raw::{RawContextTags, RawProductGroup, RawTandemMill};
use crate::{Channel, ChannelKind, ChatterDetectorKind, ContextTags, ProductGroup, TandemMill};

use super::{ChannelFacts, Checker, Purpose, MAX_WINDOW_S, STANDS_RANGE};

/// Default gain window, s: the variant that won the race (`tests/src/experiments/chatter_eval/`).
const DEFAULT_GAIN_WINDOW_S: f64 = 2.0;
/// Default release level of the slow-down request, fraction of the alarm level.
const DEFAULT_SLOW_DOWN_RELEASE: f64 = 0.8;
/// Default time below the release level before the slow-down request clears, s.
const DEFAULT_SLOW_DOWN_HOLD_S: f64 = 5.0;
/// Default settle time of the weld hold, s: on the tandem model the gain ratio was last
/// at the alarm level up to 8.6 s after the weld had left in 19 of 20 welds (one 13.0 s;
/// `docs/chatter.md`, "Welds").
const DEFAULT_WELD_SETTLE_S: f64 = 10.0;
/// Longest settle time of the weld hold, s.
const MAX_WELD_SETTLE_S: f64 = 60.0;
/// Default factor on the alarm level during the weld hold: above every weld transient's
/// peak gain ratio on the tandem model (1.83; `docs/chatter.md`, "Welds").
const DEFAULT_WELD_ALARM_FACTOR: f64 = 2.0;
/// Largest factor on the alarm level during the weld hold.
const MAX_WELD_ALARM_FACTOR: f64 = 10.0;
/// Longest slow-down hold, s.
const MAX_SLOW_DOWN_HOLD_S: f64 = 600.0;
/// Default stand samples kept before a chatter warning, s.
const DEFAULT_CAPTURE_BEFORE_S: f64 = 5.0;
/// Default stand samples kept after a chatter warning clears, s.
const DEFAULT_CAPTURE_AFTER_S: f64 = 2.0;
/// Longest time kept before or after an episode, s.
const MAX_CAPTURE_AROUND_S: f64 = 60.0;
/// Default longest chatter-episode capture, s.
const DEFAULT_CAPTURE_MAX_S: f64 = 120.0;
/// Largest `capture_max_s`, s (10 minutes of 8 stands at 10 kHz is 384 MB of `f64`:
/// the bound on what one episode may hold in memory).
const MAX_CAPTURE_MAX_S: f64 = 600.0;

/// The band-gain and slow-down keys of one mill, each `None` when reported.
struct GainKeys {
    detector: Option<ChatterDetectorKind>,
    reference_band_hz: Option<(f64, f64)>,
    gain_window_s: Option<f64>,
    gain_thresholds: Option<Vec<f64>>,
    slow_down_release: Option<f64>,
    slow_down_hold_s: Option<f64>,
    weld_settle_s: Option<f64>,
    weld_alarm_factor: Option<f64>,
}

impl Checker<'_> {
    pub(super) fn tandem_mill(
        &mut self,
        key: &str,
        raw: &RawTandemMill,
        facts: &ChannelFacts<'_>,
    ) -> Option<TandemMill> {
        let name = self.name(&format!("{key}.name"), &raw.name);
        let (stands, stands_ok) = self.stand_channels(key, raw, facts);
        let first = stands
            .iter()
            .filter_map(|&index| facts.channels[index].as_ref())
            .next();
        let band = self.chatter_band(key, raw, first);
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
        let sample_rate_hz = first.map(|c| c.sample_rate_hz);
        // The gain's keys are checked against a chatter band and stand list that passed
        // (so one mistake is reported once).
        let checked_band =
            band.filter(|&(_, high)| sample_rate_hz.is_none_or(|fs| high < fs / 2.0));
        let gain = self.band_gain_keys(
            key,
            raw,
            checked_band,
            sample_rate_hz,
            stands_ok.then_some(stands.len()),
        );
        let (capture_before_s, capture_after_s, capture_max_s) = self.capture_keys(key, raw);
        let context = match &raw.context {
            Some(tags) => self.context_tags(&format!("{key}.context"), tags, facts),
            None => Some(ContextTags::default()),
        };
        let context = context
            .filter(|tags| self.weld_stand_count(key, tags, stands_ok.then_some(stands.len())));
        let product_groups = self.product_groups(
            key,
            raw,
            gain.detector,
            stands_ok.then_some(stands.len()),
            context.as_ref(),
        );
        let identification = self.identification(
            &format!("{key}.identification"),
            raw.identification.as_ref(),
        );
        Some(TandemMill {
            name: name?,
            stands: stands_ok.then_some(stands)?,
            chatter_band_hz: band?,
            window_s: window_s?,
            k_max: k_max?,
            detector: gain.detector?,
            reference_band_hz: gain.reference_band_hz?,
            gain_window_s: gain.gain_window_s?,
            gain_thresholds: gain.gain_thresholds?,
            product_groups: product_groups?,
            slow_down_release: gain.slow_down_release?,
            slow_down_hold_s: gain.slow_down_hold_s?,
            weld_settle_s: gain.weld_settle_s?,
            weld_alarm_factor: gain.weld_alarm_factor?,
            context: context?,
            capture_before_s: capture_before_s?,
            capture_after_s: capture_after_s?,
            capture_max_s: capture_max_s?,
            identification: identification?,
        })
    }

    /// The mill's stand channels (indices of those that resolve) and whether the list
    /// passed: a count in range, no channel twice, every one an acceleration channel,
    /// one sample rate for all (one chatter window spans all stands sample for
    /// sample).
    fn stand_channels(
        &mut self,
        key: &str,
        raw: &RawTandemMill,
        facts: &ChannelFacts<'_>,
    ) -> (Vec<usize>, bool) {
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
        (stands, stands_ok)
    }

    /// `chatter_band_hz` of the mill at `key`: `[low, high]`, 0 < low < high, the
    /// upper edge below half the sample rate of `first`, its first stand channel.
    fn chatter_band(
        &mut self,
        key: &str,
        raw: &RawTandemMill,
        first: Option<&Channel>,
    ) -> Option<(f64, f64)> {
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
        if let Some(((_, high), channel)) = band.zip(first) {
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
        band
    }

    /// The context tags at `key` (`tandem_mills[0].context`): each a process-value
    /// channel, no channel for two tags; `products` whole numbers 0..=u32::MAX, each
    /// once.
    pub(super) fn context_tags(
        &mut self,
        key: &str,
        raw: &RawContextTags,
        facts: &ChannelFacts<'_>,
    ) -> Option<ContextTags> {
        let mut ok = true;
        let mut seen: Vec<(String, String)> = Vec::new();
        let mut tag = |checker: &mut Self, name: &str, channel: &Option<String>| {
            let channel = channel.as_deref()?;
            let tag_key = format!("{key}.{name}");
            if let Some((other, _)) = seen.iter().find(|(_, c)| *c == channel) {
                checker.report.push(
                    &tag_key,
                    format!(
                        "channel \"{channel}\" is already the {other} tag (each tag needs its \
                         own process value)"
                    ),
                );
                ok = false;
                return None;
            }
            seen.push((name.to_owned(), channel.to_owned()));
            let index = checker.channel_ref(&tag_key, channel, facts, ChannelKind::ProcessValue);
            ok &= index.is_some();
            index
        };
        let weld = tag(self, "weld", &raw.weld);
        let mut weld_stands = Vec::new();
        let both_welds = raw.weld.is_some() && raw.weld_stands.is_some();
        if both_welds {
            self.report.push(
                format!("{key}.weld_stands"),
                "is not allowed with `weld` (give the mill's weld bit or one per stand, not \
                 both)",
            );
        }
        let no_stands = raw.weld_stands.as_ref().is_some_and(Vec::is_empty);
        if no_stands {
            self.report.push(
                format!("{key}.weld_stands"),
                "[] is not allowed (must be one weld bit per stand, in the order of `stands`)",
            );
        }
        for (stand, channel) in raw.weld_stands.iter().flatten().enumerate() {
            let name = format!("weld_stands[{stand}]");
            // A channel that fails is reported (and fails the tags) by `tag`.
            weld_stands.extend(tag(self, &name, &Some(channel.clone())));
        }
        let tags = ContextTags {
            weld,
            weld_stands,
            speed_mpm: tag(self, "speed_mpm", &raw.speed_mpm),
            coil: tag(self, "coil", &raw.coil),
            product: tag(self, "product", &raw.product),
            thickness_mm: tag(self, "thickness_mm", &raw.thickness_mm),
            pass: tag(self, "pass", &raw.pass),
            state: tag(self, "state", &raw.state),
            products: Vec::new(),
        };
        let mut products = Vec::new();
        for (position, &code) in raw.products.iter().flatten().enumerate() {
            let product_key = format!("{key}.products[{position}]");
            match u32::try_from(code) {
                Ok(code) if products.contains(&code) => {
                    self.report
                        .push(product_key, format!("product {code} is listed twice"));
                    ok = false;
                }
                Ok(code) => products.push(code),
                Err(_) => {
                    self.report.push(
                        product_key,
                        format!("{code} is not allowed (must be a product code 0..=4294967295)"),
                    );
                    ok = false;
                }
            }
        }
        if !products.is_empty() && tags.product.is_none() && raw.product.is_none() {
            self.report.push(
                format!("{key}.products"),
                "needs the product tag (`product = \"<process value>\"`): the codes are checked \
                 against what it reads",
            );
            ok = false;
        }
        (ok && !both_welds && !no_stands).then_some(ContextTags { products, ..tags })
    }

    /// Whether the mill at `key` with `stands` stands (`None`: its list failed) has
    /// one weld bit per stand in `tags.weld_stands` (or none).
    fn weld_stand_count(&mut self, key: &str, tags: &ContextTags, stands: Option<usize>) -> bool {
        match stands {
            Some(stands) if !tags.weld_stands.is_empty() && tags.weld_stands.len() != stands => {
                self.report.push(
                    format!("{key}.context.weld_stands"),
                    format!(
                        "{} channels are not allowed (must be one weld bit per stand: {stands}, \
                         in the order of `stands`)",
                        tags.weld_stands.len()
                    ),
                );
                false
            }
            _ => true,
        }
    }

    /// `capture_before_s`, `capture_after_s` and `capture_max_s` of the mill at `key`.
    fn capture_keys(
        &mut self,
        key: &str,
        raw: &RawTandemMill,
    ) -> (Option<f64>, Option<f64>, Option<f64>) {
        let around = |checker: &mut Self, name: &str, value: Option<f64>, default: f64| {
            let value = value.unwrap_or(default);
            checker.float(
                &format!("{key}.{name}"),
                value,
                (0.0..=MAX_CAPTURE_AROUND_S).contains(&value),
                &format!(">= 0 and <= {MAX_CAPTURE_AROUND_S} s"),
            )
        };
        let before = around(
            self,
            "capture_before_s",
            raw.capture_before_s,
            DEFAULT_CAPTURE_BEFORE_S,
        );
        let after = around(
            self,
            "capture_after_s",
            raw.capture_after_s,
            DEFAULT_CAPTURE_AFTER_S,
        );
        let max = raw.capture_max_s.unwrap_or(DEFAULT_CAPTURE_MAX_S);
        let floor = before.unwrap_or(0.0);
        let max = self.float(
            &format!("{key}.capture_max_s"),
            max,
            max > floor && max <= MAX_CAPTURE_MAX_S,
            &format!("> capture_before_s ({floor} s) and <= {MAX_CAPTURE_MAX_S} s"),
        );
        (before, after, max)
    }

    /// `detector`, `reference_band_hz`, `gain_window_s`, `gain_thresholds`,
    /// `slow_down_release`, `slow_down_hold_s`, `weld_settle_s` and
    /// `weld_alarm_factor` of the mill at `key`; `band` is its
    /// checked chatter band, `sample_rate_hz` its stands' rate and `stands` their
    /// number, when known.
    fn band_gain_keys(
        &mut self,
        key: &str,
        raw: &RawTandemMill,
        band: Option<(f64, f64)>,
        sample_rate_hz: Option<f64>,
        stands: Option<usize>,
    ) -> GainKeys {
        let detector = self.detector(key, raw);
        let reference_band_hz = self.reference_band(key, raw, band, sample_rate_hz);
        let gain_window = raw.gain_window_s.unwrap_or(DEFAULT_GAIN_WINDOW_S);
        let gain_window_s = self.float(
            &format!("{key}.gain_window_s"),
            gain_window,
            gain_window > 0.0 && gain_window <= MAX_WINDOW_S,
            &format!("> 0 and <= {MAX_WINDOW_S} s"),
        );
        let gain_thresholds = self.gain_thresholds(key, raw, detector, stands);
        let release = raw.slow_down_release.unwrap_or(DEFAULT_SLOW_DOWN_RELEASE);
        let slow_down_release = self.float(
            &format!("{key}.slow_down_release"),
            release,
            release > 0.0 && release < 1.0,
            "> 0 and < 1, a fraction of the alarm level",
        );
        let hold = raw.slow_down_hold_s.unwrap_or(DEFAULT_SLOW_DOWN_HOLD_S);
        let slow_down_hold_s = self.float(
            &format!("{key}.slow_down_hold_s"),
            hold,
            (0.0..=MAX_SLOW_DOWN_HOLD_S).contains(&hold),
            &format!(">= 0 and <= {MAX_SLOW_DOWN_HOLD_S} s"),
        );
        let settle = raw.weld_settle_s.unwrap_or(DEFAULT_WELD_SETTLE_S);
        let weld_settle_s = self.float(
            &format!("{key}.weld_settle_s"),
            settle,
            (0.0..=MAX_WELD_SETTLE_S).contains(&settle),
            &format!(">= 0 and <= {MAX_WELD_SETTLE_S} s"),
        );
        let factor = raw.weld_alarm_factor.unwrap_or(DEFAULT_WELD_ALARM_FACTOR);
        let weld_alarm_factor = self.float(
            &format!("{key}.weld_alarm_factor"),
            factor,
            (1.0..=MAX_WELD_ALARM_FACTOR).contains(&factor),
            &format!(
                ">= 1 and <= {MAX_WELD_ALARM_FACTOR}, a factor on the alarm level (1: no weld \
                 hold)"
            ),
        );
        GainKeys {
            detector,
            reference_band_hz,
            gain_window_s,
            gain_thresholds,
            slow_down_release,
            slow_down_hold_s,
            weld_settle_s,
            weld_alarm_factor,
        }
    }

    /// `detector` of the mill at `key`: `band_gain` (the default) or `paper`.
    fn detector(&mut self, key: &str, raw: &RawTandemMill) -> Option<ChatterDetectorKind> {
        match raw.detector.as_deref() {
            None | Some("band_gain") => Some(ChatterDetectorKind::BandGain),
            Some("paper") => Some(ChatterDetectorKind::Paper),
            Some(other) => {
                self.report.push(
                    format!("{key}.detector"),
                    format!("\"{other}\" is not allowed (must be \"band_gain\" or \"paper\")"),
                );
                None
            }
        }
    }

    /// `reference_band_hz` of the mill at `key` (default 1.5 to 3 times the upper edge
    /// of `band`, its checked chatter band): `[low, high]` above the chatter band and
    /// below half `sample_rate_hz`.
    fn reference_band(
        &mut self,
        key: &str,
        raw: &RawTandemMill,
        band: Option<(f64, f64)>,
        sample_rate_hz: Option<f64>,
    ) -> Option<(f64, f64)> {
        let reference_key = format!("{key}.reference_band_hz");
        let reference_band_hz = match (raw.reference_band_hz.as_deref(), band) {
            (None, Some((_, high))) => Some((1.5 * high, 3.0 * high)),
            (None, None) => None,
            (Some(&[low, high]), _)
                if low.is_finite() && high.is_finite() && 0.0 < low && low < high =>
            {
                Some((low, high))
            }
            (Some(other), _) => {
                self.report.push(
                    &reference_key,
                    format!(
                        "{other:?} is not allowed (must be [low, high] with 0 < low < high, Hz)"
                    ),
                );
                None
            }
        };
        reference_band_hz.filter(|&(low, high)| {
            if let Some((_, chatter_high)) = band.filter(|&(_, chatter_high)| low < chatter_high) {
                self.report.push(
                    &reference_key,
                    format!(
                        "lower edge {low} Hz is not allowed (must be >= {chatter_high} Hz, the \
                         chatter band's upper edge: the reference band lies above it)"
                    ),
                );
                return false;
            }
            if let Some(nyquist_hz) = sample_rate_hz.map(|fs| fs / 2.0).filter(|&n| high >= n) {
                self.report.push(
                    &reference_key,
                    format!(
                        "upper edge {high} Hz is not allowed (must be < {nyquist_hz} Hz, half the \
                         stands' sample rate{})",
                        if raw.reference_band_hz.is_none() {
                            "; the default is 1.5 to 3 times the chatter band's upper edge, set \
                             the key"
                        } else {
                            ""
                        }
                    ),
                );
                return false;
            }
            true
        })
    }

    /// `gain_thresholds` of the mill at `key`: one per stand (`stands`, when known), each
    /// > 0; needed by the band-gain `detector` in service, empty when left out otherwise.
    fn gain_thresholds(
        &mut self,
        key: &str,
        raw: &RawTandemMill,
        detector: Option<ChatterDetectorKind>,
        stands: Option<usize>,
    ) -> Option<Vec<f64>> {
        self.stand_thresholds(
            &format!("{key}.gain_thresholds"),
            raw.gain_thresholds.as_deref(),
            detector,
            stands,
            raw.stands.len(),
        )
    }

    /// The per-stand thresholds at `thresholds_key` (`values`, as written): one per
    /// stand (`stands`, when known; `written_stands` the mill's list as written), each
    /// above 0; needed by the band-gain `detector` in service, empty when left out
    /// otherwise.
    fn stand_thresholds(
        &mut self,
        thresholds_key: &str,
        values: Option<&[f64]>,
        detector: Option<ChatterDetectorKind>,
        stands: Option<usize>,
        written_stands: usize,
    ) -> Option<Vec<f64>> {
        match (values, detector) {
            (None, Some(ChatterDetectorKind::BandGain)) if self.purpose == Purpose::Service => {
                self.report.push(
                    thresholds_key,
                    "missing (the band-gain detector, the default, needs one alarm threshold \
                     per stand, > 0, from stable rolling up to the highest allowed speed: \
                     `millgate chatter commission` computes them from stable recordings; or \
                     set detector = \"paper\")",
                );
                None
            }
            (None, _) => Some(Vec::new()),
            (Some(values), _) if stands.is_some_and(|n| n != values.len()) => {
                self.report.push(
                    thresholds_key,
                    format!(
                        "{} values is not allowed (must be one per stand: {written_stands})",
                        values.len(),
                    ),
                );
                None
            }
            (Some(values), _) => {
                let mut ok = true;
                for (position, &value) in values.iter().enumerate() {
                    ok &= self
                        .float(
                            &format!("{thresholds_key}[{position}]"),
                            value,
                            value > 0.0,
                            "> 0, a ratio of band RMS values",
                        )
                        .is_some();
                }
                ok.then(|| values.to_vec())
            }
        }
    }

    /// `product_groups` of the mill at `key`: each named (unique among the mill's
    /// groups), with at least one product code 0..=u32::MAX, no code in two groups (nor
    /// twice in one), each one of the context's `products` when that list is given,
    /// and its `gain_thresholds` as the mill's. Groups need the mill's `product`
    /// context tag (`context`, when it passed): they follow what it reads.
    fn product_groups(
        &mut self,
        key: &str,
        raw: &RawTandemMill,
        detector: Option<ChatterDetectorKind>,
        stands: Option<usize>,
        context: Option<&ContextTags>,
    ) -> Option<Vec<ProductGroup>> {
        let Some(raw_groups) = raw.product_groups.as_deref() else {
            return Some(Vec::new());
        };
        let list_key = format!("{key}.product_groups");
        let mut ok = true;
        if raw
            .context
            .as_ref()
            .is_none_or(|tags| tags.product.is_none())
        {
            self.report.push(
                &list_key,
                "needs the product tag (`context = { product = \"<process value>\" }`): the \
                 groups' thresholds follow the product the PLC reports",
            );
            ok = false;
        }
        // Where each product code was first seen: (group, position).
        let mut seen: Vec<(u32, usize)> = Vec::new();
        let mut group_index = 0;
        let groups = self.named_list(
            &list_key,
            "product group",
            raw_groups,
            |group| &group.name,
            |checker, group_key, group: &RawProductGroup| {
                let name = checker.name(&format!("{group_key}.name"), &group.name);
                let mut group_ok = true;
                if group.products.is_empty() {
                    checker.report.push(
                        format!("{group_key}.products"),
                        "must not be empty (at least one product code of the group)",
                    );
                    group_ok = false;
                }
                let mut products = Vec::with_capacity(group.products.len());
                let index = group_index;
                group_index += 1;
                for (position, &code) in group.products.iter().enumerate() {
                    let product_key = format!("{group_key}.products[{position}]");
                    let Ok(code) = u32::try_from(code) else {
                        checker.report.push(
                            product_key,
                            format!(
                                "{code} is not allowed (must be a product code 0..=4294967295)"
                            ),
                        );
                        group_ok = false;
                        continue;
                    };
                    if products.contains(&code) {
                        checker
                            .report
                            .push(product_key, format!("product {code} is listed twice"));
                        group_ok = false;
                        continue;
                    }
                    if let Some(&(_, other)) = seen.iter().find(|(c, _)| *c == code) {
                        checker.report.push(
                            product_key,
                            format!(
                                "product {code} is already in group \"{}\" (a product is in \
                                 one group at most)",
                                raw_groups[other].name
                            ),
                        );
                        group_ok = false;
                        continue;
                    }
                    if let Some(known) = context.map(|c| &c.products).filter(|p| !p.is_empty()) {
                        if !known.contains(&code) {
                            checker.report.push(
                                product_key,
                                format!(
                                    "product {code} is not one of the context's products \
                                     ({key}.context.products)"
                                ),
                            );
                            group_ok = false;
                            continue;
                        }
                    }
                    seen.push((code, index));
                    products.push(code);
                }
                let thresholds = checker.stand_thresholds(
                    &format!("{group_key}.gain_thresholds"),
                    group.gain_thresholds.as_deref(),
                    detector,
                    stands,
                    raw.stands.len(),
                );
                Some(ProductGroup {
                    name: name?,
                    products: group_ok.then_some(products)?,
                    gain_thresholds: thresholds?,
                })
            },
        );
        let groups: Option<Vec<ProductGroup>> = groups.into_iter().collect();
        ok.then_some(groups?)
    }
}
