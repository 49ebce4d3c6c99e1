//! The start of the iteration, with no user guess: the pencil's poles, a linear
//! least-squares fit over all of them to pick the two oscillating modes of largest
//! energy and the load rate, then the best of a few load rates.

use nalgebra::{SMatrix, SVector};

use super::levenberg_marquardt::{evaluate, Evaluation};
use super::model::FitError;
use super::record::{Data, Nonlinear};
use super::recurrence::{Pair, PairRotor, Rotor};
use crate::pencil;

/// Start of the iteration chosen from the pencil poles.
#[derive(Clone, Copy)]
pub(super) struct Guess {
    /// a5, a6, a7, a8, a10.
    pub(super) theta: Nonlinear,
    /// Whether a10 is a load pole of the pencil (else the default 10 / T, T the record
    /// length).
    rise_from_pencil: bool,
}

/// Largest basis: the constant and one function per pencil pole (a complex pair's two
/// count as its two poles).
const MAX_BASIS: usize = 1 + pencil::MODEL_ORDER;

/// Basis slot -> (pole index, is sine); slot 0 is the constant (`usize::MAX`).
type Slots = heapless::Vec<(usize, bool), MAX_BASIS>;

/// Chooses the initial a5..a8 and a10 from the pencil poles.
pub(super) fn initial_guess(data: &Data<'_>, poles: &[pencil::Pole]) -> Result<Guess, FitError> {
    let duration = data.duration_s();
    let slots = basis_slots(poles, duration);
    let coefficients = amplitudes(data, poles, &slots)?;
    let (first, second) = strongest_modes(poles, &slots, &coefficients, duration)?;
    let load = load_rate(poles, &slots, &coefficients);
    Ok(Guess {
        theta: [
            first.frequency_hz,
            second.frequency_hz,
            first.decay_per_s,
            second.decay_per_s,
            load.unwrap_or(10.0 / duration),
        ],
        rise_from_pencil: load.is_some(),
    })
}

/// The basis: the constant, each oscillating pole's cosine and sine, each real pole
/// fast enough (decaying by more than e^0.5 over the record of `duration` s) to be
/// told from the constant.
fn basis_slots(poles: &[pencil::Pole], duration: f64) -> Slots {
    let mut slots = Slots::new();
    let _ = slots.push((usize::MAX, false));
    for (k, pole) in poles.iter().enumerate() {
        if pole.frequency_hz > 0.0 {
            let _ = slots.push((k, false));
            let _ = slots.push((k, true));
        } else if pole.decay_per_s * duration > 0.5 {
            // Slower real poles are indistinguishable from the constant: dropped.
            let _ = slots.push((k, false));
        }
    }
    slots
}

/// Linear least-squares coefficients of the basis `slots` over the record (the
/// normal equations accumulated sample by sample); unused slots are 0.
fn amplitudes(
    data: &Data<'_>,
    poles: &[pencil::Pole],
    slots: &Slots,
) -> Result<SVector<f64, MAX_BASIS>, FitError> {
    // One rotor per slot, its real part the slot's function: a cosine or a real pole
    // starts at 1, a sine at -i (Re(-i z^n) = Im z^n), the constant never turns, and
    // unused slots stay 0. Fixed-size arrays with no per-sample lookup let the compiler
    // unroll the sums (a lookup per slot and sample took 3 times the instructions);
    // even and odd samples run in the two lanes of a [`Pair`], as in the fit's pass
    // over the samples, which halves the sums' instructions (every accumulator is
    // loaded and stored once per two samples).
    let dt = data.dt;
    let still = Rotor {
        re: 1.0,
        im: 0.0,
        step_re: 1.0,
        step_im: 0.0,
    };
    let mut rotors = [PairRotor::new(still, 0.0, 0.0); MAX_BASIS];
    for (s, &(k, sine)) in slots.iter().enumerate() {
        rotors[s] = if k == usize::MAX {
            PairRotor::new(still, 1.0, 0.0)
        } else {
            let rotor = Rotor::new(poles[k].decay_per_s, poles[k].frequency_hz, dt);
            if sine {
                PairRotor::new(rotor, 0.0, -1.0)
            } else {
                PairRotor::new(rotor, 1.0, 0.0)
            }
        };
    }
    let zero = Pair::splat(0.0);
    let mut ata = [[zero; MAX_BASIS]; MAX_BASIS];
    let mut atb = [zero; MAX_BASIS];
    let mut accumulate = |values: Pair, keep: Option<[bool; 2]>| {
        let mut basis: [Pair; MAX_BASIS] = core::array::from_fn(|s| rotors[s].re);
        for rotor in rotors.iter_mut() {
            rotor.advance();
        }
        if let Some(keep) = keep {
            for b in basis.iter_mut() {
                *b = b.masked(keep);
            }
        }
        for a in 0..MAX_BASIS {
            atb[a] += basis[a] * values;
            // Upper triangle only; mirrored below.
            for b in a..MAX_BASIS {
                ata[a][b] += basis[a] * basis[b];
            }
        }
    };
    let (pairs, tail) = data.pairs();
    for values in pairs {
        let keep = data.positive_only.then(|| values.lanes().map(|v| v > 0.0));
        accumulate(values, keep);
    }
    if let Some((values, keep)) = tail {
        accumulate(values, Some(keep));
    }
    let ata: [[f64; MAX_BASIS]; MAX_BASIS] = ata.map(|row| row.map(Pair::total));
    let atb: [f64; MAX_BASIS] = atb.map(Pair::total);
    let used = slots.len();
    let a = SMatrix::<f64, MAX_BASIS, MAX_BASIS>::from_fn(|i, j| {
        if i < used && j < used {
            ata[i.min(j)][i.max(j)]
        } else if i == j {
            1.0
        } else {
            0.0
        }
    });
    let b = SVector::<f64, MAX_BASIS>::from_fn(|i, _| if i < used { atb[i] } else { 0.0 });
    a.lu().solve(&b).ok_or(FitError::Singular)
}

