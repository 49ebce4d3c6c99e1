//! The service: reader tasks -> analysis task -> output tasks, and their shutdown.
//!
//! Start-up fails loudly: [`Service::new`] refuses what cannot run (a model that does
//! not load, a register map past register 65535), [`Service::spawn`] what cannot bind,
//! and once running, an output task that ends (a listener that fails for good) or an
//! analysis that dies ends the service with the error, so `millgate run` exits
//! non-zero and its supervisor restarts it.

use std::net::SocketAddr;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

use millgate_config::Config;
use tokio::net::TcpListener;
use tokio::sync::{broadcast, mpsc, watch};
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
use crate::outputs::hmi_server::{self, ModbusServer, ServerCounters};
use crate::outputs::metrics::Metrics;
use crate::outputs::plc_writer::PlcWriter;
use crate::outputs::publisher::{source_of_channel, Publisher, WearMapState};
use crate::outputs::register_map::{self, MapTooLarge};
use crate::outputs::results::GatewayState;
use crate::outputs::sparkplug::SparkplugNode;
use crate::outputs::web::{self, WebServer};
use crate::shutdown::{self, Shutdown, ShutdownTrigger};
use crate::supervision::Liveness;

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
        /// Which output: "Modbus server", "metrics endpoint" or "maintenance page".
        output: &'static str,
        /// The configured address.
        address: std::net::SocketAddr,
        /// Why.
        #[source]
        source: std::io::Error,
    },
    /// Drivelines that name a model the wear diagnosis cannot use (the model does not
    /// load, or its `wear` settings do not fit it): one `<key path>: <problem>` each,
    /// naming the model file.
    #[error("{}", .0.join("\n"))]
    Wear(Vec<String>),
    /// The register map does not fit a Modbus table.
    #[error("drivelines, tandem_mills: {0}")]
    MapTooLarge(#[from] MapTooLarge),
    /// The register map written at `outputs.plc.register_base` runs past register 65535.
    #[error(
        "outputs.plc.register_base: {base} is not allowed: the register map spans {span} \
         registers and would end at register {end}, past 65535 (must be 0..={max})"
    )]
    RegisterBase {
        /// The configured base.
        base: u16,
        /// Registers the map spans.
        span: u16,
        /// Last register the map would reach.
        end: u32,
        /// Highest base that fits.
        max: u32,
    },
    /// An output task ended while the service ran: its listener failed for good, or it
    /// panicked.
    #[error("the {output} stopped: {reason}")]
    Output {
        /// Which output.
        output: &'static str,
        /// What ended it.
        reason: String,
    },
    /// The Sparkplug B edge node's TLS files cannot be used.
    #[error("the Sparkplug B edge node cannot start: {0}")]
    SparkplugTls(#[from] crate::outputs::sparkplug::tls::TlsSetupError),
    /// The OPC UA server cannot be built or started.
    #[cfg(feature = "opcua")]
    #[error(transparent)]
    OpcUa(#[from] crate::outputs::opcua::OpcUaError),
    /// `[outputs.opcua]` in a millgate built without the `opcua` feature.
    #[error(
        "outputs.opcua: this millgate was built without the OPC UA server (build it with \
         cargo build --release -p millgate --features opcua)"
    )]
    OpcUaNotBuilt,
    /// The service's task panicked or was cancelled.
    #[error("the service task failed: {0}")]
    Task(#[from] tokio::task::JoinError),
    /// The service ended without being asked to stop.
    #[error("the service ended without being asked to stop")]
    Ended,
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
    web_listener: Option<TcpListener>,
    opcua_listener: Option<TcpListener>,
    #[cfg(feature = "opcua")]
    opcua: Option<crate::outputs::opcua::adapter::OpcUaOutputTask>,
    liveness: Arc<Liveness>,
    server_counters: Arc<ServerCounters>,
    /// Set once the PLC writer attempted its first write (at once without a PLC).
    plc_attempted: watch::Sender<bool>,
}

/// Addresses the service listens on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Bound {
    /// The Modbus server for HMIs.
    pub server: Option<SocketAddr>,
    /// The Prometheus endpoint.
    pub metrics: Option<SocketAddr>,
    /// The maintenance web page.
    pub web: Option<SocketAddr>,
    /// The OPC UA server.
    pub opcua: Option<SocketAddr>,
}

