//! Commissioning a tandem mill: its chatter thresholds from recordings of its stable
//! rolling (what `millgate chatter commission` prints and the chatter experiments
//! calibrate with).
//!
//! Every recording goes through the service's own monitor ([`windows`], as
//! `millgate chatter` does); over every window whose gain window is full, each
//! stand's largest chatter-band gain, plus a margin (10 percent by default, the
//! tandem-model race's margin), rounded up to 0.001, is its threshold: the mill's
//! `gain_thresholds`. Beside it: how many windows and seconds the recordings gave, the
//! speeds they covered (when the recordings hold the mill's speed), the largest band
//! RMS per stand (the usual vibration alarm's figure, plus the margin) and, for
//! `detector = "paper"`, `k_max`: the largest K_mean seen, moved the margin of the way
//! to 1.
//!
//! **Release level.** The slow-down request clears once the gain ratio stayed below
//! `slow_down_release` for `slow_down_hold_s`: a release below where stable rolling sits
//! never clears it, and the mill is held slow (a stand whose gain hardly changes with
//! speed sits at 1 / (1 + margin) of its threshold and above; the closed loop on the
//! tandem model showed it). So commissioning also gives `slow_down_release`: the 99th
//! percentile of the stable windows' gain ratio plus [`RELEASE_ROOM`], at least
//! [`RELEASE_FLOOR`] (the configuration's default), and says when that comes above
//! [`RELEASE_CEILING`] (then the margin is too small for a release with room below the
//! alarm).
//!
//! Refused, with the recording and the reason: a recording too short for one gain
//! window; a recording that shows chatter: a stand whose gain rises above
//! [`CHATTER_FACTOR`] times its median over the recording. A stand above
//! [`NOTE_FACTOR`] times its median is noted with the time, for the engineer to look
//! at. Where the factors come from, on the tandem model (`sim::tandem`): stable rolling
//! at a constant speed up to 95% of the critical speed, with welds and tension steps,
//! stayed within 2.5 times the median; the end of an acceleration into 95% of the
//! critical speed raised the gain for a second or two, up to 3.9 times (at 0.5 m/s^2);
//! a ramp past the critical speed reached 14-28 times its median by the time chatter
//! had developed. The thresholds hold up to the highest speed recorded: record stable
//! rolling up to the highest allowed speed, accelerations to it included.

use millgate_config::Config;
use serde::Serialize;

use super::capture::ANCHOR_BLOCK;
use super::monitor::ChatterSetupError;
use super::offline::{windows, Recording, Window};
use crate::state::context::RawContext;

/// The margin when none is given, percent.
pub(crate) const DEFAULT_MARGIN_PERCENT: f64 = 10.0;
/// Largest allowed margin, percent.
pub(crate) const MAX_MARGIN_PERCENT: f64 = 200.0;
/// A stand's gain above this many times its median over a recording means the
/// recording shows chatter (see the module docs for where the factor comes from).
pub const CHATTER_FACTOR: f64 = 8.0;
/// A stand's gain above this many times its median is noted (an acceleration's
/// transient, or the start of chatter: see the module docs).
pub const NOTE_FACTOR: f64 = 3.0;
/// Lowest `slow_down_release` given: the configuration's default.
pub const RELEASE_FLOOR: f64 = 0.8;
/// Highest `slow_down_release` given (the alarm is at 1).
pub const RELEASE_CEILING: f64 = 0.95;
/// The release level's room above the stable windows' 99th percentile ratio.
pub const RELEASE_ROOM: f64 = 0.05;

