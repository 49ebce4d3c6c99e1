//! The OPC UA output as the service runs it: the server fed from the board (a snapshot
//! at each change of the results) and the alarm stream (its events), and the
//! acknowledge method's action.

use std::sync::Arc;
use std::time::SystemTime;

use millgate_config::Config;
use tokio::sync::{broadcast, mpsc, watch};

use super::super::model::{AddressSpaceSpec, AlarmEventSpec, Snapshot};
use super::super::nodes::Acknowledger;
use super::CatalogueAdapter;
use crate::shutdown::Shutdown;
use crate::state::board::Board;
use crate::state::commands::{Command, CommandOrigin, CommandSender};
use crate::state::events::HistoryEvent;
use crate::state::results::Results;

/// Alarm events waiting for the server; more are dropped (counted and logged).
pub(crate) const EVENT_QUEUE: usize = 256;

/// The acknowledge method's action: clear the latched alarms, as an OPC UA client's
/// command to the analysis (which records it in the history).
pub(crate) fn acknowledger(commands: CommandSender) -> Acknowledger {
    std::sync::Arc::new(move |acknowledgement| {
        let origin = CommandOrigin::OpcUa(acknowledgement.peer);
        if let Err(error) = commands.send(Command::AcknowledgeAlarms { origin }) {
            tracing::warn!(%error, "OPC UA acknowledge not taken");
        }
    })
}

/// Where the feed sends: the snapshots, the alarm events, the grown address spaces.
struct FeedTo {
    updates: watch::Sender<Snapshot>,
    events: mpsc::Sender<AlarmEventSpec>,
    grown: mpsc::Sender<AddressSpaceSpec>,
}

impl FeedTo {
    /// A snapshot of `results` into `updates` when it differs from the last.
    fn snapshot(&self, adapter: &mut CatalogueAdapter, results: &Results) {
        let snapshot = adapter.snapshot(results, SystemTime::now());
        self.updates.send_if_modified(|current| {
            let changed = *current != snapshot;
            if changed {
                *current = snapshot;
            }
            changed
        });
    }
}

/// Feed the server until `shutdown`: a snapshot of the board into `updates` at each
/// change of the results (the server's subscriptions sample it), the alarm stream's
/// events into `events`, and for each configuration with drivelines added live
/// (`configs`, sent once the board has them) its address space into `grown`, before
/// any snapshot of it.
async fn feed(
    (mut adapter, rod_spans): (CatalogueAdapter, Vec<usize>),
    board: std::sync::Arc<Board>,
    (mut alarms, mut configs): (
        broadcast::Receiver<HistoryEvent>,
        watch::Receiver<Arc<Config>>,
    ),
    to: FeedTo,
    mut shutdown: Shutdown,
) {
    let mut changes = board.changes();
    let mut objects = adapter.event_objects();
    let mut dropped = 0u64;
    loop {
        tokio::select! {
            _ = changes.results() => to.snapshot(&mut adapter, &board.results()),
            Ok(()) = configs.changed() => {
                let config = Arc::clone(&configs.borrow_and_update());
                let (grown, spec) = adapter.grown(&config, &rod_spans);
                if to.grown.send(spec).await.is_err() {
                    break;
                }
                adapter = grown;
                objects = adapter.event_objects();
                to.snapshot(&mut adapter, &board.results());
            }
            event = alarms.recv() => {
                let event = match event {
                    Ok(event) => event,
                    Err(broadcast::error::RecvError::Lagged(missed)) => {
                        dropped += missed;
                        tracing::warn!(dropped, "OPC UA alarm events missed: the server is behind");
                        continue;
                    }
                    // The history handle outlives the service: no more events.
                    Err(broadcast::error::RecvError::Closed) => std::future::pending().await,
                };
                for spec in objects.events(&event, &board.results()) {
                    if to.events.try_send(spec).is_err() {
                        dropped += 1;
                        tracing::warn!(dropped, "OPC UA alarm event dropped: the server is behind");
                    }
                }
            }
            () = shutdown.recv() => break,
        }
    }
}

/// The OPC UA output as the service runs it: the server of `config`'s figures and the
/// feed from the board.
pub(crate) struct OpcUaOutputTask {
    server: super::super::OpcUaServer,
    adapter: CatalogueAdapter,
    rod_spans: Vec<usize>,
    board: std::sync::Arc<Board>,
    /// The alarm stream, subscribed when the output was prepared (before any event).
    alarms: broadcast::Receiver<HistoryEvent>,
    /// The configurations with drivelines added live, once the board has them.
    configs: watch::Receiver<Arc<Config>>,
}

impl std::fmt::Debug for OpcUaOutputTask {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("OpcUaOutputTask")
            .field("server", &self.server)
            .finish()
    }
}

impl OpcUaOutputTask {
    /// The OPC UA output of `config` (`None` without `[outputs.opcua]`), its rod mills
    /// having `rod_spans` spans; an error when its address space or its certificate
    /// store cannot be made. `configs` brings the configurations with drivelines added
    /// live (once the board has them): their nodes are added as the server runs.
    pub(crate) fn prepare(
        config: &Config,
        rod_spans: &[usize],
        board: std::sync::Arc<Board>,
        commands: CommandSender,
        configs: watch::Receiver<Arc<Config>>,
    ) -> Result<Option<Self>, super::super::OpcUaError> {
        let Some(settings) = &config.outputs.opcua else {
            return Ok(None);
        };
        let (adapter, spec) = CatalogueAdapter::new(config, rod_spans);
        let server =
            super::super::OpcUaServer::new(settings.clone(), spec, acknowledger(commands))?;
        let alarms = board.history().alarms();
        Ok(Some(Self {
            server,
            adapter,
            rod_spans: rod_spans.to_vec(),
            board,
            alarms,
            configs,
        }))
    }

    /// The server's counts.
    pub(crate) fn status(&self) -> super::super::OpcUaStatus {
        self.server.status()
    }

    /// Serve on `listener` and feed the server until `shutdown`; what ended the
    /// server (an error before the shutdown is a failure).
    pub(crate) async fn run(
        self,
        listener: tokio::net::TcpListener,
        shutdown: Shutdown,
    ) -> Result<(), String> {
        let Self {
            server,
            mut adapter,
            rod_spans,
            board,
            alarms,
            configs,
        } = self;
        let initial = adapter.snapshot(&board.results(), SystemTime::now());
        let (updates, updates_rx) = watch::channel(initial);
        let (events, events_rx) = mpsc::channel(EVENT_QUEUE);
        let (grown, grown_rx) = mpsc::channel(1);
        let to = FeedTo {
            updates,
            events,
            grown,
        };
        let feeding = feed(
            (adapter, rod_spans),
            board,
            (alarms, configs),
            to,
            shutdown.clone(),
        );
        let serving = server.run(listener, updates_rx, events_rx, grown_rx, shutdown);
        tokio::pin!(serving);
        let served = tokio::select! {
            served = &mut serving => served,
            () = feeding => serving.await,
        };
        served.map_err(|error| error.to_string())
    }
}
