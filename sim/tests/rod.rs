//! Rod-mill checks: the paper's rod frequencies from the documented geometry, growth
//! rates against a direct integration of the rod's modal equation in physical time,
//! speed bands against point-by-point evaluation, the sources of each span, the moving
//! rod, and errors that name the file, key and allowed range.

use std::f64::consts::PI;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use millgate_sim::rod::beam::{Beam, Ends};
use millgate_sim::rod::check::{check_schedule, PassSetup, Source};
use millgate_sim::rod::mill::RodMill;
use millgate_sim::rod::schedule::{self, Pass};

fn rod_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("models/rod")
}

fn mill() -> Arc<RodMill> {
    Arc::new(RodMill::load(rod_dir().join("rsm-mill.toml")).expect("example mill"))
}

fn mill_from(text: &str) -> Result<Arc<RodMill>, String> {
    RodMill::from_toml_str(text, "mill.toml", &rod_dir())
        .map(Arc::new)
        .map_err(|e| e.to_string())
}

const MILL: &str = include_str!("../models/rod/rsm-mill.toml");

fn pass(configuration: &str, speed: f64, temperature: f64, diameters_mm: [f64; 4]) -> Pass {
    Pass {
        name: "test".into(),
        configuration: configuration.into(),
        temperature_c: temperature,
        diameters_m: diameters_mm.iter().map(|d| d / 1e3).collect(),
        finishing_speed_m_s: Some(speed),
        stand_speeds_m_s: None,
        origin: "test pass".into(),
    }
}

/// The notes' geometry: pinned spans 16 mm x 1.20 m, 13.5 mm x 1.12 m, 10.5 mm x 0.57 m.
const GEOMETRY: [(f64, f64); 3] = [(0.016, 1.20), (0.0135, 1.12), (0.0105, 0.57)];

#[test]
fn documented_geometry_reproduces_the_papers_rod_frequencies() {
    // Domain notes: 19.3-13.6, 18.7-13.2, 56.0-39.6 Hz for E 150 -> 75 GPa; the paper
    // prints 19.5-13.8, 18.9-13.4, 55.4-39.2 Hz.
    let notes = [(19.3, 13.6), (18.7, 13.2), (56.0, 39.6)];
    let paper = [(19.5, 13.8), (18.9, 13.4), (55.4, 39.2)];
    for (index, &(diameter_m, length_m)) in GEOMETRY.iter().enumerate() {
        let at = |modulus_pa: f64| {
            Beam {
                length_m,
                diameter_m,
                density_kg_m3: 7700.0,
                modulus_pa,
                tension_n: 0.0,
                ends: Ends::Pinned,
            }
            .frequency_hz(1, 0.0)
        };
        let (hot, cold) = (at(75e9), at(150e9));
        assert!((cold - notes[index].0).abs() < 0.05, "span {index}: {cold}");
        assert!((hot - notes[index].1).abs() < 0.05, "span {index}: {hot}");
        assert!(
            (cold / paper[index].0 - 1.0).abs() < 0.02,
            "span {index}: {cold}"
        );
        assert!(
            (hot / paper[index].1 - 1.0).abs() < 0.02,
            "span {index}: {hot}"
        );
        // The sqrt(2) ratio of the paper's ranges is the 2:1 modulus range.
        assert!((cold / hot - 2.0_f64.sqrt()).abs() < 1e-12);
    }
    // The same through the mill file: its modulus table spans 150 GPa (700 deg C) to
    // 75 GPa (1200 deg C).
    let mill = mill();
    for (temperature, column) in [(700.0, 0), (1200.0, 1)] {
        let setup = PassSetup::new(
            &mill,
            &pass("table3", 80.0, temperature, [16.0, 13.5, 10.5, 9.0]),
        )
        .unwrap();
        let report = setup.evaluate(80.0).unwrap();
        for (span, expected) in report.spans.iter().zip(notes) {
            let f = span.points.iter().find(|p| p.mode == 1).unwrap().f_rod_hz;
            let expected = if column == 0 { expected.0 } else { expected.1 };
            assert!(
                (f - expected).abs() < 0.05,
                "{}: {f} vs {expected}",
                span.span
            );
        }
    }
}

