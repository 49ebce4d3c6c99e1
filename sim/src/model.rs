//! Driveline model files: a torsional chain (or tree) of masses and couplings, a
//! PI-controlled motor, a rolling-load ramp and the measured channel, read from and
//! written to TOML.
//!
//! A hot-mill driveline is a chain: coupling `i` joins mass `i` and mass `i + 1`. A
//! rod-mill block drive is a tree of gear stages (domain notes 3): there every coupling
//! names the two masses it joins (`between`), may cross a gear stage (`ratio`), and may
//! be engaged only by a servo coupling (`servo`) in some of the named configurations
//! (`[[configuration]]`). [`Model::tree`] refers one configuration's engaged couplings
//! and every inertia to the shaft of mass 0 (see `tree`).
//!
//! Every field is in SI units except the load torque, which is in kN*m as in the
//! paper's tables. A [`Model`] returned by [`Model::from_toml_str`] or [`Model::load`]
//! has passed `Model::validate`; code that builds a model by hand should call it too.
//!
//! The extensions used by the model-discrepancy workflow (cubic hardening and
//! Coulomb-like friction per coupling, a first-order lag of the measured channel) are
//! optional fields with `#[serde(default, skip_serializing_if = ...)]`, so files written
//! before they existed keep loading and models without them serialise as before. An
//! unmodelled inertia needs no field: it is one more mass (see [`Model::split_coupling`]).

use std::fmt::Display;
use std::path::Path;

use serde::{Deserialize, Serialize};

/// Largest number of output samples a model may ask for (duration * sample rate).
pub(crate) const MAX_OUTPUT_SAMPLES: f64 = 1.0e8;

/// A torsional driveline model: masses ordered motor first, rolls last.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Model {
    /// Free-text name of the driveline.
    pub name: String,
    /// Lumped rotating masses, motor first (index 0), rolls last; at least 2.
    #[serde(rename = "mass")]
    pub masses: Vec<Mass>,
    /// Couplings; coupling `i` joins mass `i` and mass `i + 1`, so there are
    /// `masses.len() - 1` of them.
    #[serde(rename = "coupling")]
    pub couplings: Vec<Coupling>,
    /// PI speed controller acting on mass 0.
    pub motor: Motor,
    /// Rolling-load ramp acting against the last mass.
    pub load: Load,
    /// Which torque is measured and how it is sampled.
    pub measurement: Measurement,
    /// Named configurations of the servo couplings; optional (a drive without servo
    /// couplings has none). The first one is the default.
    #[serde(
        default,
        rename = "configuration",
        skip_serializing_if = "Vec::is_empty"
    )]
    pub configurations: Vec<Configuration>,
}

/// One configuration of the servo couplings: which of them are engaged.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Configuration {
    /// Name used by schedules and commands; unique.
    pub(crate) name: String,
    /// The servo couplings engaged (names used in `coupling[i].servo`); every coupling
    /// of another servo is disengaged, couplings without a servo are always engaged.
    pub(crate) engaged: Vec<String>,
}

/// One lumped rotating mass.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Mass {
    /// Free-text name (`motor`, `pinion`, `rolls`, ...).
    pub name: String,
    /// Moment of inertia on the mass's own shaft, kg*m^2, > 0. In a model without
    /// gear ratios every shaft turns at one speed: the paper's "referred to roll speed".
    pub inertia: f64,
}

