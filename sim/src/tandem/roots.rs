//! Characteristic roots of the linearised tandem mill with its transport delays, and
//! the critical speed where the rightmost one crosses the imaginary axis.
//!
//! The characteristic equation of `x' = A x + sum_k b_k c_k^T x(t - tau_k)` is
//! `det(lambda I - A - sum_k b_k c_k^T e^(-lambda tau_k)) = 0`. Each delay enters
//! through one rank-one term (the exit gauge of one stand), so with the loop matrix
//! `G(lambda) = C (lambda I - A)^-1 B` (m x m, m = interstands) and
//! `Z = diag(e^(-lambda tau_k))` it factors as
//! `det(lambda I - A) det(I - Z G(lambda))`.
//!
//! **Method.** Newton's method on `ln det`, whose derivative is
//! `sum_j 1 / (lambda - mu_j) + tr((I - Z G)^-1 d(I - Z G)/dlambda)` (`mu_j` the
//! eigenvalues of `A`), started from a grid along the imaginary axis at half the
//! spacing of the delay roots (`pi / tau_max`) over the frequencies where the loop can
//! reach a gain of one, and from every eigenvalue of `A`. `(lambda I - A)^-1` is
//! applied through the Hessenberg form of the (balanced) `A`, O(n^2) per evaluation.
//! The rightmost root found is then **certified** by the argument principle: the
//! number of roots right of `Re lambda = alpha` is
//! `#{Re mu_j > alpha} - (1 / pi) * change of arg det(I - Z G)` along
//! `alpha + i omega`, `omega` from 0 to infinity (`det(I - Z G) -> 1` there, the
//! equation being retarded), which must be 0 just right of it.
//!
//! **Why not a discretisation.** The delays (0.3-3 s) times the chatter frequencies
//! (~1000 rad/s) put thousands of roots in the band: a Chebyshev (spectral)
//! discretisation of the delay would need thousands of nodes per delay (matrices of
//! tens of thousands of rows), and a Pade or no-delay start only finds the structural
//! modes, which sit tens of 1/s left of the chain of delay roots that crosses first.

use nalgebra::{Complex, DMatrix};

use super::linear::{LinearSystem, TandemMill};

type C64 = Complex<f64>;

/// A characteristic root `lambda = real + i 2 pi frequency`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Root {
    /// Real part (growth rate), 1/s: > 0 grows.
    pub real_per_s: f64,
    /// Frequency, Hz, >= 0.
    pub frequency_hz: f64,
}

impl Root {
    fn from_lambda(lambda: C64) -> Root {
        Root {
            real_per_s: lambda.re,
            frequency_hz: lambda.im.abs() / std::f64::consts::TAU,
        }
    }
}

/// Why the roots could not be found.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum RootsError {
    /// The system matrix has no Schur form (not finite, or the QR iteration failed).
    #[error("the linearised system's eigenvalues could not be computed")]
    Eigenvalues,
    /// No Newton start converged.
    #[error("no characteristic root converged")]
    NotFound,
    /// The argument principle finds roots right of the rightmost one found.
    #[error("{count} characteristic roots lie right of the rightmost found ({real_per_s:.4}/s)")]
    Unverified {
        /// Roots the argument principle counts right of the rightmost found.
        count: usize,
        /// Real part of the rightmost root found, 1/s.
        real_per_s: f64,
    },
    /// The mill is stable over the whole speed range searched.
    #[error("stable up to speed factor {high}: no critical speed in the range searched")]
    StableInRange {
        /// Highest speed factor searched.
        high: f64,
    },
    /// The mill is unstable already at the lowest speed searched.
    #[error("unstable already at speed factor {low}: no critical speed in the range searched")]
    UnstableInRange {
        /// Lowest speed factor searched.
        low: f64,
    },
}

/// The characteristic function of one `LinearSystem`, ready for evaluation.
#[derive(Debug)]
pub struct Characteristic {
    m: usize,
    delays: Vec<f64>,
    eigenvalues: Vec<C64>,
    /// Residues of the loop matrix, `G(lambda) = sum_j R_j / (lambda - mu_j)`:
    /// `R_j = (C v_j) (w_j^T B)`, n blocks of m x m, row-major.
    residues: Vec<C64>,
}

/// Most interstands (a schedule has at most 8 stands).
const MAX_LOOPS: usize = super::linear::MAX_STANDS - 1;