/// The health of Modbus source `index` of `config`: stale after three poll periods,
/// two timeouts or two periods of its slowest full block (new data is what keeps a
/// source fresh), whichever is longest; lost after five times that or 5 s.
fn modbus_health(config: &Config, index: usize) -> SourceHealth {
    let source = &config.modbus_sources[index];
    let slowest_block = config
        .channels
        .iter()
        .filter_map(|channel| match channel.source {
            millgate_config::ChannelSource::ModbusBlock { source, .. } if source == index => {
                Some(Duration::from_secs_f64(
                    f64::from(millgate_config::layout::MAX_BLOCK_SAMPLES) / channel.sample_rate_hz,
                ))
            }
            _ => None,
        })
        .max()
        .unwrap_or_default();
    let stale_after = (source.poll_period * 3)
        .max(source.timeout * 2)
        .max(slowest_block * 2);
    SourceHealth::new(stale_after, (stale_after * 5).max(Duration::from_secs(5)))
}

impl Service {
    /// Build every task's state from `config`; an error names the key of a setting
    /// the service cannot run with.
    pub fn new(config: Config) -> Result<Self, ServiceError> {
        let span = register_map::RegisterMap::try_new(&config)?.len();
        if let Some(plc) = &config.outputs.plc {
            let end = u32::from(plc.register_base) + u32::from(span) - 1;
            if end > u32::from(u16::MAX) {
                return Err(ServiceError::RegisterBase {
                    base: plc.register_base,
                    span,
                    end,
                    max: u32::from(u16::MAX) + 1 - u32::from(span),
                });
            }
        }
        let counters = config
            .channels
            .iter()
            .map(|_| Arc::new(ChannelCounters::default()))
            .collect();
        let health: Vec<Arc<SourceHealth>> = config
            .modbus_sources
            .iter()
            .enumerate()
            .map(|(index, _)| Arc::new(modbus_health(&config, index)))
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
        // A driveline model that does not load, or `wear` settings that do not fit it,
        // is a configuration error: `run` exits with it at once (and `check` names it)
        // rather than running on without the wear diagnosis the file asks for.
        let problems: Vec<String> = analysis
            .wear_problems()
            .iter()
            .map(ToString::to_string)
            .collect();
        if !problems.is_empty() {
            return Err(ServiceError::Wear(problems));
        }
        #[cfg(feature = "opcua")]
        let opcua = crate::outputs::opcua::adapter::OpcUaOutputTask::prepare(
            &config,
            &analysis.rod_mill_spans(),
            &publisher,
        )?;
        #[cfg(not(feature = "opcua"))]
        if config.outputs.opcua.is_some() {
            return Err(ServiceError::OpcUaNotBuilt);
        }
        let can_counters = config.can_sources.iter().map(|_| Arc::default()).collect();
        let (plc_attempted, _) = watch::channel(config.outputs.plc.is_none());
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
            web_listener: None,
            opcua_listener: None,
            #[cfg(feature = "opcua")]
            opcua,
            liveness: Arc::default(),
            server_counters: Arc::default(),
            plc_attempted,
        })
    }

    /// What the configuration exposes that an operator should know: a Modbus server
    /// or a web page reachable from other hosts. `millgate check` prints these; the
    /// service logs them as warnings at start.
    pub fn warnings(&self) -> Vec<String> {
        let outputs = &self.config.outputs;
        outputs
            .server
            .as_ref()
            .and_then(hmi_server::exposure_warning)
            .into_iter()
            .chain(outputs.web.as_ref().and_then(web::exposure_warning))
            .chain(self.opcua_warning())
            .collect()
    }

    /// The OPC UA server's exposure warning.
    #[cfg(feature = "opcua")]
    fn opcua_warning(&self) -> Option<String> {
        let settings = self.config.outputs.opcua.as_ref()?;
        crate::outputs::opcua::exposure_warning(settings)
    }

    #[cfg(not(feature = "opcua"))]
    fn opcua_warning(&self) -> Option<String> {
        None
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
        let web = outputs.web.as_ref().map(|w| w.bind);
        let opcua = outputs.opcua.as_ref().map(|o| o.bind);
        Ok(Bound {
            server: bind_once("Modbus server", &mut self.server_listener, server).await?,
            metrics: bind_once("metrics endpoint", &mut self.metrics_listener, metrics).await?,
            web: bind_once("maintenance page", &mut self.web_listener, web).await?,
            opcua: bind_once("OPC UA server", &mut self.opcua_listener, opcua).await?,
        })
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
    /// they read, and write the final registers with status "stopped" (the source
    /// statuses as they were while running: an orderly stop is not a fault).
    ///
    /// Ends early with an error when an output task or the analysis fails.
    pub async fn run(mut self, mut shutdown: Shutdown) -> Result<(), ServiceError> {
        self.bind().await?;
        for warning in self.warnings() {
            tracing::warn!("{warning}");
        }
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
            web_listener,
            opcua_listener,
            #[cfg(feature = "opcua")]
            opcua,
            liveness,
            server_counters,
            plc_attempted,
            mut analysis,
            ..
        } = self;
        let rod_mills: Vec<(String, usize)> = config
            .rod_mills
            .iter()
            .map(|mill| mill.name.clone())
            .zip(analysis.rod_mill_spans())
            .collect();
        // Readers stop on their own signal, after the final source statuses are kept.
        let (readers_stop, readers_shutdown) = shutdown::channel();
        let (samples_tx, samples_rx) = mpsc::channel(SAMPLE_QUEUE);
        let mut readers = JoinSet::new();
        for (index, source) in config.modbus_sources.iter().enumerate() {
            let reader = DaqReader::new(&config, index, &counters, Arc::clone(&health[index]));
            tracing::info!(source = %source.name, address = %source.address, "starting DaqReader");
            readers.spawn(reader.run(samples_tx.clone(), readers_shutdown.clone()));
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
                readers_shutdown.clone(),
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
            let index = job.driveline;
            let progress = {
                let publisher = Arc::clone(&publisher);
                move |done, total| {
                    publisher.set_wear_map(index, WearMapState::Building { done, total })
                }
            };
            let spawned = spawn_job(
                job,
                threads,
                maps_tx.clone(),
                Arc::clone(&cancel_maps),
                progress,
            );
            if let Err(error) = spawned {
                tracing::error!(%driveline, %error, "cannot start the gap map build");
                publisher.set_wear_map(
                    index,
                    WearMapState::Failed(format!("cannot start the gap map build: {error}")),
                );
            }
        }
        drop(maps_tx);
        let mut analysis = tokio::spawn(analysis.run(samples_rx, maps_rx, Arc::clone(&liveness)));

        // Outputs stop only after analysis has drained, so the last bite is published.
        // Each returns what ended it; before the stop, any end is a failure.
        let (outputs_stop, outputs_shutdown) = shutdown::channel();
        let mut outputs: JoinSet<(&'static str, Result<(), String>)> = JoinSet::new();
        if let Some(plc) = &config.outputs.plc {
            tracing::info!(plc = %plc.address, base = plc.register_base, "starting PlcWriter");
            let writer =
                PlcWriter::new(plc.clone(), Arc::clone(&publisher)).on_first_attempt(plc_attempted);
            let shutdown = outputs_shutdown.clone();
            outputs.spawn(async move {
                writer.run(shutdown).await;
                ("PLC writer", Ok(()))
            });
        } else {
            let beat =
                heartbeat::beat_without_plc(Arc::clone(&publisher), outputs_shutdown.clone());
            outputs.spawn(async move {
                beat.await;
                ("heartbeat", Ok(()))
            });
        }
        if let Some(monitor) = outage_monitor {
            let shutdown = outputs_shutdown.clone();
            outputs.spawn(async move {
                monitor.run(shutdown).await;
                ("outage monitor", Ok(()))
            });
        }
        if let (Some(output), Some(listener)) = (&config.outputs.server, server_listener) {
            let plc_address = config.outputs.plc.as_ref().map(|plc| plc.address.clone());
            let server = ModbusServer::new(
                output.clone(),
                Arc::clone(&publisher),
                Arc::clone(&server_counters),
            )
            .with_plc_address(plc_address);
            let shutdown = outputs_shutdown.clone();
            outputs.spawn(async move {
                let served = server.run(listener, shutdown).await;
                ("Modbus server", served.map_err(|error| error.to_string()))
            });
        }
        let sparkplug = match (&config.outputs.mqtt, &config.history) {
            (Some(mqtt), Some(history)) => {
                tracing::info!(broker = %mqtt.broker, group = %mqtt.group_id, node = %mqtt.node_id, "starting the Sparkplug B edge node");
                let node =
                    SparkplugNode::new(mqtt.clone(), history.path.clone(), Arc::clone(&publisher))?
                        .with_rod_mills(rod_mills);
                let status = node.status();
                let shutdown = outputs_shutdown.clone();
                outputs.spawn(async move {
                    node.run(shutdown).await;
                    ("Sparkplug B edge node", Ok(()))
                });
                Some(status)
            }
            _ => None,
        };
        if let (Some(settings), Some(listener)) = (&config.outputs.web, web_listener) {
            let server = WebServer::new(&config, settings.clone(), Arc::clone(&publisher));
            let shutdown = outputs_shutdown.clone();
            outputs.spawn(async move {
                let served = server.run(listener, shutdown).await;
                (
                    "maintenance page",
                    served.map_err(|error| error.to_string()),
                )
            });
        }
        #[cfg(feature = "opcua")]
        if let (Some(opcua), Some(listener)) = (opcua, opcua_listener) {
            tracing::info!("starting the OPC UA server");
            opcua.spawn(listener, &mut outputs, &outputs_shutdown);
        }
        #[cfg(not(feature = "opcua"))]
        drop(opcua_listener);
        if let Some(listener) = metrics_listener {
            let mut metrics = Metrics::new(
                &config,
                counters.clone(),
                health.clone(),
                can_counters,
                Arc::clone(&publisher),
            );
            metrics = metrics.with_server(server_counters);
            if let Some(status) = sparkplug {
                metrics = metrics.with_sparkplug(status);
            }
            let shutdown = outputs_shutdown.clone();
            outputs.spawn(async move {
                metrics.run(listener, shutdown).await;
                ("metrics endpoint", Ok(()))
            });
        }
        publisher.update(|results| results.state = GatewayState::Running);

        let mut analysis_ended = None;
        let failure = tokio::select! {
            () = shutdown.recv() => None,
            Some(ended) = outputs.join_next() => Some(output_failure(ended)),
            ended = &mut analysis => {
                let failure = match &ended {
                    Ok(()) => ServiceError::Ended,
                    Err(error) => ServiceError::Output {
                        output: "analysis",
                        reason: error.to_string(),
                    },
                };
                analysis_ended = Some(ended);
                Some(failure)
            }
        };
        if let Some(failure) = &failure {
            tracing::error!(%failure, "stopping the service");
        }
        publisher.freeze_health();
        readers_stop.trigger();
        while readers.join_next().await.is_some() {}
        cancel_maps.store(true, Ordering::Relaxed);
        let analysis_ended = match analysis_ended {
            Some(ended) => ended,
            None => analysis.await,
        };
        if let Err(error) = analysis_ended {
            tracing::error!(%error, "analysis task failed");
        }
        outputs_stop.trigger();
        while let Some(ended) = outputs.join_next().await {
            if let Ok((output, Err(reason))) = ended {
                tracing::error!(output, %reason, "output failed");
            }
        }
        publisher.update(|results| results.state = GatewayState::Stopped);
        // Last: the writer commits what analysis and the outputs recorded.
        if tokio::task::spawn_blocking(move || history.close())
            .await
            .is_err()
        {
            tracing::error!("closing the history failed");
        }
        tracing::info!("stopped");
        failure.map_or(Ok(()), Err)
    }
}

