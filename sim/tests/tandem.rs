//! The physical tandem mill: roll gap and roots against an independent numpy
//! implementation (`tandem_reference.py`, golden values below), a stand's modes against
//! the closed form of a two-mass stack, the roots against time simulations at frozen
//! speed, the critical speed, the ground truth of a ramp, a run advanced in pieces
//! against the same run at once, and the schedule file's and run settings' errors.

use millgate_sim::tandem::control::{SlowDownPolicy, SpeedControl};
use millgate_sim::tandem::online::OnlineMill;
use millgate_sim::tandem::roots::{critical_speed, Characteristic};
use millgate_sim::tandem::simulate::{
    simulate, Accelerometer, Excitation, NoiseBurst, RunError, RunSettings, Simulation, SpeedRamp,
    TensionStep,
};
use millgate_sim::tandem::truth::{developed_time, ground_truth, mill_critical_speed};
use millgate_sim::tandem::{PassSchedule, TandemMill};

fn schedule() -> PassSchedule {
    PassSchedule::example().expect("example schedule")
}

fn close(value: f64, expected: f64, relative: f64) -> bool {
    (value - expected).abs() <= relative * expected.abs()
}

/// `python3 sim/tests/tandem_reference.py`: force (N), forward slip, dF/dh (N/m),
/// df/dsigma_f (1/Pa) per stand.
const REFERENCE_STANDS: [(f64, f64, f64, f64); 5] = [
    (
        7850730.518731769,
        0.0864206322234821,
        -6453297994.285566,
        5.810321739565998e-10,
    ),
    (
        8441971.534332855,
        0.07069814560290823,
        -11299772071.349022,
        3.170978344345645e-10,
    ),
    (
        7771149.241821998,
        0.06408542601476772,
        -15523674597.220484,
        2.734070734969669e-10,
    ),
    (
        7491665.622647027,
        0.058785457322316555,
        -26174631995.439987,
        2.0845816351831373e-10,
    ),
    (
        7717696.406009602,
        0.029926999464014035,
        -34482293429.086,
        1.0112551530881181e-10,
    ),
];

/// The reference's rightmost roots: (speed factor, real part 1/s, frequency Hz).
const REFERENCE_ROOTS: [(f64, f64, f64); 2] = [
    (0.9, -0.267157587900872, 166.49580998223036),
    (1.2, 0.579814152721269, 194.72402073534846),
];

#[test]
fn roll_gap_and_partials_match_the_independent_reference() -> anyhow::Result<()> {
    let mill = TandemMill::new(&schedule())?;
    for (stand, &(force, slip, force_h, slip_front)) in mill.stands().iter().zip(&REFERENCE_STANDS)
    {
        assert!(close(stand.gap.force_n, force, 1e-9), "{stand:?}");
        assert!(close(stand.gap.forward_slip, slip, 1e-9), "{stand:?}");
        assert!(close(stand.partials.force[1], force_h, 1e-6), "{stand:?}");
        assert!(close(stand.partials.slip[3], slip_front, 1e-6), "{stand:?}");
        // Lu et al. report 7.5-8.5 MN; thicker entry pushes, thinner exit pushes harder,
        // tension relieves; back tension slows the exit, front tension speeds it.
        assert!((7.4e6..8.5e6).contains(&stand.gap.force_n));
        let [f_entry, f_exit, f_back, f_front] = stand.partials.force;
        assert!(f_entry > 0.0 && f_exit < 0.0 && f_back < 0.0 && f_front < 0.0);
        let [_, _, s_back, s_front] = stand.partials.slip;
        assert!(s_back < 0.0 && s_front > 0.0);
    }
    Ok(())
}

#[test]
fn rightmost_roots_match_the_independent_reference() -> anyhow::Result<()> {
    let mill = TandemMill::new(&schedule())?;
    for (speed, real, frequency) in REFERENCE_ROOTS {
        let root = Characteristic::new(&mill.linear_system(speed))?.rightmost()?;
        assert!((root.real_per_s - real).abs() < 1e-6, "{speed}: {root:?}");
        assert!(
            (root.frequency_hz - frequency).abs() < 1e-6,
            "{speed}: {root:?}"
        );
    }
    Ok(())
}

