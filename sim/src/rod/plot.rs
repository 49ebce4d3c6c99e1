//! SVG plots of a rod-mill check: the Ince-Strutt diagram with every pass's operating
//! points, and a Campbell chart per pass.
//!
//! - **Ince-Strutt**: the undamped tongues' edges `a_n(q)`, `b_n(q)` (grey), the damped
//!   tongues for the mill's damping ratio (shaded; `c = zeta sqrt(a)` taken at each
//!   tongue's centre), and each pass's points (one colour per pass; filled when
//!   unstable). Points beyond the plotted `a` range are left out (the title says how
//!   many).
//! - **Campbell** (one pass, finishing speed on x): each span's rod frequencies (solid),
//!   the parametric resonances `2 f_rod / n`, n = 1, 2 (dashed: an excitation crossing
//!   one pumps the rod), the roll-eccentricity lines of every stand at 1x and 2x (grey
//!   rays), the drive's torsional modes (dotted), the bands to avoid (shaded) and the
//!   pass's speed (vertical).

use plotters::coord::types::RangedCoordf64;
use plotters::coord::Shift;
use plotters::prelude::*;

use super::check::{PassReport, PassSetup, Source};
use super::mill::RodMill;
use crate::plot::{drawing, padded_range, PlotError};

/// Figure size, px.
const SIZE: (u32, u32) = (900, 600);

/// One span's (index in the pass) frequency of one bending mode over the speed range.
type RodCurve = (usize, usize, Vec<(f64, f64)>);

/// An operating point: its pass (index), `a`, `q` and whether it is stable.
type Point = (usize, f64, f64, bool);

/// A chart of the figure, `f64` on both axes.
type Chart<'a, 'b> = ChartContext<'a, SVGBackend<'b>, Cartesian2d<RangedCoordf64, RangedCoordf64>>;

/// q values per tongue edge curve.
const CURVE_POINTS: usize = 80;

/// Renders the Ince-Strutt diagram of `reports` (passes checked on `mill`).
pub fn ince_strutt_svg(mill: &RodMill, reports: &[PassReport]) -> Result<String, PlotError> {
    let points = operating_points(reports);
    if points.is_empty() {
        return Err(PlotError::Nothing("no operating points"));
    }
    // Tongues 0..=3 (a <= 10.5) by default, further when an unstable point needs it.
    let a_max = points
        .iter()
        .filter(|p| !p.3 && p.1 <= 101.0)
        .map(|p| p.1 * 1.05)
        .fold(10.5_f64, f64::max);
    let shown: Vec<&Point> = points.iter().filter(|p| p.1 <= a_max).collect();
    let q_max = shown.iter().map(|p| p.2.abs()).fold(0.2_f64, f64::max) * 1.2;
    let zeta = mill.rod.damping_ratio;
    let top_order = (a_max.sqrt().ceil() as u8).min(millgate_dsp::mathieu::MAX_ORDER);
    let qs: Vec<f64> = (0..=CURVE_POINTS)
        .map(|k| q_max * k as f64 / CURVE_POINTS as f64)
        .collect();
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, SIZE).into_drawing_area();
        root.fill(&WHITE).map_err(drawing)?;
        let hidden = points.len() - shown.len();
        let title = if hidden > 0 {
            format!("Ince-Strutt diagram, zeta = {zeta} ({hidden} points beyond a = {a_max:.0} not shown)")
        } else {
            format!("Ince-Strutt diagram, zeta = {zeta}")
        };
        let mut chart = chart(
            &root,
            title,
            (-1.0..a_max, 0.0..q_max),
            ("a = 4 omega^2 / Theta^2", "q"),
        )?;
        draw_damped_tongues(&mut chart, mill, top_order, &qs)?;
        draw_undamped_edges(&mut chart, mill, top_order, &qs)?;
        draw_passes(&mut chart, reports, &shown)?;
        draw_legend(&mut chart, SeriesLabelPosition::UpperRight)?;
        root.present().map_err(drawing)?;
    }
    Ok(svg)
}

