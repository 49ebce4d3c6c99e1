//! The service: reader tasks -> analysis task -> output tasks, and their shutdown.

use std::net::SocketAddr;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

use millgate_config::Config;
use tokio::net::TcpListener;
use tokio::sync::{broadcast, mpsc};
use tokio::task::{JoinHandle, JoinSet};

use crate::analysis::driveline::BiteReport;
use crate::analysis::gap_estimate::GapObservation;
use crate::analysis::gap_monitor::spawn_job;
use crate::analysis::{Analysis, AnalysisError};
use crate::field::can::supervisor::supervise_can;
use crate::field::counters::{CanCounters, ChannelCounters};
use crate::field::daq_reader::DaqReader;
use crate::field::source_health::SourceHealth;
use crate::outputs::heartbeat;
use crate::outputs::history::outages::{OutageMonitor, WatchedSource};
use crate::outputs::history::{History, RunInfo};
use crate::outputs::hmi_server::ModbusServer;
use crate::outputs::metrics::Metrics;
use crate::outputs::plc_writer::PlcWriter;
use crate::outputs::publisher::{source_of_channel, Publisher};
use crate::outputs::results::GatewayState;
use crate::outputs::sparkplug::SparkplugNode;
use crate::shutdown::{self, Shutdown, ShutdownTrigger};

/// Samples in flight between readers and analysis. At 2 kHz and 100-sample blocks
/// this is seconds of data per channel: enough to ride out a slow analysis step.
const SAMPLE_QUEUE: usize = 1024;

/// Why the service could not start, or its task failed.
#[derive(Debug, thiserror::Error)]
pub enum ServiceError {
    /// A driveline or tandem mill the analysis cannot be built for.
    #[error(transparent)]
    Analysis(#[from] AnalysisError),
    /// A listening output (the HMI Modbus server, the metrics endpoint) could not bind.
    #[error("cannot bind the {output} to {address}: {source}")]
    Bind {
        /// Which output: "Modbus server" or "metrics endpoint".
        output: &'static str,
        /// The configured address.
        address: std::net::SocketAddr,
        /// Why.
        #[source]
        source: std::io::Error,
    },
    /// The service's task panicked or was cancelled.
    #[error("the service task failed: {0}")]
    Task(#[from] tokio::task::JoinError),
}

/// A configured, not yet running gateway.
#[derive(Debug)]
pub struct Service {
    config: Config,
    publisher: Arc<Publisher>,
    counters: Vec<Arc<ChannelCounters>>,
    health: Vec<Arc<SourceHealth>>,
    can_counters: Vec<Arc<CanCounters>>,
    bites: broadcast::Sender<BiteReport>,
    analysis: Analysis,
    history: History,
    server_listener: Option<TcpListener>,
    metrics_listener: Option<TcpListener>,
}

/// Addresses the service listens on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Bound {
    /// The Modbus server for HMIs.
    pub server: Option<SocketAddr>,
    /// The Prometheus endpoint.
    pub metrics: Option<SocketAddr>,
}

fn modbus_health(source: &millgate_config::ModbusSource) -> SourceHealth {
    let stale_after = (source.poll_period * 3).max(source.timeout * 2);
    SourceHealth::new(stale_after, (stale_after * 5).max(Duration::from_secs(5)))
}

impl Service {
    /// Build every task's state from `config`.
    pub fn new(config: Config) -> Result<Self, ServiceError> {
        let counters = config
            .channels
            .iter()
            .map(|_| Arc::new(ChannelCounters::default()))
            .collect();
        let health: Vec<Arc<SourceHealth>> = config
            .modbus_sources
            .iter()
            .map(|source| Arc::new(modbus_health(source)))
            .chain(config.can_sources.iter().map(|_| {
                Arc::new(SourceHealth::new(
                    Duration::from_secs(1),
                    Duration::from_secs(5),
                ))
            }))
            .collect();
        let history = History::new(config.history.as_ref());
        let publisher =
            Arc::new(Publisher::new(&config, health.clone()).with_history(history.clone()));
        let (bites, _) = broadcast::channel(64);
        let analysis = Analysis::new(&config, Arc::clone(&publisher), bites.clone())?;
        for problem in analysis.wear_problems() {
            tracing::error!(%problem, "running without wear diagnosis for this driveline");
        }
        let can_counters = config.can_sources.iter().map(|_| Arc::default()).collect();
        Ok(Self {
            config,
            publisher,
            counters,
            health,
            can_counters,
            bites,
            analysis,
            history,
            server_listener: None,
            metrics_listener: None,
        })
    }

