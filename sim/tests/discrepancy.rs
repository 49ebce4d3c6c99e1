//! The model-discrepancy workflow on records with a hidden effect: it sees only the
//! record and a model without the effect, and must name the effect and its location,
//! recover its size within 25% and shrink the gap.

mod common;

use millgate_sim::discrepancy::cases::HiddenCase;
use millgate_sim::discrepancy::{run, Effect, Report};
use millgate_sim::model::Model;

/// The cases: truth is the Table 2 "adjusted" driveline; some are handed the stiffness
/// from drawings instead.
fn cases() -> anyhow::Result<Vec<HiddenCase>> {
    let adjusted = common::load("table2-adjusted.toml")?;
    let drawings = common::load("table2-drawings.toml")?;
    let case = |name: &str, handed: &Model, hidden, noise, seed| {
        HiddenCase::new(name, &adjusted, handed, hidden, noise, seed)
    };
    use Effect::*;
    Ok(vec![
        case(
            "backlash spindle 2 mrad",
            &adjusted,
            Some((Backlash, Some(1), 2.0e-3)),
            0.5,
            1,
        ),
        case(
            "backlash gear 1.5 mrad",
            &adjusted,
            Some((Backlash, Some(0), 1.5e-3)),
            0.5,
            2,
        ),
        case(
            "backlash gear 1.5 mrad, drawings",
            &drawings,
            Some((Backlash, Some(0), 1.5e-3)),
            1.0,
            3,
        ),
        case(
            "backlash spindle 3 mrad, noisy",
            &adjusted,
            Some((Backlash, Some(1), 3.0e-3)),
            2.0,
            16,
        ),
        case(
            "sensor lag 5 ms",
            &adjusted,
            Some((SensorLag, None, 5.0e-3)),
            0.5,
            4,
        ),
        case(
            "sensor lag 12 ms, drawings",
            &drawings,
            Some((SensorLag, None, 12.0e-3)),
            1.0,
            5,
        ),
        case(
            "hardening spindle",
            &adjusted,
            Some((Hardening, Some(1), 8.0e11)),
            0.5,
            6,
        ),
        case(
            "hardening gear, drawings",
            &drawings,
            Some((Hardening, Some(0), 8.0e12)),
            0.5,
            7,
        ),
        case(
            "extra inertia in spindle",
            &adjusted,
            Some((ExtraInertia, Some(1), 400.0)),
            0.3,
            8,
        ),
        case(
            "extra inertia in gear coupling",
            &adjusted,
            Some((ExtraInertia, Some(0), 3000.0)),
            0.3,
            9,
        ),
        case(
            "friction spindle 3 kN*m",
            &adjusted,
            Some((CoulombDamping, Some(1), 3.0)),
            0.3,
            10,
        ),
        case(
            "friction gear 6 kN*m, drawings",
            &drawings,
            Some((CoulombDamping, Some(0), 6.0)),
            0.5,
            11,
        ),
        case(
            "backlash spindle 1 mrad, quiet",
            &adjusted,
            Some((Backlash, Some(1), 1.0e-3)),
            0.2,
            12,
        ),
        case("null: nothing wrong", &adjusted, None, 0.5, 13),
        case("null: stiffness from drawings", &drawings, None, 1.0, 14),
        case("null: drawings, quiet", &drawings, None, 0.2, 15),
    ])
}

fn check(case: &HiddenCase, report: &Report) -> Result<(), String> {
    let named = (report.effect, report.location);
    match case.hidden {
        None => {
            if report.effect != "none" {
                return Err(format!("named {named:?} in a null case"));
            }
        }
        Some((effect, location, size)) => {
            if named != (effect.key(), location) {
                return Err(format!(
                    "named {named:?}, hidden {:?}",
                    (effect.key(), location)
                ));
            }
            let fitted = report.parameters[effect.parameter_key()];
            if (fitted / size - 1.0).abs() > 0.25 {
                return Err(format!("size {fitted:.4e}, hidden {size:.4e}"));
            }
            let above = |rmse: f64| {
                (rmse * rmse - case.noise_rms * case.noise_rms)
                    .max(0.0)
                    .sqrt()
            };
            let before = above(report.rmse_before);
            let after = above(report.rmse_after);
            if after * 3.0 > before {
                return Err(format!("gap above noise {before:.3} -> {after:.3}, not 3x"));
            }
        }
    }
    if report.rmse_after > 1.2 * case.noise_rms {
        return Err(format!(
            "rmse_after {:.3} > 1.2 x noise {:.3}",
            report.rmse_after, case.noise_rms
        ));
    }
    Ok(())
}

#[test]
fn every_hidden_effect_is_named_sized_and_removed() -> anyhow::Result<()> {
    let mut failures = Vec::new();
    for case in cases()? {
        let record = case.record()?;
        let started = std::time::Instant::now();
        let report = run(&record.measured(), &case.handed, |_| {})?;
        let outcome = check(&case, &report);
        println!(
            "{:45} -> {:16} {:?} {:?} rmse {:.3} -> {:.3} (noise {:.2}, est {:.3}) {} sims {:.2?} {}",
            case.name,
            report.effect,
            report.location,
            report.parameters.values().next(),
            report.rmse_before,
            report.rmse_after,
            case.noise_rms,
            report.noise_rms,
            report.simulations,
            started.elapsed(),
            outcome.as_ref().err().map_or("ok", |e| e.as_str()),
        );
        if let Err(e) = outcome {
            failures.push(format!("{}: {e}", case.name));
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
    Ok(())
}