/// An m x m complex matrix on the stack (m <= [`MAX_LOOPS`]).
type Small = [[C64; MAX_LOOPS]; MAX_LOOPS];

const ZERO: C64 = C64::new(0.0, 0.0);
const ONE: C64 = C64::new(1.0, 0.0);

/// Most Newton iterations from one start.
const NEWTON_ITERATIONS: usize = 30;
/// Roots further left than this (1/s) are not followed by Newton.
const LEFTMOST_FOLLOWED: f64 = -400.0;

impl Characteristic {
    /// Prepares the characteristic function of `system`: the eigenvalues of the
    /// (balanced) `A`, its eigenvectors by inverse iteration on its Hessenberg form, and
    /// the residues of the loop matrix, so one evaluation costs O(n m^2).
    pub fn new(system: &LinearSystem) -> Result<Characteristic, RootsError> {
        let n = system.a.nrows();
        let m = system.delayed.len();
        if m > MAX_LOOPS {
            return Err(RootsError::Eigenvalues);
        }
        let scale = balance(&system.a);
        let balanced = DMatrix::from_fn(n, n, |i, j| system.a[(i, j)] * scale[j] / scale[i]);
        if balanced.iter().any(|v| !v.is_finite()) {
            return Err(RootsError::Eigenvalues);
        }
        let schur = nalgebra::Schur::try_new(balanced.clone(), 1e-15, 100_000)
            .ok_or(RootsError::Eigenvalues)?;
        let eigenvalues: Vec<C64> = schur.complex_eigenvalues().iter().copied().collect();
        let (q, h) = nalgebra::Hessenberg::new(balanced.clone()).unpack();
        let hessenberg = h.transpose().as_slice().to_vec();
        // Eigenvectors of H by two steps of inverse iteration from a slightly shifted
        // eigenvalue, then of the balanced A = Q H Q^T.
        let mut vectors = DMatrix::<C64>::zeros(n, n);
        let norm_a = balanced.norm();
        for (j, mu) in eigenvalues.iter().enumerate() {
            let shift = mu + C64::new(1e-10 * norm_a, 1e-10 * norm_a);
            let lu = HessenbergLu::new(&hessenberg, n, shift).ok_or(RootsError::Eigenvalues)?;
            let mut v: Vec<C64> = (0..n).map(|i| C64::new(1.0, 0.1 * i as f64)).collect();
            for _ in 0..3 {
                lu.solve(&mut v, 1);
                let norm = v.iter().map(|c| c.norm_sqr()).sum::<f64>().sqrt();
                if !(norm.is_finite() && norm > 0.0) {
                    return Err(RootsError::Eigenvalues);
                }
                v.iter_mut().for_each(|c| *c /= norm);
            }
            for i in 0..n {
                vectors[(i, j)] = (0..n).map(|r| v[r] * q[(i, r)]).sum();
            }
        }
        let complex_a = balanced.map(|v| C64::new(v, 0.0));
        let residual = (&complex_a * &vectors
            - &vectors * DMatrix::from_diagonal(&nalgebra::DVector::from_vec(eigenvalues.clone())))
        .norm();
        if residual.is_nan() || residual > 1e-8 * norm_a * (n as f64) {
            return Err(RootsError::Eigenvalues);
        }
        let inverse = vectors
            .clone()
            .try_inverse()
            .ok_or(RootsError::Eigenvalues)?;
        let mut residues = vec![ZERO; n * m * m];
        for j in 0..n {
            for (k, coupling) in system.delayed.iter().enumerate() {
                let c_v = 2.0 * scale[coupling.source] * vectors[(coupling.source, j)];
                for (l, other) in system.delayed.iter().enumerate() {
                    let w_b: C64 = (0..n)
                        .map(|r| inverse[(j, r)] * (other.column[r] / scale[r]))
                        .sum();
                    residues[(j * m + k) * m + l] = c_v * w_b;
                }
            }
        }
        Ok(Characteristic {
            m,
            delays: system.delayed.iter().map(|d| d.delay_s).collect(),
            eigenvalues,
            residues,
        })
    }

    /// Eigenvalues of the undelayed `A`.
    pub fn eigenvalues(&self) -> &[C64] {
        &self.eigenvalues
    }