    /// Bind the listening outputs (Modbus server, metrics) now and return their
    /// addresses; `run` binds them otherwise. Lets callers learn ports chosen by
    /// the OS (`:0`).
    pub async fn bind(&mut self) -> Result<Bound, ServiceError> {
        async fn bind_once(
            output: &'static str,
            slot: &mut Option<TcpListener>,
            address: Option<SocketAddr>,
        ) -> Result<Option<SocketAddr>, ServiceError> {
            let Some(address) = address else {
                return Ok(None);
            };
            if slot.is_none() {
                let listener =
                    TcpListener::bind(address)
                        .await
                        .map_err(|source| ServiceError::Bind {
                            output,
                            address,
                            source,
                        })?;
                *slot = Some(listener);
            }
            Ok(slot.as_ref().and_then(|l| l.local_addr().ok()))
        }
        let outputs = &self.config.outputs;
        let server = outputs.server.as_ref().map(|s| s.bind);
        let metrics = outputs.metrics.as_ref().map(|m| m.bind);
        Ok(Bound {
            server: bind_once("Modbus server", &mut self.server_listener, server).await?,
            metrics: bind_once("metrics endpoint", &mut self.metrics_listener, metrics).await?,
        })
    }

    /// Why drivelines that name a model would run without wear diagnosis (a model that
    /// does not load, `wear` settings that do not fit it): logged at start, and errors
    /// for `millgate check`. Each names the key and the file.
    pub fn wear_problems(&self) -> Vec<String> {
        self.analysis
            .wear_problems()
            .iter()
            .map(ToString::to_string)
            .collect()
    }

    /// Start driveline `index`'s gap pool from `observations` (oldest first), e.g. as
    /// saved by a history before a restart ([`RunningService`] bites carry each new
    /// observation). The estimate is published as soon as the gap maps are ready.
    pub fn restore_gap_pool(&mut self, index: usize, observations: Vec<GapObservation>) {
        self.analysis.restore_gap_pool(index, observations);
    }

    /// Bites as they are analysed.
    pub fn subscribe_bites(&self) -> broadcast::Receiver<BiteReport> {
        self.bites.subscribe()
    }

    /// The published results and register map.
    pub fn publisher(&self) -> Arc<Publisher> {
        Arc::clone(&self.publisher)
    }

    /// Per-channel acquisition counters, indexed like `config.channels`.
    pub fn counters(&self) -> Vec<Arc<ChannelCounters>> {
        self.counters.clone()
    }

    /// The event history (disabled without `[history]`).
    pub fn history(&self) -> History {
        self.history.clone()
    }

    /// Open the history and publish what it restores (before any reader starts, so
    /// the first bite continues the restored counter), and pool the bites last put
    /// into each driveline's gap pool again (the history is where the pool survives a
    /// restart).
    async fn restore(&mut self) {
        let history = self.history.clone();
        let run = RunInfo::of(&self.config);
        let restored = match tokio::task::spawn_blocking(move || history.start(run)).await {
            Ok(restored) => restored,
            Err(error) => {
                tracing::error!(%error, "opening the history failed");
                return;
            }
        };
        let publisher = &self.publisher;
        publisher.update(|results| {
            restored.apply(results, publisher.driveline_names(), publisher.mill_names())
        });
        for driveline in &restored.drivelines {
            let index = publisher
                .driveline_names()
                .iter()
                .position(|name| *name == driveline.name);
            if let (Some(index), false) = (index, driveline.gap_pool.is_empty()) {
                let observations = driveline.gap_pool.iter().map(|bite| GapObservation {
                    static_torque_knm: bite.static_torque_knm,
                    taf: bite.taf,
                    taf_sigma: bite.taf_sigma,
                    period_shift_s: bite.period_shift_s,
                    period_shift_sigma_s: bite.period_shift_sigma_s,
                });
                self.analysis
                    .restore_gap_pool(index, observations.collect());
            }
            tracing::info!(
                driveline = %driveline.name,
                bite_counter = driveline.results.bite_counter,
                wear_trend = ?driveline.results.wear_trend,
                alarm_latched = driveline.results.alarm,
                last_bite = ?driveline.results.last_bite_unix_s,
                gap_alarm_latched = driveline.results.gap_alarm,
                gap_pool = driveline.gap_pool.len(),
                "state restored from the history"
            );
        }
    }

