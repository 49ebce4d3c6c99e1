//! How a driveline's bites are detected and analysed ([`BiteSetup`]), and what its
//! model gives the wear diagnosis: the linear references, the gap monitor and the
//! build of its gap maps.

use std::path::Path;

use millgate_config::{Channel, Driveline};
use millgate_dsp::bite::BiteSettings;
use millgate_dsp::transient::TransientSettings;
use millgate_sim::model::Model;

use crate::analysis::bite_window::{Detector, PRE_TRIGGER_CAPACITY, WINDOW_CAPACITY};
use crate::analysis::error::AnalysisError;
use crate::analysis::gap_monitor::{GapMapJob, GapMonitor};
use crate::analysis::simulated_bite::BiteSimulator;
use crate::analysis::wear::WearReference;
use crate::state::gap_maps::GapMapSpec;

/// Low-pass cut-off for period measurement of a driveline without a model, Hz: keeps
/// the first modes (10-30 Hz, domain notes 1.3) and removes measurement noise above
/// them. With a model the wear map's cut-off is used (1.5 x its second mode), so
/// measured period shifts compare with the maps.
const PERIOD_LOWPASS_HZ: f64 = 40.0;
/// Peak low-pass cut-off over the period cut-off of a driveline with a model (3x its
/// second mode): the oscillation's peak passes (a 21 Hz mode loses 1% of its amplitude),
/// noise is cut to a quarter at 2 kHz, and the maps are analysed alike.
const PEAK_OVER_PERIOD_CUTOFF: f64 = 2.0;

/// How one driveline's bites are detected and analysed, from its configuration and
/// model: shared by the service, the wear references and gap maps (simulated bites
/// analysed like measured ones) and `millgate wear`.
#[derive(Debug, Clone, Copy)]
pub struct BiteSetup {
    /// The bite detector.
    pub detector: Detector,
    /// The transient analysis settings.
    pub transient: TransientSettings,
    /// Rise above the baseline that marks the load onset for the fit, kN*m.
    pub onset_knm: f64,
    /// Capture before the trigger, s.
    pub pre_trigger_s: f64,
}

impl BiteSetup {
    /// The setup of driveline `index` called `name` with capture settings `bite`,
    /// measured at `fs` Hz, whose samples saturate at or beyond `saturation_knm` (low,
    /// high; kN*m); with its `model` the analysis low-passes periods at 1.5x the
    /// model's second mode (the wear maps' cut-off) and the peak at twice that, so that
    /// noise does not raise the TAF the gap is estimated from.
    pub fn new(
        index: usize,
        name: &str,
        bite: &millgate_config::BiteSettings,
        fs: f64,
        saturation_knm: (f64, f64),
        model: Option<&Model>,
    ) -> Result<Self, AnalysisError> {
        let post_trigger_samples = (bite.post_trigger_s * fs).round() as usize;
        let pre_trigger_samples = (bite.pre_trigger_s * fs).round() as usize;
        if pre_trigger_samples > PRE_TRIGGER_CAPACITY
            || post_trigger_samples > WINDOW_CAPACITY - PRE_TRIGGER_CAPACITY
        {
            return Err(AnalysisError::BiteWindow {
                index,
                pre_trigger_s: bite.pre_trigger_s,
                post_trigger_s: bite.post_trigger_s,
                sample_rate_hz: fs,
                pre_samples: pre_trigger_samples,
                post_samples: post_trigger_samples,
            });
        }
        // The readers already turn saturated samples into gaps; the detector marks any
        // that reach it (a window with one is degraded, its values not published).
        let (low, high) = saturation_knm;
        let settings = BiteSettings {
            threshold_knm: bite.threshold_knm,
            rearm_knm: bite.threshold_knm / 2.0,
            holdoff_samples: post_trigger_samples as u32,
            // Baseline time constant 0.5 s: follows a drifting zero, not a bite.
            baseline_alpha: 1.0 / (0.5 * fs).max(1.0),
            saturation_low_knm: low.min(high),
            saturation_high_knm: low.max(high),
            post_trigger_samples,
        };
        let detector = Detector::new(settings)
            .map_err(|source| AnalysisError::BiteSettings { index, source })?;
        let mut transient = TransientSettings {
            sample_rate_hz: fs,
            period_lowpass_hz: PERIOD_LOWPASS_HZ.min(0.4 * fs),
            peak_lowpass_hz: None,
            settled_fraction: 0.3,
            min_static_knm: bite.threshold_knm / 2.0,
            reference_shift_s: None,
        };
        if let Some(model) = model {
            match millgate_sim::wear_map::default_period_lowpass_hz(model) {
                Ok(cutoff) if cutoff > 0.0 => {
                    transient.period_lowpass_hz = cutoff.min(0.4 * fs);
                    transient.peak_lowpass_hz =
                        Some((PEAK_OVER_PERIOD_CUTOFF * cutoff).min(0.4 * fs));
                }
                Ok(_) => {}
                Err(error) => tracing::warn!(
                    driveline = %name,
                    %error,
                    cutoff_hz = transient.period_lowpass_hz,
                    "no modes of the model: periods measured with the default cut-off"
                ),
            }
        }
        Ok(Self {
            detector,
            transient,
            onset_knm: 0.1 * bite.threshold_knm,
            pre_trigger_s: bite.pre_trigger_s,
        })
    }

