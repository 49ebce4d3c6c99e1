//! Small fixed-size numerics shared by the eq. (1) fit ([`crate::fit`]) and the
//! matrix pencil ([`crate::pencil`]), on plain arrays: nalgebra's generic
//! decompositions took a large share of their time on these tiny matrices.
//!
//! - [`peak_magnitude`]: the scale both work at (data scaled to a peak of 1);
//! - [`Cholesky5`]: 5 x 5 Cholesky factor and solves (the fit's normal equations);
//! - [`symmetric_eigen`]: symmetric eigendecomposition (the pencil's Gram matrix);
//! - [`general_eigenvalues`]: eigenvalues of a general real matrix (the pencil's poles):
//!   Francis QR, or to the start's precision the characteristic polynomial's roots
//!   by Aberth-Ehrlich iterations;
//! - [`Precision`]: how far both eigenvalue iterations go.

use nalgebra::{Complex, SMatrix, SVector};

/// Largest |sample| and whether all samples are finite, in one branch-free pass: four
/// lanes (samples 4k + i), each a running maximum of |v| and a sum of v * 0 that stays
/// 0 unless a sample is NaN or infinite. (One maximum and a flag per sample were a
/// chain of scalar comparisons: 3% of a fit of 500 samples, perf.)
pub(crate) fn peak_magnitude(samples: &[f64]) -> (f64, bool) {
    let mut peaks = [0.0_f64; 4];
    let mut poison = [0.0_f64; 4];
    let take = |peak: &mut f64, poison: &mut f64, value: f64| {
        let magnitude = libm::fabs(value);
        // NaN compares false: left to `poison`.
        *peak = if magnitude > *peak { magnitude } else { *peak };
        *poison += value * 0.0;
    };
    let chunks = samples.chunks_exact(4);
    for ((peak, poison), &value) in peaks.iter_mut().zip(&mut poison).zip(chunks.remainder()) {
        take(peak, poison, value);
    }
    for chunk in chunks {
        for ((peak, poison), &value) in peaks.iter_mut().zip(&mut poison).zip(chunk) {
            take(peak, poison, value);
        }
    }
    let [a, b, c, d] = peaks;
    (a.max(b).max(c.max(d)), poison.iter().all(|p| *p == 0.0))
}

/// Cholesky factor L (lower, L L^T = A) of a 5 x 5 symmetric positive definite matrix,
/// on plain arrays: nalgebra's generic `cholesky` and triangular solves took a tenth of
/// the fit's time on these tiny matrices.
#[derive(Clone, Copy)]
pub(crate) struct Cholesky5 {
    lower: [[f64; 5]; 5],
    /// 1 / `L[i][i]`.
    inverse_diagonal: [f64; 5],
}

// Index loops: the factorisation and the solves walk rows and columns of `lower` at once.
#[allow(clippy::needless_range_loop)]
impl Cholesky5 {
    /// Factors `a` (lower triangle read); `None` unless positive definite and finite.
    pub(crate) fn new(a: &SMatrix<f64, 5, 5>) -> Option<Self> {
        let mut lower = [[0.0; 5]; 5];
        let mut inverse_diagonal = [0.0; 5];
        for j in 0..5 {
            let mut diagonal = a[(j, j)];
            for k in 0..j {
                diagonal -= lower[j][k] * lower[j][k];
            }
            // Also false for NaN.
            if !(diagonal > 0.0 && diagonal.is_finite()) {
                return None;
            }
            // 1 / sqrt(d) as sqrt(d) * (1 / d): the root and the division run side by
            // side instead of one waiting on the other (the factor is a chain of five).
            let root = libm::sqrt(diagonal);
            lower[j][j] = root;
            inverse_diagonal[j] = root * (1.0 / diagonal);
            for i in j + 1..5 {
                let mut value = a[(i, j)];
                for k in 0..j {
                    value -= lower[i][k] * lower[j][k];
                }
                lower[i][j] = value * inverse_diagonal[j];
            }
        }
        Some(Self {
            lower,
            inverse_diagonal,
        })
    }

    /// Solves L y = b (the forward substitution).
    fn forward(&self, b: &SVector<f64, 5>) -> SVector<f64, 5> {
        let mut y = *b;
        for i in 0..5 {
            let mut value = y[i];
            for k in 0..i {
                value -= self.lower[i][k] * y[k];
            }
            y[i] = value * self.inverse_diagonal[i];
        }
        y
    }

    /// Solves A x = b.
    pub(crate) fn solve(&self, b: &SVector<f64, 5>) -> SVector<f64, 5> {
        let mut x = self.forward(b);
        for i in (0..5).rev() {
            let mut value = x[i];
            for k in i + 1..5 {
                value -= self.lower[k][i] * x[k];
            }
            x[i] = value * self.inverse_diagonal[i];
        }
        x
    }

    /// B^T A^-1 B, as Y^T Y with L Y = B solved column by column: the forward
    /// substitutions only (half the work of solving A X = B for B^T X), and a result
    /// symmetric to the last bit.
    pub(crate) fn inverse_quadratic_form(&self, b: &SMatrix<f64, 5, 5>) -> SMatrix<f64, 5, 5> {
        let mut y = *b;
        for mut column in y.column_iter_mut() {
            let solved = self.forward(&column.clone_owned());
            column.copy_from(&solved);
        }
        y.tr_mul(&y)
    }
}

