//! Pass schedule files (TOML): the stands of a tandem cold mill, the strip, the rolls
//! and the vertical roll stack, validated with errors that name the file, the key and
//! the allowed range.
//!
//! Thickness is in mm and stresses in MPa, as mills write schedules (the key names
//! carry the unit); everything else is SI. See `sim/README.md` for the schema and
//! `sim/schedules/lu2019-5stand.toml` for the example.

use std::path::Path;

use serde::{Deserialize, Serialize};

use super::rollgap::{roll_gap, Pass, RollGap};
use crate::model::{parse_toml, read_text, Checker, ModelError};

/// Fewest and most stands a schedule may have (the chatter detectors take up to 8).
pub(crate) const STANDS: std::ops::RangeInclusive<usize> = 2..=8;

/// Largest allowed mismatch of the mass flow (exit thickness x exit speed) of any
/// stand against the last one, as a fraction.
pub(crate) const MASS_FLOW_TOLERANCE: f64 = 0.05;

/// The text of `sim/schedules/lu2019-5stand.toml`.
const EXAMPLE: &str = include_str!("../../schedules/lu2019-5stand.toml");

/// A tandem cold mill rolling one pass schedule.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PassSchedule {
    /// Free-text name.
    pub(crate) name: String,
    /// Distance between neighbouring stands (length of free strip), m, > 0.
    pub(crate) interstand_distance: f64,
    /// The strip.
    pub strip: Strip,
    /// The work rolls (shared by every stand).
    pub(crate) rolls: Rolls,
    /// The top half of each stand's vertical roll stack (shared by every stand).
    pub stack: Stack,
    /// The stands in rolling order, 2 to 8.
    #[serde(rename = "stand")]
    pub stands: Vec<StandPass>,
}

/// The strip.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Strip {
    /// Width, m, > 0.
    pub(crate) width: f64,
    /// Young's modulus (the free strip between stands is a spring), Pa, > 0.
    pub youngs_modulus: f64,
}

/// The work rolls.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct Rolls {
    /// Work-roll radius, m, > 0.
    pub(crate) work_roll_radius: f64,
    /// Young's modulus of the rolls (Hitchcock's flattening), Pa, > 0.
    pub(crate) youngs_modulus: f64,
    /// Poisson's ratio of the rolls, in [0, 0.5).
    pub(crate) poisson_ratio: f64,
}

/// The top half of a symmetric 4-high stand: work roll on backup roll on housing.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Stack {
    /// Work-roll mass (with chocks), kg, > 0.
    pub work_roll_mass: f64,
    /// Backup-roll mass (with chocks), kg, > 0.
    pub backup_roll_mass: f64,
    /// Work-roll to backup-roll contact stiffness, N/m, > 0.
    pub work_backup_stiffness: f64,
    /// Work-roll to backup-roll damping, N*s/m, >= 0.
    pub work_backup_damping: f64,
    /// Backup roll to housing (chock, screw-down, housing) stiffness, N/m, > 0.
    pub backup_housing_stiffness: f64,
    /// Backup roll to housing damping, N*s/m, >= 0.
    pub backup_housing_damping: f64,
}

/// One stand's pass.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StandPass {
    /// Entry thickness, mm, > exit; equal to the previous stand's exit.
    pub(crate) entry_mm: f64,
    /// Exit thickness, mm, > 0.
    pub(crate) exit_mm: f64,
    /// Back tension stress, MPa, >= 0 and below the flow stress; equal to the previous
    /// stand's front tension.
    pub(crate) back_tension_mpa: f64,
    /// Front tension stress, MPa, >= 0 and below the flow stress.
    pub(crate) front_tension_mpa: f64,
    /// Coulomb friction coefficient in the roll gap, in (0, 0.5].
    pub(crate) friction: f64,
    /// Work-roll surface speed at the schedule's speed, m/s, > 0.
    pub(crate) roll_speed: f64,
    /// Mean flow stress of the strip in this pass, MPa, > 0.
    pub(crate) flow_stress_mpa: f64,
}

impl PassSchedule {
    /// Parses and validates a schedule from TOML text; `file_name` labels the errors.
    pub fn from_toml_str(text: &str, file_name: &str) -> Result<PassSchedule, ModelError> {
        let schedule: PassSchedule = parse_toml(text, file_name)?;
        schedule.validate(file_name)?;
        Ok(schedule)
    }

