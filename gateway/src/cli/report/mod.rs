//! `millgate report`: a maintenance report from the event history.
//!
//! ```text
//! millgate report --db FILE --out DIR [--since T] [--until T]
//! ```
//!
//! Writes into `DIR`: `report.md` (plots linked), `report.html` (one file that opens
//! offline, plots inline) and the SVG plots, each reduced to what a reader can see
//! (a year of bites is a million per driveline):
//! - per driveline `<name>-time.svg`: in 450 time buckets (the web page's
//!   [`wear_series`]), the TAF's range and mean with its warning and alarm
//!   thresholds; the wear index's range and the wear trend; the gap estimate with
//!   its interval and thresholds when the history holds the gap diagnosis;
//! - per driveline `<name>-taf.svg`: TAF over static torque, the bites binned into
//!   180 x 90 cells shaded by count (degraded windows grey), with the thresholds and,
//!   when the driveline's model file (as configured) can be read, the wear map's
//!   curves for gaps of 0..4 mrad over the measured torque range;
//! - per driveline `<name>-capture-<id>.svg`: the captured torque of each of its last
//!   [`ALARM_TRACES`] alarm bites in the period (newest first; the history keeps
//!   alarm bites' captures longest), reduced to 450 columns of lowest and highest
//!   samples with the trigger marked, each with the capture's id and the
//!   `millgate capture export` command that writes its samples;
//! - `alarms.svg`: the alarm timeline (raised, cleared, acknowledged; latched spans);
//! - `availability.svg`: when the gateway ran (and, for a run without a recorded
//!   stop, from its last recorded event on, that the file cannot tell), each
//!   source's outages.
//!
//! The Markdown and the HTML come from one document model ([`Block`]). Bites are
//! never held: counted and aggregated by SQLite or binned as they are read, so the
//! memory is that of the buckets and cells; progress goes to stderr when it is a
//! terminal.
//!
//! The module's files follow its jobs: `data` (what is read of a driveline),
//! `document` (the document model, Markdown and HTML), `plots` (the SVG plots and the
//! binning of bites), `spans` (run and alarm spans on the time axis); this file
//! assembles the report.
//!
//! [`wear_series`]: crate::history::query::HistoryReader::wear_series

mod data;
mod document;
mod plots;
mod spans;

use std::path::PathBuf;

use plotters::prelude::*;

pub use document::{html, markdown, Block};
use plots::{lanes_svg, taf_svg, time_svg, Lane, TimeAxis, TimePanel};
use spans::{alarm_spans, at_time, clip, run_spans};

use crate::cli::history::parse_time;
use crate::cli::progress::Progress;
use crate::history::query::{AlarmRow, Filter, HistoryReader, OutageRow};
use crate::state::time::UtcTime;

/// Alarm rows listed in the report's table (all are in the timeline plot).
const ALARM_TABLE_ROWS: usize = 200;

/// Alarm bites whose captured trace the report draws, per driveline: the newest.
pub const ALARM_TRACES: u32 = 5;

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

