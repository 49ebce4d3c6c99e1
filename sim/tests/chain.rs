//! Torsional chain simulation: closed-form oracle, step halving with backlash, gap
//! behaviour, steady state and noise.

use millgate_sim::chain::{simulate, simulate_with_noise, Simulator, Transient};
use millgate_sim::model::{Coupling, Load, Mass, Measurement, Model, Motor};

mod common;

use common::load;

/// Two masses, no controller, no damping, load from t = 0.
fn two_mass(backlash: f64) -> Model {
    Model {
        name: "two masses".into(),
        masses: vec![
            Mass {
                name: "motor".into(),
                inertia: 4.0e3,
            },
            Mass {
                name: "rolls".into(),
                inertia: 1.0e3,
            },
        ],
        couplings: vec![Coupling {
            backlash,
            ..Coupling::linear("spindle", 2.0e7, 0.0)
        }],
        motor: Motor {
            speed_kp: 0.0,
            speed_ki: 0.0,
        },
        load: Load {
            static_torque: 50.0,
            rise_rate: 80.0,
            onset: 0.0,
        },
        measurement: Measurement {
            coupling: 0,
            sample_rate: 2000.0,
            duration: 0.5,
            lag: 0.0,
        },
        configurations: Vec::new(),
    }
}

fn max_abs_difference(a: &[f64], b: &[f64]) -> f64 {
    assert_eq!(a.len(), b.len());
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
}

fn peak(transient: &Transient) -> f64 {
    transient.torque_knm.iter().fold(f64::MIN, |m, &v| m.max(v))
}

#[test]
fn linear_two_mass_chain_matches_closed_form() -> anyhow::Result<()> {
    // T'' + w^2 T = w^2 r M(t), r = J1 / (J1 + J2), w^2 = C (1/J1 + 1/J2), T(0) = T'(0) = 0.
    let model = two_mass(0.0);
    let (j1, j2) = (model.masses[0].inertia, model.masses[1].inertia);
    let c = model.couplings[0].stiffness;
    let (m0, a) = (model.load.static_torque, model.load.rise_rate);
    let omega = (c * (1.0 / j1 + 1.0 / j2)).sqrt();
    let r = j1 / (j1 + j2);
    let b = r * m0 * omega * omega / (a * a + omega * omega);
    let exact = |t: f64| {
        r * m0 - b * (-a * t).exp() + (b - r * m0) * (omega * t).cos()
            - a * b / omega * (omega * t).sin()
    };
    let transient = simulate(&model)?;
    assert_eq!(transient.t.len(), 1000);
    let max_error = |transient: &Transient| {
        transient
            .t
            .iter()
            .zip(&transient.torque_knm)
            .map(|(&t, &torque)| (torque - exact(t)).abs())
            .fold(0.0, f64::max)
    };
    let error = max_error(&transient);
    // RK4 is fourth order: four times the steps cut the error by about 256.
    let simulator = Simulator::new(&model)?;
    let substeps = simulator.substeps_per_sample();
    let finer = max_error(&simulator.with_substeps_per_sample(4 * substeps).run());
    assert!(finer < error / 100.0, "error {error} with 4x steps {finer}");
    assert!(error < 2e-5 * m0, "max error {error} kN*m");
    Ok(())
}

#[test]
fn halving_the_step_changes_backlash_results_by_less_than_0_1_percent() -> anyhow::Result<()> {
    // A worn spindle, and a harsher case where the fast load makes the gap open and
    // close many times.
    let mut harsh = two_mass(4.0e-3);
    harsh.load.rise_rate = 2000.0;
    harsh.load.onset = 0.0123;
    for model in [load("table2-adjusted-backlash.toml")?, harsh] {
        let simulator = Simulator::new(&model)?;
        let mut state = simulator.initial_state();
        let mut coarse = vec![0.0; simulator.sample_count()];
        let events = simulator.run_into(&mut state, &mut coarse);
        assert!(events >= 1, "{}: the gap never closed", model.name);
        let fine = simulator
            .clone()
            .with_substeps_per_sample(2 * simulator.substeps_per_sample())
            .run();
        let difference = max_abs_difference(&coarse, &fine.torque_knm);
        let scale = coarse.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
        assert!(
            difference < 1e-3 * scale,
            "{}: {difference} kN*m of {scale} kN*m ({events} gap crossings)",
            model.name
        );
    }
    Ok(())
}