    /// `I - Z G(lambda)`, and with `derivative` also its derivative by lambda and
    /// `sum_j 1 / (lambda - mu_j)`.
    fn loop_difference(&self, lambda: C64, derivative: bool) -> (Small, Small, C64) {
        let m = self.m;
        let mut g = [[ZERO; MAX_LOOPS]; MAX_LOOPS];
        let mut g_prime = [[ZERO; MAX_LOOPS]; MAX_LOOPS];
        let mut poles = ZERO;
        for (j, mu) in self.eigenvalues.iter().enumerate() {
            let d = (lambda - mu).inv();
            let block = &self.residues[j * m * m..(j + 1) * m * m];
            for k in 0..m {
                for l in 0..m {
                    g[k][l] += block[k * m + l] * d;
                }
            }
            if derivative {
                let d2 = d * d;
                poles += d;
                for k in 0..m {
                    for l in 0..m {
                        g_prime[k][l] -= block[k * m + l] * d2;
                    }
                }
            }
        }
        let mut k_matrix = [[ZERO; MAX_LOOPS]; MAX_LOOPS];
        let mut k_prime = [[ZERO; MAX_LOOPS]; MAX_LOOPS];
        for (row, &tau) in self.delays.iter().enumerate() {
            let z = (-lambda * tau).exp();
            for col in 0..m {
                k_matrix[row][col] = if row == col { ONE } else { ZERO } - z * g[row][col];
                k_prime[row][col] = z * tau * g[row][col] - z * g_prime[row][col];
            }
        }
        (k_matrix, k_prime, poles)
    }

    /// `det(I - Z G(lambda))` and the Frobenius norm of `Z G`.
    fn loop_determinant(&self, lambda: C64) -> (C64, f64) {
        let (mut k, _, _) = self.loop_difference(lambda, false);
        let mut gain = 0.0;
        for (row, k_row) in k.iter().enumerate().take(self.m) {
            for (col, value) in k_row.iter().enumerate().take(self.m) {
                let identity = if row == col { ONE } else { ZERO };
                gain += (identity - value).norm_sqr();
            }
        }
        let (determinant, _) = small_lu(&mut k, self.m);
        (determinant, gain.sqrt())
    }

    /// `d/dlambda ln det(lambda I - A - sum B_k e^(-lambda tau_k))`.
    pub(crate) fn log_derivative(&self, lambda: C64) -> Option<C64> {
        let (mut k, k_prime, poles) = self.loop_difference(lambda, true);
        let m = self.m;
        let (determinant, pivots) = small_lu(&mut k, m);
        if determinant.norm() == 0.0 {
            return None;
        }
        // tr(K^-1 K'): solve K X = K' column by column with the factors.
        let mut trace = ZERO;
        for col in 0..m {
            let mut x = [ZERO; MAX_LOOPS];
            for (row, slot) in x.iter_mut().enumerate().take(m) {
                *slot = k_prime[pivots[row]][col];
            }
            for row in 0..m {
                for inner in 0..row {
                    let above = x[inner];
                    x[row] -= k[row][inner] * above;
                }
            }
            for row in (0..m).rev() {
                for inner in row + 1..m {
                    let below = x[inner];
                    x[row] -= k[row][inner] * below;
                }
                x[row] /= k[row][row];
            }
            trace += x[col];
        }
        let value = poles + trace;
        (value.re.is_finite() && value.im.is_finite()).then_some(value)
    }

    /// The root Newton's method reaches from `start`, if it converges.
    pub(crate) fn newton(&self, start: C64) -> Option<C64> {
        let tau_max = self.delays.iter().fold(0.0_f64, |a, &b| a.max(b));
        // At most one chain spacing per step, so a start stays near its own root.
        let max_step = std::f64::consts::TAU / tau_max.max(1e-3);
        let mut lambda = start;
        for _ in 0..NEWTON_ITERATIONS {
            let derivative = self.log_derivative(lambda)?;
            if derivative.norm() == 0.0 {
                return None;
            }
            let mut step = derivative.inv();
            if step.norm() > max_step {
                step *= max_step / step.norm();
            }
            lambda -= step;
            if lambda.re < LEFTMOST_FOLLOWED {
                return None;
            }
            if step.norm() <= 1e-11 * lambda.norm().max(1.0) {
                return Some(C64::new(lambda.re, lambda.im.abs()));
            }
        }
        None
    }