/// Write the report of `args`; returns what was written.
///
/// Memory: the report holds the alarms, runs and outages of the period (a few
/// thousand rows a year) and, per driveline, its buckets and cells, never its bites:
/// those are counted, aggregated and binned by SQLite or as they are read.
pub fn run(args: &ReportArgs) -> anyhow::Result<String> {
    let reader = HistoryReader::open(&args.db)?;
    let since = parse_time("--since", args.since.as_deref())?;
    let until = parse_time("--until", args.until.as_deref())?;
    let mut progress = Progress::on_terminal();
    let window = Filter {
        since,
        until,
        ..Filter::default()
    };
    let alarms = reader.alarms(&window)?;
    let runs = reader.runs(&Filter::default())?;
    let outages = reader.outages(&Filter {
        until,
        ..Filter::default()
    })?;
    let settings = reader.settings(&Filter::default())?;
    let state = reader.state()?;
    let mut drivelines: Vec<String> = reader.drivelines()?;
    for restored in &state.drivelines {
        if !drivelines.contains(&restored.name) {
            drivelines.push(restored.name.clone());
        }
    }
    let mut first_bite = None;
    for name in &drivelines {
        if let Some((first, _)) = reader.bite_span(name)? {
            first_bite = first_bite.min(Some(first)).or(Some(first));
        }
    }
    let first_time = runs
        .first()
        .and_then(|r| UtcTime::parse(&r.started_at).ok())
        .into_iter()
        .chain(first_bite)
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
    let mut read = Vec::new();
    for (index, name) in drivelines.iter().enumerate() {
        progress.update(|| format!("report: {name} ({} of {})", index + 1, drivelines.len()));
        let setting = settings
            .iter()
            .rev()
            .find(|s| &s.driveline == name)
            .cloned();
        read.push(data::read(
            &reader,
            name,
            since,
            until,
            setting,
            &mut progress,
        )?);
    }
    blocks.push(Block::Heading(2, "Drivelines".into()));
    blocks.push(Block::Text(
        "TAF figures are of clean windows (degraded ones left out); \"now\" is the \
         state a restart would restore; the gap is the last estimate in the period \
         with its 90% interval and coupling (model index, 0 = motor side), its trend \
         the least-squares slope over the four weeks before the period's end."
            .into(),
    ));
    let summary: Vec<Vec<String>> = drivelines
        .iter()
        .zip(&read)
        .map(|(name, data)| {
            let now = state.drivelines.iter().find(|d| &d.name == name);
            let gap = data.last.as_ref().and_then(|b| b.figures.gap);
            vec![
                name.clone(),
                data.summary.bites.to_string(),
                data.summary.degraded.to_string(),
                fmt(data.summary.taf_median, 3),
                fmt(data.summary.taf_p95, 3),
                fmt(data.summary.taf_max, 3),
                fmt(now.and_then(|d| d.results.wear_trend), 4),
                now.map_or("-".into(), |d| {
                    if d.results.taf_alarm {
                        "latched".into()
                    } else {
                        "no".into()
                    }
                }),
                now.map_or("-".into(), |d| d.results.bite_counter.to_string()),
                fmt(gap.map(|g| g.gap_mrad), 2),
                gap.map_or("-".into(), |g| {
                    format!(
                        "{}..{}",
                        fmt(Some(g.low_mrad), 2),
                        fmt(Some(g.high_mrad), 2)
                    )
                }),
                gap.map_or("-".into(), |g| {
                    g.coupling
                        .map_or_else(|| "undetermined".into(), |c| c.to_string())
                }),
                data.trend
                    .as_ref()
                    .map_or("-".into(), |t| format!("{:+.3}", t.mrad_per_week)),
            ]
        })
        .collect();
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
            "gap, mrad",
            "90% interval, mrad",
            "coupling",
            "gap trend, mrad/week",
        ]
        .map(String::from)
        .to_vec(),
        summary,
    ));
    let mut written = Vec::new();
    for (name, data) in drivelines.iter().zip(&read) {
        blocks.push(Block::Heading(3, name.clone()));
        let setting = data.setting.as_ref();
        let middle = |start: UtcTime, end: UtcTime| axis.middle(start, end);
        let mut panels = vec![TimePanel {
            y_label: "TAF",
            lines: vec![(
                "TAF mean",
                data.wear
                    .iter()
                    .filter_map(|p| Some((middle(p.start, p.end), p.taf_mean?)))
                    .collect(),
            )],
            band_label: "TAF min..max",
            band: data
                .wear
                .iter()
                .filter_map(|p| Some((middle(p.start, p.end), p.taf_min?, p.taf_max?)))
                .collect(),
            thresholds: setting
                .map(|s| vec![("warning", s.taf_warning), ("alarm", s.taf_alarm)])
                .unwrap_or_default(),
        }];
        if !data.index.is_empty() {
            panels.push(TimePanel {
                y_label: "wear index",
                lines: vec![(
                    "wear trend",
                    data.index
                        .iter()
                        .filter_map(|p| Some((middle(p.start, p.end), p.trend?)))
                        .collect(),
                )],
                band_label: "wear index min..max",
                band: data
                    .index
                    .iter()
                    .map(|p| (middle(p.start, p.end), p.index_min, p.index_max))
                    .collect(),
                thresholds: Vec::new(),
            });
        }
        let gap: Vec<(f64, f64, f64, f64)> = data
            .wear
            .iter()
            .filter_map(|p| {
                Some((
                    middle(p.start, p.end),
                    p.gap_mrad?,
                    p.gap_low_mrad?,
                    p.gap_high_mrad?,
                ))
            })
            .collect();
        if !gap.is_empty() {
            panels.push(TimePanel {
                y_label: "gap, mrad",
                lines: vec![("gap estimate", gap.iter().map(|g| (g.0, g.1)).collect())],
                band_label: "90% interval (lowest..highest)",
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
        if let Some(bucket) = data.wear.first() {
            blocks.push(Block::Text(format!(
                "Per time bucket of {}: the range of the bites' values shaded, the mean \
                 TAF, the wear trend and the gap estimate after the bucket's last bite.",
                duration_text(bucket.end.unix_ms() - bucket.start.unix_ms())
            )));
        }
        if data.index.is_empty() {
            blocks.push(Block::Text(
                "No wear index: the driveline has no model (drivelines[].model).".into(),
            ));
        }
        let curves = match &data.curves {
            Ok(curves) => curves.as_slice(),
            Err(why) => {
                blocks.push(Block::Text(format!("No wear map curves: {why}.")));
                &[]
            }
        };
        let file = format!("{}-taf.svg", file_stem(name));
        let title = format!("{name}: TAF over static torque");
        blocks.push(Block::Figure {
            svg: taf_svg(&title, &data.grid, setting, curves)?,
            file,
            title,
        });
        if data.grid.outside > 0 {
            blocks.push(Block::Text(format!(
                "{} bites lie outside the plot (a degraded window's TAF beyond the clean \
                 bites' range).",
                data.grid.outside
            )));
        }
        alarm_traces(&reader, args, name, (since, until), &mut blocks)?;
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
    let gateway = run_spans(&reader, &axis, &runs)?;
    let total = |spans: &[(f64, f64)]| spans.iter().map(|(a, b)| b - a).sum::<f64>();
    let (up, unknown) = (total(&gateway.up), total(&gateway.unknown));
    let mut text = format!(
        "The gateway ran {:.1}% of the period ({} runs, {} ended uncleanly).",
        100.0 * up / axis.span,
        runs.len(),
        runs.iter()
            .filter(|r| r.ended.as_deref() == Some("unclean"))
            .count()
    );
    if gateway.open > 0 {
        text.push_str(&format!(
            " {} run(s) have no recorded stop (killed, their power cut, or still \
             running): each counts as running until its last recorded event; from \
             there to the next start or the period's end, {:.1}% of the period, the \
             file cannot tell whether it ran (grey).",
            gateway.open,
            100.0 * unknown / axis.span
        ));
    }
    blocks.push(Block::Text(text));
    let mut sources: Vec<String> = Vec::new();
    for outage in &outages {
        if !sources.contains(&outage.source) {
            sources.push(outage.source.clone());
        }
    }
    let mut availability = Vec::new();
    let mut lanes: Vec<Lane> = vec![(
        "gateway running".into(),
        gateway
            .up
            .iter()
            .map(|(a, b)| (*a, *b, RGBColor(120, 190, 120)))
            .chain(
                gateway
                    .unknown
                    .iter()
                    .map(|(a, b)| (*a, *b, RGBColor(190, 190, 190))),
            )
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
    let bites: u64 = read.iter().map(|d| d.summary.bites).sum();
    progress.finish(&format!(
        "report: {} drivelines, {bites} bites in {:.1} s",
        drivelines.len(),
        progress.elapsed_s()
    ));
    Ok(format!(
        "report written to {}: report.md, report.html, {} ({bites} bites, {} alarm events, {} outages)",
        args.out.display(),
        written.join(", "),
        alarms.len(),
        outages.len()
    ))
}

/// `ms` as a duration a reader takes in: "6 h", "2.5 days", "40 s".
fn duration_text(ms: i64) -> String {
    let s = ms as f64 / 1000.0;
    match s {
        s if s < 120.0 => format!("{s:.0} s"),
        s if s < 7200.0 => format!("{:.0} min", s / 60.0),
        s if s < 172_800.0 => format!("{:.1} h", s / 3600.0),
        s => format!("{:.1} days", s / 86_400.0),
    }
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

/// The captured traces of `name`'s last [`ALARM_TRACES`] alarm bites in `period`,
/// read one capture at a time.
fn alarm_traces(
    reader: &HistoryReader,
    args: &ReportArgs,
    name: &str,
    (since, until): (Option<UtcTime>, Option<UtcTime>),
    blocks: &mut Vec<Block>,
) -> anyhow::Result<()> {
    let rows = reader.alarm_bite_captures(name, since, until, ALARM_TRACES)?;
    if rows.is_empty() {
        return Ok(());
    }
    blocks.push(Block::Text(format!(
        "The captured torque of the last {} alarm bites (at most {ALARM_TRACES} per \
         driveline, newest first), each reduced to the lowest and highest sample of \
         450 columns; `millgate capture export --db {} --id ID --format csv --out DIR` \
         (or `parquet`) writes a capture's samples.",
        rows.len(),
        args.db.display()
    )));
    for row in rows {
        let (id, bite, time) = (row.id, row.bite_counter, row.bite_time.clone());
        let capture = reader.capture_of(row)?;
        let title = format!(
            "{name}: alarm bite {} at {} UTC, capture {id}",
            bite.map_or("-".into(), |b| b.to_string()),
            time.unwrap_or_default()
        );
        blocks.push(Block::Figure {
            svg: plots::trace_svg(&title, &capture)?,
            file: format!("{}-capture-{id}.svg", file_stem(name)),
            title,
        });
    }
    Ok(())
}
