//! Miner's rule with a Basquin S-N curve on the torque range of one component.
//!
//! Cycles to failure at a torque range `dM` (kN*m) of the component:
//! `N(dM) = ref_cycles * (ref_range_knm / dM)^m`. The component carries
//! `torque_share` of the measured torque (1 for the measured shaft; a spindle of a
//! twin drive carries about 0.5), so its range is `torque_share * dM_measured`.
//!
//! - **Endurance limit** (optional, `endurance_knm`, a component range): below it
//!   [`EnduranceRule::Cutoff`] counts no damage; [`EnduranceRule::Haibach`] continues
//!   the curve with the slope `2m - 1` from the knee (Haibach's modification, FKM
//!   guideline), so small cycles still count, less.
//! - **Mean-torque correction** (optional, default none): [`MeanCorrection::Goodman`]
//!   raises the range of a cycle with a positive mean to the equivalent fully reversed
//!   range `dM / (1 - mean / ultimate_knm)`; a mean at or above the ultimate torque
//!   counts the cycle as the whole life (N = 1). Negative means are not credited.
//! - **Damage** of a cycle of count `n` (1 closed, 0.5 half): `n / N(dM)`; Miner's sum
//!   over cycles is the consumed life (1 = the curve's failure).
//!
//! ```
//! use millgate_dsp::miner::{EnduranceRule, MeanCorrection, SnCurve, SnCurveSettings};
//! use millgate_dsp::rainflow::Cycle;
//! let curve = SnCurve::new(SnCurveSettings {
//!     m: 5.0, ref_cycles: 2e6, ref_range_knm: 100.0, torque_share: 1.0,
//!     endurance_knm: None, endurance_rule: EnduranceRule::Cutoff,
//!     mean_correction: MeanCorrection::None,
//! }).unwrap();
//! // At the reference range one cycle uses 1 / ref_cycles; twice the range, 2^5 times more.
//! let damage = curve.damage(&Cycle { range_knm: 200.0, mean_knm: 0.0, count: 1.0 });
//! assert!((damage - 32.0 / 2e6).abs() < 1e-18);
//! ```

use crate::rainflow::Cycle;

/// What happens below the endurance limit.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum EnduranceRule {
    /// No damage below the limit.
    Cutoff,
    /// The curve goes on with the slope `2m - 1` below the limit (Haibach).
    Haibach,
}

/// The mean-torque correction.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum MeanCorrection {
    /// None: the range alone (the default).
    None,
    /// Goodman: `dM_eq = dM / (1 - mean / ultimate_knm)` for a positive mean.
    Goodman {
        /// The component's ultimate (static failure) torque, kN*m, finite and > 0.
        ultimate_knm: f64,
    },
}

/// Settings of an [`SnCurve`]; torque in kN*m of the component.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SnCurveSettings {
    /// Basquin exponent, finite and > 0 (steel shafts in torsion: about 5 to 10).
    pub m: f64,
    /// Cycles to failure at `ref_range_knm`, finite and > 0.
    pub ref_cycles: f64,
    /// Reference torque range, kN*m, finite and > 0.
    pub ref_range_knm: f64,
    /// Share of the measured torque the component carries, finite and > 0.
    pub torque_share: f64,
    /// Endurance limit (component range), kN*m, finite and > 0, or none.
    pub endurance_knm: Option<f64>,
    /// What happens below `endurance_knm`.
    pub endurance_rule: EnduranceRule,
    /// The mean-torque correction.
    pub mean_correction: MeanCorrection,
}

/// The [`SnCurveSettings`] field that failed validation.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SnCurveError {
    /// `m` is not finite and > 0.
    M,
    /// `ref_cycles` is not finite and > 0.
    RefCycles,
    /// `ref_range_knm` is not finite and > 0.
    RefRangeKnm,
    /// `torque_share` is not finite and > 0.
    TorqueShare,
    /// `endurance_knm` is not finite and > 0.
    EnduranceKnm,
    /// The Goodman `ultimate_knm` is not finite and > 0.
    UltimateKnm,
}

