//! Exponentials and sines advanced by complex recurrences, one multiplication per
//! sample and mode: [`Rotor`] sample by sample, [`PairRotor`] over the even and odd
//! samples in the two lanes of a [`Pair`].

use core::f64::consts::PI;

/// exp((-decay + i 2 pi f) t) advanced sample by sample.
#[derive(Clone, Copy)]
pub(super) struct Rotor {
    pub(super) re: f64,
    pub(super) im: f64,
    pub(super) step_re: f64,
    pub(super) step_im: f64,
}

impl Rotor {
    pub(super) fn new(decay_per_s: f64, frequency_hz: f64, dt: f64) -> Self {
        let (s, c) = libm::sincos(2.0 * PI * frequency_hz * dt);
        let m = libm::exp(-decay_per_s * dt);
        Self {
            re: 1.0,
            im: 0.0,
            step_re: m * c,
            step_im: m * s,
        }
    }

    #[inline(always)]
    pub(super) fn advance(&mut self) {
        let re = self.re * self.step_re - self.im * self.step_im;
        self.im = self.re * self.step_im + self.im * self.step_re;
        self.re = re;
    }
}

/// Two f64 lanes with element-wise arithmetic: the even and the odd samples of a pass,
/// advanced side by side. Independent lanes halve the recurrences' dependency chains
/// and let the compiler use 2-wide vector instructions (SSE2 on baseline x86-64).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct Pair(pub(super) [f64; 2]);

impl Pair {
    /// Both lanes `value`.
    pub(super) const fn splat(value: f64) -> Self {
        Self([value, value])
    }

    /// Sum of the two lanes.
    pub(super) fn total(self) -> f64 {
        self.0[0] + self.0[1]
    }
}

impl core::ops::Add for Pair {
    type Output = Self;
    #[inline(always)]
    fn add(self, other: Self) -> Self {
        Self([self.0[0] + other.0[0], self.0[1] + other.0[1]])
    }
}

impl core::ops::Sub for Pair {
    type Output = Self;
    #[inline(always)]
    fn sub(self, other: Self) -> Self {
        Self([self.0[0] - other.0[0], self.0[1] - other.0[1]])
    }
}

impl core::ops::Mul for Pair {
    type Output = Self;
    #[inline(always)]
    fn mul(self, other: Self) -> Self {
        Self([self.0[0] * other.0[0], self.0[1] * other.0[1]])
    }
}

impl core::ops::AddAssign for Pair {
    #[inline(always)]
    fn add_assign(&mut self, other: Self) {
        *self = *self + other;
    }
}

/// A [`Rotor`] split over two lanes: lane l holds z^(2m + l) at step m, and both lanes
/// advance by z^2, so consecutive samples no longer wait on each other.
#[derive(Clone, Copy)]
pub(super) struct PairRotor {
    pub(super) re: Pair,
    pub(super) im: Pair,
    pub(super) step_re: Pair,
    pub(super) step_im: Pair,
}

impl PairRotor {
    /// Lanes started at `start` and `start` z (z the step of `rotor`).
    pub(super) fn new(rotor: Rotor, start_re: f64, start_im: f64) -> Self {
        let (sr, si) = (rotor.step_re, rotor.step_im);
        Self {
            re: Pair([start_re, start_re * sr - start_im * si]),
            im: Pair([start_im, start_re * si + start_im * sr]),
            step_re: Pair::splat(sr * sr - si * si),
            step_im: Pair::splat(2.0 * sr * si),
        }
    }

    #[inline(always)]
    pub(super) fn advance(&mut self) {
        let re = self.re * self.step_re - self.im * self.step_im;
        self.im = self.re * self.step_im + self.im * self.step_re;
        self.re = re;
    }
}
