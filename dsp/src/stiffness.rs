//! Stiffness adjustment of the three-mass reduced driveline (paper eq. 2).
//!
//! Masses Q1 (motor side), Q2 (gear/pinion), Q3 (rolls), in kg*m^2, referred to roll
//! speed; couplings C12 and C23 in N*m/rad. [`forward`] gives the two non-zero natural
//! frequencies beta1 < beta2 (Hz) of the free chain; [`inverse`] finds every positive
//! (C12, C23) that reproduces measured beta1, beta2 for trusted inertias.
//!
//! The inverse uses the invariants of the free chain (w = 2 pi beta):
//! `w1^2 + w2^2 = C12 (1/Q1 + 1/Q2) + C23 (1/Q2 + 1/Q3)` and
//! `w1^2 w2^2 = C12 C23 (Q1 + Q2 + Q3) / (Q1 Q2 Q3)`, which eliminate C23 and leave a
//! quadratic in C12 with up to two positive roots.

use core::f64::consts::PI;
use heapless::Vec;

/// Moments of inertia of the three masses, kg*m^2, each finite and > 0.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Inertias {
    /// Motor-side mass Q1, kg*m^2.
    pub q1_kgm2: f64,
    /// Gear/pinion mass Q2, kg*m^2.
    pub q2_kgm2: f64,
    /// Roll mass Q3, kg*m^2.
    pub q3_kgm2: f64,
}

/// Coupling stiffnesses, N*m/rad, each finite and > 0.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Stiffness {
    /// Stiffness C12 between masses 1 and 2, N*m/rad.
    pub c12_nm_per_rad: f64,
    /// Stiffness C23 between masses 2 and 3, N*m/rad.
    pub c23_nm_per_rad: f64,
}

/// The two non-zero natural frequencies of the chain, Hz, `0 < beta1 < beta2`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NaturalFrequencies {
    /// First natural frequency, Hz.
    pub beta1_hz: f64,
    /// Second natural frequency, Hz.
    pub beta2_hz: f64,
}

/// Invalid input to [`forward`] or [`inverse`]; the variant names the field at fault.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum StiffnessError {
    /// `q1_kgm2` is not finite and > 0.
    Q1,
    /// `q2_kgm2` is not finite and > 0.
    Q2,
    /// `q3_kgm2` is not finite and > 0.
    Q3,
    /// `c12_nm_per_rad` is not finite and > 0.
    C12,
    /// `c23_nm_per_rad` is not finite and > 0.
    C23,
    /// `beta1_hz` is not finite and > 0.
    Beta1,
    /// `beta2_hz` is not finite or not greater than `beta1_hz`.
    Beta2,
    /// The drawing stiffness used to rank the roots is not finite and > 0.
    Drawing,
}

impl core::fmt::Display for StiffnessError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            StiffnessError::Q1 => "inertia Q1 (q1_kgm2) must be finite and > 0 kg*m^2",
            StiffnessError::Q2 => "inertia Q2 (q2_kgm2) must be finite and > 0 kg*m^2",
            StiffnessError::Q3 => "inertia Q3 (q3_kgm2) must be finite and > 0 kg*m^2",
            StiffnessError::C12 => "stiffness C12 (c12_nm_per_rad) must be finite and > 0 N*m/rad",
            StiffnessError::C23 => "stiffness C23 (c23_nm_per_rad) must be finite and > 0 N*m/rad",
            StiffnessError::Beta1 => "frequency beta1_hz must be finite and > 0 Hz",
            StiffnessError::Beta2 => "frequency beta2_hz must be finite and greater than beta1_hz",
            StiffnessError::Drawing => "the drawing stiffness must be finite and > 0 N*m/rad",
        })
    }
}

impl core::error::Error for StiffnessError {}

fn positive(value: f64, error: StiffnessError) -> Result<f64, StiffnessError> {
    if value.is_finite() && value > 0.0 {
        Ok(value)
    } else {
        Err(error)
    }
}

fn check_inertias(q: &Inertias) -> Result<(f64, f64, f64), StiffnessError> {
    Ok((
        positive(q.q1_kgm2, StiffnessError::Q1)?,
        positive(q.q2_kgm2, StiffnessError::Q2)?,
        positive(q.q3_kgm2, StiffnessError::Q3)?,
    ))
}

