//! The report's alarm timeline: a lane per subject and alarm with its events and the
//! spans while it was set, and the table of the alarm events.

use plotters::prelude::*;

use super::document::{fmt, Block};
use super::period::Period;
use super::plots::{lanes_svg, Lane};
use super::spans::{alarm_spans, at_time};
use crate::history::query::AlarmRow;

/// Alarm rows listed in the report's table (all are in the timeline plot).
const ALARM_TABLE_ROWS: usize = 200;

/// The alarm timeline's heading, plot and table.
pub(super) fn alarms(period: &Period, blocks: &mut Vec<Block>) -> anyhow::Result<()> {
    blocks.push(Block::Heading(2, "Alarm timeline".into()));
    blocks.push(Block::Figure {
        svg: lanes_svg(
            "Alarms: raised (red), cleared (green), acknowledged (blue); shaded while set",
            &period.axis,
            &lanes(period),
        )?,
        file: "alarms.svg".into(),
        title: "Alarm timeline".into(),
    });
    table(&period.alarms, blocks);
    Ok(())
}

/// A lane per subject and alarm, in the order they first appear: its events marked
/// (raised red, cleared green, acknowledged blue), shaded while set.
fn lanes(period: &Period) -> Vec<Lane> {
    let alarms = &period.alarms;
    let mut subjects: Vec<String> = Vec::new();
    for alarm in alarms {
        let lane = format!("{} {}", alarm.subject, alarm.kind);
        if !subjects.contains(&lane) {
            subjects.push(lane);
        }
    }
    subjects
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
                    Some((at_time(&period.axis, &a.time)?, color))
                })
                .collect();
            (lane.clone(), alarm_spans(&period.axis, &own), markers)
        })
        .collect()
}

/// The first [`ALARM_TABLE_ROWS`] alarm events as a table (and a note when there are
/// more).
fn table(alarms: &[AlarmRow], blocks: &mut Vec<Block>) {
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
}
