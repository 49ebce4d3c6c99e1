//! A pass set up: its spans and sources with everything that does not depend on the
//! finishing speed, and the Mathieu point of a source at a speed.

use std::f64::consts::PI;
use std::sync::Arc;

use millgate_dsp::mathieu::{MAX_ABS_A, MAX_ABS_Q, MAX_DAMPING};
use serde::Serialize;

use super::sources::{Source, SourceSetup, SpanSetup};
use crate::rod::mill::RodMill;
use crate::rod::schedule::Pass;
use crate::rod::RodError;

/// A band of finishing speed to avoid, with the sources that make it unstable.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct AvoidBand {
    /// Lower edge, m/s.
    pub from_m_s: f64,
    /// Upper edge, m/s.
    pub to_m_s: f64,
    /// `span / mode / source` of every unstable point in it.
    pub sources: Vec<String>,
}

/// One pass, validated, with everything that does not depend on the finishing speed.
///
/// It shares the mill (`Arc`), so a long-lived task can keep the mill and the active
/// pass's setup side by side and rebuild only the setup when the pass changes.
#[derive(Debug, Clone)]
pub struct PassSetup {
    /// The mill this pass runs on.
    pub(crate) mill: Arc<RodMill>,
    /// The pass as given.
    pub pass: Pass,
    /// Index of its configuration in [`RodMill::configurations`].
    pub(crate) configuration: usize,
    /// The configuration's finishing-speed range, m/s.
    pub speed_range_m_s: (f64, f64),
    /// The pass's finishing speed, m/s.
    pub finishing_speed_m_s: f64,
    /// Young's modulus at the pass's temperature, Pa.
    pub(crate) modulus_pa: f64,
    /// Rod exit speed of each stand over the finishing speed.
    pub(crate) stand_shares: Vec<f64>,
    /// Every span.
    pub spans: Vec<SpanSetup>,
    /// Union of the sources' bands that end or start inside the speed range (a change
    /// of speed helps), ascending.
    pub avoid: Vec<AvoidBand>,
    /// `span / mode / source` of every point unstable over the whole speed range (a
    /// torsional source without the moving-rod term: no speed helps).
    pub(crate) unstable_at_every_speed: Vec<String>,
}

/// The Mathieu point of one source at one speed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct Operating {
    pub(super) a: f64,
    pub(super) q: f64,
    pub(super) c: f64,
    pub(super) theta_rad_s: f64,
    pub(super) f_rod_hz: f64,
}

impl PassSetup {
    /// Mathieu point of `source` in `span` at finishing speed `speed`.
    pub(super) fn operating(
        &self,
        span: &SpanSetup,
        source: &SourceSetup,
        speed: f64,
    ) -> Operating {
        let rod = &self.mill.rod;
        let axial = if rod.moving_rod {
            span.speed_share * speed
        } else {
            0.0
        };
        let omega_squared = span.beam.omega_squared(source.mode, axial);
        let theta_rad_s = match source.source {
            Source::Torsion { frequency_hz, .. } => 2.0 * PI * frequency_hz,
            Source::Eccentricity { stand, harmonic } => {
                2.0 * f64::from(harmonic) * self.stand_shares[stand] * speed
                    / self.mill.stands[stand].roll_diameter_m
            }
        };
        let theta_squared = theta_rad_s * theta_rad_s;
        let a = 4.0 * omega_squared / theta_squared;
        let q = span.beam.q_factor(source.mode) * source.pulsation_n / theta_squared;
        Operating {
            a,
            q,
            c: rod.damping_ratio * a.max(0.0).sqrt(),
            theta_rad_s,
            f_rod_hz: omega_squared.max(0.0).sqrt() / (2.0 * PI),
        }
    }

    /// Growth exponent per unit Mathieu time, `None` beyond the resolved range (there:
    /// a buckled rod, a < -1e4, counts as unstable, anything else as stable; see
    /// [`crate::rod::mill::MAX_EPSILON`]).
    pub(super) fn exponent(
        &self,
        point: &Operating,
        what: impl FnOnce() -> String,
    ) -> Result<Option<f64>, RodError> {
        let resolved = point.a.abs() <= MAX_ABS_A
            && point.q.abs() <= MAX_ABS_Q
            && point.c <= MAX_DAMPING
            && (point.a - point.c * point.c).abs() <= MAX_ABS_A;
        if !resolved {
            return Ok(None);
        }
        self.mill
            .mathieu
            .exponent(point.a, point.q, point.c)
            .map(Some)
            .map_err(|source| RodError::Mathieu {
                origin: self.pass.origin.clone(),
                what: what(),
                source,
            })
    }

    pub(super) fn unstable(
        &self,
        span: &SpanSetup,
        source: &SourceSetup,
        speed: f64,
    ) -> Result<bool, RodError> {
        let point = self.operating(span, source, speed);
        Ok(
            match self.exponent(&point, || self.describe(span, source))? {
                Some(exponent) => exponent > 0.0,
                None => point.a < 0.0,
            },
        )
    }

    pub(super) fn describe(&self, span: &SpanSetup, source: &SourceSetup) -> String {
        format!(
            "{} / mode {} / {}",
            self.mill.spans[span.span].name, source.mode, source.label
        )
    }
}