/// One elastic coupling with viscous damping and an optional symmetric dead zone.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Coupling {
    /// Free-text name (`gear coupling`, `spindle`, ...).
    pub name: String,
    /// Torsional stiffness outside the gap, N*m/rad, > 0.
    pub stiffness: f64,
    /// Viscous damping on the twist rate, acting at all times, N*m*s/rad, >= 0.
    pub damping: f64,
    /// Total dead-zone width (opened gap), rad, >= 0; default 0 (linear coupling).
    #[serde(default, skip_serializing_if = "is_zero")]
    pub backlash: f64,
    /// Cubic hardening coefficient k3, N*m/rad^3, >= 0; default 0. The elastic torque
    /// outside the gap becomes `C e + k3 e^3`, where `e` is the deflection beyond the
    /// gap (`x - g`, `x + g`, or `x` without a gap).
    #[serde(default, skip_serializing_if = "is_zero")]
    pub hardening: f64,
    /// Coulomb-like friction torque, N*m, >= 0; default 0. The coupling adds
    /// `friction * tanh(rate / FRICTION_SPEED)` (rate: twist rate, rad/s; see
    /// [`crate::chain::FRICTION_SPEED`]): a damping whose share falls as the amplitude
    /// grows, so oscillations decay linearly in time rather than exponentially.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub friction: f64,
    /// The two masses this coupling joins, by name; optional. Without it coupling `i`
    /// joins mass `i` and mass `i + 1` (a chain). Either every coupling names its masses
    /// or none does; with names the couplings of each configuration must form a tree
    /// over all masses (no loop, none left out).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub between: Option<[String; 2]>,
    /// Speed of the second mass over the first (a gear stage), finite and > 0, default
    /// one. Stiffness, damping, backlash, hardening and friction are those seen on the
    /// first mass's shaft.
    #[serde(default = "one", skip_serializing_if = "is_one")]
    pub ratio: f64,
    /// The servo coupling (e.g. `M3`) that engages this coupling; optional. A coupling
    /// without one is always engaged; one with a servo is engaged in the
    /// configurations that list that servo.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub servo: Option<String>,
}

/// PI speed controller on mass 0; the reference is the nominal speed (deviation 0).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Motor {
    /// Proportional gain, N*m*s/rad, >= 0.
    pub speed_kp: f64,
    /// Integral gain, N*m/rad, >= 0.
    pub speed_ki: f64,
}

/// Rolling load M(t) = static_torque (1 - exp(-rise_rate (t - onset))) for t >= onset.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Load {
    /// Static rolling torque on the last mass, kN*m, >= 0.
    pub static_torque: f64,
    /// Rate of the exponential load rise, 1/s, > 0.
    pub rise_rate: f64,
    /// Time of metal biting (start of the load rise), s, >= 0.
    pub onset: f64,
}

/// The measured channel: the torque of one coupling, sampled uniformly.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Measurement {
    /// Index of the measured coupling, 0 ..= couplings - 1.
    pub coupling: usize,
    /// Output sample rate, Hz, > 0.
    pub sample_rate: f64,
    /// Length of the simulated record, s, > 0.
    pub duration: f64,
    /// Time constant of a first-order lag of the sensor or telemetry, s, >= 0; default 0
    /// (the channel is the coupling torque itself). The lagged channel starts at 0.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub lag: f64,
}