/// Floquet exponent (1/s) of `y'' + 2 zeta w y' + (w^2 + h cos(theta t)) y = 0` by RK4
/// over one period of the coefficient in physical time (20000 steps): the rod mode's
/// own equation, without the Mathieu substitution.
fn direct_rate(omega: f64, zeta: f64, h: f64, theta: f64) -> f64 {
    let period = 2.0 * PI / theta;
    let steps = 20_000;
    let dt = period / steps as f64;
    let rhs = |t: f64, y: [f64; 2]| -> [f64; 2] {
        [
            y[1],
            -2.0 * zeta * omega * y[1] - (omega * omega + h * (theta * t).cos()) * y[0],
        ]
    };
    let mut columns = [[1.0, 0.0], [0.0, 1.0]];
    for column in &mut columns {
        let mut y = *column;
        for k in 0..steps {
            let t = k as f64 * dt;
            let k1 = rhs(t, y);
            let k2 = rhs(
                t + dt / 2.0,
                [y[0] + dt / 2.0 * k1[0], y[1] + dt / 2.0 * k1[1]],
            );
            let k3 = rhs(
                t + dt / 2.0,
                [y[0] + dt / 2.0 * k2[0], y[1] + dt / 2.0 * k2[1]],
            );
            let k4 = rhs(t + dt, [y[0] + dt * k3[0], y[1] + dt * k3[1]]);
            for i in 0..2 {
                y[i] += dt / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]);
            }
        }
        *column = y;
    }
    // Multipliers of [[y1, y2], [y1', y2']].
    let trace = columns[0][0] + columns[1][1];
    let det = columns[0][0] * columns[1][1] - columns[1][0] * columns[0][1];
    let disc = trace * trace - 4.0 * det;
    let largest = if disc >= 0.0 {
        (trace.abs() + disc.sqrt()) / 2.0
    } else {
        det.sqrt()
    };
    largest.ln() / period
}

#[test]
fn growth_rates_match_a_direct_integration_of_the_rod_mode() {
    // Pass P3 of the example: span 1-2 is pumped by the 31.8 Hz torsional mode at about
    // twice its 16.0 Hz, span 3-4 by stand 3's eccentricity; other points are stable.
    let mill = mill();
    let passes = schedule::load(rod_dir().join("rsm-schedule.csv")).unwrap();
    let p3 = passes.iter().find(|p| p.name == "P3").unwrap();
    let setup = PassSetup::new(&mill, p3).unwrap();
    let report = setup.evaluate(setup.finishing_speed_m_s).unwrap();
    let zeta = mill.rod.damping_ratio;
    let (mut unstable, mut checked) = (0, 0);
    for (span_setup, span) in setup.spans.iter().zip(&report.spans) {
        for (source, point) in span_setup.sources.iter().zip(&span.points) {
            if point.mode != 1 {
                continue;
            }
            let beam = &span_setup.beam;
            let k = PI / beam.length_m;
            let omega = 2.0 * PI * beam.frequency_hz(1, 0.0);
            let theta = 2.0 * PI * point.theta_hz;
            let h = k * k * source.pulsation_n / beam.mass_per_length();
            // q is the notes' 2 k^2 P / (rho A Theta^2).
            assert!((point.q / (2.0 * h / (theta * theta)) - 1.0).abs() < 1e-12);
            let rate = direct_rate(omega, zeta, h, theta);
            let exponent = point.exponent_per_s.unwrap();
            assert!(
                (rate - exponent).abs() < 1e-6 * (1.0 + exponent.abs()),
                "{} / {}: direct {rate} vs {exponent}",
                span.span,
                point.source
            );
            assert_eq!(point.stable, rate <= 1e-9);
            unstable += usize::from(!point.stable);
            checked += 1;
        }
    }
    assert_eq!(unstable, 2, "P3 has two unstable first-mode points");
    assert!(checked > 15);
}

