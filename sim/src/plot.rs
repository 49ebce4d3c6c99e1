//! SVG plot of a wear map: TAF, first-period shift and (when the map has a zero-gap
//! row) the shift over the linear driveline's, each against static torque, one curve
//! per opened gap (the curves a maintenance engineer reads).

use plotters::prelude::*;

use crate::wear_map::WearMap;

/// Width of one panel and height of the figure, px.
const PANEL_SIZE: (u32, u32) = (600, 500);

/// One panel: y-axis label and the plotted value of each row of the map, in row order.
type Panel = (&'static str, Vec<Option<f64>>);

/// Why the plot could not be drawn.
#[derive(Debug, thiserror::Error)]
pub enum PlotError {
    /// The wear map has no rows with finite values to plot.
    #[error("the wear map has nothing to plot")]
    Empty,
    /// A rod-mill plot has nothing to draw (the text says which).
    #[error("nothing to plot: {0}")]
    Nothing(&'static str),
    /// plotters reported a drawing error.
    #[error("drawing the wear map: {0}")]
    Drawing(String),
}

pub(crate) fn drawing<E: std::fmt::Display>(error: E) -> PlotError {
    PlotError::Drawing(error.to_string())
}

/// Range of `values` with 5% margin, or `None` if no value is finite.
pub fn padded_range(values: impl Iterator<Item = f64>) -> Option<(f64, f64)> {
    let (low, high) = values
        .filter(|v| v.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
            (lo.min(v), hi.max(v))
        });
    if low > high {
        return None;
    }
    let margin = if high > low {
        0.05 * (high - low)
    } else {
        0.05 * high.abs().max(1.0)
    };
    Some((low - margin, high + margin))
}

/// Renders the wear map as an SVG document (panels side by side).
pub fn wear_map_svg(map: &WearMap) -> Result<String, PlotError> {
    let ms = |seconds: Option<f64>| seconds.map(|s| s * 1.0e3);
    let mut panels: Vec<Panel> = vec![
        (
            "TAF (peak / static)",
            map.rows.iter().map(|row| Some(row.taf)).collect(),
        ),
        (
            "first - second period, ms",
            map.rows.iter().map(|row| ms(row.period_shift_s)).collect(),
        ),
    ];
    let over_linear: Vec<Option<f64>> = map
        .rows
        .iter()
        .map(|row| ms(map.shift_over_linear_s(row)))
        .collect();
    if over_linear.iter().any(Option::is_some) {
        panels.push(("period shift over zero gap, ms", over_linear));
    }
    let Some(torque_range) = padded_range(map.rows.iter().map(|r| r.static_torque_knm)) else {
        return Err(PlotError::Empty);
    };

    let mut svg = String::new();
    {
        let size = (PANEL_SIZE.0 * panels.len() as u32, PANEL_SIZE.1);
        let root = SVGBackend::with_string(&mut svg, size).into_drawing_area();
        root.fill(&WHITE).map_err(drawing)?;
        let root = root
            .titled(
                &format!("Wear map: {} (coupling {})", map.model_name, map.coupling),
                ("sans-serif", 24),
            )
            .map_err(drawing)?;
        let areas = root.split_evenly((1, panels.len()));
        let gaps = map.backlashes_rad();
        for (area, (label, values)) in areas.iter().zip(&panels) {
            let y_range = padded_range(values.iter().flatten().copied()).unwrap_or((-1.0, 1.0));
            let mut chart = ChartBuilder::on(area)
                .margin(15)
                .x_label_area_size(40)
                .y_label_area_size(60)
                .build_cartesian_2d(torque_range.0..torque_range.1, y_range.0..y_range.1)
                .map_err(drawing)?;
            chart
                .configure_mesh()
                .x_desc("static torque, kN*m")
                .y_desc(*label)
                .axis_desc_style(("sans-serif", 16))
                .label_style(("sans-serif", 13))
                .draw()
                .map_err(drawing)?;
            for (index, &gap) in gaps.iter().enumerate() {
                let color = Palette99::pick(index).to_rgba();
                let points: Vec<(f64, f64)> = map
                    .rows
                    .iter()
                    .zip(values)
                    .filter(|(row, _)| row.backlash_rad == gap)
                    .filter_map(|(row, value)| value.map(|v| (row.static_torque_knm, v)))
                    .collect();
                chart
                    .draw_series(LineSeries::new(points, color.stroke_width(2)))
                    .map_err(drawing)?
                    .label(format!("gap {:.1} mrad", gap * 1.0e3))
                    .legend(move |(x, y)| {
                        PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(2))
                    });
            }
            chart
                .configure_series_labels()
                // Curves fall with static torque: the upper right stays clear.
                .position(SeriesLabelPosition::UpperRight)
                .background_style(WHITE.mix(0.8))
                .border_style(BLACK)
                .draw()
                .map_err(drawing)?;
        }
        root.present().map_err(drawing)?;
    }
    Ok(svg)
}

/// A family of curves with one highlighted and measured points over them, e.g. TAF
/// over static torque of a gap map's rows, the estimated gap's curve and the bites
/// (`millgate wear --plot`).
#[derive(Debug, Clone, PartialEq)]
pub struct CurvesPlot {
    /// Title above the chart.
    pub title: String,
    /// x-axis label with its unit.
    pub x_label: String,
    /// y-axis label with its unit.
    pub y_label: String,
    /// Thin curves: (legend label, points in x order).
    pub curves: Vec<(String, Vec<(f64, f64)>)>,
    /// The curve drawn thick and black on top, when there is one.
    pub highlighted: Option<(String, Vec<(f64, f64)>)>,
    /// Measured points, drawn as red dots, with their legend label.
    pub points: (String, Vec<(f64, f64)>),
}

