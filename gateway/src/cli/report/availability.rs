//! The report's source availability: when the gateway ran (and when the file cannot
//! tell), each source's outages as a table and all of it on one plot.

use plotters::prelude::*;

use super::document::Block;
use super::period::Period;
use super::plots::{lanes_svg, Lane};
use super::spans::{at_time, clip, run_spans, RunSpans};
use crate::history::query::{HistoryReader, OutageRow};

/// The source availability's heading, text, table and plot, the gateway's runs read
/// by `reader`.
pub(super) fn sources(
    reader: &HistoryReader,
    period: &Period,
    blocks: &mut Vec<Block>,
) -> anyhow::Result<()> {
    blocks.push(Block::Heading(2, "Source availability".into()));
    let gateway = run_spans(reader, &period.axis, &period.runs)?;
    let up = total(&gateway.up);
    blocks.push(Block::Text(running_text(period, &gateway)));
    let mut lanes: Vec<Lane> = vec![running_lane(&gateway)];
    let mut availability = Vec::new();
    for source in outage_sources(&period.outages) {
        let (row, lane) = source_outages(period, &source, up);
        availability.push(row);
        lanes.push(lane);
    }
    if availability.is_empty() {
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
            &period.axis,
            &lanes,
        )?,
        file: "availability.svg".into(),
        title: "Source availability".into(),
    });
    Ok(())
}

/// The length of `spans` together, axis units.
fn total(spans: &[(f64, f64)]) -> f64 {
    spans.iter().map(|(a, b)| b - a).sum::<f64>()
}

/// How long the gateway ran in the period, and how long the file cannot tell.
fn running_text(period: &Period, gateway: &RunSpans) -> String {
    let span = period.axis.span;
    let (up, unknown) = (total(&gateway.up), total(&gateway.unknown));
    let runs = &period.runs;
    let mut text = format!(
        "The gateway ran {:.1}% of the period ({} runs, {} ended uncleanly).",
        100.0 * up / span,
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
            100.0 * unknown / span
        ));
    }
    text
}

/// The lane of the gateway's runs: running green, unknown grey.
fn running_lane(gateway: &RunSpans) -> Lane {
    (
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
    )
}

/// The sources with outages, in the order of their first.
fn outage_sources(outages: &[OutageRow]) -> Vec<String> {
    let mut sources: Vec<String> = Vec::new();
    for outage in outages {
        if !sources.contains(&outage.source) {
            sources.push(outage.source.clone());
        }
    }
    sources
}

/// The outages of `source` in the period: its table row (the gateway ran `up` axis
/// units) and its lane.
fn source_outages(period: &Period, source: &str, up: f64) -> (Vec<String>, Lane) {
    let axis = &period.axis;
    let own: Vec<&OutageRow> = period
        .outages
        .iter()
        .filter(|o| o.source == source)
        .collect();
    let spans: Vec<(f64, f64, RGBColor)> = own
        .iter()
        .filter_map(|o| {
            let from = at_time(axis, &o.started_at)?;
            let to = o
                .ended_at
                .as_deref()
                .and_then(|t| at_time(axis, t))
                .unwrap_or(axis.span);
            let (from, to) = clip(axis, from, to)?;
            Some((from, to, RGBColor(220, 80, 60)))
        })
        .collect();
    let down: f64 = spans.iter().map(|(a, b, _)| b - a).sum();
    let row = vec![
        source.to_owned(),
        spans.len().to_string(),
        format!("{down:.2} {}", axis.unit),
        format!(
            "{:.2}%",
            100.0 * (1.0 - down / up.max(f64::MIN_POSITIVE)).clamp(0.0, 1.0)
        ),
        own.iter().map(|o| o.blocks_missed).sum::<i64>().to_string(),
    ];
    (row, (format!("{source} out"), spans, Vec::new()))
}
