//! The service's output side: every output task, built from one list. An output costs
//! its protocol code and one builder here.

use std::future::Future;
use std::pin::Pin;
use std::sync::Arc;

use millgate_config::Config;
use tokio::net::TcpListener;
use tokio::sync::watch;

use super::error::ServiceError;
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
use crate::shutdown::Shutdown;
use crate::state::board::Board;
use crate::state::commands::CommandSender;

/// An output task: its name (for the log and the error that ends the service) and
/// what it runs until the shutdown; `Err` says why it failed.
pub(super) type OutputTask = (
    &'static str,
    Pin<Box<dyn Future<Output = Result<(), String>> + Send>>,
);

/// The listeners [`super::Service::bind`] bound.
pub(super) struct Listeners {
    pub(super) server: Option<TcpListener>,
    pub(super) metrics: Option<TcpListener>,
    pub(super) web: Option<TcpListener>,
    pub(super) opcua: Option<TcpListener>,
}

/// What the outputs are built from.
pub(super) struct Wiring<'a> {
    pub(super) config: &'a Config,
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
    /// The PLC writer's counters, for `/metrics`.
    pub(super) plc_counters: Arc<PlcCounters>,
    /// The OPC UA server, made by `Service::new`.
    pub(super) opcua: Option<OpcUaOutputTask>,
    /// The `/metrics` families of the outputs built so far that start on demand, in
    /// build order: each builder adds its own.
    pub(super) metrics: Vec<Arc<dyn Families>>,
}