/// Natural frequencies beta1 < beta2 (Hz) of the free three-mass chain, paper eq. (2).
///
/// All inputs must be finite and > 0 (SI units); the result is finite for any
/// accepted input that does not overflow, otherwise the overflowing field is named.
///
/// ```
/// use millgate_dsp::stiffness::{forward, Inertias, Stiffness};
/// let q = Inertias { q1_kgm2: 46.70e3, q2_kgm2: 11.85e3, q3_kgm2: 2.48e3 };
/// let c = Stiffness { c12_nm_per_rad: 214.10e6, c23_nm_per_rad: 30.68e6 };
/// let beta = forward(&q, &c).unwrap();
/// assert!((beta.beta1_hz - 16.66).abs() < 0.01);
/// assert!((beta.beta2_hz - 25.98).abs() < 0.01);
/// ```
pub fn forward(q: &Inertias, c: &Stiffness) -> Result<NaturalFrequencies, StiffnessError> {
    let (q1, q2, q3) = check_inertias(q)?;
    let c12 = positive(c.c12_nm_per_rad, StiffnessError::C12)?;
    let c23 = positive(c.c23_nm_per_rad, StiffnessError::C23)?;
    let ratio = c12 / c23;
    let d = libm::sqrt(c23 / q2);
    let e = (q1 + q2) / (2.0 * q1);
    let f = (q2 + q3) / (2.0 * q3);
    let a = f + e * ratio;
    let b = libm::sqrt((f - e * ratio) * (f - e * ratio) + ratio);
    // a - b = 2 C23 Q2 w1^2 w2^2 / (...) > 0 analytically; clamp rounding below zero.
    let beta1_hz = d * libm::sqrt((a - b).max(0.0)) / (2.0 * PI);
    let beta2_hz = d * libm::sqrt(a + b) / (2.0 * PI);
    if !beta1_hz.is_finite() {
        return Err(StiffnessError::C12);
    }
    if !beta2_hz.is_finite() {
        return Err(StiffnessError::C23);
    }
    Ok(NaturalFrequencies { beta1_hz, beta2_hz })
}

/// Every positive (C12, C23) giving the measured beta1 < beta2 (Hz) for inertias `q`.
///
/// Returns zero, one or two solutions. With `drawing` given (finite, > 0), the solution
/// nearest to it (sum of squared relative differences) comes first; otherwise they are
/// ordered by increasing C12. An empty result means no real positive stiffness fits.
///
/// ```
/// use millgate_dsp::stiffness::{inverse, Inertias, NaturalFrequencies};
/// let q = Inertias { q1_kgm2: 46.70e3, q2_kgm2: 11.85e3, q3_kgm2: 2.48e3 };
/// let beta = NaturalFrequencies { beta1_hz: 12.03, beta2_hz: 21.09 };
/// let roots = inverse(&q, &beta, None).unwrap();
/// assert!(roots.iter().any(|c| (c.c12_nm_per_rad / 68.77e6 - 1.0).abs() < 0.005));
/// ```
pub fn inverse(
    q: &Inertias,
    beta: &NaturalFrequencies,
    drawing: Option<&Stiffness>,
) -> Result<Vec<Stiffness, 2>, StiffnessError> {
    let (q1, q2, q3) = check_inertias(q)?;
    let beta1 = positive(beta.beta1_hz, StiffnessError::Beta1)?;
    let beta2 = positive(beta.beta2_hz, StiffnessError::Beta2)?;
    if beta2 <= beta1 {
        return Err(StiffnessError::Beta2);
    }
    if let Some(d) = drawing {
        positive(d.c12_nm_per_rad, StiffnessError::Drawing)?;
        positive(d.c23_nm_per_rad, StiffnessError::Drawing)?;
    }
    let w1_sq = (2.0 * PI * beta1) * (2.0 * PI * beta1);
    let w2_sq = (2.0 * PI * beta2) * (2.0 * PI * beta2);
    let sum = w1_sq + w2_sq;
    let product = w1_sq * w2_sq;
    let a = 1.0 / q1 + 1.0 / q2;
    let b = 1.0 / q2 + 1.0 / q3;
    let g = (q1 + q2 + q3) / (q1 * q2 * q3);
    // C23 = (sum - a C12) / b and C12 C23 g = product
    // => a g C12^2 - sum g C12 + product b = 0.
    let qa = a * g;
    let qb = -sum * g;
    let qc = product * b;
    let discriminant = qb * qb - 4.0 * qa * qc;
    let mut roots: Vec<Stiffness, 2> = Vec::new();
    if !discriminant.is_finite() || discriminant < 0.0 {
        return Ok(roots);
    }
    let sqrt_disc = libm::sqrt(discriminant);
    // Numerically stable pair of roots: q = -(qb + sign(qb) sqrt) / 2; x1 = q/qa, x2 = qc/q.
    let half = -0.5 * (qb - sqrt_disc); // qb < 0, so this adds magnitudes
    let candidates = [qc / half, half / qa];
    for (index, &c12) in candidates.iter().enumerate() {
        if index == 1 && discriminant == 0.0 {
            break;
        }
        let c23 = (sum - a * c12) / b;
        if c12.is_finite() && c23.is_finite() && c12 > 0.0 && c23 > 0.0 {
            // Capacity is 2 and at most two candidates exist.
            let _ = roots.push(Stiffness {
                c12_nm_per_rad: c12,
                c23_nm_per_rad: c23,
            });
        }
    }
    match drawing {
        Some(d) => {
            let distance = |s: &Stiffness| {
                let r12 = s.c12_nm_per_rad / d.c12_nm_per_rad - 1.0;
                let r23 = s.c23_nm_per_rad / d.c23_nm_per_rad - 1.0;
                r12 * r12 + r23 * r23
            };
            roots.sort_unstable_by(|x, y| distance(x).total_cmp(&distance(y)));
        }
        None => roots.sort_unstable_by(|x, y| x.c12_nm_per_rad.total_cmp(&y.c12_nm_per_rad)),
    }
    Ok(roots)
}

