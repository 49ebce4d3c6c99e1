//! The rod between two stands as a beam under axial tension: bending frequencies, the
//! Euler load and the Mathieu parameters of a pulsating tension (domain notes 3).
//!
//! `EI y'''' - T(t) y'' + rho A y_tt = 0`, `T(t) = T0 + P cos(Theta t)`, reduced per
//! mode `m` by a one-mode Galerkin projection on the span's beam mode `phi_m`:
//!
//! - `omega_m^2 = (beta_m^4 EI / L^4 + g_m T / L^2) / (rho A)`,
//! - `a = 4 omega_m^2 / Theta^2`, `q = 2 g_m P / (L^2 rho A Theta^2)`, time
//!   `tau = Theta t / 2`, damping `c = zeta sqrt(a)` (modal damping ratio zeta),
//!
//! with `beta_m L` the beam's eigenvalue and `g_m = L^2 int phi'^2 / int phi^2` its
//! tension factor. Pinned ends: `beta_m L = g_m^(1/2) = m pi` (exact: sine modes).
//! Clamped ends: `cos(beta L) cosh(beta L) = 1` and `g_m` from the clamped-clamped
//! modes (mode 1: 500.56 and 12.303, the notes' figures); the projection ignores the
//! tension's coupling of clamped modes of equal symmetry.
//!
//! The moving rod (optional): the axial speed `V` adds `rho A (2 V y_xt + V^2 y_xx)`;
//! its `V^2` part lowers the effective tension to `T0 - rho A V^2` (kept); the
//! gyroscopic `2 V y_xt` part is left out, as the notes do. The critical speed, where
//! the first mode's frequency reaches 0, is `V_crit = sqrt((P_E + T0) / (rho A))` with
//! the Euler load `P_E = beta_1^4 EI / (g_1 L^2)` (pinned: `pi^2 EI / L^2`; clamped:
//! `40.69 EI / L^2`, the one-mode value of `4 pi^2 = 39.48`); for `T0 = 0` and pinned
//! ends `V_crit = 2 L f_1`.

use std::f64::consts::PI;

use serde::{Deserialize, Serialize};

/// How the rod is held at both ends of a span.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Ends {
    /// Free to rotate (simply supported): sine modes.
    Pinned,
    /// Held in angle by the roll passes: clamped-clamped beam modes.
    Clamped,
}

/// Clamped-clamped beam: `beta_m L` (roots of `cos x cosh x = 1`) and the tension
/// factor `g_m = L^2 int phi'^2 / int phi^2`, modes 1..=10 (mpmath, 15 digits; the test
/// `clamped_constants_match_the_mode_shapes` recomputes them).
const CLAMPED: [(f64, f64); 10] = [
    (4.730_040_744_862_7, 12.302_618_623),
    (7.853_204_624_095_8, 46.050_120_143_5),
    (10.995_607_838_001_7, 98.904_801_402_5),
    (14.137_165_491_257_5, 171.585_655_702),
    (17.278_759_657_399_5, 263.997_980_736),
    (20.420_352_245_626_1, 376.150_083_492),
    (23.561_944_902_040_5, 508.041_357_638),
    (26.703_537_555_508_2, 659.671_842_874),
    (29.845_130_209_103_3, 831.041_536_78),
    (32.986_722_862_692_8, 1_022.150_439_49),
];

/// Largest bending mode handled per span.
pub(crate) const MAX_MODES: usize = CLAMPED.len();

/// A rod span with one pass's section and modulus.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Beam {
    /// Span length between the roll gaps, m, > 0.
    pub length_m: f64,
    /// Rod diameter in the span (exit of the upstream stand), m, > 0.
    pub diameter_m: f64,
    /// Density, kg/m^3, > 0.
    pub density_kg_m3: f64,
    /// Young's modulus at the rod's temperature, Pa, > 0.
    pub modulus_pa: f64,
    /// Setup tension T0, N, >= 0.
    pub tension_n: f64,
    /// End conditions.
    pub ends: Ends,
}

impl Beam {
    /// Mass per unit length rho A, kg/m.
    pub fn mass_per_length(&self) -> f64 {
        self.density_kg_m3 * PI * self.diameter_m * self.diameter_m / 4.0
    }

    /// Bending stiffness EI, N*m^2.
    pub(crate) fn bending_stiffness(&self) -> f64 {
        self.modulus_pa * PI * self.diameter_m.powi(4) / 64.0
    }

    /// `(beta_m L, g_m)` of mode `m` (1..=10).
    pub(crate) fn mode_constants(&self, mode: usize) -> (f64, f64) {
        match self.ends {
            Ends::Pinned => {
                let x = mode as f64 * PI;
                (x, x * x)
            }
            Ends::Clamped => CLAMPED[mode - 1],
        }
    }

