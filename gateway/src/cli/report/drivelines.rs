//! The report's drivelines: each one's part read ([`read`]), the summary table of
//! all, and per driveline its section: the plot over time, the TAF over static torque
//! and the captured traces of its last alarm bites.

use std::path::Path;

use super::data::{self, DrivelineData};
use super::document::{fmt, Block};
use super::period::Period;
use super::plots::{taf_svg, time_svg, trace_svg, TimePanel};
use crate::cli::progress::Progress;
use crate::history::query::HistoryReader;
use crate::state::time::UtcTime;

/// Alarm bites whose captured trace the report draws, per driveline: the newest.
pub const ALARM_TRACES: u32 = 5;

/// The part of each of the period's drivelines, in order, showing how far on
/// `progress`.
pub(super) fn read(
    reader: &HistoryReader,
    period: &Period,
    progress: &mut Progress,
) -> anyhow::Result<Vec<DrivelineData>> {
    let mut read = Vec::with_capacity(period.drivelines.len());
    for (index, name) in period.drivelines.iter().enumerate() {
        let of = period.drivelines.len();
        progress.update(|| format!("report: {name} ({} of {of})", index + 1));
        let setting = period.setting(name);
        read.push(data::read(
            reader,
            name,
            period.since,
            period.until,
            setting,
            progress,
        )?);
    }
    Ok(read)
}

/// The drivelines' heading and summary table: per driveline, its bites, TAF, state
/// now and gap.
pub(super) fn summary(period: &Period, read: &[DrivelineData], blocks: &mut Vec<Block>) {
    blocks.push(Block::Heading(2, "Drivelines".into()));
    blocks.push(Block::Text(
        "TAF figures are of clean windows (degraded ones left out); \"now\" is the \
         state a restart would restore; the gap is the last estimate in the period \
         with its 90% interval and coupling (model index, 0 = motor side), its trend \
         the least-squares slope over the four weeks before the period's end."
            .into(),
    ));
    let rows = period
        .drivelines
        .iter()
        .zip(read)
        .map(|(name, data)| summary_row(period, name, data))
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
        rows,
    ));
}

/// Driveline `name`'s row of the summary table, from its `data`.
fn summary_row(period: &Period, name: &str, data: &DrivelineData) -> Vec<String> {
    let now = period.state.drivelines.iter().find(|d| d.name == name);
    let gap = data.last.as_ref().and_then(|b| b.figures.gap);
    vec![
        name.to_owned(),
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
}

/// Driveline `name`'s section, from its `data`: the plot over time, the TAF over
/// static torque, the captured traces of its last alarm bites (read by `reader` from
/// the history `db`).
pub(super) fn section(
    reader: &HistoryReader,
    db: &Path,
    period: &Period,
    (name, data): (&str, &DrivelineData),
    blocks: &mut Vec<Block>,
) -> anyhow::Result<()> {
    blocks.push(Block::Heading(3, name.to_owned()));
    over_time(period, name, data, blocks)?;
    taf_over_torque(name, data, blocks)?;
    alarm_traces(reader, db, period, name, blocks)
}

/// The plot of `name`'s TAF, wear and gap over time, with what it shows.
fn over_time(
    period: &Period,
    name: &str,
    data: &DrivelineData,
    blocks: &mut Vec<Block>,
) -> anyhow::Result<()> {
    let file = format!("{}-time.svg", file_stem(name));
    let title = format!("{name}: TAF, wear and gap over time");
    blocks.push(Block::Figure {
        svg: time_svg(&title, &period.axis, &time_panels(period, data))?,
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
    Ok(())
}

/// The panels of a driveline's plot over time: the TAF, the wear index (with a
/// model) and the gap estimate (when the history holds the gap diagnosis).
fn time_panels(period: &Period, data: &DrivelineData) -> Vec<TimePanel<'static>> {
    let setting = data.setting.as_ref();
    let middle = |start: UtcTime, end: UtcTime| period.axis.middle(start, end);
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
    panels
}

/// The plot of `name`'s bites' TAF over static torque, with the wear map's curves
/// (or why there are none).
fn taf_over_torque(
    name: &str,
    data: &DrivelineData,
    blocks: &mut Vec<Block>,
) -> anyhow::Result<()> {
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
        svg: taf_svg(&title, &data.grid, data.setting.as_ref(), curves)?,
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
    Ok(())
}

/// The captured traces of `name`'s last [`ALARM_TRACES`] alarm bites in the period,
/// read one capture at a time from the history `db`.
fn alarm_traces(
    reader: &HistoryReader,
    db: &Path,
    period: &Period,
    name: &str,
    blocks: &mut Vec<Block>,
) -> anyhow::Result<()> {
    let rows = reader.alarm_bite_captures(name, period.since, period.until, ALARM_TRACES)?;
    if rows.is_empty() {
        return Ok(());
    }
    blocks.push(Block::Text(format!(
        "The captured torque of the last {} alarm bites (at most {ALARM_TRACES} per \
         driveline, newest first), each reduced to the lowest and highest sample of \
         450 columns; `millgate capture export --db {} --id ID --format csv --out DIR` \
         (or `parquet`) writes a capture's samples.",
        rows.len(),
        db.display()
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
            svg: trace_svg(&title, &capture)?,
            file: format!("{}-capture-{id}.svg", file_stem(name)),
            title,
        });
    }
    Ok(())
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
