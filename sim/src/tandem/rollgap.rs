//! Quasi-static roll gap of one cold-rolling pass: Hill's force formula with
//! Hitchcock's flattened roll radius, Bland and Ford's neutral point and forward slip,
//! and their partial derivatives by entry and exit thickness and back and front tension.
//!
//! ```text
//! F   = w k_eff sqrt(R' dh) Q_p                        (Hill)
//! Q_p = 1.08 + 1.79 r mu sqrt(1 - r) sqrt(R' / h) - 1.02 r,   r = dh / H
//! k_eff = k - (2 sigma_b + sigma_f) / 3
//! R'  = R [1 + 16 (1 - nu^2) F / (pi E_roll w dh)]     (Hitchcock, solved by iteration)
//! H(phi) = 2 sqrt(R'/h) atan(sqrt(R'/h) phi)           (Bland-Ford)
//! H_n = H(phi_1) / 2 + ln[(h / H) (1 - sigma_b / k) / (1 - sigma_f / k)] / (2 mu)
//! phi_n = sqrt(h / R') tan(H_n sqrt(h / R') / 2),   f = R' phi_n^2 / h,   x_n = R' phi_n
//! ```
//!
//! `phi_1 = sqrt(dh / R')` is the bite angle, `x_n` the horizontal distance from the
//! neutral point to the exit plane and `l = sqrt(R' dh)` the contact length. The
//! partial derivatives are central differences (the model is smooth and has no closed
//! form once the flattening iterates); steps of 1e-4 of the draft and of the flow stress
//! keep the truncation error near 1e-8 relative.

use std::f64::consts::PI;

/// One pass through one stand, SI units.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pass {
    /// Entry thickness H, m, > exit thickness.
    pub entry_m: f64,
    /// Exit thickness h, m, > 0.
    pub exit_m: f64,
    /// Back (entry) tension stress sigma_b, Pa, >= 0 and < flow stress.
    pub back_tension_pa: f64,
    /// Front (exit) tension stress sigma_f, Pa, >= 0 and < flow stress.
    pub front_tension_pa: f64,
    /// Mean flow stress k of the strip in the pass, Pa, > 0.
    pub flow_stress_pa: f64,
    /// Coulomb friction coefficient mu, > 0.
    pub friction: f64,
    /// Undeformed work-roll radius R, m, > 0.
    pub roll_radius_m: f64,
    /// Strip width w, m, > 0.
    pub width_m: f64,
    /// Young's modulus of the rolls, Pa, > 0 (Hitchcock).
    pub roll_modulus_pa: f64,
    /// Poisson's ratio of the rolls, in [0, 0.5).
    pub roll_poisson: f64,
}

/// The roll gap at one operating point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RollGap {
    /// Rolling force F, N.
    pub force_n: f64,
    /// Forward slip f: exit strip speed = roll speed (1 + f).
    pub forward_slip: f64,
    /// Hitchcock's flattened roll radius R', m.
    pub(crate) flattened_radius_m: f64,
    /// Contact length l = sqrt(R' dh), m.
    pub(crate) contact_length_m: f64,
    /// Neutral point to exit plane x_n = R' phi_n, m.
    pub(crate) neutral_point_m: f64,
}

/// Partial derivatives of force and forward slip, in the order entry thickness (per m),
/// exit thickness (per m), back tension (per Pa), front tension (per Pa).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GapPartials {
    /// dF/dH (N/m), dF/dh (N/m), dF/dsigma_b (N/Pa), dF/dsigma_f (N/Pa).
    pub force: [f64; 4],
    /// df/dH (1/m), df/dh (1/m), df/dsigma_b (1/Pa), df/dsigma_f (1/Pa).
    pub slip: [f64; 4],
}

/// Why a pass has no valid roll gap.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum RollGapError {
    /// Exit thickness not in (0, entry thickness).
    #[error("the exit thickness must be > 0 and below the entry thickness")]
    Reduction,
    /// The tensions leave no effective flow stress, or Hill's Q_p is not positive.
    #[error("the tensions leave no positive effective flow stress (k - (2 sigma_b + sigma_f) / 3 and Hill's Q_p must be > 0)")]
    EffectiveStress,
    /// Hitchcock's iteration did not converge.
    #[error("Hitchcock's flattened radius does not converge (force too large for the roll)")]
    Flattening,
    /// The neutral point falls outside the arc of contact.
    #[error("the neutral point falls outside the arc of contact (friction too low or tensions too unbalanced)")]
    NeutralPoint,
}

/// Largest Hitchcock iterations.
const FLATTENING_ITERATIONS: usize = 500;