#[cfg(test)]
mod tests {
    use super::*;

    const Q: Inertias = Inertias {
        q1_kgm2: 46.70e3,
        q2_kgm2: 11.85e3,
        q3_kgm2: 2.48e3,
    };

    /// Eigenfrequencies from the invariants, independent of the closed form.
    fn invariants(q: &Inertias, c: &Stiffness) -> (f64, f64) {
        let sum = c.c12_nm_per_rad * (1.0 / q.q1_kgm2 + 1.0 / q.q2_kgm2)
            + c.c23_nm_per_rad * (1.0 / q.q2_kgm2 + 1.0 / q.q3_kgm2);
        let product = c.c12_nm_per_rad * c.c23_nm_per_rad * (q.q1_kgm2 + q.q2_kgm2 + q.q3_kgm2)
            / (q.q1_kgm2 * q.q2_kgm2 * q.q3_kgm2);
        (sum, product)
    }

    #[test]
    fn forward_matches_chain_invariants() {
        let c = Stiffness {
            c12_nm_per_rad: 100e6,
            c23_nm_per_rad: 50e6,
        };
        let beta = forward(&Q, &c).unwrap();
        let w1 = 2.0 * PI * beta.beta1_hz;
        let w2 = 2.0 * PI * beta.beta2_hz;
        let (sum, product) = invariants(&Q, &c);
        assert!(((w1 * w1 + w2 * w2) / sum - 1.0).abs() < 1e-12);
        assert!(((w1 * w1 * w2 * w2) / product - 1.0).abs() < 1e-12);
    }

    #[test]
    fn inverse_round_trips_forward() {
        let c = Stiffness {
            c12_nm_per_rad: 150e6,
            c23_nm_per_rad: 20e6,
        };
        let beta = forward(&Q, &c).unwrap();
        let roots = inverse(&Q, &beta, Some(&c)).unwrap();
        let first = roots[0];
        assert!((first.c12_nm_per_rad / c.c12_nm_per_rad - 1.0).abs() < 1e-9);
        assert!((first.c23_nm_per_rad / c.c23_nm_per_rad - 1.0).abs() < 1e-9);
        for root in &roots {
            let back = forward(&Q, root).unwrap();
            assert!((back.beta1_hz - beta.beta1_hz).abs() < 1e-9);
            assert!((back.beta2_hz - beta.beta2_hz).abs() < 1e-9);
        }
    }

    #[test]
    fn invalid_fields_are_named() {
        let bad_q = Inertias { q2_kgm2: -1.0, ..Q };
        let c = Stiffness {
            c12_nm_per_rad: 1e6,
            c23_nm_per_rad: f64::NAN,
        };
        assert_eq!(forward(&bad_q, &c), Err(StiffnessError::Q2));
        assert_eq!(forward(&Q, &c), Err(StiffnessError::C23));
        let swapped = NaturalFrequencies {
            beta1_hz: 20.0,
            beta2_hz: 10.0,
        };
        assert_eq!(inverse(&Q, &swapped, None), Err(StiffnessError::Beta2));
    }

    #[test]
    fn too_close_frequencies_have_no_root() {
        // beta2/beta1 barely above 1 is impossible for this inertia split.
        let beta = NaturalFrequencies {
            beta1_hz: 20.0,
            beta2_hz: 20.001,
        };
        assert!(inverse(&Q, &beta, None).unwrap().is_empty());
    }
}
