//! What is watched: drivelines (bites, wear, the gap), tandem mills (chatter) and rod
//! mills (the rod between stands).

use std::path::PathBuf;

use super::Identification;

/// Bite detection settings of one driveline.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BiteSettings {
    /// Rise above the tracked baseline that marks a bite, kN*m (> 0).
    pub threshold_knm: f64,
    /// Window kept before the trigger, s, 0..=10 (default 0.1).
    pub pre_trigger_s: f64,
    /// Window captured after the trigger, s, > 0 and <= 10 (default 0.5).
    pub post_trigger_s: f64,
}

/// A hot-mill driveline: one torque channel analysed at each bite.
#[derive(Debug, Clone, PartialEq)]
pub struct Driveline {
    /// Unique among drivelines.
    pub name: String,
    /// Index into [`Config::channels`](crate::Config::channels) of the torque channel.
    pub torque: usize,
    /// Index into [`Config::channels`](crate::Config::channels) of an optional "metal in
    /// stand" trigger.
    pub metal_in_stand: Option<usize>,
    /// Indices into [`Config::channels`](crate::Config::channels) of other sampled channels
    /// kept in each bite's capture beside the torque (motor current, speed, ...): distinct,
    /// not the torque channel, block or CAN channels at the torque channel's sample rate.
    pub extra_channels: Vec<usize>,
    /// Optional driveline model file (sim model TOML), relative to the config file.
    pub model: Option<PathBuf>,
    /// Bite detection.
    pub bite: BiteSettings,
    /// TAF and gap warning and alarm.
    pub thresholds: DrivelineThresholds,
    /// The gap diagnosis against `model` (used only with a model).
    pub wear: WearSettings,
    /// The fatigue ledger of the driveline's components (`None`: no ledger).
    pub fatigue: Option<FatigueSettings>,
    /// Its nameplate (`identification`, empty when left out).
    pub identification: Identification,
    /// The mill's process context at each bite (`context` table; every tag but
    /// `weld`): a bite while the state is idle, threading or maintenance is recorded
    /// but not pooled into the wear trend. All `None` when left out.
    pub context: ContextTags,
    /// Mill speed range whose bites are pooled into the wear trend, m/min, `0 <= low
    /// < high` (`pool_speed_range_mpm`, needs the `speed_mpm` context tag): a bite
    /// rolled outside it is recorded but not pooled. `None`: any speed.
    pub pool_speed_range_mpm: Option<(f64, f64)>,
}

/// `drivelines[].fatigue`: rainflow counting of the whole torque stream and Miner's
/// rule per component.
#[derive(Debug, Clone, PartialEq)]
pub struct FatigueSettings {
    /// Hysteresis gate of the reversals, kN*m: finite, >= 0 and below the torque
    /// channel's range where its encoding bounds it. Default: 1% of that range, or 10%
    /// of `bite.threshold_knm` for a channel without a bounded range.
    pub gate_knm: f64,
    /// Consumed life at which a component is due, in (0, 1] (default 0.8): the
    /// expected date of reaching it is forecast from the consumption rate.
    pub life_limit: f64,
    /// The components whose life is counted, at least one, names distinct.
    pub components: Vec<FatigueComponent>,
}

/// One coupling or spindle of a fatigue ledger.
#[derive(Debug, Clone, PartialEq)]
pub struct FatigueComponent {
    /// Unique in the driveline, e.g. `spindle 2`.
    pub name: String,
    /// Its S-N curve (Basquin, torque share, endurance limit, mean correction).
    pub curve: millgate_dsp::miner::SnCurve,
}

/// Alarm thresholds of a driveline.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DrivelineThresholds {
    /// TAF above which the TAF warning bit is set (> 1).
    pub taf_warning: f64,
    /// TAF above which the TAF alarm bit is set (>= warning).
    pub taf_alarm: f64,
    /// Estimated opened gap (maximum likelihood) at or above which the gap warning bit
    /// is set, mrad (> 0; default 2).
    pub gap_warning_mrad: f64,
    /// Opened gap whose 90% interval lies wholly at or above it sets the gap alarm
    /// bit (latched until acknowledged), mrad (>= `gap_warning_mrad`; default 4).
    pub gap_alarm_mrad: f64,
}