/// The error of an output task that ended while the service ran.
fn output_failure(
    ended: Result<(&'static str, Result<(), String>), tokio::task::JoinError>,
) -> ServiceError {
    match ended {
        Ok((output, Err(reason))) => ServiceError::Output { output, reason },
        Ok((output, Ok(()))) => ServiceError::Output {
            output,
            reason: "it ended on its own".into(),
        },
        Err(error) => ServiceError::Output {
            output: "an output task",
            reason: error.to_string(),
        },
    }
}

/// A service running in its own task, started by [`Service::spawn`]: what `main`,
/// tests, the demo and benchmarks need to watch it and stop it.
#[derive(Debug)]
pub struct RunningService {
    bound: Bound,
    publisher: Arc<Publisher>,
    counters: Vec<Arc<ChannelCounters>>,
    history: History,
    bites: broadcast::Receiver<BiteReport>,
    liveness: Arc<Liveness>,
    plc_attempted: watch::Receiver<bool>,
    #[cfg(feature = "opcua")]
    opcua: Option<crate::outputs::opcua::OpcUaStatus>,
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
        let publisher = self.publisher();
        let counters = self.counters();
        let history = self.history();
        let bites = self.subscribe_bites();
        let liveness = Arc::clone(&self.liveness);
        let plc_attempted = self.plc_attempted.subscribe();
        #[cfg(feature = "opcua")]
        let opcua = self.opcua.as_ref().map(|opcua| opcua.status());
        let (stop, shutdown) = shutdown::channel();
        let task = tokio::spawn(self.run(shutdown));
        Ok(RunningService {
            bound,
            publisher,
            counters,
            history,
            bites,
            liveness,
            plc_attempted,
            #[cfg(feature = "opcua")]
            opcua,
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

    /// The published results and register map.
    pub fn publisher(&self) -> Arc<Publisher> {
        Arc::clone(&self.publisher)
    }

    /// The OPC UA server's counts, with `[outputs.opcua]`.
    #[cfg(feature = "opcua")]
    pub fn opcua(&self) -> Option<crate::outputs::opcua::OpcUaStatus> {
        self.opcua.clone()
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

/// Run the gateway for `config` until `shutdown` fires.
pub async fn run(config: Config, shutdown: Shutdown) -> Result<(), ServiceError> {
    Service::new(config)?.run(shutdown).await
}