#[test]
fn fast_load_makes_the_gap_open_and_close_repeatedly() -> anyhow::Result<()> {
    let mut model = two_mass(4.0e-3);
    model.load.rise_rate = 2000.0;
    let simulator = Simulator::new(&model)?;
    let mut state = simulator.initial_state();
    let mut torque = vec![0.0; simulator.sample_count()];
    let events = simulator.run_into(&mut state, &mut torque);
    assert!(events > 4, "only {events} gap crossings");
    // Undamped: the torque is exactly zero whenever the gap is open, so the record has
    // stretches of zeros after the first contact as well as before it.
    let first_contact = torque
        .iter()
        .position(|&v| v != 0.0)
        .unwrap_or(torque.len());
    assert!(torque[first_contact..].contains(&0.0));
    Ok(())
}

#[test]
fn gap_delays_the_first_contact_and_raises_the_peak() -> anyhow::Result<()> {
    let linear = simulate(&two_mass(0.0))?;
    let worn = simulate(&two_mass(4.0e-3))?;
    let first_nonzero = |t: &Transient| t.torque_knm.iter().position(|&v| v > 1e-9);
    // Loaded from t = 0, the linear coupling carries torque from the first step.
    assert_eq!(first_nonzero(&linear), Some(1));
    let contact = first_nonzero(&worn).unwrap_or(usize::MAX);
    assert!(contact > 5, "contact at sample {contact}");
    assert!(peak(&worn) > peak(&linear) * 1.05);
    Ok(())
}

#[test]
fn torque_settles_at_the_static_load() -> anyhow::Result<()> {
    for name in ["table2-adjusted.toml", "table2-adjusted-backlash.toml"] {
        let mut model = load(name)?;
        model.measurement.duration = 3.0;
        let transient = simulate(&model)?;
        let last = transient.torque_knm.last().copied().unwrap_or_default();
        assert!(
            (last - model.load.static_torque).abs() < 0.005 * model.load.static_torque,
            "{name}: settles at {last}"
        );
        assert!(transient.torque_knm[0] == 0.0);
        assert!((transient.t[1] - transient.t[0] - 1.0 / 2000.0).abs() < 1e-15);
    }
    Ok(())
}

#[test]
fn nothing_moves_before_the_onset() -> anyhow::Result<()> {
    let model = load("table2-adjusted.toml")?;
    let transient = simulate(&model)?;
    for (t, torque) in transient.t.iter().zip(&transient.torque_knm) {
        if *t <= model.load.onset {
            assert_eq!(*torque, 0.0, "at {t} s");
        }
    }
    Ok(())
}

#[test]
fn noise_is_seeded_gaussian_with_the_requested_rms() -> anyhow::Result<()> {
    let model = load("table2-adjusted.toml")?;
    let clean = simulate(&model)?;
    let noisy = simulate_with_noise(&model, 2.0, 7)?;
    let again = simulate_with_noise(&model, 2.0, 7)?;
    let other = simulate_with_noise(&model, 2.0, 8)?;
    assert_eq!(noisy, again);
    assert_ne!(noisy, other);
    let count = clean.torque_knm.len() as f64;
    let residual: Vec<f64> = noisy
        .torque_knm
        .iter()
        .zip(&clean.torque_knm)
        .map(|(n, c)| n - c)
        .collect();
    let mean = residual.iter().sum::<f64>() / count;
    let rms = (residual.iter().map(|r| r * r).sum::<f64>() / count).sqrt();
    assert!((rms - 2.0).abs() < 0.2, "rms {rms}");
    assert!(mean.abs() < 0.25, "mean {mean}");
    assert!(simulate_with_noise(&model, -1.0, 7).is_err());
    assert!(simulate_with_noise(&model, f64::NAN, 7).is_err());
    Ok(())
}

