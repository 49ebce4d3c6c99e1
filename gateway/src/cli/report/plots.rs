//! The report's SVG plots (plotters): quantities over time in stacked panels
//! ([`time_svg`]), TAF over static torque with the wear map's curves ([`taf_svg`],
//! [`wear_curves`]), lanes of spans over time ([`lanes_svg`]: alarms, availability)
//! an alarm bite's captured torque ([`trace_svg`]) and the fatigue components' damage
//! per bite over its TAF ([`damage_svg`]).

use std::path::Path;

use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

use crate::history::captures::Capture;
use crate::history::fatigue_series::FatigueDamagePoint;
use crate::history::query::SettingsRow;
use crate::history::summary::TafPoint;
use crate::state::time::UtcTime;

/// Width and height of a plot panel, px.
const PANEL: (u32, u32) = (900, 300);

/// The time axis of the plots: seconds, minutes, hours or days since the period's
/// start, whichever gives readable numbers, labelled in UTC clock time
/// ([`TimeAxis::clock`]: `16:30`, `11-22 16:30` or `2026-11-22` as the span asks).
#[derive(Debug, Clone, Copy)]
pub(super) struct TimeAxis {
    start: UtcTime,
    unit_s: f64,
    pub(super) unit: &'static str,
    pub(super) span: f64,
}

impl TimeAxis {
    pub(super) fn new(start: UtcTime, end: UtcTime) -> Self {
        let span_s = ((end.unix_ms() - start.unix_ms()) as f64 / 1000.0).max(1.0);
        let (unit_s, unit) = match span_s {
            s if s < 300.0 => (1.0, "s"),
            s if s < 5.0 * 3600.0 => (60.0, "min"),
            s if s < 5.0 * 86_400.0 => (3600.0, "h"),
            _ => (86_400.0, "days"),
        };
        Self {
            start,
            unit_s,
            unit,
            span: span_s / unit_s,
        }
    }

    pub(super) fn x(&self, time: &str) -> Option<f64> {
        Some(self.x_of(UtcTime::parse(time).ok()?))
    }

    /// `time` on the axis.
    pub(super) fn x_of(&self, time: UtcTime) -> f64 {
        (time.unix_ms() - self.start.unix_ms()) as f64 / 1000.0 / self.unit_s
    }

    /// The middle of `[start, end)` on the axis: where a time bucket is drawn.
    pub(super) fn middle(&self, start: UtcTime, end: UtcTime) -> f64 {
        (self.x_of(start) + self.x_of(end)) / 2.0
    }

    fn label(&self) -> String {
        let start = self.start.to_string();
        format!("time, UTC (from {} {})", &start[..10], &start[11..19])
    }

    /// The clock time (UTC) at `x` on the axis, as much of it as the axis' unit
    /// needs: `HH:MM:SS` for seconds, `HH:MM` for minutes, `MM-DD HH:MM` for hours,
    /// the date for days.
    pub(super) fn clock(&self, x: f64) -> String {
        let unix_ms = self.start.unix_ms() + (x * self.unit_s * 1000.0).round() as i64;
        let text = UtcTime::from_unix_ms(unix_ms).to_string();
        match self.unit {
            "s" => text[11..19].to_owned(),
            "min" => text[11..16].to_owned(),
            "h" => format!("{} {}", &text[5..10], &text[11..16]),
            _ => text[..10].to_owned(),
        }
    }
}

fn drawing<E: std::fmt::Display>(error: E) -> anyhow::Error {
    anyhow::anyhow!("drawing a report plot: {error}")
}

pub(super) fn range(values: impl Iterator<Item = f64>) -> (f64, f64) {
    millgate_sim::plot::padded_range(values).unwrap_or((0.0, 1.0))
}

/// A panel of lines over time: `(label, line)` series and horizontal threshold lines
/// `(label, value)`; `bands` ranges `(label, [(x, low, high)])` drawn shaded (the
/// first blue, the next orange); `marks` vertical lines at `x` with their text; the
/// legend upper left, or lower right where the data leave that corner free.
pub(super) struct TimePanel<'a> {
    pub(super) y_label: &'a str,
    pub(super) lines: Vec<(&'a str, Vec<(f64, f64)>)>,
    pub(super) bands: Vec<Band<'a>>,
    pub(super) thresholds: Vec<(&'a str, f64)>,
    pub(super) marks: Vec<(f64, String)>,
    pub(super) legend_lower_right: bool,
}

/// A labelled range over time: `(label, [(x, low, high)])`.
pub(super) type Band<'a> = (&'a str, Vec<(f64, f64, f64)>);

