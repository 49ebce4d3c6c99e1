//! Modal analysis of the linear driveline (chain or tree): natural frequencies and
//! mass-normalised mode shapes of K x = w^2 M x.
//!
//! A tree model is analysed in its default configuration, referred to mass 0's shaft
//! (`Tree::modes`, defined here, for another configuration). The drive is free (the
//! motor side is not grounded and the PI controller is not part of K), so the first
//! mode is the rigid-body mode at 0 Hz. Backlash is ignored: the couplings are taken
//! at their full stiffness.

use std::f64::consts::TAU;

use nalgebra::{DMatrix, SymmetricEigen};

use crate::model::Model;
use crate::tree::Tree;

/// Eigenvalues below this fraction of the largest are rounded to 0 (rigid-body mode).
const RIGID_BODY_TOLERANCE: f64 = 1.0e-12;

/// Natural frequencies and mode shapes of a chain, sorted by ascending frequency.
#[derive(Debug, Clone, PartialEq)]
pub struct Modes {
    /// Natural frequencies, Hz, ascending; the rigid-body mode (0 Hz) first for a free
    /// chain.
    pub frequencies_hz: Vec<f64>,
    /// Mass-normalised mode shapes (x^T M x = 1), one column per frequency, one row
    /// per mass, rad per sqrt(kg*m^2). The sign is chosen so that the entry of
    /// largest magnitude is positive.
    pub shapes: DMatrix<f64>,
}

/// Why a modal analysis failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum ModalError {
    /// The mass matrix is not positive definite (an inertia <= 0 or not finite).
    #[error("the mass matrix is not positive definite (every inertia must be > 0)")]
    MassNotPositiveDefinite,
    /// The matrices are not square or do not have the same size.
    #[error("mass and stiffness matrices must be square and of the same size")]
    Shape,
    /// The model's couplings do not form a tree (it was not validated).
    #[error("the model's couplings do not join every mass exactly once (validate the model)")]
    Topology,
}

impl Modes {
    /// Mode `index` as a vector over the masses (rows of [`Modes::shapes`]).
    pub fn shape(&self, index: usize) -> Vec<f64> {
        self.shapes.column(index).iter().copied().collect()
    }

    /// Mode `index` scaled to unit Euclidean norm (the normalisation of the paper's
    /// Table 3), same sign convention as [`Modes::shapes`].
    pub fn unit_shape(&self, index: usize) -> Vec<f64> {
        let column = self.shapes.column(index);
        let norm = column.norm();
        column.iter().map(|value| value / norm).collect()
    }

    /// The elastic natural frequencies, Hz, ascending: every one but the rigid-body
    /// mode (rounded to exactly 0).
    pub(crate) fn elastic_hz(&self) -> impl Iterator<Item = f64> + '_ {
        self.frequencies_hz.iter().copied().filter(|&f| f > 0.0)
    }
}

impl Tree {
    /// Natural frequencies and mass-normalised mode shapes (referred coordinates).
    pub fn modes(&self) -> Result<Modes, ModalError> {
        solve(&self.mass_matrix(), &self.stiffness_matrix())
    }
}

/// Mass matrix diag(inertias) of a chain model (no gear ratios), kg*m^2.
pub fn mass_matrix(model: &Model) -> DMatrix<f64> {
    let inertias: Vec<f64> = model.masses.iter().map(|mass| mass.inertia).collect();
    DMatrix::from_diagonal(&nalgebra::DVector::from_vec(inertias))
}

/// Tridiagonal chain matrix of per-coupling coefficients (stiffness or damping).
///
/// `coefficients[i]` joins mass `i` and mass `i + 1`; the result is `n x n` with
/// `n = coefficients.len() + 1`.
pub fn chain_matrix(coefficients: &[f64]) -> DMatrix<f64> {
    let n = coefficients.len() + 1;
    let mut matrix = DMatrix::zeros(n, n);
    for (i, &c) in coefficients.iter().enumerate() {
        matrix[(i, i)] += c;
        matrix[(i + 1, i + 1)] += c;
        matrix[(i, i + 1)] -= c;
        matrix[(i + 1, i)] -= c;
    }
    matrix
}