/// How far [`symmetric_eigen`] and [`general_eigenvalues`] iterate: when an
/// off-diagonal entry counts as zero next to its diagonal neighbours (QL, Francis QR),
/// or when a root's correction counts as zero next to the largest root (the
/// characteristic polynomial's roots that [`general_eigenvalues`] takes to `Start`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Precision {
    /// To rounding (EISPACK's tests): the pencil's public poles, which `mode_damping`
    /// and the simulator's identification use as they are.
    Full,
    /// Below [`START_DEFLATION`] of its neighbours: the eigenvalues to about that
    /// relative size, for a start that an iteration refines (the eq. (1) fit's). The
    /// iterations converge quadratically or faster, so this saves their last sweep
    /// or step, about one in four. The general eigenvalues come from the
    /// characteristic polynomial of the Hessenberg form (Aberth-Ehrlich), whose
    /// coefficients cost the roots about cond * 1e-16 relative, far below this.
    Start,
}

/// Relative size of an off-diagonal entry that [`Precision::Start`] takes for zero.
/// The fit's start needs its poles to far less (the pencil's own error on a noisy
/// record is larger), and the Levenberg-Marquardt iteration refines them.
pub(crate) const START_DEFLATION: f64 = 1e-6;

/// Most QL sweeps spent on one eigenvalue before [`symmetric_eigen`] gives up.
const MAX_SWEEPS: usize = 60;

/// Eigenvalues and eigenvectors of the symmetric matrix `a` (`a[i][j]`, only the lower
/// triangle read): Householder reduction to tridiagonal form, then implicit QL with
/// Wilkinson-like shifts (EISPACK tred2 + tql2), to `precision`. Returns the
/// eigenvalues, unsorted, and the eigenvectors as `vectors[j]` (unit norm) for
/// eigenvalue j; `None` if a value did not converge within [`MAX_SWEEPS`] sweeps. Written out because nalgebra's generic
/// `SymmetricEigen` took 60% of the pencil's time on 12 x 12; this is the same
/// algorithm on plain arrays.
// Index loops: the algorithm walks both triangles of `a` at once.
#[allow(clippy::needless_range_loop)]
pub(crate) fn symmetric_eigen<const N: usize>(
    mut a: [[f64; N]; N],
    precision: Precision,
) -> Option<([f64; N], [[f64; N]; N])> {
    let deflation = match precision {
        Precision::Full => f64::EPSILON,
        Precision::Start => START_DEFLATION,
    };
    let mut d = [0.0_f64; N];
    let mut e = [0.0_f64; N];
    // Householder: row i (from the last) is reflected onto its subdiagonal entry; the
    // reflectors are kept in the rows of `a` and accumulated afterwards.
    for i in (1..N).rev() {
        let l = i - 1;
        let mut h = 0.0;
        if l > 0 {
            let scale: f64 = a[i][..=l].iter().map(|v| libm::fabs(*v)).sum();
            if scale == 0.0 {
                e[i] = a[i][l];
            } else {
                // Products by reciprocals, not divisions in the loops (about 200 of
                // them at 12 x 12, each a slot of the divider).
                let inverse_scale = 1.0 / scale;
                for v in a[i][..=l].iter_mut() {
                    *v *= inverse_scale;
                    h += *v * *v;
                }
                let f = a[i][l];
                let g = if f >= 0.0 {
                    -libm::sqrt(h)
                } else {
                    libm::sqrt(h)
                };
                e[i] = scale * g;
                h -= f * g;
                a[i][l] = f - g;
                let mut f = 0.0;
                let inverse_h = 1.0 / h;
                for j in 0..=l {
                    a[j][i] = a[i][j] * inverse_h;
                    let mut g = 0.0;
                    for k in 0..=j {
                        g += a[j][k] * a[i][k];
                    }
                    for k in j + 1..=l {
                        g += a[k][j] * a[i][k];
                    }
                    e[j] = g * inverse_h;
                    f += e[j] * a[i][j];
                }
                let hh = f / (h + h);
                for j in 0..=l {
                    let f = a[i][j];
                    let g = e[j] - hh * f;
                    e[j] = g;
                    for k in 0..=j {
                        a[j][k] -= f * e[k] + g * a[i][k];
                    }
                }
            }
        } else {
            e[i] = a[i][l];
        }
        d[i] = h;
    }
    d[0] = 0.0;
    e[0] = 0.0;
    // Accumulate the reflectors into the orthogonal matrix, in place.
    for i in 0..N {
        if d[i] != 0.0 {
            for j in 0..i {
                let mut g = 0.0;
                for k in 0..i {
                    g += a[i][k] * a[k][j];
                }
                for k in 0..i {
                    a[k][j] -= g * a[k][i];
                }
            }
        }
        d[i] = a[i][i];
        a[i][i] = 1.0;
        for j in 0..i {
            a[j][i] = 0.0;
            a[i][j] = 0.0;
        }
    }
    // Implicit QL on the tridiagonal (d, e); rotations applied to the rows of the
    // transposed vector matrix, so each touches two contiguous rows.
    let mut vectors = [[0.0_f64; N]; N];
    for (i, row) in vectors.iter_mut().enumerate() {
        for (k, v) in row.iter_mut().enumerate() {
            *v = a[k][i];
        }
    }
    for i in 1..N {
        e[i - 1] = e[i];
    }
    e[N - 1] = 0.0;
    for l in 0..N {
        let mut sweeps = 0;
        loop {
            let mut m = l;
            while m + 1 < N {
                let dd = libm::fabs(d[m]) + libm::fabs(d[m + 1]);
                if libm::fabs(e[m]) <= deflation * dd {
                    break;
                }
                m += 1;
            }
            if m == l {
                break;
            }
            sweeps += 1;
            if sweeps > MAX_SWEEPS {
                return None;
            }
            let mut g = (d[l + 1] - d[l]) / (2.0 * e[l]);
            // Plain square roots, not hypot (a third of the time here): the pencil's
            // matrices are scaled to entries of order 1 to N, far from overflow.
            let mut r = libm::sqrt(g * g + 1.0);
            g = d[m] - d[l] + e[l] / (g + if g >= 0.0 { r } else { -r });
            let (mut s, mut c, mut p) = (1.0, 1.0, 0.0);
            let mut deflated = false;
            for i in (l..m).rev() {
                let f = s * e[i];
                let b = c * e[i];
                let squares = f * f + g * g;
                r = libm::sqrt(squares);
                e[i + 1] = r;
                // Also r == 0. Entries this small relative to the matrix's (of order
                // 1 to N) are zero to the sweep; below it 1 / squares would overflow.
                if squares < f64::MIN_POSITIVE {
                    d[i + 1] -= p;
                    e[m] = 0.0;
                    deflated = true;
                    break;
                }
                // 1 / r as r * (1 / r^2): the root and the division run side by side,
                // not one after the other, on the sweep's chain of rotations.
                let inverse = r * (1.0 / squares);
                s = f * inverse;
                c = g * inverse;
                g = d[i + 1] - p;
                r = (d[i] - g) * s + 2.0 * c * b;
                p = s * r;
                d[i + 1] = g + p;
                g = c * r - b;
                let (low, high) = vectors.split_at_mut(i + 1);
                for (x, y) in low[i].iter_mut().zip(high[0].iter_mut()) {
                    let f = *y;
                    *y = s * *x + c * f;
                    *x = c * *x - s * f;
                }
            }
            if deflated {
                continue;
            }
            d[l] -= p;
            e[l] = g;
            e[m] = 0.0;
        }
    }
    Some((d, vectors))
}

