//! What the edge node sends: the births, the bites from the history (live, or the
//! backlog flagged historical), the tandem mills' capture announcements and the data,
//! each handed to the MQTT client and noted in the session's [`Confirmations`].

use std::sync::atomic::Ordering;

use rumqttc::{AsyncClient, QoS};

use super::forward::Confirmations;
use super::node::{self, CaptureNotice, EdgeNode};
use super::store::BiteSource;
use super::{now_ms, SparkplugNode, MAX_OUTSTANDING};
use crate::history::query::{BiteRow, CaptureRow, Filter};
use crate::history::HistoryError;
use crate::state::board::Board;

impl SparkplugNode {
    /// Hand `message` to the client, noting it in `confirmations` (`bite`: the row id
    /// of the bite it carries); false when the client's queue is full.
    pub(super) fn send(
        &self,
        client: &AsyncClient,
        confirmations: &mut Confirmations,
        message: node::Outgoing,
        qos: QoS,
        bite: Option<i64>,
    ) -> bool {
        match client.try_publish(message.topic, qos, false, message.payload) {
            Ok(()) => {
                confirmations.queued(bite);
                self.status.published.fetch_add(1, Ordering::Relaxed);
                true
            }
            Err(error) => {
                tracing::warn!(%error, "Sparkplug message not queued");
                false
            }
        }
    }

    pub(super) fn publish(
        &self,
        client: &AsyncClient,
        confirmations: &mut Confirmations,
        messages: Vec<node::Outgoing>,
    ) {
        for message in messages {
            self.send(client, confirmations, message, QoS::AtMostOnce, None);
        }
    }

    /// Publish the births; returns the history's last bite id: the replay ends there.
    pub(super) async fn births(
        &self,
        client: &AsyncClient,
        node: &mut EdgeNode,
        confirmations: &mut Confirmations,
        bites: &mut BiteSource,
    ) -> Option<i64> {
        let captures = newest_captures(bites, capture_subjects(&self.board)).await;
        let results = self.board.results();
        self.publish(
            client,
            confirmations,
            node.births(&results, &captures, now_ms()),
        );
        let last = bites.read(|reader| reader.last_bite_id()).await?;
        (last > confirmations.read()).then_some(last)
    }

    /// Publish the next bites of the history after the last one read, as `step` says.
    pub(super) async fn forward(
        &self,
        client: &AsyncClient,
        node: &mut EdgeNode,
        confirmations: &mut Confirmations,
        bites: &mut BiteSource,
        step: Step,
    ) {
        let (limit, until, historical) = match step {
            Step::Replay { batch, end } => (batch, Some(end), true),
            Step::Live => (MAX_OUTSTANDING, None, false),
        };
        let room = MAX_OUTSTANDING.saturating_sub(confirmations.outstanding());
        let limit = u32::try_from(limit.min(room)).unwrap_or(u32::MAX);
        if limit == 0 {
            return;
        }
        let filter = Filter {
            after_id: Some(confirmations.read()),
            limit: Some(limit),
            ..Filter::default()
        };
        // The bites and their captures, in one read.
        let read = bites
            .read(move |reader| {
                let rows = reader.bites(&filter)?;
                let captures = match (rows.first(), rows.last()) {
                    (Some(first), Some(last)) => reader.bite_captures(first.id, last.id)?,
                    _ => Vec::new(),
                };
                Ok((rows, captures))
            })
            .await;
        let Some((rows, captures)) = read else {
            return;
        };
        let results = self.board.results();
        let names = self.board.driveline_names();
        for row in rows
            .iter()
            .take_while(|row| until.is_none_or(|end| row.id <= end))
        {
            if let Some(index) = names.iter().position(|name| *name == row.driveline) {
                let capture = captures
                    .iter()
                    .find(|c| c.bite_id == Some(row.id))
                    .map(capture_notice);
                let message =
                    self.bite_message(node, index, row, &results, (historical, capture.as_ref()));
                if !self.send(
                    client,
                    confirmations,
                    message,
                    QoS::AtLeastOnce,
                    Some(row.id),
                ) {
                    break;
                }
                let counter = if historical {
                    &self.status.replayed
                } else {
                    &self.status.bites
                };
                counter.fetch_add(1, Ordering::Relaxed);
            }
            confirmations.read_up_to(row.id);
        }
        if let (Some(end), true) = (until, rows.is_empty()) {
            // Nothing left up to `end`: the retention deleted the rest meanwhile.
            confirmations.read_up_to(end);
        }
    }

