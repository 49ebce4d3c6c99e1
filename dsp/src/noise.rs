//! The white-noise level of a record, from the data alone.
//!
//! ```
//! use millgate_dsp::noise::noise_rms;
//! // A cubic trend plus +-0.5 alternating: every fourth difference is +-8, so the
//! // estimate is 1.4826 * 8 / sqrt(70); the trend does not count.
//! let record: Vec<f64> = (0..100)
//!     .map(|k| {
//!         let t = k as f64;
//!         0.001 * t * t * t - 2.0 * t + if k % 2 == 0 { 0.5 } else { -0.5 }
//!     })
//!     .collect();
//! let expected = 1.4826 * 8.0 / 70.0_f64.sqrt();
//! assert!((noise_rms(&record) - expected).abs() < 1e-9);
//! ```

/// Standard deviation over median absolute value for a zero-mean Gaussian.
const GAUSSIAN_SIGMA_PER_MEDIAN: f64 = 1.4826;

/// How much the fourth difference multiplies white noise's variance: `1 + 16 + 36 +
/// 16 + 1`.
const FOURTH_DIFFERENCE_VARIANCE_GAIN: f64 = 70.0;

/// White-noise RMS of a record from its fourth differences, in the record's unit (a
/// torque record in kN*m gives kN*m).
///
/// The fourth difference `y[k] - 4 y[k+1] + 6 y[k+2] - 4 y[k+3] + y[k+4]` multiplies
/// white noise's variance by 70 and a sine of frequency f by `(2 sin(pi f / fs))^4`:
/// 2e-5 for a 21 Hz mode at 2 kHz, so even a 100 kN*m oscillation leaves only 2e-3 kN*m,
/// and it removes any cubic trend. The median absolute value (1.4826 MAD for a
/// Gaussian) ignores the few samples where a fast transient or a spike dominates.
///
/// `samples`: equally spaced values of one channel; fewer than 5 give 0. Meant for
/// finite values: a non-finite difference counts as the largest, so a few are ignored
/// like spikes, and more than half of them give infinity or NaN. The median of an even
/// number of differences is the upper of the middle two.
///
/// No heap: the median is selected in place of a sorted copy, by the magnitudes' bit
/// patterns one byte at a time (eight passes over the record, 256 counters on the
/// stack).
pub fn noise_rms(samples: &[f64]) -> f64 {
    if samples.len() < 5 {
        return 0.0;
    }
    let differences = samples.len() - 4;
    let median = f64::from_bits(nth_smallest_magnitude_bits(samples, differences / 2));
    GAUSSIAN_SIGMA_PER_MEDIAN * median / libm::sqrt(FOURTH_DIFFERENCE_VARIANCE_GAIN)
}

/// The bit patterns of the fourth differences' magnitudes. A magnitude's sign bit is
/// clear, so its bits order as the value does (infinity above every finite value, NaN
/// above infinity, as `f64::total_cmp` orders them).
fn magnitude_bits(samples: &[f64]) -> impl Iterator<Item = u64> + '_ {
    samples.windows(5).map(|w| {
        (w[0] - 4.0 * w[1] + 6.0 * w[2] - 4.0 * w[3] + w[4])
            .abs()
            .to_bits()
    })
}

/// The bits of the magnitude of rank `rank` (0 = smallest) among the fourth
/// differences of `samples` (`rank < samples.len() - 4`): a radix selection from the
/// top byte down, each pass counting the byte below the prefix found so far. Once the
/// prefix leaves at most [`GATHERED`] candidates, one more pass gathers them on the
/// stack and a sort finishes the selection: on a bite window (about 1 500 samples of
/// noise) that is three passes instead of eight.
fn nth_smallest_magnitude_bits(samples: &[f64], mut rank: usize) -> u64 {
    let mut prefix = 0_u64;
    for shift in (0..64).step_by(8).rev() {
        let above = u64::MAX.checked_shl(shift + 8).unwrap_or(0);
        let mut counts = [0_usize; 256];
        for bits in magnitude_bits(samples).filter(|bits| bits & above == prefix) {
            counts[((bits >> shift) & 0xff) as usize] += 1;
        }
        let mut candidates = 0;
        for (byte, &count) in counts.iter().enumerate() {
            if rank < count {
                prefix |= (byte as u64) << shift;
                candidates = count;
                break;
            }
            rank -= count;
        }
        if shift > 0 && candidates <= GATHERED {
            // The `candidates` magnitudes under the prefix, `rank` among them.
            let mut gathered = [0_u64; GATHERED];
            let mut len = 0;
            for bits in magnitude_bits(samples).filter(|bits| bits >> shift == prefix >> shift) {
                gathered[len] = bits;
                len += 1;
            }
            let gathered = &mut gathered[..len];
            gathered.sort_unstable();
            return gathered[rank];
        }
    }
    prefix
}

/// Most candidates [`nth_smallest_magnitude_bits`] gathers to sort (1 KiB of stack).
const GATHERED: usize = 128;
