//! Northbound: the gateway as a Sparkplug B edge node on an MQTT broker
//! (`[outputs.mqtt]`).
//!
//! - [`payload`]: the Sparkplug B protobuf messages (prost, written by hand).
//! - [`devices`]: the devices and their metrics, from the catalogue of figures.
//! - [`node`]: the edge node's messages and sequence numbers, without I/O.
//! - `status.rs`: the counters `/metrics` shows and why a connection failed;
//!   `store.rs`: the node's state in the history file (bdSeq, the bites, the cursor).
//! - The task ([`SparkplugNode::run`]): one MQTT session at a time with `rumqttc`.
//!   Before each connection it takes the next `bdSeq` from the history file
//!   ([`next_bd_seq`]) and sets the Will (NDEATH with that bdSeq); at the broker's
//!   CONNACK it subscribes to its NCMD topic and publishes NBIRTH and the DBIRTHs;
//!   then every bite as its own DDATA at once and the other changed values every
//!   `data_period`; an NCMD `Node Control/Rebirth` gets the births again, at most once
//!   per [`REBIRTH_INTERVAL`] (requests meanwhile are answered by one rebirth at its
//!   end). An NCMD that is retained (Sparkplug forbids it), larger than
//!   [`MAX_COMMAND_BYTES`] or undecodable is refused and counted, and the session goes
//!   on; the client reads packets up to [`MAX_INCOMING_PACKET`]. A larger one ends the
//!   session: rumqttc refuses a packet by its header and ends the connection, it cannot
//!   skip the packet. The next connection then waits twice as long as the last, up to
//!   a minute, and first clears any retained message on the node's NCMD topic (an
//!   empty retained publish, before it subscribes), so a retained oversized NCMD ends
//!   one session, not every one. On a clean
//!   stop it publishes its NDEATH before disconnecting. Births and data are QoS 0 and
//!   not retained, the Will QoS 1, as the specification asks.
//!
//! - With `primary_host_id`, it also subscribes to the host's STATE and sends no
//!   birth until the host is online; a STATE offline gets the NDEATH and ends the
//!   session (the next one, with the next bdSeq, waits for the host again).
//!
//! - Bites go from the history file, in order, each as its own DDATA at QoS 1; bites
//!   the broker did not acknowledge before a session ended, or recorded while the
//!   broker or the primary host was away, are replayed flagged historical after the
//!   next births, paced ([`forward`]).
//!
//! - With `[outputs.mqtt.tls]` the session runs over TLS ([`tls`]); username and
//!   password go in the CONNECT.

pub mod devices;
pub mod forward;
mod metrics;
pub mod node;
pub mod payload;
mod status;
mod store;
mod timers;
pub mod tls;

pub use status::{ConnectFailure, SparkplugCounts, SparkplugStatus};
pub use store::next_bd_seq;

use std::path::PathBuf;
use std::sync::atomic::{AtomicI64, Ordering};
use std::sync::Arc;
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use tokio::time::Instant;

use millgate_config::MqttOutput;
use rumqttc::{
    AsyncClient, Event, EventLoop, LastWill, MqttOptions, Outgoing, Packet, QoS, TlsConfiguration,
    Transport,
};

use crate::history::query::{BiteRow, CaptureRow, Filter};
use crate::history::HistoryError;
use crate::shutdown::Shutdown;
use crate::state::board::Board;
use crate::warn_limit::{WarnLimit, WARN_PERIOD};
use forward::Confirmations;
use node::{CaptureNotice, EdgeNode};
use store::{keep_cursor, BiteSource};
pub use timers::REBIRTH_INTERVAL;
use timers::{Rebirths, Reconnect, RECONNECT_DELAY};