impl core::fmt::Display for SnCurveError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            SnCurveError::M => "m must be finite and > 0",
            SnCurveError::RefCycles => "ref_cycles must be finite and > 0",
            SnCurveError::RefRangeKnm => "ref_range_knm must be finite and > 0 kN*m",
            SnCurveError::TorqueShare => "torque_share must be finite and > 0",
            SnCurveError::EnduranceKnm => "endurance_knm must be finite and > 0 kN*m",
            SnCurveError::UltimateKnm => "ultimate_knm must be finite and > 0 kN*m",
        })
    }
}

impl core::error::Error for SnCurveError {}

/// A validated S-N curve of one component.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SnCurve {
    settings: SnCurveSettings,
}

impl SnCurve {
    /// Validates `settings`.
    pub fn new(settings: SnCurveSettings) -> Result<Self, SnCurveError> {
        let positive = |v: f64| v.is_finite() && v > 0.0;
        if !positive(settings.m) {
            return Err(SnCurveError::M);
        }
        if !positive(settings.ref_cycles) {
            return Err(SnCurveError::RefCycles);
        }
        if !positive(settings.ref_range_knm) {
            return Err(SnCurveError::RefRangeKnm);
        }
        if !positive(settings.torque_share) {
            return Err(SnCurveError::TorqueShare);
        }
        if settings.endurance_knm.is_some_and(|e| !positive(e)) {
            return Err(SnCurveError::EnduranceKnm);
        }
        if let MeanCorrection::Goodman { ultimate_knm } = settings.mean_correction {
            if !positive(ultimate_knm) {
                return Err(SnCurveError::UltimateKnm);
            }
        }
        Ok(Self { settings })
    }

    /// The validated settings.
    pub fn settings(&self) -> &SnCurveSettings {
        &self.settings
    }

    /// Life fraction `1 / N(dM)` one closed cycle of the component's range
    /// `range_knm` consumes (0 for a range of 0, or below a cut-off endurance limit).
    pub fn damage_per_cycle(&self, range_knm: f64) -> f64 {
        let s = &self.settings;
        // NaN or <= 0: no damage.
        if range_knm.is_nan() || range_knm <= 0.0 {
            return 0.0;
        }
        let basquin = |range: f64| libm::pow(range / s.ref_range_knm, s.m) / s.ref_cycles;
        match s.endurance_knm {
            Some(limit) if range_knm < limit => match s.endurance_rule {
                EnduranceRule::Cutoff => 0.0,
                EnduranceRule::Haibach => {
                    basquin(limit) * libm::pow(range_knm / limit, 2.0 * s.m - 1.0)
                }
            },
            _ => basquin(range_knm),
        }
    }