#[test]
fn argument_principle_counts_the_roots_newton_finds() -> anyhow::Result<()> {
    let mill = TandemMill::new(&schedule())?;
    let characteristic = Characteristic::new(&mill.linear_system(1.2))?;
    let roots = characteristic.roots_near_axis(0.0, 2.0);
    for alpha in [0.0, 0.2, 0.5] {
        let right: usize = roots
            .iter()
            .filter(|r| r.re > alpha)
            .map(|r| if r.im.abs() > 1e-9 { 2 } else { 1 })
            .sum();
        assert_eq!(
            characteristic.count_right_of(alpha),
            Some(right),
            "alpha {alpha}"
        );
    }
    assert!(characteristic.count_right_of(0.0) > Some(0));
    Ok(())
}

/// Two-mass stack with the strip's stiffness on the work roll: the undamped natural
/// frequencies from `det(K - w^2 M) = 0`, Hz.
fn stack_frequencies_hz(schedule: &PassSchedule, strip_stiffness: f64) -> [f64; 2] {
    let s = &schedule.stack;
    let (m1, m2) = (s.work_roll_mass, s.backup_roll_mass);
    let k11 = s.work_backup_stiffness + strip_stiffness;
    let k22 = s.work_backup_stiffness + s.backup_housing_stiffness;
    let k12 = s.work_backup_stiffness;
    let (a, b, c) = (m1 * m2, -(m1 * k22 + m2 * k11), k11 * k22 - k12 * k12);
    let root = (b * b - 4.0 * a * c).sqrt();
    let tau = std::f64::consts::TAU;
    [
        ((-b - root) / (2.0 * a)).sqrt() / tau,
        ((-b + root) / (2.0 * a)).sqrt() / tau,
    ]
}

#[test]
fn a_stands_modes_match_the_two_mass_closed_form() -> anyhow::Result<()> {
    // No damping and a strip too soft to couple the stands: each stand is its own
    // two-mass stack, the strip acting as a spring -2 dF/dh on the work roll (the gap
    // is twice its displacement).
    let mut schedule = schedule();
    schedule.stack.work_backup_damping = 0.0;
    schedule.stack.backup_housing_damping = 0.0;
    schedule.strip.youngs_modulus = 1e-6;
    let mill = TandemMill::new(&schedule)?;
    let characteristic = Characteristic::new(&mill.linear_system(1.0))?;
    let mut found: Vec<f64> = characteristic
        .eigenvalues()
        .iter()
        .filter(|mu| mu.im > 1.0)
        .map(|mu| mu.im / std::f64::consts::TAU)
        .collect();
    found.sort_by(f64::total_cmp);
    let mut expected: Vec<f64> = mill
        .stands()
        .iter()
        .flat_map(|stand| stack_frequencies_hz(&schedule, -2.0 * stand.partials.force[1]))
        .collect();
    expected.sort_by(f64::total_cmp);
    assert_eq!(found.len(), expected.len());
    for (f, e) in found.iter().zip(&expected) {
        assert!(close(*f, *e, 1e-6), "{found:?} vs {expected:?}");
    }
    // The note's third-octave band: one backup-roll mode per stand at 110-210 Hz.
    assert!(
        expected[..5].iter().all(|f| (110.0..210.0).contains(f)),
        "{expected:?}"
    );
    assert!(expected[5..].iter().all(|f| *f > 700.0), "{expected:?}");
    Ok(())
}

fn quiet() -> Accelerometer {
    Accelerometer {
        noise_rms: 0.0,
        ..Accelerometer::default()
    }
}