    /// Euler load `P_E = beta_1^4 EI / (g_1 L^2)`, N (module docs).
    pub(crate) fn euler_load_n(&self) -> f64 {
        let (beta, g) = self.mode_constants(1);
        beta.powi(4) * self.bending_stiffness() / (g * self.length_m * self.length_m)
    }

    /// Critical axial speed `sqrt((P_E + T0) / (rho A))`, m/s.
    pub(crate) fn critical_speed_m_s(&self) -> f64 {
        ((self.euler_load_n() + self.tension_n) / self.mass_per_length()).sqrt()
    }

    /// `omega_m^2` (rad^2/s^2) at axial rod speed `speed_m_s` (0 without the moving-rod
    /// term); <= 0 when the effective tension buckles the mode.
    pub(crate) fn omega_squared(&self, mode: usize, speed_m_s: f64) -> f64 {
        let (beta, g) = self.mode_constants(mode);
        let l2 = self.length_m * self.length_m;
        let mass = self.mass_per_length();
        let tension = self.tension_n - mass * speed_m_s * speed_m_s;
        (beta.powi(4) * self.bending_stiffness() / (l2 * l2) + g * tension / l2) / mass
    }

    /// Natural frequency of mode `m`, Hz (0 when buckled), at axial speed `speed_m_s`.
    pub fn frequency_hz(&self, mode: usize, speed_m_s: f64) -> f64 {
        self.omega_squared(mode, speed_m_s).max(0.0).sqrt() / (2.0 * PI)
    }

    /// `q` per unit `P / Theta^2`: `2 g_m / (L^2 rho A)`, so `q = this * P / Theta^2`.
    pub(crate) fn q_factor(&self, mode: usize) -> f64 {
        let (_, g) = self.mode_constants(mode);
        2.0 * g / (self.length_m * self.length_m * self.mass_per_length())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Clamped-clamped mode shape and its slope at x (L = 1): `cosh bx - cos bx -
    /// s (sinh bx - sin bx)`, with `s = (cosh b - cos b) / (sinh b - sin b)`. The
    /// hyperbolic parts are written with `1 - s` (computed without cancellation) so
    /// that high modes (cosh b ~ 1e14) keep their digits.
    fn clamped_shape(beta: f64, x: f64) -> (f64, f64) {
        let one_minus_s = (beta.cos() - beta.sin() - (-beta).exp()) / (beta.sinh() - beta.sin());
        let one_plus_s = 2.0 - one_minus_s;
        let bx = beta * x;
        let (grow, decay) = (0.5 * one_minus_s * bx.exp(), 0.5 * one_plus_s * (-bx).exp());
        // cosh - s sinh = grow + decay; sinh - s cosh = grow - decay.
        (
            grow + decay - bx.cos() + (1.0 - one_minus_s) * bx.sin(),
            beta * (grow - decay + bx.sin() + (1.0 - one_minus_s) * bx.cos()),
        )
    }

    #[test]
    fn clamped_constants_match_the_mode_shapes() {
        for (beta, g) in CLAMPED {
            assert!((beta.cos() * beta.cosh() - 1.0).abs() < 1e-9 * beta.cosh());
            // Simpson's rule on 2000 intervals.
            let n = 2000;
            let (mut slope, mut shape) = (0.0, 0.0);
            for i in 0..=n {
                let weight = if i == 0 || i == n {
                    1.0
                } else if i % 2 == 1 {
                    4.0
                } else {
                    2.0
                };
                let (phi, dphi) = clamped_shape(beta, i as f64 / n as f64);
                slope += weight * dphi * dphi;
                shape += weight * phi * phi;
            }
            assert!(
                (slope / shape / g - 1.0).abs() < 1e-8,
                "beta {beta}: {}",
                slope / shape
            );
        }
        // The notes' one-mode figures.
        assert!((CLAMPED[0].0.powi(4) - 500.56).abs() < 0.01);
        assert!((CLAMPED[0].1 - 12.303).abs() < 0.001);
    }

    #[test]
    fn moving_rod_reaches_zero_frequency_at_the_critical_speed() {
        for ends in [Ends::Pinned, Ends::Clamped] {
            let beam = Beam {
                length_m: 1.2,
                diameter_m: 0.016,
                density_kg_m3: 7700.0,
                modulus_pa: 150e9,
                tension_n: 2000.0,
                ends,
            };
            let critical = beam.critical_speed_m_s();
            assert!(beam.omega_squared(1, critical).abs() < 1e-9 * beam.omega_squared(1, 0.0));
        }
        // Pinned, no tension: V_crit = 2 L f1.
        let beam = Beam {
            length_m: 1.2,
            diameter_m: 0.016,
            density_kg_m3: 7700.0,
            modulus_pa: 150e9,
            tension_n: 0.0,
            ends: Ends::Pinned,
        };
        let expected = 2.0 * 1.2 * beam.frequency_hz(1, 0.0);
        assert!((beam.critical_speed_m_s() / expected - 1.0).abs() < 1e-12);
    }
}
