//! `millgate report`: a maintenance report from the event history.
//!
//! ```text
//! millgate report --db FILE --out DIR [--since T] [--until T]
//! ```
//!
//! Writes into `DIR`: `report.md` (plots linked), `report.html` (one file that opens
//! offline, plots inline) and the SVG plots:
//! - per driveline `<name>-time.svg`: TAF of each bite over time with its warning and
//!   alarm thresholds; the wear index and trend; the gap estimate with its interval
//!   and thresholds when the history holds the gap diagnosis;
//! - per driveline `<name>-taf.svg`: TAF over static torque (degraded windows apart)
//!   with the thresholds and, when the driveline's model file (as configured) can be
//!   read, the wear map's curves for gaps of 0..4 mrad over the measured torque range;
//! - `alarms.svg`: the alarm timeline (raised, cleared, acknowledged; latched spans);
//! - `availability.svg`: each source's outages and the gateway's own down time.
//!
//! The Markdown and the HTML come from one document model ([`Block`]).

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use plotters::prelude::*;

use crate::cli::history::parse_time;
use crate::outputs::history::query::{
    AlarmRow, BiteRow, Filter, HistoryReader, OutageRow, RunRow, SettingsRow, WearRow,
};
use crate::state::time::UtcTime;

/// Width and height of a plot panel, px.
const PANEL: (u32, u32) = (900, 300);
/// Alarm rows listed in the report's table (all are in the timeline plot).
const ALARM_TABLE_ROWS: usize = 200;

/// Arguments of `millgate report`.
#[derive(Debug, Clone, clap::Args)]
pub struct ReportArgs {
    /// The history file.
    #[arg(long)]
    pub db: PathBuf,
    /// Folder for report.md, report.html and the plots (created when missing).
    #[arg(long)]
    pub out: PathBuf,
    /// From this time on (UTC; default: the first event).
    #[arg(long)]
    pub since: Option<String>,
    /// Up to this time (UTC; default: now).
    #[arg(long)]
    pub until: Option<String>,
}

/// One part of the report.
#[derive(Debug, Clone, PartialEq)]
pub enum Block {
    /// A heading of level 1..=3.
    Heading(u8, String),
    /// A paragraph.
    Text(String),
    /// A table: header and rows.
    Table(Vec<String>, Vec<Vec<String>>),
    /// A plot: its file name, its title and the SVG document.
    Figure {
        /// File name in the report folder.
        file: String,
        /// What it shows.
        title: String,
        /// The SVG.
        svg: String,
    },
}

/// The report as Markdown, figures linked to their files.
pub fn markdown(blocks: &[Block]) -> String {
    let mut out = String::new();
    for block in blocks {
        match block {
            Block::Heading(level, text) => {
                let _ = writeln!(out, "{} {text}\n", "#".repeat(usize::from(*level)));
            }
            Block::Text(text) => {
                let _ = writeln!(out, "{text}\n");
            }
            Block::Table(header, rows) => {
                let _ = writeln!(out, "| {} |", header.join(" | "));
                let _ = writeln!(out, "|{}", "---|".repeat(header.len()));
                for row in rows {
                    let cells: Vec<String> = row.iter().map(|c| c.replace('|', "\\|")).collect();
                    let _ = writeln!(out, "| {} |", cells.join(" | "));
                }
                out.push('\n');
            }
            Block::Figure { file, title, .. } => {
                let _ = writeln!(out, "![{title}]({file})\n");
            }
        }
    }
    out
}