    /// The outage monitor of every source.
    fn outage_monitor(&self) -> OutageMonitor {
        let config = &self.config;
        let names = config
            .modbus_sources
            .iter()
            .map(|s| &s.name)
            .chain(config.can_sources.iter().map(|s| &s.name));
        let sources = names
            .zip(&self.health)
            .enumerate()
            .map(|(index, (name, health))| WatchedSource {
                name: name.clone(),
                health: Arc::clone(health),
                channels: (0..config.channels.len())
                    .filter(|&c| source_of_channel(config, c) == index)
                    .map(|c| Arc::clone(&self.counters[c]))
                    .collect(),
            })
            .collect();
        OutageMonitor::new(sources, self.history.clone())
    }

    /// Run until `shutdown` fires; then stop the readers, let analysis drain what
    /// they read, and write the final registers with status "stopped".
    pub async fn run(mut self, shutdown: Shutdown) -> Result<(), ServiceError> {
        self.bind().await?;
        self.restore().await;
        let outage_monitor = self.history.is_enabled().then(|| self.outage_monitor());
        let Service {
            config,
            publisher,
            counters,
            health,
            can_counters,
            history,
            server_listener,
            metrics_listener,
            mut analysis,
            ..
        } = self;
        let (samples_tx, samples_rx) = mpsc::channel(SAMPLE_QUEUE);
        let mut readers = JoinSet::new();
        for (index, source) in config.modbus_sources.iter().enumerate() {
            let reader = DaqReader::new(&config, index, &counters, Arc::clone(&health[index]));
            tracing::info!(source = %source.name, address = %source.address, "starting DaqReader");
            readers.spawn(reader.run(samples_tx.clone(), shutdown.clone()));
        }
        for (index, source) in config.can_sources.iter().enumerate() {
            tracing::info!(source = %source.name, interface = %source.interface, "starting CanReader");
            let health = Arc::clone(&health[config.modbus_sources.len() + index]);
            readers.spawn(supervise_can(
                Arc::new(config.clone()),
                index,
                health,
                Arc::clone(&can_counters[index]),
                samples_tx.clone(),
                shutdown.clone(),
            ));
        }
        drop(samples_tx);
        // Gap maps: read from the cache or built on threads of their own while the
        // service runs; the analysis installs them as they come.
        let jobs = analysis.take_gap_map_jobs();
        let (maps_tx, maps_rx) = mpsc::channel(jobs.len().max(1));
        let cancel_maps = Arc::new(AtomicBool::new(false));
        let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
        for job in jobs {
            let driveline = job.driveline_name.clone();
            if let Err(error) = spawn_job(job, threads, maps_tx.clone(), Arc::clone(&cancel_maps)) {
                tracing::error!(%driveline, %error, "cannot start the gap map build");
            }
        }
        drop(maps_tx);
        let analysis = tokio::spawn(analysis.run_with_maps(samples_rx, maps_rx));

        // Outputs stop only after analysis has drained, so the last bite is published.
        let (outputs_stop, outputs_shutdown) = shutdown::channel();
        let mut outputs = JoinSet::new();
        if let Some(plc) = &config.outputs.plc {
            tracing::info!(plc = %plc.address, base = plc.register_base, "starting PlcWriter");
            let writer = PlcWriter::new(plc.clone(), Arc::clone(&publisher));
            outputs.spawn(writer.run(outputs_shutdown.clone()));
        } else {
            outputs.spawn(heartbeat::beat_without_plc(
                Arc::clone(&publisher),
                outputs_shutdown.clone(),
            ));
        }
        if let Some(monitor) = outage_monitor {
            outputs.spawn(monitor.run(outputs_shutdown.clone()));
        }
        if let (Some(output), Some(listener)) = (&config.outputs.server, server_listener) {
            let plc_address = config.outputs.plc.as_ref().map(|plc| plc.address.clone());
            let server = ModbusServer::new(output.clone(), Arc::clone(&publisher))
                .with_plc_address(plc_address);
            let shutdown = outputs_shutdown.clone();
            outputs.spawn(async move {
                if let Err(error) = server.run(listener, shutdown).await {
                    tracing::error!(%error, "Modbus server failed");
                }
            });
        }
        let sparkplug = match (&config.outputs.mqtt, &config.history) {
            (Some(mqtt), Some(history)) => {
                tracing::info!(broker = %mqtt.broker, group = %mqtt.group_id, node = %mqtt.node_id, "starting the Sparkplug B edge node");
                let node =
                    SparkplugNode::new(mqtt.clone(), history.path.clone(), Arc::clone(&publisher));
                let status = node.status();
                outputs.spawn(node.run(outputs_shutdown.clone()));
                Some(status)
            }
            _ => None,
        };
        if let Some(listener) = metrics_listener {
            let mut metrics = Metrics::new(
                &config,
                counters.clone(),
                health.clone(),
                can_counters,
                Arc::clone(&publisher),
            );
            if let Some(status) = sparkplug {
                metrics = metrics.with_sparkplug(status);
            }
            outputs.spawn(metrics.run(listener, outputs_shutdown));
        }
        publisher.update(|results| results.state = GatewayState::Running);

        while readers.join_next().await.is_some() {}
        cancel_maps.store(true, Ordering::Relaxed);
        if analysis.await.is_err() {
            tracing::error!("analysis task failed");
        }
        outputs_stop.trigger();
        while outputs.join_next().await.is_some() {}
        publisher.update(|results| results.state = GatewayState::Stopped);
        // Last: the writer commits what analysis and the outputs recorded.
        if tokio::task::spawn_blocking(move || history.close())
            .await
            .is_err()
        {
            tracing::error!("closing the history failed");
        }
        tracing::info!("stopped");
        Ok(())
    }
}

/// A service running in its own task, started by [`Service::spawn`]: what tests, the
/// demo and benchmarks need to watch it and stop it.
#[derive(Debug)]
pub struct RunningService {
    bound: Bound,
    publisher: Arc<Publisher>,
    counters: Vec<Arc<ChannelCounters>>,
    history: History,
    bites: broadcast::Receiver<BiteReport>,
    stop: ShutdownTrigger,
    task: JoinHandle<Result<(), ServiceError>>,
}

impl Service {
    /// Bind the listening outputs, then run in a new tokio task until
    /// [`RunningService::stop`]. Every bite analysed after this call is queued for
    /// [`RunningService::bites`] (the last 64 when nobody reads them).
    pub async fn spawn(mut self) -> Result<RunningService, ServiceError> {
        let bound = self.bind().await?;
        let publisher = self.publisher();
        let counters = self.counters();
        let history = self.history();
        let bites = self.subscribe_bites();
        let (stop, shutdown) = shutdown::channel();
        let task = tokio::spawn(self.run(shutdown));
        Ok(RunningService {
            bound,
            publisher,
            counters,
            history,
            bites,
            stop,
            task,
        })
    }
}

impl RunningService {
    /// The addresses the listening outputs bound (ports the OS chose for `:0`).
    pub fn bound(&self) -> Bound {
        self.bound
    }

    /// The published results and register map.
    pub fn publisher(&self) -> Arc<Publisher> {
        Arc::clone(&self.publisher)
    }

    /// Per-channel acquisition counters, indexed like `config.channels`.
    pub fn counters(&self) -> &[Arc<ChannelCounters>] {
        &self.counters
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
        self.task.is_finished()
    }

    /// Stop the service as SIGTERM does (readers stop, analysis drains, the final
    /// registers are written with status "stopped") and wait for it.
    pub async fn stop(self) -> Result<(), ServiceError> {
        self.stop.trigger();
        self.task.await?
    }
}

/// Run the gateway for `config` until `shutdown` fires.
pub async fn run(config: Config, shutdown: Shutdown) -> Result<(), ServiceError> {
    Service::new(config)?.run(shutdown).await
}