/// Growth rate of the tension deviations (all interstands, 1 s blocks, block means
/// removed) over `from_s..`: slope of the log RMS, 1/s.
fn tension_growth(record: &millgate_sim::tandem::simulate::Record, from_s: f64) -> f64 {
    let fs = record.sample_rate_hz as usize;
    let points: Vec<(f64, f64)> = (0..record.len() / fs)
        .filter(|&b| b as f64 >= from_s)
        .map(|b| {
            let energy: f64 = record
                .tension_pa
                .iter()
                .map(|t| {
                    let block = &t[b * fs..(b + 1) * fs];
                    let mean = block.iter().sum::<f64>() / fs as f64;
                    block.iter().map(|v| (v - mean).powi(2)).sum::<f64>()
                })
                .sum();
            (b as f64 + 0.5, 0.5 * energy.ln())
        })
        .collect();
    let n = points.len() as f64;
    let (mt, my) = points
        .iter()
        .fold((0.0, 0.0), |(a, b), (t, y)| (a + t / n, b + y / n));
    let (sxy, sxx) = points.iter().fold((0.0, 0.0), |(a, b), (t, y)| {
        (a + (t - mt) * (y - my), b + (t - mt).powi(2))
    });
    sxy / sxx
}

#[test]
fn frozen_speed_growth_matches_the_rightmost_root() -> anyhow::Result<()> {
    let mill = TandemMill::new(&schedule())?;
    // Above the critical speed, driven by the default noise: the rightmost root
    // dominates after ~10 s.
    let speed = 1.3;
    let root = Characteristic::new(&mill.linear_system(speed))?.rightmost()?;
    let run = RunSettings {
        ramp: SpeedRamp::constant(speed),
        excitation: Excitation::default(),
        sensor: quiet(),
        duration_s: 30.0,
        seed: 4,
        internal_rate_hz: None,
    };
    let growth = tension_growth(&simulate(&mill, &run)?, 20.0);
    println!(
        "s = {speed}: root {:.4}/s, simulated {growth:.4}/s",
        root.real_per_s
    );
    assert!(root.real_per_s > 0.5 && close(growth, root.real_per_s, 0.02));
    // The same at twice the internal rate: the integrator adds nothing measurable.
    let fine = RunSettings {
        internal_rate_hz: Some(20_000.0),
        ..run.clone()
    };
    let fine_growth = tension_growth(&simulate(&mill, &fine)?, 20.0);
    assert!(
        close(fine_growth, growth, 0.005),
        "{fine_growth} vs {growth}"
    );

    // Below it, no noise, a step of the payoff tension: the late decay.
    let speed = 0.9;
    let root = Characteristic::new(&mill.linear_system(speed))?.rightmost()?;
    let step = RunSettings {
        ramp: SpeedRamp::constant(speed),
        excitation: Excitation {
            force_noise_density: 0.0,
            eccentricity_m: [0.0; 2],
            entry_gauge_rms_m: 0.0,
            entry_gauge_bandwidth_hz: 1.0,
            tension_steps: vec![TensionStep {
                time_s: 0.0,
                entry_mpa: 5.0,
                exit_mpa: 0.0,
            }],
            noise_bursts: Vec::new(),
        },
        sensor: quiet(),
        duration_s: 60.0,
        seed: 4,
        internal_rate_hz: None,
    };
    let decay = tension_growth(&simulate(&mill, &step)?, 40.0);
    println!(
        "s = {speed}: root {:.4}/s, simulated {decay:.4}/s",
        root.real_per_s
    );
    assert!(root.real_per_s < -0.1 && close(decay, root.real_per_s, 0.05));
    Ok(())
}

#[test]
fn critical_speed_of_the_example_and_its_friction_sensitivity() -> anyhow::Result<()> {
    let nominal = mill_critical_speed(&TandemMill::new(&schedule())?)?;
    println!("{nominal:?}");
    assert!((nominal.speed - 1.098).abs() < 0.003, "{nominal:?}");
    assert!((150.0..220.0).contains(&nominal.frequency_hz));
    // Less friction, less damping: chatter at lower speed (domain note).
    let base = schedule();
    let low_friction = critical_speed(&TandemMill::new(&base.scaled(0.9, 1.0))?, 0.3, 3.0, 1e-2)?;
    let low_damping = critical_speed(&TandemMill::new(&base.scaled(1.0, 0.9))?, 0.3, 3.0, 1e-2)?;
    assert!(low_friction.speed < 0.9 * nominal.speed, "{low_friction:?}");
    assert!(low_damping.speed < 0.95 * nominal.speed, "{low_damping:?}");
    Ok(())
}