/// The shade of a panel's band `index`.
fn band_colour(index: usize) -> RGBAColor {
    match index {
        0 => BLUE.mix(0.15),
        _ => RGBColor(230, 120, 0).mix(0.2),
    }
}

pub(super) fn time_svg(
    title: &str,
    axis: &TimeAxis,
    panels: &[TimePanel<'_>],
) -> anyhow::Result<String> {
    let mut svg = String::new();
    {
        let size = (PANEL.0, PANEL.1 * panels.len() as u32 + 40);
        let root = SVGBackend::with_string(&mut svg, size).into_drawing_area();
        root.fill(&WHITE).map_err(drawing)?;
        let root = root.titled(title, ("sans-serif", 20)).map_err(drawing)?;
        for (area, panel) in root.split_evenly((panels.len(), 1)).iter().zip(panels) {
            let values = panel
                .lines
                .iter()
                .flat_map(|(_, p)| p.iter().map(|(_, y)| *y))
                .chain(
                    panel
                        .bands
                        .iter()
                        .flat_map(|(_, band)| band.iter().flat_map(|(_, lo, hi)| [*lo, *hi])),
                )
                .chain(panel.thresholds.iter().map(|(_, v)| *v));
            let (y_low, y_high) = range(values);
            let mut chart = ChartBuilder::on(area)
                .margin(10)
                .x_label_area_size(35)
                .y_label_area_size(60)
                .build_cartesian_2d(0.0..axis.span.max(1e-9), y_low..y_high)
                .map_err(drawing)?;
            chart
                .configure_mesh()
                .x_desc(axis.label())
                .x_label_formatter(&|x| axis.clock(*x))
                .y_desc(panel.y_label)
                .label_style(("sans-serif", 12))
                .draw()
                .map_err(drawing)?;
            for (index, (label, band)) in panel.bands.iter().enumerate() {
                if band.is_empty() {
                    continue;
                }
                let colour = band_colour(index);
                let mut upper: Vec<(f64, f64)> = band.iter().map(|(x, _, hi)| (*x, *hi)).collect();
                let lower = band.iter().rev().map(|(x, lo, _)| (*x, *lo));
                upper.extend(lower);
                chart
                    .draw_series(std::iter::once(Polygon::new(upper, colour.filled())))
                    .map_err(drawing)?
                    .label(*label)
                    .legend(move |(x, y)| {
                        Rectangle::new([(x, y - 4), (x + 16, y + 4)], colour.filled())
                    });
            }
            for (index, (label, points)) in panel.lines.iter().enumerate() {
                let color = Palette99::pick(index + 3).to_rgba();
                chart
                    .draw_series(LineSeries::new(points.clone(), color.stroke_width(2)))
                    .map_err(drawing)?
                    .label(*label)
                    .legend(move |(x, y)| {
                        PathElement::new(vec![(x, y), (x + 16, y)], color.stroke_width(2))
                    });
            }
            for (index, (label, value)) in panel.thresholds.iter().enumerate() {
                let color = if index == 0 {
                    RGBColor(230, 150, 0)
                } else {
                    RED
                };
                chart
                    .draw_series(LineSeries::new(
                        vec![(0.0, *value), (axis.span, *value)],
                        color.stroke_width(1),
                    ))
                    .map_err(drawing)?
                    .label(format!("{label} {value}"))
                    .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], color));
            }
            for (x, text) in &panel.marks {
                let colour = RED.mix(0.8);
                chart
                    .draw_series(LineSeries::new(
                        vec![(*x, y_low), (*x, y_high)],
                        colour.stroke_width(1),
                    ))
                    .map_err(drawing)?;
                // The text beside the line, on the side with room, near the top.
                let pos = if *x > axis.span / 2.0 {
                    Pos::new(HPos::Right, VPos::Top)
                } else {
                    Pos::new(HPos::Left, VPos::Top)
                };
                let style = ("sans-serif", 13).into_font().color(&RED).pos(pos);
                chart
                    .draw_series(std::iter::once(Text::new(
                        text.clone(),
                        (*x, y_high - 0.04 * (y_high - y_low)),
                        style,
                    )))
                    .map_err(drawing)?;
            }
            chart
                .configure_series_labels()
                .position(if panel.legend_lower_right {
                    SeriesLabelPosition::LowerRight
                } else {
                    SeriesLabelPosition::UpperLeft
                })
                .background_style(WHITE.mix(0.8))
                .border_style(BLACK)
                .draw()
                .map_err(drawing)?;
        }
        root.present().map_err(drawing)?;
    }
    Ok(svg)
}

