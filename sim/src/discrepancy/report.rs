//! The report folder of the workflow: the extended model and the calibrated linear
//! model as model TOML files, a plot of each bite (record, calibrated linear and
//! extended model, residuals below), a Markdown summary and the JSON report.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use plotters::prelude::*;

use super::decision::describe;
use super::windows::DISAGREEMENT_FACTOR;
use super::{Report, Verdict, BIC_MARGIN};

/// The extended model (the calibrated linear one when no effect was named).
pub const MODEL_FILE: &str = "extended-model.toml";
/// The calibrated linear model to monitor against (stiffness adjusted, a nonlinear
/// effect removed).
pub const CALIBRATED_MODEL_FILE: &str = "calibrated-model.toml";
/// The plot.
pub(crate) const PLOT_FILE: &str = "discrepancy.svg";
/// The summary.
pub(crate) const SUMMARY_FILE: &str = "summary.md";
/// The JSON report.
pub(crate) const JSON_FILE: &str = "report.json";

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
    /// A model could not be written as TOML.
    #[error("{path}: {source}")]
    Model {
        /// The model file.
        path: PathBuf,
        /// Why.
        source: crate::model::ModelError,
    },
    /// The JSON report could not be serialised.
    #[error("{path}: {source}")]
    Json {
        /// The JSON file.
        path: PathBuf,
        /// Why.
        source: serde_json::Error,
    },
    /// The plot could not be drawn.
    #[error("{path}: drawing failed: {source}")]
    Plot {
        /// The plot file.
        path: PathBuf,
        /// What plotters reported.
        source: Box<dyn std::error::Error + Send + Sync>,
    },
}

/// Writes into `dir` (created if missing): [`MODEL_FILE`] (the extended model, or the
/// calibrated linear one when no effect was named), [`CALIBRATED_MODEL_FILE`], the SVG
/// plot (each bite: record and models, residuals below), the Markdown summary and the
/// JSON report. Returns the paths written.
pub fn write(report: &Report, dir: &Path) -> Result<Vec<PathBuf>, ReportError> {
    let io = |path: &Path| {
        let path = path.to_path_buf();
        move |source| ReportError::Io { path, source }
    };
    std::fs::create_dir_all(dir).map_err(io(dir))?;
    let mut written = Vec::new();
    let series = &report.series;
    let effect = report.effect.map_or("none", |e| e.key());
    let models = [
        (
            MODEL_FILE,
            series
                .extended_model
                .as_ref()
                .or(series.linear_model.as_ref()),
            if series.extended_model.is_some() {
                format!("# Calibrated model extended with {effect} (millgate discrepancy).\n")
            } else {
                "# Calibrated linear model; no missing effect was found (millgate discrepancy).\n"
                    .to_owned()
            },
        ),
        (
            CALIBRATED_MODEL_FILE,
            series.calibrated_model.as_ref(),
            format!(
                "# Calibrated linear model to monitor against: stiffness adjusted, \
                 missing effect ({effect}) removed unless linear (millgate discrepancy).\n"
            ),
        ),
    ];
    for (name, model, header) in models {
        let Some(model) = model else { continue };
        let path = dir.join(name);
        let text = model
            .to_toml_string()
            .map_err(|source| ReportError::Model {
                path: path.clone(),
                source,
            })?;
        std::fs::write(&path, header + &text).map_err(io(&path))?;
        written.push(path);
    }
    let path = dir.join(PLOT_FILE);
    plot(report, &path).map_err(|source| ReportError::Plot {
        path: path.clone(),
        source,
    })?;
    written.push(path);
    let path = dir.join(SUMMARY_FILE);
    std::fs::write(&path, summary(report)).map_err(io(&path))?;
    written.push(path);
    let path = dir.join(JSON_FILE);
    let json = serde_json::to_string_pretty(report).map_err(|source| ReportError::Json {
        path: path.clone(),
        source,
    })?;
    std::fs::write(&path, json + "\n").map_err(io(&path))?;
    written.push(path);
    Ok(written)
}

/// The Markdown summary.
pub fn summary(report: &Report) -> String {
    let mut text = String::new();
    let _ = writeln!(text, "# Model discrepancy\n");
    verdict(&mut text, report);
    let _ = writeln!(
        text,
        "Residual RMS {:.3} kN*m before (calibrated linear model), {:.3} kN*m after; \
         noise in the record {:.3} kN*m.\n",
        report.rmse_before, report.rmse_after, report.noise_rms
    );
    bites_table(&mut text, report);
    calibration(&mut text, report);
    disagreement(&mut text, report);
    candidates(&mut text, report);
    text
}

