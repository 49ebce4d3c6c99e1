//! Streaming rainflow counting (ASTM E1049-85) of one torque channel, without heap.
//!
//! The counter is split into coefficients ([`Rainflow`], built once from validated
//! [`RainflowSettings`]) and state ([`RainflowState`], mutated per sample).
//!
//! - **Reversals with a hysteresis gate**: the first sample is the start point; a
//!   running extreme becomes a reversal once the torque has moved back from it by more
//!   than `gate_knm`. With a gate of 0 every change of slope is a reversal (plateaus are
//!   one point), which is the reversal rule of ASTM E1049-85 and of the Python
//!   `rainflow` package; a gate of a few noise RMS keeps noise wiggles from being
//!   counted. Non-finite samples are skipped and counted ([`RainflowState::non_finite`]).
//! - **Four-point rule** on a stack of at most `STACK` reversals: with the last four
//!   points `a b c d`, the inner range `|c - b|` is a closed cycle when it is below
//!   `|b - a|` and not above `|d - c|`; `b` and `c` leave the stack and the rule is
//!   applied again. (Below, not "not above", on the left: a range that ties with the
//!   one before it stays in the residue, so the closed cycles and the residue's half
//!   cycles are those of ASTM's three-point rule, start point included.)
//! - **A full stack** ([`RainflowState::overflows`] counts it): before a reversal is
//!   pushed onto a full stack, its oldest range is emitted as a half cycle and its
//!   oldest point dropped, as ASTM E1049-85 does with a range that holds the start
//!   point. Never a silent drop, never a panic.
//! - **The residue** on demand ([`Rainflow::residue`]): the pending extreme is taken as
//!   the last reversal (closing what it closes, as the end of a record does in ASTM)
//!   and the ranges left on the stack are reported as half cycles. The state is not
//!   changed: counting goes on.
//!
//! ```
//! use millgate_dsp::rainflow::{Cycle, Rainflow, RainflowSettings};
//! let counter = Rainflow::<16>::new(RainflowSettings { gate_knm: 0.0 }).unwrap();
//! let mut state = counter.state();
//! // ASTM E1049-85 figure 6's series: -2 1 -3 5 -1 3 -4 4 -2.
//! let mut closed = heapless::Vec::<Cycle, 8>::new();
//! counter.block(&mut state, &[-2.0, 1.0, -3.0, 5.0, -1.0, 3.0, -4.0, 4.0, -2.0], |c| {
//!     closed.push(c).unwrap();
//! });
//! assert_eq!(closed.len(), 1); // the range -1 .. 3 closes at -4
//! assert_eq!((closed[0].range_knm, closed[0].mean_knm, closed[0].count), (4.0, 1.0, 1.0));
//! let mut halves = 0.0;
//! counter.residue(&state, |c| halves += c.count * c.range_knm);
//! // ASTM's table: half cycles of 3, 4, 8, 9, 8, 6 (3 + 4 + 8 + 9 + 8 + 6 = 38).
//! assert_eq!(halves, 0.5 * 38.0);
//! ```

use heapless::Vec;

/// Settings of a [`Rainflow`] counter; torque in kN*m.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RainflowSettings {
    /// Hysteresis gate: how far the torque must move back from a running extreme for it
    /// to become a reversal, kN*m, finite and >= 0 (0: every change of slope).
    pub gate_knm: f64,
}

/// The [`RainflowSettings`] field (or capacity) that failed validation.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RainflowSettingsError {
    /// `gate_knm` is not finite and >= 0.
    GateKnm,
    /// The stack capacity `STACK` is below 4 (the four-point rule needs four points).
    Stack,
}

impl core::fmt::Display for RainflowSettingsError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            RainflowSettingsError::GateKnm => "gate_knm must be finite and >= 0 kN*m",
            RainflowSettingsError::Stack => {
                "the residue stack must hold at least 4 reversals (the four-point rule)"
            }
        })
    }
}

impl core::error::Error for RainflowSettingsError {}

/// One counted cycle: a closed cycle (`count` 1) or a half cycle (`count` 0.5).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Cycle {
    /// Range (peak to valley), kN*m, >= 0.
    pub range_knm: f64,
    /// Mean of peak and valley, kN*m.
    pub mean_knm: f64,
    /// 1.0 for a closed cycle, 0.5 for a half cycle.
    pub count: f64,
}

impl Cycle {
    fn between(from_knm: f64, to_knm: f64, count: f64) -> Self {
        Self {
            range_knm: libm::fabs(to_knm - from_knm),
            mean_knm: 0.5 * (from_knm + to_knm),
            count,
        }
    }
}