/// Cells of [`TafGrid`] and [`DamageGrid`] across and up: 4.5 by 4 px of a 900 by
/// 450 px plot.
const GRID: (usize, usize) = (180, 90);

/// The cell of `value` among `cells` equal cells over `low..=high` (the top edge
/// the last cell's); `None` outside.
fn cell(value: f64, (low, high): (f64, f64), cells: usize) -> Option<usize> {
    let at = (value - low) / (high - low) * cells as f64;
    (0.0..=cells as f64)
        .contains(&at)
        .then(|| (at as usize).min(cells - 1))
}

/// Bites binned over static torque (x) and TAF (y) for [`taf_svg`]: a year of bites
/// drawn as at most 180 x 90 shaded cells instead of a million circles; clean and
/// degraded windows apart.
#[derive(Debug, Clone)]
pub(super) struct TafGrid {
    x: (f64, f64),
    y: (f64, f64),
    clean: Vec<u32>,
    degraded: Vec<u32>,
    /// Bites with a TAF outside the ranges (not drawn).
    pub(super) outside: u64,
}

impl TafGrid {
    /// An empty grid over static torque `x` (kN*m) and TAF `y`, each `(low, high)`
    /// with low < high.
    pub(super) fn new(x: (f64, f64), y: (f64, f64)) -> Self {
        Self {
            x,
            y,
            clean: vec![0; GRID.0 * GRID.1],
            degraded: vec![0; GRID.0 * GRID.1],
            outside: 0,
        }
    }

    /// Count a bite (one without a TAF is not plotted).
    pub(super) fn add(&mut self, point: TafPoint) {
        let Some(taf) = point.taf else {
            return;
        };
        match (
            cell(point.static_torque_knm, self.x, GRID.0),
            cell(taf, self.y, GRID.1),
        ) {
            (Some(i), Some(j)) => {
                let cells = if point.degraded {
                    &mut self.degraded
                } else {
                    &mut self.clean
                };
                cells[j * GRID.0 + i] += 1;
            }
            _ => self.outside += 1,
        }
    }

    /// The occupied cells of `cells`: `(x0, y0, x1, y1, count)`.
    fn occupied<'a>(
        &'a self,
        cells: &'a [u32],
    ) -> impl Iterator<Item = (f64, f64, f64, f64, u32)> + 'a {
        let width = (self.x.1 - self.x.0) / GRID.0 as f64;
        let height = (self.y.1 - self.y.0) / GRID.1 as f64;
        cells
            .iter()
            .enumerate()
            .filter(|(_, count)| **count > 0)
            .map(move |(index, count)| {
                let (i, j) = ((index % GRID.0) as f64, (index / GRID.0) as f64);
                let (x0, y0) = (self.x.0 + i * width, self.y.0 + j * height);
                (x0, y0, x0 + width, y0 + height, *count)
            })
    }
}