/// Why recordings cannot commission the mill.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CommissionError {
    /// No recording.
    #[error("no recording given (--input STABLE.csv, once per recording)")]
    NoRecording,
    /// The margin is out of range.
    #[error("--margin: {0} is not allowed (must be >= 0 and <= {MAX_MARGIN_PERCENT} percent)")]
    Margin(f64),
    /// The mill's monitor cannot be built.
    #[error("{recording}")]
    Monitor {
        /// The recording it was built for.
        recording: String,
        /// Why.
        #[source]
        source: ChatterSetupError,
    },
    /// A recording gives no full gain window.
    #[error(
        "{recording}: {duration_s:.3} s is too short for the gain window: the first gain needs \
         {needed_s:.3} s of samples (the first {ANCHOR_BLOCK}-sample block, then gain_window_s = \
         {gain_window_s} s and a hop of {hop_s} s)"
    )]
    TooShort {
        /// The recording.
        recording: String,
        /// Its length, s.
        duration_s: f64,
        /// Length the first gain needs, s.
        needed_s: f64,
        /// The mill's gain window, s.
        gain_window_s: f64,
        /// The monitor's hop, s.
        hop_s: f64,
    },
    /// A recording shows chatter.
    #[error(
        "{recording}: shows chatter: the chatter-band gain of stand {stand} (`{channel}`) \
         reaches {largest:.3} at t = {largest_at_s:.2} s, {factor:.1} times its median \
         {median:.3} over the recording (stable rolling stays below {CHATTER_FACTOR} times); \
         it first passed {CHATTER_FACTOR} times at t = {first_at_s:.2} s: commission from \
         stable rolling only (cut the recording before then)"
    )]
    Chatter {
        /// The recording.
        recording: String,
        /// The stand, 1-based.
        stand: usize,
        /// The stand's channel.
        channel: String,
        /// Its largest gain.
        largest: f64,
        /// When, s (the recording's time).
        largest_at_s: f64,
        /// Its median gain over the recording.
        median: f64,
        /// Largest over median.
        factor: f64,
        /// When the gain first passed the factor, s.
        first_at_s: f64,
    },
    /// A recording's `product` column holds two products.
    #[error(
        "{recording}: the product column holds {first} and then {other} (line {line}): \
         commissioning by product takes one product per recording (split the recording at \
         the product change)"
    )]
    MixedProducts {
        /// The recording.
        recording: String,
        /// Its first product.
        first: u32,
        /// The other product.
        other: u32,
        /// The file's line (or the sample's number) where it first appears.
        line: usize,
    },
    /// `--min-group-recordings` is 0.
    #[error("--min-group-recordings: 0 is not allowed (must be >= 1 recording)")]
    MinGroupRecordings,
}

/// The speeds some windows covered, from a speed column of the recordings.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SpeedCoverage {
    /// The column.
    pub column: String,
    /// Lowest speed at a window's end.
    pub lowest: f64,
    /// Highest speed at a window's end.
    pub highest: f64,
}

/// One recording's part.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RecordingFigures {
    /// The recording.
    pub recording: String,
    /// Its length, s.
    pub duration_s: f64,
    /// Windows with a full gain window.
    pub windows: usize,
    /// Per stand, the largest gain over the median gain.
    pub largest_over_median: Vec<f64>,
    /// Per stand, when its largest gain was, s (the recording's time).
    pub largest_at_s: Vec<f64>,
    /// The speeds its windows covered.
    pub speeds: Option<SpeedCoverage>,
}

/// One stand's figures over every recording.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct StandFigures {
    /// The stand's channel.
    pub channel: String,
    /// Largest chatter-band gain.
    pub largest_gain: f64,
    /// Largest chatter-band RMS, channel unit.
    pub largest_band_rms: f64,
}