#[test]
fn speed_bands_agree_with_the_points_and_speed_changes_reach_an_edge() {
    let mill = mill();
    let passes = schedule::load(rod_dir().join("rsm-schedule.csv")).unwrap();
    for pass in &passes[..3] {
        let setup = PassSetup::new(&mill, pass).unwrap();
        let (lo, hi) = setup.speed_range_m_s;
        // Each point's edge is probed once, at the first speed that reports one.
        let mut probed = std::collections::HashSet::new();
        for k in 0..40 {
            let v = lo + (hi - lo) * (k as f64 + 0.37) / 40.0;
            let report = setup.evaluate(v).unwrap();
            for (s, span) in setup.spans.iter().enumerate() {
                for (k, source) in span.sources.iter().enumerate() {
                    let point = &report.spans[s].points[k];
                    let in_band = source.bands.iter().any(|&(from, to)| from <= v && v <= to);
                    assert_eq!(
                        !point.stable, in_band,
                        "{} at {v}: {}",
                        pass.name, point.source
                    );
                    let Some(change) = point.speed_change_m_s else {
                        continue;
                    };
                    if !probed.insert((s, k)) {
                        continue;
                    }
                    // Just past the edge the stability differs from just before it.
                    let edge = v + change;
                    let step = 1e-6 * hi;
                    let side =
                        |speed: f64| setup.evaluate(speed).unwrap().spans[s].points[k].stable;
                    let toward = change.signum();
                    let label = format!(
                        "{} at {v}: {} / {}",
                        pass.name, report.spans[s].span, point.source
                    );
                    assert_eq!(side(edge - toward * step), point.stable, "{label}");
                    assert_ne!(side(edge + toward * step), point.stable, "{label}");
                }
            }
        }
        // The pass's avoid bands cover every source band that a speed change can leave.
        for source in setup.spans.iter().flat_map(|s| s.sources.iter()) {
            for &(from, to) in &source.bands {
                if (from, to) == setup.speed_range_m_s {
                    continue;
                }
                assert!(setup
                    .avoid
                    .iter()
                    .any(|b| b.from_m_s <= from && to <= b.to_m_s));
            }
        }
    }
}

#[test]
fn each_span_is_pumped_by_the_modes_that_twist_its_stands_differently() {
    let mill = mill();
    let setup =
        PassSetup::new(&mill, &pass("table3", 80.0, 950.0, [16.0, 13.5, 10.5, 9.0])).unwrap();
    let torsion = |span: usize| -> Vec<(f64, f64)> {
        setup.spans[span]
            .sources
            .iter()
            .filter(|s| s.mode == 1)
            .filter_map(|s| match s.source {
                Source::Torsion {
                    frequency_hz,
                    participation,
                } => Some((frequency_hz, participation)),
                Source::Eccentricity { .. } => None,
            })
            .collect()
    };
    // Spans 1-2 and 3-4: only their own branch mode, stands fully against each other.
    let first = torsion(0);
    assert_eq!(first.len(), 1);
    assert!((first[0].0 - 31.8).abs() < 0.05 && (first[0].1 - 1.0).abs() < 0.01);
    let last = torsion(2);
    assert_eq!(last.len(), 1);
    assert!((last[0].0 - 25.2).abs() < 0.05 && (last[0].1 - 1.0).abs() < 0.01);
    // Span 2-3: 22.7 Hz strongest (stands 2 and 3 in opposite phase), then the branch
    // modes (one stand still), 62.8 and 20.1 Hz.
    let middle = torsion(1);
    let strongest = middle
        .iter()
        .fold((0.0, 0.0), |best, &m| if m.1 > best.1 { m } else { best });
    assert!((strongest.0 - 22.7).abs() < 0.05, "{middle:?}");
    for frequency in [20.1, 25.2, 31.8, 62.8] {
        assert!(
            middle.iter().any(|m| (m.0 - frequency).abs() < 0.05),
            "{frequency}: {middle:?}"
        );
    }
    // Every span has the eccentricity of its two stands at 1x and 2x, per mode.
    let eccentric = setup.spans[1]
        .sources
        .iter()
        .filter(|s| matches!(s.source, Source::Eccentricity { .. }))
        .count();
    assert_eq!(eccentric, 4 * mill.rod.modes);
}

