//! [`AnalysisError`]: what in a configuration the analysis cannot be built for.

use millgate_dsp::bite::BiteSettingsError;

use super::bite_window::{PRE_TRIGGER_CAPACITY, WINDOW_CAPACITY};
use super::chatter::ChatterSetupError;
use super::rod_monitor::RodSetupError;

/// A driveline or tandem mill of the configuration that the analysis cannot be built
/// for. Each message starts with the key at fault (`drivelines[0].bite`), as the
/// configuration's own problems do.
#[derive(Debug, thiserror::Error)]
pub enum AnalysisError {
    /// A tandem mill the chatter monitor cannot be built for.
    #[error(transparent)]
    Chatter(#[from] ChatterSetupError),
    /// A rod mill whose mill file, schedule or configuration names are not usable.
    #[error(transparent)]
    RodMill(#[from] RodSetupError),
    /// The bite window needs more samples than the detector holds.
    #[error(
        "drivelines[{index}].bite: pre_trigger_s {pre_trigger_s} s and post_trigger_s \
         {post_trigger_s} s at {sample_rate_hz} Hz need {pre_samples} + {post_samples} \
         samples; the bite detector holds at most {PRE_TRIGGER_CAPACITY} + {} samples",
        WINDOW_CAPACITY - PRE_TRIGGER_CAPACITY
    )]
    BiteWindow {
        /// Index of the driveline in the configuration.
        index: usize,
        /// Configured capture before the trigger, s.
        pre_trigger_s: f64,
        /// Configured capture after the trigger, s.
        post_trigger_s: f64,
        /// Sample rate of the torque channel, Hz.
        sample_rate_hz: f64,
        /// Samples before the trigger that asks for.
        pre_samples: usize,
        /// Samples from the trigger on that asks for.
        post_samples: usize,
    },
    /// The bite detector refused the settings derived from the driveline.
    #[error("drivelines[{index}].bite: {source}")]
    BiteSettings {
        /// Index of the driveline in the configuration.
        index: usize,
        /// What the detector refused.
        #[source]
        source: BiteSettingsError,
    },
    /// The wear trend refused the driveline's `wear.horizon_days`.
    #[error("drivelines[{index}].wear.horizon_days: {source}")]
    WearTrend {
        /// Index of the driveline in the configuration.
        index: usize,
        /// What the trend refused.
        #[source]
        source: millgate_dsp::wear_trend::TrendError,
    },
    /// The driveline's `wear` settings do not fit its model (the message names the
    /// key).
    #[error("{source}")]
    GapMaps {
        /// Index of the driveline in the configuration.
        index: usize,
        /// What does not fit (boxed: the error stays small on the `Ok` path).
        #[source]
        source: Box<super::gap_map::GapMapError>,
    },
    /// The rainflow counter refused the driveline's `fatigue.gate_knm`.
    #[error("drivelines[{index}].fatigue.gate_knm: {source}")]
    FatigueGate {
        /// Index of the driveline in the configuration.
        index: usize,
        /// What the counter refused.
        #[source]
        source: millgate_dsp::rainflow::RainflowSettingsError,
    },
    /// The driveline's model file (for the wear diagnosis) is not a valid model.
    #[error("drivelines[{index}].model: {source}")]
    Model {
        /// Index of the driveline in the configuration.
        index: usize,
        /// What is wrong with the model file (it names the file and the key).
        #[source]
        source: millgate_sim::model::ModelError,
    },
}
