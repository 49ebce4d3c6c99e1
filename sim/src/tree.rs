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
//! lists; the engaged couplings must join all masses without a loop. The validation
//! names the file, the key (`coupling[5].between`, `mass[7]`, `configuration[1]`) and
//! what is allowed.

use nalgebra::{DMatrix, DVector};

use crate::modal::{self, ModalError, Modes};
use crate::model::{Checker, Model, ModelError};

/// One engaged coupling of a [`Tree`], referred to mass 0's shaft.
#[derive(Debug, Clone, PartialEq)]
pub struct Edge {
    /// Index of the coupling in the model (`coupling[i]`).
    pub coupling: usize,
    /// Index of its first mass.
    pub first: usize,
    /// Index of its second mass.
    pub second: usize,
    /// Referred stiffness `C n_first^2`, N*m/rad.
    pub stiffness: f64,
    /// Referred damping `h n_first^2`, N*m*s/rad.
    pub damping: f64,
}

/// A drive in one configuration, referred to the shaft of mass 0.
#[derive(Debug, Clone, PartialEq)]
pub struct Tree {
    /// The configuration's name (`None` for a model without configurations).
    pub configuration: Option<String>,
    /// Referred inertias `J_j n_j^2`, kg*m^2, one per mass.
    pub inertias: Vec<f64>,
    /// Speed of each mass over mass 0's (`n_j`; 1 for mass 0).
    pub speed_ratios: Vec<f64>,
    /// The engaged couplings, in model order; one fewer than the masses.
    pub edges: Vec<Edge>,
}

impl Tree {
    /// Mass matrix diag(referred inertias), kg*m^2.
    pub fn mass_matrix(&self) -> DMatrix<f64> {
        DMatrix::from_diagonal(&DVector::from_vec(self.inertias.clone()))
    }

