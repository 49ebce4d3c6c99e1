//! The report folder of the workflow: the extended model as a model TOML, a plot of
//! record, calibrated linear and extended model with the residuals below, and a short
//! Markdown summary.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use plotters::prelude::*;

use super::Report;

/// Files written by [`write()`].
pub const MODEL_FILE: &str = "extended-model.toml";
/// The plot.
pub const PLOT_FILE: &str = "discrepancy.svg";
/// The summary.
pub const SUMMARY_FILE: &str = "summary.md";
/// The JSON report.
pub const JSON_FILE: &str = "report.json";

/// Why the report folder could not be written.
#[derive(Debug, thiserror::Error)]
pub enum ReportError {
    /// A file or the folder could not be written.
    #[error("{path}: {source}")]
    Io {
        /// The path.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    /// The model could not be written as TOML.
    #[error(transparent)]
    Model(#[from] crate::model::ModelError),
    /// The plot could not be drawn.
    #[error("drawing {PLOT_FILE}: {0}")]
    Plot(String),
}

/// Writes the model TOML (the extended model, or the calibrated linear one when no
/// effect was named), the SVG plot, the Markdown summary and `report.json` into `dir`
/// (created if missing). Returns the paths written.
pub fn write(report: &Report, dir: &Path) -> Result<Vec<PathBuf>, ReportError> {
    let io = |path: &Path| {
        let path = path.to_path_buf();
        move |source| ReportError::Io { path, source }
    };
    std::fs::create_dir_all(dir).map_err(io(dir))?;
    let mut written = Vec::new();
    let series = &report.series;
    if let Some(model) = series
        .extended_model
        .as_ref()
        .or(series.linear_model.as_ref())
    {
        let path = dir.join(MODEL_FILE);
        let header = if series.extended_model.is_some() {
            format!(
                "# Calibrated model extended with {} (millgate discrepancy).\n",
                report.effect
            )
        } else {
            "# Calibrated linear model; no missing effect was found (millgate discrepancy).\n"
                .to_owned()
        };
        std::fs::write(&path, header + &model.to_toml_string()?).map_err(io(&path))?;
        written.push(path);
    }
    let path = dir.join(PLOT_FILE);
    plot(report, &path)?;
    written.push(path);
    let path = dir.join(SUMMARY_FILE);
    std::fs::write(&path, summary(report)).map_err(io(&path))?;
    written.push(path);
    let path = dir.join(JSON_FILE);
    let json = serde_json::to_string_pretty(report).map_err(|e| ReportError::Io {
        path: path.clone(),
        source: std::io::Error::other(e),
    })?;
    std::fs::write(&path, json + "\n").map_err(io(&path))?;
    written.push(path);
    Ok(written)
}

/// The Markdown summary.
pub fn summary(report: &Report) -> String {
    let mut text = String::new();
    let _ = writeln!(text, "# Model discrepancy\n");
    let location = report
        .location
        .map_or(String::new(), |i| format!(" in coupling {i}"));
    let parameters: Vec<String> = report
        .parameters
        .iter()
        .map(|(k, v)| format!("{k} = {v:.4e}"))
        .collect();
    let _ = writeln!(
        text,
        "**Missing effect: {}{}** {}\n",
        report.effect,
        location,
        if parameters.is_empty() {
            String::new()
        } else {
            format!("({})", parameters.join(", "))
        }
    );
    let _ = writeln!(
        text,
        "Residual RMS {:.3} kN*m before (calibrated linear model), {:.3} kN*m after; \
         noise in the record {:.3} kN*m.\n",
        report.rmse_before, report.rmse_after, report.noise_rms
    );
    let _ = writeln!(text, "## Calibration of the linear model\n");
    if let (Some(b1), Some(b2)) = (report.calibration.beta1_hz, report.calibration.beta2_hz) {
        let _ = writeln!(
            text,
            "Identified beta1 = {b1:.3} Hz, beta2 = {b2:.3} Hz (eq. (1) fit).\n"
        );
    }
    let _ = writeln!(text, "| quantity | unit | model | calibrated | change |");
    let _ = writeln!(text, "|---|---|---|---|---|");
    for a in &report.calibration.adjustments {
        let change = a
            .change_percent
            .map_or("-".to_owned(), |c| format!("{c:+.1}%"));
        let _ = writeln!(
            text,
            "| {} | {} | {:.4e} | {:.4e} | {} |",
            a.key, a.unit, a.model, a.calibrated, change
        );
    }
    let _ = writeln!(text, "\n## Where the linear model disagrees\n");
    if report.disagreement.is_empty() {
        let _ = writeln!(text, "Nowhere above 1.5x the noise.");
    }
    for d in &report.disagreement {
        let _ = writeln!(
            text,
            "- {:.3} s to {:.3} s: {} (residual RMS {:.2} kN*m)",
            d.t_start_s, d.t_end_s, d.feature, d.residual_rms
        );
    }
    let _ = writeln!(text, "\n| feature | measured | linear model |");
    let _ = writeln!(text, "|---|---|---|");
    let show = |v: Option<f64>| v.map_or("-".to_owned(), |v| format!("{v:.4}"));
    for f in &report.features {
        let _ = writeln!(
            text,
            "| {} | {} | {} |",
            f.name,
            show(f.measured),
            show(f.model)
        );
    }
    let _ = writeln!(text, "\n## Candidates (best first)\n");
    let _ = writeln!(text, "| effect | coupling | size | RMS kN*m | BIC |");
    let _ = writeln!(text, "|---|---|---|---|---|");
    let _ = writeln!(
        text,
        "| (linear) | - | - | {:.3} | {:.1} |",
        report.rmse_before, report.bic_linear
    );
    for c in &report.candidates {
        let _ = writeln!(
            text,
            "| {} | {} | {:.4e} {} | {:.3} | {:.1} |",
            c.effect.key(),
            c.location.map_or("-".to_owned(), |i| i.to_string()),
            c.value,
            c.effect.parameter_key(),
            c.rmse,
            c.bic
        );
    }
    let _ = writeln!(
        text,
        "\nAn effect is named when its BIC is more than {} below the linear model's.",
        super::BIC_MARGIN
    );
    text
}

/// One plot panel: its area, y-axis label and the lines (values, colour, legend).
type Panel<'p, 'b> = (
    &'p DrawingArea<SVGBackend<'b>, plotters::coord::Shift>,
    &'static str,
    Vec<(&'p [f64], RGBColor, String)>,
);

/// Draws record, linear and extended model (top) and both residuals (bottom).
fn plot(report: &Report, path: &Path) -> Result<(), ReportError> {
    let error = |e: &dyn std::fmt::Display| ReportError::Plot(e.to_string());
    let s = &report.series;
    let root = SVGBackend::new(path, (1200, 800)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| error(&e))?;
    let (top, bottom) = root.split_vertically(520);
    let t_range = (
        s.t_s.first().copied().unwrap_or(0.0),
        s.t_s.last().copied().unwrap_or(1.0),
    );
    let range = |series: &[&[f64]]| {
        let (lo, hi) = series
            .iter()
            .flat_map(|v| v.iter())
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
                (lo.min(*v), hi.max(*v))
            });
        let margin = 0.05 * (hi - lo).max(1.0e-9);
        (lo - margin, hi + margin)
    };
    let residual =
        |model: &[f64]| -> Vec<f64> { s.measured.iter().zip(model).map(|(m, v)| m - v).collect() };
    let linear_residual = residual(&s.linear);
    let extended_residual = residual(&s.extended);
    let extended_label = format!("extended ({})", report.effect);
    let panels: [Panel<'_, '_>; 2] = [
        (
            &top,
            "torque, kN*m",
            vec![
                (&s.measured, RGBColor(150, 150, 150), "measured".to_owned()),
                (&s.linear, BLUE, "calibrated linear".to_owned()),
                (&s.extended, RED, extended_label.clone()),
            ],
        ),
        (
            &bottom,
            "residual, kN*m",
            vec![
                (&linear_residual, BLUE, "measured - linear".to_owned()),
                (
                    &extended_residual,
                    RED,
                    format!("measured - {extended_label}"),
                ),
            ],
        ),
    ];
    for (area, label, lines) in panels {
        let values: Vec<&[f64]> = lines.iter().map(|l| l.0).collect();
        let (lo, hi) = range(&values);
        let mut chart = ChartBuilder::on(area)
            .margin(15)
            .x_label_area_size(40)
            .y_label_area_size(70)
            .build_cartesian_2d(t_range.0..t_range.1, lo..hi)
            .map_err(|e| error(&e))?;
        chart
            .configure_mesh()
            .x_desc("time, s")
            .y_desc(label)
            .draw()
            .map_err(|e| error(&e))?;
        for (values, color, name) in lines {
            chart
                .draw_series(LineSeries::new(
                    s.t_s.iter().copied().zip(values.iter().copied()),
                    color.stroke_width(if name == "measured" { 1 } else { 2 }),
                ))
                .map_err(|e| error(&e))?
                .label(name)
                .legend(move |(x, y)| PathElement::new([(x, y), (x + 20, y)], color));
        }
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()
            .map_err(|e| error(&e))?;
    }
    root.present().map_err(|e| error(&e))?;
    Ok(())
}