/// Stiffness matrix of a chain model (couplings at full stiffness), N*m/rad.
pub fn stiffness_matrix(model: &Model) -> DMatrix<f64> {
    let stiffnesses: Vec<f64> = model.couplings.iter().map(|c| c.stiffness).collect();
    chain_matrix(&stiffnesses)
}

/// Natural frequencies and mode shapes of a validated model (backlash ignored); a
/// tree in its default configuration, referred to mass 0's shaft.
///
/// # Example
/// ```
/// let model = millgate_sim::model::Model::load(concat!(
///     env!("CARGO_MANIFEST_DIR"),
///     "/models/table2-adjusted.toml"
/// ))?;
/// let modes = millgate_sim::modal::modes(&model)?;
/// assert!(modes.frequencies_hz[0].abs() < 1e-6); // rigid-body mode
/// assert!((modes.frequencies_hz[1] - 12.03).abs() < 0.01);
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub fn modes(model: &Model) -> Result<Modes, ModalError> {
    model.tree(None).map_err(|_| ModalError::Topology)?.modes()
}

/// Natural frequencies (Hz) and mass-normalised modes of K x = w^2 M x.
///
/// `mass` must be symmetric positive definite (kg*m^2) and `stiffness` symmetric
/// positive semi-definite (N*m/rad). Solved via the Cholesky factor M = L L^T and the
/// symmetric eigenproblem of L^-1 K L^-T.
pub fn solve(mass: &DMatrix<f64>, stiffness: &DMatrix<f64>) -> Result<Modes, ModalError> {
    let n = mass.nrows();
    if mass.ncols() != n || stiffness.nrows() != n || stiffness.ncols() != n {
        return Err(ModalError::Shape);
    }
    if mass.iter().any(|value| !value.is_finite()) {
        return Err(ModalError::MassNotPositiveDefinite);
    }
    let cholesky = mass
        .clone()
        .cholesky()
        .ok_or(ModalError::MassNotPositiveDefinite)?;
    let lower = cholesky.l();
    // A = L^-1 K L^-T, computed by two triangular solves.
    let left = lower
        .solve_lower_triangular(stiffness)
        .ok_or(ModalError::MassNotPositiveDefinite)?;
    let reduced_t = lower
        .solve_lower_triangular(&left.transpose())
        .ok_or(ModalError::MassNotPositiveDefinite)?;
    let reduced = (&reduced_t + reduced_t.transpose()) * 0.5;
    let eigen = SymmetricEigen::new(reduced);

    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by(|&a, &b| eigen.eigenvalues[a].total_cmp(&eigen.eigenvalues[b]));
    let largest = eigen
        .eigenvalues
        .iter()
        .fold(0.0_f64, |m, v| m.max(v.abs()));

    let lower_t = lower.transpose();
    let mut frequencies_hz = Vec::with_capacity(n);
    let mut shapes = DMatrix::zeros(n, n);
    for (column, &index) in order.iter().enumerate() {
        let omega_squared = eigen.eigenvalues[index];
        let omega_squared = if omega_squared <= RIGID_BODY_TOLERANCE * largest {
            0.0
        } else {
            omega_squared
        };
        frequencies_hz.push(omega_squared.sqrt() / TAU);
        // x = L^-T v is mass-normalised when v is unit length.
        let mut shape = lower_t
            .solve_upper_triangular(&eigen.eigenvectors.column(index).into_owned())
            .ok_or(ModalError::MassNotPositiveDefinite)?;
        let dominant = shape.iter().fold(0.0_f64, |best, &value| {
            if value.abs() > best.abs() {
                value
            } else {
                best
            }
        });
        if dominant < 0.0 {
            shape.neg_mut();
        }
        shapes.set_column(column, &shape);
    }
    Ok(Modes {
        frequencies_hz,
        shapes,
    })
}
