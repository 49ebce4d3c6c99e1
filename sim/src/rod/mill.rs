//! The rod-mill file: the drive (a model file with its configurations), the stands in
//! rolling order, the spans between them, the rod's material and damping, the motor's
//! speed range.
//!
//! ```toml
//! name = "RSM block"
//! drive = "../rsm-drive.toml"   # model file, relative to this file
//!
//! [motor]
//! speed_min_rpm = 600.0         # > 0
//! speed_max_rpm = 1800.0        # > speed_min_rpm
//!
//! [rod]
//! density = 7700.0              # kg/m^3, > 0
//! damping_ratio = 0.02          # modal damping ratio of the rod's bending modes, 0..1
//! modes = 2                     # bending modes per span, 1..=10
//! epsilon = 0.1                 # pulsation P / (P_E + T0) of each source, 0 < e <= 0.5
//! moving_rod = false            # optional: include -rho A V^2 in the axial force
//! min_participation = 0.01      # optional: drive modes below it pump no span
//! [[rod.modulus]]               # E(T), linear between points, T strictly increasing
//! temperature_c = 700.0
//! modulus_pa = 150e9
//!
//! [[stand]]                     # rolling order; the last is the finishing stand
//! name = "stand 1"
//! mass = "stand 1"              # optional: the drive mass of its rolls (default: name)
//! roll_diameter = 0.228         # m, > 0
//!
//! [[span]]                      # between consecutive stands
//! from = "stand 1"
//! to = "stand 2"
//! length = 1.20                 # m, > 0
//! ends = "pinned"               # or "clamped"
//! tension = 0.0                 # N, setup tension T0, >= 0; optional
//! ```

use std::f64::consts::PI;
use std::path::Path;

use millgate_dsp::mathieu::Mathieu;
use serde::Deserialize;

use super::beam::{Ends, MAX_MODES};
use super::RodError;
use crate::model::{parse_toml, read_text, Checker, Model};