/// Validated coefficients of a rainflow counter whose residue stack holds `STACK`
/// reversals (>= 4; a stack of 64 holds the ring-down of a bite above a gate of a few
/// noise RMS).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Rainflow<const STACK: usize> {
    settings: RainflowSettings,
}

/// Where the torque is heading from the last reversal.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Heading {
    /// Not yet moved beyond the gate from the start point.
    Unknown,
    Up,
    Down,
}

/// Mutable state of one channel; create with [`Rainflow::state`]. Fixed size:
/// `STACK` reversals and a few counters.
#[derive(Clone, Debug)]
pub struct RainflowState<const STACK: usize> {
    /// Reversals not yet closed, oldest first (the start point at the bottom).
    stack: Vec<f64, STACK>,
    heading: Heading,
    /// The running extreme since the last reversal (the start point while `Unknown`).
    pending_knm: f64,
    overflows: u64,
    non_finite: u64,
}

impl<const STACK: usize> RainflowState<STACK> {
    /// Times a full stack emitted its oldest range as a half cycle.
    pub fn overflows(&self) -> u64 {
        self.overflows
    }

    /// Non-finite samples skipped.
    pub fn non_finite(&self) -> u64 {
        self.non_finite
    }

    /// Reversals on the residue stack (not counting the pending extreme).
    pub fn residue_len(&self) -> usize {
        self.stack.len()
    }

    /// The state as plain numbers, to save and [`Rainflow::resume`] later: the
    /// reversals on the stack (oldest first, the start point at the bottom), and the
    /// running extreme with whether the torque is rising towards it (`None` before the
    /// torque has moved beyond the gate from the start point). The counters are not
    /// saved.
    pub fn saved(&self) -> (&[f64], Option<(f64, bool)>) {
        let pending = match self.heading {
            Heading::Unknown => None,
            Heading::Up => Some((self.pending_knm, true)),
            Heading::Down => Some((self.pending_knm, false)),
        };
        (&self.stack, pending)
    }
}

/// Why [`Rainflow::resume`] refused a saved state.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ResumeError {
    /// More reversals than the stack holds.
    Capacity,
    /// A reversal or the running extreme is not finite.
    NotFinite,
    /// A running extreme without a start point on the stack.
    NoStart,
}

impl core::fmt::Display for ResumeError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            ResumeError::Capacity => "more reversals than the residue stack holds",
            ResumeError::NotFinite => "a reversal or the running extreme is not finite",
            ResumeError::NoStart => "a running extreme without a start point",
        })
    }
}

impl core::error::Error for ResumeError {}

impl<const STACK: usize> Rainflow<STACK> {
    /// Validates `settings` and the capacity `STACK`.
    pub fn new(settings: RainflowSettings) -> Result<Self, RainflowSettingsError> {
        if !(settings.gate_knm.is_finite() && settings.gate_knm >= 0.0) {
            return Err(RainflowSettingsError::GateKnm);
        }
        if STACK < 4 {
            return Err(RainflowSettingsError::Stack);
        }
        Ok(Self { settings })
    }

    /// The validated settings.
    pub fn settings(&self) -> &RainflowSettings {
        &self.settings
    }

    /// A fresh state that has seen no sample.
    pub fn state(&self) -> RainflowState<STACK> {
        RainflowState {
            stack: Vec::new(),
            heading: Heading::Unknown,
            pending_knm: 0.0,
            overflows: 0,
            non_finite: 0,
        }
    }

    /// A state that continues one [`RainflowState::saved`] gave: the same reversals and
    /// running extreme (counters at 0).
    pub fn resume(
        &self,
        reversals: &[f64],
        pending: Option<(f64, bool)>,
    ) -> Result<RainflowState<STACK>, ResumeError> {
        let mut state = self.state();
        if reversals.iter().any(|r| !r.is_finite()) || pending.is_some_and(|(p, _)| !p.is_finite())
        {
            return Err(ResumeError::NotFinite);
        }
        state.stack = Vec::from_slice(reversals).map_err(|_| ResumeError::Capacity)?;
        if let Some((pending_knm, rising)) = pending {
            if reversals.is_empty() {
                return Err(ResumeError::NoStart);
            }
            state.pending_knm = pending_knm;
            state.heading = if rising { Heading::Up } else { Heading::Down };
        }
        Ok(state)
    }