/// The verdict: the missing effect and its size, or the rivals that cannot be told
/// apart and how to tell them.
fn verdict(text: &mut String, report: &Report) {
    let effect = report.effect.map_or("none", |e| e.key());
    let location = report
        .location
        .map_or(String::new(), |i| format!(" in coupling {i}"));
    let parameters: Vec<String> = report
        .parameters
        .iter()
        .map(|(k, v)| format!("{k} = {v:.4e}"))
        .collect();
    let sizes = if parameters.is_empty() {
        String::new()
    } else {
        format!("({})", parameters.join(", "))
    };
    match report.verdict {
        Verdict::CannotTell => {
            let _ = writeln!(
                text,
                "**Cannot tell: {effect}{location} {sizes} or one of the alternatives \
                 below explain the bites equally (BIC within {BIC_MARGIN}).**\n"
            );
            for c in &report.alternatives {
                let _ = writeln!(
                    text,
                    "- {} ({} = {:.4e}): RMS {:.3} kN*m, BIC {:.1}",
                    describe(&c.effect, c.location),
                    c.effect.parameter_key(),
                    c.value,
                    c.rmse,
                    c.bic
                );
            }
            if let Some(further) = &report.tell_apart {
                let _ = writeln!(text, "\nTo tell them apart, {}.", further.advice);
            }
            let _ = writeln!(text);
        }
        Verdict::Named | Verdict::None => {
            let _ = writeln!(text, "**Missing effect: {effect}{location}** {sizes}\n");
        }
    }
}

/// Each bite's noise, load and residuals.
fn bites_table(text: &mut String, report: &Report) {
    let _ = writeln!(text, "## Bites\n");
    let _ = writeln!(
        text,
        "| bite | t0 s | samples | noise kN*m | static kN*m | onset s | RMS before | RMS after |"
    );
    let _ = writeln!(text, "|---|---|---|---|---|---|---|---|");
    for (b, bite) in report.bites.iter().enumerate() {
        let _ = writeln!(
            text,
            "| {} | {:.3} | {} | {:.3} | {:.1} | {:.4} | {:.3} | {:.3} |",
            b + 1,
            bite.t0_s,
            bite.samples,
            bite.noise_rms,
            bite.static_torque_knm,
            bite.onset_s,
            bite.rmse_before,
            bite.rmse_after
        );
    }
}

/// How the linear model was calibrated: identifications and adjustments.
fn calibration(text: &mut String, report: &Report) {
    let _ = writeln!(text, "\n## Calibration of the linear model\n");
    if let (Some(b1), Some(b2)) = (report.calibration.beta1_hz, report.calibration.beta2_hz) {
        let _ = writeln!(
            text,
            "Identified beta1 = {b1:.3} Hz, beta2 = {b2:.3} Hz (eq. (1) fit on the first \
             bite's transient).\n"
        );
    }
    for id in &report.calibration.identified {
        let _ = writeln!(
            text,
            "- bite {}, {} part from {:.3} s: beta1 = {:.3} Hz, beta2 = {:.3} Hz",
            id.bite + 1,
            id.window,
            id.t_start_s,
            id.beta1_hz,
            id.beta2_hz
        );
    }
    let _ = writeln!(
        text,
        "\n| quantity | bite | unit | model | calibrated | change |"
    );
    let _ = writeln!(text, "|---|---|---|---|---|---|");
    for a in &report.calibration.adjustments {
        let change = a
            .change_percent
            .map_or("-".to_owned(), |c| format!("{c:+.1}%"));
        let bite = a.bite.map_or("-".to_owned(), |b| (b + 1).to_string());
        let _ = writeln!(
            text,
            "| {} | {} | {} | {:.4e} | {:.4e} | {} |",
            a.key, bite, a.unit, a.model, a.calibrated, change
        );
    }
}

/// Where the linear model disagrees, and the transient features compared.
fn disagreement(text: &mut String, report: &Report) {
    let _ = writeln!(text, "\n## Where the linear model disagrees\n");
    if report.disagreement.is_empty() {
        let _ = writeln!(text, "Nowhere above {DISAGREEMENT_FACTOR}x the noise.");
    }
    for d in &report.disagreement {
        let _ = writeln!(
            text,
            "- bite {}, {:.3} s to {:.3} s: {} (residual RMS {:.2} kN*m)",
            d.bite + 1,
            d.t_start_s,
            d.t_end_s,
            d.feature,
            d.residual_rms
        );
    }
    let _ = writeln!(text, "\n| bite | feature | measured | linear model |");
    let _ = writeln!(text, "|---|---|---|---|");
    let show = |v: Option<f64>| v.map_or("-".to_owned(), |v| format!("{v:.4}"));
    for f in &report.features {
        let _ = writeln!(
            text,
            "| {} | {} | {} | {} |",
            f.bite + 1,
            f.name,
            show(f.measured),
            show(f.model)
        );
    }
}

