//! Tree drivelines: one configuration's engaged couplings, every mass and coupling
//! referred to the shaft of mass 0.
//!
//! A coupling joins two masses (by name in `between`, or `i` and `i + 1` in a chain) and
//! may cross a gear stage: `ratio` is the speed of its second mass over its first.
//! Walking the tree from mass 0 gives each mass's speed ratio `n_j = w_j / w_0`. In
//! coordinates referred to mass 0's shaft (`phi_j = theta_j / n_j`, equal for every
//! mass in a rigid rotation) kinetic and elastic energies are kept when
//!
//! - inertia `J_j` becomes `J_j n_j^2`,
//! - a coupling's stiffness and damping, given on its first mass's shaft, become
//!   `C n_first^2` (its twist on that shaft is `n_first (phi_first - phi_second)`),
//! - the torque it carries on its first mass's shaft is the referred torque over
//!   `n_first`.
//!
//! A configuration engages every coupling without a servo and those whose servo it
//! lists; the engaged couplings must join all masses without a loop. That shape is
//! checked where the model is validated ([`Model::validate`]), with errors naming the
//! file, the key (`coupling[5].between`, `mass[7]`, `configuration[1]`) and what is
//! allowed; this module adds [`Model::tree`], which refers a valid model's configuration
//! to mass 0's shaft. The modes of a [`Tree`] are [`Tree::modes`] (in [`crate::modal`]).

use nalgebra::{DMatrix, DVector};

use crate::model::{Checker, Model, ModelError};

/// One engaged coupling of a [`Tree`], referred to mass 0's shaft.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Edge {
    /// Index of the coupling in the model (`coupling[i]`).
    pub(crate) coupling: usize,
    /// Index of its first mass.
    pub(crate) first: usize,
    /// Index of its second mass.
    pub(crate) second: usize,
    /// Referred stiffness `C n_first^2`, N*m/rad.
    pub(crate) stiffness: f64,
    /// Referred damping `h n_first^2`, N*m*s/rad.
    pub(crate) damping: f64,
}

/// A drive in one configuration, referred to the shaft of mass 0.
#[derive(Debug, Clone, PartialEq)]
pub struct Tree {
    /// The configuration's name (`None` for a model without configurations).
    pub(crate) configuration: Option<String>,
    /// Referred inertias `J_j n_j^2`, kg*m^2, one per mass.
    pub inertias: Vec<f64>,
    /// Speed of each mass over mass 0's (`n_j`; 1 for mass 0).
    pub speed_ratios: Vec<f64>,
    /// The engaged couplings, in model order; one fewer than the masses.
    pub(crate) edges: Vec<Edge>,
}

impl Tree {
    /// Mass matrix diag(referred inertias), kg*m^2.
    pub(crate) fn mass_matrix(&self) -> DMatrix<f64> {
        DMatrix::from_diagonal(&DVector::from_vec(self.inertias.clone()))
    }

    /// Stiffness matrix of the engaged couplings (referred), N*m/rad.
    pub(crate) fn stiffness_matrix(&self) -> DMatrix<f64> {
        let n = self.inertias.len();
        let mut matrix = DMatrix::zeros(n, n);
        for edge in &self.edges {
            let (i, j, c) = (edge.first, edge.second, edge.stiffness);
            matrix[(i, i)] += c;
            matrix[(j, j)] += c;
            matrix[(i, j)] -= c;
            matrix[(j, i)] -= c;
        }
        matrix
    }
}

impl Model {
    /// The drive in one configuration (`None`: the first one, or every coupling when
    /// the model has none), referred to the shaft of mass 0.
    ///
    /// The model must be valid (`Model::validate`); an unknown configuration name is
    /// an error naming the known ones.
    pub fn tree(&self, configuration: Option<&str>) -> Result<Tree, ModelError> {
        let check = Checker { file: "<model>" };
        let index = match configuration {
            None => (!self.configurations.is_empty()).then_some(0),
            Some(name) => Some(
                self.configurations
                    .iter()
                    .position(|c| c.name == name)
                    .ok_or_else(|| {
                        let known: Vec<String> = self
                            .configurations
                            .iter()
                            .map(|c| format!("{:?}", c.name))
                            .collect();
                        check.error(
                            "configuration",
                            format!("{name:?}"),
                            if known.is_empty() {
                                "absent: the model has no configurations".to_owned()
                            } else {
                                format!("one of {}", known.join(", "))
                            },
                        )
                    })?,
            ),
        };
        let engaged = self.engaged_tree(index, &check)?;
        // Speed ratios by walking out from mass 0.
        let n = self.masses.len();
        let mut ratio = vec![f64::NAN; n];
        ratio[0] = 1.0;
        let mut changed = true;
        while changed {
            changed = false;
            for &(coupling, i, j) in &engaged {
                let r = self.couplings[coupling].ratio;
                if ratio[i].is_finite() && !ratio[j].is_finite() {
                    ratio[j] = ratio[i] * r;
                    changed = true;
                } else if ratio[j].is_finite() && !ratio[i].is_finite() {
                    ratio[i] = ratio[j] / r;
                    changed = true;
                }
            }
        }
        let inertias = self
            .masses
            .iter()
            .zip(&ratio)
            .map(|(mass, n)| mass.inertia * n * n)
            .collect();
        let edges = engaged
            .iter()
            .map(|&(coupling, first, second)| {
                let scale = ratio[first] * ratio[first];
                Edge {
                    coupling,
                    first,
                    second,
                    stiffness: self.couplings[coupling].stiffness * scale,
                    damping: self.couplings[coupling].damping * scale,
                }
            })
            .collect();
        Ok(Tree {
            configuration: index.map(|i| self.configurations[i].name.clone()),
            inertias,
            speed_ratios: ratio,
            edges,
        })
    }
}