/// Every schedule in `sim/schedules/` loads, rolls stably at its own speed (the
/// critical speed factor its comment states, from the characteristic roots) and
/// chatters at a plausible third-octave frequency.
#[test]
fn every_schedule_is_stable_at_its_own_speed() -> anyhow::Result<()> {
    let dir = concat!(env!("CARGO_MANIFEST_DIR"), "/schedules");
    let mut seen = Vec::new();
    for entry in std::fs::read_dir(dir)? {
        let path = entry?.path();
        let schedule = PassSchedule::load(&path)?;
        let critical = mill_critical_speed(&TandemMill::new(&schedule)?)?;
        let name = path.file_name().and_then(|n| n.to_str()).unwrap_or("?");
        println!("{name}: {critical:?}");
        let stated = match name {
            "lu2019-5stand.toml" => 1.098,
            "heavy-5stand.toml" => 1.190,
            "tinplate-5stand.toml" => 1.084,
            other => anyhow::bail!("{other}: a schedule this test does not know"),
        };
        assert!(
            (critical.speed - stated).abs() < 0.005,
            "{name}: {critical:?}"
        );
        assert!(
            (100.0..250.0).contains(&critical.frequency_hz),
            "{name}: {critical:?}"
        );
        seen.push(name.to_owned());
    }
    assert_eq!(seen.len(), 3, "{seen:?}");
    Ok(())
}

#[test]
fn a_ramp_through_the_critical_speed_has_onset_then_developed_chatter() -> anyhow::Result<()> {
    let mill = TandemMill::new(&schedule())?;
    let critical = mill_critical_speed(&mill)?;
    let ramp = SpeedRamp {
        start: 0.9,
        end: 1.6,
        hold_s: 2.0,
        accel_m_s2: 1.5,
    };
    let run = RunSettings {
        ramp,
        excitation: Excitation::default(),
        sensor: Accelerometer::default(),
        duration_s: 20.0,
        seed: 11,
        internal_rate_hz: None,
    };
    let record = simulate(&mill, &run)?;
    let truth = ground_truth(&mill, &ramp, &record, critical);
    println!("{truth:?}");
    let onset = truth.onset_s.expect("the ramp passes the critical speed");
    let developed = truth.developed_s.expect("chatter develops");
    // 0.9 -> 1.098 at 1.5 m/s^2 on a 22.8 m/s exit: 3.0 s after the hold.
    assert!((onset - 5.0).abs() < 0.1, "{onset}");
    assert!(developed > onset + 1.0 && developed < 20.0, "{truth:?}");
    // Same seed, same record; a stable run never develops.
    assert_eq!(simulate(&mill, &run)?, record);
    let stable = RunSettings {
        ramp: SpeedRamp::constant(0.9),
        duration_s: 10.0,
        ..run
    };
    let stable_record = simulate(&mill, &stable)?;
    assert_eq!(
        ground_truth(&mill, &stable.ramp, &stable_record, critical).developed_s,
        None
    );
    Ok(())
}