/// The gap diagnosis of a driveline with a model: which couplings may carry the gap,
/// the wear maps' grid and the forecast's horizon.
#[derive(Debug, Clone, PartialEq)]
pub struct WearSettings {
    /// Couplings (model indices, motor side first) that may carry the gap, distinct;
    /// `None`: every coupling of the model.
    pub couplings: Option<Vec<usize>>,
    /// Largest opened gap the maps cover, mrad, in (0, 100] (default 8).
    pub max_gap_mrad: f64,
    /// Gap step of the maps, mrad, > 0 with at most 400 steps up to `max_gap_mrad`
    /// (default 0.125).
    pub gap_step_mrad: f64,
    /// Static torque range the maps cover, kN*m, `0 < low < high`; `None`: from the
    /// model's static torque (0.25x to 2x, and at least 1.25x the bite threshold).
    pub static_torque_knm: Option<(f64, f64)>,
    /// Static torques of the maps' grid (geometric spacing over the range), 3..=64
    /// (default 16).
    pub torque_points: usize,
    /// How far ahead the gap forecast looks, calendar days, in [1, 3650] (default
    /// 365): a crossing later than this is reported as beyond the horizon.
    pub horizon_days: f64,
    /// Bites within this of the trend's first (after a start, a wear reset or a jump
    /// of the gap) are taken as one gap, s, in [0, 2 592 000] (default 3600): the
    /// growth comes from bites further apart. 0 takes a growth from two bites a bar
    /// apart (the demo's wear, compressed into seconds).
    pub growth_span_s: f64,
}

impl Default for WearSettings {
    /// The defaults of a `[drivelines.wear]` table left out.
    fn default() -> Self {
        Self {
            couplings: None,
            max_gap_mrad: 8.0,
            gap_step_mrad: 0.125,
            static_torque_knm: None,
            torque_points: 16,
            horizon_days: 365.0,
            growth_span_s: 3600.0,
        }
    }
}

impl DrivelineThresholds {
    /// Default gap warning threshold, mrad.
    pub(crate) const DEFAULT_GAP_WARNING_MRAD: f64 = 2.0;
    /// Default gap alarm threshold, mrad.
    pub(crate) const DEFAULT_GAP_ALARM_MRAD: f64 = 4.0;
}

