//! The OPC UA server (`[outputs.opcua]`, cargo feature `opcua`): the gateway's figures
//! as an address space, alarms as events, an acknowledge method. Built on
//! async-opcua's server (its in-memory node manager, its secure channels, sessions and
//! subscriptions).
//!
//! The server knows nothing of the results types: it publishes an
//! [`model::AddressSpaceSpec`] and the [`model::Snapshot`]s and
//! [`model::AlarmEventSpec`]s it is given, and calls an `nodes::Acknowledger` when
//! a client acknowledges. `adapter` maps the catalogue and the board to them.
//!
//! Files: `model.rs` (the vocabulary and the address space table), `nodes.rs` (the
//! namespace, the nodes, the acknowledge guard), `events.rs` (alarm events),
//! `auth.rs` (anonymous and user sign-in), `pki.rs` (the certificate store),
//! `conditions.rs` (the condition instances' state: Alarms & Conditions),
//! `front.rs` (the listener: connection bound, framing check, client addresses),
//! `status.rs` (the counters), `metrics.rs` (their `/metrics` families), `error.rs`
//! (why it stopped), `adapter/` (the catalogue to the address space, the board to
//! snapshots; the task that feeds the server), `alarms.rs` (the alarm stream to
//! events), `tools.rs` (what the command line uses: the address space
//! table, the demo's `--opcua`).
//!
//! The rest of the gateway (the service, `millgate check`, `millgate address-space`,
//! the demo's `--opcua`) uses only this module's face: `OpcUaOutputTask`,
//! [`OpcUaStatus`], [`OpcUaError`], [`exposure_warning`], [`address_space_table`] and
//! [`DemoOption`]. A millgate built without the feature gets the same names from
//! `outputs/opcua_not_built.rs`, which refuses `[outputs.opcua]`, so no other file
//! needs a `#[cfg(feature = "opcua")]`.

pub(crate) mod adapter;
mod alarms;
mod auth;
mod conditions;
mod error;
mod events;
pub mod front;
mod metrics;
pub mod model;
pub(crate) mod nodes;
mod pki;
mod status;
mod tools;

use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::Duration;

use millgate_config::{OpcUaOutput, OpcUaSecurityMode};
use opcua::nodes::Event;
use opcua::server::node_manager::memory::{InMemoryNodeManager, InMemoryNodeManagerBuilder};
use opcua::server::{ServerBuilder, ServerEndpoint, ServerHandle, ANONYMOUS_USER_TOKEN_ID};
use opcua::types::{DataValue, DateTime, MessageSecurityMode, StatusCode, Variant};
use tokio::net::TcpListener;
use tokio::sync::{mpsc, watch};

use crate::shutdown::Shutdown;
use crate::warn_limit::{WarnLimit, WARN_PERIOD};

pub(crate) use adapter::OpcUaOutputTask;
pub use error::OpcUaError;
pub use status::OpcUaStatus;
pub use tools::{address_space_table, DemoOption};

use conditions::Conditions;
use front::{ChannelPeers, FrontDoor, SessionPeers};
use model::{AddressSpaceSpec, AlarmEventSpec, Quality, Snapshot, Value, VariableUpdate};
use nodes::{Acknowledger, CommandGuard, MillgateNodes, MillgateNodesBuilder, NodeIds};
use status::{count, OpcUaCounters};

/// Largest message a client may send, bytes: async-opcua's receive buffer.
const MAX_MESSAGE: u32 = u16::MAX as u32;
/// async-opcua's subscription tick, ms: a subscription publishes on the first tick at
/// or after its publishing interval, so a 100 ms tick turns a 100 ms interval into
/// 100 or 200 ms by jitter; a 20 ms one keeps it within 20 ms.
const SUBSCRIPTION_TICK_MS: u64 = 20;
/// How long the server may take to come up or to stop.
const START_STOP_LIMIT: Duration = Duration::from_secs(10);
/// Longest a subscription lives without publish requests (publishing interval x
/// lifetime count, revised to fit): a subscription left behind by a closed session
/// is gone after it (round-4 audit, finding 2).
const MAX_SUBSCRIPTION_LIFETIME: Duration = Duration::from_secs(600);
/// Monitored items on the server, all sessions together, unless
/// `max_monitored_items_per_subscription` is larger (about 1.5 kB each).
const MAX_MONITORED_ITEMS: usize = 20_000;
/// Most notifications in one Publish response (the client may ask for fewer). A data
/// change of a double with both timestamps is about 40 bytes, one of our longest
/// strings about 100: 1 000 stay far below the 327 675-byte message async-opcua and
/// most clients allow. Unbounded, 8 800 figures changing at once made a response of
/// about 330 kB: the server answered `Bad_ResponseTooLarge` and the client lost every
/// value in it, with nothing to say which (issue 42, item 5).
const MAX_NOTIFICATIONS_PER_PUBLISH: u64 = 1_000;
/// Continuation points a session may hold (browse, history, query): each keeps the
/// rest of a result until the client asks for it (async-opcua allows 5 000).
const MAX_CONTINUATION_POINTS: usize = 10;
/// Queue of an item of events whose client leaves its size to the server (0):
/// room for a ConditionRefresh's retained conditions and a burst of alarms
/// (async-opcua's default, one, kept only the last; the kept patch's setting).
const EVENT_QUEUE_SIZE: usize = 100;
/// How often `pki_dir/rejected/` is trimmed to [`pki::MAX_REJECTED`] files.
const REJECTED_TRIM_PERIOD: Duration = Duration::from_secs(1);

