//! Plain-text rendering of a schedule check (the JSON form is the reports' serde
//! serialisation).

use std::fmt::Write as _;

use super::check::{AvoidBand, PassReport, PointReport, ScheduleReport};

fn optional(value: Option<f64>, precision: usize) -> String {
    value.map_or_else(|| "-".to_owned(), |v| format!("{v:.precision$}"))
}

fn bands(bands: &[AvoidBand]) -> String {
    if bands.is_empty() {
        return "none".to_owned();
    }
    bands
        .iter()
        .map(|b| format!("{:.1}-{:.1}", b.from_m_s, b.to_m_s))
        .collect::<Vec<_>>()
        .join(", ")
}

fn point_row(point: &PointReport) -> String {
    let tongue = match (point.tongue, point.inside) {
        (Some(order), Some(true)) => format!("{order} in"),
        (Some(order), _) => format!("{order} out"),
        _ => "-".to_owned(),
    };
    format!(
        "    {:>4}  {:<28} {:>8.2} {:>8.2} {:>9.3} {:>8.4} {:>6.3} {:>7} {:>9} {:>6} {:>9} {:>8}",
        point.mode,
        point.source,
        point.f_rod_hz,
        point.theta_hz,
        point.a,
        point.q,
        point.c,
        tongue,
        optional(point.exponent_per_s, 3),
        if point.stable { "yes" } else { "NO" },
        optional(point.margin_a, 3),
        optional(point.speed_change_m_s, 2),
    )
}

fn pass_text(text: &mut String, pass: &PassReport) {
    let worst = optional(pass.worst_exponent_per_s, 3);
    let _ = writeln!(
        text,
        "Pass {} (configuration {}): finishing {:.1} m/s (range {:.1}-{:.1}), {} deg C, \
         E {:.1} GPa: {}, worst exponent {worst} 1/s",
        pass.pass,
        pass.configuration,
        pass.finishing_speed_m_s,
        pass.speed_range_m_s.0,
        pass.speed_range_m_s.1,
        pass.temperature_c,
        pass.modulus_pa * 1e-9,
        if pass.stable { "stable" } else { "UNSTABLE" },
    );
    for span in &pass.spans {
        let _ = writeln!(
            text,
            "  span {}: d {:.1} mm, rod {:.1} m/s, V/V_crit {:.2}, Euler load {:.0} N",
            span.span, span.diameter_mm, span.rod_speed_m_s, span.v_over_v_crit, span.euler_load_n
        );
        let _ = writeln!(
            text,
            "    {:>4}  {:<28} {:>8} {:>8} {:>9} {:>8} {:>6} {:>7} {:>9} {:>6} {:>9} {:>8}",
            "mode",
            "source",
            "f_rod Hz",
            "Theta Hz",
            "a",
            "q",
            "c",
            "tongue",
            "exp 1/s",
            "stable",
            "margin a",
            "dV m/s"
        );
        for point in &span.points {
            let _ = writeln!(text, "{}", point_row(point));
        }
    }
    let _ = writeln!(
        text,
        "  finishing speeds to avoid, m/s: {}",
        bands(&pass.avoid)
    );
    for band in &pass.avoid {
        let _ = writeln!(
            text,
            "    {:.1}-{:.1}: {}",
            band.from_m_s,
            band.to_m_s,
            band.sources.join("; ")
        );
    }
    if !pass.unstable_at_every_speed.is_empty() {
        let _ = writeln!(
            text,
            "  unstable at every speed of the range: {}",
            pass.unstable_at_every_speed.join("; ")
        );
    }
    text.push('\n');
}

/// The report as text: every pass with a table of its points, then the finishing
/// speeds to avoid per configuration.
pub fn text(report: &ScheduleReport) -> String {
    let mut text = format!("{}\n\n", report.mill);
    for pass in &report.passes {
        pass_text(&mut text, pass);
    }
    let _ = writeln!(text, "Finishing speeds to avoid, by configuration");
    for configuration in &report.configurations {
        let modes: Vec<String> = configuration
            .torsional_hz
            .iter()
            .map(|f| format!("{f:.1}"))
            .collect();
        let _ = writeln!(
            text,
            "  {} (gearbox range {:.1}-{:.1} m/s; drive modes {} Hz)",
            configuration.name,
            configuration.speed_range_m_s.0,
            configuration.speed_range_m_s.1,
            modes.join(", ")
        );
        if configuration.passes.is_empty() {
            let _ = writeln!(text, "    no pass of the schedule uses it");
        }
        for pass in &configuration.passes {
            let every = if pass.unstable_at_every_speed.is_empty() {
                String::new()
            } else {
                format!(
                    "; unstable at every speed ({} points)",
                    pass.unstable_at_every_speed.len()
                )
            };
            let _ = writeln!(text, "    {}: {}{every}", pass.pass, bands(&pass.avoid));
        }
    }
    text
}