    /// Stiffness matrix of the engaged couplings (referred), N*m/rad.
    pub fn stiffness_matrix(&self) -> DMatrix<f64> {
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

    /// Natural frequencies and mass-normalised mode shapes (referred coordinates).
    pub fn modes(&self) -> Result<Modes, ModalError> {
        modal::solve(&self.mass_matrix(), &self.stiffness_matrix())
    }
}

/// Checks that every configuration of `model` (or the model itself when it has none)
/// engages a tree over all masses, and the names the couplings and configurations use.
pub(crate) fn validate(model: &Model, file: &str) -> Result<(), ModelError> {
    let check = Checker { file };
    let named = model.couplings.iter().any(|c| c.between.is_some());
    if named {
        for (index, mass) in model.masses.iter().enumerate() {
            if model.masses[..index].iter().any(|m| m.name == mass.name) {
                return Err(check.error(
                    &format!("mass[{index}].name"),
                    format!("{:?}", mass.name),
                    "a name no other mass has (couplings name their masses)",
                ));
            }
        }
    }
    ends(model, &check)?;
    let servos: Vec<&str> = model
        .couplings
        .iter()
        .filter_map(|c| c.servo.as_deref())
        .collect();
    if model.configurations.is_empty() {
        if let Some(index) = model.couplings.iter().position(|c| c.servo.is_some()) {
            return Err(check.error(
                &format!("coupling[{index}].servo"),
                format!(
                    "{:?}",
                    model.couplings[index].servo.as_deref().unwrap_or("")
                ),
                "absent unless the model has [[configuration]] entries that engage servos",
            ));
        }
    }
    for (index, configuration) in model.configurations.iter().enumerate() {
        if model.configurations[..index]
            .iter()
            .any(|c| c.name == configuration.name)
        {
            return Err(check.error(
                &format!("configuration[{index}].name"),
                format!("{:?}", configuration.name),
                "a name no other configuration has",
            ));
        }
        for servo in &configuration.engaged {
            if !servos.contains(&servo.as_str()) {
                return Err(check.error(
                    &format!("configuration[{index}].engaged"),
                    format!("{servo:?}"),
                    format!("a servo named by a coupling (known: {})", servos.join(", ")),
                ));
            }
        }
    }
    if model.configurations.is_empty() {
        build_checked(model, None, &check)?;
    }
    for index in 0..model.configurations.len() {
        build_checked(model, Some(index), &check)?;
    }
    Ok(())
}

/// Refuses a model that is not a plain chain, for tools that need one.
pub(crate) fn require_chain(model: &Model, file: &str, purpose: &str) -> Result<(), ModelError> {
    if model.is_chain() {
        return Ok(());
    }
    Err(Checker { file }.error(
        "coupling",
        "a tree, gear ratios or servo configurations",
        format!("a chain (coupling i joins masses i and i+1, ratio 1, no servo) for {purpose}"),
    ))
}

/// The tree of `configuration` (by name; `None`: the first, or all couplings when the
/// model has no configurations).
pub(crate) fn build(
    model: &Model,
    configuration: Option<&str>,
    file: &str,
) -> Result<Tree, ModelError> {
    let check = Checker { file };
    let index = match configuration {
        None => (!model.configurations.is_empty()).then_some(0),
        Some(name) => Some(
            model
                .configurations
                .iter()
                .position(|c| c.name == name)
                .ok_or_else(|| {
                    let known: Vec<String> = model
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
    build_checked(model, index, &check)
}

/// The two mass indices of every coupling.
fn ends(model: &Model, check: &Checker<'_>) -> Result<Vec<(usize, usize)>, ModelError> {
    let named = model.couplings.iter().any(|c| c.between.is_some());
    model
        .couplings
        .iter()
        .enumerate()
        .map(|(index, coupling)| {
            let key = format!("coupling[{index}].between");
            let Some([first, second]) = &coupling.between else {
                if named {
                    return Err(check.error(
                        &key,
                        "missing",
                        "two mass names, as every other coupling gives them",
                    ));
                }
                return Ok((index, index + 1));
            };
            let find = |name: &str| {
                model
                    .masses
                    .iter()
                    .position(|m| m.name == name)
                    .ok_or_else(|| {
                        let known: Vec<String> = model
                            .masses
                            .iter()
                            .map(|m| format!("{:?}", m.name))
                            .collect();
                        check.error(
                            &key,
                            format!("{name:?}"),
                            format!("a mass name (known: {})", known.join(", ")),
                        )
                    })
            };
            let (i, j) = (find(first)?, find(second)?);
            if i == j {
                return Err(check.error(
                    &key,
                    format!("[{first:?}, {second:?}]"),
                    "two different masses",
                ));
            }
            Ok((i, j))
        })
        .collect()
}

/// Builds and checks the tree of configuration `index` (`None`: every coupling).
fn build_checked(
    model: &Model,
    index: Option<usize>,
    check: &Checker<'_>,
) -> Result<Tree, ModelError> {
    let ends = ends(model, check)?;
    let configuration = index.map(|i| &model.configurations[i]);
    let context =
        configuration.map_or(String::new(), |c| format!(" in configuration {:?}", c.name));
    let engaged: Vec<usize> = (0..model.couplings.len())
        .filter(|&i| match (&model.couplings[i].servo, configuration) {
            (None, _) => true,
            (Some(servo), Some(configuration)) => configuration.engaged.contains(servo),
            (Some(_), None) => false,
        })
        .collect();
    let n = model.masses.len();
    // Union-find: a coupling whose masses are already joined closes a loop.
    let mut parent: Vec<usize> = (0..n).collect();
    fn root(parent: &mut [usize], mut i: usize) -> usize {
        while parent[i] != i {
            parent[i] = parent[parent[i]];
            i = parent[i];
        }
        i
    }
    for &coupling in &engaged {
        let (i, j) = ends[coupling];
        let (ri, rj) = (root(&mut parent, i), root(&mut parent, j));
        if ri == rj {
            return Err(check.error(
                &format!("coupling[{coupling}].between"),
                format!("[{:?}, {:?}]", model.masses[i].name, model.masses[j].name),
                format!(
                    "a tree: these masses are already joined by other couplings{context} (a loop)"
                ),
            ));
        }
        parent[ri] = rj;
    }
    let drive = root(&mut parent, 0);
    if let Some(lone) = (1..n).find(|&j| root(&mut parent, j) != drive) {
        return Err(check.error(
            &format!("mass[{lone}]"),
            format!("{:?}", model.masses[lone].name),
            format!(
                "joined to mass[0] {:?} by engaged couplings (none reaches it{context})",
                model.masses[0].name
            ),
        ));
    }
    // Speed ratios by walking out from mass 0.
    let mut ratio = vec![f64::NAN; n];
    ratio[0] = 1.0;
    let mut changed = true;
    while changed {
        changed = false;
        for &coupling in &engaged {
            let (i, j) = ends[coupling];
            let r = model.couplings[coupling].ratio;
            if ratio[i].is_finite() && !ratio[j].is_finite() {
                ratio[j] = ratio[i] * r;
                changed = true;
            } else if ratio[j].is_finite() && !ratio[i].is_finite() {
                ratio[i] = ratio[j] / r;
                changed = true;
            }
        }
    }
    let inertias = model
        .masses
        .iter()
        .zip(&ratio)
        .map(|(mass, n)| mass.inertia * n * n)
        .collect();
    let edges = engaged
        .iter()
        .map(|&coupling| {
            let (first, second) = ends[coupling];
            let scale = ratio[first] * ratio[first];
            Edge {
                coupling,
                first,
                second,
                stiffness: model.couplings[coupling].stiffness * scale,
                damping: model.couplings[coupling].damping * scale,
            }
        })
        .collect();
    Ok(Tree {
        configuration: configuration.map(|c| c.name.clone()),
        inertias,
        speed_ratios: ratio,
        edges,
    })
}