/// The warning for a server reachable from other hosts, `None` on a loopback bind.
/// `millgate check` prints it and the service logs it at start.
pub fn exposure_warning(settings: &OpcUaOutput) -> Option<String> {
    if settings.bind.ip().is_loopback() {
        return None;
    }
    let mut warning = format!(
        "outputs.opcua.bind: {} accepts OPC UA clients from other hosts",
        settings.bind
    );
    if settings.security_modes.contains(&OpcUaSecurityMode::None) {
        warning.push_str(
            "; outputs.opcua.security_modes has none: messages travel unsigned and \
             unencrypted (clients are asked to encrypt passwords)",
        );
    }
    if settings.anonymous {
        warning.push_str("; anonymous clients may read every figure");
    }
    if settings.allow_remote_commands {
        warning.push_str(
            "; outputs.opcua.allow_remote_commands = true lets a signed-in user on any host \
             acknowledge alarms",
        );
    }
    Some(warning)
}

/// The OPC UA server: its settings, what it publishes and who acknowledges.
pub struct OpcUaServer {
    settings: OpcUaOutput,
    spec: Arc<AddressSpaceSpec>,
    acknowledge: Acknowledger,
    counters: Arc<OpcUaCounters>,
    handle: Arc<std::sync::Mutex<Option<ServerHandle>>>,
}

impl std::fmt::Debug for OpcUaServer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("OpcUaServer")
            .field("endpoint", &self.settings.endpoint_url())
            .field("objects", &self.spec.objects.len())
            .finish()
    }
}

impl OpcUaServer {
    /// A server of `spec` with `settings`; `acknowledge` is called for each acknowledge
    /// call the guard lets through. The address space is checked now (two nodes with
    /// one id are refused).
    pub fn new(
        settings: OpcUaOutput,
        spec: AddressSpaceSpec,
        acknowledge: Acknowledger,
    ) -> Result<Self, OpcUaError> {
        NodeIds::new(&spec, 1).map_err(OpcUaError::AddressSpace)?;
        Ok(Self {
            settings,
            spec: Arc::new(spec),
            acknowledge,
            counters: Arc::default(),
            handle: Arc::default(),
        })
    }

    /// The counts, now and while it runs.
    pub fn status(&self) -> OpcUaStatus {
        OpcUaStatus {
            counters: Arc::clone(&self.counters),
            handle: Arc::clone(&self.handle),
        }
    }

    /// The application URI (in the certificate and the application description).
    fn application_uri(&self) -> String {
        format!("urn:{}:millgate", self.settings.host)
    }