    /// Damage of a counted cycle of the measured torque: `count / N` at the
    /// component's range (its share, mean-corrected).
    pub fn damage(&self, cycle: &Cycle) -> f64 {
        let s = &self.settings;
        let range = s.torque_share * cycle.range_knm;
        let mean = s.torque_share * cycle.mean_knm;
        let equivalent = match s.mean_correction {
            MeanCorrection::None => range,
            MeanCorrection::Goodman { ultimate_knm } if mean >= ultimate_knm => {
                return cycle.count;
            }
            MeanCorrection::Goodman { ultimate_knm } if mean > 0.0 => {
                range / (1.0 - mean / ultimate_knm)
            }
            MeanCorrection::Goodman { .. } => range,
        };
        cycle.count * libm::fmin(self.damage_per_cycle(equivalent), 1.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::assert_isclose;

    fn curve(endurance_knm: Option<f64>, rule: EnduranceRule) -> SnCurve {
        SnCurve::new(SnCurveSettings {
            m: 4.0,
            ref_cycles: 1e6,
            ref_range_knm: 100.0,
            torque_share: 0.5,
            endurance_knm,
            endurance_rule: rule,
            mean_correction: MeanCorrection::None,
        })
        .unwrap()
    }

    fn cycle(range_knm: f64, mean_knm: f64, count: f64) -> Cycle {
        Cycle {
            range_knm,
            mean_knm,
            count,
        }
    }

    #[test]
    fn basquin_on_the_components_share() {
        let c = curve(None, EnduranceRule::Cutoff);
        // 400 kN*m measured is 200 at the component: (200/100)^4 / 1e6.
        assert_isclose(c.damage(&cycle(400.0, 0.0, 1.0)), 16e-6, 1e-12, 0.0, "full");
        assert_isclose(c.damage(&cycle(400.0, 0.0, 0.5)), 8e-6, 1e-12, 0.0, "half");
        assert_eq!(c.damage(&cycle(0.0, 0.0, 1.0)), 0.0);
    }

    #[test]
    fn endurance_limit_cuts_off_or_bends_with_haibach() {
        let cut = curve(Some(50.0), EnduranceRule::Cutoff);
        let haibach = curve(Some(50.0), EnduranceRule::Haibach);
        // 80 measured = 40 at the component, below the 50 limit.
        assert_eq!(cut.damage(&cycle(80.0, 0.0, 1.0)), 0.0);
        let knee = libm::pow(0.5, 4.0) / 1e6;
        let expected = knee * libm::pow(40.0 / 50.0, 7.0);
        assert_isclose(
            haibach.damage(&cycle(80.0, 0.0, 1.0)),
            expected,
            1e-12,
            0.0,
            "haibach",
        );
        // Continuous at the knee, and Basquin above it for both.
        assert_isclose(
            haibach.damage(&cycle(100.0, 0.0, 1.0)),
            knee,
            1e-12,
            0.0,
            "knee",
        );
        assert_eq!(
            cut.damage(&cycle(300.0, 0.0, 1.0)),
            haibach.damage(&cycle(300.0, 0.0, 1.0))
        );
    }

    #[test]
    fn goodman_raises_positive_means_only() {
        let mut settings = *curve(None, EnduranceRule::Cutoff).settings();
        settings.torque_share = 1.0;
        settings.mean_correction = MeanCorrection::Goodman {
            ultimate_knm: 400.0,
        };
        let goodman = SnCurve::new(settings).unwrap();
        // Mean 200 of 400: the range counts double, 2^4 times the damage.
        let plain = goodman.damage_per_cycle(100.0);
        assert_isclose(
            goodman.damage(&cycle(100.0, 200.0, 1.0)),
            16.0 * plain,
            1e-12,
            0.0,
            "mean",
        );
        assert_eq!(goodman.damage(&cycle(100.0, -200.0, 1.0)), plain);
        assert_eq!(goodman.damage(&cycle(100.0, 500.0, 0.5)), 0.5);
    }

    #[test]
    fn non_positive_values_are_refused_by_name() {
        let good = *curve(None, EnduranceRule::Cutoff).settings();
        type Spoil = fn(&mut SnCurveSettings);
        let cases: [(Spoil, SnCurveError); 6] = [
            (|s| s.m = 0.0, SnCurveError::M),
            (|s| s.ref_cycles = -1.0, SnCurveError::RefCycles),
            (|s| s.ref_range_knm = f64::NAN, SnCurveError::RefRangeKnm),
            (|s| s.torque_share = 0.0, SnCurveError::TorqueShare),
            (|s| s.endurance_knm = Some(0.0), SnCurveError::EnduranceKnm),
            (
                |s| s.mean_correction = MeanCorrection::Goodman { ultimate_knm: -5.0 },
                SnCurveError::UltimateKnm,
            ),
        ];
        for (spoil, error) in cases {
            let mut settings = good;
            spoil(&mut settings);
            assert_eq!(SnCurve::new(settings), Err(error));
        }
    }
}