    /// Number of characteristic roots (conjugates counted) with real part > `alpha`,
    /// by the argument principle (see the module docs).
    ///
    /// The phase of `det(I - Z G)` is followed along `alpha + i omega`. Where
    /// `|Z G|_F < sin(pi / m)` every eigenvalue of `I - Z G` stays within `pi / m` of
    /// the positive real axis, so the determinant's principal phase is its continuous
    /// phase and the fast turning of the delay factors needs no sampling; elsewhere the
    /// steps are short enough (a quarter turn of the delay factors, a tenth of the
    /// distance to the nearest eigenvalue of `A`) that no turn is missed.
    pub fn count_right_of(&self, alpha: f64) -> Option<usize> {
        let tau_sum: f64 = self.delays.iter().sum();
        let spectral_radius = self
            .eigenvalues
            .iter()
            .fold(0.0_f64, |a, mu| a.max(mu.norm()));
        let safe_gain = 0.9 * (std::f64::consts::PI / self.m.max(2) as f64).sin();
        let delay_step = 0.25 / tau_sum.max(1e-3);
        let sample = |omega: f64| -> Option<(C64, bool)> {
            let (determinant, loop_gain) = self.loop_determinant(C64::new(alpha, omega));
            (determinant.re.is_finite() && determinant.im.is_finite())
                .then_some((determinant, loop_gain < safe_gain))
        };
        let nearest = |omega: f64| {
            self.eigenvalues
                .iter()
                .map(|mu| (C64::new(alpha, omega) - mu).norm())
                .fold(f64::INFINITY, f64::min)
        };
        let (mut previous, mut previous_safe) = sample(0.0)?;
        let mut omega = 0.0;
        let mut winding = 0.0;
        let end = 2.0 * spectral_radius.max(1.0);
        while omega < end || !previous_safe {
            let mut step = (0.1 * nearest(omega)).max(1e-6);
            if !previous_safe {
                step = step.min(delay_step);
            }
            loop {
                let (next, next_safe) = sample(omega + step)?;
                if previous_safe && next_safe {
                    winding += next.arg() - previous.arg();
                } else {
                    let turn = (next / previous).arg();
                    if turn.abs() > 0.5 && step > 1e-9 {
                        step *= 0.25;
                        continue;
                    }
                    winding += turn;
                }
                previous = next;
                previous_safe = next_safe;
                omega += step;
                break;
            }
            if omega > 100.0 * end {
                return None;
            }
        }
        // Beyond `end` the loop stays weak and det(I - Z G) -> 1 without a turn.
        winding -= previous.arg();
        let unstable_poles = self.eigenvalues.iter().filter(|mu| mu.re > alpha).count() as f64;
        let count = unstable_poles - winding / std::f64::consts::PI;
        let rounded = count.round();
        ((count - rounded).abs() < 0.1 && rounded >= 0.0).then_some(rounded as usize)
    }

    /// Frequencies (rad/s) where the loop may reach a gain of one for roots right of
    /// `alpha`: `|Z G(alpha + i omega)|_F >= 0.5` on a 1 Hz grid.
    fn loop_band(&self, alpha: f64) -> Vec<(f64, f64)> {
        let top = self
            .eigenvalues
            .iter()
            .fold(0.0_f64, |a, mu| a.max(mu.im.abs()))
            * 1.5;
        let step = std::f64::consts::TAU;
        let mut bands: Vec<(f64, f64)> = Vec::new();
        let mut omega = 0.0;
        while omega <= top {
            let (_, gain) = self.loop_determinant(C64::new(alpha, omega));
            if gain >= 0.5 {
                match bands.last_mut() {
                    Some(band) if band.1 >= omega - step => band.1 = omega + step,
                    _ => bands.push(((omega - step).max(0.0), omega + step)),
                }
            }
            omega += step;
        }
        bands
    }

    /// Every root Newton reaches from the starts described in the module docs.
    pub fn roots_near_axis(&self, alpha_floor: f64, density: f64) -> Vec<C64> {
        let tau_max = self.delays.iter().fold(0.0_f64, |a, &b| a.max(b));
        let spacing = std::f64::consts::PI / tau_max.max(1e-3) / density;
        let mut starts: Vec<C64> = Vec::new();
        for (low, high) in self.loop_band(alpha_floor) {
            let mut omega = low;
            while omega <= high {
                starts.push(C64::new(0.0, omega));
                omega += spacing;
            }
        }
        starts.extend(self.eigenvalues.iter().filter(|mu| mu.im >= 0.0));
        let mut roots: Vec<C64> = Vec::new();
        for start in starts {
            if let Some(root) = self.newton(start) {
                if !roots
                    .iter()
                    .any(|r| (r - root).norm() <= 1e-7 * root.norm().max(1.0))
                {
                    roots.push(root);
                }
            }
        }
        roots.sort_by(|a, b| b.re.total_cmp(&a.re));
        roots
    }