/// The roll gap of `pass`.
///
/// # Example
/// ```
/// use millgate_sim::tandem::rollgap::{roll_gap, Pass};
/// // Lu et al. (2019), stand 1: 2.000 -> 1.269 mm, 55 / 140.6 MPa, mu 0.065, k 396 MPa.
/// let pass = Pass {
///     entry_m: 2.0e-3, exit_m: 1.269e-3, back_tension_pa: 55e6, front_tension_pa: 140.6e6,
///     flow_stress_pa: 396e6, friction: 0.065, roll_radius_m: 0.29, width_m: 1.25,
///     roll_modulus_pa: 210e9, roll_poisson: 0.3,
/// };
/// let gap = roll_gap(&pass)?;
/// assert!((7.5e6..8.5e6).contains(&gap.force_n));
/// # Ok::<(), millgate_sim::tandem::rollgap::RollGapError>(())
/// ```
pub fn roll_gap(pass: &Pass) -> Result<RollGap, RollGapError> {
    let (big_h, h) = (pass.entry_m, pass.exit_m);
    if !(h > 0.0 && h < big_h) {
        return Err(RollGapError::Reduction);
    }
    let draft = big_h - h;
    let reduction = draft / big_h;
    let k = pass.flow_stress_pa;
    let k_eff = k - (2.0 * pass.back_tension_pa + pass.front_tension_pa) / 3.0;
    if !(k_eff > 0.0 && pass.back_tension_pa < k && pass.front_tension_pa < k) {
        return Err(RollGapError::EffectiveStress);
    }
    let radius = pass.roll_radius_m;
    let hitchcock =
        16.0 * (1.0 - pass.roll_poisson * pass.roll_poisson) / (PI * pass.roll_modulus_pa);
    let force_at = |flattened: f64| -> Result<f64, RollGapError> {
        let q_p = 1.08
            + 1.79 * reduction * pass.friction * (1.0 - reduction).sqrt() * (flattened / h).sqrt()
            - 1.02 * reduction;
        if q_p > 0.0 {
            Ok(pass.width_m * k_eff * (flattened * draft).sqrt() * q_p)
        } else {
            Err(RollGapError::EffectiveStress)
        }
    };
    let mut flattened = radius;
    let mut converged = false;
    for _ in 0..FLATTENING_ITERATIONS {
        let next = radius * (1.0 + hitchcock * force_at(flattened)? / (pass.width_m * draft));
        let change = (next - flattened).abs();
        flattened = next;
        if !flattened.is_finite() {
            break;
        }
        if change <= 1e-15 * flattened {
            converged = true;
            break;
        }
    }
    if !converged {
        return Err(RollGapError::Flattening);
    }
    let force_n = force_at(flattened)?;

    let a = (flattened / h).sqrt();
    let bite_angle = (draft / flattened).sqrt();
    let h_bite = 2.0 * a * (a * bite_angle).atan();
    let tension_ratio = (1.0 - pass.back_tension_pa / k) / (1.0 - pass.front_tension_pa / k);
    let h_neutral = 0.5 * h_bite + (h / big_h * tension_ratio).ln() / (2.0 * pass.friction);
    let neutral_angle = (0.5 * h_neutral / a).tan() / a;
    if !(neutral_angle > 0.0 && neutral_angle < bite_angle) {
        return Err(RollGapError::NeutralPoint);
    }
    Ok(RollGap {
        force_n,
        forward_slip: flattened * neutral_angle * neutral_angle / h,
        flattened_radius_m: flattened,
        contact_length_m: (flattened * draft).sqrt(),
        neutral_point_m: flattened * neutral_angle,
    })
}

/// The roll gap of `pass` and its partial derivatives (central differences).
pub(crate) fn partials(pass: &Pass) -> Result<(RollGap, GapPartials), RollGapError> {
    let gap = roll_gap(pass)?;
    let thickness_step = 1e-4 * (pass.entry_m - pass.exit_m);
    let tension_step = 1e-4 * pass.flow_stress_pa;
    let mut result = GapPartials {
        force: [0.0; 4],
        slip: [0.0; 4],
    };
    for variable in 0..4 {
        let shifted = |sign: f64| {
            let mut p = *pass;
            match variable {
                0 => p.entry_m += sign * thickness_step,
                1 => p.exit_m += sign * thickness_step,
                2 => p.back_tension_pa += sign * tension_step,
                _ => p.front_tension_pa += sign * tension_step,
            }
            roll_gap(&p)
        };
        let step = if variable < 2 {
            thickness_step
        } else {
            tension_step
        };
        let (up, down) = (shifted(1.0)?, shifted(-1.0)?);
        result.force[variable] = (up.force_n - down.force_n) / (2.0 * step);
        result.slip[variable] = (up.forward_slip - down.forward_slip) / (2.0 * step);
    }
    Ok((gap, result))
}