/// What commissioning found.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Commissioning {
    /// The tandem mill.
    pub mill: String,
    /// Margin over the largest stable figures, percent.
    pub margin_percent: f64,
    /// Per stand, the largest gain plus the margin, rounded up to 0.001: the
    /// `gain_thresholds` to paste.
    pub gain_thresholds: Vec<f64>,
    /// Per stand, the largest band RMS plus the margin, rounded up to 0.001 (what a
    /// band-RMS alarm would be set to).
    pub band_rms_thresholds: Vec<f64>,
    /// 99th percentile over the stable windows of the largest gain / threshold.
    pub stable_ratio_p99: f64,
    /// The release level of the slow-down request for these thresholds (see the
    /// module docs): `slow_down_release` to paste.
    pub slow_down_release: f64,
    /// Whether the release would have to be above [`RELEASE_CEILING`] (a margin too
    /// small).
    pub release_cramped: bool,
    /// The same release for a band-RMS alarm at `band_rms_thresholds`.
    pub band_rms_release: f64,
    /// Largest K_mean over every window.
    pub largest_k_mean: f64,
    /// For `detector = "paper"`: the largest K_mean moved the margin of the way to 1,
    /// rounded up to 0.001 (at most 0.999).
    pub k_max: f64,
    /// Per stand.
    pub stands: Vec<StandFigures>,
    /// Windows with a full gain window, over every recording.
    pub windows: usize,
    /// Seconds of recordings.
    pub duration_s: f64,
    /// The speeds every recording's windows covered.
    pub speeds: Option<SpeedCoverage>,
    /// Per recording.
    pub recordings: Vec<RecordingFigures>,
    /// By product group ([`commission_by_product`]; empty when no recording has a
    /// product): each group's thresholds, or why it has none. With groups,
    /// `slow_down_release` (and `stable_ratio_p99`, `release_cramped`) are those of the
    /// mill's and every commissioned group's thresholds together: the release is one
    /// key of the mill.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub product_groups: Vec<GroupCommissioning>,
    /// The recordings left out of the product groups because their context was not
    /// trusted (a capture's stale or invalid context: its product is not used); they
    /// count for the mill's thresholds only. Filled by the caller that knows the
    /// context (`millgate chatter commission --db`).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub not_pooled: Vec<NotPooled>,
}

/// A recording left out of the product groups: its context was not trusted.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct NotPooled {
    /// The recording.
    pub recording: String,
    /// Its context's status (`stale`, `invalid`).
    pub context_status: String,
    /// Why (the stale tags, the impossible value).
    pub context_note: Option<String>,
}

/// One product group's part of commissioning by product.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct GroupCommissioning {
    /// The group: its name in the mill's `product_groups`, or `product-CODE` for a
    /// product when the mill has none configured.
    pub name: String,
    /// Its product codes.
    pub products: Vec<u32>,
    /// Whether the group comes from the mill's configured `product_groups`.
    pub configured: bool,
    /// The recordings of its products.
    pub recordings: Vec<String>,
    /// Its windows with a full gain window.
    pub windows: usize,
    /// Fewest recordings for its own thresholds (`--min-group-recordings`).
    pub min_recordings: usize,
    /// Its thresholds (its largest stable gain per stand plus the margin, rounded up to
    /// 0.001); `None` when it had fewer than the minimum of recordings: its products
    /// then fall back to the mill's thresholds.
    pub gain_thresholds: Option<Vec<f64>>,
    /// The 99th percentile over its stable windows of the gain ratio against its
    /// thresholds (with thresholds).
    pub stable_ratio_p99: Option<f64>,
}

/// Commission mill `index` of `config` from stable `recordings` with `margin_percent`
/// (see the module docs); the recordings' stands are in the mill's order.
pub fn commission(
    config: &Config,
    index: usize,
    recordings: &[Recording],
    margin_percent: f64,
) -> Result<Commissioning, CommissionError> {
    if !(0.0..=MAX_MARGIN_PERCENT).contains(&margin_percent) {
        return Err(CommissionError::Margin(margin_percent));
    }
    if recordings.is_empty() {
        return Err(CommissionError::NoRecording);
    }
    let mut stable = Stable::new(config, index);
    let figures = recordings
        .iter()
        .map(|recording| stable.add(config, index, recording))
        .collect::<Result<Vec<_>, _>>()?;
    Ok(stable.commissioning(margin_percent, figures))
}

/// Fewest recordings of a product group for its own thresholds, when none is given.
pub const DEFAULT_MIN_GROUP_RECORDINGS: usize = 2;