    /// The rightmost characteristic root, certified by the argument principle.
    pub fn rightmost(&self) -> Result<Root, RootsError> {
        let mut last = None;
        for (floor, density) in [(0.0, 1.0), (-3.0, 1.0), (-20.0, 2.0), (-100.0, 4.0)] {
            let roots = self.roots_near_axis(floor, density);
            let Some(&best) = roots.first() else {
                continue;
            };
            let margin = 1e-3 + 1e-6 * best.norm();
            match self.count_right_of(best.re + margin) {
                Some(0) => return Ok(Root::from_lambda(best)),
                Some(count) => {
                    last = Some(RootsError::Unverified {
                        count,
                        real_per_s: best.re,
                    })
                }
                None => last = Some(RootsError::NotFound),
            }
        }
        Err(last.unwrap_or(RootsError::NotFound))
    }
}

/// LU factorisation with partial pivoting of the leading m x m block in place (unit
/// lower factor below the diagonal, with row exchanges applied to whole rows);
/// returns the determinant and the row order (row i of the factors is original row
/// `order[i]`).
fn small_lu(a: &mut Small, m: usize) -> (C64, [usize; MAX_LOOPS]) {
    let mut order = [0; MAX_LOOPS];
    for (i, slot) in order.iter_mut().enumerate() {
        *slot = i;
    }
    let mut determinant = ONE;
    for k in 0..m {
        let pivot = (k..m)
            .max_by(|&x, &y| a[x][k].norm().total_cmp(&a[y][k].norm()))
            .unwrap_or(k);
        if pivot != k {
            a.swap(pivot, k);
            order.swap(pivot, k);
            determinant = -determinant;
        }
        let diagonal = a[k][k];
        determinant *= diagonal;
        if diagonal.norm() == 0.0 {
            return (ZERO, order);
        }
        let pivot_row = a[k];
        for row in a.iter_mut().take(m).skip(k + 1) {
            let factor = row[k] / diagonal;
            row[k] = factor;
            for (value, above) in row.iter_mut().zip(&pivot_row).take(m).skip(k + 1) {
                *value -= factor * above;
            }
        }
    }
    (determinant, order)
}

/// Diagonal scaling (powers of 2) that balances the row and column norms of `a`
/// (Parlett and Reinsch), so the Schur and Hessenberg forms keep relative accuracy:
/// the SI state mixes micrometres and megapascals.
fn balance(a: &DMatrix<f64>) -> Vec<f64> {
    let n = a.nrows();
    let mut scale = vec![1.0_f64; n];
    for _ in 0..100 {
        let mut converged = true;
        for i in 0..n {
            let (mut column, mut row) = (0.0, 0.0);
            for j in 0..n {
                if j != i {
                    column += (a[(j, i)] * scale[i] / scale[j]).abs();
                    row += (a[(i, j)] * scale[j] / scale[i]).abs();
                }
            }
            if column == 0.0 || row == 0.0 {
                continue;
            }
            let mut factor = 1.0;
            let (mut c, mut r) = (column, row);
            while c < r / 2.0 {
                c *= 2.0;
                r /= 2.0;
                factor *= 2.0;
            }
            while c > r * 2.0 {
                c /= 2.0;
                r *= 2.0;
                factor /= 2.0;
            }
            if factor != 1.0 {
                scale[i] *= factor;
                converged = false;
            }
        }
        if converged {
            break;
        }
    }
    scale
}

/// Gaussian elimination of `lambda I - H` (H upper Hessenberg), pivoting between
/// neighbouring rows: O(n^2). Hand-rolled because nalgebra's LU is O(n^3) and knows
/// no Hessenberg structure.
struct HessenbergLu {
    n: usize,
    /// Upper triangle, row-major.
    upper: Vec<C64>,
    multipliers: Vec<C64>,
    swapped: Vec<bool>,
}

