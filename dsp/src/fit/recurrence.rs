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

/// The per-sample steps of the basis at one nonlinear point: the two modes' rotors
/// and the load's factor exp(-a10 dt). An evaluation takes them once for its Gram
/// matrix and its pass over the samples (two sines and cosines and three exponentials
/// that both computed alike before).
#[derive(Clone, Copy)]
pub(super) struct BasisSteps {
    pub(super) mode1: Rotor,
    pub(super) mode2: Rotor,
    pub(super) load: f64,
}

impl BasisSteps {
    /// The steps at `theta` (the nonlinear parameters a5, a6, a7, a8, a10, as
    /// `record::Nonlinear`) for samples `dt` seconds apart.
    pub(super) fn new(theta: &[f64; 5], dt: f64) -> Self {
        Self {
            mode1: Rotor::new(theta[2], theta[0], dt),
            mode2: Rotor::new(theta[3], theta[1], dt),
            load: libm::exp(-theta[4] * dt),
        }
    }
}

/// Two f64 lanes with element-wise arithmetic: the even and the odd samples of a pass,
/// advanced side by side. Independent lanes halve the recurrences' dependency chains
/// and fill one 2-wide vector register.
///
/// On x86-64 the lanes are an SSE2 register (baseline there, so no runtime detection)
/// driven by its intrinsics. Written as plain `[f64; 2]` arithmetic, LLVM's SLP
/// vectoriser regrouped the lanes (real with imaginary parts, with a shuffle per
/// product): 131 instructions per step of [`super::projection`]'s pass, against the
/// fewer than 60 the lane layout needs (valgrind, one fit of 2000 samples). Other
/// targets (the Cortex-M build among them) keep the portable arrays.
#[derive(Clone, Copy, Debug)]
pub(super) struct Pair(Lanes);

#[cfg(all(target_arch = "x86_64", target_feature = "sse2"))]
type Lanes = core::arch::x86_64::__m128d;
#[cfg(not(all(target_arch = "x86_64", target_feature = "sse2")))]
type Lanes = [f64; 2];

// SAFETY (every `unsafe` here): the intrinsics need SSE2, and this module is only
// compiled when the target enables it (`target_feature = "sse2"`: every x86-64 target,
// it is in the architecture's baseline). They only compute on register values; none
// reads or writes memory.
#[cfg(all(target_arch = "x86_64", target_feature = "sse2"))]
#[allow(unsafe_code)]
mod lanes {
    use super::Lanes;
    use core::arch::x86_64 as arch;

    #[inline(always)]
    pub(super) fn new(even: f64, odd: f64) -> Lanes {
        unsafe { arch::_mm_set_pd(odd, even) }
    }
    #[inline(always)]
    pub(super) fn get(lanes: Lanes) -> [f64; 2] {
        unsafe {
            [
                arch::_mm_cvtsd_f64(lanes),
                arch::_mm_cvtsd_f64(arch::_mm_unpackhi_pd(lanes, lanes)),
            ]
        }
    }
    #[inline(always)]
    pub(super) fn add(a: Lanes, b: Lanes) -> Lanes {
        unsafe { arch::_mm_add_pd(a, b) }
    }
    #[inline(always)]
    pub(super) fn sub(a: Lanes, b: Lanes) -> Lanes {
        unsafe { arch::_mm_sub_pd(a, b) }
    }
    #[inline(always)]
    pub(super) fn mul(a: Lanes, b: Lanes) -> Lanes {
        unsafe { arch::_mm_mul_pd(a, b) }
    }
}

#[cfg(not(all(target_arch = "x86_64", target_feature = "sse2")))]
mod lanes {
    use super::Lanes;

    #[inline(always)]
    pub(super) fn new(even: f64, odd: f64) -> Lanes {
        [even, odd]
    }
    #[inline(always)]
    pub(super) fn get(lanes: Lanes) -> [f64; 2] {
        lanes
    }
    #[inline(always)]
    pub(super) fn add(a: Lanes, b: Lanes) -> Lanes {
        [a[0] + b[0], a[1] + b[1]]
    }
    #[inline(always)]
    pub(super) fn sub(a: Lanes, b: Lanes) -> Lanes {
        [a[0] - b[0], a[1] - b[1]]
    }
    #[inline(always)]
    pub(super) fn mul(a: Lanes, b: Lanes) -> Lanes {
        [a[0] * b[0], a[1] * b[1]]
    }
}

impl Pair {
    /// The even lane `even`, the odd one `odd`.
    #[inline(always)]
    pub(super) fn new(even: f64, odd: f64) -> Self {
        Self(lanes::new(even, odd))
    }

    /// Both lanes `value`.
    #[inline(always)]
    pub(super) fn splat(value: f64) -> Self {
        Self::new(value, value)
    }

    /// The even and the odd lane.
    #[inline(always)]
    pub(super) fn lanes(self) -> [f64; 2] {
        lanes::get(self.0)
    }

    /// Sum of the two lanes.
    pub(super) fn total(self) -> f64 {
        let [even, odd] = self.lanes();
        even + odd
    }

    /// The lanes with `keep` false set to 0.
    pub(super) fn masked(self, keep: [bool; 2]) -> Self {
        let [even, odd] = self.lanes();
        Self::new(
            if keep[0] { even } else { 0.0 },
            if keep[1] { odd } else { 0.0 },
        )
    }
}

impl core::ops::Add for Pair {
    type Output = Self;
    #[inline(always)]
    fn add(self, other: Self) -> Self {
        Self(lanes::add(self.0, other.0))
    }
}

impl core::ops::Sub for Pair {
    type Output = Self;
    #[inline(always)]
    fn sub(self, other: Self) -> Self {
        Self(lanes::sub(self.0, other.0))
    }
}

impl core::ops::Mul for Pair {
    type Output = Self;
    #[inline(always)]
    fn mul(self, other: Self) -> Self {
        Self(lanes::mul(self.0, other.0))
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
            re: Pair::new(start_re, start_re * sr - start_im * si),
            im: Pair::new(start_im, start_re * si + start_im * sr),
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
