//! What one bite tells about the opened gap of a driveline: a likelihood over
//! (coupling, gap) against the gap maps. The wear trend ([`super::gap_trend`]) folds
//! these bite after bite into an estimate that follows the gap as it grows.
//!
//! - **Observation** ([`GapObservation`]): a bite's static torque, TAF and first-period
//!   shift, each with its standard deviation from the window's own noise (the white-noise
//!   RMS from the window's fourth differences, carried through the low-pass filters of
//!   the peak and of the period measurement: the peak's error is the filtered noise, a
//!   zero crossing's error is the filtered noise over the oscillation's slope there).
//! - **Likelihood**: the maps give, at the bite's static torque, TAF and shift for every
//!   (coupling, gap) on a fine gap grid ([`SUBSTEPS`] per map step). Each measure is
//!   compared under a Gaussian whose variance is the measurement's plus the map's
//!   interpolation error plus a model floor ([`TAF_FLOOR`], [`SHIFT_FLOOR_S`]), mixed
//!   with a small uniform outlier part ([`OUTLIER_WEIGHT`]) so one odd bite cannot veto
//!   the truth. The first-period shift jumps where a gap adds or removes an oscillation
//!   crossing in the first period; where the four map corners around a point spread by
//!   more than [`SHIFT_JUMP_S`], the point's shift likelihood is the mixture of the
//!   corners' (the bite is on one branch or the other) rather than an interpolated value
//!   no bite ever shows.
//!   The likelihood is given with one of two [`Allowance`]s: with the model floor (one
//!   bite on its own) or without it (what the trend folds in; it carries the floor
//!   beside the filter).
//! - **One bite's estimate** ([`estimate`]): the gap is the maximum of the
//!   log-likelihood; the 90% interval holds every gap whose log-likelihood is within
//!   chi2(1, 0.90) / 2 of it (a likelihood-ratio interval, which reaches 0 when the
//!   data allow no gap); the coupling is the best one when its best beats every other
//!   coupling's by [`COUPLING_LOGLIK`] (a likelihood ratio of 100), else undetermined,
//!   and the interval then spans every coupling's gaps within reach.

use millgate_dsp::transient::{TransientResult, TransientSettings};
use serde::{Deserialize, Serialize};

use millgate_dsp::wear_trend::GapGrid;

use crate::state::gap_maps::{Cell, GapMaps};

/// Fine gap steps per map gap step.
pub const SUBSTEPS: usize = 8;
/// Half the 0.90 quantile of chi2 with one degree of freedom: the drop in
/// log-likelihood that bounds the 90% interval.
pub(crate) const INTERVAL_LOGLIK: f64 = 2.705_543_454_095_404 / 2.0;
/// Log-likelihood by which the best coupling must beat every other to be named (ln 100).
pub const COUPLING_LOGLIK: f64 = 4.605_170_185_988_091;
/// Model error of the TAF beyond the interpolation estimate (standard deviation): what
/// a calibrated model leaves. Four calibrations of the Table 2 driveline by the
/// discrepancy workflow (three bites each, from the drawings' model) moved the maps' TAF
/// by 0.0014 RMS against the true driveline's (`cargo test -p millgate --test gap
/// model_error_allowance -- --ignored`, which fails should this allowance fall short).
pub const TAF_FLOOR: f64 = 0.002;
/// Model error of the first-period shift beyond the interpolation estimate, s: the
/// same calibrations moved the maps' shift by 0.29 ms RMS (see [`TAF_FLOOR`]).
pub const SHIFT_FLOOR_S: f64 = 0.3e-3;
/// Weight of the uniform outlier part of each measure's likelihood.
pub const OUTLIER_WEIGHT: f64 = 0.02;
/// Width of the TAF range the outlier part spreads over.
const TAF_OUTLIER_SPAN: f64 = 2.0;
/// Width of the shift range the outlier part spreads over, s.
const SHIFT_OUTLIER_SPAN_S: f64 = 0.1;
/// Spread of a point's four map corners above which its shift is a jump, s.
pub const SHIFT_JUMP_S: f64 = 5e-3;
/// Variance of filtered white noise over that of the input, per cut-off over sample
/// rate, for the zero-phase (forward-backward) second-order Butterworth low-pass of
/// the transient analysis: 2 / fs times its noise bandwidth, the integral of
/// |H|^4 = 1 / (1 + (f/fc)^4)^2, which is 3 pi / (8 sqrt 2) fc.
const FILTFILT_NOISE_GAIN: f64 =
    2.0 * 3.0 * std::f64::consts::PI / (8.0 * std::f64::consts::SQRT_2);
/// Smallest oscillation amplitude taken for the slope at a crossing, as a fraction of
/// the static torque.
const MIN_AMPLITUDE_FRACTION: f64 = 0.05;

/// What one bite tells about the gap: its measures and their standard deviations.
/// Torque kN*m, times s. The history keeps these per bite.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct GapObservation {
    /// Static (settled) torque, kN*m.
    pub static_torque_knm: f64,
    /// Torque amplification factor.
    pub taf: f64,
    /// Standard deviation of `taf` from the window's noise.
    pub taf_sigma: f64,
    /// First minus second oscillation period, s, when measured.
    pub period_shift_s: Option<f64>,
    /// Standard deviation of `period_shift_s`, s.
    pub period_shift_sigma_s: f64,
}