/// Every operating point of every pass.
fn operating_points(reports: &[PassReport]) -> Vec<Point> {
    reports
        .iter()
        .enumerate()
        .flat_map(|(pass, report)| {
            report
                .spans
                .iter()
                .flat_map(|s| s.points.iter())
                .map(move |p| (pass, p.a, p.q, p.stable))
        })
        .collect()
}

/// A chart on all of `root` titled `title` over `ranges` (x, y), its axes described by
/// `descriptions` (x, y).
fn chart<'a, 'b>(
    root: &'a DrawingArea<SVGBackend<'b>, Shift>,
    title: String,
    ranges: (std::ops::Range<f64>, std::ops::Range<f64>),
    (x_desc, y_desc): (&str, &str),
) -> Result<Chart<'a, 'b>, PlotError> {
    let mut chart = ChartBuilder::on(root)
        .caption(title, ("sans-serif", 20))
        .margin(15)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(ranges.0, ranges.1)
        .map_err(drawing)?;
    chart
        .configure_mesh()
        .x_desc(x_desc)
        .y_desc(y_desc)
        .light_line_style(TRANSPARENT)
        .axis_desc_style(("sans-serif", 16))
        .label_style(("sans-serif", 13))
        .draw()
        .map_err(drawing)?;
    Ok(chart)
}

/// The series' legend at `position`.
fn draw_legend<'a, 'b: 'a>(
    chart: &mut Chart<'a, 'b>,
    position: SeriesLabelPosition,
) -> Result<(), PlotError> {
    chart
        .configure_series_labels()
        .position(position)
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .draw()
        .map_err(drawing)
}

fn mathieu_error(error: millgate_dsp::mathieu::MathieuError) -> PlotError {
    PlotError::Drawing(error.to_string())
}

/// The damped tongues 1..=`top_order` (shaded) over `qs`, `c = zeta n` for tongue n.
fn draw_damped_tongues(
    chart: &mut Chart<'_, '_>,
    mill: &RodMill,
    top_order: u8,
    qs: &[f64],
) -> Result<(), PlotError> {
    let zeta = mill.rod.damping_ratio;
    for order in 1..=top_order {
        let c = zeta * f64::from(order);
        let mut lower = Vec::new();
        let mut upper = Vec::new();
        for &q in qs {
            if let Some((lo, hi)) = mill
                .mathieu
                .damped_tongue(order, q, c)
                .map_err(mathieu_error)?
            {
                lower.push((lo, q));
                upper.push((hi, q));
            }
        }
        if lower.len() >= 2 {
            let outline: Vec<(f64, f64)> =
                lower.into_iter().chain(upper.into_iter().rev()).collect();
            chart
                .draw_series(std::iter::once(Polygon::new(
                    outline,
                    RED.mix(0.2).filled(),
                )))
                .map_err(drawing)?;
        }
    }
    Ok(())
}

/// The undamped tongues' edges `a_n(q)`, `b_n(q)` up to `top_order` over `qs` (grey).
fn draw_undamped_edges(
    chart: &mut Chart<'_, '_>,
    mill: &RodMill,
    top_order: u8,
    qs: &[f64],
) -> Result<(), PlotError> {
    let mathieu = &mill.mathieu;
    let grey = BLACK.mix(0.4);
    for order in 0..=top_order {
        let a_curve: Vec<(f64, f64)> = qs
            .iter()
            .map(|&q| Ok((mathieu.characteristic_a(order, q)?, q)))
            .collect::<Result<_, _>>()
            .map_err(mathieu_error)?;
        chart
            .draw_series(LineSeries::new(a_curve, grey.stroke_width(1)))
            .map_err(drawing)?;
        if order >= 1 {
            let b_curve: Vec<(f64, f64)> = qs
                .iter()
                .map(|&q| Ok((mathieu.characteristic_b(order, q)?, q)))
                .collect::<Result<_, _>>()
                .map_err(mathieu_error)?;
            chart
                .draw_series(LineSeries::new(b_curve, grey.stroke_width(1)))
                .map_err(drawing)?;
        }
    }
    Ok(())
}