/// Why a model file (a driveline, a pass schedule) could not be read or is not valid.
///
/// Every variant names the file; the schema and value variants also name the key path
/// (`mass[1].inertia`) and what is allowed there.
#[derive(Debug, thiserror::Error)]
pub enum ModelError {
    /// The file could not be read.
    #[error("{file}: cannot read: {source}")]
    Io {
        /// The file as given.
        file: String,
        /// The underlying I/O error.
        source: std::io::Error,
    },
    /// The text is not valid TOML.
    #[error("{file}:{line}: malformed TOML: {message}")]
    Syntax {
        /// The file as given.
        file: String,
        /// 1-based line of the error.
        line: usize,
        /// What the TOML parser reported.
        message: String,
    },
    /// The TOML is valid but does not match the schema (unknown key, missing key,
    /// wrong type).
    #[error("{file}:{line}: {key}: {message}")]
    Schema {
        /// The file as given.
        file: String,
        /// 1-based line of the offending item (0 if unknown).
        line: usize,
        /// Key path, e.g. `coupling[0]`.
        key: String,
        /// What serde reported, including the expected keys or type.
        message: String,
    },
    /// A value is outside its allowed range.
    #[error("{file}: {key}: {value} is not allowed (must be {allowed})")]
    Value {
        /// The file as given (or `<model>` for a model built in code).
        file: String,
        /// Key path, e.g. `mass[1].inertia`.
        key: String,
        /// The offending value as written.
        value: String,
        /// The allowed range with its unit.
        allowed: String,
    },
    /// The model could not be written as TOML.
    #[error("cannot write model as TOML: {0}")]
    Serialize(#[from] toml::ser::Error),
}

impl Model {
    /// Parses and validates a model from TOML text; `file_name` is used in error messages.
    ///
    /// # Example
    /// ```
    /// let text = r#"
    /// name = "two masses"
    /// [[mass]]
    /// name = "motor"
    /// inertia = 1.0e3
    /// [[mass]]
    /// name = "rolls"
    /// inertia = 1.0e2
    /// [[coupling]]
    /// name = "spindle"
    /// stiffness = 1.0e6
    /// damping = 10.0
    /// [motor]
    /// speed_kp = 0.0
    /// speed_ki = 0.0
    /// [load]
    /// static_torque = 10.0
    /// rise_rate = 50.0
    /// onset = 0.0
    /// [measurement]
    /// coupling = 0
    /// sample_rate = 1000.0
    /// duration = 0.1
    /// "#;
    /// let model = millgate_sim::model::Model::from_toml_str(text, "two.toml")?;
    /// assert_eq!(model.masses.len(), 2);
    /// # Ok::<(), millgate_sim::model::ModelError>(())
    /// ```
    pub fn from_toml_str(text: &str, file_name: &str) -> Result<Model, ModelError> {
        let model: Model = parse_toml(text, file_name)?;
        model.validate(file_name)?;
        Ok(model)
    }

    /// Reads, parses and validates a model file; errors name the path as given.
    pub fn load(path: impl AsRef<Path>) -> Result<Model, ModelError> {
        let (text, file) = read_text(path.as_ref())?;
        Model::from_toml_str(&text, &file)
    }

    /// Writes the model as TOML in the same schema [`Model::from_toml_str`] reads.
    pub fn to_toml_string(&self) -> Result<String, ModelError> {
        Ok(toml::to_string(self)?)
    }

    /// Checks every value against its allowed range and the drive's shape (a chain, or
    /// a tree in every configuration).
    ///
    /// `file_name` only labels the error. The first problem found is reported.
    pub(crate) fn validate(&self, file_name: &str) -> Result<(), ModelError> {
        let check = Checker { file: file_name };
        if self.masses.len() < 2 {
            return Err(check.error("mass", self.masses.len(), "at least 2 entries"));
        }
        for (index, mass) in self.masses.iter().enumerate() {
            check.positive(&format!("mass[{index}].inertia"), mass.inertia, "kg*m^2")?;
        }
        let named = self.couplings.iter().any(|c| c.between.is_some());
        if !named && self.couplings.len() != self.masses.len() - 1 {
            return Err(check.error(
                "coupling",
                format!("{} entries", self.couplings.len()),
                format!(
                    "one fewer than the masses: {} entries",
                    self.masses.len() - 1
                ),
            ));
        }
        for (index, coupling) in self.couplings.iter().enumerate() {
            let key = format!("coupling[{index}]");
            check.positive(&format!("{key}.stiffness"), coupling.stiffness, "N*m/rad")?;
            check.non_negative(&format!("{key}.damping"), coupling.damping, "N*m*s/rad")?;
            check.non_negative(&format!("{key}.backlash"), coupling.backlash, "rad")?;
            check.non_negative(&format!("{key}.hardening"), coupling.hardening, "N*m/rad^3")?;
            check.non_negative(&format!("{key}.friction"), coupling.friction, "N*m")?;
            check.positive(
                &format!("{key}.ratio"),
                coupling.ratio,
                "(speed of the second mass over the first)",
            )?;
        }
        self.validate_topology(&check)?;
        check.non_negative("motor.speed_kp", self.motor.speed_kp, "N*m*s/rad")?;
        check.non_negative("motor.speed_ki", self.motor.speed_ki, "N*m/rad")?;
        check.non_negative("load.static_torque", self.load.static_torque, "kN*m")?;
        check.positive("load.rise_rate", self.load.rise_rate, "1/s")?;
        check.non_negative("load.onset", self.load.onset, "s")?;
        if self.measurement.coupling >= self.couplings.len() {
            return Err(check.error(
                "measurement.coupling",
                self.measurement.coupling,
                format!("a coupling index, 0 ..= {}", self.couplings.len() - 1),
            ));
        }
        check.positive(
            "measurement.sample_rate",
            self.measurement.sample_rate,
            "Hz",
        )?;
        check.positive("measurement.duration", self.measurement.duration, "s")?;
        check.non_negative("measurement.lag", self.measurement.lag, "s")?;
        let samples = self.measurement.duration * self.measurement.sample_rate;
        if samples > MAX_OUTPUT_SAMPLES {
            return Err(check.error(
                "measurement.duration",
                self.measurement.duration,
                format!(
                    "at most {MAX_OUTPUT_SAMPLES:e} samples, i.e. <= {} s at this sample rate",
                    MAX_OUTPUT_SAMPLES / self.measurement.sample_rate
                ),
            ));
        }
        Ok(())
    }