    /// Bites of `model` simulated and analysed with this setup.
    pub fn simulator(&self, model: &Model) -> BiteSimulator {
        BiteSimulator::new(model, self.detector, self.transient, self.pre_trigger_s)
    }

    /// The setup of driveline `index` of the configuration, `driveline`, measured on
    /// `torque`, with its model when it has one.
    pub(super) fn of(
        index: usize,
        driveline: &Driveline,
        torque: &Channel,
        model: Option<&Model>,
    ) -> Result<Self, AnalysisError> {
        // The ends of the channel's raw range (field::quality, as the readers use).
        let limits = crate::field::quality::saturation_limits(torque);
        Self::new(
            index,
            &driveline.name,
            &driveline.bite,
            torque.sample_rate_hz,
            (limits.low, limits.high),
            model,
        )
    }
}

/// The driveline's model and what is built from it.
pub(super) struct ModelParts {
    /// The model.
    pub(super) model: Model,
    /// What its gap maps are built of.
    pub(super) spec: GapMapSpec,
}

impl ModelParts {
    /// The model of driveline `index` of the configuration, `driveline`, when it names
    /// one; a model that does not load or does not fit the `wear` settings is logged
    /// and returned as the problem that keeps the wear diagnosis off.
    pub(super) fn of(
        index: usize,
        driveline: &Driveline,
    ) -> (Option<ModelParts>, Option<AnalysisError>) {
        let parts = driveline
            .model
            .as_ref()
            .map(|path| Self::load(index, driveline, path));
        match parts {
            Some(Ok(parts)) => (Some(parts), None),
            Some(Err(problem)) => {
                tracing::error!(driveline = %driveline.name, %problem, "no wear diagnosis");
                (None, Some(problem))
            }
            None => (None, None),
        }
    }

    /// The model at `path` of driveline `index`, `driveline`, and its gap maps' spec.
    fn load(index: usize, driveline: &Driveline, path: &Path) -> Result<Self, AnalysisError> {
        let model = Model::load(path).map_err(|source| AnalysisError::Model { index, source })?;
        let spec = GapMapSpec::new(index, &driveline.wear, &model, driveline.bite.threshold_knm)
            .map_err(|source| AnalysisError::GapMaps {
                index,
                source: Box::new(source),
            })?;
        Ok(Self { model, spec })
    }
}

/// A driveline's wear diagnosis: the linear references, the gap monitor and the build
/// of its gap maps (until the service takes it).
pub(super) struct WearDiagnosis {
    /// The linear references.
    pub(super) wear: WearReference,
    /// The gap diagnosis.
    pub(super) gap: GapMonitor,
    /// The maps to build.
    pub(super) gap_job: GapMapJob,
}

impl WearDiagnosis {
    /// The diagnosis of driveline `index`, `driveline`, from its model `parts` (loaded
    /// from `path`) with `setup`, its gap maps cached in `cache_dir`.
    pub(super) fn new(
        index: usize,
        driveline: &Driveline,
        (parts, path): (ModelParts, &Path),
        setup: &BiteSetup,
        cache_dir: &Path,
    ) -> Result<Self, AnalysisError> {
        let gap = GapMonitor::new(&driveline.name, &driveline.thresholds, &driveline.wear)
            .map_err(|source| AnalysisError::WearTrend { index, source })?;
        let simulator = setup.simulator(&parts.model);
        let mut reference = WearReference::new(simulator.clone());
        // Simulate the model's own load level now: a model that cannot give a
        // reference is reported at start, not at the first bite.
        match reference.reference(parts.model.load.static_torque) {
            Ok(reference) => tracing::info!(
                driveline = %driveline.name,
                period_lowpass_hz = setup.transient.period_lowpass_hz,
                peak_lowpass_hz = ?setup.transient.peak_lowpass_hz,
                level_knm = reference.level_knm,
                reference_taf = reference.taf,
                reference_shift_s = ?reference.period_shift_s,
                "linear wear reference"
            ),
            Err(error) => tracing::warn!(
                driveline = %driveline.name,
                %error,
                "no linear wear reference at the model's load"
            ),
        }
        Ok(Self {
            wear: reference,
            gap,
            gap_job: GapMapJob::new(
                index,
                &driveline.name,
                path,
                simulator,
                parts.spec,
                cache_dir,
            ),
        })
    }
}