    /// Serve on `listener` (bound to `settings.bind`) until `shutdown`: `updates` holds
    /// the latest snapshot (applied at start and at each change), `events` the alarms to
    /// send, `grown` the address spaces grown from this one by drivelines added live
    /// (their nodes added while the server runs; each one before any snapshot of it).
    /// An error when the certificate store, async-opcua or a listener fails.
    pub async fn run(
        self,
        listener: TcpListener,
        mut updates: watch::Receiver<Snapshot>,
        mut events: mpsc::Receiver<AlarmEventSpec>,
        mut grown: mpsc::Receiver<AddressSpaceSpec>,
        mut shutdown: Shutdown,
    ) -> Result<(), OpcUaError> {
        let public = listener.local_addr()?;
        let pki_dir = self.settings.pki_dir.clone();
        let (uri, host) = (self.application_uri(), self.settings.host.clone());
        tokio::task::spawn_blocking(move || pki::prepare(&pki_dir, &uri, &host))
            .await
            .map_err(|error| OpcUaError::Server(error.to_string()))??;
        let peers = Arc::new(ChannelPeers::default());
        let guard = Arc::new(CommandGuard {
            allow_remote: self.settings.allow_remote_commands,
            peers: Arc::clone(&peers),
            acknowledge: Arc::clone(&self.acknowledge),
            counters: Arc::clone(&self.counters),
            pace: std::sync::Mutex::default(),
        });
        let conditions = Arc::new(std::sync::Mutex::new(Conditions::default()));
        let session_peers = Arc::new(SessionPeers {
            peers: Arc::clone(&peers),
            counters: Arc::clone(&self.counters),
            problems: std::sync::Mutex::new(WarnLimit::new(WARN_PERIOD)),
        });
        let (server, handle) = self
            .builder(public.port())
            .with_session_clients(session_peers)
            .with_node_manager(InMemoryNodeManagerBuilder::new(MillgateNodesBuilder {
                spec: Arc::clone(&self.spec),
                guard,
                conditions: Arc::clone(&conditions),
            }))
            .build()
            .map_err(OpcUaError::Server)?;
        *crate::lock(&self.handle) = Some(handle.clone());
        let backend_listener = TcpListener::bind((std::net::Ipv4Addr::LOCALHOST, 0)).await?;
        let backend = backend_listener.local_addr()?;
        let mut served = tokio::spawn(server.run_with(backend_listener));
        // async-opcua writes its own listener's port into the endpoint URLs it hands
        // out: once it has, the front door's port goes there instead.
        let started = tokio::time::Instant::now();
        while handle.info().port.load(Ordering::Relaxed) != backend.port() {
            if served.is_finished() || started.elapsed() > START_STOP_LIMIT {
                handle.cancel();
                return Err(OpcUaError::Server("did not start".into()));
            }
            tokio::time::sleep(Duration::from_millis(2)).await;
        }
        handle.info().port.store(public.port(), Ordering::Relaxed);
        let nodes = handle
            .node_managers()
            .get_of_type::<InMemoryNodeManager<MillgateNodes>>()
            .ok_or_else(|| OpcUaError::Server("the millgate namespace is missing".into()))?;
        let ns = handle
            .get_namespace_index(nodes::NAMESPACE_URI)
            .ok_or_else(|| OpcUaError::Server("the millgate namespace is missing".into()))?;
        let ids = NodeIds::new(&self.spec, ns).map_err(OpcUaError::AddressSpace)?;
        let companions = [nodes::MACHINERY_URI, nodes::DI_URI]
            .map(|uri| handle.get_namespace_index(uri).unwrap_or_default());
        let mut publish = Publish {
            spec: Arc::clone(&self.spec),
            ids,
            ns,
            companions: (companions[0], companions[1]),
            grown: false,
            nodes: &nodes,
            handle: &handle,
            counters: &self.counters,
            last: Snapshot::default(),
            conditions: &conditions,
        };
        publish.apply(&updates.borrow_and_update());
        let front = FrontDoor {
            listener,
            backend,
            max_connections: self.settings.max_connections,
            max_message: MAX_MESSAGE,
            none_allowed: self
                .settings
                .security_modes
                .contains(&OpcUaSecurityMode::None),
            counters: Arc::clone(&self.counters),
            peers,
        };
        let mut front = tokio::spawn(front.run(shutdown.clone()));
        tracing::info!(endpoint = %self.settings.endpoint_url(), local = %public, "OPC UA server listening");
        let mut trim = tokio::time::interval(REJECTED_TRIM_PERIOD);
        trim.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        let mut trim_problems = WarnLimit::new(WARN_PERIOD);
        let ended = loop {
            tokio::select! {
                // A grown address space before the snapshots of it (sent after it).
                biased;
                Some(spec) = grown.recv() => publish.grow(spec),
                _ = trim.tick() => self.trim_rejected(&mut trim_problems).await,
                changed = updates.changed() => match changed {
                    Ok(()) => publish.apply(&updates.borrow_and_update()),
                    Err(_) => break Ok(()),
                },
                Some(alarm) = events.recv() => publish.event(&alarm),
                () = shutdown.recv() => break Ok(()),
                ended = &mut served => break Err(OpcUaError::Server(match ended {
                    Ok(Ok(())) => "ended on its own".into(),
                    Ok(Err(error)) => error,
                    Err(error) => error.to_string(),
                })),
                ended = &mut front => break match ended {
                    Ok(Ok(())) => Ok(()),
                    Ok(Err(error)) => Err(OpcUaError::Io(error)),
                    Err(error) => Err(OpcUaError::Server(error.to_string())),
                },
            }
        };
        handle.set_server_state(opcua::types::ServerState::Shutdown);
        handle.cancel();
        let _ = tokio::time::timeout(START_STOP_LIMIT, &mut served).await;
        front.abort();
        ended
    }