/// A tandem cold mill watched for chatter.
#[derive(Debug, Clone, PartialEq)]
pub struct TandemMill {
    /// Unique among tandem mills.
    pub name: String,
    /// Indices into [`Config::channels`](crate::Config::channels) of the stands' vibration
    /// channels, in rolling order; 2..=8 distinct acceleration channels sharing one sample
    /// rate.
    pub stands: Vec<usize>,
    /// Chatter band, Hz: (low, high), 0 < low < high < half of every stand's sample rate.
    pub chatter_band_hz: (f64, f64),
    /// Sliding analysis window, s, > 0 and <= 10.
    pub window_s: f64,
    /// K_max: largest adjacent-stand correlation seen in steady rolling (0..1).
    pub k_max: f64,
    /// Which detector raises the chatter alarm and the slow-down request.
    pub detector: ChatterDetectorKind,
    /// Reference band of the chatter-band gain, Hz: (low, high), above the chatter
    /// band (low >= its upper edge) and below half the sample rate. Default: 1.5 to 3
    /// times the chatter band's upper edge.
    pub reference_band_hz: (f64, f64),
    /// Window of the chatter-band gain, s, > 0 and <= 10 (default 2); the monitor
    /// checks it is 1..=16 hops of `window_s / 2`.
    pub gain_window_s: f64,
    /// Alarm threshold of the chatter-band gain per stand, in `stands` order, each
    /// finite and > 0 (from commissioning: the largest gain in stable rolling up to
    /// the highest allowed speed, plus a margin). Required with the band-gain
    /// detector; may be empty with the paper's (no gain ratio is then published).
    pub gain_thresholds: Vec<f64>,
    /// Chatter thresholds per product group (`[[tandem_mills.product_groups]]`, empty
    /// when left out): while the PLC's product (the `product` context tag) is one of a
    /// group's products, that group's `gain_thresholds` judge the windows; any other
    /// product, or no valid and fresh product, falls back to the mill's
    /// `gain_thresholds`. No product is in two groups.
    pub product_groups: Vec<ProductGroup>,
    /// The slow-down request clears once the alarm figure (the gain ratio, or for the
    /// paper's detector the synchronization) has stayed below this fraction of its
    /// alarm level for `slow_down_hold_s`; > 0 and < 1 (default 0.8).
    pub slow_down_release: f64,
    /// Time the alarm figure must stay below the release level before the slow-down
    /// request clears, s, >= 0 and <= 600 (default 5).
    pub slow_down_hold_s: f64,
    /// The weld hold (with the mill's weld bit, band-gain detector): time after the
    /// weld bit fell during which the alarm needs `weld_alarm_factor` times its level,
    /// s, >= 0 and <= 60 (default from the closed loop on the tandem model,
    /// `docs/chatter.md`).
    pub weld_settle_s: f64,
    /// Factor on the alarm level while a weld is in the mill and for `weld_settle_s`
    /// after, >= 1 and <= 10 (1: no hold; default from the closed loop).
    pub weld_alarm_factor: f64,
    /// The process context read from the PLC (`context` table; all `None` and empty
    /// when left out).
    pub context: ContextTags,
    /// Chatter-episode captures (with `[history]`): stand samples kept before the
    /// warning is raised, s, >= 0 and <= 60 (default 5).
    pub capture_before_s: f64,
    /// Stand samples kept after the warning clears, s, >= 0 and <= 60 (default 2).
    pub capture_after_s: f64,
    /// Longest chatter-episode capture, s, > `capture_before_s` and <= 600 (default
    /// 120): a longer episode's capture is cut there and says so.
    pub capture_max_s: f64,
    /// Its nameplate (`identification`, empty when left out).
    pub identification: Identification,
}

/// Chatter thresholds for a group of products of a tandem mill
/// (`[[tandem_mills.product_groups]]`).
#[derive(Debug, Clone, PartialEq)]
pub struct ProductGroup {
    /// Unique among the mill's groups (non-empty); the name the outputs show for the
    /// thresholds in use.
    pub name: String,
    /// The product codes of the group, at least one, each in no other group of the
    /// mill (and one of the context's `products` when that list is given).
    pub products: Vec<u32>,
    /// Alarm threshold of the chatter-band gain per stand, as the mill's
    /// `gain_thresholds` (one per stand, each > 0). Empty only where the mill's may be
    /// (not yet commissioned, or the paper's detector): the mill's then judge.
    pub gain_thresholds: Vec<f64>,
}

impl TandemMill {
    /// The index in [`Self::product_groups`] of the group holding `product`; `None`
    /// when no group does (the mill's thresholds judge).
    pub fn product_group(&self, product: u32) -> Option<usize> {
        self.product_groups
            .iter()
            .position(|group| group.products.contains(&product))
    }

    /// The thresholds that judge while group `group` is in use (`None`: the mill's):
    /// the group's, or the mill's when the group has none.
    pub fn thresholds_of(&self, group: Option<usize>) -> &[f64] {
        match group.map(|g| &self.product_groups[g].gain_thresholds) {
            Some(thresholds) if !thresholds.is_empty() => thresholds,
            _ => &self.gain_thresholds,
        }
    }
}

/// A mill's process-context tags (`context = { weld = "...", ... }`): each names a
/// `process_value` channel read like any channel (so a stale source flags it as it
/// flags the channel).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ContextTags {
    /// The weld-tracking bit for the mill (0/1: 1 from the weld reaching the first
    /// stand until it has left the last); index into
    /// [`Config::channels`](crate::Config::channels).
    pub weld: Option<usize>,
    /// The weld-tracking bits per stand (`weld_stands`, one per stand in the mill's
    /// order, 0/1: 1 while the weld is in that stand); indices into
    /// [`Config::channels`](crate::Config::channels). Empty: none (exclusive with
    /// [`Self::weld`]).
    pub weld_stands: Vec<usize>,
    /// Mill speed, m/min.
    pub speed_mpm: Option<usize>,
    /// Coil or bar id (a whole number; u32 registers).
    pub coil: Option<usize>,
    /// Product (steel grade) code (a whole number).
    pub product: Option<usize>,
    /// Strip thickness, mm.
    pub thickness_mm: Option<usize>,
    /// Pass number.
    pub pass: Option<usize>,
    /// The PLC's state code: 0 idle, 1 threading, 2 rolling, 3 maintenance.
    pub state: Option<usize>,
    /// The known product codes (`products`); a product read outside them makes the
    /// context invalid. Empty: any code.
    pub products: Vec<u32>,
}