/// Every candidate against the linear model, and the naming rule.
fn candidates(text: &mut String, report: &Report) {
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
            c.effect,
            c.location.map_or("-".to_owned(), |i| i.to_string()),
            c.value,
            c.effect.parameter_key(),
            c.rmse,
            c.bic
        );
    }
    let _ = writeln!(
        text,
        "\nAn effect is named when its BIC is more than {BIC_MARGIN} below the linear \
         model's; two effects within {BIC_MARGIN} of each other cannot be told apart."
    );
}

/// One plot panel: its area, y-axis label and the lines (values, colour, legend).
type Panel<'p, 'b> = (
    &'p DrawingArea<SVGBackend<'b>, plotters::coord::Shift>,
    String,
    Vec<(&'p [f64], RGBColor, String)>,
);

/// Height of one bite's block in the plot, pixels.
const BITE_HEIGHT: u32 = 600;

/// An error of the plot, boxed.
type PlotError = Box<dyn std::error::Error + Send + Sync>;

/// Draws for each bite the record, linear and extended model, and both residuals below.
fn plot(report: &Report, path: &Path) -> Result<(), PlotError> {
    let blocks = report.series.bites.len().max(1);
    let root = SVGBackend::new(path, (1200, BITE_HEIGHT * blocks as u32)).into_drawing_area();
    root.fill(&WHITE)?;
    let effect = report.effect.map_or("none", |e| e.key());
    for (b, (area, s)) in root
        .split_evenly((blocks, 1))
        .iter()
        .zip(&report.series.bites)
        .enumerate()
    {
        let (top, bottom) = area.split_vertically(BITE_HEIGHT * 62 / 100);
        let t_range = (
            s.t_s.first().copied().unwrap_or(0.0),
            s.t_s.last().copied().unwrap_or(1.0),
        );
        let residual = |model: &[f64]| -> Vec<f64> {
            s.measured.iter().zip(model).map(|(m, v)| m - v).collect()
        };
        let linear_residual = residual(&s.linear);
        let extended_residual = residual(&s.extended);
        let extended_label = format!("extended ({effect})");
        let static_knm = report.bites.get(b).map_or(0.0, |x| x.static_torque_knm);
        let panels: [Panel<'_, '_>; 2] = [
            (
                &top,
                format!("bite {}, {static_knm:.0} kN*m: torque, kN*m", b + 1),
                vec![
                    (&s.measured, RGBColor(150, 150, 150), "measured".to_owned()),
                    (&s.linear, BLUE, "calibrated linear".to_owned()),
                    (&s.extended, RED, extended_label.clone()),
                ],
            ),
            (
                &bottom,
                "residual, kN*m".to_owned(),
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
            let (lo, hi) = value_range(lines.iter().map(|l| l.0));
            let mut chart = ChartBuilder::on(area)
                .margin(15)
                .x_label_area_size(40)
                .y_label_area_size(70)
                .build_cartesian_2d(t_range.0..t_range.1, lo..hi)?;
            chart
                .configure_mesh()
                .x_desc("time, s")
                .y_desc(label)
                .draw()?;
            for (values, color, name) in lines {
                chart
                    .draw_series(LineSeries::new(
                        s.t_s.iter().copied().zip(values.iter().copied()),
                        color.stroke_width(if name == "measured" { 1 } else { 2 }),
                    ))?
                    .label(name)
                    .legend(move |(x, y)| PathElement::new([(x, y), (x + 20, y)], color));
            }
            chart
                .configure_series_labels()
                .background_style(WHITE.mix(0.8))
                .border_style(BLACK)
                .draw()?;
        }
    }
    root.present()?;
    Ok(())
}

/// The range of every value in `series`, with a 5% margin.
fn value_range<'a>(series: impl Iterator<Item = &'a [f64]>) -> (f64, f64) {
    let (lo, hi) = series
        .flat_map(|v| v.iter())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
            (lo.min(*v), hi.max(*v))
        });
    if !(lo.is_finite() && hi.is_finite()) {
        return (0.0, 1.0);
    }
    let margin = 0.05 * (hi - lo).max(1.0e-9);
    (lo - margin, hi + margin)
}