/// Each pass's `shown` points in its colour, filled when unstable, with its legend.
fn draw_passes(
    chart: &mut Chart<'_, '_>,
    reports: &[PassReport],
    shown: &[&Point],
) -> Result<(), PlotError> {
    for (pass, report) in reports.iter().enumerate() {
        let color = Palette99::pick(pass).to_rgba();
        let mine: Vec<(f64, f64, bool)> = shown
            .iter()
            .filter(|p| p.0 == pass)
            .map(|p| (p.1, p.2.abs(), p.3))
            .collect();
        chart
            .draw_series(mine.iter().map(|&(a, q, stable)| {
                let style = if stable {
                    color.stroke_width(2)
                } else {
                    color.filled()
                };
                Circle::new((a, q), 5, style)
            }))
            .map_err(drawing)?
            .label(format!("{} ({})", report.pass, report.configuration))
            .legend(move |(x, y)| Circle::new((x + 10, y), 5, color.filled()));
    }
    Ok(())
}

/// Renders the Campbell chart of one pass (see the module docs).
pub fn campbell_svg(setup: &PassSetup) -> Result<String, PlotError> {
    let mill = &setup.mill;
    let (v_lo, v_hi) = setup.speed_range_m_s;
    let speeds: Vec<f64> = (0..=CURVE_POINTS)
        .map(|k| v_lo + (v_hi - v_lo) * k as f64 / CURVE_POINTS as f64)
        .collect();
    let rod_curves = rod_curves(setup, &speeds);
    let f_max = rod_curves
        .iter()
        .filter(|(_, mode, _)| *mode == 1)
        .flat_map(|(_, _, curve)| curve.iter().map(|p| 2.5 * p.1))
        .fold(f64::NAN, f64::max);
    let Some((_, f_top)) = padded_range([0.0, f_max].into_iter()) else {
        return Err(PlotError::Nothing("no rod frequency"));
    };
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, SIZE).into_drawing_area();
        root.fill(&WHITE).map_err(drawing)?;
        let title = format!(
            "Campbell chart: pass {} (configuration {})",
            setup.pass.name, mill.configurations[setup.configuration].name
        );
        let mut chart = chart(
            &root,
            title,
            (v_lo..v_hi, 0.0..f_top),
            ("finishing speed, m/s", "frequency, Hz"),
        )?;
        for band in &setup.avoid {
            chart
                .draw_series(std::iter::once(Rectangle::new(
                    [(band.from_m_s, 0.0), (band.to_m_s, f_top)],
                    RED.mix(0.12).filled(),
                )))
                .map_err(drawing)?;
        }
        draw_eccentricity(&mut chart, setup, &speeds)?;
        draw_torsional_modes(&mut chart, setup)?;
        draw_rod_curves(&mut chart, setup, &rod_curves)?;
        let v = setup.finishing_speed_m_s;
        chart
            .draw_series(LineSeries::new(
                [(v, 0.0), (v, f_top)],
                BLUE.stroke_width(2),
            ))
            .map_err(drawing)?
            .label(format!("pass speed {v:.1} m/s"))
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLUE.stroke_width(2)));
        draw_legend(&mut chart, SeriesLabelPosition::UpperLeft)?;
        root.present().map_err(drawing)?;
    }
    Ok(svg)
}

