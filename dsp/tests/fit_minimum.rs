//! The eq. (1) fit on simulated bites of the Table 2 driveline where its first start
//! ended in a poor local minimum (docs/measured.md, "What a burst of bites costs"):
//! at 150 kN*m without a gap f1 came out 2.17 Hz, at 80 kN*m with a 3 mrad gap
//! 1.25 Hz, where the driveline's first mode is near 12 Hz; and where it stopped short
//! of the minimum (docs/measured.md, "The fit's residual curvature"): at 80 kN*m
//! without a gap at its iteration limit, at 112 kN*m without a gap at f1 = 8.15 Hz,
//! 3.3 Hz from it.
//!
//! The records are `millgate sim transient` output (`fit_minimum/make.sh` says how
//! they were made); the bite is found and cut as `millgate analyze` does (its detector
//! settings, the fit from the load onset, the baseline taken off), and the expected
//! frequencies come from the model's inertias and stiffnesses by eq. (2), not from the
//! fit.

use millgate_dsp::bite::{BiteDetector, BiteSettings};
use millgate_dsp::fit::{fit_eq1, Eq1Fit, FitOptions, FitStatus};
use millgate_dsp::stiffness::{forward, Inertias, NaturalFrequencies, Stiffness};

const FS: f64 = 2000.0;

/// `config/examples/table2-adjusted.toml`'s natural frequencies (backlash ignored).
fn model_modes() -> NaturalFrequencies {
    let inertias = Inertias {
        q1_kgm2: 46.70e3,
        q2_kgm2: 11.85e3,
        q3_kgm2: 2.48e3,
    };
    let stiffness = Stiffness {
        c12_nm_per_rad: 68.77e6,
        c23_nm_per_rad: 32.81e6,
    };
    forward(&inertias, &stiffness).unwrap()
}

/// The torque column of a `t,torque` CSV.
fn torque(csv: &str) -> Vec<f64> {
    csv.lines()
        .skip(1)
        .map(|line| line.split(',').nth(1).unwrap().parse().unwrap())
        .collect()
}

/// The fit of the one bite in `samples` with the default options, cut as `millgate
/// analyze` cuts it ([`fit_bite_with`]).
fn fit_bite(samples: &[f64]) -> Eq1Fit {
    fit_bite_with(samples, &FitOptions::new(FS))
}

/// The fit of the one bite in `samples` with `options`, cut as `millgate analyze` cuts it: its
/// detector (a rise of 20 kN*m above a 0.5 s baseline, 0.6 s after the trigger), the
/// record from the last sample within 2 kN*m of the baseline, the baseline taken off.
fn fit_bite_with(samples: &[f64], options: &FitOptions) -> Eq1Fit {
    let detector = BiteDetector::<256, 2048>::new(BiteSettings {
        threshold_knm: 20.0,
        rearm_knm: 10.0,
        holdoff_samples: (0.5 * FS) as u32,
        baseline_alpha: 1.0 / (0.5 * FS),
        saturation_low_knm: f64::NEG_INFINITY,
        saturation_high_knm: f64::INFINITY,
        post_trigger_samples: (0.6 * FS) as usize,
    })
    .unwrap();
    let mut state = detector.state();
    let mut events = Vec::new();
    detector.block(&mut state, samples, |event| events.push(event));
    events.extend(detector.gap(&mut state, 0));
    assert_eq!(events.len(), 1, "one bite in the record");
    let event = &events[0];
    let window = &event.window;
    let onset = window[..=event.trigger_index]
        .iter()
        .rposition(|&x| x - event.baseline_knm <= 2.0)
        .unwrap_or(0);
    let record: Vec<f64> = window[onset..]
        .iter()
        .map(|&x| x - event.baseline_knm)
        .collect();
    fit_eq1(&record, options).unwrap()
}

/// The fit converged (or stalled at its tolerance) with f2 within 5% of the model's
/// second mode (the gap leaves it where it is).
fn converged_with_the_second_mode(fit: &Eq1Fit, modes: &NaturalFrequencies) {
    assert!(
        matches!(fit.status, FitStatus::Converged | FitStatus::Stalled),
        "{fit:?}"
    );
    assert!(
        (fit.f2_hz / modes.beta2_hz - 1.0).abs() < 0.05,
        "f2 {} Hz against the model's {} Hz",
        fit.f2_hz,
        modes.beta2_hz
    );
}

/// 150 kN*m, no gap: the first start's coarse pass took mode 1 through 0 Hz (f1 came
/// out 2.17 Hz, inside the band a 0.6 s record resolves, so the gateway published it).
#[test]
fn no_gap_fit_finds_the_first_mode() {
    let fit = fit_bite(&torque(include_str!("fit_minimum/static150-gap0mrad.csv")));
    let modes = model_modes();
    converged_with_the_second_mode(&fit, &modes);
    assert!(
        (fit.f1_hz / modes.beta1_hz - 1.0).abs() < 0.05,
        "f1 {} Hz against the model's {} Hz",
        fit.f1_hz,
        modes.beta1_hz
    );
}