#[test]
fn the_moving_rod_lowers_the_frequency_to_zero_at_the_critical_speed() {
    let moving = MILL.replace("epsilon = 0.1", "epsilon = 0.1\nmoving_rod = true");
    assert_ne!(moving, MILL);
    let mill = mill_from(&moving).unwrap();
    let still = self::mill();
    let pass = pass("table3", 60.0, 950.0, [16.0, 13.5, 10.5, 9.0]);
    let moving_report = PassSetup::new(&mill, &pass)
        .unwrap()
        .evaluate(60.0)
        .unwrap();
    let still_report = PassSetup::new(&still, &pass)
        .unwrap()
        .evaluate(60.0)
        .unwrap();
    for (a, b) in moving_report.spans.iter().zip(&still_report.spans) {
        // Pinned, T0 = 0: f = f0 sqrt(1 - (V / V_crit)^2), V_crit = 2 L f0.
        let f0 = b.points.iter().find(|p| p.mode == 1).unwrap().f_rod_hz;
        let f = a.points.iter().find(|p| p.mode == 1).unwrap().f_rod_hz;
        let ratio = a.v_over_v_crit;
        assert_eq!(ratio, b.v_over_v_crit, "reported with or without the term");
        let expected = f0 * (1.0 - ratio * ratio).max(0.0).sqrt();
        assert!(
            (f - expected).abs() < 1e-9 * f0,
            "{}: {f} vs {expected}",
            a.span
        );
    }
}

#[test]
fn the_schedule_check_reports_every_pass_and_configuration() {
    let mill = mill();
    let passes = schedule::load(rod_dir().join("rsm-schedule.csv")).unwrap();
    let report = check_schedule(&mill, &passes).unwrap();
    assert_eq!(report.passes.len(), 4);
    assert_eq!(report.configurations.len(), 2);
    assert_eq!(report.configurations[0].passes.len(), 2);
    // P3 (fast) cannot be rolled stably at any speed: span 1-2's first mode sits in the
    // principal tongue of the 31.8 Hz drive mode.
    let p3 = &report.configurations[1].passes[0];
    assert_eq!(p3.pass, "P3");
    assert_eq!(p3.unstable_at_every_speed.len(), 1);
    assert!(p3.unstable_at_every_speed[0].contains("torsion 31.8 Hz"));
    let text = millgate_sim::rod::report::text(&report);
    assert!(text.contains("Pass P3 (configuration fast)") && text.contains("UNSTABLE"));
    let json = serde_json::to_value(&report).unwrap();
    assert_eq!(json["passes"][0]["spans"][0]["points"][0]["mode"], 1);
}

#[test]
fn bad_passes_name_the_field_and_the_allowed_range() {
    let mill = mill();
    let error = |pass: Pass| PassSetup::new(&mill, &pass).unwrap_err().to_string();
    assert_eq!(
        error(pass("slow", 60.0, 950.0, [16.0, 13.5, 10.5, 9.0])),
        "test pass: configuration: \"slow\" is not allowed (must be a configuration of the \
         drive (known: \"table3\", \"fast\"))"
    );
    assert!(error(pass("table3", 60.0, 1300.0, [16.0, 13.5, 10.5, 9.0]))
        .contains("temperature_c: 1300 is not allowed (must be within the modulus table, 700 ..= 1200 deg C)"));
    assert!(error(pass("table3", 0.0, 950.0, [16.0, 13.5, 10.5, 9.0]))
        .contains("finishing_speed_m_s: 0 is not allowed (must be > 0 m/s"));
    assert!(error(pass("table3", 120.0, 950.0, [16.0, 13.5, 10.5, 9.0]))
        .contains("within configuration \"table3\"'s range 31.5 ..= 94.5 m/s"));
    assert!(error(pass("table3", 60.0, 950.0, [16.0, -13.5, 10.5, 9.0]))
        .contains("diameters_mm: -13.5"));
}