/// Range of p^2 + q^2 + r^2 in which [`general_eigenvalues`] builds a reflector from
/// p, q, r unscaled (from here): no square underflows to lose the sum's precision.
const SAFE_SQUARES_LOW: f64 = 1e-290;
/// Upper end of the range of [`SAFE_SQUARES_LOW`]: no square overflows.
const SAFE_SQUARES_HIGH: f64 = 1e290;

/// Most Francis double-shift QR steps spent on one eigenvalue (or pair) before
/// [`general_eigenvalues`] gives up; exceptional shifts every 10 steps.
const MAX_QR_STEPS: usize = 60;

/// Eigenvalues of the real square matrix `a` (`a[i][j]`, row i, column j) to
/// `precision`, unsorted, complex pairs adjacent; `None` if one did not converge within [`MAX_QR_STEPS`]
/// steps or the input is not finite. Householder reduction to upper Hessenberg form,
/// then, to [`Precision::Full`], Francis double-shift QR with deflation (EISPACK hqr),
/// no Schur vectors: the pencil needs the poles only, and nalgebra's generic `Schur`
/// (which accumulates the vectors) took a fifth of the pencil's time on its 6 x 6
/// matrix. To [`Precision::Start`], the roots of the Hessenberg form's characteristic
/// polynomial by Aberth-Ehrlich iterations ([`polynomial_roots`]), Francis QR where
/// they do not converge.
pub(crate) fn general_eigenvalues<const N: usize>(
    a: [[f64; N]; N],
    precision: Precision,
) -> Option<[Complex<f64>; N]> {
    if a.iter().flatten().any(|v| !v.is_finite()) {
        return None;
    }
    let hessenberg = hessenberg(a);
    if precision == Precision::Start {
        if let Some(roots) = polynomial_roots(&characteristic_polynomial(&hessenberg)) {
            return Some(roots);
        }
    }
    francis_eigenvalues(hessenberg, precision)
}

/// Upper Hessenberg form of `a` by Householder reflections (the same eigenvalues).
// Index loops: the reflections walk rows and columns of `a` at once.
#[allow(clippy::needless_range_loop)]
fn hessenberg<const N: usize>(mut a: [[f64; N]; N]) -> [[f64; N]; N] {
    // Householder: column k below the subdiagonal is reflected onto a[k + 1][k].
    for k in 0..N.saturating_sub(2) {
        let norm = libm::sqrt(a[k + 1..].iter().map(|row| row[k] * row[k]).sum::<f64>());
        if norm == 0.0 {
            continue;
        }
        let alpha = if a[k + 1][k] > 0.0 { -norm } else { norm };
        let mut v = [0.0_f64; N];
        for i in k + 1..N {
            v[i] = a[i][k];
        }
        v[k + 1] -= alpha;
        let v_norm2: f64 = v[k + 1..].iter().map(|x| x * x).sum();
        if v_norm2 == 0.0 {
            continue;
        }
        let beta = 2.0 / v_norm2;
        // From the left: rows k + 1.. of columns k..
        for j in k..N {
            let dot: f64 = (k + 1..N).map(|i| v[i] * a[i][j]).sum();
            let f = beta * dot;
            for i in k + 1..N {
                a[i][j] -= f * v[i];
            }
        }
        // From the right: columns k + 1.. of every row.
        for row in a.iter_mut() {
            let dot: f64 = (k + 1..N).map(|j| row[j] * v[j]).sum();
            let f = beta * dot;
            for j in k + 1..N {
                row[j] -= f * v[j];
            }
        }
        a[k + 1][k] = alpha;
        for row in a[k + 2..].iter_mut() {
            row[k] = 0.0;
        }
    }

    a
}