/// As [`commission`], and the recordings grouped by product: each recording's product
/// is its `product` column's (one product per recording; rows with no valid code are
/// left out of the grouping, a recording without any is the mill's only). The groups
/// are the mill's configured `product_groups` (products in none only count for the
/// mill's thresholds), or without those one group per product (`product-CODE`). A
/// group with `min_group_recordings` recordings or more gets thresholds from its own
/// recordings as the mill's come from all of them; one with fewer is reported without
/// thresholds (its products fall back to the mill's). The mill's thresholds come from
/// every recording: the fallback for any product outside a group.
pub fn commission_by_product(
    config: &Config,
    index: usize,
    recordings: &[Recording],
    margin_percent: f64,
    min_group_recordings: usize,
) -> Result<Commissioning, CommissionError> {
    if !(0.0..=MAX_MARGIN_PERCENT).contains(&margin_percent) {
        return Err(CommissionError::Margin(margin_percent));
    }
    if recordings.is_empty() {
        return Err(CommissionError::NoRecording);
    }
    if min_group_recordings == 0 {
        return Err(CommissionError::MinGroupRecordings);
    }
    let products = recordings
        .iter()
        .map(recording_product)
        .collect::<Result<Vec<_>, _>>()?;
    let mill = &config.tandem_mills[index];
    let mut groups: Vec<(GroupCommissioning, Stable, Vec<RecordingFigures>)> = Vec::new();
    let mut group = |name: String, products: Vec<u32>, configured: bool| {
        let figures = GroupCommissioning {
            name,
            products,
            configured,
            recordings: Vec::new(),
            windows: 0,
            min_recordings: min_group_recordings,
            gain_thresholds: None,
            stable_ratio_p99: None,
        };
        groups.push((figures, Stable::new(config, index), Vec::new()));
    };
    for configured in &mill.product_groups {
        group(configured.name.clone(), configured.products.clone(), true);
    }
    if mill.product_groups.is_empty() {
        let mut seen: Vec<u32> = products.iter().flatten().copied().collect();
        seen.sort_unstable();
        seen.dedup();
        for code in seen {
            group(format!("product-{code}"), vec![code], false);
        }
    }
    let mut all = Stable::new(config, index);
    let mut figures = Vec::with_capacity(recordings.len());
    for (recording, product) in recordings.iter().zip(&products) {
        let evaluated = evaluate(config, index, recording)?;
        figures.push(all.take(config, index, recording, &evaluated)?);
        let Some((group, stable, group_figures)) = groups
            .iter_mut()
            .find(|(g, _, _)| product.is_some_and(|p| g.products.contains(&p)))
        else {
            continue;
        };
        group.recordings.push(recording.name.clone());
        group_figures.push(stable.take(config, index, recording, &evaluated)?);
    }
    let mut commissioning = all.commissioning(margin_percent, figures);
    for (mut group, stable, group_figures) in groups {
        group.windows = group_figures.iter().map(|f| f.windows).sum();
        if group.recordings.len() >= min_group_recordings {
            let own = stable.commissioning(margin_percent, group_figures);
            commissioning.stable_ratio_p99 =
                commissioning.stable_ratio_p99.max(own.stable_ratio_p99);
            commissioning.release_cramped |= own.release_cramped;
            commissioning.slow_down_release =
                commissioning.slow_down_release.max(own.slow_down_release);
            group.gain_thresholds = Some(own.gain_thresholds);
            group.stable_ratio_p99 = Some(own.stable_ratio_p99);
        }
        commissioning.product_groups.push(group);
    }
    Ok(commissioning)
}

/// The one product of `recording` (its `product` column's valid codes); `None`
/// without the column or a valid code in it.
fn recording_product(recording: &Recording) -> Result<Option<u32>, CommissionError> {
    let Some(column) = &recording.context.product else {
        return Ok(None);
    };
    let mut first: Option<u32> = None;
    for (k, &value) in column.iter().enumerate() {
        let raw = RawContext {
            product: Some(value),
            ..RawContext::default()
        };
        let Ok(Some(code)) = raw.check(&[]).map(|c| c.product) else {
            continue;
        };
        match first {
            None => first = Some(code),
            Some(p) if p == code => {}
            Some(p) => {
                let line = recording
                    .context
                    .lines
                    .as_ref()
                    .and_then(|lines| lines.get(k).copied())
                    .unwrap_or(k + 1);
                return Err(CommissionError::MixedProducts {
                    recording: recording.name.clone(),
                    first: p,
                    other: code,
                    line,
                });
            }
        }
    }
    Ok(first)
}

