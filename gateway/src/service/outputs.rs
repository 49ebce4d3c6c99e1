//! The service's output side: every output task, built from one list. An output costs
//! its protocol code and one builder here. [`Outputs`] runs them, and a reload
//! restarts those whose settings changed ([`Outputs::stop_touched`],
//! [`Outputs::start_touched`]): each has a stop of its
//! own, and a listening output keeps its socket between two runs (a client that
//! connects meanwhile waits in the backlog), so only a new address is bound anew.

use std::future::Future;
use std::net::SocketAddr;
use std::pin::Pin;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

use millgate_config::Config;
use tokio::net::TcpListener;
use tokio::sync::{oneshot, watch};
use tokio::task::{AbortHandle, JoinSet};

use super::error::ServiceError;
use super::reload::Live;
use crate::exposition::Families;
use crate::field::counters::Acquisition;
use crate::field::metrics::AcquisitionFamilies;
use crate::history::outages::OutageMonitor;
use crate::outputs::metrics::Metrics;
use crate::outputs::modbus::frame::Served;
use crate::outputs::modbus::heartbeat;
use crate::outputs::modbus::hmi_server::{ModbusServer, ServerCounters};
use crate::outputs::modbus::plc_writer::{PlcCounters, PlcWriter};
use crate::outputs::modbus::register_map::RegisterMap;
use crate::outputs::opcua::OpcUaOutputTask;
use crate::outputs::sparkplug::SparkplugNode;
use crate::outputs::web::WebServer;
use crate::shutdown::{self, Shutdown, ShutdownTrigger};
use crate::state::board::Board;
use crate::state::commands::CommandSender;
use crate::state::results::GatewayState;

/// An output task: its name (for the log and the error that ends the service) and
/// what it runs until the shutdown; `Err` says why it failed.
pub(super) type OutputTask = (
    &'static str,
    Pin<Box<dyn Future<Output = Result<(), String>> + Send>>,
);

/// The listeners [`super::Service::bind`] bound: the Modbus server's, the metrics
/// endpoint's and the web page's kept for every run of their output; the OPC UA
/// server's taken once (it is not restarted).
pub(super) struct Listeners {
    pub(super) server: Option<Kept>,
    pub(super) metrics: Option<Kept>,
    pub(super) web: Option<Kept>,
    pub(super) opcua: Option<TcpListener>,
}

/// A listening socket kept by the service, bound for its configured address; each run
/// of its output accepts on a duplicate of it.
pub(super) struct Kept {
    /// The address as configured (port 0 included).
    configured: SocketAddr,
    socket: std::net::TcpListener,
}

impl Kept {
    /// Keep `listener`, bound for `configured`.
    pub(super) fn new(configured: SocketAddr, listener: TcpListener) -> std::io::Result<Self> {
        Ok(Self {
            configured,
            socket: listener.into_std()?,
        })
    }

    /// A listener for one run of `output`, on the kept socket.
    fn listener(&self, output: &'static str) -> Result<TcpListener, ServiceError> {
        self.socket
            .try_clone()
            .and_then(TcpListener::from_std)
            .map_err(|source| ServiceError::Bind {
                output,
                address: self.configured,
                source,
            })
    }
}

/// What the outputs are built from.
pub(super) struct Wiring {
    /// The configuration the outputs run (a reload replaces what it applies).
    config: Config,
    parts: WiringParts,
    /// The PLC writer's counters, for `/metrics`.
    plc_counters: Arc<PlcCounters>,
    /// The `/metrics` families of the outputs that start on demand, by their place in
    /// [`OUTPUTS`]: each builder sets its own (the metrics endpoint shows them in this
    /// order).
    metrics: [Option<Arc<dyn Families>>; OUTPUTS.len()],
    /// The families of the output just built, for [`Self::metrics`].
    built_families: Option<Arc<dyn Families>>,
    /// Set before the PLC writer stops when another takes over.
    handover: Arc<AtomicBool>,
}