/// The standard deviation of white noise of RMS `rms` after the analysis low-pass at
/// `cutoff_hz` (`None`: unfiltered) at `rate_hz`.
fn filtered(rms: f64, cutoff_hz: Option<f64>, rate_hz: f64) -> f64 {
    match cutoff_hz {
        Some(cutoff) => rms * (FILTFILT_NOISE_GAIN * cutoff / rate_hz).min(1.0).sqrt(),
        None => rms,
    }
}

impl GapObservation {
    /// The observation of a bite whose window (kN*m, as captured) gave `transient` with
    /// `settings`; `None` without a TAF.
    pub(crate) fn from_window(
        window: &[f64],
        transient: &TransientResult,
        settings: &TransientSettings,
    ) -> Option<Self> {
        let taf = transient.taf?;
        let rate = settings.sample_rate_hz;
        let noise = millgate_dsp::noise::noise_rms(window);
        let static_knm = transient.static_torque_knm;
        let tail = ((window.len() as f64 * settings.settled_fraction) as usize).max(1);
        let static_sigma = noise / (tail as f64).sqrt();
        let peak_sigma = filtered(noise, settings.peak_lowpass_hz, rate);
        let taf_sigma = peak_sigma.hypot(taf * static_sigma) / static_knm;
        let period_shift_sigma_s = match (transient.period_shift_s, transient.second_period_s) {
            (Some(_), Some(period)) => {
                let amplitude = (transient.peak_torque_knm - static_knm)
                    .max(MIN_AMPLITUDE_FRACTION * static_knm);
                let slope = 2.0 * std::f64::consts::PI * amplitude / period;
                let crossing = filtered(noise, Some(settings.period_lowpass_hz), rate) / slope;
                // first - second = -c0 + 2 c1 - c2 over three crossings.
                6.0_f64.sqrt() * crossing
            }
            _ => 0.0,
        };
        Some(Self {
            static_torque_knm: static_knm,
            taf,
            taf_sigma,
            period_shift_s: transient.period_shift_s,
            period_shift_sigma_s,
        })
    }
}

/// The gap estimate from one bite.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct GapEstimate {
    /// Opened gap, maximum likelihood, mrad.
    pub gap_mrad: f64,
    /// Lower end of the 90% interval, mrad.
    pub gap_low_mrad: f64,
    /// Upper end of the 90% interval, mrad.
    pub gap_high_mrad: f64,
    /// The coupling holding the gap (model index), `None` when the bites cannot tell.
    pub coupling: Option<usize>,
    /// The likeliest coupling (model index), named or not.
    pub likeliest_coupling: usize,
}

/// Log of a Gaussian density of `residual` with variance `variance`.
fn log_gauss(residual: f64, variance: f64) -> f64 {
    -0.5 * (residual * residual / variance + (2.0 * std::f64::consts::PI * variance).ln())
}

/// `ln((1 - w) exp(log_density) + w / span)`: a density with an outlier part.
fn robust(log_density: f64, span: f64) -> f64 {
    ((1.0 - OUTLIER_WEIGHT) * log_density.exp() + OUTLIER_WEIGHT / span).ln()
}

/// Which errors a bite's likelihood allows for besides the bite's own noise.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Allowance {
    /// The noise and the maps' interpolation error: what the wear trend folds in bite
    /// after bite. The model floor is systematic (it does not average out over bites),
    /// so the trend carries it beside the filter, on its published intervals.
    Trend,
    /// Also the model floor ([`TAF_FLOOR`], [`SHIFT_FLOOR_S`]): one bite on its own.
    Whole,
}

impl Allowance {
    /// The model floors' variances (TAF, shift s^2) this allowance adds.
    fn model_floors(self) -> (f64, f64) {
        match self {
            Self::Trend => (0.0, 0.0),
            Self::Whole => (TAF_FLOOR.powi(2), SHIFT_FLOOR_S.powi(2)),
        }
    }
}

/// How far below the outlier part a Gaussian part's log-density must lie to vanish
/// from [`robust`]'s sum: `exp(-40)` = 4.2e-18 of the outlier part is below half a unit
/// in the last place of any double (at least 2^-54 = 5.6e-17 of it), so the sum
/// rounds to the outlier part exactly.
const NEGLIGIBLE_LOG: f64 = 40.0;

/// What a bite's likelihood at every grid point shares: its variances under the
/// allowance, and what lets a point far from the maps' values skip the exponential and
/// the logarithm of [`robust`] (most of a fine grid's points, a few standard
/// deviations into the tails, at two `exp` and three `ln` each).
#[derive(Debug, Clone, Copy)]
struct Terms {
    /// The TAF's and the shift's variances (s^2) before the maps' interpolation error.
    taf_variance: f64,
    shift_variance: f64,
    /// `ln(2 pi v)` of those variances: a point's variance adds the map's error to
    /// them, so its Gaussian's log-density is at most `-(q + this) / 2` for the
    /// point's `q = residual^2 / variance`.
    taf_log_floor: f64,
    shift_log_floor: f64,
    /// `robust` of a vanishing Gaussian part: the outlier part's log-density alone.
    taf_outliers: f64,
    shift_outliers: f64,
}