/// The stable figures of the recordings so far.
struct Stable {
    /// The tandem mill.
    mill: String,
    /// Its stands' channels, in its order.
    channels: Vec<String>,
    /// Per stand, the largest gain.
    largest_gain: Vec<f64>,
    /// Per stand, the largest band RMS.
    largest_rms: Vec<f64>,
    /// The largest K_mean of any window.
    largest_k_mean: f64,
    /// Every stable window's gains per stand, for the release levels.
    gains: Vec<Vec<f64>>,
    /// Every stable window's band RMS per stand, for the release levels.
    band_rms: Vec<Vec<f64>>,
}

/// One stand's gain over a recording's full windows.
struct StandGain {
    /// Its median.
    median: f64,
    /// Its largest.
    largest: f64,
    /// When the largest was, s.
    largest_at_s: f64,
}

impl Stable {
    /// Nothing seen yet of mill `index` of `config`.
    fn new(config: &Config, index: usize) -> Self {
        let mill = &config.tandem_mills[index];
        let channels: Vec<String> = mill
            .stands
            .iter()
            .map(|&c| config.channels[c].name.clone())
            .collect();
        let stands = channels.len();
        Self {
            mill: mill.name.clone(),
            channels,
            largest_gain: vec![0.0_f64; stands],
            largest_rms: vec![0.0_f64; stands],
            largest_k_mean: f64::NEG_INFINITY,
            gains: Vec::new(),
            band_rms: Vec::new(),
        }
    }

    /// Take in `recording` of mill `index` of `config`: its windows through the
    /// monitor, each stand checked for chatter; returns its figures.
    fn add(
        &mut self,
        config: &Config,
        index: usize,
        recording: &Recording,
    ) -> Result<RecordingFigures, CommissionError> {
        let evaluated = evaluate(config, index, recording)?;
        self.take(config, index, recording, &evaluated)
    }

    /// Take in `recording` of mill `index` of `config` by its windows through the
    /// monitor (`evaluated`), each stand checked for chatter; returns its figures.
    fn take(
        &mut self,
        config: &Config,
        index: usize,
        recording: &Recording,
        evaluated: &[Window],
    ) -> Result<RecordingFigures, CommissionError> {
        let full: Vec<&Window> = evaluated.iter().filter(|w| w.gain.is_some()).collect();
        if full.is_empty() {
            return Err(too_short(config, index, recording));
        }
        let mut largest_over_median = Vec::with_capacity(self.channels.len());
        let mut largest_at_s = Vec::with_capacity(self.channels.len());
        for stand in 0..self.channels.len() {
            let gain = StandGain::of(&full, stand);
            if gain.largest > CHATTER_FACTOR * gain.median {
                return Err(gain.chatter(&full, stand, &self.channels[stand], recording));
            }
            largest_over_median.push(gain.largest / gain.median);
            largest_at_s.push(gain.largest_at_s);
            self.largest_gain[stand] = self.largest_gain[stand].max(gain.largest);
            for window in &full {
                if let Some(gain) = &window.gain {
                    self.largest_rms[stand] = self.largest_rms[stand].max(gain.band_rms[stand]);
                }
            }
        }
        for window in &full {
            if let Some(gain) = &window.gain {
                self.gains.push(gain.gain.to_vec());
                self.band_rms.push(gain.band_rms.to_vec());
            }
        }
        self.largest_k_mean = evaluated
            .iter()
            .map(|w| w.result.k_mean)
            .fold(self.largest_k_mean, f64::max);
        Ok(RecordingFigures {
            recording: recording.name.clone(),
            duration_s: recording.duration_s(),
            windows: full.len(),
            largest_over_median,
            largest_at_s,
            speeds: window_speeds(recording, &full),
        })
    }