/// Rod frequencies of every span and mode at `speeds`.
fn rod_curves(setup: &PassSetup, speeds: &[f64]) -> Vec<RodCurve> {
    let mill = &setup.mill;
    let moving = mill.rod.moving_rod;
    let mut rod_curves: Vec<RodCurve> = Vec::new();
    for (index, span) in setup.spans.iter().enumerate() {
        for mode in 1..=mill.rod.modes {
            let curve = speeds
                .iter()
                .map(|&v| {
                    let axial = if moving { span.speed_share * v } else { 0.0 };
                    (v, span.beam.frequency_hz(mode, axial))
                })
                .collect();
            rod_curves.push((index, mode, curve));
        }
    }
    rod_curves
}

/// The roll-eccentricity rays of every stand at 1x and 2x (grey).
fn draw_eccentricity(
    chart: &mut Chart<'_, '_>,
    setup: &PassSetup,
    speeds: &[f64],
) -> Result<(), PlotError> {
    let mill = &setup.mill;
    let grey = BLACK.mix(0.35);
    for (stand, share) in setup.stand_shares.iter().enumerate() {
        let diameter = mill.stands[stand].roll_diameter_m;
        for harmonic in [1.0, 2.0] {
            let ray = speeds
                .iter()
                .map(|&v| (v, harmonic * share * v / (std::f64::consts::PI * diameter)));
            let series = chart
                .draw_series(LineSeries::new(ray, grey.stroke_width(1)))
                .map_err(drawing)?;
            if stand == 0 && harmonic == 1.0 {
                series
                    .label("roll eccentricity 1x, 2x of each stand")
                    .legend(move |(x, y)| {
                        PathElement::new(vec![(x, y), (x + 20, y)], grey.stroke_width(1))
                    });
            }
        }
    }
    Ok(())
}

/// The drive's torsional modes that pump a span (dotted, each once).
fn draw_torsional_modes(chart: &mut Chart<'_, '_>, setup: &PassSetup) -> Result<(), PlotError> {
    let (v_lo, v_hi) = setup.speed_range_m_s;
    let torsional: Vec<f64> = setup
        .spans
        .iter()
        .flat_map(|s| s.sources.iter())
        .filter_map(|s| match s.source {
            Source::Torsion { frequency_hz, .. } => Some(frequency_hz),
            Source::Eccentricity { .. } => None,
        })
        .fold(Vec::new(), |mut all, f| {
            if !all.contains(&f) {
                all.push(f);
            }
            all
        });
    for (index, f) in torsional.into_iter().enumerate() {
        let series = chart
            .draw_series(DottedLineSeries::new(
                [(v_lo, f), (v_hi, f)],
                2,
                6,
                |point| Circle::new(point, 1, BLACK.filled()),
            ))
            .map_err(drawing)?;
        if index == 0 {
            series
                .label("drive torsional modes pumping a span")
                .legend(|(x, y)| Circle::new((x + 10, y), 2, BLACK.filled()));
        }
    }
    Ok(())
}

/// Each span's rod frequencies (solid, one colour per span) and their parametric
/// resonances `2 f_rod / n`, n = 1, 2 (dashed).
fn draw_rod_curves(
    chart: &mut Chart<'_, '_>,
    setup: &PassSetup,
    rod_curves: &[RodCurve],
) -> Result<(), PlotError> {
    let mill = &setup.mill;
    for (span, mode, curve) in rod_curves {
        let color = Palette99::pick(*span).to_rgba();
        let name = &mill.spans[setup.spans[*span].span].name;
        let series = chart
            .draw_series(LineSeries::new(curve.clone(), color.stroke_width(2)))
            .map_err(drawing)?;
        if *mode == 1 {
            series
                .label(format!("span {name}: f_rod, 2 f_rod / n"))
                .legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(2))
                });
        }
        for n in [1.0, 2.0] {
            let resonance: Vec<(f64, f64)> = curve.iter().map(|&(v, f)| (v, 2.0 * f / n)).collect();
            chart
                .draw_series(DashedLineSeries::new(
                    resonance,
                    6,
                    4,
                    color.stroke_width(1),
                ))
                .map_err(drawing)?;
        }
    }
    Ok(())
}