impl Terms {
    fn new(observation: &GapObservation, allowance: Allowance) -> Self {
        let (taf_model, shift_model) = allowance.model_floors();
        let taf_variance = observation.taf_sigma.powi(2) + taf_model;
        let shift_variance = observation.period_shift_sigma_s.powi(2) + shift_model;
        let log_floor = |variance: f64| (2.0 * std::f64::consts::PI * variance).ln();
        Self {
            taf_variance,
            shift_variance,
            taf_log_floor: log_floor(taf_variance),
            shift_log_floor: log_floor(shift_variance),
            taf_outliers: (OUTLIER_WEIGHT / TAF_OUTLIER_SPAN).ln(),
            shift_outliers: (OUTLIER_WEIGHT / SHIFT_OUTLIER_SPAN_S).ln(),
        }
    }
}

/// `robust(log_gauss(residual, variance), span)`, bit for bit, where `log_floor` is at
/// most `ln(2 pi variance)` and `outliers` is `robust`'s value without a Gaussian part
/// for `span`: that value without computing the Gaussian's part when it cannot reach
/// the sum's last bit ([`NEGLIGIBLE_LOG`]).
#[inline(always)]
fn robust_gauss(residual: f64, variance: f64, (log_floor, outliers): (f64, f64), span: f64) -> f64 {
    if -0.5 * (residual * residual / variance + log_floor) < outliers - NEGLIGIBLE_LOG {
        return outliers;
    }
    robust(log_gauss(residual, variance), span)
}

/// The log-likelihoods of `observation` at the gap `weight` of the way from gap row
/// `row` to the next of one coupling's map (`cells`: the map at the bite's static
/// torque, one per gap row), one per allowance `terms` were made for: the maps are
/// interpolated at the point once for all of them.
///
/// This and the helpers it calls per point are `#[inline(always)]`: left to the
/// compiler, one bite's estimate (one allowance) ran 20-40% slower than before the
/// allowances shared the pass (`cargo bench -p millgate --bench gap`, alternated).
#[inline(always)]
fn point_logliks<const N: usize>(
    cells: &[Cell],
    observation: &GapObservation,
    terms: &[Terms; N],
    row: usize,
    weight: f64,
) -> [f64; N] {
    let (taf, taf_floor, corners) = interpolated(cells, row, weight);
    let shift = observation
        .period_shift_s
        .map(|measured| (measured, ShiftCorners::new(&corners)));
    core::array::from_fn(|at| {
        let terms = &terms[at];
        let mut loglik = robust_gauss(
            observation.taf - taf,
            terms.taf_variance + taf_floor * taf_floor,
            (terms.taf_log_floor, terms.taf_outliers),
            TAF_OUTLIER_SPAN,
        );
        if let Some((measured, corners)) = &shift {
            loglik += corners
                .as_ref()
                .map_or(0.0, |corners| corners.loglik(*measured, terms));
        }
        loglik
    })
}

/// What every point from gap row `row` of `cells` to the next has under each allowance
/// `terms` were made for, when all of them lie far in both measures' tails: their
/// Gaussian parts then vanish ([`robust_gauss`]) and each point's value is its outlier
/// parts' sum, bit for bit what [`point_logliks`] gives. `None` when some point may
/// not (the row's points are then taken one by one).
///
/// The bound: within a row's span a point's TAF and shift are linear in its weight
/// (so are their interpolation errors), so a residual is smallest at an end or zero
/// where it changes sign, and a variance largest at an end. Most rows of a fine grid
/// are far from the bite (a likelihood is peaked over a few map steps): one bound per
/// row spares their points the maps' interpolation.
#[inline(always)]
fn far_logliks<const N: usize>(
    cells: &[Cell],
    observation: &GapObservation,
    terms: &[Terms; N],
    row: usize,
) -> Option<[f64; N]> {
    let lower = &cells[row];
    let upper = cells.get(row + 1).unwrap_or(lower);
    let ends = |of: fn(&Cell, usize) -> f64| {
        let end = |cell: &Cell| lerp(of(cell, 0), of(cell, 1), cell.weight);
        (end(lower), end(upper))
    };
    let taf = ends(|cell, side| cell.points[side].taf);
    let taf_floor = ends(|cell, side| cell.taf_floor[side]);
    let taf_far = |terms: &Terms| {
        far(
            observation.taf,
            taf,
            taf_floor,
            terms.taf_variance,
            (terms.taf_log_floor, terms.taf_outliers),
        )
    };
    let Some(measured) = observation.period_shift_s else {
        return terms
            .iter()
            .all(taf_far)
            .then(|| terms.map(|terms| terms.taf_outliers));
    };
    // Every corner has a shift and they spread by no more than a jump: each point's
    // shift term is then its Gaussian one (`ShiftCorners::loglik`).
    let (mut low, mut high) = (f64::INFINITY, f64::NEG_INFINITY);
    for point in lower.points.iter().chain(&upper.points) {
        let shift = point.period_shift_s?;
        low = low.min(shift);
        high = high.max(shift);
    }
    if high - low > SHIFT_JUMP_S {
        return None;
    }
    let shift = ends(|cell, side| cell.points[side].period_shift_s.unwrap_or(0.0));
    let shift_floor = ends(|cell, side| cell.shift_floor_s[side]);
    let shift_far = |terms: &Terms| {
        far(
            measured,
            shift,
            shift_floor,
            terms.shift_variance,
            (terms.shift_log_floor, terms.shift_outliers),
        )
    };
    terms
        .iter()
        .all(|terms| taf_far(terms) && shift_far(terms))
        .then(|| {
            terms.map(|terms| {
                let mut loglik = terms.taf_outliers;
                loglik += terms.shift_outliers;
                loglik
            })
        })
}