/// TAF over static torque: the bites' cells (shaded by count; degraded windows a
/// grey dot per cell), the thresholds, the wear map's curves.
pub(super) fn taf_svg(
    title: &str,
    grid: &TafGrid,
    settings: Option<&SettingsRow>,
    curves: &[Curve],
) -> anyhow::Result<String> {
    let thresholds: Vec<(&str, f64)> = settings
        .map(|s| vec![("TAF warning", s.taf_warning), ("TAF alarm", s.taf_alarm)])
        .unwrap_or_default();
    let (x_range, y_range) = (grid.x, grid.y);
    let most = grid.clean.iter().max().copied().unwrap_or(0).max(1);
    let axes = XyAxes {
        x: (x_range, "static torque, kN*m"),
        y: (y_range, "TAF (peak / static)"),
        y_format: None,
    };
    xy_svg(title, &axes, SeriesLabelPosition::UpperRight, |chart| {
        // Shade by the logarithm of the count: one bite still shows, the densest
        // cell is darkest.
        let shade = |count: u32| 0.2 + 0.8 * f64::from(count).ln_1p() / f64::from(most).ln_1p();
        chart
            .draw_series(grid.occupied(&grid.clean).map(|(x0, y0, x1, y1, count)| {
                Rectangle::new([(x0, y0), (x1, y1)], BLUE.mix(shade(count)).filled())
            }))
            .map_err(drawing)?
            .label(format!("bites (shade: bites per cell, darkest {most})"))
            .legend(|(x, y)| Rectangle::new([(x, y - 4), (x + 8, y + 4)], BLUE.filled()));
        // Degraded windows as a dot per occupied cell, over the clean bites' shade
        // (they are few; cells of their own would hide the clean density).
        let grey = RGBColor(90, 90, 90);
        chart
            .draw_series(grid.occupied(&grid.degraded).map(|(x0, y0, x1, y1, _)| {
                Circle::new(((x0 + x1) / 2.0, (y0 + y1) / 2.0), 1, grey.filled())
            }))
            .map_err(drawing)?
            .label("bites, degraded window (a dot per cell)")
            .legend(move |(x, y)| Circle::new((x + 4, y), 2, grey.filled()));
        for (index, (label, curve)) in curves.iter().enumerate() {
            let color = CURVE_COLOURS[index % CURVE_COLOURS.len()];
            chart
                .draw_series(LineSeries::new(curve.clone(), color.stroke_width(2)))
                .map_err(drawing)?
                .label(label.as_str())
                .legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 16, y)], color.stroke_width(2))
                });
        }
        for (index, (label, value)) in thresholds.iter().enumerate() {
            let color = if index == 0 {
                RGBColor(230, 150, 0)
            } else {
                RED
            };
            chart
                .draw_series(LineSeries::new(
                    vec![(x_range.0, *value), (x_range.1, *value)],
                    color,
                ))
                .map_err(drawing)?
                .label(format!("{label} {value}"))
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], color));
        }
        Ok(())
    })
}

/// The chart of [`xy_svg`].
type XyChart<'a, 'b> =
    ChartContext<'a, SVGBackend<'b>, Cartesian2d<RangedCoordf64, RangedCoordf64>>;

/// The axes of [`xy_svg`]: each `((low, high), description)`, and how y's labels
/// are written (plotters' own numbers when `None`).
struct XyAxes<'a> {
    x: ((f64, f64), &'a str),
    y: ((f64, f64), &'a str),
    y_format: Option<&'a dyn Fn(&f64) -> String>,
}

/// A 900 x 450 px plot titled `title` over `axes`, with what `draw` adds and its
/// legend at `legend`.
fn xy_svg(
    title: &str,
    axes: &XyAxes<'_>,
    legend: SeriesLabelPosition,
    draw: impl FnOnce(&mut XyChart<'_, '_>) -> anyhow::Result<()>,
) -> anyhow::Result<String> {
    let (((x_low, x_high), x_desc), ((y_low, y_high), y_desc)) = (axes.x, axes.y);
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (PANEL.0, 450)).into_drawing_area();
        root.fill(&WHITE).map_err(drawing)?;
        let root = root.titled(title, ("sans-serif", 20)).map_err(drawing)?;
        let mut chart = ChartBuilder::on(&root)
            .margin(10)
            .x_label_area_size(35)
            .y_label_area_size(60)
            .build_cartesian_2d(x_low..x_high, y_low..y_high)
            .map_err(drawing)?;
        let mut mesh = chart.configure_mesh();
        mesh.x_desc(x_desc)
            .y_desc(y_desc)
            .label_style(("sans-serif", 12));
        if let Some(format) = axes.y_format {
            mesh.y_label_formatter(format);
        }
        mesh.draw().map_err(drawing)?;
        draw(&mut chart)?;
        chart
            .configure_series_labels()
            .position(legend)
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()
            .map_err(drawing)?;
        root.present().map_err(drawing)?;
    }
    Ok(svg)
}