#[test]
fn schedule_errors_name_the_file_the_key_and_the_range() {
    let text = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/schedules/lu2019-5stand.toml"
    ))
    .expect("example");
    let cases = [
        (
            text.replacen("entry_mm = 1.269", "entry_mm = 1.27", 1),
            "s.toml: stand[1].entry_mm: 1.27 is not allowed (must be equal to stand[0].exit_mm = 1.269 mm)",
        ),
        (
            text.replacen("friction = 0.040", "friction = 0.9", 1),
            "s.toml: stand[2].friction: 0.9 is not allowed (must be in (0, 0.5])",
        ),
        (
            text.replacen("back_tension_mpa = 205.6", "back_tension_mpa = 200.0", 1),
            "s.toml: stand[4].back_tension_mpa: 200 is not allowed (must be equal to stand[3].front_tension_mpa = 205.6 MPa)",
        ),
        (
            text.replacen("roll_speed = 9.43", "roll_speed = 12.0", 1),
            "s.toml: stand[2].roll_speed: 12 is not allowed (must be within 5% of the mass flow",
        ),
        (
            text.replacen("width = 1.25", "widht = 1.25", 1),
            "s.toml:11: strip.widht: unknown field `widht`",
        ),
        (
            text.replacen("interstand_distance = 5.0", "interstand_distance = -5.0", 1),
            "s.toml: interstand_distance: -5 is not allowed (must be > 0 m)",
        ),
        (
            text.replacen("name = ", "name == ", 1),
            "s.toml:7: malformed TOML",
        ),
    ];
    for (changed, expected) in cases {
        let error = PassSchedule::from_toml_str(&changed, "s.toml")
            .expect_err(expected)
            .to_string();
        assert!(error.starts_with(expected), "{error}\n expected {expected}");
    }
}

#[test]
fn the_built_in_example_is_the_checked_in_file() -> anyhow::Result<()> {
    let file = PassSchedule::load(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/schedules/lu2019-5stand.toml"
    ))?;
    assert_eq!(PassSchedule::example()?, file);
    assert_eq!(
        PassSchedule::from_toml_str(&file.to_toml_string()?, "again.toml")?,
        file
    );
    Ok(())
}

#[test]
fn run_settings_out_of_range_are_named() {
    let mill = TandemMill::new(&schedule()).expect("mill");
    let run = RunSettings {
        ramp: SpeedRamp::constant(1.0),
        excitation: Excitation::default(),
        sensor: Accelerometer {
            sample_rate_hz: 100.0,
            ..Accelerometer::default()
        },
        duration_s: 1.0,
        seed: 1,
        internal_rate_hz: None,
    };
    let error = simulate(&mill, &run).expect_err("100 Hz");
    assert!(matches!(
        error,
        RunError::Setting {
            key: "sensor.sample_rate_hz",
            ..
        }
    ));
    assert_eq!(
        error.to_string(),
        "sensor.sample_rate_hz: 100 is not allowed (must be 500 ..= 20000 Hz)"
    );
}

#[test]
fn a_run_advanced_in_pieces_is_the_run_advanced_at_once() -> anyhow::Result<()> {
    // A ramp through the critical speed with every excitation (a tension step and a
    // noise burst included), advanced once and in pieces of 1 to 700 samples that
    // cut across the ramp's start, the step and the burst.
    let mill = TandemMill::new(&schedule())?;
    let mut excitation = Excitation::default();
    excitation.tension_steps.push(TensionStep {
        time_s: 0.61,
        entry_mpa: 8.0,
        exit_mpa: -3.0,
    });
    excitation.noise_bursts.push(NoiseBurst {
        time_s: 1.3,
        duration_s: 0.7,
        factor: 4.0,
        stand: None,
    });
    let ramp = SpeedRamp {
        start: 1.0,
        end: 1.3,
        hold_s: 0.8,
        accel_m_s2: 2.0,
    };
    let run = RunSettings {
        ramp,
        excitation,
        sensor: Accelerometer::default(),
        duration_s: 3.0,
        seed: 12,
        internal_rate_hz: None,
    };
    let once = simulate(&mill, &run)?;
    let mut simulation = Simulation::new(&mill, &run.setup())?;
    let exit_speed = mill.exit_speed(mill.stands().len() - 1, 1.0);
    let mut pieces = simulation.record(once.len());
    let sizes = [1, 2, 700, 119, 3, 120, 611, 1];
    let mut k = 0;
    while pieces.len() < once.len() {
        let size = sizes[k % sizes.len()].min(once.len() - pieces.len());
        simulation.advance(size, |t| ramp.speed_at(t, exit_speed), &mut pieces)?;
        k += 1;
        assert_eq!(simulation.samples(), pieces.len());
    }
    assert_eq!(simulation.time_s(), 3.0);
    // Sample by sample, not to a tolerance: the same arithmetic in the same order.
    assert_eq!(pieces, once);
    // The burst is in the record: the stands shake harder during it.
    let rms = |from_s: f64, to_s: f64| {
        let range = (from_s * 2500.0) as usize..(to_s * 2500.0) as usize;
        let values = &once.acceleration[0][range];
        (values.iter().map(|v| v * v).sum::<f64>() / values.len() as f64).sqrt()
    };
    assert!(
        rms(1.4, 2.0) > 2.0 * rms(0.7, 1.3),
        "{} {}",
        rms(1.4, 2.0),
        rms(0.7, 1.3)
    );
    Ok(())
}