    /// The thresholds with `margin_percent` over what was seen, with the recordings'
    /// `figures`.
    fn commissioning(self, margin_percent: f64, figures: Vec<RecordingFigures>) -> Commissioning {
        let margin = margin_percent / 100.0;
        let gain_thresholds: Vec<f64> = self
            .largest_gain
            .iter()
            .map(|g| up(g * (1.0 + margin)))
            .collect();
        let band_rms_thresholds: Vec<f64> = self
            .largest_rms
            .iter()
            .map(|r| up(r * (1.0 + margin)))
            .collect();
        let (stable_ratio_p99, slow_down_release) = release(&self.gains, &gain_thresholds);
        let (_, band_rms_release) = release(&self.band_rms, &band_rms_thresholds);
        let largest_k_mean = self.largest_k_mean;
        Commissioning {
            mill: self.mill,
            margin_percent,
            gain_thresholds,
            band_rms_thresholds,
            stable_ratio_p99,
            release_cramped: stable_ratio_p99 + RELEASE_ROOM > RELEASE_CEILING,
            slow_down_release,
            band_rms_release,
            largest_k_mean,
            k_max: up(largest_k_mean + margin * (1.0 - largest_k_mean)).min(0.999),
            stands: self
                .channels
                .into_iter()
                .zip(self.largest_gain.iter().zip(&self.largest_rms))
                .map(
                    |(channel, (&largest_gain, &largest_band_rms))| StandFigures {
                        channel,
                        largest_gain,
                        largest_band_rms,
                    },
                )
                .collect(),
            windows: figures.iter().map(|f| f.windows).sum(),
            duration_s: figures.iter().map(|f| f.duration_s).sum(),
            speeds: all_speeds(&figures),
            recordings: figures,
            product_groups: Vec::new(),
            not_pooled: Vec::new(),
        }
    }
}

impl StandGain {
    /// Stand `stand`'s gain over the `full` windows (each with a gain).
    fn of(full: &[&Window], stand: usize) -> Self {
        let gains = stand_gains(full, stand);
        let mut sorted: Vec<f64> = gains.iter().map(|&(_, g)| g).collect();
        sorted.sort_by(f64::total_cmp);
        let median = sorted[sorted.len() / 2];
        let (largest_at_s, largest) =
            gains
                .iter()
                .copied()
                .fold((0.0, f64::NEG_INFINITY), |best, (t, g)| {
                    if g > best.1 {
                        (t, g)
                    } else {
                        best
                    }
                });
        Self {
            median,
            largest,
            largest_at_s,
        }
    }

    /// The refusal of `recording`, whose stand `stand` (on `channel`) shows chatter
    /// over the `full` windows.
    fn chatter(
        &self,
        full: &[&Window],
        stand: usize,
        channel: &str,
        recording: &Recording,
    ) -> CommissionError {
        let first_at_s = stand_gains(full, stand)
            .iter()
            .find(|&&(_, g)| g > CHATTER_FACTOR * self.median)
            .map_or(self.largest_at_s, |&(t, _)| t);
        CommissionError::Chatter {
            recording: recording.name.clone(),
            stand: stand + 1,
            channel: channel.to_owned(),
            largest: self.largest,
            largest_at_s: self.largest_at_s,
            median: self.median,
            factor: self.largest / self.median,
            first_at_s,
        }
    }
}

/// `recording`'s windows through the monitor of mill `index` of `config`.
fn evaluate(
    config: &Config,
    index: usize,
    recording: &Recording,
) -> Result<Vec<Window>, CommissionError> {
    windows(config, index, &recording.time_s, &recording.stands).map_err(|source| {
        CommissionError::Monitor {
            recording: recording.name.clone(),
            source,
        }
    })
}

/// Stand `stand`'s gain in each of the `full` windows, with the window's end time, s.
fn stand_gains(full: &[&Window], stand: usize) -> Vec<(f64, f64)> {
    full.iter()
        .filter_map(|w| w.gain.as_ref().map(|g| (w.t_s, g.gain[stand])))
        .collect()
}

/// The refusal of `recording` of mill `index` of `config`: too short for a full gain
/// window.
fn too_short(config: &Config, index: usize, recording: &Recording) -> CommissionError {
    let mill = &config.tandem_mills[index];
    let rate_hz = config.channels[mill.stands[0]].sample_rate_hz;
    let window = (mill.window_s * rate_hz).round() as usize;
    let hop = (window / 2).max(1);
    let gain = (mill.gain_window_s * rate_hz).round() as usize;
    CommissionError::TooShort {
        recording: recording.name.clone(),
        duration_s: recording.len() as f64 / rate_hz,
        needed_s: (ANCHOR_BLOCK + window.max(gain + hop)) as f64 / rate_hz,
        gain_window_s: mill.gain_window_s,
        hop_s: hop as f64 / rate_hz,
    }
}

