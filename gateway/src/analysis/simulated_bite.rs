//! A driveline model's bite, simulated and analysed as a measured one.
//!
//! The linear wear references ([`super::wear`]) and the gap maps ([`super::gap_map`])
//! ask the same question: what would this driveline's torque channel show at a bite of
//! a given static torque, with a given opened gap in a given coupling? The answer comes
//! from the model's physics ([`millgate_sim::chain`]) and from the live path's own
//! code: the simulated torque runs through the driveline's bite detector (same
//! threshold, pre- and post-trigger lengths, baseline) and the same transient analysis
//! with the same settings (period and peak cut-offs, settled fraction) as the measured
//! samples ([`super::bite_window::window_transient`]).
//!
//! The model is simulated from rest with every coupling's backlash set to 0 except the
//! one asked for (a backlash in the model file is ignored: the maps vary it), the load
//! onset after an idle time long enough for the detector's baseline and pre-trigger
//! history, and the record long enough for the whole window at low static torques.

use std::fmt;

use millgate_dsp::bite::BiteSettings;
use millgate_dsp::transient::{TransientError, TransientResult, TransientSettings};
use millgate_sim::chain::simulate;
use millgate_sim::model::{Model, ModelError};

use super::bite_window::{window_transient, Detector};

/// Time simulated after the bite window, s: margin for the load rise to reach the
/// bite threshold at low static torques.
const RISE_MARGIN_S: f64 = 0.5;
/// Idle time simulated before the load onset beyond the pre-trigger window, s, so the
/// detector has a baseline and a full pre-trigger history, as on a real bar.
const IDLE_MARGIN_S: f64 = 0.05;

/// An opened gap in one coupling.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Gap {
    /// Coupling index (model order, motor side first).
    pub coupling: usize,
    /// Total dead-zone width, rad (the simulator's backlash), >= 0.
    pub width_rad: f64,
}

/// What was simulated, for messages: "the linear model" or "the model with a 2 mrad
/// gap in coupling 1".
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Simulated {
    /// Static torque of the load, kN*m.
    pub static_knm: f64,
    /// The gap, `None` for the linear model.
    pub gap: Option<Gap>,
}

impl fmt::Display for Simulated {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.gap {
            None => write!(f, "the linear model at {} kN*m", self.static_knm),
            Some(gap) => write!(
                f,
                "the model with a {} mrad gap in coupling {} at {} kN*m",
                gap.width_rad * 1e3,
                gap.coupling,
                self.static_knm
            ),
        }
    }
}

/// Why a simulated bite gives no transient measures.
#[derive(Debug, thiserror::Error)]
pub enum SimulatedBiteError {
    /// The model could not be simulated (an invalid value after the overrides, a tree
    /// driveline).
    #[error("simulating {what}: {source}")]
    Model {
        /// What was simulated.
        what: Simulated,
        /// What the simulator refused (boxed: the error stays small on the `Ok` path).
        #[source]
        source: Box<ModelError>,
    },
    /// The gap's coupling is not one of the model's.
    #[error("{what}: the model has {couplings} couplings (0 ..= {})", couplings.saturating_sub(1))]
    NoCoupling {
        /// What was asked for.
        what: Simulated,
        /// Couplings of the model.
        couplings: usize,
    },
    /// The simulated load never crossed the bite threshold, or the window was cut.
    #[error("{what} gives no bite window: the torque never rises above the bite threshold")]
    NoBite {
        /// What was simulated.
        what: Simulated,
    },
    /// The bite was detected but not analysable.
    #[error("{what} is not analysable: {source}")]
    Analysis {
        /// What was simulated.
        what: Simulated,
        /// Why the transient analysis refused the window.
        #[source]
        source: TransientError,
    },
    /// The bite has no TAF (static torque below the analysis minimum).
    #[error("{what} has no TAF: its static torque is below half the bite threshold")]
    NoTaf {
        /// What was simulated.
        what: Simulated,
    },
}

/// The transient measures of a simulated bite.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SimulatedBite {
    /// Peak / static torque (always measured: a bite without it is an error).
    pub taf: f64,
    /// Every measure, as for a measured bite.
    pub transient: TransientResult,
}