/// Whether [`robust_gauss`] gives its outlier part alone at every point of a row's
/// span for a measure `measured` whose model runs linearly from `model.0` to `model.1`
/// with interpolation errors from `floor.0` to `floor.1`: `variance` and `(log_floor,
/// outliers)` as it takes them. The residual is taken smaller by its rounding (a few
/// units in the last place of the values it comes from) and the bound is one unit of
/// `q` beyond the point's, so no rounding can put a point on the other side.
#[inline(always)]
fn far(
    measured: f64,
    model: (f64, f64),
    floor: (f64, f64),
    variance: f64,
    (log_floor, outliers): (f64, f64),
) -> bool {
    let (to_low, to_high) = (measured - model.0, measured - model.1);
    let nearest = if to_low.signum() == to_high.signum() {
        to_low.abs().min(to_high.abs())
    } else {
        0.0
    };
    let rounding = 8.0 * f64::EPSILON * (measured.abs() + model.0.abs() + model.1.abs());
    let nearest = (nearest - rounding).max(0.0);
    let widest = variance + floor.0.abs().max(floor.1.abs()).powi(2);
    // A point's Gaussian part vanishes where -(q + log_floor) / 2 < outliers -
    // NEGLIGIBLE_LOG, q = residual^2 / its variance.
    let q_needed = 2.0 * (NEGLIGIBLE_LOG - outliers) - log_floor + 1.0;
    nearest * nearest > q_needed * widest * (1.0 + 1e-9)
}

fn lerp(a: f64, b: f64, weight: f64) -> f64 {
    a + (b - a) * weight
}

/// The four map corners around a point: (cell, torque neighbour, bilinear weight).
type Corners<'a> = [(&'a Cell, usize, f64); 4];

/// The map's TAF and TAF interpolation error at the point `weight` of the way from gap
/// row `row` to the next of `cells`, and the point's corners.
#[inline(always)]
fn interpolated(cells: &[Cell], row: usize, weight: f64) -> (f64, f64, Corners<'_>) {
    let (lower, upper, weight) = match cells.get(row + 1) {
        Some(next) => (&cells[row], next, weight),
        None => (&cells[row], &cells[row], 0.0),
    };
    // Each row has its own torque weight (its measured static torques differ a little).
    let corners = [
        (lower, 0, (1.0 - weight) * (1.0 - lower.weight)),
        (lower, 1, (1.0 - weight) * lower.weight),
        (upper, 0, weight * (1.0 - upper.weight)),
        (upper, 1, weight * upper.weight),
    ];
    let taf_floor = corners
        .iter()
        .map(|&(cell, side, w)| w * cell.taf_floor[side])
        .sum::<f64>();
    (lerp(lower.taf(), upper.taf(), weight), taf_floor, corners)
}

/// The map's shifts at a point's four corners: what the point's shift term needs
/// besides the allowance.
struct ShiftCorners {
    /// The corners' shifts (0 where a corner's weight is 0), s.
    values: [f64; 4],
    /// The corners' bilinear weights.
    weights: [f64; 4],
    /// Largest minus smallest shift of the corners in use, s.
    spread: f64,
    /// The interpolated shift, s.
    value: f64,
    /// The interpolated shift's interpolation error, s.
    floor: f64,
}

impl ShiftCorners {
    /// The shifts at `corners` (cell, torque side, bilinear weight); `None` when a
    /// corner in use has no shift (the point's shift term is then 0).
    #[inline(always)]
    fn new(corners: &Corners<'_>) -> Option<Self> {
        let mut values = [0.0; 4];
        let (mut low, mut high) = (f64::INFINITY, f64::NEG_INFINITY);
        let (mut value, mut floor) = (0.0, 0.0);
        for (slot, &(cell, side, weight)) in values.iter_mut().zip(corners) {
            if weight <= 0.0 {
                continue;
            }
            let shift = cell.points[side].period_shift_s?;
            *slot = shift;
            low = low.min(shift);
            high = high.max(shift);
            value += weight * shift;
            floor += weight * cell.shift_floor_s[side];
        }
        Some(Self {
            values,
            weights: corners.map(|(_, _, weight)| weight),
            spread: high - low,
            value,
            floor,
        })
    }