    /// Keep `pki_dir/rejected/` within [`pki::MAX_REJECTED`] files, the oldest removed.
    async fn trim_rejected(&self, problems: &mut WarnLimit) {
        let pki_dir = self.settings.pki_dir.clone();
        let trimmed =
            tokio::task::spawn_blocking(move || pki::trim_rejected(&pki_dir, pki::MAX_REJECTED))
                .await;
        let now = tokio::time::Instant::now();
        match trimmed {
            Ok(Ok(0)) => {}
            Ok(Ok(removed)) => {
                self.counters
                    .rejected_certificates_removed
                    .fetch_add(removed as u64, Ordering::Relaxed);
                if let Some(suppressed) = problems.occurred(now) {
                    tracing::warn!(removed, suppressed, keep = pki::MAX_REJECTED, "OPC UA: the oldest refused client certificates removed from pki_dir/rejected/");
                }
            }
            Ok(Err(error)) => {
                if let Some(suppressed) = problems.occurred(now) {
                    tracing::warn!(%error, suppressed, "OPC UA: pki_dir/rejected/ not trimmed");
                }
            }
            Err(error) => tracing::error!(%error, "OPC UA: pki_dir/rejected/ trimming failed"),
        }
    }

    /// async-opcua's settings: endpoints, limits, the certificate store, users.
    fn builder(&self, port: u16) -> ServerBuilder {
        let settings = &self.settings;
        let mut builder = ServerBuilder::new()
            .application_name(format!("millgate {}", self.spec.name))
            .application_uri(self.application_uri())
            .product_uri(PRODUCT_URI)
            .build_info(build_info())
            .host(settings.host.clone())
            .port(port)
            .pki_dir(settings.pki_dir.clone())
            .create_sample_keypair(false)
            .trust_client_certs(false)
            .check_cert_time(true)
            .discovery_urls(vec![settings.endpoint_url()])
            .max_sessions(settings.max_sessions)
            .max_session_timeout_ms(settings.max_session_timeout.as_millis() as u64)
            .diagnostics_enabled(true)
            .subscription_poll_interval_ms(SUBSCRIPTION_TICK_MS)
            .with_authenticator(Arc::new(auth::Users::new(
                settings.anonymous,
                settings.users.clone(),
                Arc::clone(&self.counters),
            )));
        let limits = builder.limits_mut();
        limits.subscriptions.max_subscriptions_per_session = settings.max_subscriptions_per_session;
        limits.subscriptions.max_monitored_items_per_sub =
            settings.max_monitored_items_per_subscription;
        // The bounds of the kept patch (patches/README.md): all sessions' subscriptions
        // (closed sessions' too, until they expire) and monitored items together, the
        // lifetime of a subscription nobody publishes, the idle session that makes
        // room for a new one when all are taken, the sessions a client address holds.
        limits.subscriptions.max_subscriptions =
            settings.max_sessions * settings.max_subscriptions_per_session;
        limits.subscriptions.max_monitored_items =
            MAX_MONITORED_ITEMS.max(settings.max_monitored_items_per_subscription);
        limits.subscriptions.max_lifetime_ms = MAX_SUBSCRIPTION_LIFETIME.as_millis() as f64;
        limits.subscriptions.default_event_queue_size = EVENT_QUEUE_SIZE;
        limits.subscriptions.max_notifications_per_publish = MAX_NOTIFICATIONS_PER_PUBLISH;
        limits.evict_idle_session_ms = front::EVICT_IDLE.as_millis() as u64;
        limits.max_sessions_per_client = settings.max_sessions_per_peer;
        limits.max_browse_continuation_points = MAX_CONTINUATION_POINTS;
        limits.max_history_continuation_points = MAX_CONTINUATION_POINTS;
        limits.max_query_continuation_points = MAX_CONTINUATION_POINTS;
        let tokens = [ANONYMOUS_USER_TOKEN_ID.to_owned()];
        for mode in &settings.security_modes {
            let mut endpoint = match mode {
                OpcUaSecurityMode::None => ServerEndpoint::new_none("/", &tokens),
                OpcUaSecurityMode::Sign => ServerEndpoint::new(
                    "/",
                    opcua::crypto::SecurityPolicy::Basic256Sha256,
                    MessageSecurityMode::Sign,
                    &tokens,
                ),
                OpcUaSecurityMode::SignAndEncrypt => ServerEndpoint::new(
                    "/",
                    opcua::crypto::SecurityPolicy::Basic256Sha256,
                    MessageSecurityMode::SignAndEncrypt,
                    &tokens,
                ),
            };
            endpoint.password_security_policy = Some(auth::PASSWORD_POLICY.to_string());
            builder = builder.add_endpoint(mode.name(), endpoint);
        }
        builder
    }
}