    /// Number of output samples: `round(duration * sample_rate)`, at t = k / sample_rate.
    pub fn sample_count(&self) -> usize {
        let samples = (self.measurement.duration * self.measurement.sample_rate).round();
        if samples.is_finite() && samples > 0.0 {
            samples.min(MAX_OUTPUT_SAMPLES) as usize
        } else {
            0
        }
    }

    /// The same chain driveline with a mass of `inertia` (kg*m^2) inserted in the
    /// middle of coupling `index` (a tree model is refused): the coupling becomes two halves in series, each with twice its
    /// stiffness, damping and hardening (so the series combination is the original),
    /// the backlash and friction on the motor-side half. When the split coupling is the
    /// measured one, the motor-side half is measured; later measured indices shift by one.
    ///
    /// `index` must be a coupling index and `inertia` > 0; the result is validated.
    pub fn split_coupling(&self, index: usize, inertia: f64) -> Result<Model, ModelError> {
        self.require_chain("<split>", "splitting a coupling")?;
        let Some(original) = self.couplings.get(index) else {
            return Err(Checker { file: "<split>" }.error(
                "coupling",
                index,
                format!(
                    "a coupling index, 0 ..= {}",
                    self.couplings.len().saturating_sub(1)
                ),
            ));
        };
        let mut model = self.clone();
        let motor_side = Coupling {
            name: format!("{} (motor side)", original.name),
            stiffness: 2.0 * original.stiffness,
            damping: 2.0 * original.damping,
            hardening: 8.0 * original.hardening,
            ..original.clone()
        };
        let roll_side = Coupling {
            name: format!("{} (roll side)", original.name),
            backlash: 0.0,
            friction: 0.0,
            ..motor_side.clone()
        };
        model.couplings[index] = motor_side;
        model.couplings.insert(index + 1, roll_side);
        model.masses.insert(
            index + 1,
            Mass {
                name: format!("inertia inside {}", original.name),
                inertia,
            },
        );
        if model.measurement.coupling > index {
            model.measurement.coupling += 1;
        }
        model.validate("<split>")?;
        Ok(model)
    }

    /// True when coupling `i` joins mass `i` and mass `i + 1` at ratio 1 without a
    /// servo: the shape the time simulation and the discrepancy workflow need.
    pub fn is_chain(&self) -> bool {
        self.configurations.is_empty()
            && self.couplings.iter().enumerate().all(|(i, c)| {
                c.ratio == 1.0
                    && c.servo.is_none()
                    && c.between.as_ref().is_none_or(|[first, second]| {
                        self.masses.get(i).is_some_and(|m| &m.name == first)
                            && self.masses.get(i + 1).is_some_and(|m| &m.name == second)
                    })
            })
    }

