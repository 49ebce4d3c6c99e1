//! A service running in its own task: what `main`, tests, the demo and benchmarks use to
//! watch it and stop it.

use std::path::Path;
use std::sync::Arc;

use tokio::sync::{broadcast, mpsc, oneshot, watch};
use tokio::task::JoinHandle;

use super::error::ServiceError;
use super::reload::Reload;
use super::{Bound, ReloadRequest, Service};
use crate::analysis::driveline::BiteReport;
use crate::field::counters::ChannelCounters;
use crate::outputs::modbus::register_map::RegisterMap;
use crate::shutdown::{self, ShutdownTrigger};
use crate::state::board::Board;
use crate::state::commands::CommandSender;
use crate::state::history::History;
use crate::supervision::Liveness;

/// A service running in its own task, started by [`Service::spawn`]: what `main`,
/// tests, the demo and benchmarks need to watch it and stop it.
#[derive(Debug)]
pub struct RunningService {
    bound: Bound,
    board: Arc<Board>,
    map: Arc<RegisterMap>,
    commands: CommandSender,
    counters: Vec<Arc<ChannelCounters>>,
    history: History,
    bites: broadcast::Receiver<BiteReport>,
    liveness: Arc<Liveness>,
    plc_attempted: watch::Receiver<bool>,
    opcua: Option<crate::outputs::opcua::OpcUaStatus>,
    reloads: mpsc::Sender<ReloadRequest>,
    stop: ShutdownTrigger,
    /// The service's task, until its outcome was taken.
    task: Option<JoinHandle<Result<(), ServiceError>>>,
    /// The task's outcome, when [`RunningService::ready`] saw it end.
    ended: Option<Result<(), ServiceError>>,
}

impl Service {
    /// Bind the listening outputs, then run in a new tokio task until
    /// [`RunningService::stop`]. Every bite analysed after this call is queued for
    /// [`RunningService::bites`] (the last 64 when nobody reads them).
    pub async fn spawn(mut self) -> Result<RunningService, ServiceError> {
        let bound = self.bind().await?;
        let board = self.board();
        let commands = self.commands();
        let map = self.register_map();
        let counters = self.counters();
        let history = self.history();
        let bites = self.subscribe_bites();
        let liveness = Arc::clone(&self.liveness);
        let plc_attempted = self.plc_attempted.subscribe();
        let opcua = self.opcua.as_ref().map(|opcua| opcua.status());
        let reloads = self.reloads.0.clone();
        let (stop, shutdown) = shutdown::channel();
        let task = tokio::spawn(self.run(shutdown));
        Ok(RunningService {
            bound,
            board,
            map,
            commands,
            counters,
            history,
            bites,
            liveness,
            plc_attempted,
            opcua,
            reloads,
            stop,
            task: Some(task),
            ended: None,
        })
    }
}

impl RunningService {
    /// The addresses the listening outputs bound (ports the OS chose for `:0`).
    pub fn bound(&self) -> Bound {
        self.bound
    }

    /// The OPC UA server's counts, with `[outputs.opcua]`.
    pub fn opcua(&self) -> Option<crate::outputs::opcua::OpcUaStatus> {
        self.opcua.clone()
    }

    /// Reload the configuration file at `path` as SIGHUP does: the service applies
    /// what it can without a restart, logs and counts the outcome
    /// ([`super::reload`]); the outcome, once the service has handled it (requests
    /// made before the service runs wait for it). `None` when the service ended first.
    /// Dropping the future leaves the request with the service.
    pub fn reload(&self, path: &Path) -> impl std::future::Future<Output = Option<Reload>> {
        let reloads = self.reloads.clone();
        let (reply, outcome) = oneshot::channel();
        let request = ReloadRequest {
            path: path.to_owned(),
            reply,
        };
        async move {
            reloads.send(request).await.ok()?;
            outcome.await.ok()
        }
    }

    /// The published results.
    pub fn board(&self) -> Arc<Board> {
        Arc::clone(&self.board)
    }

    /// The register map the PLC writer and the HMI server encode the results with.
    pub fn register_map(&self) -> Arc<RegisterMap> {
        Arc::clone(&self.map)
    }

    /// The register map's words as the HMI server would answer now.
    pub fn words(&self) -> Vec<u16> {
        self.map.encode(&self.board.results())
    }

    /// Where commands to the analysis go (acknowledge alarms, reset wear), as the HMI
    /// server sends them.
    pub fn commands(&self) -> CommandSender {
        self.commands.clone()
    }

    /// Per-channel acquisition counters, indexed like `config.channels`.
    pub fn counters(&self) -> &[Arc<ChannelCounters>] {
        &self.counters
    }

    /// The turns of the analysis loop, for a watchdog
    /// ([`crate::supervision::watchdog`]).
    pub fn liveness(&self) -> Arc<Liveness> {
        Arc::clone(&self.liveness)
    }

    /// The event history: [`History::stored`] counts the events committed.
    pub fn history(&self) -> &History {
        &self.history
    }

    /// The bites analysed since the service was spawned, oldest first.
    pub fn bites(&mut self) -> &mut broadcast::Receiver<BiteReport> {
        &mut self.bites
    }

    /// Whether the service's task has ended (it runs until stopped).
    pub fn is_finished(&self) -> bool {
        self.ended.is_some() || self.task.as_ref().is_none_or(JoinHandle::is_finished)
    }

    /// Wait until the service is ready: every listener bound (done by `spawn`) and the
    /// PLC writer's first write attempted, whatever its outcome (at once without a PLC
    /// output). An error when the service ends first.
    pub async fn ready(&mut self) -> Result<(), ServiceError> {
        if let Some(task) = self.task.as_mut() {
            let mut attempted = self.plc_attempted.clone();
            let ended = tokio::select! {
                seen = attempted.wait_for(|attempted| *attempted) => match seen {
                    Ok(_) => return Ok(()),
                    // The writer is gone before attempting: the service is ending.
                    Err(_) => None,
                },
                ended = task => Some(ended.unwrap_or_else(|error| Err(error.into()))),
            };
            if let Some(ended) = ended {
                self.task = None;
                self.ended = Some(ended);
            }
        }
        self.finished().await
    }

    /// Wait until the service's task ends by itself. It runs until stopped, so this
    /// is always an error: what ended it, or [`ServiceError::Ended`]. Cancel-safe: the
    /// task stays with the service until it has ended.
    pub async fn finished(&mut self) -> Result<(), ServiceError> {
        if self.ended.is_none() {
            if let Some(task) = self.task.as_mut() {
                let outcome = task.await.unwrap_or_else(|error| Err(error.into()));
                self.task = None;
                self.ended = Some(outcome);
            }
        }
        self.ended
            .take()
            .unwrap_or(Ok(()))
            .and(Err(ServiceError::Ended))
    }

    /// Stop the service as SIGTERM does (readers stop, analysis drains, the final
    /// registers are written with status "stopped") and wait for it.
    pub async fn stop(self) -> Result<(), ServiceError> {
        self.stop.trigger();
        match (self.ended, self.task) {
            (Some(outcome), _) => outcome,
            (None, Some(task)) => task.await?,
            (None, None) => Ok(()),
        }
    }
}