/// The wear map's curves over the bites' blue shade: dark, saturated colours, each
/// at least 4.5:1 against white (WCAG's contrast for text, computed as WCAG 2.1
/// defines it; the Palette99 colours they had from its sixth on measure 6.9, 1.4,
/// 3.3, 1.25 and 1.6:1), none of them the shade's blue.
const CURVE_COLOURS: [RGBColor; 5] = [
    RGBColor(0, 110, 40),  // green, 6.4:1
    RGBColor(170, 0, 120), // magenta, 7.0:1
    RGBColor(120, 70, 0),  // brown, 7.9:1
    RGBColor(0, 100, 110), // teal, 6.9:1
    RGBColor(90, 40, 160), // violet, 9.4:1
];

/// A labelled curve of (x, y) points.
pub(super) type Curve = (String, Vec<(f64, f64)>);

/// Horizontal bars per row over time: `(row label, [(from, to, color)], [(x, marker color)])`.
pub(super) type Lane = (String, Vec<(f64, f64, RGBColor)>, Vec<(f64, RGBColor)>);

pub(super) fn lanes_svg(title: &str, axis: &TimeAxis, lanes: &[Lane]) -> anyhow::Result<String> {
    let mut svg = String::new();
    {
        let height = 80 + 28 * lanes.len().max(1) as u32;
        let root = SVGBackend::with_string(&mut svg, (PANEL.0, height)).into_drawing_area();
        root.fill(&WHITE).map_err(drawing)?;
        let root = root.titled(title, ("sans-serif", 20)).map_err(drawing)?;
        let rows = lanes.len().max(1) as f64;
        let mut chart = ChartBuilder::on(&root)
            .margin(10)
            .x_label_area_size(35)
            .y_label_area_size(220)
            .build_cartesian_2d(0.0..axis.span.max(1e-9), -0.5..rows - 0.5)
            .map_err(drawing)?;
        let names: Vec<String> = lanes.iter().map(|l| l.0.clone()).collect();
        chart
            .configure_mesh()
            .x_desc(axis.label())
            .x_label_formatter(&|x| axis.clock(*x))
            .y_labels(lanes.len().max(1))
            .y_label_formatter(&|y| {
                let index = y.round();
                if (y - index).abs() < 0.01 && index >= 0.0 {
                    names.get(index as usize).cloned().unwrap_or_default()
                } else {
                    String::new()
                }
            })
            .disable_y_mesh()
            .label_style(("sans-serif", 12))
            .draw()
            .map_err(drawing)?;
        for (row, (_, spans, markers)) in lanes.iter().enumerate() {
            let y = row as f64;
            chart
                .draw_series(spans.iter().map(|(from, to, color)| {
                    Rectangle::new([(*from, y - 0.3), (to.max(*from), y + 0.3)], color.filled())
                }))
                .map_err(drawing)?;
            chart
                .draw_series(
                    markers
                        .iter()
                        .map(|(x, color)| TriangleMarker::new((*x, y), 6, color.filled())),
                )
                .map_err(drawing)?;
        }
        root.present().map_err(drawing)?;
    }
    Ok(svg)
}

/// Columns a captured trace is reduced to: each column's lowest and highest sample,
/// what a reader can see at the plot's width (a bite window is about 1 300 samples).
const TRACE_COLUMNS: usize = 450;