    /// The checked-in example: the 5-stand schedule of Lu et al. (2019)
    /// (`sim/schedules/lu2019-5stand.toml`), for tests, benchmarks and demos.
    pub fn example() -> Result<PassSchedule, ModelError> {
        PassSchedule::from_toml_str(EXAMPLE, "sim/schedules/lu2019-5stand.toml")
    }

    /// Reads, parses and validates a schedule file; errors name the path as given.
    pub fn load(path: impl AsRef<Path>) -> Result<PassSchedule, ModelError> {
        let (text, file) = read_text(path.as_ref())?;
        PassSchedule::from_toml_str(&text, &file)
    }

    /// Writes the schedule as TOML in the schema [`PassSchedule::from_toml_str`] reads.
    pub fn to_toml_string(&self) -> Result<String, ModelError> {
        Ok(toml::to_string(self)?)
    }

    /// The pass of stand `index` in SI units.
    ///
    /// # Panics
    /// If `index` is not a stand index.
    pub(crate) fn pass(&self, index: usize) -> Pass {
        let stand = &self.stands[index];
        Pass {
            entry_m: stand.entry_mm * 1e-3,
            exit_m: stand.exit_mm * 1e-3,
            back_tension_pa: stand.back_tension_mpa * 1e6,
            front_tension_pa: stand.front_tension_mpa * 1e6,
            flow_stress_pa: stand.flow_stress_mpa * 1e6,
            friction: stand.friction,
            roll_radius_m: self.rolls.work_roll_radius,
            width_m: self.strip.width,
            roll_modulus_pa: self.rolls.youngs_modulus,
            roll_poisson: self.rolls.poisson_ratio,
        }
    }

    /// The same schedule with every friction coefficient times `friction` and every
    /// stack damping times `damping` (the variations of the evaluation).
    pub fn scaled(&self, friction: f64, damping: f64) -> PassSchedule {
        let mut scaled = self.clone();
        for stand in &mut scaled.stands {
            stand.friction *= friction;
        }
        scaled.stack.work_backup_damping *= damping;
        scaled.stack.backup_housing_damping *= damping;
        scaled
    }

    /// Checks every value against its range, the stands against each other (thickness
    /// and tension continuity, mass flow) and every roll gap. The first problem found is
    /// reported; `file_name` only labels it.
    pub(crate) fn validate(&self, file_name: &str) -> Result<(), ModelError> {
        let check = Checker { file: file_name };
        check.positive("interstand_distance", self.interstand_distance, "m")?;
        check.positive("strip.width", self.strip.width, "m")?;
        check.positive("strip.youngs_modulus", self.strip.youngs_modulus, "Pa")?;
        check.positive("rolls.work_roll_radius", self.rolls.work_roll_radius, "m")?;
        check.positive("rolls.youngs_modulus", self.rolls.youngs_modulus, "Pa")?;
        let poisson = self.rolls.poisson_ratio;
        if !(0.0..0.5).contains(&poisson) {
            return Err(check.error("rolls.poisson_ratio", poisson, "in [0, 0.5)"));
        }
        let stack = &self.stack;
        check.positive("stack.work_roll_mass", stack.work_roll_mass, "kg")?;
        check.positive("stack.backup_roll_mass", stack.backup_roll_mass, "kg")?;
        check.positive(
            "stack.work_backup_stiffness",
            stack.work_backup_stiffness,
            "N/m",
        )?;
        check.non_negative(
            "stack.work_backup_damping",
            stack.work_backup_damping,
            "N*s/m",
        )?;
        check.positive(
            "stack.backup_housing_stiffness",
            stack.backup_housing_stiffness,
            "N/m",
        )?;
        check.non_negative(
            "stack.backup_housing_damping",
            stack.backup_housing_damping,
            "N*s/m",
        )?;
        if !STANDS.contains(&self.stands.len()) {
            return Err(check.error(
                "stand",
                format!("{} entries", self.stands.len()),
                format!("{} to {} stands", STANDS.start(), STANDS.end()),
            ));
        }
        for (index, stand) in self.stands.iter().enumerate() {
            self.validate_stand(&check, index, stand)?;
        }
        let gaps = self.roll_gaps(file_name)?;
        let flows: Vec<f64> = self
            .stands
            .iter()
            .zip(&gaps)
            .map(|(stand, gap)| stand.exit_mm * stand.roll_speed * (1.0 + gap.forward_slip))
            .collect();
        let last_flow = flows[flows.len() - 1];
        for (index, (stand, flow)) in self.stands.iter().zip(&flows).enumerate() {
            let mismatch = flow / last_flow - 1.0;
            if mismatch.abs() > MASS_FLOW_TOLERANCE {
                let matching = last_flow / (stand.exit_mm * (1.0 + gaps[index].forward_slip));
                return Err(check.error(
                    &format!("stand[{index}].roll_speed"),
                    stand.roll_speed,
                    format_args!(
                        "within {:.0}% of the mass flow of the last stand: {matching:.3} m/s \
                         matches it (forward slip {:.4}); this speed is {:+.1}% off",
                        MASS_FLOW_TOLERANCE * 100.0,
                        gaps[index].forward_slip,
                        mismatch * 100.0
                    ),
                ));
            }
        }
        Ok(())
    }