impl Wiring {
    /// The wiring of `config`'s outputs; `metrics` and the handover start empty.
    pub(super) fn new(config: Config, parts: WiringParts) -> Self {
        Self {
            config,
            parts,
            plc_counters: Arc::default(),
            metrics: Default::default(),
            built_families: None,
            handover: Arc::default(),
        }
    }
}

/// What [`Wiring::new`] takes besides the configuration.
pub(super) struct WiringParts {
    pub(super) map: Arc<RegisterMap>,
    pub(super) board: Arc<Board>,
    pub(super) commands: CommandSender,
    pub(super) acquisition: Acquisition,
    pub(super) server_counters: Arc<ServerCounters>,
    /// Told once the PLC writer attempted its first write (taken by the writer).
    pub(super) plc_attempted: Option<watch::Sender<bool>>,
    pub(super) listeners: Listeners,
    pub(super) outage_monitor: Option<OutageMonitor>,
    pub(super) rod_mill_spans: Vec<usize>,
    /// The OPC UA server, made by `Service::new`.
    pub(super) opcua: Option<OpcUaOutputTask>,
    /// The reloads' counts, for `/metrics`.
    pub(super) reloads: Arc<ReloadCounters>,
}

/// Builds one output, or none when it is not configured.
type Builder = fn(&mut Wiring, &Shutdown) -> Result<Option<OutputTask>, ServiceError>;

/// Every output in start order (`/metrics` last: it shows the families the outputs
/// before it added, in this order), with the parts of the configuration a reload
/// restarts it for (the metrics endpoint also restarts with any output whose families
/// it shows: the PLC writer's, the page's, the Sparkplug node's).
///
/// Drivelines added live ([`Live::Drivelines`]) restart the outputs that show
/// drivelines: the PLC writer and the HMI server on the map with their blocks, the
/// page and `/metrics` with their rows, the Sparkplug node with a new session whose
/// births carry their devices (a DBIRTH before any DDATA of a device). The OPC UA
/// server runs on: it adds their nodes as it runs (`Started::add_drivelines` tells it).
const OUTPUTS: [(Builder, &[Live]); 8] = [
    (plc_writer, &[Live::Plc, Live::Drivelines]),
    (heartbeat_without_plc, &[Live::Plc]),
    (outage_monitor, &[]),
    // The server tells the PLC's commands from an HMI's by the PLC's address.
    (hmi_server, &[Live::Server, Live::Plc, Live::Drivelines]),
    // The page shows the thresholds.
    (
        web_page,
        &[Live::Web, Live::Thresholds, Live::Drivelines, Live::Sources],
    ),
    (sparkplug, &[Live::Mqtt, Live::Drivelines]),
    (opcua, &[]),
    (
        metrics,
        &[
            Live::Metrics,
            Live::Plc,
            Live::Web,
            Live::Mqtt,
            Live::Drivelines,
            Live::Sources,
        ],
    ),
];

/// How long a restarted output may take to stop before it is aborted.
const STOP_LIMIT: Duration = Duration::from_secs(10);

/// The reloads counted by outcome, for `/metrics`.
#[derive(Debug, Default)]
pub(crate) struct ReloadCounters {
    /// Applied, refused, needs a restart, unchanged.
    counts: [std::sync::atomic::AtomicU64; 4],
}

