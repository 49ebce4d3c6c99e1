//! A pass's own keys checked against the mill: its configuration, diameters,
//! temperature and speeds; an error names the pass's origin, the key and the range.

use crate::rod::mill::{ConfigurationModes, RodMill};
use crate::rod::schedule::Pass;
use crate::rod::RodError;

/// What a pass's keys give once checked against the mill.
pub(super) struct CheckedPass<'m> {
    /// Index of the pass's configuration in [`RodMill::configurations`].
    pub(super) configuration: usize,
    /// That configuration's modes and speed range.
    pub(super) modes: &'m ConfigurationModes,
    /// Young's modulus at the pass's temperature, Pa.
    pub(super) modulus_pa: f64,
    /// The pass's finishing speed, m/s, within the configuration's range.
    pub(super) finishing_speed_m_s: f64,
    /// Rod exit speed of each stand over the finishing speed.
    pub(super) stand_shares: Vec<f64>,
}

/// Checks `pass` against `mill`, key by key in the pass file's order.
pub(super) fn check_pass<'m>(mill: &'m RodMill, pass: &Pass) -> Result<CheckedPass<'m>, RodError> {
    let (configuration, modes) = configuration(mill, pass)?;
    check_diameters(mill, pass)?;
    let modulus_pa = modulus(mill, pass)?;
    let (finishing_speed_m_s, stand_shares) = speeds(mill, pass)?;
    check_speed_range(mill, pass, modes, finishing_speed_m_s)?;
    Ok(CheckedPass {
        configuration,
        modes,
        modulus_pa,
        finishing_speed_m_s,
        stand_shares,
    })
}

/// The error for `pass`'s `key` at `value`, naming what is `allowed`.
fn refuse(pass: &Pass, key: &str, value: String, allowed: String) -> RodError {
    RodError::Pass {
        origin: pass.origin.clone(),
        key: key.to_owned(),
        value,
        allowed,
    }
}

/// The pass's configuration: its index and modes.
fn configuration<'m>(
    mill: &'m RodMill,
    pass: &Pass,
) -> Result<(usize, &'m ConfigurationModes), RodError> {
    mill.configuration(&pass.configuration).ok_or_else(|| {
        let known: Vec<String> = mill
            .configurations
            .iter()
            .map(|c| format!("{:?}", c.name))
            .collect();
        refuse(
            pass,
            "configuration",
            format!("{:?}", pass.configuration),
            format!("a configuration of the drive (known: {})", known.join(", ")),
        )
    })
}

/// One diameter per stand, each > 0.
fn check_diameters(mill: &RodMill, pass: &Pass) -> Result<(), RodError> {
    let stands = mill.stands.len();
    if pass.diameters_m.len() != stands {
        return Err(refuse(
            pass,
            "diameters_mm",
            format!("{} values", pass.diameters_m.len()),
            format!("one per stand: {stands} values"),
        ));
    }
    if let Some(bad) = pass
        .diameters_m
        .iter()
        .find(|d| !(d.is_finite() && **d > 0.0))
    {
        return Err(refuse(
            pass,
            "diameters_mm",
            format!("{}", bad * 1e3),
            "> 0 mm".to_owned(),
        ));
    }
    Ok(())
}

/// Young's modulus at the pass's temperature, within the mill's table, Pa.
fn modulus(mill: &RodMill, pass: &Pass) -> Result<f64, RodError> {
    let (t_lo, t_hi) = mill.temperature_range_c();
    mill.modulus_pa(pass.temperature_c).ok_or_else(|| {
        refuse(
            pass,
            "temperature_c",
            format!("{}", pass.temperature_c),
            format!("within the modulus table, {t_lo} ..= {t_hi} deg C"),
        )
    })
}

/// The finishing speed (m/s) and each stand's share of it: from the stand speeds
/// when given, else by mass flow from the diameters.
fn speeds(mill: &RodMill, pass: &Pass) -> Result<(f64, Vec<f64>), RodError> {
    let stands = mill.stands.len();
    match (&pass.stand_speeds_m_s, pass.finishing_speed_m_s) {
        (Some(speeds), _) => {
            if speeds.len() != stands {
                return Err(refuse(
                    pass,
                    "stand_speeds_m_s",
                    format!("{} values", speeds.len()),
                    format!("one per stand: {stands} values"),
                ));
            }
            if let Some(bad) = speeds.iter().find(|v| !(v.is_finite() && **v > 0.0)) {
                return Err(refuse(
                    pass,
                    "stand_speeds_m_s",
                    format!("{bad}"),
                    "> 0 m/s".to_owned(),
                ));
            }
            let last = speeds[stands - 1];
            Ok((last, speeds.iter().map(|v| v / last).collect::<Vec<f64>>()))
        }
        (None, Some(speed)) => {
            let finishing = pass.diameters_m[stands - 1];
            let shares = pass
                .diameters_m
                .iter()
                .map(|d| (finishing / d).powi(2))
                .collect();
            Ok((speed, shares))
        }
        (None, None) => Err(refuse(
            pass,
            "finishing_speed_m_s",
            "missing".to_owned(),
            "> 0 m/s".to_owned(),
        )),
    }
}

/// The finishing speed is > 0 and within the configuration's range.
fn check_speed_range(
    mill: &RodMill,
    pass: &Pass,
    modes: &ConfigurationModes,
    finishing_speed_m_s: f64,
) -> Result<(), RodError> {
    let (v_lo, v_hi) = modes.speed_range_m_s;
    if !(finishing_speed_m_s.is_finite() && finishing_speed_m_s > 0.0) {
        return Err(refuse(
            pass,
            "finishing_speed_m_s",
            format!("{finishing_speed_m_s}"),
            format!(
                "> 0 m/s, within configuration {:?}'s range {v_lo:.1} ..= {v_hi:.1} m/s",
                modes.name
            ),
        ));
    }
    // A relative slack of 1e-9 absorbs rounding at the range's ends.
    if finishing_speed_m_s < v_lo * (1.0 - 1e-9) || finishing_speed_m_s > v_hi * (1.0 + 1e-9) {
        return Err(refuse(
            pass,
            "finishing_speed_m_s",
            format!("{finishing_speed_m_s}"),
            format!(
                "within configuration {:?}'s range {v_lo:.1} ..= {v_hi:.1} m/s (motor {} ..= {} rpm)",
                modes.name, mill.motor_rpm.0, mill.motor_rpm.1
            ),
        ));
    }
    Ok(())
}