/// Requests the MQTT client queues for its event loop.
const CLIENT_QUEUE: usize = 256;
/// Bites handed to the client and not yet acknowledged, at most: below
/// [`CLIENT_QUEUE`], so the births and data of the session always find room.
const MAX_OUTSTANDING: usize = 192;
/// How long a clean stop waits for the PUBACKs of the bites in flight.
const STOP_ACK_WAIT: Duration = Duration::from_secs(1);
/// Largest MQTT packet the node reads, bytes (rumqttc's default, 10 KiB, let one
/// large NCMD end the session).
pub const MAX_INCOMING_PACKET: usize = 1 << 20;
/// Largest packet the node sends, bytes (rumqttc's default).
const MAX_OUTGOING_PACKET: usize = 10 * 1024;
/// Largest NCMD payload decoded, bytes (a Rebirth is about 40).
pub const MAX_COMMAND_BYTES: usize = 64 * 1024;

/// The edge node task.
#[derive(Debug)]
pub struct SparkplugNode {
    config: MqttOutput,
    history: PathBuf,
    board: Arc<Board>,
    status: Arc<SparkplugStatus>,
    tls: Option<Arc<rustls::ClientConfig>>,
    /// Rod mills: name and span count.
    rod_mills: Vec<(String, usize)>,
}

fn now_ms() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| u64::try_from(d.as_millis()).unwrap_or(u64::MAX))
}

impl SparkplugNode {
    /// The node of `config`, keeping its bdSeq in the history file `history`; fails
    /// when the TLS files of `config` cannot be used.
    pub fn new(
        config: MqttOutput,
        history: PathBuf,
        board: Arc<Board>,
    ) -> Result<Self, tls::TlsSetupError> {
        let tls = config.tls.as_ref().map(tls::client_config).transpose()?;
        Ok(Self {
            config,
            history,
            board,
            status: Arc::new(SparkplugStatus::default()),
            tls,
            rod_mills: Vec::new(),
        })
    }

    /// The node with these rod mills as devices: `(name, span count)` in config order
    /// (the span count from the mill file; it fixes the `span<i>` metrics at birth).
    pub fn with_rod_mills(mut self, rod_mills: Vec<(String, usize)>) -> Self {
        self.rod_mills = rod_mills;
        self
    }

    /// The counters, shared with `/metrics`.
    pub fn status(&self) -> Arc<SparkplugStatus> {
        Arc::clone(&self.status)
    }

    fn node_key(&self) -> String {
        format!("{}/{}", self.config.group_id, self.config.node_id)
    }

    /// The next bdSeq from the history file; `None` when the file cannot take it
    /// (logged as an error when `loud`, else at debug level).
    async fn stored_bd_seq(&self, loud: bool) -> Option<u8> {
        let (path, key) = (self.history.clone(), self.node_key());
        match tokio::task::spawn_blocking(move || next_bd_seq(&path, &key)).await {
            Ok(Ok(bd_seq)) => Some(bd_seq),
            Ok(Err(error)) if loud => {
                tracing::error!(%error, "Sparkplug bdSeq not read from the history file");
                None
            }
            Ok(Err(error)) => {
                tracing::debug!(%error, "Sparkplug bdSeq not read from the history file");
                None
            }
            Err(error) => {
                tracing::error!(%error, "Sparkplug bdSeq task failed");
                None
            }
        }
    }

    /// The next bdSeq; when the history file cannot take it, one more than `last`
    /// (logged: a host then may see a bdSeq repeat after a restart).
    async fn next_bd_seq(&self, last: u8) -> u8 {
        self.stored_bd_seq(true)
            .await
            .unwrap_or_else(|| last.wrapping_add(1))
    }

    /// `read` until it gives a value (every [`RECONNECT_DELAY`]; only the first
    /// failure is `loud`, logged as an error), `None` when `shutdown` came first: the
    /// session's first bdSeq and replay cursor come from the file, never from a
    /// default below what it holds.
    async fn from_file<T, F: std::future::Future<Output = Option<T>>>(
        shutdown: &mut Shutdown,
        mut read: impl FnMut(bool) -> F,
    ) -> Option<T> {
        let mut loud = true;
        loop {
            if let Some(value) = read(loud).await {
                return Some(value);
            }
            loud = false;
            tokio::select! {
                () = shutdown.recv() => return None,
                () = tokio::time::sleep(RECONNECT_DELAY) => {}
            }
        }
    }