#[test]
fn invalid_hand_built_model_is_an_error_not_a_panic() {
    let mut model = two_mass(0.0);
    model.couplings.push(Coupling::linear("extra", 1.0, 0.0));
    assert!(simulate(&model).is_err());
    let mut model = two_mass(0.0);
    model.masses[1].inertia = 0.0;
    assert!(Simulator::new(&model).is_err());
}

#[test]
fn halving_the_step_changes_hardening_and_friction_results_by_less_than_0_1_percent(
) -> anyhow::Result<()> {
    let mut model = load("table2-adjusted.toml")?;
    model.couplings[1].hardening = 8.0e11;
    model.couplings[0].friction = 6.0e3;
    let simulator = Simulator::new(&model)?;
    let coarse = simulator.run();
    let fine = simulator
        .clone()
        .with_substeps_per_sample(2 * simulator.substeps_per_sample())
        .run();
    let difference = max_abs_difference(&coarse.torque_knm, &fine.torque_knm);
    assert!(difference < 1e-3 * peak(&coarse), "{difference} kN*m");
    // And the extensions act: the response differs from the linear chain's.
    let linear = simulate(&load("table2-adjusted.toml")?)?;
    assert!(max_abs_difference(&coarse.torque_knm, &linear.torque_knm) > 0.05 * peak(&linear));
    Ok(())
}

#[test]
fn lagged_channel_is_the_first_order_filtered_torque() -> anyhow::Result<()> {
    let direct_model = load("table2-adjusted.toml")?;
    let mut lagged_model = direct_model.clone();
    let tau = 5.0e-3;
    lagged_model.measurement.lag = tau;
    let direct = simulate(&direct_model)?.torque_knm;
    let lagged = simulate(&lagged_model)?.torque_knm;
    // Exact response of dy/dt = (x - y) / tau to x linear between samples.
    let dt = 1.0 / direct_model.measurement.sample_rate;
    let a = (-dt / tau).exp();
    let mut filtered = vec![0.0; direct.len()];
    for k in 1..direct.len() {
        let slope = (direct[k] - direct[k - 1]) / dt;
        filtered[k] = a * filtered[k - 1] + direct[k] - a * direct[k - 1] - tau * slope * (1.0 - a);
    }
    let scale = direct.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
    assert!(max_abs_difference(&lagged, &filtered) < 2e-3 * scale);
    assert!(
        max_abs_difference(&lagged, &direct) > 0.05 * scale,
        "the lag did nothing"
    );
    Ok(())
}

#[test]
fn splitting_a_coupling_by_a_small_inertia_keeps_the_response() -> anyhow::Result<()> {
    let model = load("table2-adjusted.toml")?;
    let base = simulate(&model)?;
    for coupling in 0..2 {
        let split = model.split_coupling(coupling, 20.0)?;
        assert_eq!(split.masses.len(), 4);
        assert_eq!(
            split.measurement.coupling,
            if coupling == 0 { 2 } else { 1 }
        );
        let response = simulate(&split)?;
        let difference = max_abs_difference(&base.torque_knm, &response.torque_knm);
        assert!(
            difference < 5e-3 * peak(&base),
            "coupling {coupling}: {difference} kN*m"
        );
    }
    // A large inertia in the spindle adds a mode the chain did not have.
    let heavy = simulate(&model.split_coupling(1, 2000.0)?)?;
    let difference = max_abs_difference(&base.torque_knm, &heavy.torque_knm);
    assert!(difference > 0.01 * peak(&base), "{difference} kN*m");
    assert!(model.split_coupling(2, 20.0).is_err());
    Ok(())
}