    /// The shift term of a bite that measured `measured` s, with the allowance `terms`
    /// were made for.
    #[inline(always)]
    fn loglik(&self, measured: f64, terms: &Terms) -> f64 {
        let variance = terms.shift_variance + self.floor * self.floor;
        if self.spread <= SHIFT_JUMP_S {
            return robust_gauss(
                measured - self.value,
                variance,
                (terms.shift_log_floor, terms.shift_outliers),
                SHIFT_OUTLIER_SPAN_S,
            );
        }
        let density: f64 = self
            .values
            .iter()
            .zip(self.weights)
            .map(|(&shift, weight)| weight * log_gauss(measured - shift, variance).exp())
            .sum();
        ((1.0 - OUTLIER_WEIGHT) * density + OUTLIER_WEIGHT / SHIFT_OUTLIER_SPAN_S).ln()
    }
}

/// Coupling `index`'s log-likelihood of `observation` at the gaps of `grid` (mrad)
/// into `out` (its first `grid.len` slots), with `allowance`; `false` when the bite's
/// static torque is outside the maps. Gaps beyond the maps take the last row's values.
pub fn loglik_at(
    maps: &GapMaps,
    index: usize,
    observation: &GapObservation,
    grid: GapGrid,
    allowance: Allowance,
    out: &mut [f64],
) -> bool {
    logliks_at(maps, index, observation, grid, [allowance], [out])
}

/// [`loglik_at`] under each of `allowances` into the matching `outs`, the maps
/// interpolated once per point for all of them.
fn logliks_at<const N: usize>(
    maps: &GapMaps,
    index: usize,
    observation: &GapObservation,
    grid: GapGrid,
    allowances: [Allowance; N],
    outs: [&mut [f64]; N],
) -> bool {
    let Some(cells) = maps.cells(index, observation.static_torque_knm) else {
        return false;
    };
    cells_logliks(
        &cells,
        observation,
        (grid, map_step_mrad(maps)),
        allowances,
        outs,
    );
    true
}

/// [`logliks_at`] on one coupling's `cells` (one per gap row, `step_mrad` apart).
fn cells_logliks<const N: usize>(
    cells: &[Cell],
    observation: &GapObservation,
    (grid, step_mrad): (GapGrid, f64),
    allowances: [Allowance; N],
    mut outs: [&mut [f64]; N],
) {
    let terms = allowances.map(|allowance| Terms::new(observation, allowance));
    let len = outs.iter().map(|out| out.len()).fold(grid.len, usize::min);
    // The last row's span and what its points all have when they are far.
    let mut span: Option<(usize, Option<[f64; N]>)> = None;
    for k in 0..len {
        let rows = (grid.at(k) / step_mrad).max(0.0);
        let row = (rows.floor() as usize).min(cells.len() - 1);
        let far = match span {
            Some((last, far)) if last == row => far,
            _ => {
                let far = far_logliks(cells, observation, &terms, row);
                span = Some((row, far));
                far
            }
        };
        let values = far
            .unwrap_or_else(|| point_logliks(cells, observation, &terms, row, rows - row as f64));
        for (out, value) in outs.iter_mut().zip(values) {
            out[k] = value;
        }
    }
}

/// The maps' gap step, mrad.
fn map_step_mrad(maps: &GapMaps) -> f64 {
    let gaps = maps.gaps_rad();
    gaps.get(1)
        .map_or(f64::INFINITY, |next| (next - gaps[0]) * 1e3)
}

/// The maps' fine gap grid ([`SUBSTEPS`] points per map step, from 0 to the largest
/// gap), mrad.
pub fn fine_grid(maps: &GapMaps) -> GapGrid {
    let gaps = maps.gaps_rad();
    GapGrid {
        first_mrad: gaps[0] * 1e3,
        step_mrad: map_step_mrad(maps) / SUBSTEPS as f64,
        len: (gaps.len() - 1) * SUBSTEPS + 1,
    }
}

/// The log-likelihood of `observation` per coupling (maps' order) on the fine grid
/// ([`fine_grid`]) with `allowance`; `None` when the bite's static torque is outside
/// the maps.
pub fn fine_loglik(
    maps: &GapMaps,
    observation: &GapObservation,
    allowance: Allowance,
) -> Option<Vec<Vec<f64>>> {
    let [sums] = fine_logliks(maps, observation, [allowance])?;
    Some(sums)
}

/// [`fine_loglik`] under each of `allowances`, the maps interpolated once per point for
/// all of them (the wear trend folds in one and keeps the other's interval).
pub fn fine_logliks<const N: usize>(
    maps: &GapMaps,
    observation: &GapObservation,
    allowances: [Allowance; N],
) -> Option<[Vec<Vec<f64>>; N]> {
    let grid = fine_grid(maps);
    let mut sums: [Vec<Vec<f64>>; N] = core::array::from_fn(|_| Vec::new());
    for index in 0..maps.maps().len() {
        let mut outs: [Vec<f64>; N] = core::array::from_fn(|_| vec![0.0; grid.len]);
        let slices = outs.each_mut().map(Vec::as_mut_slice);
        if !logliks_at(maps, index, observation, grid, allowances, slices) {
            return None;
        }
        for (coupling, out) in sums.iter_mut().zip(outs) {
            coupling.push(out);
        }
    }
    Some(sums)
}