/// Largest pulsation ratio epsilon accepted: with `q / a <= epsilon / 2` the points
/// beyond the resolved Mathieu range (|a| > 1e4 or |q| > 100) lie at tongue orders
/// near 100, where tongues are narrower than 1e-100 (taken as stable).
pub(crate) const MAX_EPSILON: f64 = 0.5;

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct MillFile {
    name: String,
    drive: String,
    motor: MotorFile,
    rod: RodFile,
    #[serde(rename = "stand")]
    stands: Vec<StandFile>,
    #[serde(rename = "span")]
    spans: Vec<SpanFile>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct MotorFile {
    speed_min_rpm: f64,
    speed_max_rpm: f64,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RodFile {
    density: f64,
    damping_ratio: f64,
    modes: usize,
    epsilon: f64,
    #[serde(default)]
    moving_rod: bool,
    #[serde(default = "default_min_participation")]
    min_participation: f64,
    modulus: Vec<ModulusPoint>,
}

fn default_min_participation() -> f64 {
    0.01
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct StandFile {
    name: String,
    #[serde(default)]
    mass: Option<String>,
    roll_diameter: f64,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct SpanFile {
    from: String,
    to: String,
    length: f64,
    ends: Ends,
    #[serde(default)]
    tension: f64,
}

/// One point of the modulus table.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct ModulusPoint {
    /// Rod temperature, deg C.
    pub(crate) temperature_c: f64,
    /// Young's modulus at that temperature, Pa, > 0.
    pub(crate) modulus_pa: f64,
}

/// The rod's material, damping and excitation settings.
#[derive(Debug, Clone, PartialEq)]
pub struct RodSettings {
    /// Density, kg/m^3.
    pub(crate) density_kg_m3: f64,
    /// Modal damping ratio zeta of every bending mode.
    pub damping_ratio: f64,
    /// Bending modes per span, 1..=10.
    pub modes: usize,
    /// Pulsation amplitude P / (P_E + T0) of each excitation source.
    pub(crate) epsilon: f64,
    /// Whether the axial rod speed lowers the effective tension (`T0 - rho A V^2`).
    pub(crate) moving_rod: bool,
    /// Drive modes whose participation in a span is below this pump nothing there.
    pub(crate) min_participation: f64,
    /// E(T), temperature strictly increasing.
    pub(crate) modulus: Vec<ModulusPoint>,
}

/// A stand: its rolls' drive mass and diameter.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Stand {
    /// Name used by spans and reports.
    pub(crate) name: String,
    /// Index of the drive mass carrying its rolls.
    pub(crate) mass: usize,
    /// Working roll diameter, m.
    pub(crate) roll_diameter_m: f64,
}

/// A span between consecutive stands.
#[derive(Debug, Clone, PartialEq)]
pub struct Span {
    /// `"<upstream> - <downstream>"`.
    pub name: String,
    /// Index of the upstream stand (the span carries its exit section).
    pub(crate) upstream: usize,
    /// Index of the downstream stand (`upstream + 1`).
    pub(crate) downstream: usize,
    /// Free length between the roll gaps, m.
    pub(crate) length_m: f64,
    /// End conditions.
    pub(crate) ends: Ends,
    /// Setup tension T0, N.
    pub(crate) tension_n: f64,
}

/// The drive in one configuration: its modes and finishing-speed range.
#[derive(Debug, Clone, PartialEq)]
pub struct ConfigurationModes {
    /// Configuration name (the drive model's; `"default"` when it has none).
    pub name: String,
    /// Finishing speed at the motor's minimum and maximum speed, m/s.
    pub speed_range_m_s: (f64, f64),
    /// Elastic natural frequencies, Hz, ascending (the rigid mode left out).
    pub(crate) frequencies_hz: Vec<f64>,
    /// Per elastic mode, the unit-norm shape's entry at each stand's mass.
    pub(crate) stand_shapes: Vec<Vec<f64>>,
}

/// A validated rod-mill file.
#[derive(Debug, Clone)]
pub struct RodMill {
    /// Free-text name.
    pub name: String,
    /// The mill file as given (for messages).
    pub file: String,
    /// Motor speed range, rpm (min, max).
    pub(crate) motor_rpm: (f64, f64),
    /// Rod material, damping and excitation settings.
    pub rod: RodSettings,
    /// Stands in rolling order; the last is the finishing stand.
    pub(crate) stands: Vec<Stand>,
    /// Spans between consecutive stands.
    pub spans: Vec<Span>,
    /// Every configuration of the drive (one, `"default"`, when it has none).
    pub configurations: Vec<ConfigurationModes>,
    /// The Mathieu solver (default tolerance).
    pub(crate) mathieu: Mathieu,
}

impl RodMill {
    /// Reads and validates a mill file; its `drive` path is relative to the file.
    pub fn load(path: impl AsRef<Path>) -> Result<RodMill, RodError> {
        let path = path.as_ref();
        let (text, file) = read_text(path)?;
        RodMill::from_toml_str(&text, &file, path.parent().unwrap_or(Path::new(".")))
    }

    /// Parses and validates a mill file's text; `file_name` labels errors and
    /// `base_dir` resolves the `drive` path.
    pub fn from_toml_str(
        text: &str,
        file_name: &str,
        base_dir: &Path,
    ) -> Result<RodMill, RodError> {
        let raw: MillFile = parse_toml(text, file_name)?;
        let check = Checker { file: file_name };
        let drive = Model::load(base_dir.join(&raw.drive))?;

        check.positive("motor.speed_min_rpm", raw.motor.speed_min_rpm, "rpm")?;
        if !(raw.motor.speed_max_rpm.is_finite()
            && raw.motor.speed_max_rpm > raw.motor.speed_min_rpm)
        {
            return Err(check
                .error(
                    "motor.speed_max_rpm",
                    raw.motor.speed_max_rpm,
                    format!("> motor.speed_min_rpm ({} rpm)", raw.motor.speed_min_rpm),
                )
                .into());
        }
        let rod = rod_settings(raw.rod, &check)?;
        let stands = stands(&raw.stands, &drive, &check)?;
        let spans = spans(&raw.spans, &stands, &check)?;
        let configurations = configurations(
            &drive,
            &stands,
            raw.motor.speed_min_rpm,
            raw.motor.speed_max_rpm,
        )?;
        Ok(RodMill {
            name: raw.name,
            file: file_name.to_owned(),
            motor_rpm: (raw.motor.speed_min_rpm, raw.motor.speed_max_rpm),
            rod,
            stands,
            spans,
            configurations,
            mathieu: Mathieu::default(),
        })
    }

    /// The configuration named `name`, with its index.
    pub fn configuration(&self, name: &str) -> Option<(usize, &ConfigurationModes)> {
        self.configurations
            .iter()
            .enumerate()
            .find(|(_, c)| c.name == name)
    }

    /// Young's modulus at `temperature_c` (linear in the table), or `None` outside it.
    pub(crate) fn modulus_pa(&self, temperature_c: f64) -> Option<f64> {
        let table = &self.rod.modulus;
        if !temperature_c.is_finite() {
            return None;
        }
        if table.len() == 1 {
            return (temperature_c == table[0].temperature_c).then_some(table[0].modulus_pa);
        }
        table.windows(2).find_map(|w| {
            let (lo, hi) = (w[0], w[1]);
            (lo.temperature_c..=hi.temperature_c)
                .contains(&temperature_c)
                .then(|| {
                    let t =
                        (temperature_c - lo.temperature_c) / (hi.temperature_c - lo.temperature_c);
                    lo.modulus_pa + t * (hi.modulus_pa - lo.modulus_pa)
                })
        })
    }

    /// The modulus table's temperature range, deg C.
    pub fn temperature_range_c(&self) -> (f64, f64) {
        let table = &self.rod.modulus;
        (table[0].temperature_c, table[table.len() - 1].temperature_c)
    }
}

fn rod_settings(raw: RodFile, check: &Checker<'_>) -> Result<RodSettings, RodError> {
    check.positive("rod.density", raw.density, "kg/m^3")?;
    if !(raw.damping_ratio.is_finite() && (0.0..1.0).contains(&raw.damping_ratio)) {
        return Err(check
            .error(
                "rod.damping_ratio",
                raw.damping_ratio,
                "in 0 .. 1 (exclusive)",
            )
            .into());
    }
    if !(1..=MAX_MODES).contains(&raw.modes) {
        return Err(check
            .error("rod.modes", raw.modes, format!("1 ..= {MAX_MODES}"))
            .into());
    }
    if !(raw.epsilon.is_finite() && raw.epsilon > 0.0 && raw.epsilon <= MAX_EPSILON) {
        return Err(check
            .error(
                "rod.epsilon",
                raw.epsilon,
                format!("> 0 and <= {MAX_EPSILON} (P / (P_E + T0))"),
            )
            .into());
    }
    if !(raw.min_participation.is_finite() && (0.0..=1.0).contains(&raw.min_participation)) {
        return Err(check
            .error("rod.min_participation", raw.min_participation, "in 0 ..= 1")
            .into());
    }
    if raw.modulus.is_empty() {
        return Err(check
            .error(
                "rod.modulus",
                "no entries",
                "at least one [[rod.modulus]] point",
            )
            .into());
    }
    for (index, point) in raw.modulus.iter().enumerate() {
        let key = format!("rod.modulus[{index}]");
        check.positive(&format!("{key}.modulus_pa"), point.modulus_pa, "Pa")?;
        let previous = index.checked_sub(1).map(|i| raw.modulus[i].temperature_c);
        let ok =
            point.temperature_c.is_finite() && previous.is_none_or(|p| point.temperature_c > p);
        if !ok {
            return Err(check
                .error(
                    &format!("{key}.temperature_c"),
                    point.temperature_c,
                    "finite and above the previous point's (deg C, increasing)",
                )
                .into());
        }
    }
    Ok(RodSettings {
        density_kg_m3: raw.density,
        damping_ratio: raw.damping_ratio,
        modes: raw.modes,
        epsilon: raw.epsilon,
        moving_rod: raw.moving_rod,
        min_participation: raw.min_participation,
        modulus: raw.modulus,
    })
}

fn stands(raw: &[StandFile], drive: &Model, check: &Checker<'_>) -> Result<Vec<Stand>, RodError> {
    if raw.len() < 2 {
        return Err(check
            .error(
                "stand",
                format!("{} entries", raw.len()),
                "at least 2 stands",
            )
            .into());
    }
    raw.iter()
        .enumerate()
        .map(|(index, stand)| {
            if raw[..index].iter().any(|s| s.name == stand.name) {
                return Err(check
                    .error(
                        &format!("stand[{index}].name"),
                        format!("{:?}", stand.name),
                        "a name no other stand has",
                    )
                    .into());
            }
            let mass_name = stand.mass.as_deref().unwrap_or(&stand.name);
            let mass = drive
                .masses
                .iter()
                .position(|m| m.name == mass_name)
                .ok_or_else(|| {
                    let known: Vec<String> = drive
                        .masses
                        .iter()
                        .map(|m| format!("{:?}", m.name))
                        .collect();
                    check.error(
                        &format!("stand[{index}].mass"),
                        format!("{mass_name:?}"),
                        format!("a mass of the drive (known: {})", known.join(", ")),
                    )
                })?;
            check.positive(
                &format!("stand[{index}].roll_diameter"),
                stand.roll_diameter,
                "m",
            )?;
            Ok(Stand {
                name: stand.name.clone(),
                mass,
                roll_diameter_m: stand.roll_diameter,
            })
        })
        .collect()
}

fn spans(raw: &[SpanFile], stands: &[Stand], check: &Checker<'_>) -> Result<Vec<Span>, RodError> {
    if raw.is_empty() {
        return Err(check
            .error("span", "no entries", "at least one [[span]]")
            .into());
    }
    let known: Vec<String> = stands.iter().map(|s| format!("{:?}", s.name)).collect();
    raw.iter()
        .enumerate()
        .map(|(index, span)| {
            let find = |key: &str, name: &str| {
                stands.iter().position(|s| s.name == name).ok_or_else(|| {
                    check.error(
                        &format!("span[{index}].{key}"),
                        format!("{name:?}"),
                        format!("a stand (known: {})", known.join(", ")),
                    )
                })
            };
            let upstream = find("from", &span.from)?;
            let downstream = find("to", &span.to)?;
            if downstream != upstream + 1 {
                return Err(check
                    .error(
                        &format!("span[{index}].to"),
                        format!("{:?}", span.to),
                        format!(
                            "the stand after {:?} in rolling order{}",
                            span.from,
                            stands
                                .get(upstream + 1)
                                .map_or(String::new(), |s| format!(" ({:?})", s.name))
                        ),
                    )
                    .into());
            }
            if raw[..index].iter().any(|s| s.from == span.from) {
                return Err(check
                    .error(
                        &format!("span[{index}].from"),
                        format!("{:?}", span.from),
                        "a stand no other span starts at",
                    )
                    .into());
            }
            check.positive(&format!("span[{index}].length"), span.length, "m")?;
            check.non_negative(&format!("span[{index}].tension"), span.tension, "N")?;
            Ok(Span {
                name: format!("{} - {}", span.from, span.to),
                upstream,
                downstream,
                length_m: span.length,
                ends: span.ends,
                tension_n: span.tension,
            })
        })
        .collect()
}

fn configurations(
    drive: &Model,
    stands: &[Stand],
    rpm_min: f64,
    rpm_max: f64,
) -> Result<Vec<ConfigurationModes>, RodError> {
    let names: Vec<Option<&str>> = if drive.configurations.is_empty() {
        vec![None]
    } else {
        drive
            .configurations
            .iter()
            .map(|c| Some(c.name.as_str()))
            .collect()
    };
    let finishing = stands.last().expect("validated: at least 2 stands");
    names
        .into_iter()
        .map(|name| {
            let tree = drive.tree(name)?;
            let modes = tree
                .modes()
                .map_err(|error| crate::model::ModelError::Value {
                    file: "<drive>".to_owned(),
                    key: "configuration".to_owned(),
                    value: name.unwrap_or("default").to_owned(),
                    allowed: format!("a drive with positive inertias ({error})"),
                })?;
            let mut frequencies_hz = Vec::new();
            let mut stand_shapes = Vec::new();
            for (index, &frequency) in modes.frequencies_hz.iter().enumerate() {
                if frequency <= 0.0 {
                    continue;
                }
                let shape = modes.unit_shape(index);
                frequencies_hz.push(frequency);
                stand_shapes.push(stands.iter().map(|s| shape[s.mass]).collect());
            }
            // Finishing speed = roll surface speed of the finishing stand.
            let surface = |rpm: f64| {
                PI * finishing.roll_diameter_m * rpm / 60.0 * tree.speed_ratios[finishing.mass]
            };
            Ok(ConfigurationModes {
                name: name.unwrap_or("default").to_owned(),
                speed_range_m_s: (surface(rpm_min), surface(rpm_max)),
                frequencies_hz,
                stand_shapes,
            })
        })
        .collect()
}