    /// The roll gap of every stand; an invalid gap is an error naming the stand.
    pub(crate) fn roll_gaps(&self, file_name: &str) -> Result<Vec<RollGap>, ModelError> {
        (0..self.stands.len())
            .map(|index| {
                roll_gap(&self.pass(index)).map_err(|problem| {
                    Checker { file: file_name }.error(
                        &format!("stand[{index}]"),
                        format_args!(
                            "{} -> {} mm at mu {}",
                            self.stands[index].entry_mm,
                            self.stands[index].exit_mm,
                            self.stands[index].friction
                        ),
                        format_args!("a pass with a valid roll gap: {problem}"),
                    )
                })
            })
            .collect()
    }

    fn validate_stand(
        &self,
        check: &Checker<'_>,
        index: usize,
        stand: &StandPass,
    ) -> Result<(), ModelError> {
        let key = |field: &str| format!("stand[{index}].{field}");
        check.positive(&key("exit_mm"), stand.exit_mm, "mm")?;
        if !(stand.entry_mm.is_finite() && stand.entry_mm > stand.exit_mm) {
            return Err(check.error(
                &key("entry_mm"),
                stand.entry_mm,
                format_args!("> exit_mm = {} mm", stand.exit_mm),
            ));
        }
        check.positive(&key("flow_stress_mpa"), stand.flow_stress_mpa, "MPa")?;
        for (field, tension) in [
            ("back_tension_mpa", stand.back_tension_mpa),
            ("front_tension_mpa", stand.front_tension_mpa),
        ] {
            if !(tension.is_finite() && tension >= 0.0 && tension < stand.flow_stress_mpa) {
                return Err(check.error(
                    &key(field),
                    tension,
                    format_args!(
                        ">= 0 MPa and below the flow stress {} MPa",
                        stand.flow_stress_mpa
                    ),
                ));
            }
        }
        if !(stand.friction > 0.0 && stand.friction <= 0.5) {
            return Err(check.error(&key("friction"), stand.friction, "in (0, 0.5]"));
        }
        check.positive(&key("roll_speed"), stand.roll_speed, "m/s")?;
        if let Some(previous) = index.checked_sub(1).map(|i| &self.stands[i]) {
            let same = |a: f64, b: f64| (a - b).abs() <= 1e-9 * a.abs().max(b.abs());
            if !same(stand.entry_mm, previous.exit_mm) {
                return Err(check.error(
                    &key("entry_mm"),
                    stand.entry_mm,
                    format_args!(
                        "equal to stand[{}].exit_mm = {} mm",
                        index - 1,
                        previous.exit_mm
                    ),
                ));
            }
            if !same(stand.back_tension_mpa, previous.front_tension_mpa) {
                return Err(check.error(
                    &key("back_tension_mpa"),
                    stand.back_tension_mpa,
                    format_args!(
                        "equal to stand[{}].front_tension_mpa = {} MPa",
                        index - 1,
                        previous.front_tension_mpa
                    ),
                ));
            }
        }
        Ok(())
    }
}