#[test]
fn a_speed_outside_the_simulations_range_is_refused() -> anyhow::Result<()> {
    let mill = TandemMill::new(&schedule())?;
    let run = RunSettings {
        ramp: SpeedRamp::constant(0.9),
        excitation: Excitation::default(),
        sensor: Accelerometer::default(),
        duration_s: 1.0,
        seed: 1,
        internal_rate_hz: None,
    };
    let mut simulation = Simulation::new(&mill, &run.setup())?;
    let mut record = simulation.record(10);
    simulation.advance(10, |_| 0.9, &mut record)?;
    let error = simulation
        .advance(10, |_| 0.95, &mut record)
        .expect_err("above the range");
    assert_eq!(
        error.to_string(),
        "speed factor 0.95 at t = 0.004 s is outside the simulation's speed range 0.9 ..= 0.9"
    );
    Ok(())
}

#[test]
fn the_online_mill_is_the_simulated_ramp_when_nothing_requests_a_slow_down() -> anyhow::Result<()> {
    // The automation ramps from 90% of the critical speed at 2 m/s^2 to 1.3 times it,
    // one 48 ms PLC cycle at a time and never asked to slow down: the same run as the
    // ramp simulated at once (to rounding: the speed passes through m/s), chatter
    // developing at the same sample.
    let mill = TandemMill::new(&schedule())?;
    let critical = mill_critical_speed(&mill)?.speed;
    let unit = mill.exit_speed(mill.stands().len() - 1, 1.0);
    let ramp = SpeedRamp {
        start: 0.9 * critical,
        end: 1.3 * critical,
        hold_s: 0.0,
        accel_m_s2: 2.0,
    };
    let run = RunSettings {
        ramp,
        excitation: Excitation::default(),
        sensor: Accelerometer::default(),
        duration_s: 12.0,
        seed: 5,
        internal_rate_hz: None,
    };
    let once = simulate(&mill, &run)?;
    let policy = SlowDownPolicy {
        accel_m_s2: 2.0,
        ..SlowDownPolicy::default()
    };
    let control = SpeedControl::new(policy, ramp.start * unit, ramp.end * unit)?;
    let mut online = OnlineMill::new(&mill, &run.setup(), control, 120, ramp.end * unit)?;
    let mut record = online.record(once.len());
    let mut largest_swing = 0.0_f64;
    while record.len() < once.len() {
        let truth = online.cycle(false, &mut record)?;
        largest_swing = largest_swing.max(truth.swing);
    }
    assert_eq!(online.time_s(), 12.0);
    for (online, once) in record.acceleration.iter().zip(&once.acceleration) {
        for (a, b) in online.iter().zip(once) {
            assert!((a - b).abs() <= 1e-9 * (1.0 + b.abs()), "{a} vs {b}");
        }
    }
    let developed = developed_time(&mill, &once).expect("chatter develops");
    let online_developed = online.developed_s().expect("developed online");
    assert!(
        (online_developed - developed).abs() < 1e-9,
        "{online_developed} vs {developed}"
    );
    assert!(largest_swing > 1.0);
    assert!(online.control().events().is_empty());
    Ok(())
}