impl ContextTags {
    /// Whether a weld bit is configured: the mill's or one per stand.
    pub fn has_weld_bits(&self) -> bool {
        self.weld.is_some() || !self.weld_stands.is_empty()
    }

    /// The tags' keys and channels, in the documentation's order, those configured
    /// (the per-stand weld bits are in [`Self::weld_stands`], not here).
    pub fn tags(&self) -> impl Iterator<Item = (&'static str, usize)> + '_ {
        [
            ("weld", self.weld),
            ("speed_mpm", self.speed_mpm),
            ("coil", self.coil),
            ("product", self.product),
            ("thickness_mm", self.thickness_mm),
            ("pass", self.pass),
            ("state", self.state),
        ]
        .into_iter()
        .filter_map(|(key, channel)| channel.map(|c| (key, c)))
    }
}

/// The chatter detector that raises a tandem mill's alarm (`detector` key).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ChatterDetectorKind {
    /// `"band_gain"` (the default): chatter-band RMS over reference-band RMS per stand
    /// against `gain_thresholds`; the detector that warned earliest at zero false
    /// alarms in the tandem-model race (`tests/src/experiments/chatter_eval/`).
    #[default]
    BandGain,
    /// `"paper"`: the synchronization conditions (sigma_n <= sigma_min and K_mean >=
    /// K_max); in the race they fired before developed chatter in 38 of 60 ramps.
    Paper,
}

/// A rod (wire) mill whose rod spans are checked online against the Mathieu
/// instability tongues, from PLC process values (`[[rod_mills]]`).
#[derive(Debug, Clone, PartialEq)]
pub struct RodMill {
    /// Unique among rod mills.
    pub name: String,
    /// Rod-mill file (`millgate-sim` rod mill TOML: drive, stands, spans, modulus
    /// table), relative to the config file; its content is checked by the service.
    pub mill: PathBuf,
    /// Pass schedule CSV (rod diameters and temperature per pass), relative to the
    /// config file.
    pub schedule: PathBuf,
    /// Index into [`Config::channels`](crate::Config::channels) of the process value
    /// carrying the active drive configuration: value k (an integer
    /// 0..configurations.len()) selects `configurations[k]`.
    pub configuration: usize,
    /// Drive configuration names (of the mill's drive) by PLC value, 1..=64 names.
    pub configurations: Vec<String>,
    /// Index into [`Config::channels`](crate::Config::channels) of the process value
    /// carrying the pass number: k (1-based) selects the k-th row of the schedule.
    pub pass: usize,
    /// Index into [`Config::channels`](crate::Config::channels) of the finishing speed, m/s
    /// (rod speed out of the last stand).
    pub finishing_speed: usize,
    /// Index into [`Config::channels`](crate::Config::channels) of the rod temperature,
    /// deg C; without it the schedule's temperature of the pass is used.
    pub temperature: Option<usize>,
    /// A stable span whose speed margin is below this is "near a tongue", m/s, > 0
    /// (default 2).
    pub near_tongue_m_s: f64,
    /// Speed hysteresis of the unstable and near-tongue flags, m/s, >= 0 (default
    /// 0.5): a flag clears only once the margin is this much beyond where it was set.
    pub hysteresis_m_s: f64,
    /// Rod temperature step, deg C, > 0 (default 10): the measured temperature is
    /// rounded to a multiple of it before the pass's setup is (re)computed.
    pub temperature_step_c: f64,
    /// Its nameplate (`identification`, empty when left out).
    pub identification: Identification,
}