    /// Processes one torque sample (kN*m), calling `on_cycle` for each cycle it closes
    /// (and for the half cycle of a full stack).
    #[inline]
    pub fn process(
        &self,
        state: &mut RainflowState<STACK>,
        torque_knm: f64,
        mut on_cycle: impl FnMut(Cycle),
    ) {
        if !torque_knm.is_finite() {
            state.non_finite += 1;
            return;
        }
        let gate = self.settings.gate_knm;
        match state.heading {
            Heading::Up if torque_knm > state.pending_knm => state.pending_knm = torque_knm,
            Heading::Down if torque_knm < state.pending_knm => state.pending_knm = torque_knm,
            Heading::Up | Heading::Down => {
                if libm::fabs(torque_knm - state.pending_knm) > gate {
                    push(state, state.pending_knm, &mut on_cycle);
                    state.heading = match state.heading {
                        Heading::Up => Heading::Down,
                        _ => Heading::Up,
                    };
                    state.pending_knm = torque_knm;
                }
            }
            Heading::Unknown => match state.stack.last() {
                None => push(state, torque_knm, &mut on_cycle),
                Some(&start) if torque_knm - start > gate => {
                    state.heading = Heading::Up;
                    state.pending_knm = torque_knm;
                }
                Some(&start) if start - torque_knm > gate => {
                    state.heading = Heading::Down;
                    state.pending_knm = torque_knm;
                }
                Some(_) => {}
            },
        }
    }

    /// [`Self::process`] for each sample of `torque_knm`, in order.
    pub fn block(
        &self,
        state: &mut RainflowState<STACK>,
        torque_knm: &[f64],
        mut on_cycle: impl FnMut(Cycle),
    ) {
        for &sample in torque_knm {
            self.process(state, sample, &mut on_cycle);
        }
    }

    /// The cycles the record would end with if it ended now: the pending extreme as the
    /// last reversal (what it closes, `count` 1) and then the residue's ranges, oldest
    /// first, as half cycles. `state` is not changed.
    pub fn residue(&self, state: &RainflowState<STACK>, mut on_cycle: impl FnMut(Cycle)) {
        let mut end = state.clone();
        if end.heading != Heading::Unknown {
            let pending_knm = end.pending_knm;
            push(&mut end, pending_knm, &mut on_cycle);
        }
        for pair in end.stack.windows(2) {
            on_cycle(Cycle::between(pair[0], pair[1], 0.5));
        }
    }
}