#[test]
fn bad_mill_files_name_the_key_and_the_allowed_range() {
    let cases = [
        ("roll_diameter = 0.228", "roll_diameter = -0.2", "mill.toml: stand[0].roll_diameter: -0.2 is not allowed (must be > 0 m)"),
        ("to = \"stand 3\"", "to = \"stand 4\"", "mill.toml: span[1].to: \"stand 4\" is not allowed (must be the stand after \"stand 2\" in rolling order (\"stand 3\"))"),
        ("modes = 2", "modes = 11", "mill.toml: rod.modes: 11 is not allowed (must be 1 ..= 10)"),
        ("epsilon = 0.1", "epsilon = 0.8", "mill.toml: rod.epsilon: 0.8 is not allowed (must be > 0 and <= 0.5 (P / (P_E + T0)))"),
        ("temperature_c = 900.0", "temperature_c = 600.0", "mill.toml: rod.modulus[1].temperature_c: 600 is not allowed (must be finite and above the previous point's (deg C, increasing))"),
    ];
    for (from, to, expected) in cases {
        let text = MILL.replacen(from, to, 1);
        assert_ne!(text, MILL, "{from}");
        assert_eq!(mill_from(&text).unwrap_err(), expected);
    }
    let text = MILL.replacen(
        "name = \"stand 1\"",
        "name = \"stand 1\"\nmass = \"stand 9\"",
        1,
    );
    let message = mill_from(&text).unwrap_err();
    assert!(message.starts_with("mill.toml: stand[0].mass: \"stand 9\" is not allowed (must be a mass of the drive (known: \"drive\""), "{message}");
    // The drive file's own errors name the drive file.
    let message = mill_from(&MILL.replace("../rsm-drive.toml", "../missing.toml")).unwrap_err();
    assert!(message.contains("missing.toml: cannot read"), "{message}");
}

#[test]
fn span_status_agrees_with_the_full_evaluation() {
    let mill = mill();
    let passes = schedule::load(rod_dir().join("rsm-schedule.csv")).unwrap();
    for pass in &passes {
        let setup = PassSetup::new(&mill, pass).unwrap();
        let (lo, hi) = setup.speed_range_m_s;
        for k in 0..7 {
            let v = lo + (hi - lo) * (k as f64 + 0.5) / 7.0;
            let status = setup.status(v).unwrap();
            let report = setup.evaluate(v).unwrap();
            for (s, span) in status.iter().zip(&report.spans) {
                assert_eq!(s.span, span.span);
                assert_eq!(s.stable, span.stable);
                let worst = span
                    .points
                    .iter()
                    .filter_map(|p| p.exponent_per_s)
                    .fold(f64::NEG_INFINITY, f64::max);
                assert_eq!(s.worst_exponent_per_s, Some(worst));
                let changes: Vec<f64> = span
                    .points
                    .iter()
                    .filter(|p| p.stable)
                    .filter_map(|p| p.speed_change_m_s.map(f64::abs))
                    .collect();
                match s.speed_margin_m_s {
                    Some(margin) if s.stable => {
                        assert_eq!(
                            margin,
                            changes.iter().copied().fold(f64::INFINITY, f64::min)
                        )
                    }
                    Some(margin) => assert!(margin < 0.0),
                    None => assert!(!s.stable || changes.is_empty()),
                }
            }
        }
    }
}