fn escape_html(text: &str) -> String {
    text.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// The report as one HTML page that needs no other file: the SVGs are inline.
pub fn html(title: &str, blocks: &[Block]) -> String {
    let mut out = format!(
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>{}</title>\n\
         <style>body{{font-family:sans-serif;max-width:960px;margin:2em auto;color:#222}}\
         table{{border-collapse:collapse;margin:1em 0}}td,th{{border:1px solid #bbb;\
         padding:2px 8px;text-align:left}}figure{{margin:1em 0}}svg{{max-width:100%;\
         height:auto}}</style></head><body>\n",
        escape_html(title)
    );
    for block in blocks {
        match block {
            Block::Heading(level, text) => {
                let _ = writeln!(out, "<h{level}>{}</h{level}>", escape_html(text));
            }
            Block::Text(text) => {
                let _ = writeln!(out, "<p>{}</p>", escape_html(text));
            }
            Block::Table(header, rows) => {
                out.push_str("<table><tr>");
                for cell in header {
                    let _ = write!(out, "<th>{}</th>", escape_html(cell));
                }
                out.push_str("</tr>\n");
                for row in rows {
                    out.push_str("<tr>");
                    for cell in row {
                        let _ = write!(out, "<td>{}</td>", escape_html(cell));
                    }
                    out.push_str("</tr>\n");
                }
                out.push_str("</table>\n");
            }
            Block::Figure { title, svg, .. } => {
                // The SVG document without its XML declaration, inline.
                let body = svg.find("<svg").map_or(svg.as_str(), |at| &svg[at..]);
                let _ = writeln!(
                    out,
                    "<figure>{body}<figcaption>{}</figcaption></figure>",
                    escape_html(title)
                );
            }
        }
    }
    out.push_str("</body></html>\n");
    out
}

/// The time axis of the plots: seconds, minutes, hours or days since the period's
/// start, whichever gives readable numbers.
#[derive(Debug, Clone, Copy)]
struct TimeAxis {
    start: UtcTime,
    unit_s: f64,
    unit: &'static str,
    span: f64,
}

impl TimeAxis {
    fn new(start: UtcTime, end: UtcTime) -> Self {
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

    fn x(&self, time: &str) -> Option<f64> {
        let t = UtcTime::parse(time).ok()?;
        Some((t.unix_ms() - self.start.unix_ms()) as f64 / 1000.0 / self.unit_s)
    }

    fn label(&self) -> String {
        format!("{} since {} UTC", self.unit, self.start)
    }
}

fn drawing<E: std::fmt::Display>(error: E) -> anyhow::Error {
    anyhow::anyhow!("drawing a report plot: {error}")
}

fn range(values: impl Iterator<Item = f64>) -> (f64, f64) {
    millgate_sim::plot::padded_range(values).unwrap_or((0.0, 1.0))
}

/// A panel of points and lines over time: `(label, points, line)` series and
/// horizontal threshold lines `(label, value)`; `band` an interval drawn shaded.
struct TimePanel<'a> {
    y_label: &'a str,
    points: Vec<(&'a str, Vec<(f64, f64)>)>,
    lines: Vec<(&'a str, Vec<(f64, f64)>)>,
    band: Vec<(f64, f64, f64)>,
    thresholds: Vec<(&'a str, f64)>,
}

fn time_svg(title: &str, axis: &TimeAxis, panels: &[TimePanel<'_>]) -> anyhow::Result<String> {
    let mut svg = String::new();
    {
        let size = (PANEL.0, PANEL.1 * panels.len() as u32 + 40);
        let root = SVGBackend::with_string(&mut svg, size).into_drawing_area();
        root.fill(&WHITE).map_err(drawing)?;
        let root = root.titled(title, ("sans-serif", 20)).map_err(drawing)?;
        for (area, panel) in root.split_evenly((panels.len(), 1)).iter().zip(panels) {
            let values = panel
                .points
                .iter()
                .chain(&panel.lines)
                .flat_map(|(_, p)| p.iter().map(|(_, y)| *y))
                .chain(panel.band.iter().flat_map(|(_, lo, hi)| [*lo, *hi]))
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
                .y_desc(panel.y_label)
                .label_style(("sans-serif", 12))
                .draw()
                .map_err(drawing)?;
            if !panel.band.is_empty() {
                let mut upper: Vec<(f64, f64)> =
                    panel.band.iter().map(|(x, _, hi)| (*x, *hi)).collect();
                let lower = panel.band.iter().rev().map(|(x, lo, _)| (*x, *lo));
                upper.extend(lower);
                chart
                    .draw_series(std::iter::once(Polygon::new(
                        upper,
                        BLUE.mix(0.15).filled(),
                    )))
                    .map_err(drawing)?
                    .label("interval")
                    .legend(|(x, y)| {
                        Rectangle::new([(x, y - 4), (x + 16, y + 4)], BLUE.mix(0.15).filled())
                    });
            }
            for (index, (label, points)) in panel.points.iter().enumerate() {
                let color = Palette99::pick(index).to_rgba();
                chart
                    .draw_series(points.iter().map(|p| Circle::new(*p, 2, color.filled())))
                    .map_err(drawing)?
                    .label(*label)
                    .legend(move |(x, y)| Circle::new((x + 8, y), 3, color.filled()));
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

/// TAF over static torque: bites (degraded apart), thresholds, wear map curves.
fn taf_svg(
    title: &str,
    bites: &[BiteRow],
    settings: Option<&SettingsRow>,
    curves: &[Curve],
) -> anyhow::Result<String> {
    let points = |degraded: bool| -> Vec<(f64, f64)> {
        bites
            .iter()
            .filter(|b| b.degraded == degraded)
            .filter_map(|b| b.taf.map(|taf| (b.static_torque_knm, taf)))
            .collect()
    };
    let (good, degraded) = (points(false), points(true));
    let all = || {
        good.iter()
            .chain(&degraded)
            .chain(curves.iter().flat_map(|(_, c)| c.iter()))
    };
    let x_range = range(all().map(|p| p.0));
    let thresholds: Vec<(&str, f64)> = settings
        .map(|s| vec![("TAF warning", s.taf_warning), ("TAF alarm", s.taf_alarm)])
        .unwrap_or_default();
    let y_range = range(all().map(|p| p.1).chain(thresholds.iter().map(|t| t.1)));
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (PANEL.0, 450)).into_drawing_area();
        root.fill(&WHITE).map_err(drawing)?;
        let root = root.titled(title, ("sans-serif", 20)).map_err(drawing)?;
        let mut chart = ChartBuilder::on(&root)
            .margin(10)
            .x_label_area_size(35)
            .y_label_area_size(60)
            .build_cartesian_2d(x_range.0..x_range.1, y_range.0..y_range.1)
            .map_err(drawing)?;
        chart
            .configure_mesh()
            .x_desc("static torque, kN*m")
            .y_desc("TAF (peak / static)")
            .label_style(("sans-serif", 12))
            .draw()
            .map_err(drawing)?;
        for (index, (label, curve)) in curves.iter().enumerate() {
            let color = Palette99::pick(index + 5).to_rgba();
            chart
                .draw_series(LineSeries::new(curve.clone(), color.stroke_width(1)))
                .map_err(drawing)?
                .label(label.as_str())
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], color));
        }
        chart
            .draw_series(good.iter().map(|p| Circle::new(*p, 3, BLUE.filled())))
            .map_err(drawing)?
            .label("bite")
            .legend(|(x, y)| Circle::new((x + 8, y), 3, BLUE.filled()));
        chart
            .draw_series(
                degraded
                    .iter()
                    .map(|p| Circle::new(*p, 3, RGBColor(150, 150, 150))),
            )
            .map_err(drawing)?
            .label("bite, degraded window")
            .legend(|(x, y)| Circle::new((x + 8, y), 3, RGBColor(150, 150, 150)));
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

/// A labelled curve of (x, y) points.
type Curve = (String, Vec<(f64, f64)>);

/// Horizontal bars per row over time: `(row label, [(from, to, color)], [(x, marker color)])`.
type Lane = (String, Vec<(f64, f64, RGBColor)>, Vec<(f64, RGBColor)>);

fn lanes_svg(title: &str, axis: &TimeAxis, lanes: &[Lane]) -> anyhow::Result<String> {
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

/// The wear map of the driveline model at `model`, TAF over static torque for gaps of
/// 0..4 mrad over `torques` (kN*m); why not, when the file cannot be read or simulated.
fn wear_curves(model: &str, torques: (f64, f64)) -> Result<Vec<Curve>, String> {
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

fn fmt(value: Option<f64>, digits: usize) -> String {
    value.map_or_else(|| "-".to_owned(), |v| format!("{v:.digits$}"))
}

/// Quantile `q` (0..=1) of `values` (sorted here), nearest rank.
fn quantile(values: &mut [f64], q: f64) -> Option<f64> {
    values.sort_by(f64::total_cmp);
    let last = values.len().checked_sub(1)?;
    Some(values[((last as f64) * q).round() as usize])
}

/// Overlap of `[from, to)` with the axis' period, in axis units.
fn clip(axis: &TimeAxis, from: f64, to: f64) -> Option<(f64, f64)> {
    let (from, to) = (from.max(0.0), to.min(axis.span));
    (to > from).then_some((from, to))
}

/// Write the report of `args`; returns what was written.
pub fn run(args: &ReportArgs) -> anyhow::Result<String> {
    let reader = HistoryReader::open(&args.db)?;
    let since = parse_time("--since", args.since.as_deref())?;
    let until = parse_time("--until", args.until.as_deref())?;
    let window = Filter {
        since,
        until,
        ..Filter::default()
    };
    let bites = reader.bites(&window)?;
    let alarms = reader.alarms(&window)?;
    let runs = reader.runs(&Filter::default())?;
    let outages = reader.outages(&Filter {
        until,
        ..Filter::default()
    })?;
    let settings = reader.settings(&Filter::default())?;
    let wear = reader.wear(&window)?;
    let first_time = runs
        .first()
        .map(|r| r.started_at.as_str())
        .into_iter()
        .chain(bites.first().map(|b| b.time.as_str()))
        .filter_map(|t| UtcTime::parse(t).ok())
        .min();
    let start = since.or(first_time).unwrap_or_else(UtcTime::now);
    let end = until.unwrap_or_else(UtcTime::now);
    anyhow::ensure!(
        end > start,
        "--until must be after --since (or after the first event)"
    );
    let axis = TimeAxis::new(start, end);
    let config_name = runs.last().map_or("millgate", |r| r.config_name.as_str());

    let mut blocks = vec![
        Block::Heading(1, format!("Maintenance report: {config_name}")),
        Block::Text(format!(
            "History {}, {} to {} (UTC); generated {} by millgate {}.",
            args.db.display(),
            start,
            end,
            UtcTime::now(),
            env!("CARGO_PKG_VERSION")
        )),
    ];
    let state = reader.state()?;
    let mut drivelines: Vec<String> = reader.drivelines()?;
    for restored in &state.drivelines {
        if !drivelines.contains(&restored.name) {
            drivelines.push(restored.name.clone());
        }
    }
    blocks.push(Block::Heading(2, "Drivelines".into()));
    let mut summary = Vec::new();
    for name in &drivelines {
        let own: Vec<&BiteRow> = bites.iter().filter(|b| &b.driveline == name).collect();
        let mut tafs: Vec<f64> = own
            .iter()
            .filter(|b| !b.degraded)
            .filter_map(|b| b.taf)
            .collect();
        let now = state.drivelines.iter().find(|d| &d.name == name);
        summary.push(vec![
            name.clone(),
            own.len().to_string(),
            own.iter().filter(|b| b.degraded).count().to_string(),
            fmt(quantile(&mut tafs, 0.5), 3),
            fmt(quantile(&mut tafs, 0.95), 3),
            fmt(quantile(&mut tafs, 1.0), 3),
            fmt(now.and_then(|d| d.results.wear_trend), 4),
            now.map_or("-".into(), |d| {
                if d.results.taf_alarm {
                    "latched".into()
                } else {
                    "no".into()
                }
            }),
            now.map_or("-".into(), |d| d.results.bite_counter.to_string()),
        ]);
    }
    blocks.push(Block::Table(
        [
            "driveline",
            "bites",
            "degraded",
            "TAF median",
            "TAF p95",
            "TAF max",
            "wear trend now",
            "TAF alarm",
            "bite counter",
        ]
        .map(String::from)
        .to_vec(),
        summary,
    ));
    let mut written = Vec::new();
    for name in &drivelines {
        let own: Vec<BiteRow> = bites
            .iter()
            .filter(|b| &b.driveline == name)
            .cloned()
            .collect();
        let own_wear: Vec<&WearRow> = wear.iter().filter(|w| &w.driveline == name).collect();
        let setting = settings.iter().rev().find(|s| &s.driveline == name);
        blocks.push(Block::Heading(3, name.clone()));
        let at = |time: &str| axis.x(time);
        let taf_points: Vec<(f64, f64)> = own
            .iter()
            .filter_map(|b| Some((at(&b.time)?, b.taf?)))
            .collect();
        let mut panels = vec![TimePanel {
            y_label: "TAF",
            points: vec![("TAF of each bite", taf_points)],
            lines: Vec::new(),
            band: Vec::new(),
            thresholds: setting
                .map(|s| vec![("warning", s.taf_warning), ("alarm", s.taf_alarm)])
                .unwrap_or_default(),
        }];
        let index: Vec<(f64, f64)> = own_wear
            .iter()
            .filter_map(|w| Some((at(&w.time)?, w.wear_index?)))
            .collect();
        let trend: Vec<(f64, f64)> = own_wear
            .iter()
            .filter_map(|w| Some((at(&w.time)?, w.wear_trend?)))
            .collect();
        if !index.is_empty() {
            panels.push(TimePanel {
                y_label: "wear index",
                points: vec![("wear index", index)],
                lines: vec![("wear trend", trend)],
                band: Vec::new(),
                thresholds: Vec::new(),
            });
        }
        let gap: Vec<(f64, f64, f64, f64)> = own_wear
            .iter()
            .filter_map(|w| Some((at(&w.time)?, w.gap_mrad?, w.gap_low_mrad?, w.gap_high_mrad?)))
            .collect();
        if !gap.is_empty() {
            panels.push(TimePanel {
                y_label: "gap, mrad",
                points: Vec::new(),
                lines: vec![("gap estimate", gap.iter().map(|g| (g.0, g.1)).collect())],
                band: gap.iter().map(|g| (g.0, g.2, g.3)).collect(),
                thresholds: setting
                    .map(|s| {
                        [("warning", s.gap_warning_mrad), ("alarm", s.gap_alarm_mrad)]
                            .into_iter()
                            .filter_map(|(label, v)| Some((label, v?)))
                            .collect()
                    })
                    .unwrap_or_default(),
            });
        }
        let file = format!("{}-time.svg", file_stem(name));
        let title = format!("{name}: TAF, wear and gap over time");
        blocks.push(Block::Figure {
            svg: time_svg(&title, &axis, &panels)?,
            file,
            title,
        });
        if panels.len() == 1 {
            blocks.push(Block::Text(
                "No wear index: the driveline has no model (drivelines[].model).".into(),
            ));
        }
        let torques = range(own.iter().map(|b| b.static_torque_knm));
        let curves = match setting.and_then(|s| s.model.as_deref()) {
            Some(model) => match wear_curves(model, torques) {
                Ok(curves) => curves,
                Err(why) => {
                    blocks.push(Block::Text(format!("No wear map curves: {model}: {why}.")));
                    Vec::new()
                }
            },
            None => Vec::new(),
        };
        let file = format!("{}-taf.svg", file_stem(name));
        let title = format!("{name}: TAF over static torque");
        blocks.push(Block::Figure {
            svg: taf_svg(&title, &own, setting, &curves)?,
            file,
            title,
        });
    }

    blocks.push(Block::Heading(2, "Alarm timeline".into()));
    let mut subjects: Vec<String> = Vec::new();
    for alarm in &alarms {
        let lane = format!("{} {}", alarm.subject, alarm.kind);
        if !subjects.contains(&lane) {
            subjects.push(lane);
        }
    }
    let lanes: Vec<Lane> = subjects
        .iter()
        .map(|lane| {
            let own: Vec<&AlarmRow> = alarms
                .iter()
                .filter(|a| &format!("{} {}", a.subject, a.kind) == lane)
                .collect();
            let markers = own
                .iter()
                .filter_map(|a| {
                    let color = match a.event.as_str() {
                        "raised" => RED,
                        "cleared" => GREEN,
                        _ => BLUE,
                    };
                    Some((at_time(&axis, &a.time)?, color))
                })
                .collect();
            (lane.clone(), alarm_spans(&axis, &own), markers)
        })
        .collect();
    blocks.push(Block::Figure {
        svg: lanes_svg(
            "Alarms: raised (red), cleared (green), acknowledged (blue); shaded while set",
            &axis,
            &lanes,
        )?,
        file: "alarms.svg".into(),
        title: "Alarm timeline".into(),
    });
    let rows: Vec<Vec<String>> = alarms
        .iter()
        .take(ALARM_TABLE_ROWS)
        .map(|a| {
            vec![
                a.time.clone(),
                a.subject.clone(),
                a.kind.clone(),
                a.event.clone(),
                match &a.peer {
                    Some(peer) => format!("{} {peer}", a.origin),
                    None => a.origin.clone(),
                },
                fmt(a.value, 3),
            ]
        })
        .collect();
    if alarms.len() > ALARM_TABLE_ROWS {
        blocks.push(Block::Text(format!(
            "The first {ALARM_TABLE_ROWS} of {} alarm events (all are in the plot; \
             `millgate history --kind alarms` lists them all).",
            alarms.len()
        )));
    }
    blocks.push(Block::Table(
        ["time", "subject", "alarm", "event", "by", "value"]
            .map(String::from)
            .to_vec(),
        rows,
    ));

    blocks.push(Block::Heading(2, "Source availability".into()));
    let gateway_up = run_spans(&axis, &runs, &bites);
    let up: f64 = gateway_up.iter().map(|(a, b)| b - a).sum();
    blocks.push(Block::Text(format!(
        "The gateway ran {:.1}% of the period ({} runs, {} ended uncleanly).",
        100.0 * up / axis.span,
        runs.len(),
        runs.iter()
            .filter(|r| r.ended.as_deref() == Some("unclean"))
            .count()
    )));
    let mut sources: Vec<String> = Vec::new();
    for outage in &outages {
        if !sources.contains(&outage.source) {
            sources.push(outage.source.clone());
        }
    }
    let mut availability = Vec::new();
    let mut lanes: Vec<Lane> = vec![(
        "gateway running".into(),
        gateway_up
            .iter()
            .map(|(a, b)| (*a, *b, RGBColor(120, 190, 120)))
            .collect(),
        Vec::new(),
    )];
    for source in &sources {
        let own: Vec<&OutageRow> = outages.iter().filter(|o| &o.source == source).collect();
        let spans: Vec<(f64, f64, RGBColor)> = own
            .iter()
            .filter_map(|o| {
                let from = at_time(&axis, &o.started_at)?;
                let to = o
                    .ended_at
                    .as_deref()
                    .and_then(|t| at_time(&axis, t))
                    .unwrap_or(axis.span);
                let (from, to) = clip(&axis, from, to)?;
                Some((from, to, RGBColor(220, 80, 60)))
            })
            .collect();
        let down: f64 = spans.iter().map(|(a, b, _)| b - a).sum();
        availability.push(vec![
            source.clone(),
            spans.len().to_string(),
            format!("{down:.2} {}", axis.unit),
            format!(
                "{:.2}%",
                100.0 * (1.0 - down / up.max(f64::MIN_POSITIVE)).clamp(0.0, 1.0)
            ),
            own.iter().map(|o| o.blocks_missed).sum::<i64>().to_string(),
        ]);
        lanes.push((format!("{source} out"), spans, Vec::new()));
    }
    if sources.is_empty() {
        blocks.push(Block::Text(
            "No source outages recorded in the period.".into(),
        ));
    } else {
        blocks.push(Block::Table(
            [
                "source",
                "outages",
                "down",
                "available while the gateway ran",
                "blocks missed",
            ]
            .map(String::from)
            .to_vec(),
            availability,
        ));
    }
    blocks.push(Block::Figure {
        svg: lanes_svg(
            "Gateway running (green) and source outages (red)",
            &axis,
            &lanes,
        )?,
        file: "availability.svg".into(),
        title: "Source availability".into(),
    });

    std::fs::create_dir_all(&args.out)
        .map_err(|e| anyhow::anyhow!("{}: cannot create the folder: {e}", args.out.display()))?;
    let write = |name: &str, text: &str| {
        let path = args.out.join(name);
        std::fs::write(&path, text)
            .map_err(|e| anyhow::anyhow!("{}: cannot write: {e}", path.display()))
    };
    for block in &blocks {
        if let Block::Figure { file, svg, .. } = block {
            write(file, svg)?;
            written.push(file.clone());
        }
    }
    write("report.md", &markdown(&blocks))?;
    write(
        "report.html",
        &html(&format!("Maintenance report: {config_name}"), &blocks),
    )?;
    Ok(format!(
        "report written to {}: report.md, report.html, {} ({} bites, {} alarm events, {} outages)",
        args.out.display(),
        written.join(", "),
        bites.len(),
        alarms.len(),
        outages.len()
    ))
}

fn at_time(axis: &TimeAxis, time: &str) -> Option<f64> {
    axis.x(time)
}

/// Spans while a latched alarm or warning was set: from raised to cleared or
/// acknowledged (or the period's end).
fn alarm_spans(axis: &TimeAxis, alarms: &[&AlarmRow]) -> Vec<(f64, f64, RGBColor)> {
    let mut spans = Vec::new();
    let mut since: Option<f64> = None;
    for alarm in alarms {
        let Some(x) = at_time(axis, &alarm.time) else {
            continue;
        };
        match (alarm.event.as_str(), since) {
            ("raised", None) => since = Some(x),
            ("cleared" | "acknowledged", Some(from)) => {
                spans.extend(clip(axis, from, x).map(|(a, b)| (a, b, RGBColor(250, 200, 190))));
                since = None;
            }
            _ => {}
        }
    }
    if let Some(from) = since {
        spans.extend(clip(axis, from, axis.span).map(|(a, b)| (a, b, RGBColor(250, 200, 190))));
    }
    spans
}

/// When the gateway ran, in axis units: each run from its start to its stop; a run
/// that was killed to its last recorded bite.
fn run_spans(axis: &TimeAxis, runs: &[RunRow], bites: &[BiteRow]) -> Vec<(f64, f64)> {
    runs.iter()
        .filter_map(|run| {
            let from = at_time(axis, &run.started_at)?;
            let to = match (&run.stopped_at, &run.ended) {
                (Some(stopped), _) => at_time(axis, stopped)?,
                (None, None) => axis.span,
                (None, Some(_)) => bites
                    .iter()
                    .filter(|b| b.run_id == run.id)
                    .filter_map(|b| at_time(axis, &b.time))
                    .fold(from, f64::max),
            };
            clip(axis, from, to)
        })
        .collect()
}

/// A file-name-safe form of a driveline name.
fn file_stem(name: &str) -> String {
    name.chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' || c == '_' {
                c
            } else {
                '_'
            }
        })
        .collect()
}