/// Pushes a reversal, making room first on a full stack, then applies the four-point
/// rule until it closes nothing more.
fn push<const STACK: usize>(
    state: &mut RainflowState<STACK>,
    reversal_knm: f64,
    on_cycle: &mut impl FnMut(Cycle),
) {
    if state.stack.is_full() {
        // STACK >= 4 (checked in `new`): the stack has two points to emit.
        on_cycle(Cycle::between(state.stack[0], state.stack[1], 0.5));
        state.stack.remove(0);
        state.overflows += 1;
    }
    // Cannot fail: the stack was made not full above.
    let _ = state.stack.push(reversal_knm);
    while let [.., a, b, c, d] = state.stack[..] {
        let inner = libm::fabs(c - b);
        if !(inner < libm::fabs(b - a) && inner <= libm::fabs(d - c)) {
            break;
        }
        on_cycle(Cycle::between(b, c, 1.0));
        let len = state.stack.len();
        state.stack.truncate(len - 3);
        let _ = state.stack.push(d);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    extern crate std;
    use std::vec::Vec as StdVec;

    /// ASTM E1049-85 section 5.4.4's three-point rule on a whole record (the algorithm
    /// of the Python `rainflow` package, with its reversals): the reference the
    /// streaming four-point counter must agree with.
    fn astm_three_point(series: &[f64]) -> StdVec<Cycle> {
        let mut reversals = StdVec::new();
        if series.len() < 2 {
            return StdVec::new();
        }
        reversals.push(series[0]);
        let (mut x, mut d_last) = (series[1], series[1] - series[0]);
        for &next in &series[2..] {
            if next == x {
                continue;
            }
            let d = next - x;
            if d_last * d < 0.0 {
                reversals.push(x);
            }
            x = next;
            d_last = d;
        }
        reversals.push(*series.last().unwrap());
        let mut points: StdVec<f64> = StdVec::new();
        let mut cycles = StdVec::new();
        for r in reversals {
            points.push(r);
            while points.len() >= 3 {
                let n = points.len();
                let (x1, x2, x3) = (points[n - 3], points[n - 2], points[n - 1]);
                if libm::fabs(x3 - x2) < libm::fabs(x2 - x1) {
                    break;
                } else if n == 3 {
                    cycles.push(Cycle::between(points[0], points[1], 0.5));
                    points.remove(0);
                } else {
                    cycles.push(Cycle::between(x1, x2, 1.0));
                    points.truncate(n - 3);
                    points.push(x3);
                }
            }
        }
        for pair in points.windows(2) {
            cycles.push(Cycle::between(pair[0], pair[1], 0.5));
        }
        cycles
    }

    fn streamed<const S: usize>(gate_knm: f64, series: &[f64]) -> (StdVec<Cycle>, u64) {
        let counter = Rainflow::<S>::new(RainflowSettings { gate_knm }).unwrap();
        let mut state = counter.state();
        let mut cycles = StdVec::new();
        counter.block(&mut state, series, |c| cycles.push(c));
        counter.residue(&state, |c| cycles.push(c));
        (cycles, state.overflows())
    }

    /// Cycles as sorted (range, mean, count) with equal ones merged: the comparison of
    /// the Python package's `count_cycles`, with means.
    fn merged(mut cycles: StdVec<Cycle>) -> StdVec<(f64, f64, f64)> {
        cycles.retain(|c| c.range_knm > 0.0);
        cycles.sort_by(|a, b| {
            (a.range_knm, a.mean_knm)
                .partial_cmp(&(b.range_knm, b.mean_knm))
                .unwrap()
        });
        let mut out: StdVec<(f64, f64, f64)> = StdVec::new();
        for c in cycles {
            match out.last_mut() {
                Some(last) if last.0 == c.range_knm && last.1 == c.mean_knm => last.2 += c.count,
                _ => out.push((c.range_knm, c.mean_knm, c.count)),
            }
        }
        out
    }

    /// A deterministic pseudo-random walk with plateaus and ties (values on a grid).
    fn walk(seed: u64, len: usize) -> StdVec<f64> {
        let mut s = seed.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1);
        (0..len)
            .map(|_| {
                s = s
                    .wrapping_mul(6_364_136_223_846_793_005)
                    .wrapping_add(1_442_695_040_888_963_407);
                ((s >> 33) % 21) as f64 - 10.0
            })
            .collect()
    }

    #[test]
    fn astm_example_counts_its_table() {
        // ASTM E1049-85 figure 6 / table 4 (rainflow): 0.5 x 3, 0.5 x 4, 1 x 4
        // (-1..3), 0.5 x 6, 0.5 x 8 twice (means 1 and 0), 0.5 x 9.
        let series = [-2.0, 1.0, -3.0, 5.0, -1.0, 3.0, -4.0, 4.0, -2.0];
        let (cycles, overflows) = streamed::<16>(0.0, &series);
        assert_eq!(overflows, 0);
        let ranges: StdVec<(f64, f64)> = merged(cycles).iter().map(|&(r, _, n)| (r, n)).collect();
        assert_eq!(
            ranges,
            [
                (3.0, 0.5),
                (4.0, 0.5),
                (4.0, 1.0),
                (6.0, 0.5),
                (8.0, 0.5),
                (8.0, 0.5),
                (9.0, 0.5)
            ]
        );
    }

    #[test]
    fn streaming_four_point_agrees_with_astm_three_point() {
        for seed in 0..200 {
            let series = walk(seed, 300);
            let (cycles, overflows) = streamed::<512>(0.0, &series);
            assert_eq!(overflows, 0);
            assert_eq!(
                merged(cycles),
                merged(astm_three_point(&series)),
                "seed {seed}"
            );
        }
    }

    #[test]
    fn closed_cycles_are_those_of_astm_one_by_one() {
        // Not only merged: the full cycles in order, before the residue.
        let series = walk(7, 2000);
        let counter = Rainflow::<512>::new(RainflowSettings { gate_knm: 0.0 }).unwrap();
        let mut state = counter.state();
        let mut closed = StdVec::new();
        counter.block(&mut state, &series, |c| closed.push(c));
        let reference: StdVec<Cycle> = astm_three_point(&series)
            .into_iter()
            .filter(|c| c.count == 1.0)
            .collect();
        let mut residue_full = StdVec::new();
        counter.residue(&state, |c| {
            if c.count == 1.0 {
                residue_full.push(c)
            }
        });
        closed.extend(residue_full);
        assert_eq!(closed, reference);
    }

    #[test]
    fn gate_drops_noise_reversals_and_keeps_the_large_cycles() {
        // A 100 kN*m sine with +-1 kN*m wiggles every other sample.
        let clean: StdVec<f64> = (0..4000)
            .map(|i| 100.0 * libm::sin(i as f64 * core::f64::consts::TAU / 400.0))
            .collect();
        let noisy: StdVec<f64> = clean
            .iter()
            .enumerate()
            .map(|(i, v)| v + if i % 2 == 0 { 1.0 } else { -1.0 })
            .collect();
        let (ungated, _) = streamed::<64>(0.0, &noisy);
        assert!(ungated.len() > 1000, "{}", ungated.len());
        let (gated, overflows) = streamed::<64>(5.0, &noisy);
        assert_eq!(overflows, 0);
        // Ten periods of 202 kN*m (equal ranges close as pairs of half cycles, as in
        // ASTM), and below that only the start's and the end's half cycles.
        let large: f64 = gated
            .iter()
            .filter(|c| (c.range_knm - 202.0).abs() < 2.0)
            .map(|c| c.count)
            .sum();
        assert!((9.5..=10.0).contains(&large), "{large}");
        let small = gated.iter().filter(|c| c.range_knm < 150.0).count();
        assert!(small <= 2, "{gated:?}");
    }

    #[test]
    fn a_full_stack_emits_its_oldest_range_as_a_half_cycle_and_counts_it() {
        // A growing oscillation: every range exceeds the one before, nothing closes and
        // the diverging residue fills any stack.
        let series: StdVec<f64> = (0..40)
            .map(|i| if i % 2 == 0 { -(i as f64) } else { i as f64 })
            .collect();
        let (small, overflows) = streamed::<4>(0.0, &series);
        // 39 reversals pushed (the last extreme is pending) on a stack of 4.
        assert_eq!(overflows, 35);
        let (large, none) = streamed::<64>(0.0, &series);
        assert_eq!(none, 0);
        // A diverging record is all half cycles either way: the same account.
        assert_eq!(merged(small), merged(large));
    }

    #[test]
    fn non_finite_samples_are_skipped_and_counted() {
        let counter = Rainflow::<8>::new(RainflowSettings { gate_knm: 0.0 }).unwrap();
        let mut state = counter.state();
        let mut cycles = 0;
        counter.block(
            &mut state,
            &[0.0, f64::NAN, 5.0, f64::INFINITY, 1.0, 4.0, -3.0, 0.0],
            |_| cycles += 1,
        );
        assert_eq!(state.non_finite(), 2);
        assert_eq!(cycles, 1, "1 .. 4 closes");
    }

    #[test]
    fn a_resumed_state_counts_on_as_if_never_stopped() {
        // Stopped and resumed at every point of random walks, with and without a gate:
        // the same cycles, in the same order, as one run through.
        for (seed, gate) in [(3, 0.0), (11, 0.0), (5, 1.5)] {
            let series = walk(seed, 400);
            let counter = Rainflow::<64>::new(RainflowSettings { gate_knm: gate }).unwrap();
            let mut whole = StdVec::new();
            let mut state = counter.state();
            counter.block(&mut state, &series, |c| whole.push(c));
            counter.residue(&state, |c| whole.push(c));
            for stop in [0, 1, 2, 57, 200, 399] {
                let mut cycles = StdVec::new();
                let mut first = counter.state();
                counter.block(&mut first, &series[..stop], |c| cycles.push(c));
                let (reversals, pending) = first.saved();
                let mut resumed = counter.resume(reversals, pending).unwrap();
                counter.block(&mut resumed, &series[stop..], |c| cycles.push(c));
                counter.residue(&resumed, |c| cycles.push(c));
                assert_eq!(cycles, whole, "seed {seed}, stop {stop}");
            }
        }
        let counter = Rainflow::<4>::new(RainflowSettings { gate_knm: 0.0 }).unwrap();
        assert_eq!(
            counter.resume(&[0.0; 5], None).map(|_| ()),
            Err(ResumeError::Capacity)
        );
        assert_eq!(
            counter.resume(&[0.0, f64::NAN], None).map(|_| ()),
            Err(ResumeError::NotFinite)
        );
        assert_eq!(
            counter.resume(&[], Some((1.0, true))).map(|_| ()),
            Err(ResumeError::NoStart)
        );
    }

    #[test]
    fn bad_settings_are_refused() {
        for gate in [-1.0, f64::NAN, f64::INFINITY] {
            assert_eq!(
                Rainflow::<8>::new(RainflowSettings { gate_knm: gate }),
                Err(RainflowSettingsError::GateKnm)
            );
        }
        assert_eq!(
            Rainflow::<3>::new(RainflowSettings { gate_knm: 0.0 }),
            Err(RainflowSettingsError::Stack)
        );
    }
}