    /// Announce on its tandem mill's device each capture of a tandem mill stored
    /// after `cursor` (at the first call, the newest capture's id: the births carry
    /// the older ones), at most [`MAX_OUTSTANDING`] per call.
    pub(super) async fn announce_mill_captures(
        &self,
        client: &AsyncClient,
        node: &mut EdgeNode,
        confirmations: &mut Confirmations,
        bites: &mut BiteSource,
        cursor: &mut Option<i64>,
    ) {
        let mills = self.board.tandem_mill_names().to_vec();
        if mills.is_empty() {
            return;
        }
        let after = *cursor;
        let limit = u32::try_from(MAX_OUTSTANDING).unwrap_or(u32::MAX);
        let read = bites
            .read(move |reader| match after {
                None => {
                    let newest = reader.newest::<CaptureRow>(&Filter {
                        limit: Some(1),
                        ..Filter::default()
                    })?;
                    Ok((newest.first().map_or(0, |row| row.id), Vec::new()))
                }
                Some(after) => {
                    let rows = reader.rows::<CaptureRow>(&Filter {
                        after_id: Some(after),
                        limit: Some(limit),
                        ..Filter::default()
                    })?;
                    Ok((rows.last().map_or(after, |row| row.id), rows))
                }
            })
            .await;
        let Some((last, rows)) = read else {
            return;
        };
        *cursor = Some(last);
        for row in rows {
            if let Some(mill) = mills.iter().position(|name| *name == row.subject) {
                let message = node.mill_capture(mill, &capture_notice(&row), now_ms());
                self.send(client, confirmations, message, QoS::AtMostOnce, None);
            }
        }
    }

    /// The DDATA of the bite `row` of driveline `index`: live with the results' values
    /// when they are still this bite's (with the flags of the moment), else from the
    /// row.
    fn bite_message(
        &self,
        node: &mut EdgeNode,
        index: usize,
        row: &BiteRow,
        results: &crate::state::results::Results,
        (historical, capture): (bool, Option<&CaptureNotice>),
    ) -> node::Outgoing {
        let time = row
            .figures
            .last_bite_unix_ms
            .and_then(|ms| u64::try_from(ms).ok())
            .unwrap_or_else(now_ms);
        let current = results
            .drivelines
            .get(index)
            .filter(|live| !historical && live.bite_counter == row.figures.bite_counter);
        // What a bite row keeps: the catalogue's figures with a bite column.
        let recorded: Vec<&str> = crate::state::catalogue::DRIVELINE
            .iter()
            .filter(|figure| figure.columns.bite.is_some())
            .map(|figure| figure.key)
            .collect();
        match current {
            Some(live) => node.bite(index, live, time, (None, false), capture),
            None => node.bite(
                index,
                &crate::history::query::trusted(row),
                time,
                (Some(&recorded), historical),
                capture,
            ),
        }
    }
}

/// Which bites [`SparkplugNode::forward`] publishes.
#[derive(Debug, Clone, Copy)]
pub(super) enum Step {
    /// The backlog: at most `batch` bites, none after row `end`, flagged historical.
    Replay { batch: usize, end: i64 },
    /// What was recorded after the backlog, live.
    Live,
}

/// A capture row as the node announces it.
fn capture_notice(row: &CaptureRow) -> CaptureNotice {
    let count = |v: i64| u64::try_from(v).unwrap_or(0);
    CaptureNotice {
        id: count(row.id),
        kind: row.kind.clone(),
        samples: count(row.samples),
        first_sample_ms: count(row.first_sample_unix_ns / 1_000_000),
        span_s: row.duration_s,
        bytes: count(row.bytes),
    }
}

/// The names whose newest capture the births carry: the drivelines', then the
/// tandem mills', in order.
pub(super) fn capture_subjects(board: &Board) -> Vec<String> {
    let mut names = board.driveline_names().to_vec();
    names.extend_from_slice(board.tandem_mill_names());
    names
}

/// The newest capture of each driveline or tandem mill (`names`, in order) in the
/// history, for the births; none where the file cannot be read.
pub(super) async fn newest_captures(
    bites: &mut BiteSource,
    names: Vec<String>,
) -> Vec<Option<CaptureNotice>> {
    let count = names.len();
    bites
        .read(move |reader| {
            names
                .into_iter()
                .map(|name| {
                    let filter = Filter {
                        name: Some(name),
                        limit: Some(1),
                        ..Filter::default()
                    };
                    Ok(reader
                        .newest::<CaptureRow>(&filter)?
                        .first()
                        .map(capture_notice))
                })
                .collect::<Result<Vec<_>, HistoryError>>()
        })
        .await
        .unwrap_or_else(|| vec![None; count])
}