/// The running server's publishing side: snapshots to values, alarms to events, the
/// nodes of drivelines added live.
struct Publish<'a> {
    spec: Arc<AddressSpaceSpec>,
    ids: NodeIds,
    /// The millgate namespace and the companions' (Machinery, DI).
    ns: u16,
    companions: (u16, u16),
    /// Set by [`Self::grow`] until a snapshot of the grown address space comes: one
    /// the feed sent before it (fewer objects) is not applied to the grown one.
    grown: bool,
    nodes: &'a InMemoryNodeManager<MillgateNodes>,
    handle: &'a ServerHandle,
    counters: &'a OpcUaCounters,
    last: Snapshot,
    conditions: &'a std::sync::Mutex<Conditions>,
}

impl Publish<'_> {
    /// Add the nodes `spec` (this address space grown by drivelines added live) has
    /// beyond the running ones, as the start builds them, and publish on it from now
    /// on: the conditions keep their states, every value is written anew (the objects
    /// after the new ones moved in the snapshots). Clients browse the new nodes at
    /// once; a GeneralModelChangeEvent is not sent.
    fn grow(&mut self, spec: AddressSpaceSpec) {
        let ids = match NodeIds::new(&spec, self.ns) {
            Ok(ids) => ids,
            Err(error) => {
                tracing::error!(%error, "OPC UA nodes of the added drivelines not made");
                return;
            }
        };
        let before = self.ids.objects.len();
        {
            let mut address_space = self.nodes.address_space().write();
            nodes::build(&mut address_space, &spec, &ids, self.ns);
            nodes::add_machines(&mut address_space, &spec, &ids, self.ns, self.companions);
        }
        crate::lock(self.conditions).grown(&spec, &ids.objects, &ids.conditions);
        tracing::info!(
            objects = ids.objects.len() - before,
            "OPC UA nodes of the added drivelines added"
        );
        self.spec = Arc::new(spec);
        self.ids = ids;
        self.last = Snapshot::default();
        self.grown = true;
    }

    /// Write what changed since the last snapshot; subscribed clients are notified.
    fn apply(&mut self, snapshot: &Snapshot) {
        if self.grown {
            if snapshot.objects.len() != self.spec.objects.len() {
                return;
            }
            self.grown = false;
        }
        let now = DateTime::now();
        let mut changes = Vec::new();
        for (object, updates) in snapshot.objects.iter().enumerate() {
            let (Some(specs), Some(ids)) = (
                self.spec.objects.get(object),
                self.ids.variables.get(object),
            ) else {
                continue;
            };
            let last = self.last.objects.get(object);
            for (variable, update) in updates.iter().enumerate() {
                let (Some(spec), Some(id)) = (specs.variables.get(variable), ids.get(variable))
                else {
                    continue;
                };
                if last.and_then(|l| l.get(variable)) == Some(update) {
                    continue;
                }
                let value = self.data_value(spec.datatype, update, now);
                changes.push((id, value));
            }
        }
        for (machine, now_is) in snapshot.machines.iter().enumerate() {
            let Some([_, state, health]) = self.ids.machines.get(machine) else {
                continue;
            };
            if self.last.machines.get(machine) == Some(now_is) {
                continue;
            }
            let (state_now, health_now) = now_is;
            let good = |value: Variant| DataValue {
                value: Some(value),
                status: Some(StatusCode::Good),
                source_timestamp: Some(now),
                server_timestamp: Some(now),
                ..Default::default()
            };
            let text = opcua::types::LocalizedText::new("en", state_now.name());
            changes.push((state, good(Variant::from(text))));
            changes.push((health, good(Variant::UInt32(*health_now as u32))));
        }
        if changes.is_empty() {
            return;
        }
        self.counters
            .value_changes
            .fetch_add(changes.len() as u64, Ordering::Relaxed);
        let written = self.nodes.set_values(
            self.handle.subscriptions(),
            changes.into_iter().map(|(id, value)| (id, None, value)),
        );
        if let Err(status) = written {
            tracing::error!(%status, "OPC UA values not written");
        }
        self.last = snapshot.clone();
    }

    /// The DataValue of `update` for a variable of `datatype`: a value only with a
    /// good or uncertain quality, of the right type and finite.
    fn data_value(
        &self,
        datatype: model::VariableType,
        update: &VariableUpdate,
        now: DateTime,
    ) -> DataValue {
        let source_time = update.source_time.map_or(now, events::ua_time);
        let value = match update.value.filter(|_| update.quality.carries_value()) {
            Some(value) if value.datatype() != datatype || !is_finite(value) => {
                count(&self.counters.invalid_updates);
                tracing::error!(?value, expected = datatype.name(), "OPC UA update refused");
                return DataValue {
                    value: Some(Variant::Empty),
                    status: Some(StatusCode::BadTypeMismatch),
                    source_timestamp: Some(source_time),
                    server_timestamp: Some(now),
                    ..Default::default()
                };
            }
            Some(value) => variant(value),
            // An empty variant rather than none: async-opcua 0.19 reads a variable
            // without a value as good, whatever its status.
            None => Variant::Empty,
        };
        DataValue {
            value: Some(value),
            status: Some(status_code(update.quality)),
            source_timestamp: Some(source_time),
            server_timestamp: Some(now),
            ..Default::default()
        }
    }

    /// Apply `alarm` to its condition and send the condition's event from its
    /// object: to the clients subscribed to the object's events or the Server
    /// object's (async-opcua adds those of the Server object).
    fn event(&mut self, alarm: &AlarmEventSpec) {
        // Held while the event is queued: a ConditionRefresh sees it before or after.
        let mut conditions = crate::lock(self.conditions);
        let Some((event, source)) = conditions.update(alarm) else {
            tracing::error!(
                object = alarm.object,
                kind = alarm.kind,
                "OPC UA alarm of no condition"
            );
            return;
        };
        self.handle
            .subscriptions()
            .notify_events([(&event as &dyn Event, &source)].into_iter());
        count(&self.counters.events);
    }
}

