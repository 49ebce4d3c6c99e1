//! The fatigue account of a torque stream: the dsp crate's streaming rainflow count
//! ([`millgate_dsp::rainflow`]) and Miner's rule ([`millgate_dsp::miner`]) over
//! segments of samples, as `millgate fatigue` reads them (a record, or the bite
//! captures a history keeps).
//!
//! A segment is counted on its own (a fresh counter, its residue as half cycles at its
//! end): samples are never joined across segments. Two passes over the segments keep
//! the memory fixed whatever their number: the first finds the largest range, the
//! mean's bounds and the damage; the second fills the histogram.

use millgate_dsp::miner::SnCurve;
use millgate_dsp::rainflow::{Cycle, Rainflow, RainflowSettings, RainflowSettingsError};

/// Reversals a channel's residue stack holds: 2 KiB per channel. A bite's ring-down
/// above a gate of 2 kN*m on 2 kN*m of noise stays within 256 (the zero-allocation
/// test counts no overflow on 12 bites of the paper's table 1 transient).
pub(crate) const STACK: usize = 256;

/// Range bins of the histogram (over 0 ..= the largest range).
pub(crate) const RANGE_BINS: usize = 10;
/// Mean bins of the histogram (over the smallest ..= the largest mean).
pub(crate) const MEAN_BINS: usize = 10;
/// A cycle counts in `cycles_over_10pct` when its range exceeds this fraction of the
/// largest.
pub(crate) const LARGE_FRACTION: f64 = 0.1;

/// What the counted cycles of all segments add up to.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Account {
    /// Segments counted.
    pub segments: u64,
    /// Samples counted (non-finite ones skipped).
    pub samples: u64,
    /// Non-finite samples skipped.
    pub non_finite: u64,
    /// Full-stack overflows (oldest range emitted as a half cycle).
    pub overflows: u64,
    /// Cycles counted (half cycles as 0.5).
    pub cycles: f64,
    /// Largest range, kN*m (0 without cycles).
    pub max_range_knm: f64,
    /// Smallest and largest mean, kN*m.
    pub mean_bounds_knm: (f64, f64),
    /// Miner's damage per curve, in the order given.
    pub damage: Vec<f64>,
    /// Cycles whose range exceeds [`LARGE_FRACTION`] of the largest.
    pub cycles_over_10pct: f64,
    /// Counts, `[range bin][mean bin]`.
    pub histogram: [[f64; MEAN_BINS]; RANGE_BINS],
}

impl Account {
    /// The edges of the range bins, kN*m (`RANGE_BINS + 1` values).
    pub(crate) fn range_edges_knm(&self) -> Vec<f64> {
        edges(0.0, self.max_range_knm, RANGE_BINS)
    }

    /// The edges of the mean bins, kN*m (`MEAN_BINS + 1` values).
    pub(crate) fn mean_edges_knm(&self) -> Vec<f64> {
        edges(self.mean_bounds_knm.0, self.mean_bounds_knm.1, MEAN_BINS)
    }
}

fn edges(low: f64, high: f64, bins: usize) -> Vec<f64> {
    (0..=bins)
        .map(|i| low + (high - low) * i as f64 / bins as f64)
        .collect()
}

/// The bin of `value` among `bins` equal bins over `low ..= high` (the last bin
/// closed; all in bin 0 when `high <= low`).
fn bin(value: f64, low: f64, high: f64, bins: usize) -> usize {
    if high <= low {
        return 0;
    }
    (((value - low) / (high - low) * bins as f64) as usize).min(bins - 1)
}

/// Calls `on_segment` with each segment of samples, kN*m, in order.
pub(crate) type Segments<'a, E> = dyn FnMut(&mut dyn FnMut(&[f64])) -> Result<(), E> + 'a;

/// Counts every segment with a gate of `gate_knm`, calling `on_cycle` for each cycle
/// (the residue's at the segment's end); returns (segments, samples, non-finite,
/// overflows).
fn count<E>(
    counter: &Rainflow<STACK>,
    segments: &mut Segments<'_, E>,
    on_cycle: &mut dyn FnMut(Cycle),
) -> Result<(u64, u64, u64, u64), E> {
    let mut totals = (0, 0, 0, 0);
    segments(&mut |samples| {
        let mut state = counter.state();
        counter.block(&mut state, samples, &mut *on_cycle);
        counter.residue(&state, &mut *on_cycle);
        totals.0 += 1;
        totals.1 += samples.len() as u64 - state.non_finite();
        totals.2 += state.non_finite();
        totals.3 += state.overflows();
    })?;
    Ok(totals)
}