/// A capture's first channel (an alarm bite's torque) over time from its first
/// sample, reduced to [`TRACE_COLUMNS`] columns of lowest and highest samples (every
/// peak stays visible), with the trigger marked when the capture says where it was.
pub(super) fn trace_svg(title: &str, capture: &Capture) -> anyhow::Result<String> {
    let Some(channel) = capture.channels.first() else {
        anyhow::bail!("capture {} has no channel", capture.row.id);
    };
    let samples = &channel.samples;
    let per_column = samples.len().div_ceil(TRACE_COLUMNS).max(1);
    // Each column's lowest and highest sample, in the order they came.
    let mut envelope = Vec::with_capacity(2 * TRACE_COLUMNS);
    for (column, chunk) in samples.chunks(per_column).enumerate() {
        let finite = chunk
            .iter()
            .enumerate()
            .filter(|(_, v)| v.is_finite())
            .map(|(i, &v)| (column * per_column + i, v));
        let low = finite.clone().min_by(|a, b| a.1.total_cmp(&b.1));
        let high = finite.max_by(|a, b| a.1.total_cmp(&b.1));
        let (Some(low), Some(high)) = (low, high) else {
            continue;
        };
        let (first, second) = if low.0 <= high.0 {
            (low, high)
        } else {
            (high, low)
        };
        envelope.push((capture.time_s(first.0), first.1));
        if second.0 != first.0 {
            envelope.push((capture.time_s(second.0), second.1));
        }
    }
    let (low, high) = range(envelope.iter().map(|p| p.1));
    let span_s = capture.time_s(samples.len()).max(1e-9);
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, PANEL).into_drawing_area();
        root.fill(&WHITE).map_err(drawing)?;
        let root = root.titled(title, ("sans-serif", 18)).map_err(drawing)?;
        let mut chart = ChartBuilder::on(&root)
            .margin(10)
            .x_label_area_size(35)
            .y_label_area_size(60)
            .build_cartesian_2d(0.0..span_s, low..high)
            .map_err(drawing)?;
        chart
            .configure_mesh()
            .x_desc("s from the first sample")
            .y_desc(format!("{}, {}", channel.name, channel.unit))
            .label_style(("sans-serif", 12))
            .draw()
            .map_err(drawing)?;
        chart
            .draw_series(LineSeries::new(envelope, &BLUE))
            .map_err(drawing)?
            .label("captured torque")
            .legend(|(x, y)| PathElement::new([(x, y), (x + 16, y)], BLUE));
        if let Some(analysis) = &capture.meta.analysis {
            let t = capture.time_s(analysis.trigger_index);
            chart
                .draw_series(LineSeries::new([(t, low), (t, high)], RED.mix(0.6)))
                .map_err(drawing)?
                .label("trigger")
                .legend(|(x, y)| PathElement::new([(x, y), (x + 16, y)], RED.mix(0.6)));
        }
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .label_font(("sans-serif", 12))
            .draw()
            .map_err(drawing)?;
        root.present().map_err(drawing)?;
    }
    Ok(svg)
}

/// The wear map of the driveline model at `model`, TAF over static torque for gaps of
/// 0..4 mrad over `torques` (kN*m); why not, when the file cannot be read or simulated.
pub(super) fn wear_curves(model: &str, torques: (f64, f64)) -> Result<Vec<Curve>, String> {
    use millgate_sim::wear_map::{wear_map, WearMapSpec};
    let model = millgate_sim::model::Model::load(Path::new(model)).map_err(|e| e.to_string())?;
    let (low, high) = (torques.0.max(5.0), torques.1.max(torques.0.max(5.0) + 5.0));
    let spec = WearMapSpec {
        static_torques_knm: (0..6)
            .map(|i| low + (high - low) * f64::from(i) / 5.0)
            .collect(),
        backlashes_rad: (0..=4).map(|i| f64::from(i) * 1.0e-3).collect(),
        coupling: None,
        period_lowpass_hz: None,
    };
    let map = wear_map(&model, &spec, |_, _, _| {}).map_err(|e| e.to_string())?;
    Ok(map
        .backlashes_rad()
        .into_iter()
        .map(|gap| {
            let curve = map
                .rows
                .iter()
                .filter(|row| row.backlash_rad == gap)
                .map(|row| (row.static_torque_knm, row.taf))
                .collect();
            (format!("wear map, gap {:.0} mrad", gap * 1e3), curve)
        })
        .collect())
}

/// Bites' damage per fatigue component over their TAF for [`damage_svg`]: binned into
/// [`GRID`] cells over the TAF (x) and the damage's decimal logarithm (y), so a year
/// of bites is drawn as at most 180 x 90 dots per component.
#[derive(Debug, Clone)]
pub(super) struct DamageGrid {
    taf: (f64, f64),
    log_damage: (f64, f64),
    /// Counts per component index, `[j * GRID.0 + i]`.
    cells: Vec<Vec<u32>>,
    /// Bites whose damage was 0 (every cycle under the endurance limit): not on a
    /// logarithmic axis.
    pub(super) without_damage: u64,
    /// Bites drawn.
    pub(super) drawn: u64,
}