/// Eigenvalues of the upper Hessenberg matrix `a` by Francis double-shift QR with
/// deflation (EISPACK hqr) to `precision`; `None` if one did not converge within
/// [`MAX_QR_STEPS`] steps.
// Index loops: the QR sweeps walk rows and columns of `a` at once.
#[allow(clippy::needless_range_loop)]
fn francis_eigenvalues<const N: usize>(
    mut a: [[f64; N]; N],
    precision: Precision,
) -> Option<[Complex<f64>; N]> {
    let mut eigenvalues = [Complex::new(0.0, 0.0); N];
    // Scale for negligible subdiagonal entries when both neighbours vanish.
    let mut norm = 0.0;
    for i in 0..N {
        for j in i.saturating_sub(1)..N {
            norm += libm::fabs(a[i][j]);
        }
    }
    // Sum of the exceptional shifts applied to the diagonal.
    let mut shift_total = 0.0;
    // Active block is rows and columns low..=high; high counts down as values deflate.
    let mut high = N;
    while high > 0 {
        let nn = high - 1;
        let mut steps = 0;
        loop {
            // Smallest l such that a[l..=nn] is unreduced (a[l][l - 1] negligible).
            let mut l = nn;
            while l > 0 {
                let mut s = libm::fabs(a[l - 1][l - 1]) + libm::fabs(a[l][l]);
                if s == 0.0 {
                    s = norm;
                }
                let negligible = match precision {
                    Precision::Full => libm::fabs(a[l][l - 1]) + s == s,
                    Precision::Start => libm::fabs(a[l][l - 1]) <= START_DEFLATION * s,
                };
                if negligible {
                    a[l][l - 1] = 0.0;
                    break;
                }
                l -= 1;
            }
            let mut x = a[nn][nn];
            if l == nn {
                eigenvalues[nn] = Complex::new(x + shift_total, 0.0);
                high -= 1;
                break;
            }
            let mut y = a[nn - 1][nn - 1];
            let mut w = a[nn][nn - 1] * a[nn - 1][nn];
            if l + 1 == nn {
                // Trailing 2 x 2 block: its two eigenvalues in closed form.
                let p = 0.5 * (y - x);
                let q = p * p + w;
                let root = libm::sqrt(libm::fabs(q));
                x += shift_total;
                if q >= 0.0 {
                    let z = p + if p >= 0.0 { root } else { -root };
                    eigenvalues[nn - 1] = Complex::new(x + z, 0.0);
                    eigenvalues[nn] = Complex::new(if z != 0.0 { x - w / z } else { x + z }, 0.0);
                } else {
                    eigenvalues[nn - 1] = Complex::new(x + p, root);
                    eigenvalues[nn] = Complex::new(x + p, -root);
                }
                high -= 2;
                break;
            }
            if steps == MAX_QR_STEPS {
                return None;
            }
            if steps > 0 && steps % 10 == 0 {
                // Exceptional shift (ad hoc, as in EISPACK) to break a cycle.
                shift_total += x;
                for i in 0..=nn {
                    a[i][i] -= x;
                }
                let s = libm::fabs(a[nn][nn - 1]) + libm::fabs(a[nn - 1][nn - 2]);
                x = 0.75 * s;
                y = x;
                w = -0.4375 * s * s;
            }
            steps += 1;
            // First column of (H - s1)(H - s2), started as low as two consecutive small
            // subdiagonal entries allow.
            let (mut p, mut q, mut r);
            let mut m = nn - 2;
            loop {
                let z = a[m][m];
                let rr = x - z;
                let ss = y - z;
                p = (rr * ss - w) / a[m + 1][m] + a[m][m + 1];
                q = a[m + 1][m + 1] - z - rr - ss;
                r = a[m + 2][m + 1];
                let inverse = 1.0 / (libm::fabs(p) + libm::fabs(q) + libm::fabs(r));
                p *= inverse;
                q *= inverse;
                r *= inverse;
                if m == l {
                    break;
                }
                let u = libm::fabs(a[m][m - 1]) * (libm::fabs(q) + libm::fabs(r));
                let v = libm::fabs(p)
                    * (libm::fabs(a[m - 1][m - 1]) + libm::fabs(z) + libm::fabs(a[m + 1][m + 1]));
                if u + v == v {
                    break;
                }
                m -= 1;
            }
            for i in m + 2..=nn {
                a[i][i - 2] = 0.0;
                if i != m + 2 {
                    a[i][i - 3] = 0.0;
                }
            }
            // Double-shift QR step: chase the bulge down with 3 x 3 reflectors.
            for k in m..nn {
                // The reflector depends on the ratios of p, q, r only: they are scaled
                // (a division on the chain of the bulge chase) only when their squares
                // would underflow or overflow.
                let mut scale = 1.0;
                let mut squares = p * p + q * q + r * r;
                if k != m {
                    p = a[k][k - 1];
                    q = a[k + 1][k - 1];
                    r = if k + 1 != nn { a[k + 2][k - 1] } else { 0.0 };
                    squares = p * p + q * q + r * r;
                    if !(SAFE_SQUARES_LOW..=SAFE_SQUARES_HIGH).contains(&squares) {
                        scale = libm::fabs(p) + libm::fabs(q) + libm::fabs(r);
                        if scale != 0.0 {
                            let inverse = 1.0 / scale;
                            p *= inverse;
                            q *= inverse;
                            r *= inverse;
                            squares = p * p + q * q + r * r;
                        }
                    }
                }
                let length = libm::sqrt(squares);
                let s = if p >= 0.0 { length } else { -length };
                if s == 0.0 {
                    continue;
                }
                if k == m {
                    if l != m {
                        a[k][k - 1] = -a[k][k - 1];
                    }
                } else {
                    a[k][k - 1] = -s * scale;
                }
                p += s;
                let inverse_s = 1.0 / s;
                let inverse_p = 1.0 / p;
                let (vx, vy, vz) = (p * inverse_s, q * inverse_s, r * inverse_s);
                let (q, r) = (q * inverse_p, r * inverse_p);
                // Rows k, k + 1, k + 2.
                for j in k..=nn {
                    let mut t = a[k][j] + q * a[k + 1][j];
                    if k + 1 != nn {
                        t += r * a[k + 2][j];
                        a[k + 2][j] -= t * vz;
                    }
                    a[k + 1][j] -= t * vy;
                    a[k][j] -= t * vx;
                }
                // Columns k, k + 1, k + 2.
                for i in l..=nn.min(k + 3) {
                    let mut t = vx * a[i][k] + vy * a[i][k + 1];
                    if k + 1 != nn {
                        t += vz * a[i][k + 2];
                        a[i][k + 2] -= t * r;
                    }
                    a[i][k + 1] -= t * q;
                    a[i][k] -= t;
                }
            }
        }
    }
    Some(eigenvalues)
}