/// Bites of one driveline model, simulated and analysed like its measured ones.
#[derive(Debug, Clone)]
pub struct BiteSimulator {
    /// The model with every backlash 0 and the torque channel's sample rate.
    linear: Model,
    detector: Detector,
    transient: TransientSettings,
    /// Idle time before the load onset, s.
    onset_s: f64,
    /// Simulated record length, s.
    duration_s: f64,
}

impl BiteSimulator {
    /// Bites of `model` captured with `detector` (whose pre-trigger history is
    /// `pre_trigger_s`, s) and analysed with `transient` (whose sample rate becomes the
    /// simulation's). The detector's saturation limits are dropped: they are the
    /// channel's, and a simulated bite beyond them is still physics (a measured one
    /// there is marked degraded and not used).
    pub fn new(
        model: &Model,
        detector: Detector,
        transient: TransientSettings,
        pre_trigger_s: f64,
    ) -> Self {
        let unlimited = BiteSettings {
            saturation_low_knm: f64::NEG_INFINITY,
            saturation_high_knm: f64::INFINITY,
            ..*detector.settings()
        };
        // The same settings with wider limits: valid whenever the original were.
        let detector = Detector::new(unlimited).unwrap_or(detector);
        let mut linear = model.clone();
        for coupling in &mut linear.couplings {
            coupling.backlash = 0.0;
        }
        linear.measurement.sample_rate = transient.sample_rate_hz;
        let post_trigger_s =
            detector.settings().post_trigger_samples as f64 / transient.sample_rate_hz;
        let onset_s = pre_trigger_s + IDLE_MARGIN_S;
        Self {
            linear,
            detector,
            transient,
            onset_s,
            duration_s: onset_s + post_trigger_s + RISE_MARGIN_S,
        }
    }

    /// The model as simulated without a gap (every backlash 0, the channel's sample
    /// rate).
    pub fn linear_model(&self) -> &Model {
        &self.linear
    }

    /// The detector bites are captured with.
    pub fn detector(&self) -> &Detector {
        &self.detector
    }

    /// The transient analysis settings.
    pub fn transient(&self) -> &TransientSettings {
        &self.transient
    }

    /// Everything the simulated bites depend on, as text (for cache keys): the model as
    /// simulated (TOML), the detector and analysis settings, the idle and record
    /// lengths.
    pub fn describe(&self) -> Result<String, ModelError> {
        Ok(format!(
            "{}\ndetector {:?}\ntransient {:?}\nonset_s {:?} duration_s {:?}",
            self.linear.to_toml_string()?,
            self.detector.settings(),
            self.transient,
            self.onset_s,
            self.duration_s
        ))
    }

    /// The transient measures of a bite of static torque `static_knm` (kN*m, > 0) with
    /// `gap` opened (`None`: the linear model).
    pub fn bite(
        &self,
        static_knm: f64,
        gap: Option<Gap>,
    ) -> Result<SimulatedBite, SimulatedBiteError> {
        let what = Simulated { static_knm, gap };
        let mut model = self.linear.clone();
        model.load.static_torque = static_knm;
        model.load.onset = self.onset_s;
        model.measurement.duration = self.duration_s;
        if let Some(gap) = gap {
            let couplings = model.couplings.len();
            let coupling = model
                .couplings
                .get_mut(gap.coupling)
                .ok_or(SimulatedBiteError::NoCoupling { what, couplings })?;
            coupling.backlash = gap.width_rad;
        }
        let record = simulate(&model).map_err(|source| SimulatedBiteError::Model {
            what,
            source: Box::new(source),
        })?;
        let mut state = self.detector.state();
        let event = record
            .torque_knm
            .iter()
            .find_map(|&torque| self.detector.process(&mut state, torque))
            .filter(|event| event.quality.is_good())
            .ok_or(SimulatedBiteError::NoBite { what })?;
        let transient = window_transient(
            &event.window,
            event.trigger_index,
            event.baseline_knm,
            &self.transient,
        )
        .map_err(|source| SimulatedBiteError::Analysis { what, source })?;
        let taf = transient.taf.ok_or(SimulatedBiteError::NoTaf { what })?;
        Ok(SimulatedBite { taf, transient })
    }
}