/// The speeds at the ends of `recording`'s `full` windows, when it has a speed column.
fn window_speeds(recording: &Recording, full: &[&Window]) -> Option<SpeedCoverage> {
    recording.speed.as_ref().map(|(column, speed)| {
        let at_ends = full.iter().map(|w| speed[w.last_sample]);
        SpeedCoverage {
            column: column.clone(),
            lowest: at_ends.clone().fold(f64::INFINITY, f64::min),
            highest: at_ends.fold(f64::NEG_INFINITY, f64::max),
        }
    })
}

/// The speeds every recording covered, when each has a speed column.
fn all_speeds(figures: &[RecordingFigures]) -> Option<SpeedCoverage> {
    figures
        .iter()
        .map(|f| f.speeds.clone())
        .collect::<Option<Vec<_>>>()
        .and_then(|all| {
            let column = all.first()?.column.clone();
            Some(SpeedCoverage {
                column,
                lowest: all.iter().map(|s| s.lowest).fold(f64::INFINITY, f64::min),
                highest: all
                    .iter()
                    .map(|s| s.highest)
                    .fold(f64::NEG_INFINITY, f64::max),
            })
        })
}

/// The 99th percentile over `windows` of the largest figure / threshold, and the
/// release level for it (see the module docs).
fn release(windows: &[Vec<f64>], thresholds: &[f64]) -> (f64, f64) {
    let mut ratios: Vec<f64> = windows
        .iter()
        .map(|figures| {
            figures
                .iter()
                .zip(thresholds)
                .map(|(figure, threshold)| figure / threshold)
                .fold(0.0, f64::max)
        })
        .collect();
    ratios.sort_by(f64::total_cmp);
    let p99 = ratios
        .get((ratios.len() as f64 * 0.99) as usize)
        .or(ratios.last())
        .copied()
        .unwrap_or(0.0);
    let level = ((p99 + RELEASE_ROOM) * 100.0).ceil() / 100.0;
    (p99, level.clamp(RELEASE_FLOOR, RELEASE_CEILING))
}

/// `value` rounded up to 0.001, so a given threshold is never below the computed one.
fn up(value: f64) -> f64 {
    (value * 1000.0 - 1e-9).ceil() / 1000.0
}

#[cfg(test)]
mod tests {
    use super::super::testing::{example_tandem, lines_recording};
    use super::*;

    #[test]
    fn the_first_gain_needs_the_first_block_the_gain_window_and_a_hop() {
        let config = example_tandem();
        // 120 + 5000 + 625 samples: one window with a full gain window, gain 4.
        let needed = ANCHOR_BLOCK + 5000 + 625;
        let c = commission(&config, 0, &[lines_recording(needed, |_| 2.0)], 10.0)
            .expect("commissioned");
        assert_eq!(c.windows, 1);
        for (threshold, stand) in c.gain_thresholds.iter().zip(&c.stands) {
            assert!((stand.largest_gain - 4.0).abs() < 0.16, "{stand:?}");
            assert_eq!(*threshold, up(stand.largest_gain * 1.1));
        }
        let error = commission(&config, 0, &[lines_recording(needed - 1, |_| 2.0)], 10.0)
            .expect_err("one sample short");
        assert_eq!(
            error.to_string(),
            "lines.csv: 2.298 s is too short for the gain window: the first gain needs 2.298 s \
             of samples (the first 120-sample block, then gain_window_s = 2 s and a hop of 0.25 s)"
        );
    }

    /// [`lines_recording`] of 3 s (five windows with a full gain window), chatter line
    /// `amplitude` over the reference's 0.5 (gain `2 amplitude`), named `name`, its
    /// `product` column `product` on every row.
    fn product_recording(name: &str, amplitude: f64, product: Option<f64>) -> Recording {
        let mut recording = lines_recording(7_500, |_| amplitude);
        recording.name = name.into();
        recording.context.product = product.map(|code| vec![code; recording.len()]);
        recording
    }