/// Most Aberth-Ehrlich iterations [`polynomial_roots`] spends before giving up (to
/// Francis QR). Cubic convergence from the seeds takes far fewer on the pencil's
/// matrices; a multiple root converges only linearly and may run out.
const MAX_ABERTH_ITERATIONS: usize = 40;

/// Coefficients c_0..c_{N-1} (lowest power first) of the monic characteristic
/// polynomial det(z I - h) = z^N + c_{N-1} z^(N-1) + ... + c_0 of the upper
/// Hessenberg `h`, by the recurrence on its leading principal minors (expansion along
/// the last column): p_(r+1) = (z - h_rr) p_r - sum over s < r of
/// h_sr (h_(s+1)s ... h_r(r-1)) p_s.
// Index loops: the recurrence walks the minors' coefficients and `h` at once.
#[allow(clippy::needless_range_loop)]
fn characteristic_polynomial<const N: usize>(h: &[[f64; N]; N]) -> [f64; N] {
    // minors[s]: p_s, monic of degree s (s < N).
    let mut minors = [[0.0_f64; N]; N];
    let mut last = [0.0_f64; N];
    if N == 0 {
        return last;
    }
    minors[0][0] = 1.0;
    for r in 0..N {
        // p_(r+1) without its leading 1 (the z^(r+1) term).
        let mut next = [0.0_f64; N];
        next[1..=r].copy_from_slice(&minors[r][..r]);
        for k in 0..=r {
            next[k] -= h[r][r] * minors[r][k];
        }
        let mut subdiagonal_product = 1.0;
        for s in (0..r).rev() {
            subdiagonal_product *= h[s + 1][s];
            let factor = h[s][r] * subdiagonal_product;
            for k in 0..=s {
                next[k] -= factor * minors[s][k];
            }
        }
        if r + 1 < N {
            next[r + 1] = 1.0;
            minors[r + 1] = next;
        } else {
            last = next;
        }
    }
    last
}