/// Renders `plot` as an SVG document.
pub fn curves_svg(plot: &CurvesPlot) -> Result<String, PlotError> {
    let all = || {
        plot.curves
            .iter()
            .flat_map(|(_, points)| points.iter())
            .chain(
                plot.highlighted
                    .iter()
                    .flat_map(|(_, points)| points.iter()),
            )
            .chain(plot.points.1.iter())
    };
    let (Some(x_range), Some(y_range)) = (
        padded_range(all().map(|p| p.0)),
        padded_range(all().map(|p| p.1)),
    ) else {
        return Err(PlotError::Nothing("no curve and no point"));
    };
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (900, 600)).into_drawing_area();
        root.fill(&WHITE).map_err(drawing)?;
        let root = root
            .titled(&plot.title, ("sans-serif", 22))
            .map_err(drawing)?;
        let mut chart = ChartBuilder::on(&root)
            .margin(15)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d(x_range.0..x_range.1, y_range.0..y_range.1)
            .map_err(drawing)?;
        chart
            .configure_mesh()
            .x_desc(plot.x_label.as_str())
            .y_desc(plot.y_label.as_str())
            .axis_desc_style(("sans-serif", 16))
            .label_style(("sans-serif", 13))
            .draw()
            .map_err(drawing)?;
        for (index, (label, points)) in plot.curves.iter().enumerate() {
            let color = Palette99::pick(index).to_rgba();
            chart
                .draw_series(LineSeries::new(points.clone(), color.stroke_width(1)))
                .map_err(drawing)?
                .label(label.as_str())
                .legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(1))
                });
        }
        if let Some((label, points)) = &plot.highlighted {
            chart
                .draw_series(LineSeries::new(points.clone(), BLACK.stroke_width(4)))
                .map_err(drawing)?
                .label(label.as_str())
                .legend(|(x, y)| {
                    PathElement::new(vec![(x, y), (x + 20, y)], BLACK.stroke_width(4))
                });
        }
        let (label, points) = &plot.points;
        chart
            .draw_series(
                points
                    .iter()
                    .map(|&(x, y)| Circle::new((x, y), 5, RED.filled())),
            )
            .map_err(drawing)?
            .label(label.as_str())
            .legend(|(x, y)| Circle::new((x + 10, y), 5, RED.filled()));
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperRight)
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()
            .map_err(drawing)?;
        root.present().map_err(drawing)?;
    }
    Ok(svg)
}

/// One panel of [`time_series_svg`]: y-axis label and named series, one value per
/// time point (`None` = not valid there, a break in the curve).
pub(crate) type TimePanel<'a> = (&'a str, Vec<(String, Vec<Option<f64>>)>);

/// Renders curves over time as an SVG document, panels stacked (one x axis, s).
/// Used by `millgate chatter --plot`.
pub fn time_series_svg(
    title: &str,
    time_s: &[f64],
    panels: &[TimePanel<'_>],
) -> Result<String, PlotError> {
    let Some(time_range) = padded_range(time_s.iter().copied()) else {
        return Err(PlotError::Nothing("no time points"));
    };
    if panels.is_empty() {
        return Err(PlotError::Nothing("no panels"));
    }
    let mut svg = String::new();
    {
        let size = (PANEL_SIZE.0 * 2, 260 * panels.len() as u32 + 40);
        let root = SVGBackend::with_string(&mut svg, size).into_drawing_area();
        root.fill(&WHITE).map_err(drawing)?;
        let root = root.titled(title, ("sans-serif", 22)).map_err(drawing)?;
        let areas = root.split_evenly((panels.len(), 1));
        for (area, (label, series)) in areas.iter().zip(panels) {
            let values = series.iter().flat_map(|(_, v)| v.iter().flatten().copied());
            let y_range = padded_range(values).unwrap_or((-1.0, 1.0));
            let mut chart = ChartBuilder::on(area)
                .margin(10)
                .x_label_area_size(35)
                .y_label_area_size(60)
                .build_cartesian_2d(time_range.0..time_range.1, y_range.0..y_range.1)
                .map_err(drawing)?;
            chart
                .configure_mesh()
                .x_desc("t, s")
                .y_desc(*label)
                .axis_desc_style(("sans-serif", 14))
                .label_style(("sans-serif", 12))
                .draw()
                .map_err(drawing)?;
            for (index, (name, values)) in series.iter().enumerate() {
                let color = Palette99::pick(index).to_rgba();
                // Each run of valid values is its own line: no line across a gap.
                let mut runs: Vec<Vec<(f64, f64)>> = vec![Vec::new()];
                for (&t, value) in time_s.iter().zip(values) {
                    match value.filter(|v| v.is_finite()) {
                        Some(v) => {
                            if let Some(run) = runs.last_mut() {
                                run.push((t, v));
                            }
                        }
                        None if runs.last().is_some_and(|run| !run.is_empty()) => {
                            runs.push(Vec::new());
                        }
                        None => {}
                    }
                }
                for (run_index, run) in runs.into_iter().enumerate() {
                    let drawn = chart
                        .draw_series(LineSeries::new(run, color.stroke_width(2)))
                        .map_err(drawing)?;
                    if run_index == 0 {
                        drawn.label(name.clone()).legend(move |(x, y)| {
                            PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(2))
                        });
                    }
                }
            }
            chart
                .configure_series_labels()
                .position(SeriesLabelPosition::UpperLeft)
                .background_style(WHITE.mix(0.8))
                .border_style(BLACK)
                .draw()
                .map_err(drawing)?;
        }
        root.present().map_err(drawing)?;
    }
    Ok(svg)
}
