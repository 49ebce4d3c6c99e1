//! The outage monitor: a task that watches every source's health, signals each change
//! of a source's status (a source goes stale with no event: only time tells, so the
//! outputs learn it here, through the change signal), and records an outage from the
//! moment a source is not ok (stale or lost) until it answers again, with the blocks
//! its channels lost meanwhile. It runs with or without a history file: the alarm
//! stream carries the outages either way.
//!
//! A source that has not answered yet at start is given [`START_GRACE`] before its
//! outage is recorded (from the start): connecting takes a moment. The blocks lost are
//! read a [`PERIOD`] after the source is ok again, since a reader counts the sequence
//! gap of an outage at its first answer after it.

use std::sync::Arc;
use std::time::{Duration, Instant};

use crate::field::counters::ChannelCounters;
use crate::field::source_health::{SourceHealth, SourceStatus};
use crate::shutdown::Shutdown;

use crate::state::events::{EndedBy, HistoryEvent};
use crate::state::history::History;
use crate::state::time::UtcTime;

/// Time between health checks.
pub(crate) const PERIOD: Duration = Duration::from_millis(250);
/// Time a source may take to answer first after the gateway starts.
pub(crate) const START_GRACE: Duration = Duration::from_secs(10);

/// One source watched.
#[derive(Debug)]
pub(crate) struct WatchedSource {
    /// Its name.
    pub name: String,
    /// Its health.
    pub health: Arc<SourceHealth>,
    /// The counters of its channels (blocks missed).
    pub channels: Vec<Arc<ChannelCounters>>,
}

#[derive(Debug)]
enum Outage {
    None,
    Open {
        lost: bool,
        blocks_missed_at_start: u64,
    },
    /// Ok again since `at`; ends at the next check.
    Recovering {
        at: UtcTime,
        blocks_missed_at_start: u64,
    },
}

/// Watches the sources and records their outages.
#[derive(Debug)]
pub(crate) struct OutageMonitor {
    sources: Vec<WatchedSource>,
    history: History,
}

impl WatchedSource {
    fn blocks_missed(&self) -> u64 {
        self.channels
            .iter()
            .map(|c| c.snapshot().blocks_missed)
            .sum()
    }
}

impl OutageMonitor {
    /// A monitor of `sources` recording into `history`.
    pub(crate) fn new(sources: Vec<WatchedSource>, history: History) -> Self {
        Self { sources, history }
    }

    /// Check every [`PERIOD`] until shutdown; outages still open then are closed by
    /// the history's stop.
    pub(crate) async fn run(self, mut shutdown: Shutdown) {
        let started = Instant::now();
        let started_at = UtcTime::now();
        let mut outages: Vec<Outage> = self.sources.iter().map(|_| Outage::None).collect();
        let signal = self.history.signal();
        let mut statuses: Vec<SourceStatus> =
            self.sources.iter().map(|s| s.health.status()).collect();
        let mut ticks = tokio::time::interval(PERIOD);
        loop {
            tokio::select! {
                _ = ticks.tick() => {}
                () = shutdown.recv() => return,
            }
            let now: Vec<SourceStatus> = self.sources.iter().map(|s| s.health.status()).collect();
            if now != statuses {
                signal.results_changed();
                statuses = now;
            }
            let in_grace = started.elapsed() < START_GRACE;
            for (source, outage) in self.sources.iter().zip(&mut outages) {
                let status = source.health.status();
                let was = std::mem::replace(outage, Outage::None);
                *outage = self.next(source, was, status, (in_grace, started_at));
            }
        }
    }

    /// `source`'s outage after `outage` with the source now `status` (recording what
    /// happened); `in_grace` while the start's grace lasts, `started_at` the start.
    fn next(
        &self,
        source: &WatchedSource,
        outage: Outage,
        status: SourceStatus,
        (in_grace, started_at): (bool, UtcTime),
    ) -> Outage {
        let answered_once = source.health.connects() > 0;
        match (outage, status) {
            (Outage::None, SourceStatus::Ok) => Outage::None,
            (Outage::None, _) if in_grace && !answered_once => Outage::None,
            (Outage::None, status) => {
                self.history.record(HistoryEvent::OutageStarted {
                    time: if answered_once {
                        UtcTime::now()
                    } else {
                        started_at
                    },
                    source: source.name.clone(),
                    status: status.name(),
                });
                Outage::Open {
                    lost: status == SourceStatus::Lost,
                    blocks_missed_at_start: source.blocks_missed(),
                }
            }
            (
                Outage::Open {
                    blocks_missed_at_start,
                    ..
                },
                SourceStatus::Ok,
            ) => Outage::Recovering {
                at: UtcTime::now(),
                blocks_missed_at_start,
            },
            (
                Outage::Open {
                    lost,
                    blocks_missed_at_start,
                },
                status,
            ) => {
                let now_lost = status == SourceStatus::Lost;
                if now_lost && !lost {
                    self.history.record(HistoryEvent::OutageWorse {
                        source: source.name.clone(),
                    });
                }
                Outage::Open {
                    lost: lost || now_lost,
                    blocks_missed_at_start,
                }
            }
            (
                Outage::Recovering {
                    at,
                    blocks_missed_at_start,
                },
                SourceStatus::Ok,
            ) => {
                self.history.record(HistoryEvent::OutageEnded {
                    time: at,
                    source: source.name.clone(),
                    blocks_missed: source
                        .blocks_missed()
                        .saturating_sub(blocks_missed_at_start),
                    ended_by: EndedBy::Recovered,
                });
                Outage::None
            }
            // Lost again before the outage was closed: it goes on.
            (
                Outage::Recovering {
                    blocks_missed_at_start,
                    ..
                },
                status,
            ) => Outage::Open {
                lost: status == SourceStatus::Lost,
                blocks_missed_at_start,
            },
        }
    }
}