    /// Refuses a model that is not a plain chain ([`Model::is_chain`]), for tools that
    /// need one; `file` labels the error, `purpose` says what needs the chain.
    pub(crate) fn require_chain(&self, file: &str, purpose: &str) -> Result<(), ModelError> {
        if self.is_chain() {
            return Ok(());
        }
        Err(Checker { file }.error(
            "coupling",
            "a tree, gear ratios or servo configurations",
            format!("a chain (coupling i joins masses i and i+1, ratio 1, no servo) for {purpose}"),
        ))
    }
}

/// The drive's shape: every configuration engages a tree over all masses.
impl Model {
    /// Checks that every configuration (or the model itself when it has none) engages
    /// a tree over all masses, and the names the couplings and configurations use.
    fn validate_topology(&self, check: &Checker<'_>) -> Result<(), ModelError> {
        let named = self.couplings.iter().any(|c| c.between.is_some());
        if named {
            for (index, mass) in self.masses.iter().enumerate() {
                if self.masses[..index].iter().any(|m| m.name == mass.name) {
                    return Err(check.error(
                        &format!("mass[{index}].name"),
                        format!("{:?}", mass.name),
                        "a name no other mass has (couplings name their masses)",
                    ));
                }
            }
        }
        self.coupling_ends(check)?;
        let servos: Vec<&str> = self
            .couplings
            .iter()
            .filter_map(|c| c.servo.as_deref())
            .collect();
        if self.configurations.is_empty() {
            if let Some(index) = self.couplings.iter().position(|c| c.servo.is_some()) {
                return Err(check.error(
                    &format!("coupling[{index}].servo"),
                    format!("{:?}", self.couplings[index].servo.as_deref().unwrap_or("")),
                    "absent unless the model has [[configuration]] entries that engage servos",
                ));
            }
        }
        for (index, configuration) in self.configurations.iter().enumerate() {
            if self.configurations[..index]
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
        if self.configurations.is_empty() {
            self.engaged_tree(None, check)?;
        }
        for index in 0..self.configurations.len() {
            self.engaged_tree(Some(index), check)?;
        }
        Ok(())
    }

    /// The two mass indices of every coupling.
    fn coupling_ends(&self, check: &Checker<'_>) -> Result<Vec<(usize, usize)>, ModelError> {
        let named = self.couplings.iter().any(|c| c.between.is_some());
        self.couplings
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
                    self.masses
                        .iter()
                        .position(|m| m.name == name)
                        .ok_or_else(|| {
                            let known: Vec<String> = self
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

    /// The couplings configuration `index` engages (`None`: every coupling), each as
    /// `(coupling, first mass, second mass)` in model order, checked to join all masses
    /// without a loop.
    pub(crate) fn engaged_tree(
        &self,
        index: Option<usize>,
        check: &Checker<'_>,
    ) -> Result<Vec<(usize, usize, usize)>, ModelError> {
        let ends = self.coupling_ends(check)?;
        let configuration = index.map(|i| &self.configurations[i]);
        let context =
            configuration.map_or(String::new(), |c| format!(" in configuration {:?}", c.name));
        let engaged: Vec<(usize, usize, usize)> = (0..self.couplings.len())
            .filter(|&i| match (&self.couplings[i].servo, configuration) {
                (None, _) => true,
                (Some(servo), Some(configuration)) => configuration.engaged.contains(servo),
                (Some(_), None) => false,
            })
            .map(|i| (i, ends[i].0, ends[i].1))
            .collect();
        let n = self.masses.len();
        // Union-find: a coupling whose masses are already joined closes a loop.
        let mut parent: Vec<usize> = (0..n).collect();
        fn root(parent: &mut [usize], mut i: usize) -> usize {
            while parent[i] != i {
                parent[i] = parent[parent[i]];
                i = parent[i];
            }
            i
        }
        for &(coupling, i, j) in &engaged {
            let (ri, rj) = (root(&mut parent, i), root(&mut parent, j));
            if ri == rj {
                return Err(check.error(
                    &format!("coupling[{coupling}].between"),
                    format!("[{:?}, {:?}]", self.masses[i].name, self.masses[j].name),
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
                format!("{:?}", self.masses[lone].name),
                format!(
                    "joined to mass[0] {:?} by engaged couplings (none reaches it{context})",
                    self.masses[0].name
                ),
            ));
        }
        Ok(engaged)
    }
}

impl Coupling {
    /// A coupling without backlash.
    pub fn linear(name: impl Into<String>, stiffness: f64, damping: f64) -> Coupling {
        Coupling {
            name: name.into(),
            stiffness,
            damping,
            backlash: 0.0,
            hardening: 0.0,
            friction: 0.0,
            between: None,
            ratio: 1.0,
            servo: None,
        }
    }
}

/// Builds range errors for one file.
pub(crate) struct Checker<'a> {
    pub(crate) file: &'a str,
}

impl Checker<'_> {
    pub(crate) fn error(
        &self,
        key: &str,
        value: impl Display,
        allowed: impl Display,
    ) -> ModelError {
        ModelError::Value {
            file: self.file.to_owned(),
            key: key.to_owned(),
            value: value.to_string(),
            allowed: allowed.to_string(),
        }
    }

    pub(crate) fn positive(&self, key: &str, value: f64, unit: &str) -> Result<(), ModelError> {
        if value.is_finite() && value > 0.0 {
            Ok(())
        } else {
            Err(self.error(key, value, format_args!("> 0 {unit}")))
        }
    }

    pub(crate) fn non_negative(&self, key: &str, value: f64, unit: &str) -> Result<(), ModelError> {
        if value.is_finite() && value >= 0.0 {
            Ok(())
        } else {
            Err(self.error(key, value, format_args!(">= 0 {unit}")))
        }
    }
}

/// Reads a text file; the error and the returned name are the path as given.
pub(crate) fn read_text(path: &Path) -> Result<(String, String), ModelError> {
    let file = path.display().to_string();
    let text = std::fs::read_to_string(path).map_err(|source| ModelError::Io {
        file: file.clone(),
        source,
    })?;
    Ok((text, file))
}

/// Parses TOML text into `T`; errors name `file_name`, the line, and for schema
/// errors the key path and what serde expected.
pub(crate) fn parse_toml<T: serde::de::DeserializeOwned>(
    text: &str,
    file_name: &str,
) -> Result<T, ModelError> {
    let deserializer = toml::Deserializer::parse(text).map_err(|error| ModelError::Syntax {
        file: file_name.to_owned(),
        line: line_of(text, error.span()),
        message: error.message().to_owned(),
    })?;
    serde_path_to_error::deserialize(deserializer).map_err(|error| {
        let key = error.path().to_string();
        let inner = error.inner();
        ModelError::Schema {
            file: file_name.to_owned(),
            line: line_of(text, inner.span()),
            key: if key == "." {
                "(top level)".to_owned()
            } else {
                key
            },
            message: inner.message().to_owned(),
        }
    })
}

/// 1-based line of the start of `span` in `text`, 0 when there is no span.
fn line_of(text: &str, span: Option<std::ops::Range<usize>>) -> usize {
    span.map_or(0, |span| {
        let end = span.start.min(text.len());
        text.as_bytes()[..end]
            .iter()
            .filter(|&&b| b == b'\n')
            .count()
            + 1
    })
}

fn is_zero(value: &f64) -> bool {
    *value == 0.0
}

fn one() -> f64 {
    1.0
}

fn is_one(value: &f64) -> bool {
    *value == 1.0
}
