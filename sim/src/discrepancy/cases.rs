//! A seeded generator of "measured" records with one hidden effect, for testing the
//! workflow the way it is used: it only sees the CSV-like record and a model without
//! the effect (sometimes with the stiffness from drawings rather than the true one).

use crate::chain::simulate_with_noise;
use crate::model::{Model, ModelError};

use super::effects::Effect;
use super::Measured;

/// One test case: the truth, what the workflow is handed, and the hidden effect.
#[derive(Debug, Clone, PartialEq)]
pub struct HiddenCase {
    /// Short name for reports.
    pub name: String,
    /// The hidden effect, its location and size (parameter units), or `None`.
    pub hidden: Option<(Effect, Option<usize>, f64)>,
    /// Noise RMS added to the record, kN*m.
    pub noise_rms: f64,
    /// Seed of the noise.
    pub seed: u64,
    /// The true linear driveline.
    pub truth: Model,
    /// The model handed to the workflow (no effect; maybe other stiffness).
    pub handed: Model,
}

/// A generated record.
#[derive(Debug, Clone, PartialEq)]
pub struct Record {
    /// Sample times, s.
    pub t_s: Vec<f64>,
    /// Torque, kN*m.
    pub torque_knm: Vec<f64>,
    /// Sample rate, Hz.
    pub sample_rate_hz: f64,
}

impl Record {
    /// The record as the workflow's input.
    pub fn measured(&self) -> Measured<'_> {
        Measured {
            t0_s: self.t_s.first().copied().unwrap_or(0.0),
            sample_rate_hz: self.sample_rate_hz,
            torque_knm: &self.torque_knm,
        }
    }
}

impl HiddenCase {
    /// A case on `truth` with `hidden` added, handed `handed`.
    pub fn new(
        name: impl Into<String>,
        truth: &Model,
        handed: &Model,
        hidden: Option<(Effect, Option<usize>, f64)>,
        noise_rms: f64,
        seed: u64,
    ) -> HiddenCase {
        HiddenCase {
            name: name.into(),
            hidden,
            noise_rms,
            seed,
            truth: truth.clone(),
            handed: handed.clone(),
        }
    }

    /// Simulates the truth with the hidden effect and adds the seeded noise.
    pub fn record(&self) -> Result<Record, ModelError> {
        let model = match self.hidden {
            Some((effect, location, value)) => effect.apply(&self.truth, location, value)?,
            None => self.truth.clone(),
        };
        let transient = simulate_with_noise(&model, self.noise_rms, self.seed)?;
        Ok(Record {
            t_s: transient.t,
            torque_knm: transient.torque_knm,
            sample_rate_hz: model.measurement.sample_rate,
        })
    }
}