/// The basis slots that start a pole (an oscillating pole's cosine, a real pole), with
/// the pole.
fn pole_slots<'p>(
    poles: &'p [pencil::Pole],
    slots: &'p Slots,
) -> impl Iterator<Item = (usize, pencil::Pole)> + 'p {
    slots
        .iter()
        .enumerate()
        .skip(1)
        .filter(|(_, &(_, sine))| !sine)
        .map(|(slot, &(k, _))| (slot, poles[k]))
}

/// The two oscillating poles of largest energy over the record of `duration` s, lower
/// frequency first.
fn strongest_modes(
    poles: &[pencil::Pole],
    slots: &Slots,
    coefficients: &SVector<f64, MAX_BASIS>,
    duration: f64,
) -> Result<(pencil::Pole, pencil::Pole), FitError> {
    let mut best: [(f64, Option<pencil::Pole>); 2] = [(-1.0, None); 2];
    for (slot, pole) in pole_slots(poles, slots).filter(|(_, pole)| pole.frequency_hz > 0.0) {
        let (c, s) = (coefficients[slot], coefficients[slot + 1]);
        let rate = 2.0 * pole.decay_per_s;
        let weight = if libm::fabs(rate * duration) < 1e-9 {
            duration
        } else {
            (1.0 - libm::exp(-rate * duration)) / rate
        };
        let energy = (c * c + s * s) * weight;
        if energy.is_finite() {
            if energy > best[0].0 {
                best[1] = best[0];
                best[0] = (energy, Some(pole));
            } else if energy > best[1].0 {
                best[1] = (energy, Some(pole));
            }
        }
    }
    let [(_, Some(one)), (_, Some(other))] = best else {
        return Err(FitError::ModesNotFound);
    };
    Ok(if one.frequency_hz <= other.frequency_hz {
        (one, other)
    } else {
        (other, one)
    })
}

/// The decay rate of the largest real pole whose amplitude has the sign of a load
/// rise: the load term is -a9 exp(-a10 t), opposite in sign to the constant.
fn load_rate(
    poles: &[pencil::Pole],
    slots: &Slots,
    coefficients: &SVector<f64, MAX_BASIS>,
) -> Option<f64> {
    let constant = coefficients[0];
    let mut load: Option<(f64, f64)> = None;
    for (slot, pole) in pole_slots(poles, slots).filter(|(_, pole)| pole.frequency_hz <= 0.0) {
        let c = coefficients[slot];
        if c * constant < 0.0 && load.is_none_or(|(m, _)| libm::fabs(c) > m) {
            load = Some((libm::fabs(c), pole.decay_per_s));
        }
    }
    load.map(|(_, decay)| decay)
}