/// The account of `segments` counted with a gate of `gate_knm` (>= 0), with Miner's
/// damage for each of `curves`; `segments` is read twice.
pub(crate) fn account<E: From<RainflowSettingsError>>(
    gate_knm: f64,
    curves: &[SnCurve],
    segments: &mut Segments<'_, E>,
) -> Result<Account, E> {
    let counter = Rainflow::<STACK>::new(RainflowSettings { gate_knm })?;
    let mut damage = vec![0.0; curves.len()];
    let (mut cycles, mut max_range, mut low, mut high) = (0.0, 0.0_f64, f64::MAX, f64::MIN);
    let (segment_count, samples, non_finite, overflows) =
        count(&counter, segments, &mut |cycle| {
            cycles += cycle.count;
            max_range = max_range.max(cycle.range_knm);
            low = low.min(cycle.mean_knm);
            high = high.max(cycle.mean_knm);
            for (sum, curve) in damage.iter_mut().zip(curves) {
                *sum += curve.damage(&cycle);
            }
        })?;
    if cycles == 0.0 {
        (low, high) = (0.0, 0.0);
    }
    let mut histogram = [[0.0; MEAN_BINS]; RANGE_BINS];
    let mut large = 0.0;
    count(&counter, segments, &mut |cycle| {
        let r = bin(cycle.range_knm, 0.0, max_range, RANGE_BINS);
        let m = bin(cycle.mean_knm, low, high, MEAN_BINS);
        histogram[r][m] += cycle.count;
        if cycle.range_knm > LARGE_FRACTION * max_range {
            large += cycle.count;
        }
    })?;
    Ok(Account {
        segments: segment_count,
        samples,
        non_finite,
        overflows,
        cycles,
        max_range_knm: max_range,
        mean_bounds_knm: (low, high),
        damage,
        cycles_over_10pct: large,
        histogram,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use millgate_dsp::miner::{EnduranceRule, MeanCorrection, SnCurveSettings};

    #[derive(Debug, PartialEq)]
    struct Refused;
    impl From<RainflowSettingsError> for Refused {
        fn from(_: RainflowSettingsError) -> Self {
            Refused
        }
    }

    #[test]
    fn segments_are_counted_apart_and_binned() {
        let curve = SnCurve::new(SnCurveSettings {
            m: 3.0,
            ref_cycles: 1000.0,
            ref_range_knm: 10.0,
            torque_share: 1.0,
            endurance_knm: None,
            endurance_rule: EnduranceRule::Cutoff,
            mean_correction: MeanCorrection::None,
        })
        .unwrap();
        // Two segments 0 10 0: each a half cycle up and one down (10 kN*m, mean 5);
        // joined they would close a full cycle 10 .. 0 and differ.
        let mut segments = |each: &mut dyn FnMut(&[f64])| -> Result<(), Refused> {
            each(&[0.0, 10.0, 0.0]);
            each(&[0.0, 10.0, 0.0, f64::NAN]);
            Ok(())
        };
        let account = account(0.0, &[curve], &mut segments).unwrap();
        assert_eq!(account.segments, 2);
        assert_eq!((account.samples, account.non_finite), (6, 1));
        assert_eq!(account.cycles, 2.0);
        assert_eq!(account.max_range_knm, 10.0);
        assert_eq!(account.cycles_over_10pct, 2.0);
        assert_eq!(account.histogram[RANGE_BINS - 1][0], 2.0);
        // Four half cycles of the reference range: 2 / ref_cycles.
        assert!((account.damage[0] - 2.0 / 1000.0).abs() < 1e-15);
        assert_eq!(account.range_edges_knm()[RANGE_BINS], 10.0);
        let mut bad = |_: &mut dyn FnMut(&[f64])| -> Result<(), Refused> { Ok(()) };
        assert_eq!(account_of_gate(-1.0, &mut bad), Err(Refused));
    }

    fn account_of_gate(
        gate: f64,
        segments: &mut Segments<'_, Refused>,
    ) -> Result<Account, Refused> {
        account(gate, &[], segments)
    }
}
