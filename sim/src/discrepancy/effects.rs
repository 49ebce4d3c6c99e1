//! The candidate effects a calibrated linear model may lack, each a model extension
//! with one bounded parameter at one location.

use crate::model::{Model, ModelError};

/// A physical effect the workflow can add to a model.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Effect {
    /// An opened gap (dead zone) in coupling i: `width_rad`, rad.
    Backlash,
    /// A first-order lag of the sensor or telemetry on the measured channel: `tau_s`, s.
    SensorLag,
    /// Cubic stiffness hardening in coupling i: `k3_nm_per_rad3`, N*m/rad^3.
    Hardening,
    /// An unmodelled inertia in the middle of coupling i: `inertia_kgm2`, kg*m^2.
    ExtraInertia,
    /// Amplitude-dependent (Coulomb-like) friction in coupling i: `friction_knm`, kN*m.
    CoulombDamping,
}

keyed!(Effect);

impl Effect {
    /// Every effect, in the order the search tries them.
    pub(crate) const ALL: [Effect; 5] = [
        Effect::Backlash,
        Effect::SensorLag,
        Effect::Hardening,
        Effect::ExtraInertia,
        Effect::CoulombDamping,
    ];

    /// The name used in JSON and on the command line.
    pub fn key(self) -> &'static str {
        match self {
            Effect::Backlash => "backlash",
            Effect::SensorLag => "sensor_lag",
            Effect::Hardening => "hardening",
            Effect::ExtraInertia => "extra_inertia",
            Effect::CoulombDamping => "coulomb_damping",
        }
    }

    /// JSON key of the effect's parameter (its unit is in the key).
    pub(crate) fn parameter_key(self) -> &'static str {
        match self {
            Effect::Backlash => "width_rad",
            Effect::SensorLag => "tau_s",
            Effect::Hardening => "k3_nm_per_rad3",
            Effect::ExtraInertia => "inertia_kgm2",
            Effect::CoulombDamping => "friction_knm",
        }
    }

    /// Whether the model with the effect is still linear (an extra inertia, a sensor
    /// lag): such an effect stays in the calibrated linear model, the others (what wear
    /// changes: a gap, hardening, friction) are removed from it.
    pub(crate) fn is_linear(self) -> bool {
        matches!(self, Effect::SensorLag | Effect::ExtraInertia)
    }

    /// Whether the effect sits in a coupling (otherwise it has no location).
    pub(crate) fn per_coupling(self) -> bool {
        !matches!(self, Effect::SensorLag)
    }

    /// The locations to try in `model`: every coupling, or the single `None`.
    pub(crate) fn locations(self, model: &Model) -> Vec<Option<usize>> {
        if self.per_coupling() {
            (0..model.couplings.len()).map(Some).collect()
        } else {
            vec![None]
        }
    }

    /// The plausible range `(low, high)` of the parameter in `model` at `location`, and
    /// a few starting values spread over it (log-spaced).
    ///
    /// Sizes are relative to the driveline so the same search fits any mill: the static
    /// twist `e = M / C` of the coupling at the model's static load for gaps and
    /// hardening, the static load for friction, the smaller neighbouring inertia for an
    /// extra inertia, the first oscillation period `T1` for the lag. A gap is allowed up
    /// to 8 static twists: at a low static torque a worn coupling's gap can be several
    /// times its twist.
    pub(crate) fn range(
        self,
        model: &Model,
        location: Option<usize>,
        first_period_s: f64,
    ) -> Range {
        let static_nm = model.load.static_torque * 1.0e3;
        let coupling = location.and_then(|i| model.couplings.get(i));
        let static_twist = coupling.map_or(0.0, |c| static_nm / c.stiffness);
        let (low, high) = match self {
            Effect::Backlash => (1.0e-3 * static_twist, 8.0 * static_twist),
            Effect::SensorLag => (2.0e-3 * first_period_s, 0.3 * first_period_s),
            Effect::Hardening => {
                let stiffness = coupling.map_or(0.0, |c| c.stiffness);
                let per_twist_sq = stiffness / (static_twist * static_twist);
                (1.0e-3 * per_twist_sq, 3.0 * per_twist_sq)
            }
            Effect::ExtraInertia => {
                let neighbours = location.map_or(0.0, |i| {
                    model.masses[i].inertia.min(model.masses[i + 1].inertia)
                });
                (3.0e-3 * neighbours, 3.0 * neighbours)
            }
            Effect::CoulombDamping => (
                1.0e-4 * model.load.static_torque,
                0.1 * model.load.static_torque,
            ),
        };
        Range { low, high }
    }

    /// `model` with this effect of size `value` (parameter units) at `location`.
    pub(crate) fn apply(
        self,
        model: &Model,
        location: Option<usize>,
        value: f64,
    ) -> Result<Model, ModelError> {
        let mut extended = model.clone();
        let coupling = location.unwrap_or(model.measurement.coupling);
        match self {
            Effect::Backlash => extended.couplings[coupling].backlash = value,
            Effect::SensorLag => extended.measurement.lag = value,
            Effect::Hardening => extended.couplings[coupling].hardening = value,
            Effect::ExtraInertia => return model.split_coupling(coupling, value),
            Effect::CoulombDamping => extended.couplings[coupling].friction = value * 1.0e3,
        }
        extended.validate("<extended model>")?;
        Ok(extended)
    }
}

/// Allowed values of an effect parameter, `low < high`, both > 0.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Range {
    /// Smallest value, parameter units.
    pub(crate) low: f64,
    /// Largest value, parameter units.
    pub(crate) high: f64,
}

impl Range {
    /// `count` log-spaced values strictly inside the range.
    pub(crate) fn starts(&self, count: usize) -> Vec<f64> {
        let ratio = self.high / self.low;
        (0..count)
            .map(|k| self.low * ratio.powf((k as f64 + 0.5) / count as f64))
            .collect()
    }

    /// The unbounded coordinate of `value`: the logit of its position between
    /// `ln(low)` and `ln(high)` (values outside are taken 1e-9 inside the ends).
    pub(crate) fn unsquash(&self, value: f64) -> f64 {
        let position =
            ((value / self.low).ln() / (self.high / self.low).ln()).clamp(1.0e-9, 1.0 - 1.0e-9);
        (position / (1.0 - position)).ln()
    }

    /// The value at unbounded coordinate `q`: always strictly inside the range.
    pub(crate) fn squash(&self, q: f64) -> f64 {
        let position = 1.0 / (1.0 + (-q).exp());
        self.low * (self.high / self.low).powf(position)
    }
}

#[cfg(test)]
mod tests {
    use super::Range;

    #[test]
    fn squash_inverts_unsquash_and_stays_inside() {
        let range = Range {
            low: 1.0e-5,
            high: 1.0e-2,
        };
        for value in [2.0e-5, 1.0e-4, 3.3e-3, 9.0e-3] {
            let back = range.squash(range.unsquash(value));
            assert!((back / value - 1.0).abs() < 1e-9, "{value} -> {back}");
        }
        for q in [-50.0, 50.0] {
            let value = range.squash(q);
            assert!(value >= range.low && value <= range.high, "{value}");
        }
    }
}