/// Evaluates `guess` with a10 at 8 / T and 24 / T (T the record length), and as
/// guessed when the pencil found a load pole, and returns the best. The pencil's real
/// poles are the least reliable of its output, and a start with a10 far above the truth
/// costs many rejected steps; the variable-projection cost is smooth and unimodal in
/// a10, so a few trials suffice. (Without a load pole the guess is 10 / T, too close to
/// 8 / T to be worth its own evaluation.)
pub(super) fn best_rise(guess: Guess, data: &Data<'_>) -> Option<Evaluation> {
    let duration = data.duration_s();
    let theta = guess.theta;
    let pencil_rise = guess.rise_from_pencil.then_some(theta[4]);
    let mut best: Option<Evaluation> = None;
    for rise in pencil_rise
        .into_iter()
        .chain([8.0 / duration, 24.0 / duration])
    {
        let mut trial = theta;
        trial[4] = rise;
        if let Some(candidate) = evaluate(trial, data) {
            if best.is_none_or(|b| candidate.cost < b.cost) {
                best = Some(candidate);
            }
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;
    use core::f64::consts::PI;

    /// The least squares of [`amplitudes`] (rotors, two lanes, a mask) against nalgebra's
    /// SVD solve on the basis evaluated with libm's exp, cos and sin: strides 1 and 4,
    /// even and odd sample counts (a last pair with one sample), the positive-only mask,
    /// a slow real pole left out of the basis and an unused slot.
    #[test]
    fn amplitudes_match_a_direct_least_squares_solve() {
        const ROWS: usize = 64;
        let poles = [
            pencil::Pole {
                decay_per_s: 5.0,
                frequency_hz: 12.0,
            },
            pencil::Pole {
                decay_per_s: 0.1,
                frequency_hz: 0.0,
            },
            pencil::Pole {
                decay_per_s: 2.0,
                frequency_hz: 31.0,
            },
            pencil::Pole {
                decay_per_s: 20.0,
                frequency_hz: 0.0,
            },
        ];
        // A transient with a wiggle none of the poles explains, crossing zero.
        let samples: [f64; 4 * ROWS] = core::array::from_fn(|i| {
            let t = i as f64 * 1e-3;
            30.0 * libm::exp(-5.0 * t) * libm::cos(2.0 * PI * 12.0 * t + 0.3)
                - 12.0 * libm::exp(-2.0 * t) * libm::sin(2.0 * PI * 31.0 * t)
                + 4.0 * (1.0 - libm::exp(-20.0 * t))
                + 9.0 * libm::sin(0.37 * (i * i) as f64)
                - 2.0
        });
        let mut checked = 0;
        for (len, stride) in [(64, 1), (63, 1), (128, 2), (127, 2), (256, 4), (251, 4)] {
            for positive_only in [false, true] {
                let data = Data::new(
                    &samples[..len],
                    stride,
                    0.02,
                    1e-3 * stride as f64,
                    positive_only,
                );
                let slots = basis_slots(&poles, data.duration_s());
                assert_eq!(slots.len(), MAX_BASIS - 1, "the slow pole is left out");
                let found = amplitudes(&data, &poles, &slots).unwrap();

                let mut basis = SMatrix::<f64, ROWS, MAX_BASIS>::zeros();
                let mut values = SVector::<f64, ROWS>::zeros();
                for (n, value) in data.values().enumerate() {
                    if positive_only && value <= 0.0 {
                        continue;
                    }
                    let t = n as f64 * data.dt;
                    values[n] = value;
                    for (s, &(k, sine)) in slots.iter().enumerate() {
                        basis[(n, s)] = if k == usize::MAX {
                            1.0
                        } else {
                            let pole = poles[k];
                            let angle = 2.0 * PI * pole.frequency_hz * t;
                            let phase = if sine {
                                libm::sin(angle)
                            } else {
                                libm::cos(angle)
                            };
                            libm::exp(-pole.decay_per_s * t) * phase
                        };
                    }
                }
                let expected = basis.svd(true, true).solve(&values, 1e-14).unwrap();
                let label = (len, stride, positive_only);
                for s in 0..MAX_BASIS {
                    assert!(
                        libm::fabs(found[s] - expected[s])
                            <= 1e-9 * (1.0 + libm::fabs(expected[s])),
                        "{label:?} slot {s}: {found} vs {expected}"
                    );
                }
                assert_eq!(found[MAX_BASIS - 1], 0.0, "{label:?}: the unused slot");
                checked += 1;
            }
        }
        assert_eq!(checked, 12);
    }
}
