//! Modal analysis against the paper's Table 2 and Friswell et al. Example 9.7.1.

use millgate_dsp::testing::assert_allclose;
use millgate_sim::modal::{self, chain_matrix, mass_matrix, solve};
use nalgebra::{DMatrix, DVector};

mod common;

use common::load;

#[test]
fn table2_from_drawings() -> anyhow::Result<()> {
    let modes = modal::modes(&load("table2-drawings.toml")?)?;
    assert_allclose(&modes.frequencies_hz, &[0.0, 16.66, 25.98], 0.0, 0.01);
    Ok(())
}

#[test]
fn table2_adjusted_to_measurement() -> anyhow::Result<()> {
    let modes = modal::modes(&load("table2-adjusted.toml")?)?;
    assert_allclose(&modes.frequencies_hz, &[0.0, 12.03, 21.09], 0.0, 0.01);
    Ok(())
}

#[test]
fn table2_matches_the_papers_closed_form() -> anyhow::Result<()> {
    // Paper eq. (2): beta1,2 = d sqrt(a -+ b) / (2 pi).
    let model = load("table2-drawings.toml")?;
    let (q1, q2, q3) = (
        model.masses[0].inertia,
        model.masses[1].inertia,
        model.masses[2].inertia,
    );
    let (c12, c23) = (model.couplings[0].stiffness, model.couplings[1].stiffness);
    let c = c12 / c23;
    let d = (c23 / q2).sqrt();
    let e = (q1 + q2) / (2.0 * q1);
    let f = (q2 + q3) / (2.0 * q3);
    let a = f + e * c;
    let b = ((f - e * c).powi(2) + c).sqrt();
    let tau = std::f64::consts::TAU;
    let closed_form = [0.0, d * (a - b).sqrt() / tau, d * (a + b).sqrt() / tau];
    assert_allclose(
        &modal::modes(&model)?.frequencies_hz,
        &closed_form,
        0.0,
        1e-9,
    );
    Ok(())
}

#[test]
fn friswell_example_9_7_1() -> anyhow::Result<()> {
    let mass = DMatrix::from_diagonal(&DVector::from_vec(vec![3.5e-3, 3.5e-3, 3.5e-3, 0.15, 0.05]));
    let stiffness = chain_matrix(&[12e3, 12e3, 14e3, 10e3]);
    let modes = solve(&mass, &stiffness)?;
    assert_allclose(
        &modes.frequencies_hz,
        &[0.0, 81.21, 141.21, 378.95, 536.36],
        0.0,
        0.05,
    );
    Ok(())
}

#[test]
fn shapes_are_mass_normalised_and_solve_the_eigenproblem() -> anyhow::Result<()> {
    let model = load("table2-adjusted.toml")?;
    let modes = modal::modes(&model)?;
    let mass = mass_matrix(&model);
    let stiffness = modal::stiffness_matrix(&model);
    let generalised_mass = modes.shapes.transpose() * &mass * &modes.shapes;
    let identity = DMatrix::<f64>::identity(3, 3);
    assert!((generalised_mass - identity).abs().max() < 1e-9);
    for (index, frequency) in modes.frequencies_hz.iter().enumerate() {
        let omega_squared = (std::f64::consts::TAU * frequency).powi(2);
        let shape = modes.shapes.column(index);
        let residual = &stiffness * shape - &mass * shape * omega_squared;
        assert!(residual.norm() < 1e-6 * stiffness.norm(), "mode {index}");
        // Largest component positive (the sign convention).
        let largest = shape
            .iter()
            .fold(0.0_f64, |m, v| if v.abs() > m.abs() { *v } else { m });
        assert!(largest > 0.0);
        assert_eq!(modes.shape(index).len(), 3);
    }
    // The rigid-body mode moves every mass by the same angle.
    let rigid = modes.shape(0);
    assert!(rigid.iter().all(|v| (v - rigid[0]).abs() < 1e-9));
    Ok(())
}

#[test]
fn bad_matrices_are_errors() {
    let mass = DMatrix::from_diagonal(&DVector::from_vec(vec![1.0, -1.0]));
    assert_eq!(
        solve(&mass, &chain_matrix(&[1.0])),
        Err(modal::ModalError::MassNotPositiveDefinite)
    );
    let mass = DMatrix::<f64>::identity(3, 3);
    assert_eq!(
        solve(&mass, &chain_matrix(&[1.0])),
        Err(modal::ModalError::Shape)
    );
}
