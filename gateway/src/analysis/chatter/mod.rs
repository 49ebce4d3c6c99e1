//! Chatter monitoring of tandem mills: aligned sliding windows of the stands'
//! vibration, their spectra and the synchronization conditions of `dsp::chatter`, the
//! chatter-band gain of `dsp::band_gain`, the configured detector's alarm and the
//! slow-down request, published and recorded in the history.
//!
//! One file per job, along the data path:
//!
//! - `align`: the stands' samples on one common axis (ring
//!   buffers, anchoring against arrival times, the window grid, restarts);
//! - `spectra`: per window the Hann-windowed FFTs, the principal frequencies, sigma_n
//!   and K_mean (the paper's detector);
//! - `gain`: the chatter-band gain per stand and its ratio to the thresholds (the
//!   band-gain detector, the default);
//! - `verdict`: the configured detector's warning and alarm, the slow-down request
//!   with its hysteresis ([`SlowDown`]);
//! - `monitor`: [`ChatterMonitor`], one mill's monitor built from the configuration;
//! - `publish`: [`ChatterAnalysis`], every mill's monitor fed by the analysis task,
//!   each update published;
//! - `history`: the chatter episodes and alarms recorded in the history;
//! - `capture`: each episode's stand samples kept as a capture (`EpisodeRecorder`);
//! - `offline`: a recording through the monitor window by window (the chatter tools,
//!   the page's band signals and spectra of a captured episode);
//! - [`commission`]: the mill's thresholds from recordings of its stable rolling
//!   (`millgate chatter commission`).

mod align;
mod capture;
pub mod commission;
mod gain;
mod history;
mod monitor;
mod offline;
mod publish;
mod spectra;
#[cfg(test)]
pub(crate) mod testing;
mod verdict;

pub use align::MAX_STAND_LAG_S;
pub use capture::ANCHOR_BLOCK;
pub use gain::GainReading;
pub(crate) use monitor::ChatterSetupError;
pub use monitor::{ChatterMonitor, ChatterUpdate, MIN_WINDOW_SAMPLES};
pub use offline::{
    episode_bands, welch_psd, windows, windows_in_context, ContextColumns, InvalidContext,
    Recording, Window, SPECTRUM_WINDOWS_EACH_SIDE,
};
pub use publish::ChatterAnalysis;
pub use spectra::chatter_frequency_hz;
pub use verdict::{SlowDown, Verdict, WeldHold};
