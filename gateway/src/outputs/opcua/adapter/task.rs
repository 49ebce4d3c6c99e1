//! The OPC UA output as the service runs it: the server fed from the board (a snapshot
//! at each change of the results) and the alarm stream (its events), and the
//! acknowledge method's action.

use std::time::SystemTime;

use millgate_config::Config;
use tokio::sync::{broadcast, mpsc, watch};

use super::super::model::{AlarmEventSpec, Snapshot};
use super::super::nodes::Acknowledger;
use super::CatalogueAdapter;
use crate::shutdown::Shutdown;
use crate::state::board::Board;
use crate::state::commands::{Command, CommandOrigin, CommandSender};
use crate::state::events::HistoryEvent;

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

/// Feed the server until `shutdown`: a snapshot of the board into `updates` at each
/// change of the results (the server's subscriptions sample it), and the alarm
/// stream's events into `events`.
async fn feed(
    mut adapter: CatalogueAdapter,
    board: std::sync::Arc<Board>,
    mut alarms: broadcast::Receiver<HistoryEvent>,
    updates: watch::Sender<Snapshot>,
    events: mpsc::Sender<AlarmEventSpec>,
    mut shutdown: Shutdown,
) {
    let mut changes = board.changes();
    let mut objects = adapter.event_objects();
    let mut dropped = 0u64;
    loop {
        tokio::select! {
            _ = changes.results() => {
                let snapshot = adapter.snapshot(&board.results(), SystemTime::now());
                updates.send_if_modified(|current| {
                    let changed = *current != snapshot;
                    if changed {
                        *current = snapshot;
                    }
                    changed
                });
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
                    if events.try_send(spec).is_err() {
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
    board: std::sync::Arc<Board>,
    /// The alarm stream, subscribed when the output was prepared (before any event).
    alarms: broadcast::Receiver<HistoryEvent>,
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
    /// store cannot be made.
    pub(crate) fn prepare(
        config: &Config,
        rod_spans: &[usize],
        board: std::sync::Arc<Board>,
        commands: CommandSender,
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
            board,
            alarms,
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
            board,
            alarms,
        } = self;
        let initial = adapter.snapshot(&board.results(), SystemTime::now());
        let (updates, updates_rx) = watch::channel(initial);
        let (events, events_rx) = mpsc::channel(EVENT_QUEUE);
        let feeding = feed(adapter, board, alarms, updates, events, shutdown.clone());
        let serving = server.run(listener, updates_rx, events_rx, shutdown);
        tokio::pin!(serving);
        let served = tokio::select! {
            served = &mut serving => served,
            () = feeding => serving.await,
        };
        served.map_err(|error| error.to_string())
    }
}