/// A value as an OPC UA variant.
fn variant(value: Value) -> Variant {
    match value {
        Value::Double(value) => Variant::Double(value),
        Value::Boolean(value) => Variant::Boolean(value),
        Value::UInt32(value) => Variant::UInt32(value),
        Value::UInt64(value) => Variant::UInt64(value),
        Value::DateTime(time) => Variant::from(events::ua_time(time)),
    }
}

fn is_finite(value: Value) -> bool {
    match value {
        Value::Double(value) => value.is_finite(),
        _ => true,
    }
}

/// The product's URI (BuildInfo, the application description).
const PRODUCT_URI: &str = "urn:millgate";

/// The server's BuildInfo (`Server/ServerStatus/BuildInfo`): millgate, its version
/// (the crate's) and the build's date: when the executable was written (the link; a
/// build records no date of its own, so two builds of one commit stay the same).
fn build_info() -> opcua::types::BuildInfo {
    let version = env!("CARGO_PKG_VERSION");
    let built = std::env::current_exe()
        .and_then(std::fs::metadata)
        .and_then(|file| file.modified())
        .map_or_else(|_| DateTime::null(), events::ua_time);
    opcua::types::BuildInfo {
        product_uri: PRODUCT_URI.into(),
        manufacturer_name: "millgate project".into(),
        product_name: "millgate".into(),
        software_version: version.into(),
        build_number: version.into(),
        build_date: built,
    }
}

/// The OPC UA status code of `quality`.
pub(crate) fn status_code(quality: Quality) -> StatusCode {
    match quality {
        Quality::Good => StatusCode::Good,
        Quality::UncertainLastUsableValue => StatusCode::UncertainLastUsableValue,
        Quality::BadWaitingForInitialData => StatusCode::BadWaitingForInitialData,
        Quality::BadNoCommunication => StatusCode::BadNoCommunication,
        Quality::BadDeviceFailure => StatusCode::BadDeviceFailure,
        Quality::BadOutOfRange => StatusCode::BadOutOfRange,
        Quality::BadNoData => StatusCode::BadNoData,
    }
}