impl HessenbergLu {
    fn new(hessenberg: &[f64], n: usize, lambda: C64) -> Option<HessenbergLu> {
        let mut upper: Vec<C64> = hessenberg.iter().map(|&v| C64::new(-v, 0.0)).collect();
        for i in 0..n {
            upper[i * n + i] += lambda;
        }
        let mut multipliers = vec![C64::new(0.0, 0.0); n.saturating_sub(1)];
        let mut swapped = vec![false; n.saturating_sub(1)];
        for k in 0..n.saturating_sub(1) {
            if upper[(k + 1) * n + k].norm() > upper[k * n + k].norm() {
                for j in k..n {
                    upper.swap(k * n + j, (k + 1) * n + j);
                }
                swapped[k] = true;
            }
            let pivot = upper[k * n + k];
            if pivot.norm() == 0.0 {
                return None;
            }
            let factor = upper[(k + 1) * n + k] / pivot;
            multipliers[k] = factor;
            upper[(k + 1) * n + k] = C64::new(0.0, 0.0);
            for j in k + 1..n {
                let above = upper[k * n + j];
                upper[(k + 1) * n + j] -= factor * above;
            }
        }
        if n > 0 && upper[n * n - 1].norm() == 0.0 {
            return None;
        }
        Some(HessenbergLu {
            n,
            upper,
            multipliers,
            swapped,
        })
    }

    /// Solves in place for `columns` right-hand sides (row-major n x columns).
    fn solve(&self, rhs: &mut [C64], columns: usize) {
        let n = self.n;
        for k in 0..n.saturating_sub(1) {
            for c in 0..columns {
                if self.swapped[k] {
                    rhs.swap(k * columns + c, (k + 1) * columns + c);
                }
                let above = rhs[k * columns + c];
                rhs[(k + 1) * columns + c] -= self.multipliers[k] * above;
            }
        }
        for i in (0..n).rev() {
            for c in 0..columns {
                let mut value = rhs[i * columns + c];
                for j in i + 1..n {
                    value -= self.upper[i * n + j] * rhs[j * columns + c];
                }
                rhs[i * columns + c] = value / self.upper[i * n + i];
            }
        }
    }
}

/// The speed factor where the mill's rightmost root crosses the imaginary axis.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CriticalSpeed {
    /// Speed factor (times the schedule's roll speeds).
    pub speed: f64,
    /// Frequency of the rightmost root just above it, Hz.
    pub frequency_hz: f64,
}

/// Whether `mill` is stable at speed factor `speed`: no characteristic root right of
/// the imaginary axis, counted by the argument principle (exact, no root search).
pub fn is_stable(mill: &TandemMill, speed: f64) -> Result<bool, RootsError> {
    let characteristic = Characteristic::new(&mill.linear_system(speed))?;
    Ok(characteristic
        .count_right_of(0.0)
        .ok_or(RootsError::NotFound)?
        == 0)
}

/// The lowest speed factor in `low..=high` where `mill` turns unstable, to a relative
/// `tolerance`: the first unstable point on a grid of 0.1, then bisection; stability
/// by [`is_stable`]. The frequency is that of the rightmost root at the unstable end.
pub fn critical_speed(
    mill: &TandemMill,
    low: f64,
    high: f64,
    tolerance: f64,
) -> Result<CriticalSpeed, RootsError> {
    if !is_stable(mill, low)? {
        return Err(RootsError::UnstableInRange { low });
    }
    let mut stable = low;
    let mut unstable = None;
    let steps = ((high - low) / 0.1).ceil().max(1.0) as usize;
    for step in 1..=steps {
        let speed = (low + step as f64 * 0.1).min(high);
        if !is_stable(mill, speed)? {
            unstable = Some(speed);
            break;
        }
        stable = speed;
    }
    let mut unstable = unstable.ok_or(RootsError::StableInRange { high })?;
    while unstable - stable > tolerance * unstable {
        let middle = 0.5 * (stable + unstable);
        if is_stable(mill, middle)? {
            stable = middle;
        } else {
            unstable = middle;
        }
    }
    let crossing = Characteristic::new(&mill.linear_system(unstable))?.rightmost()?;
    Ok(CriticalSpeed {
        speed: 0.5 * (stable + unstable),
        frequency_hz: crossing.frequency_hz,
    })
}
