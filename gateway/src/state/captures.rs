//! Captures: the samples a verdict was made from, as the history keeps them. The
//! analysis builds a [`CaptureRecord`] for each bite window (and each chatter episode,
//! and each manual request) and records it on the history's queue beside the event it
//! belongs to; the history's writer compresses and stores it
//! ([`crate::history::captures`]).
//!
//! Samples are kept exactly as the analysis saw them (engineering units, `f64`), with
//! each channel's scale and offset: the writer stores raw counts when every sample is
//! its count decoded by the channel's `millgate_config::Scaling` bit for bit (a Modbus
//! DAQ's samples), the `f64` values otherwise, so an export gives back the very
//! samples the analysis used.

use std::sync::Arc;

use serde::{Deserialize, Serialize};

use super::context::ContextReading;
use super::time::UtcTime;

/// What a capture was taken for.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum CaptureKind {
    /// A driveline's bite window (pre- and post-trigger).
    Bite,
    /// A tandem mill's chatter episode, every stand.
    Chatter,
    /// Channels captured on request (a command register, the web API).
    Manual,
}

impl CaptureKind {
    /// As stored: `bite`, `chatter`, `manual`.
    pub fn name(self) -> &'static str {
        match self {
            CaptureKind::Bite => "bite",
            CaptureKind::Chatter => "chatter",
            CaptureKind::Manual => "manual",
        }
    }
}

/// How long a capture is kept under the budget: the retention deletes the lowest
/// class first (oldest first within a class).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum KeepClass {
    /// An ordinary bite: thinned after a few days, deleted first.
    Ordinary = 0,
    /// A bite with a TAF or gap warning.
    Warning = 1,
    /// An alarm bite, a chatter episode, a manual capture: kept longest.
    Important = 2,
}

impl KeepClass {
    /// As stored (0, 1, 2).
    pub fn code(self) -> i64 {
        self as i64
    }
}

/// One channel of a capture.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CaptureChannel {
    /// The channel's name in the configuration.
    pub name: String,
    /// Unit of the samples (`kN*m` for torque).
    pub unit: String,
    /// Engineering units per raw count.
    pub scale: f64,
    /// Engineering value at raw 0.
    pub offset: f64,
    /// The samples, oldest first, engineering units (not serialized: the writer
    /// stores them in the blob).
    #[serde(skip)]
    pub samples: Vec<f64>,
    /// The channel's own timing when it was captured beside another channel (a
    /// driveline's `extra_channels` beside its torque); `None`: the capture's.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub timing: Option<ChannelTiming>,
}

impl CaptureChannel {
    /// `channel` of the configuration as a capture describes it, with no samples yet
    /// and the capture's timing.
    pub fn described(channel: &millgate_config::Channel) -> Self {
        Self {
            name: channel.name.clone(),
            unit: channel.unit.clone(),
            scale: channel.scale,
            offset: channel.offset,
            samples: Vec::new(),
            timing: None,
        }
    }
}

/// The own timing of a channel captured beside the channel that sets a capture's rows
/// (a bite's extra channel beside its torque). Row `k` holds the channel's sample
/// nearest in time to the capture's row `k`; rows outside `first_row..end_row` hold no
/// sample (NaN; an empty cell in CSV): data the gateway no longer or not yet held.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ChannelTiming {
    /// Time of the channel's sample in row `first_row`, ns since the Unix epoch (UTC).
    pub first_sample_unix_ns: i64,
    /// The channel's sample rate, Hz.
    pub sample_rate_hz: f64,
    /// Whether that time comes from the kernel's receive timestamps (CAN).
    pub kernel_time: bool,
    /// First row holding a sample of the channel.
    pub first_row: usize,
    /// One past the last row holding a sample; below the capture's length when the
    /// channel's data had not arrived when the bite's hold ended (a gap at the end).
    pub end_row: usize,
}

/// Data lost inside or at the end of a capture.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct CaptureGap {
    /// Index of the first sample after the loss (the capture's length when it ended
    /// the capture).
    pub before_sample: usize,
    /// Samples lost, when the reader knows.
    pub missed_samples: Option<u64>,
}

/// How the analysis read a bite window: what `millgate analyze` needs to analyse the
/// exported window as the gateway did (same code, same samples, same settings).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct BiteWindowAnalysis {
    /// Index of the trigger sample in the window.
    pub trigger_index: usize,
    /// The detector's baseline at the trigger, kN*m.
    pub baseline_knm: f64,
    /// Rise above the baseline that marks the load onset for the fit, kN*m.
    pub onset_knm: f64,
    /// Low-pass cut-off of the period measurement, Hz.
    pub period_lowpass_hz: f64,
    /// Low-pass cut-off of the peak, Hz (`None`: unfiltered).
    pub peak_lowpass_hz: Option<f64>,
    /// Fraction of the window's end taken as the settled level.
    pub settled_fraction: f64,
    /// Static torque below which no TAF or periods are measured, kN*m.
    pub min_static_knm: f64,
}