impl ReloadCounters {
    const OUTCOMES: [&'static str; 4] = ["applied", "refused", "needs_restart", "unchanged"];

    /// Count a reload of `outcome` ([`super::reload::Reload::outcome`]).
    pub(crate) fn count(&self, outcome: &str) {
        if let Some(index) = Self::OUTCOMES.iter().position(|name| *name == outcome) {
            self.counts[index].fetch_add(1, Ordering::Relaxed);
        }
    }
}

impl Families for ReloadCounters {
    fn write_families(&self, page: &mut crate::exposition::Exposition) {
        page.family(
            "millgate_config_reloads_total",
            crate::exposition::Kind::Counter,
            "Configuration reloads (SIGHUP, systemctl reload), by outcome: applied (every change applied), refused (the file has errors, or a new listener cannot bind: nothing applied), needs_restart (some changes wait for a restart; the others were applied), unchanged.",
            Self::OUTCOMES
                .iter()
                .zip(&self.counts)
                .map(|(outcome, count)| {
                    (vec![("outcome", *outcome)], count.load(Ordering::Relaxed) as f64)
                }),
        );
    }
}

/// One run of an output.
struct Run {
    /// Its place in [`OUTPUTS`] and which run of it this is.
    generation: u64,
    stop: ShutdownTrigger,
    /// Told when the run has ended.
    ended: oneshot::Receiver<()>,
    abort: AbortHandle,
}

/// How an output's task ended: its place in [`OUTPUTS`], its run, its name and what
/// it returned.
type Ended = (usize, u64, &'static str, Result<(), String>);

/// The running outputs.
pub(super) struct Outputs {
    wiring: Wiring,
    runs: [Option<Run>; OUTPUTS.len()],
    tasks: JoinSet<Ended>,
    generations: u64,
}

impl Outputs {
    /// Build and start every configured output.
    pub(super) fn start(wiring: Wiring) -> Result<Self, ServiceError> {
        let mut outputs = Self {
            wiring,
            runs: Default::default(),
            tasks: JoinSet::new(),
            generations: 0,
        };
        for index in 0..OUTPUTS.len() {
            outputs.start_one(index)?;
        }
        Ok(outputs)
    }

    /// Build output `index` from the wiring and start it, when it is configured.
    fn start_one(&mut self, index: usize) -> Result<(), ServiceError> {
        let (stop, shutdown) = shutdown::channel();
        let (build, _) = OUTPUTS[index];
        self.wiring.metrics[index] = None;
        let built = build(&mut self.wiring, &shutdown)?;
        self.wiring.metrics[index] = self.wiring.built_families.take();
        let Some((name, task)) = built else {
            return Ok(());
        };
        self.generations += 1;
        let generation = self.generations;
        let (tell, ended) = oneshot::channel();
        let abort = self.tasks.spawn(async move {
            let outcome = task.await;
            let _ = tell.send(());
            (index, generation, name, outcome)
        });
        self.runs[index] = Some(Run {
            generation,
            stop,
            ended,
            abort,
        });
        Ok(())
    }

    /// Wait until an output ends by itself: the failure (before the stop, any end is
    /// one). Outputs stopped by a reload are not failures. Cancel-safe.
    pub(super) async fn failure(&mut self) -> ServiceError {
        loop {
            let Some(ended) = self.tasks.join_next().await else {
                return std::future::pending().await;
            };
            match ended {
                Ok((index, generation, name, outcome)) => {
                    let current = self.runs[index]
                        .as_ref()
                        .is_some_and(|run| run.generation == generation);
                    if current {
                        return output_failure(name, outcome);
                    }
                }
                Err(error) if error.is_cancelled() => {}
                Err(error) => {
                    return ServiceError::Output {
                        output: "an output task",
                        reason: error.to_string(),
                    }
                }
            }
        }
    }

    /// The sockets `config`'s listening outputs need that are not bound yet: bound now,
    /// before anything stops (an address in use refuses the reload, the outputs run on).
    pub(super) async fn bind_new(&self, config: &Config) -> Result<NewListeners, ServiceError> {
        async fn bind(
            output: &'static str,
            kept: Option<&Kept>,
            address: Option<SocketAddr>,
        ) -> Result<Option<Kept>, ServiceError> {
            let Some(address) = address else {
                return Ok(None);
            };
            if kept.is_some_and(|kept| kept.configured == address) {
                return Ok(None);
            }
            let bound = match TcpListener::bind(address).await {
                Ok(listener) => Kept::new(address, listener),
                Err(error) => Err(error),
            };
            bound.map(Some).map_err(|source| ServiceError::Bind {
                output,
                address,
                source,
            })
        }
        let (outputs, kept) = (&config.outputs, &self.wiring.parts.listeners);
        Ok(NewListeners {
            server: bind(
                "Modbus server",
                kept.server.as_ref(),
                outputs.server.as_ref().map(|s| s.bind),
            )
            .await?,
            metrics: bind(
                "metrics endpoint",
                kept.metrics.as_ref(),
                outputs.metrics.as_ref().map(|m| m.bind),
            )
            .await?,
            web: bind(
                "maintenance page",
                kept.web.as_ref(),
                outputs.web.as_ref().map(|w| w.bind),
            )
            .await?,
        })
    }

    /// Stop the outputs a reload's `live` parts touch (`config` is the running one
    /// with them applied): the PLC gets no "stopped" write while `config` keeps a PLC
    /// output. Returns them, for [`Self::start_touched`].
    pub(super) async fn stop_touched(&mut self, config: &Config, live: &[Live]) -> Vec<usize> {
        let touched = |parts: &[Live]| parts.iter().any(|part| live.contains(part));
        let restart: Vec<usize> = (0..OUTPUTS.len())
            .filter(|&index| touched(OUTPUTS[index].1))
            .collect();
        for &index in restart.iter().rev() {
            if let Some(run) = self.runs[index].take() {
                self.wiring
                    .handover
                    .store(config.outputs.plc.is_some(), Ordering::Relaxed);
                run.stop.trigger();
                if tokio::time::timeout(STOP_LIMIT, run.ended).await.is_err() {
                    tracing::warn!(limit = ?STOP_LIMIT, "an output did not stop in time: aborted");
                    run.abort.abort();
                }
                self.wiring.handover.store(false, Ordering::Relaxed);
            }
        }
        restart
    }

    /// Run `config` (the running one with a reload's `live` parts applied): start the
    /// outputs [`Self::stop_touched`] stopped (`restart`) again with it on `listeners`
    /// (from [`Self::bind_new`]). An output that cannot be built again is the error
    /// (the others are running by then).
    pub(super) fn start_touched(
        &mut self,
        config: Config,
        live: &[Live],
        restart: &[usize],
        listeners: NewListeners,
    ) -> Result<(), ServiceError> {
        let outputs = &config.outputs;
        let kept = &mut self.wiring.parts.listeners;
        replace(&mut kept.server, listeners.server, outputs.server.is_some());
        replace(
            &mut kept.metrics,
            listeners.metrics,
            outputs.metrics.is_some(),
        );
        replace(&mut kept.web, listeners.web, outputs.web.is_some());
        self.wiring.config = config;
        if live.contains(&Live::Plc) {
            // A PLC output removed had its last write say "stopped"; the service runs.
            self.wiring
                .parts
                .board
                .update(|results| results.state = GatewayState::Running);
        }
        for &index in restart {
            self.start_one(index)?;
        }
        Ok(())
    }

    /// Encode on `map` from the next start of the PLC writer and the HMI server on
    /// (drivelines added live: [`Live::Drivelines`] restarts them).
    pub(super) fn use_map(&mut self, map: Arc<RegisterMap>) {
        self.wiring.parts.map = map;
    }

    /// Show `acquisition` (grown by sources added live: [`Live::Sources`] restarts the
    /// outputs that show it) from the next start of an output on.
    pub(super) fn use_acquisition(&mut self, acquisition: Acquisition) {
        self.wiring.parts.acquisition = acquisition;
    }

    /// Stop every output and wait for them (the PLC gets its last write).
    pub(super) async fn stop(mut self) {
        for run in self.runs.iter().flatten() {
            run.stop.trigger();
        }
        while let Some(ended) = self.tasks.join_next().await {
            if let Ok((_, _, output, Err(reason))) = ended {
                tracing::error!(output, %reason, "output failed");
            }
        }
    }
}

/// The sockets a reload bound for new addresses.
pub(super) struct NewListeners {
    server: Option<Kept>,
    metrics: Option<Kept>,
    web: Option<Kept>,
}

/// Into `slot`, the socket `new` bound for a new address, or none when the output is
/// not `configured` any more; otherwise the kept one stays.
fn replace(slot: &mut Option<Kept>, new: Option<Kept>, configured: bool) {
    if new.is_some() || !configured {
        *slot = new;
    }
}

/// The error of an output task that ended while the service ran.
fn output_failure(output: &'static str, outcome: Result<(), String>) -> ServiceError {
    ServiceError::Output {
        output,
        reason: outcome
            .err()
            .unwrap_or_else(|| "it ended on its own".into()),
    }
}

fn task(
    name: &'static str,
    run: impl Future<Output = Result<(), String>> + Send + 'static,
) -> Option<OutputTask> {
    Some((name, Box::pin(run)))
}

fn plc_writer(w: &mut Wiring, shutdown: &Shutdown) -> Result<Option<OutputTask>, ServiceError> {
    let Some(plc) = &w.config.outputs.plc else {
        return Ok(None);
    };
    tracing::info!(plc = %plc.address, base = plc.register_base, "starting PlcWriter");
    let mut writer = PlcWriter::new(
        plc.clone(),
        (Arc::clone(&w.parts.map), Arc::clone(&w.parts.board)),
        Arc::clone(&w.plc_counters),
    );
    if let Some(attempted) = w.parts.plc_attempted.take() {
        writer = writer.on_first_attempt(attempted);
    }
    writer = writer.with_handover(Arc::clone(&w.handover));
    let shutdown = shutdown.clone();
    Ok(task("PLC writer", async move {
        writer.run(shutdown).await;
        Ok(())
    }))
}

fn heartbeat_without_plc(
    w: &mut Wiring,
    shutdown: &Shutdown,
) -> Result<Option<OutputTask>, ServiceError> {
    if w.config.outputs.plc.is_some() {
        return Ok(None);
    }
    let beat = heartbeat::beat_without_plc(Arc::clone(&w.parts.board), shutdown.clone());
    Ok(task("heartbeat", async move {
        beat.await;
        Ok(())
    }))
}

fn outage_monitor(w: &mut Wiring, shutdown: &Shutdown) -> Result<Option<OutputTask>, ServiceError> {
    let Some(monitor) = w.parts.outage_monitor.take() else {
        return Ok(None);
    };
    let shutdown = shutdown.clone();
    Ok(task("outage monitor", async move {
        monitor.run(shutdown).await;
        Ok(())
    }))
}

fn hmi_server(w: &mut Wiring, shutdown: &Shutdown) -> Result<Option<OutputTask>, ServiceError> {
    let (Some(output), Some(kept)) = (&w.config.outputs.server, &w.parts.listeners.server) else {
        return Ok(None);
    };
    let listener = kept.listener("Modbus server")?;
    let plc_address = w.config.outputs.plc.as_ref().map(|plc| plc.address.clone());
    let served = Served {
        map: Arc::clone(&w.parts.map),
        board: Arc::clone(&w.parts.board),
        commands: w.parts.commands.clone(),
    };
    let server = ModbusServer::new(output.clone(), served, Arc::clone(&w.parts.server_counters))
        .with_plc_address(plc_address);
    let shutdown = shutdown.clone();
    Ok(task("Modbus server", async move {
        server
            .run(listener, shutdown)
            .await
            .map_err(|error| error.to_string())
    }))
}

fn sparkplug(w: &mut Wiring, shutdown: &Shutdown) -> Result<Option<OutputTask>, ServiceError> {
    let (Some(mqtt), Some(history)) = (&w.config.outputs.mqtt, &w.config.history) else {
        return Ok(None);
    };
    tracing::info!(brokers = ?mqtt.brokers, group = %mqtt.group_id, node = %mqtt.node_id, "starting the Sparkplug B edge node");
    let rod_mills = w
        .config
        .rod_mills
        .iter()
        .map(|mill| mill.name.clone())
        .zip(w.parts.rod_mill_spans.iter().copied())
        .collect();
    let node = SparkplugNode::new(
        mqtt.clone(),
        history.path.clone(),
        Arc::clone(&w.parts.board),
    )?
    .with_rod_mills(rod_mills);
    w.built_families = Some(node.status());
    let shutdown = shutdown.clone();
    Ok(task("Sparkplug B edge node", async move {
        node.run(shutdown).await;
        Ok(())
    }))
}

fn web_page(w: &mut Wiring, shutdown: &Shutdown) -> Result<Option<OutputTask>, ServiceError> {
    let (Some(settings), Some(kept)) = (&w.config.outputs.web, &w.parts.listeners.web) else {
        return Ok(None);
    };
    let listener = kept.listener("maintenance page")?;
    let server = WebServer::new(&w.config, settings.clone(), Arc::clone(&w.parts.board)).map_err(
        |error| ServiceError::Output {
            output: "maintenance page",
            reason: format!("cannot start its history query threads: {error}"),
        },
    )?;
    // The page plots a tandem mill's captured episode with the monitor's own code.
    let config = Arc::new(w.config.clone());
    let server = server
        .with_commands(w.parts.commands.clone())
        .with_capture_bands(Arc::new(move |mill, rate_hz, stands, episode| {
            crate::analysis::chatter::episode_bands(&config, mill, rate_hz, stands, episode)
                .map_err(|error| error.to_string())
        }));
    w.built_families = Some(server.query_slots());
    let shutdown = shutdown.clone();
    Ok(task("maintenance page", async move {
        server
            .run(listener, shutdown)
            .await
            .map_err(|error| error.to_string())
    }))
}

/// The OPC UA server (made by `Service::new`; a millgate built without the `opcua`
/// feature refused `[outputs.opcua]` there, so it has none).
fn opcua(w: &mut Wiring, shutdown: &Shutdown) -> Result<Option<OutputTask>, ServiceError> {
    let (Some(opcua), Some(listener)) = (w.parts.opcua.take(), w.parts.listeners.opcua.take())
    else {
        return Ok(None);
    };
    tracing::info!("starting the OPC UA server");
    w.built_families = Some(Arc::new(opcua.status()));
    Ok(task("OPC UA server", opcua.run(listener, shutdown.clone())))
}

fn metrics(w: &mut Wiring, shutdown: &Shutdown) -> Result<Option<OutputTask>, ServiceError> {
    let Some(kept) = &w.parts.listeners.metrics else {
        return Ok(None);
    };
    let listener = kept.listener("metrics endpoint")?;
    // The acquisition's, the PLC writer's, the latencies, the HMI server's (counted
    // with or without one) and the history's, then those the outputs built added.
    let mut metrics = Metrics::new(
        &w.config,
        Arc::clone(&w.parts.board),
        &w.parts.rod_mill_spans,
    )
    .with(Arc::new(AcquisitionFamilies::new(
        &w.config,
        w.parts.acquisition.clone(),
    )));
    if w.config.outputs.plc.is_some() {
        metrics = metrics.with(w.plc_counters.clone());
    }
    metrics = metrics.with(Arc::clone(w.parts.board.latencies()) as Arc<dyn Families>);
    metrics = metrics
        .with(w.parts.server_counters.clone())
        .with(Arc::new(w.parts.board.history().clone()));
    metrics = metrics.with(w.parts.reloads.clone());
    for families in w.metrics.iter().flatten() {
        metrics = metrics.with(Arc::clone(families));
    }
    let shutdown = shutdown.clone();
    Ok(task("metrics endpoint", async move {
        metrics
            .run(listener, shutdown)
            .await
            .map_err(|error| error.to_string())
    }))
}
