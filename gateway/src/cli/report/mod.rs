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
//!
//! The module's files follow its jobs: `document` (the document model, Markdown and
//! HTML), `plots` (the SVG plots), `spans` (run and alarm spans on the time axis);
//! this file reads the history and assembles the report.

mod document;
mod plots;
mod spans;

use std::path::PathBuf;

use plotters::prelude::*;

pub use document::{html, markdown, Block};
use plots::{lanes_svg, range, taf_svg, time_svg, wear_curves, Lane, TimeAxis, TimePanel};
use spans::{alarm_spans, at_time, clip, run_spans};

use crate::cli::history::parse_time;
use crate::outputs::history::query::{
    AlarmRow, BiteRow, Filter, HistoryReader, OutageRow, WearRow,
};
use crate::outputs::history::time::UtcTime;

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

fn fmt(value: Option<f64>, digits: usize) -> String {
    value.map_or_else(|| "-".to_owned(), |v| format!("{v:.digits$}"))
}

/// Quantile `q` (0..=1) of `values` (sorted here), nearest rank.
fn quantile(values: &mut [f64], q: f64) -> Option<f64> {
    values.sort_by(f64::total_cmp);
    let last = values.len().checked_sub(1)?;
    Some(values[((last as f64) * q).round() as usize])
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
                if d.results.alarm {
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