/// The estimate from one bite against `maps` (with its whole allowance); `None` when
/// the bite lies outside the maps' static torque range.
pub fn estimate(maps: &GapMaps, observation: &GapObservation) -> Option<GapEstimate> {
    estimate_of(maps, &fine_loglik(maps, observation, Allowance::Whole)?)
}

/// The estimate from one bite's log-likelihood per coupling on the fine grid with the
/// whole allowance ([`fine_loglik`]), for a caller that has it already.
pub(crate) fn estimate_of(maps: &GapMaps, sums: &[Vec<f64>]) -> Option<GapEstimate> {
    let grid = fine_grid(maps);
    let gaps: Vec<f64> = (0..grid.len).map(|k| grid.at(k) * 1e-3).collect();
    let best_of = |sum: &[f64]| {
        sum.iter()
            .copied()
            .enumerate()
            .fold((0, f64::NEG_INFINITY), |best, (k, v)| {
                if v > best.1 {
                    (k, v)
                } else {
                    best
                }
            })
    };
    let bests: Vec<(usize, f64)> = sums.iter().map(|sum| best_of(sum)).collect();
    let (winner, &(best_k, best)) = bests
        .iter()
        .enumerate()
        .max_by(|a, b| a.1 .1.total_cmp(&b.1 .1))?;
    let runner_up = bests
        .iter()
        .enumerate()
        .filter(|&(index, _)| index != winner)
        .map(|(_, &(_, value))| value)
        .fold(f64::NEG_INFINITY, f64::max);
    let threshold = best - INTERVAL_LOGLIK;
    let winner_interval = interval(&sums[winner], &gaps, threshold);
    // A gap that may be 0 is the same in every coupling: nothing to tell apart.
    let determined = best - runner_up >= COUPLING_LOGLIK && winner_interval.0 > 0.0;
    let (low, high) = if determined {
        winner_interval
    } else {
        sums.iter()
            .map(|sum| interval(sum, &gaps, threshold))
            .fold((f64::INFINITY, f64::NEG_INFINITY), |a, b| {
                (a.0.min(b.0), a.1.max(b.1))
            })
    };
    Some(GapEstimate {
        gap_mrad: gaps[best_k] * 1e3,
        gap_low_mrad: low * 1e3,
        gap_high_mrad: high * 1e3,
        coupling: determined.then(|| maps.maps()[winner].coupling),
        likeliest_coupling: maps.maps()[winner].coupling,
    })
}