    #[test]
    fn by_product_each_group_with_enough_recordings_gets_its_own_thresholds() {
        let config = example_tandem();
        // Product 1 rolls at gain 1 (two recordings), product 2 at gain 2 (one), and a
        // recording without a product column at gain 1.5.
        let recordings = [
            product_recording("a.csv", 0.5, Some(1.0)),
            product_recording("b.csv", 0.5, Some(1.0)),
            product_recording("c.csv", 1.0, Some(2.0)),
            product_recording("d.csv", 0.75, None),
        ];
        let c = commission_by_product(&config, 0, &recordings, 10.0, 2).expect("commissioned");
        // The mill's (the fallback) from every recording: gain 2 plus 10%.
        for threshold in &c.gain_thresholds {
            assert!((threshold - 2.2).abs() < 0.1, "{c:?}");
        }
        assert_eq!(c.recordings.len(), 4);
        let names: Vec<&str> = c.product_groups.iter().map(|g| g.name.as_str()).collect();
        assert_eq!(names, ["product-1", "product-2"]);
        let one = &c.product_groups[0];
        assert_eq!(
            (one.products.as_slice(), one.recordings.len()),
            (&[1][..], 2)
        );
        let own = one
            .gain_thresholds
            .as_ref()
            .expect("two recordings: its own");
        for threshold in own {
            assert!((threshold - 1.1).abs() < 0.05, "{one:?}");
        }
        // Product 2 has one recording: too few, its products fall back to the mill's.
        let two = &c.product_groups[1];
        assert_eq!(
            (two.recordings.len(), two.gain_thresholds.as_ref()),
            (1, None)
        );
        // With one recording enough, it has its own (the mill's, here).
        let c = commission_by_product(&config, 0, &recordings, 10.0, 1).expect("commissioned");
        assert!(c.product_groups[1].gain_thresholds.is_some());
        // Without product columns: no groups, the plain commissioning.
        let plain = commission_by_product(&config, 0, &recordings[3..], 10.0, 2).expect("plain");
        assert_eq!(
            plain,
            commission(&config, 0, &recordings[3..], 10.0).expect("plain")
        );
        assert!(plain.product_groups.is_empty());

        // A recording with two products is refused, naming the line of the change.
        let mut mixed = product_recording("mixed.csv", 0.5, Some(1.0));
        if let Some(column) = mixed.context.product.as_mut() {
            column[4000..].fill(2.0);
        }
        assert_eq!(
            commission_by_product(&config, 0, &[mixed], 10.0, 2)
                .expect_err("two products")
                .to_string(),
            "mixed.csv: the product column holds 1 and then 2 (line 4001): commissioning by \
             product takes one product per recording (split the recording at the product change)"
        );
        assert_eq!(
            commission_by_product(&config, 0, &recordings, 10.0, 0),
            Err(CommissionError::MinGroupRecordings)
        );
    }

    #[test]
    fn a_chatter_line_growing_past_eight_times_its_median_is_refused() {
        let config = example_tandem();
        // 20 s steady, then the chatter line grows 20-fold over 5 s.
        let growing = |t: f64| 0.5 * (1.0 + 19.0 * ((t - 20.0) / 5.0).clamp(0.0, 1.0));
        let error =
            commission(&config, 0, &[lines_recording(62_500, growing)], 10.0).expect_err("chatter");
        let message = error.to_string();
        assert!(
            message.starts_with(
                "lines.csv: shows chatter: the chatter-band gain of stand 1 (`s1_vib`)"
            ),
            "{message}"
        );
        assert!(
            message.contains("commission from stable rolling only"),
            "{message}"
        );
        // Growing fourfold: noted, not refused.
        let milder = |t: f64| 0.5 * (1.0 + 3.5 * ((t - 20.0) / 5.0).clamp(0.0, 1.0));
        let c =
            commission(&config, 0, &[lines_recording(62_500, milder)], 10.0).expect("commissioned");
        let factor = c.recordings[0].largest_over_median[0];
        assert!(factor > NOTE_FACTOR && factor < CHATTER_FACTOR, "{factor}");
        assert_eq!(
            commission(&config, 0, &[], 10.0),
            Err(CommissionError::NoRecording)
        );
        assert_eq!(
            commission(&config, 0, &[lines_recording(62_500, milder)], -1.0)
                .expect_err("negative margin")
                .to_string(),
            "--margin: -1 is not allowed (must be >= 0 and <= 200 percent)"
        );
    }
}