/// The N roots of the monic z^N + c_(N-1) z^(N-1) + ... + c_0 (`coefficients` lowest
/// power first) by simultaneous Aberth-Ehrlich iterations, to a correction below
/// [`START_DEFLATION`] of the largest root; roots within that of the real axis are
/// made real. `None` if they do not converge within [`MAX_ABERTH_ITERATIONS`].
///
/// Each root's correction is p / (p' - p sum 1 / (z_i - z_j)), taken as
/// p Q / (p' Q - p Q') with Q the product of the z_i - z_j: one complex division per
/// root and iteration, and the N roots' corrections independent of each other (the
/// Francis steps it replaces are one chain of square roots and divisions).
fn polynomial_roots<const N: usize>(coefficients: &[f64; N]) -> Option<[Complex<f64>; N]> {
    let zero = Complex::new(0.0, 0.0);
    // Seeds on a circle about the roots' centroid c = -c_(N-1) / N, of their geometric
    // mean distance from it |p(c)|^(1/N), turned off the real axis (the seeds of a real
    // polynomial symmetric about it would stay symmetric).
    let centre = -coefficients[N - 1] / N as f64;
    let mut at_centre = 1.0;
    for &c in coefficients.iter().rev() {
        at_centre = at_centre * centre + c;
    }
    let mut radius = libm::pow(libm::fabs(at_centre), 1.0 / N as f64);
    if !(radius > 0.0 && radius.is_finite()) {
        radius = 1.0;
    }
    let mut roots: [Complex<f64>; N] = core::array::from_fn(|k| {
        let angle = 2.0 * core::f64::consts::PI * (k as f64 + 0.25) / N as f64;
        let (sin, cos) = libm::sincos(angle);
        Complex::new(centre + radius * cos, radius * sin)
    });
    for _ in 0..MAX_ABERTH_ITERATIONS {
        let mut corrections = [zero; N];
        for (i, correction) in corrections.iter_mut().enumerate() {
            let z = roots[i];
            let (mut value, mut derivative) = (Complex::new(1.0, 0.0), zero);
            for &c in coefficients.iter().rev() {
                derivative = derivative * z + value;
                value = value * z + c;
            }
            let (mut product, mut product_derivative) = (Complex::new(1.0, 0.0), zero);
            for (j, &other) in roots.iter().enumerate() {
                if j != i {
                    let difference = z - other;
                    product_derivative = product_derivative * difference + product;
                    product *= difference;
                }
            }
            *correction = value * product / (derivative * product - value * product_derivative);
        }
        let mut largest_root = 0.0_f64;
        let mut largest_correction = 0.0_f64;
        let mut finite = true;
        for (root, correction) in roots.iter_mut().zip(&corrections) {
            *root -= correction;
            // (f64::max passes over NaN: checked apart.)
            finite &= root.re.is_finite() && root.im.is_finite();
            largest_root = largest_root.max(root.norm_sqr());
            largest_correction = largest_correction.max(correction.norm_sqr());
        }
        if !finite {
            return None;
        }
        let tolerance = START_DEFLATION * START_DEFLATION * largest_root;
        if largest_correction <= tolerance {
            for root in roots.iter_mut() {
                if root.im * root.im <= tolerance {
                    root.im = 0.0;
                }
            }
            return Some(roots);
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Q a Q^T with a fixed Householder Q: a matrix with `a`'s spectrum.
    fn householder_similar(a: &[[f64; 6]; 6]) -> [[f64; 6]; 6] {
        let v = [0.3, -0.5, 0.2, 0.7, -0.1, 0.4];
        let v_norm2: f64 = v.iter().map(|x| x * x).sum();
        let q: [[f64; 6]; 6] = core::array::from_fn(|i| {
            core::array::from_fn(|j| f64::from(u8::from(i == j)) - 2.0 * v[i] * v[j] / v_norm2)
        });
        let product = |x: &[[f64; 6]; 6], y: &[[f64; 6]; 6]| -> [[f64; 6]; 6] {
            core::array::from_fn(|i| {
                core::array::from_fn(|j| (0..6).map(|k| x[i][k] * y[k][j]).sum())
            })
        };
        product(&product(&q, a), &q)
    }

    /// The four lanes against one plain scan: every length's remainder, the peak in
    /// each lane, NaN and infinities anywhere.
    #[test]
    fn peak_magnitude_matches_a_plain_scan() {
        let values: [f64; 11] = core::array::from_fn(|i| (i as f64 - 4.3) * [1.0, -2.5][i % 2]);
        for len in 0..=values.len() {
            for special in [
                None,
                Some(f64::NAN),
                Some(f64::INFINITY),
                Some(-f64::INFINITY),
            ] {
                for at in 0..len.max(1) {
                    let mut samples = values;
                    if let Some(value) = special.filter(|_| at < len) {
                        samples[at] = value;
                    }
                    let samples = &samples[..len];
                    let finite = samples.iter().all(|v| v.is_finite());
                    let peak = samples
                        .iter()
                        .filter(|v| !v.is_nan())
                        .fold(0.0_f64, |m, v| m.max(libm::fabs(*v)));
                    assert_eq!(peak_magnitude(samples), (peak, finite), "{samples:?}");
                }
            }
        }
    }

    #[test]
    fn cholesky5_matches_nalgebra() {
        // A Hilbert-like SPD matrix plus a diagonal, and a solve against it.
        let a = SMatrix::<f64, 5, 5>::from_fn(|i, j| {
            1.0 / (1.0 + i as f64 + j as f64) + if i == j { 0.1 * (i + 1) as f64 } else { 0.0 }
        });
        let b = SVector::<f64, 5>::from_fn(|i, _| (i as f64 - 1.5) * 0.7);
        let ours = Cholesky5::new(&a).unwrap();
        let theirs = a.cholesky().unwrap();
        let (x, expected) = (ours.solve(&b), theirs.solve(&b));
        assert!(
            (x - expected).norm() <= 1e-12 * expected.norm(),
            "{x} vs {expected}"
        );
        let residual = a * x - b;
        assert!(residual.norm() <= 1e-12 * b.norm());
        let columns =
            SMatrix::<f64, 5, 5>::from_fn(|i, j| (i * 5 + j) as f64 - 0.3 * (i * i) as f64);
        let form = ours.inverse_quadratic_form(&columns);
        let expected = columns.transpose() * theirs.solve(&columns);
        assert!((form - expected).norm() <= 1e-12 * expected.norm());
        assert_eq!(form, form.transpose());
        // Not positive definite, not finite.
        let mut indefinite = a;
        indefinite[(3, 3)] = -1.0;
        assert!(Cholesky5::new(&indefinite).is_none());
        let mut nan = a;
        nan[(2, 1)] = f64::NAN;
        assert!(Cholesky5::new(&nan).is_none());
    }

    /// Asserts that `vectors` are orthonormal (to 1e-13: rotations keep them so at
    /// any precision) and `a v = lambda v` to `tolerance` for each pair.
    fn assert_eigenpairs<const N: usize>(
        a: &[[f64; N]; N],
        values: &[f64; N],
        vectors: &[[f64; N]; N],
        tolerance: f64,
    ) {
        for (j, vector) in vectors.iter().enumerate() {
            for (k, other) in vectors.iter().enumerate() {
                let dot: f64 = vector.iter().zip(other).map(|(x, y)| x * y).sum();
                let expected = if j == k { 1.0 } else { 0.0 };
                assert!(libm::fabs(dot - expected) < 1e-13, "{j} {k}: {dot}");
            }
            for (row, a_row) in a.iter().enumerate() {
                let product: f64 = a_row.iter().zip(vector).map(|(x, y)| x * y).sum();
                let residual = libm::fabs(product - values[j] * vector[row]);
                assert!(residual <= tolerance, "{j}: {residual}");
            }
        }
    }

    #[test]
    fn symmetric_eigen_diagonalises() {
        // Symmetric, with a cluster of close eigenvalues and a zero row and column.
        let a: [[f64; 7]; 7] = core::array::from_fn(|i| {
            core::array::from_fn(|j| match (i, j) {
                (6, _) | (_, 6) => 0.0,
                _ => 1.0 / (1.0 + i as f64 + j as f64) + if i == j { 0.5 } else { 0.0 },
            })
        });
        let (values, vectors) = symmetric_eigen(a, Precision::Full).unwrap();
        assert_eigenpairs(&a, &values, &vectors, 1e-13);
        let mut sorted = values;
        sorted.sort_unstable_by(f64::total_cmp);
        assert!(libm::fabs(sorted[0]) < 1e-14, "{sorted:?}");
        let expected = SMatrix::<f64, 7, 7>::from_fn(|i, j| a[i][j]).symmetric_eigenvalues();
        let mut expected: [f64; 7] = expected.into();
        expected.sort_unstable_by(f64::total_cmp);
        for (x, y) in sorted.iter().zip(expected) {
            assert!(libm::fabs(x - y) < 1e-13, "{sorted:?} vs {expected:?}");
        }
    }

    /// [`Precision::Start`] stops short of rounding but keeps the vectors orthonormal
    /// (rotations) and the eigenvalues within the deflated entries' size.
    #[test]
    fn symmetric_eigen_to_the_start_precision() {
        let a: [[f64; 12]; 12] = core::array::from_fn(|i| {
            core::array::from_fn(|j| {
                1.0 / (1.0 + i as f64 + j as f64) + if i == j { 0.01 * i as f64 } else { 0.0 }
            })
        });
        let (full, _) = symmetric_eigen(a, Precision::Full).unwrap();
        let (start, vectors) = symmetric_eigen(a, Precision::Start).unwrap();
        let norm = full.iter().fold(0.0_f64, |m, v| m.max(libm::fabs(*v)));
        assert_eigenpairs(&a, &start, &vectors, 2.0 * START_DEFLATION * norm);
        let (mut full, mut start) = (full, start);
        full.sort_unstable_by(f64::total_cmp);
        start.sort_unstable_by(f64::total_cmp);
        for (x, y) in start.iter().zip(full) {
            assert!(
                libm::fabs(x - y) <= 2.0 * START_DEFLATION * norm,
                "{start:?} {full:?}"
            );
        }
    }

    /// Eigenvalues of `a` by nalgebra's Schur decomposition, for comparison.
    fn reference_eigenvalues(a: &[[f64; 6]; 6]) -> [Complex<f64>; 6] {
        let matrix = SMatrix::<f64, 6, 6>::from_fn(|i, j| a[i][j]);
        let values = nalgebra::Schur::new(matrix).complex_eigenvalues();
        core::array::from_fn(|i| values[i])
    }

    /// Asserts that `found` and `expected` are the same multiset to `tolerance`.
    fn assert_same_eigenvalues<const N: usize>(
        found: &[Complex<f64>; N],
        expected: &[Complex<f64>; N],
        tolerance: f64,
    ) {
        let mut taken = [false; N];
        for value in found {
            let nearest = (0..N)
                .filter(|&j| !taken[j])
                .min_by(|&i, &j| {
                    (expected[i] - value)
                        .norm()
                        .total_cmp(&(expected[j] - value).norm())
                })
                .unwrap();
            taken[nearest] = true;
            assert!(
                (expected[nearest] - value).norm() <= tolerance,
                "{found:?} vs {expected:?}"
            );
        }
    }

    #[test]
    fn general_eigenvalues_match_nalgebra() {
        // Deterministic pseudo-random matrices (LCG): non-normal, with complex pairs.
        let mut state = 0x2545_f491_4f6c_dd1d_u64;
        let mut next = || {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1);
            (state >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
        };
        for _ in 0..200 {
            let a: [[f64; 6]; 6] = core::array::from_fn(|_| core::array::from_fn(|_| next()));
            let expected = reference_eigenvalues(&a);
            let found = general_eigenvalues(a, Precision::Full).unwrap();
            assert_same_eigenvalues(&found, &expected, 1e-12);
            // To the start's precision: the deflated entries' size, times the
            // eigenvalues' condition (these random matrices are far from normal).
            let found = general_eigenvalues(a, Precision::Start).unwrap();
            assert_same_eigenvalues(&found, &expected, 100.0 * START_DEFLATION);
        }
    }

    /// The characteristic polynomial of a Hessenberg form: its value at each
    /// eigenvalue of a matrix with a known spectrum is zero to rounding, and it is
    /// monic (z^6 dominates far from the spectrum).
    #[test]
    fn characteristic_polynomial_vanishes_at_the_eigenvalues() {
        // Eigenvalues 1, 0.86, 0.9 e^(+-0.3i), 0.95 e^(+-0.52i) (the pencil's kind:
        // the constant, the load, two damped modes), as a real block-diagonal matrix
        // turned by a Householder similarity, then reduced.
        let pair = |modulus: f64, angle: f64| {
            let (sin, cos) = libm::sincos(angle);
            [
                [modulus * cos, -modulus * sin],
                [modulus * sin, modulus * cos],
            ]
        };
        let (mode1, mode2) = (pair(0.9, 0.3), pair(0.95, 0.52));
        let mut a = [[0.0_f64; 6]; 6];
        a[0][0] = 1.0;
        a[1][1] = 0.86;
        for i in 0..2 {
            for j in 0..2 {
                a[2 + i][2 + j] = mode1[i][j];
                a[4 + i][4 + j] = mode2[i][j];
            }
        }
        let turned = householder_similar(&a);
        let coefficients = characteristic_polynomial(&hessenberg(turned));
        let evaluate = |z: Complex<f64>| {
            coefficients
                .iter()
                .rev()
                .fold(Complex::new(1.0, 0.0), |value, &c| value * z + c)
        };
        let polar = |modulus: f64, angle: f64| Complex::from_polar(modulus, angle);
        let expected = [
            Complex::new(1.0, 0.0),
            Complex::new(0.86, 0.0),
            polar(0.9, 0.3),
            polar(0.9, -0.3),
            polar(0.95, 0.52),
            polar(0.95, -0.52),
        ];
        for z in expected {
            assert!(evaluate(z).norm() < 1e-14, "{z}: {}", evaluate(z));
        }
        // Monic of degree 6: p(z) / z^6 -> 1.
        let far = Complex::new(1e4, 0.0);
        assert!((evaluate(far) / far.powu(6) - 1.0).norm() < 1e-3);
        // The roots: the same spectrum, the real ones exactly real.
        let roots = polynomial_roots(&coefficients).unwrap();
        assert_same_eigenvalues(&roots, &expected, 1e-10);
        assert_eq!(roots.iter().filter(|z| z.im == 0.0).count(), 2, "{roots:?}");
        assert_eq!(
            general_eigenvalues(turned, Precision::Start),
            Some(roots),
            "Start takes the roots"
        );
    }

    /// Roots of small known polynomials (none real, one real), and `None`, never NaN
    /// roots, for non-finite coefficients.
    #[test]
    fn polynomial_roots_of_known_polynomials() {
        // z^2 + 1: a pair, neither made real.
        let roots = polynomial_roots(&[1.0, 0.0]).unwrap();
        assert_same_eigenvalues(
            &roots,
            &[Complex::new(0.0, 1.0), Complex::new(0.0, -1.0)],
            1e-10,
        );
        assert!(polynomial_roots(&[f64::NAN, 0.0, 1.0]).is_none());
        assert!(polynomial_roots(&[1.0, f64::INFINITY, 0.0]).is_none());
        // z^3 - 1: one real root, a pair at +-120 degrees.
        let roots = polynomial_roots(&[-1.0, 0.0, 0.0]).unwrap();
        let third = 2.0 * core::f64::consts::PI / 3.0;
        let expected = [
            Complex::new(1.0, 0.0),
            Complex::from_polar(1.0, third),
            Complex::from_polar(1.0, -third),
        ];
        assert_same_eigenvalues(&roots, &expected, 1e-10);
    }

    /// Degenerate spectra to the start's precision: the zero matrix (a polynomial z^6,
    /// whose roots' centroid and spread are 0) and a six-fold eigenvalue (a Jordan
    /// block: the roots converge only linearly, or Francis QR takes over), each
    /// eigenvalue to the sixth root of rounding the block allows.
    #[test]
    fn general_eigenvalues_of_degenerate_spectra_to_the_start_precision() {
        let zero = general_eigenvalues([[0.0; 6]; 6], Precision::Start).unwrap();
        assert_same_eigenvalues(&zero, &[Complex::new(0.0, 0.0); 6], 1e-12);
        let jordan: [[f64; 6]; 6] = core::array::from_fn(|i| {
            core::array::from_fn(|j| match j as isize - i as isize {
                0 => 0.9,
                1 => 1.0,
                _ => 0.0,
            })
        });
        let found = general_eigenvalues(jordan, Precision::Start).unwrap();
        assert_same_eigenvalues(&found, &[Complex::new(0.9, 0.0); 6], 1e-2);
    }

    #[test]
    fn general_eigenvalues_of_known_spectra() {
        // Triangular plus a rotation block: eigenvalues 2, -1, 0.5 +- 0.25i, 3, 3.
        let a = [
            [2.0, 1.0, 0.5, -0.3, 0.2, 0.1],
            [0.0, -1.0, 0.7, 0.4, -0.6, 0.9],
            [0.0, 0.0, 0.5, 0.25, 1.5, -2.0],
            [0.0, 0.0, -0.25, 0.5, 0.3, 0.8],
            [0.0, 0.0, 0.0, 0.0, 3.0, 1.0],
            [0.0, 0.0, 0.0, 0.0, 0.0, 3.0],
        ];
        let expected = [
            Complex::new(2.0, 0.0),
            Complex::new(-1.0, 0.0),
            Complex::new(0.5, 0.25),
            Complex::new(0.5, -0.25),
            Complex::new(3.0, 0.0),
            Complex::new(3.0, 0.0),
        ];
        let found = general_eigenvalues(a, Precision::Full).unwrap();
        assert_same_eigenvalues(&found, &expected, 1e-12);
        // A similarity transform keeps the spectrum: Q a Q^T with a Householder Q.
        let similar = householder_similar(&a);
        let found = general_eigenvalues(similar, Precision::Full).unwrap();
        // The double eigenvalue 3 (a Jordan block) is only determined to sqrt(eps).
        assert_same_eigenvalues(&found, &expected, 1e-7);
        // To the start's precision (the polynomial's roots, or Francis QR where they
        // do not converge): the double eigenvalue to the square root of it.
        for matrix in [a, similar] {
            let found = general_eigenvalues(matrix, Precision::Start).unwrap();
            assert_same_eigenvalues(&found, &expected, 1e-3);
        }
        assert_same_eigenvalues(&found, &reference_eigenvalues(&similar), 1e-7);
        assert!(general_eigenvalues([[f64::NAN; 6]; 6], Precision::Full).is_none());
    }
}