impl DamageGrid {
    /// An empty grid over the TAF `taf` and the damage `damage` (> 0), each
    /// `(low, high)` with low < high.
    pub(super) fn new(taf: (f64, f64), damage: (f64, f64)) -> Self {
        Self {
            taf,
            log_damage: (damage.0.log10(), damage.1.log10()),
            cells: Vec::new(),
            without_damage: 0,
            drawn: 0,
        }
    }

    /// The upper corner of the plot with fewer occupied cells (a quarter of the width,
    /// a fifth of the height): where the legend hides the fewest dots.
    fn legend_corner(&self) -> SeriesLabelPosition {
        let in_corner = |left: bool| {
            let columns = if left {
                0..GRID.0 / 4
            } else {
                GRID.0 - GRID.0 / 4..GRID.0
            };
            let rows = GRID.1 - GRID.1 / 5..GRID.1;
            let mut occupied = 0;
            for cells in &self.cells {
                for j in rows.clone() {
                    let row = &cells[j * GRID.0..(j + 1) * GRID.0];
                    occupied += row[columns.clone()].iter().filter(|c| **c > 0).count();
                }
            }
            occupied
        };
        if in_corner(true) <= in_corner(false) {
            SeriesLabelPosition::UpperLeft
        } else {
            SeriesLabelPosition::UpperRight
        }
    }

    /// Count a component's damage at a bite.
    pub(super) fn add(&mut self, point: FatigueDamagePoint) {
        if point.damage <= 0.0 {
            self.without_damage += 1;
            return;
        }
        let (Some(i), Some(j)) = (
            cell(point.taf, self.taf, GRID.0),
            cell(point.damage.log10(), self.log_damage, GRID.1),
        ) else {
            return;
        };
        if self.cells.len() <= point.component_index {
            self.cells
                .resize(point.component_index + 1, vec![0; GRID.0 * GRID.1]);
        }
        self.cells[point.component_index][j * GRID.0 + i] += 1;
        self.drawn += 1;
    }
}

/// Damage per bite over the bite's TAF: per component (`names`, by index) a dot per
/// occupied cell of `grid` at its centre, shaded by its count; damage on a
/// logarithmic axis (its decimal logarithm drawn linearly, labelled as the damage:
/// plotters' own logarithmic axis crowds its labels within a decade); the legend in
/// the upper corner with fewer dots.
pub(super) fn damage_svg(
    title: &str,
    grid: &DamageGrid,
    names: &[String],
) -> anyhow::Result<String> {
    let (x_range, (y_low, y_high)) = (grid.taf, grid.log_damage);
    let most = grid
        .cells
        .iter()
        .flat_map(|cells| cells.iter())
        .max()
        .copied()
        .unwrap_or(0)
        .max(1);
    let (width, height) = (
        (x_range.1 - x_range.0) / GRID.0 as f64,
        (y_high - y_low) / GRID.1 as f64,
    );
    let damage_label = |y: &f64| format!("{:.1e}", 10f64.powf(*y));
    let axes = XyAxes {
        x: (x_range, "TAF of the bite (peak / static)"),
        y: (
            (y_low, y_high),
            "damage per bite (Miner's sum, 1 = failure; logarithmic)",
        ),
        y_format: Some(&damage_label),
    };
    xy_svg(title, &axes, grid.legend_corner(), |chart| {
        let shade = |count: u32| 0.35 + 0.65 * f64::from(count).ln_1p() / f64::from(most).ln_1p();
        for (index, cells) in grid.cells.iter().enumerate() {
            let colour = CURVE_COLOURS[index % CURVE_COLOURS.len()];
            let name = names.get(index).map_or("component", String::as_str);
            chart
                .draw_series(
                    cells
                        .iter()
                        .enumerate()
                        .filter(|(_, c)| **c > 0)
                        .map(|(k, count)| {
                            let (i, j) = ((k % GRID.0) as f64, (k / GRID.0) as f64);
                            let x = x_range.0 + (i + 0.5) * width;
                            let y = y_low + (j + 0.5) * height;
                            Circle::new((x, y), 2, colour.mix(shade(*count)).filled())
                        }),
                )
                .map_err(drawing)?
                .label(name.to_owned())
                .legend(move |(x, y)| Circle::new((x + 4, y), 3, colour.filled()));
        }
        Ok(())
    })
}