/// Builds one output, or none when it is not configured.
type Builder = fn(&mut Wiring<'_>, &Shutdown) -> Result<Option<OutputTask>, ServiceError>;

/// Every output in start order (`/metrics` last: it shows the families the outputs
/// before it added, in this order).
const OUTPUTS: [Builder; 8] = [
    plc_writer,
    heartbeat_without_plc,
    outage_monitor,
    hmi_server,
    web_page,
    sparkplug,
    opcua,
    metrics,
];

/// The configured outputs' tasks.
pub(super) fn tasks(
    mut wiring: Wiring<'_>,
    shutdown: &Shutdown,
) -> Result<Vec<OutputTask>, ServiceError> {
    let mut tasks = Vec::new();
    for build in OUTPUTS {
        tasks.extend(build(&mut wiring, shutdown)?);
    }
    Ok(tasks)
}

fn task(
    name: &'static str,
    run: impl Future<Output = Result<(), String>> + Send + 'static,
) -> Option<OutputTask> {
    Some((name, Box::pin(run)))
}

fn plc_writer(w: &mut Wiring<'_>, shutdown: &Shutdown) -> Result<Option<OutputTask>, ServiceError> {
    let Some(plc) = &w.config.outputs.plc else {
        return Ok(None);
    };
    tracing::info!(plc = %plc.address, base = plc.register_base, "starting PlcWriter");
    let mut writer = PlcWriter::new(
        plc.clone(),
        (Arc::clone(&w.map), Arc::clone(&w.board)),
        Arc::clone(&w.plc_counters),
    );
    if let Some(attempted) = w.plc_attempted.take() {
        writer = writer.on_first_attempt(attempted);
    }
    let shutdown = shutdown.clone();
    Ok(task("PLC writer", async move {
        writer.run(shutdown).await;
        Ok(())
    }))
}

fn heartbeat_without_plc(
    w: &mut Wiring<'_>,
    shutdown: &Shutdown,
) -> Result<Option<OutputTask>, ServiceError> {
    if w.config.outputs.plc.is_some() {
        return Ok(None);
    }
    let beat = heartbeat::beat_without_plc(Arc::clone(&w.board), shutdown.clone());
    Ok(task("heartbeat", async move {
        beat.await;
        Ok(())
    }))
}

fn outage_monitor(
    w: &mut Wiring<'_>,
    shutdown: &Shutdown,
) -> Result<Option<OutputTask>, ServiceError> {
    let Some(monitor) = w.outage_monitor.take() else {
        return Ok(None);
    };
    let shutdown = shutdown.clone();
    Ok(task("outage monitor", async move {
        monitor.run(shutdown).await;
        Ok(())
    }))
}

fn hmi_server(w: &mut Wiring<'_>, shutdown: &Shutdown) -> Result<Option<OutputTask>, ServiceError> {
    let (Some(output), Some(listener)) = (&w.config.outputs.server, w.listeners.server.take())
    else {
        return Ok(None);
    };
    let plc_address = w.config.outputs.plc.as_ref().map(|plc| plc.address.clone());
    let served = Served {
        map: Arc::clone(&w.map),
        board: Arc::clone(&w.board),
        commands: w.commands.clone(),
    };
    let server = ModbusServer::new(output.clone(), served, Arc::clone(&w.server_counters))
        .with_plc_address(plc_address);
    let shutdown = shutdown.clone();
    Ok(task("Modbus server", async move {
        server
            .run(listener, shutdown)
            .await
            .map_err(|error| error.to_string())
    }))
}

fn sparkplug(w: &mut Wiring<'_>, shutdown: &Shutdown) -> Result<Option<OutputTask>, ServiceError> {
    let (Some(mqtt), Some(history)) = (&w.config.outputs.mqtt, &w.config.history) else {
        return Ok(None);
    };
    tracing::info!(brokers = ?mqtt.brokers, group = %mqtt.group_id, node = %mqtt.node_id, "starting the Sparkplug B edge node");
    let rod_mills = w
        .config
        .rod_mills
        .iter()
        .map(|mill| mill.name.clone())
        .zip(w.rod_mill_spans.iter().copied())
        .collect();
    let node = SparkplugNode::new(mqtt.clone(), history.path.clone(), Arc::clone(&w.board))?
        .with_rod_mills(rod_mills);
    w.metrics.push(node.status());
    let shutdown = shutdown.clone();
    Ok(task("Sparkplug B edge node", async move {
        node.run(shutdown).await;
        Ok(())
    }))
}

fn web_page(w: &mut Wiring<'_>, shutdown: &Shutdown) -> Result<Option<OutputTask>, ServiceError> {
    let (Some(settings), Some(listener)) = (&w.config.outputs.web, w.listeners.web.take()) else {
        return Ok(None);
    };
    let server =
        WebServer::new(w.config, settings.clone(), Arc::clone(&w.board)).map_err(|error| {
            ServiceError::Output {
                output: "maintenance page",
                reason: format!("cannot start its history query threads: {error}"),
            }
        })?;
    // The page plots a tandem mill's captured episode with the monitor's own code.
    let config = Arc::new(w.config.clone());
    let server = server
        .with_commands(w.commands.clone())
        .with_capture_bands(Arc::new(move |mill, rate_hz, stands, episode| {
            crate::analysis::chatter::episode_bands(&config, mill, rate_hz, stands, episode)
                .map_err(|error| error.to_string())
        }));
    w.metrics.push(server.query_slots());
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
fn opcua(w: &mut Wiring<'_>, shutdown: &Shutdown) -> Result<Option<OutputTask>, ServiceError> {
    let (Some(opcua), Some(listener)) = (w.opcua.take(), w.listeners.opcua.take()) else {
        return Ok(None);
    };
    tracing::info!("starting the OPC UA server");
    w.metrics.push(Arc::new(opcua.status()));
    Ok(task("OPC UA server", opcua.run(listener, shutdown.clone())))
}

fn metrics(w: &mut Wiring<'_>, shutdown: &Shutdown) -> Result<Option<OutputTask>, ServiceError> {
    let Some(listener) = w.listeners.metrics.take() else {
        return Ok(None);
    };
    // The acquisition's, the PLC writer's, the HMI server's (counted with or without
    // one) and the history's, then those the outputs built added.
    let mut metrics = Metrics::new(w.config, Arc::clone(&w.board), &w.rod_mill_spans).with(
        Arc::new(AcquisitionFamilies::new(w.config, w.acquisition.clone())),
    );
    if w.config.outputs.plc.is_some() {
        metrics = metrics.with(w.plc_counters.clone());
    }
    metrics = metrics
        .with(w.server_counters.clone())
        .with(Arc::new(w.board.history().clone()));
    for families in w.metrics.drain(..) {
        metrics = metrics.with(families);
    }
    let shutdown = shutdown.clone();
    Ok(task("metrics endpoint", async move {
        metrics
            .run(listener, shutdown)
            .await
            .map_err(|error| error.to_string())
    }))
}