    fn options(&self, will: node::Outgoing) -> MqttOptions {
        let (host, port) = self
            .config
            .broker
            .rsplit_once(':')
            .map(|(host, port)| (host.trim_matches(['[', ']']), port.parse().unwrap_or(1883)))
            .unwrap_or((self.config.broker.as_str(), 1883));
        let mut options = MqttOptions::new(self.config.client_id.clone(), host, port);
        options.set_keep_alive(self.config.keep_alive);
        options.set_max_packet_size(MAX_INCOMING_PACKET, MAX_OUTGOING_PACKET);
        options.set_clean_session(true);
        options.set_last_will(LastWill::new(
            will.topic,
            will.payload,
            QoS::AtLeastOnce,
            false,
        ));
        if let Some((user, password)) = &self.config.credentials {
            options.set_credentials(user.clone(), password.clone());
        }
        if let Some(config) = &self.tls {
            options.set_transport(Transport::tls_with_config(TlsConfiguration::Rustls(
                Arc::clone(config),
            )));
        }
        options
    }

    /// Hand `message` to the client, noting it in `confirmations` (`bite`: the row id
    /// of the bite it carries); false when the client's queue is full.
    fn send(
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

    fn publish(
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
    async fn births(
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
    async fn forward(
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
    async fn announce_mill_captures(
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

    /// The stored replay cursor (the history's last bite for a new node); `None`
    /// when the file cannot be read (logged as an error when `loud`).
    async fn load_cursor(&self, loud: bool) -> Option<i64> {
        let (path, key) = (self.history.clone(), self.node_key());
        match tokio::task::spawn_blocking(move || forward::load_cursor(&path, &key)).await {
            Ok(Ok(cursor)) => Some(cursor),
            Ok(Err(error)) if loud => {
                tracing::error!(%error, "Sparkplug replay cursor not read from the history file");
                None
            }
            Ok(Err(error)) => {
                tracing::debug!(%error, "Sparkplug replay cursor not read from the history file");
                None
            }
            Err(error) => {
                tracing::error!(%error, "Sparkplug cursor task failed");
                None
            }
        }
    }

    /// Whether the NCMD `message` is to be obeyed (`Some` for a rebirth); a retained,
    /// oversized or undecodable one is refused: counted, warned (once per
    /// [`WARN_PERIOD`] with the number suppressed), and the session goes on.
    fn command(&self, message: &rumqttc::Publish, warnings: &mut WarnLimit) -> Option<()> {
        let refused = if message.retain {
            Some("retained (Sparkplug NCMDs are never retained): clear it on the broker".to_owned())
        } else if message.payload.len() > MAX_COMMAND_BYTES {
            Some(format!(
                "{} bytes, more than {MAX_COMMAND_BYTES}",
                message.payload.len()
            ))
        } else {
            match node::is_rebirth(&message.payload) {
                Ok(rebirth) => return rebirth.then_some(()),
                Err(error) => Some(format!("undecodable: {error}")),
            }
        };
        if let Some(reason) = refused {
            self.status.commands_refused.fetch_add(1, Ordering::Relaxed);
            if let Some(suppressed) = warnings.occurred(Instant::now()) {
                tracing::warn!(topic = %message.topic, suppressed, "Sparkplug NCMD refused: {reason}");
            }
        }
        None
    }

    /// Publish until `shutdown`, reconnecting with a new bdSeq after each lost session.
    pub async fn run(self, mut shutdown: Shutdown) {
        let board = Arc::clone(&self.board);
        let Some(mut bd_seq) =
            Self::from_file(&mut shutdown, |loud| self.stored_bd_seq(loud)).await
        else {
            return;
        };
        let Some(cursor) = Self::from_file(&mut shutdown, |loud| self.load_cursor(loud)).await
        else {
            return;
        };
        let mut confirmations = Confirmations::new(cursor);
        // The cursor is stored and the backlog counted by a task of its own: a timer
        // in the select below would cancel the event loop's poll, and a CONNECT in
        // flight with it (the broker then sees the next CONNECT take the session over
        // and sends the Will).
        let confirmed = Arc::new(AtomicI64::new(confirmations.confirmed()));
        let (stop_keeper, keeper_stop) = tokio::sync::oneshot::channel();
        let keeper = tokio::spawn(keep_cursor(
            self.history.clone(),
            self.node_key(),
            Arc::clone(&self.status),
            Arc::clone(&confirmed),
            keeper_stop,
        ));
        let mut bites = BiteSource::new(self.history.clone());
        let mut node = EdgeNode::new(
            &self.config.group_id,
            &self.config.node_id,
            (board.driveline_names(), board.tandem_mill_names()),
            &self.rod_mills,
            bd_seq,
        );
        self.status.bd_seq.store(bd_seq, Ordering::Relaxed);
        let (client, mut events) =
            AsyncClient::new(self.options(node.death(now_ms())), CLIENT_QUEUE);
        let command_qos = if self.config.command_qos == 0 {
            QoS::AtMostOnce
        } else {
            QoS::AtLeastOnce
        };
        let state_topic = self
            .config
            .primary_host_id
            .as_deref()
            .map(node::state_topic);
        let mut connected = false;
        // The last failure logged as a warning: the same failure again is only debug.
        let mut last_failure = None;
        // Births sent in this session (with a primary host: after its STATE online).
        let mut born = false;
        // While replaying: the last bite id of the backlog.
        let mut replay_end: Option<i64> = None;
        let replay_batch = usize::try_from(self.config.replay_batch).unwrap_or(usize::MAX);
        // Bites go out as the history stores them: woken by its settled events.
        let mut stored = board.changes();
        // The last capture looked at for the tandem mills' announcements.
        let mut announced: Option<i64> = None;
        // Paced from each session's births (reset there); a late batch delays the
        // next ones rather than bursting.
        let mut replay = tokio::time::interval(self.config.replay_period);
        replay.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        let mut data = tokio::time::interval(self.config.data_period);
        let mut rebirths = Rebirths::new();
        let mut command_warnings = WarnLimit::new(WARN_PERIOD);
        let mut reconnect = Reconnect::new();
        // Set by a packet over the size limit: the next session clears its NCMD topic's
        // retained message before subscribing.
        let mut clear_retained_command = false;
        loop {
            tokio::select! {
                () = shutdown.recv() => break,
                event = events.poll() => match event {
                    Ok(Event::Incoming(Packet::ConnAck(_))) => {
                        last_failure = None;
                        rebirths.forget();
                        tracing::info!(broker = %self.config.broker, bd_seq, "Sparkplug session up");
                        connected = true;
                        self.status.connected.store(1, Ordering::Relaxed);
                        self.status.connections.fetch_add(1, Ordering::Relaxed);
                        if std::mem::take(&mut clear_retained_command) {
                            // The broker handles a client's packets in order: the
                            // retained message is gone before the subscription.
                            tracing::warn!(topic = node.command_topic(), "clearing any retained NCMD on the broker (a packet over the size limit ended the last session; NCMDs are never retained)");
                            if let Err(error) = client.try_publish(node.command_topic(), QoS::AtLeastOnce, true, Vec::new()) {
                                tracing::warn!(%error, "Sparkplug retained NCMD clear not queued");
                            }
                        }
                        if let Err(error) = client.try_subscribe(node.command_topic(), command_qos) {
                            tracing::warn!(%error, "Sparkplug NCMD subscription not queued");
                        }
                        match &state_topic {
                            Some(topic) => {
                                if let Err(error) = client.try_subscribe(topic.clone(), QoS::AtLeastOnce) {
                                    tracing::warn!(%error, "Sparkplug STATE subscription not queued");
                                }
                            }
                            None => {
                                replay_end = self.births(&client, &mut node, &mut confirmations, &mut bites).await;
                                replay.reset_immediately();
                                born = true;
                                rebirths.born();
                            }
                        }
                    }
                    Ok(Event::Incoming(Packet::PubAck(ack))) => confirmations.acknowledged(ack.pkid),
                    Ok(Event::Outgoing(Outgoing::Publish(pkid))) => confirmations.written(pkid),
                    Ok(Event::Incoming(Packet::Publish(message))) => {
                        if message.topic == node.command_topic() {
                            match self.command(&message, &mut command_warnings) {
                                Some(()) if born => {
                                    self.status.rebirth_requests.fetch_add(1, Ordering::Relaxed);
                                    rebirths.requested();
                                }
                                _ => {}
                            }
                        } else if state_topic.as_deref() == Some(message.topic.as_str()) {
                            match node::host_online(&message.payload) {
                                Some(true) if !born => {
                                    tracing::info!(host = ?self.config.primary_host_id, "primary host online");
                                    replay_end = self.births(&client, &mut node, &mut confirmations, &mut bites).await;
                                    replay.reset_immediately();
                                    born = true;
                                    rebirths.born();
                                }
                                Some(false) if born => {
                                    // The specification: NDEATH and disconnect; the next
                                    // session waits for the host again.
                                    tracing::warn!(host = ?self.config.primary_host_id, "primary host offline: ending the session");
                                    self.send(&client, &mut confirmations, node.death(now_ms()), QoS::AtLeastOnce, None);
                                    let _ = client.try_disconnect();
                                    born = false;
                                }
                                Some(_) => {}
                                None => tracing::warn!(topic = %message.topic, "unreadable Sparkplug STATE"),
                            }
                        }
                    }
                    Ok(_) => {}
                    Err(error) => {
                        let failure = ConnectFailure::of(&error);
                        // A packet over the limit (a huge NCMD, retained perhaps, that
                        // the broker sends at every subscription) ends each session:
                        // wait longer each time rather than reconnect every second.
                        let oversize = is_oversize(&error);
                        let delay = reconnect.delay(oversize);
                        if oversize {
                            tracing::warn!(%error, limit = MAX_INCOMING_PACKET, next_attempt_s = delay.as_secs(), "Sparkplug session ended by a packet over the size limit (a retained NCMD on the broker? clear it there)");
                            clear_retained_command = true;
                        }
                        let slot = ConnectFailure::ALL.iter().position(|&f| f == failure).unwrap_or(0);
                        self.status.failures[slot].fetch_add(1, Ordering::Relaxed);
                        if connected {
                            tracing::warn!(%error, broker = %self.config.broker, "Sparkplug session ended");
                        } else if last_failure != Some(failure) {
                            tracing::warn!(%error, broker = %self.config.broker, reason = failure.name(), "Sparkplug broker connection failed, retrying every {} s: {}", RECONNECT_DELAY.as_secs(), failure.hint());
                        } else {
                            tracing::debug!(%error, broker = %self.config.broker, "Sparkplug broker connection failed again");
                        }
                        last_failure = Some(failure);
                        // What the dead session had queued belongs to it: its seq
                        // numbers mean nothing in the next session. Its unacknowledged
                        // bites are replayed from the history.
                        drop_pending(&mut events);
                        confirmations.session_lost();
                        replay_end = None;
                        // A new bdSeq only after a session the broker accepted: a
                        // refused or failed CONNECT never registered its Will.
                        if connected {
                            bd_seq = self.next_bd_seq(bd_seq).await;
                            node.new_session(bd_seq);
                            self.status.bd_seq.store(bd_seq, Ordering::Relaxed);
                            let will = node.death(now_ms());
                            events.mqtt_options.set_last_will(LastWill::new(will.topic, will.payload, QoS::AtLeastOnce, false));
                        }
                        connected = false;
                        born = false;
                        self.status.connected.store(0, Ordering::Relaxed);
                        tokio::select! {
                            () = shutdown.recv() => break,
                            () = tokio::time::sleep(delay) => {}
                        }
                    }
                },
                _ = replay.tick(), if born && replay_end.is_some() => {
                    if let Some(end) = replay_end {
                        let step = Step::Replay { batch: replay_batch, end };
                        self.forward(&client, &mut node, &mut confirmations, &mut bites, step).await;
                    }
                    if replay_end.is_some_and(|end| confirmations.read() >= end) {
                        tracing::info!(replayed = self.status.replayed.load(Ordering::Relaxed), "Sparkplug backlog replayed");
                        replay_end = None;
                    }
                }
                _ = stored.settled(), if born && replay_end.is_none() => {
                    self.forward(&client, &mut node, &mut confirmations, &mut bites, Step::Live).await;
                    self.announce_mill_captures(&client, &mut node, &mut confirmations, &mut bites, &mut announced).await;
                }
                () = tokio::time::sleep_until(rebirths.due()), if born && rebirths.wanted() => {
                    // Every request since the last births, answered by one rebirth.
                    rebirths.born();
                    tracing::info!("Sparkplug rebirth on command");
                    self.status.rebirths.fetch_add(1, Ordering::Relaxed);
                    let captures = newest_captures(&mut bites, capture_subjects(&board)).await;
                    let results = board.results();
                    self.publish(&client, &mut confirmations, node.births(&results, &captures, now_ms()));
                }
                _ = data.tick(), if born => {
                    self.publish(&client, &mut confirmations, node.data(&board.results(), now_ms()));
                }
            }
            confirmed.store(confirmations.confirmed(), Ordering::Relaxed);
        }
        if born {
            // A clean stop: the PUBACKs of the bites in flight (so the next start does
            // not replay them), the NDEATH the Will would have sent, then DISCONNECT
            // (which discards the Will).
            let acks = async {
                while confirmations.outstanding() > 0 {
                    match events.poll().await {
                        Ok(Event::Incoming(Packet::PubAck(ack))) => {
                            confirmations.acknowledged(ack.pkid)
                        }
                        Ok(Event::Outgoing(Outgoing::Publish(pkid))) => confirmations.written(pkid),
                        Ok(_) => {}
                        Err(_) => break,
                    }
                }
            };
            let _ = tokio::time::timeout(STOP_ACK_WAIT, acks).await;
            let death = node.death(now_ms());
            let _ = client.try_publish(death.topic, QoS::AtLeastOnce, false, death.payload);
            let _ = client.try_disconnect();
            let flush = async {
                while let Ok(event) = events.poll().await {
                    if matches!(event, Event::Outgoing(Outgoing::Disconnect)) {
                        break;
                    }
                }
            };
            let _ = tokio::time::timeout(Duration::from_secs(2), flush).await;
        }
        confirmed.store(confirmations.confirmed(), Ordering::Relaxed);
        let _ = stop_keeper.send(());
        let _ = keeper.await;
        self.status.connected.store(0, Ordering::Relaxed);
    }
}

/// Which bites [`SparkplugNode::forward`] publishes.
#[derive(Debug, Clone, Copy)]
enum Step {
    /// The backlog: at most `batch` bites, none after row `end`, flagged historical.
    Replay { batch: usize, end: i64 },
    /// What was recorded after the backlog, live.
    Live,
}

/// Whether `error` is an incoming packet over [`MAX_INCOMING_PACKET`].
fn is_oversize(error: &rumqttc::ConnectionError) -> bool {
    matches!(
        error,
        rumqttc::ConnectionError::MqttState(rumqttc::StateError::Deserialization(
            rumqttc::Error::PayloadSizeLimitExceeded(_)
        ))
    )
}

/// Drop what the event loop would send at its next connection.
fn drop_pending(events: &mut EventLoop) {
    events.clean();
    events.pending.clear();
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
fn capture_subjects(board: &Board) -> Vec<String> {
    let mut names = board.driveline_names().to_vec();
    names.extend_from_slice(board.tandem_mill_names());
    names
}

/// The newest capture of each driveline or tandem mill (`names`, in order) in the
/// history, for the births; none where the file cannot be read.
async fn newest_captures(bites: &mut BiteSource, names: Vec<String>) -> Vec<Option<CaptureNotice>> {
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