/// The gaps (rad) where `sum` is at or above `threshold`, from the first to the last,
/// each end moved to where the log-likelihood crosses the threshold between fine grid
/// points (linear interpolation); `(inf, -inf)` when none is.
fn interval(sum: &[f64], gaps: &[f64], threshold: f64) -> (f64, f64) {
    let Some(first) = sum.iter().position(|&v| v >= threshold) else {
        return (f64::INFINITY, f64::NEG_INFINITY);
    };
    let last = sum.iter().rposition(|&v| v >= threshold).unwrap_or(first);
    let crossing = |inside: usize, outside: usize| {
        let (a, b) = (sum[inside], sum[outside]);
        let fraction = if a > b {
            (a - threshold) / (a - b)
        } else {
            0.0
        };
        lerp(gaps[inside], gaps[outside], fraction.clamp(0.0, 1.0))
    };
    let low = if first > 0 {
        crossing(first, first - 1)
    } else {
        gaps[0]
    };
    let high = if last + 1 < sum.len() {
        crossing(last, last + 1)
    } else {
        gaps[last]
    };
    (low, high)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::state::gap_maps::MapPoint;
    use rand::{Rng as _, SeedableRng as _};

    /// The likelihood of one point as it was before the far points' shortcut: every
    /// term through its exponential and logarithm.
    fn every_term(
        cells: &[Cell],
        observation: &GapObservation,
        allowance: Allowance,
        row: usize,
        weight: f64,
    ) -> f64 {
        let (taf_model, shift_model) = allowance.model_floors();
        let taf_variance = observation.taf_sigma.powi(2) + taf_model;
        let shift_variance = observation.period_shift_sigma_s.powi(2) + shift_model;
        let (taf, taf_floor, corners) = interpolated(cells, row, weight);
        let mut loglik = robust(
            log_gauss(observation.taf - taf, taf_variance + taf_floor * taf_floor),
            TAF_OUTLIER_SPAN,
        );
        let Some(measured) = observation.period_shift_s else {
            return loglik;
        };
        let (mut values, mut value, mut floor) = ([0.0; 4], 0.0, 0.0);
        let (mut low, mut high) = (f64::INFINITY, f64::NEG_INFINITY);
        for (slot, &(cell, side, w)) in values.iter_mut().zip(&corners) {
            if w <= 0.0 {
                continue;
            }
            let Some(shift) = cell.points[side].period_shift_s else {
                return loglik;
            };
            *slot = shift;
            low = low.min(shift);
            high = high.max(shift);
            value += w * shift;
            floor += w * cell.shift_floor_s[side];
        }
        let variance = shift_variance + floor * floor;
        let density = if high - low <= SHIFT_JUMP_S {
            log_gauss(measured - value, variance).exp()
        } else {
            values
                .iter()
                .zip(&corners)
                .map(|(&shift, &(_, _, w))| w * log_gauss(measured - shift, variance).exp())
                .sum()
        };
        loglik += ((1.0 - OUTLIER_WEIGHT) * density + OUTLIER_WEIGHT / SHIFT_OUTLIER_SPAN_S).ln();
        loglik
    }

    /// The shortcut for far points changes no bit: seeded random maps (TAF 1-4, shifts
    /// of -10..10 ms with jumps, some corners without a shift, interpolation errors
    /// from none to large) and bites (noise from none to large, residuals from zero
    /// to far in the tails), both allowances, every gap row and weight. At least a
    /// tenth of the points must have taken the shortcut and a tenth not, or the test
    /// would prove nothing.
    #[test]
    fn far_points_skip_their_exponentials_without_changing_a_bit() {
        let mut rng = rand::rngs::StdRng::seed_from_u64(42);
        let (mut points, mut skipped) = (0, 0);
        for _ in 0..2_000 {
            let point = |rng: &mut rand::rngs::StdRng| MapPoint {
                static_knm: 500.0,
                taf: rng.random_range(1.0..4.0),
                period_shift_s: rng.random_bool(0.95).then(|| rng.random_range(-0.01..0.01)),
            };
            let cells: Vec<Cell> = (0..6)
                .map(|_| Cell {
                    points: [point(&mut rng), point(&mut rng)],
                    taf_floor: [rng.random_range(0.0..0.05), rng.random_range(0.0..0.05)],
                    shift_floor_s: [rng.random_range(0.0..1e-3), rng.random_range(0.0..1e-3)],
                    weight: rng.random_range(0.0..1.0),
                })
                .collect();
            let scale = 10f64.powf(rng.random_range(-4.0..0.0));
            let observation = GapObservation {
                static_torque_knm: 500.0,
                taf: rng.random_range(0.5..4.5),
                taf_sigma: if rng.random_bool(0.1) { 0.0 } else { scale },
                period_shift_s: rng
                    .random_bool(0.8)
                    .then(|| rng.random_range(-0.012..0.012)),
                period_shift_sigma_s: scale * 1e-2,
            };
            // Both allowances at once, as the wear trend takes them.
            let allowances = [Allowance::Trend, Allowance::Whole];
            let terms = allowances.map(|allowance| Terms::new(&observation, allowance));
            for row in 0..cells.len() {
                let weight = rng.random_range(0.0..1.0);
                let both = point_logliks(&cells, &observation, &terms, row, weight);
                for ((fast, allowance), terms) in both.into_iter().zip(allowances).zip(&terms) {
                    let slow = every_term(&cells, &observation, allowance, row, weight);
                    assert_eq!(fast.to_bits(), slow.to_bits(), "{fast} against {slow}: {observation:?}, {allowance:?}, row {row}, weight {weight}");
                    points += 1;
                    skipped += usize::from(fast_skips(&cells, &observation, terms, row, weight));
                }
            }
        }
        assert!(
            skipped * 10 > points && (points - skipped) * 10 > points,
            "{skipped} of {points} points skipped"
        );
    }

    /// The far rows' shortcut changes no bit either: seeded maps shaped as a
    /// driveline's (TAF and shift drifting over the gap rows, some shifts jumping or
    /// missing), bites near one row with noise from small to large, with and without a
    /// shift, both allowances, a fine grid reaching beyond the maps. At least a tenth of
    /// the rows must have taken the shortcut and a tenth not.
    #[test]
    fn far_rows_take_their_outlier_parts_without_changing_a_bit() {
        let mut rng = rand::rngs::StdRng::seed_from_u64(7);
        let (mut rows, mut far_rows) = (0, 0);
        for _ in 0..1_000 {
            let taf = (rng.random_range(1.0..2.0), rng.random_range(-0.1..0.1));
            let shift = (rng.random_range(-5e-3..5e-3), rng.random_range(-1e-3..1e-3));
            let jump_at = rng.random_range(0..40);
            let point = |rng: &mut rand::rngs::StdRng, row: usize| MapPoint {
                static_knm: 500.0,
                taf: taf.0 + taf.1 * row as f64 + rng.random_range(-1e-3..1e-3),
                period_shift_s: rng.random_bool(0.98).then_some(
                    shift.0 + shift.1 * row as f64 + if row >= jump_at { 8e-3 } else { 0.0 },
                ),
            };
            let cells: Vec<Cell> = (0..17)
                .map(|row| Cell {
                    points: [point(&mut rng, row), point(&mut rng, row)],
                    taf_floor: [rng.random_range(0.0..0.01), rng.random_range(0.0..0.01)],
                    shift_floor_s: [rng.random_range(0.0..3e-4), rng.random_range(0.0..3e-4)],
                    weight: rng.random_range(0.0..1.0),
                })
                .collect();
            let near = rng.random_range(0..cells.len());
            let scale = 10f64.powf(rng.random_range(-4.0..-1.0));
            let observation = GapObservation {
                static_torque_knm: 500.0,
                taf: cells[near].taf() + rng.random_range(-3.0..3.0) * scale,
                taf_sigma: scale,
                period_shift_s: rng.random_bool(0.8).then(|| {
                    cells[near].points[0].period_shift_s.unwrap_or(0.0)
                        + rng.random_range(-3.0..3.0) * scale * 1e-2
                }),
                period_shift_sigma_s: scale * 1e-2,
            };
            let step_mrad = 0.125;
            let grid = GapGrid {
                first_mrad: 0.0,
                step_mrad: step_mrad / SUBSTEPS as f64,
                len: (cells.len() + 1) * SUBSTEPS + 1,
            };
            let allowances = [Allowance::Trend, Allowance::Whole];
            let mut outs = [vec![0.0; grid.len], vec![0.0; grid.len]];
            let slices = outs.each_mut().map(Vec::as_mut_slice);
            cells_logliks(&cells, &observation, (grid, step_mrad), allowances, slices);
            for k in 0..grid.len {
                let at = (grid.at(k) / step_mrad).max(0.0);
                let row = (at.floor() as usize).min(cells.len() - 1);
                for (out, allowance) in outs.iter().zip(allowances) {
                    let slow = every_term(&cells, &observation, allowance, row, at - row as f64);
                    assert_eq!(
                        out[k].to_bits(),
                        slow.to_bits(),
                        "{} against {slow}: {observation:?}, {allowance:?}, row {row}",
                        out[k]
                    );
                }
            }
            let terms = allowances.map(|allowance| Terms::new(&observation, allowance));
            for row in 0..cells.len() {
                rows += 1;
                far_rows += usize::from(far_logliks(&cells, &observation, &terms, row).is_some());
            }
        }
        assert!(
            far_rows * 10 > rows && (rows - far_rows) * 10 > rows,
            "{far_rows} of {rows} rows far"
        );
    }

    /// Whether the TAF term of a point skipped its exponential.
    fn fast_skips(
        cells: &[Cell],
        observation: &GapObservation,
        terms: &Terms,
        row: usize,
        weight: f64,
    ) -> bool {
        let (taf, floor, _) = interpolated(cells, row, weight);
        let residual = observation.taf - taf;
        let variance = terms.taf_variance + floor * floor;
        -0.5 * (residual * residual / variance + terms.taf_log_floor)
            < terms.taf_outliers - NEGLIGIBLE_LOG
    }

    #[test]
    fn the_interval_ends_where_the_log_likelihood_crosses_the_threshold() {
        let gaps = [0.0, 1.0, 2.0, 3.0, 4.0];
        // A parabola with its top at 2: crossings of -1 at 2 -+ 1 / sqrt(2) on the
        // exact curve; linear between points: -0.5 at 1 and -2 at 0.. gives 1 - 1/3.
        let sum: Vec<f64> = gaps
            .iter()
            .map(|g: &f64| -0.5 * (g - 2.0).powi(2))
            .collect();
        let (low, high) = interval(&sum, &gaps, -0.5);
        assert_eq!((low, high), (1.0, 3.0));
        let (low, high) = interval(&sum, &gaps, -1.0);
        assert!(
            (low - (1.0 - 1.0 / 3.0)).abs() < 1e-12 && (high - (3.0 + 1.0 / 3.0)).abs() < 1e-12
        );
        // The top at the grid's end: the interval reaches it.
        assert_eq!(interval(&[0.0, -10.0], &[0.0, 1.0], -1.0).0, 0.0);
        assert_eq!(interval(&[-5.0, -6.0], &[0.0, 1.0], -1.0).0, f64::INFINITY);
    }

    #[test]
    fn the_noise_gain_of_the_zero_phase_butterworth_is_its_noise_bandwidth() {
        // 2 / fs * integral_0^inf (1 + (f / fc)^4)^-2 df, numerically (midpoint rule
        // in u = f / fc up to 200, the rest below 1e-13).
        let steps = 2_000_000;
        let du = 200.0 / steps as f64;
        let integral: f64 = (0..steps)
            .map(|k| {
                let u = (k as f64 + 0.5) * du;
                (1.0 + u.powi(4)).powi(-2) * du
            })
            .sum();
        assert!(
            (2.0 * integral - FILTFILT_NOISE_GAIN).abs() < 1e-6,
            "{integral}"
        );
        assert_eq!(filtered(2.0, None, 2000.0), 2.0);
        assert!(
            (filtered(1.0, Some(60.0), 2000.0) - (FILTFILT_NOISE_GAIN * 0.03).sqrt()).abs() < 1e-12
        );
    }
}