/// Where the warning sits in a chatter-episode capture: what `millgate chatter
/// --input` and the tandem mill's page need to find the episode's windows again.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ChatterEpisode {
    /// Index one past the last sample of the window that raised the warning (the
    /// capture starts a whole number of hops before it, so its windows fall on the
    /// monitor's grid).
    pub warning_sample: usize,
    /// Index one past the last sample of the window that cleared it; `None` when
    /// the capture was cut before.
    pub cleared_sample: Option<usize>,
    /// Samples per analysis window.
    pub window_samples: usize,
    /// Samples per hop between windows.
    pub hop_samples: usize,
    /// The episode ran past `capture_max_s`: the capture ends there.
    pub cut: bool,
}

/// The bite a capture belongs to.
#[derive(Debug, Clone, PartialEq)]
pub struct CapturedBite {
    /// The driveline's bite counter after the bite.
    pub counter: u32,
    /// The bite's time (its `bites.time`).
    pub time: UtcTime,
}

/// One capture, as the analysis hands it to the history.
#[derive(Debug, Clone, PartialEq)]
pub struct CaptureRecord {
    /// Bite, chatter episode or manual.
    pub kind: CaptureKind,
    /// The driveline, the tandem mill, or the manual request's name.
    pub subject: String,
    /// The bite, for a bite capture.
    pub bite: Option<CapturedBite>,
    /// Time of the first sample, ns since the Unix epoch (UTC).
    pub first_sample_unix_ns: i64,
    /// Whether that time comes from the kernel's receive timestamps (CAN) rather
    /// than from when the gateway handled the samples.
    pub kernel_time: bool,
    /// Sample rate of every channel, Hz.
    pub sample_rate_hz: f64,
    /// The channels, each with as many samples.
    pub channels: Vec<CaptureChannel>,
    /// Where data was lost.
    pub gaps: Vec<CaptureGap>,
    /// For a bite window: how the analysis read it.
    pub analysis: Option<BiteWindowAnalysis>,
    /// For a chatter episode: where the warning sits.
    pub episode: Option<ChatterEpisode>,
    /// How long it is kept under the budget.
    pub keep: KeepClass,
    /// The process context of its time (a bite's at the bite, a chatter episode's
    /// when its warning was raised); `None` without context tags.
    pub context: Option<ContextReading>,
}

impl CaptureRecord {
    /// Samples per channel (0 without channels).
    pub fn samples(&self) -> usize {
        self.channels.first().map_or(0, |c| c.samples.len())
    }

    /// The first sample's time, ms resolution.
    pub fn started_at(&self) -> UtcTime {
        UtcTime::from_unix_ms(self.first_sample_unix_ns.div_euclid(1_000_000))
    }
}

/// `time` in ns since the Unix epoch (negative before it).
pub fn unix_ns(time: std::time::SystemTime) -> i64 {
    match time.duration_since(std::time::UNIX_EPOCH) {
        Ok(after) => i64::try_from(after.as_nanos()).unwrap_or(i64::MAX),
        Err(before) => -i64::try_from(before.duration().as_nanos()).unwrap_or(i64::MAX),
    }
}

/// What the tandem mill's page plots of a chatter or manual capture of its stands:
/// the chatter monitor's band signal over time and the spectra around the warning
/// (computed by `analysis::chatter::episode_bands`; the web layer gets the function
/// as a [`CaptureBandsFn`] from the service, as it imports no analysis).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CaptureBands {
    /// The mill's chatter band, Hz (low, high).
    pub chatter_band_hz: (f64, f64),
    /// End of each evaluated window with a full band-gain window, s after the
    /// capture's first sample.
    pub window_end_s: Vec<f64>,
    /// Per stand, the chatter-band RMS over the band gain's window
    /// (`gain_window_s`) at each of `window_end_s` (the stands' unit).
    pub band_rms: Vec<Vec<f64>>,
    /// The samples the spectra average: from, to, s after the first sample.
    pub spectrum_span_s: (f64, f64),
    /// Per stand, the spectrum of that span (empty when it is shorter than a
    /// window).
    pub spectra: Vec<StandSpectrum>,
}

/// One stand's power spectral density (Welch).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct StandSpectrum {
    /// Frequency of bin k: k * this, Hz.
    pub frequency_step_hz: f64,
    /// One-sided PSD per bin, unit² / Hz.
    pub psd: Vec<f64>,
}

/// The band analysis of a capture of tandem mill `mill` (index in the
/// configuration): its stands' samples at a sample rate, Hz, and the episode; an
/// error names why the mill's monitor cannot be built.
pub type CaptureBandsFn = Arc<
    dyn Fn(usize, f64, &[Vec<f64>], Option<&ChatterEpisode>) -> Result<CaptureBands, String>
        + Send
        + Sync,
>;