/// 80 kN*m with a 3 mrad gap in the spindles: the gap lowers the first mode below the
/// linear model's frequency (the other 3 mrad fits gave 8.8-10.7 Hz), and the first
/// start ended at 1.25 Hz, a growing exponential in place of the mode.
#[test]
fn gap_fit_finds_a_softened_first_mode_not_a_slow_exponential() {
    let fit = fit_bite(&torque(include_str!("fit_minimum/static80-gap3mrad.csv")));
    let modes = model_modes();
    converged_with_the_second_mode(&fit, &modes);
    assert!(
        fit.f1_hz > 0.75 * modes.beta1_hz && fit.f1_hz < 1.02 * modes.beta1_hz,
        "f1 {} Hz against the model's {} Hz",
        fit.f1_hz,
        modes.beta1_hz
    );
    assert!(fit.decay1_per_s > 0.0, "{fit:?}");
}

/// The records of this suite (name, CSV) and, with `MILLGATE_FIT_RECORDS` naming a
/// folder, its `*.csv` too (`fit_minimum/make.sh` makes more with other cases).
fn records() -> Vec<(String, String)> {
    let mut records: Vec<(String, String)> = [
        (
            "static150-gap0mrad",
            include_str!("fit_minimum/static150-gap0mrad.csv"),
        ),
        (
            "static80-gap3mrad",
            include_str!("fit_minimum/static80-gap3mrad.csv"),
        ),
        (
            "static80-gap0mrad",
            include_str!("fit_minimum/static80-gap0mrad.csv"),
        ),
        (
            "static112-gap0mrad",
            include_str!("fit_minimum/static112-gap0mrad.csv"),
        ),
    ]
    .into_iter()
    .map(|(name, csv)| (name.to_string(), csv.to_string()))
    .collect();
    if let Ok(folder) = std::env::var("MILLGATE_FIT_RECORDS") {
        let mut paths: Vec<_> = std::fs::read_dir(&folder)
            .unwrap_or_else(|error| panic!("MILLGATE_FIT_RECORDS {folder}: {error}"))
            .map(|entry| entry.unwrap().path())
            .filter(|path| path.extension().is_some_and(|e| e == "csv"))
            .collect();
        paths.sort();
        for path in paths {
            let name = path.file_stem().unwrap().to_string_lossy().into_owned();
            records.push((name, std::fs::read_to_string(&path).unwrap()));
        }
    }
    records
}

/// The fit ends at the minimum of its cost: against the same fit run to a tolerance of
/// 1e-12 and up to 5 000 iterations (which reaches it, however slowly), f1 within
/// 0.01 Hz and f2 within 0.002 Hz, the residual no larger. Without the secant term the
/// 80 kN*m bite without a gap stopped at the iteration limit (withheld) and the 112
/// kN*m one at f1 = 8.15 Hz (rms 2.645 kN*m against the minimum's 2.561 at 11.47 Hz).
/// Prints the table of docs/measured.md (`-- --nocapture`).
#[test]
fn the_fit_ends_at_its_minimum() {
    let reference_options = FitOptions {
        tolerance: 1e-12,
        max_iterations: 5_000,
        ..FitOptions::new(FS)
    };
    println!("record | f1 Hz (minimum) | f2 Hz (minimum) | rms kN*m (minimum) | iterations (to the minimum)");
    for (name, csv) in records() {
        let samples = torque(&csv);
        let fit = fit_bite(&samples);
        let minimum = fit_bite_with(&samples, &reference_options);
        println!(
            "{name} | {:.4} ({:.4}) | {:.4} ({:.4}) | {:.4} ({:.4}) | {} ({})",
            fit.f1_hz,
            minimum.f1_hz,
            fit.f2_hz,
            minimum.f2_hz,
            fit.rms_residual,
            minimum.rms_residual,
            fit.iterations,
            minimum.iterations
        );
        assert!(
            matches!(minimum.status, FitStatus::Converged),
            "{name}: the reference did not converge: {minimum:?}"
        );
        assert!(
            matches!(fit.status, FitStatus::Converged | FitStatus::Stalled)
                && (fit.f1_hz - minimum.f1_hz).abs() <= 0.01
                && (fit.f2_hz - minimum.f2_hz).abs() <= 0.002
                && fit.rms_residual <= minimum.rms_residual * (1.0 + 1e-4),
            "{name}: {fit:?} against the minimum {minimum:?}"
        );
    }
}
