//! One edge node's MQTT sessions, one at a time ([`Session::run`]): the state a session
//! keeps (the client, the node's sequence numbers, what the broker confirmed, whether
//! the births went out, the backlog still to replay) and what each event does to it:
//! the broker's CONNACK, an NCMD or the primary host's STATE, a lost connection, the
//! replay and data timers, a rebirth, the clean stop.

use std::sync::atomic::{AtomicI64, Ordering};
use std::sync::Arc;
use std::time::Duration;

use rumqttc::{AsyncClient, Event, EventLoop, Outgoing, Packet, QoS};
use tokio::time::{Instant, Interval};

use super::forward::Confirmations;
use super::node::{self, EdgeNode};
use super::outbox::{capture_subjects, newest_captures, Step};
use super::store::{keep_cursor, BiteSource};
use super::timers::{Rebirths, Reconnect, RECONNECT_DELAY};
use super::{
    now_ms, ConnectFailure, SparkplugNode, CLIENT_QUEUE, MAX_COMMAND_BYTES, MAX_INCOMING_PACKET,
};
use crate::shutdown::Shutdown;
use crate::state::changes::Changes;
use crate::warn_limit::{WarnLimit, WARN_PERIOD};

/// How long a clean stop waits for the PUBACKs of the bites in flight.
const STOP_ACK_WAIT: Duration = Duration::from_secs(1);

impl SparkplugNode {
    /// Publish until `shutdown`, reconnecting with a new bdSeq after each lost session.
    pub async fn run(self, mut shutdown: Shutdown) {
        let Some(bd_seq) = Self::from_file(&mut shutdown, |loud| self.stored_bd_seq(loud)).await
        else {
            return;
        };
        let Some(cursor) = Self::from_file(&mut shutdown, |loud| self.load_cursor(loud)).await
        else {
            return;
        };
        let confirmations = Confirmations::new(cursor);
        // The cursor is stored and the backlog counted by a task of its own: a timer
        // in the session's select would cancel the event loop's poll, and a CONNECT in
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
        Session::new(&self, bd_seq, confirmations)
            .run(&mut shutdown, &confirmed)
            .await;
        let _ = stop_keeper.send(());
        let _ = keeper.await;
        self.status.connected.store(0, Ordering::Relaxed);
    }
}

/// The node's sessions with the broker, and what carries over from one to the next.
pub(super) struct Session<'a> {
    task: &'a SparkplugNode,
    client: AsyncClient,
    events: EventLoop,
    node: EdgeNode,
    confirmations: Confirmations,
    bites: BiteSource,
    bd_seq: u8,
    /// The server in use: its index in `brokers`.
    server: usize,
    command_qos: QoS,
    /// The primary host's STATE topic, with `primary_host_id`.
    state_topic: Option<String>,
    /// The broker accepted this session (CONNACK).
    connected: bool,
    /// The last failure logged as a warning: the same failure again is only debug.
    last_failure: Option<ConnectFailure>,
    /// Births sent in this session (with a primary host: after its STATE online).
    born: bool,
    /// While replaying: the last bite id of the backlog.
    replay_end: Option<i64>,
    replay_batch: usize,
    /// Bites go out as the history stores them: woken by its settled events.
    stored: Changes,
    /// The last capture looked at for the tandem mills' announcements.
    announced: Option<i64>,
    /// Paced from each session's births (reset there); a late batch delays the next
    /// ones rather than bursting.
    replay: Interval,
    data: Interval,
    rebirths: Rebirths,
    command_warnings: WarnLimit,
    reconnect: Reconnect,
    /// Set by a packet over the size limit: the next session clears its NCMD topic's
    /// retained message before subscribing.
    clear_retained_command: bool,
}

impl<'a> Session<'a> {
    /// The sessions of `task`, the first with `bd_seq`, bites confirmed up to
    /// `confirmations`' cursor.
    pub(super) fn new(task: &'a SparkplugNode, bd_seq: u8, confirmations: Confirmations) -> Self {
        let config = &task.config;
        let node = EdgeNode::new(
            &config.group_id,
            &config.node_id,
            (
                &task.board.driveline_names(),
                task.board.tandem_mill_names(),
            ),
            &task.rod_mills,
            bd_seq,
        );
        task.status.bd_seq.store(bd_seq, Ordering::Relaxed);
        task.status.session_down();
        let (client, events) =
            AsyncClient::new(task.options(0, node.death(now_ms())), CLIENT_QUEUE);
        let mut replay = tokio::time::interval(config.replay_period);
        replay.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        Self {
            task,
            client,
            events,
            node,
            confirmations,
            bites: BiteSource::new(task.history.clone()),
            bd_seq,
            server: 0,
            command_qos: if config.command_qos == 0 {
                QoS::AtMostOnce
            } else {
                QoS::AtLeastOnce
            },
            state_topic: config.primary_host_id.as_deref().map(node::state_topic),
            connected: false,
            last_failure: None,
            born: false,
            replay_end: None,
            replay_batch: usize::try_from(config.replay_batch).unwrap_or(usize::MAX),
            stored: task.board.changes(),
            announced: None,
            replay,
            data: tokio::time::interval(config.data_period),
            rebirths: Rebirths::new(),
            command_warnings: WarnLimit::new(WARN_PERIOD),
            reconnect: Reconnect::new(),
            clear_retained_command: false,
        }
    }

    /// Sessions until `shutdown`, a new bdSeq after each lost one; `confirmed` follows
    /// the bites the broker confirmed (the cursor keeper stores it).
    pub(super) async fn run(mut self, shutdown: &mut Shutdown, confirmed: &AtomicI64) {
        loop {
            tokio::select! {
                () = shutdown.recv() => break,
                event = self.events.poll() => match event {
                    Ok(Event::Incoming(Packet::ConnAck(_))) => self.accepted().await,
                    Ok(Event::Incoming(Packet::PubAck(ack))) => self.confirmations.acknowledged(ack.pkid),
                    Ok(Event::Outgoing(Outgoing::Publish(pkid))) => self.confirmations.written(pkid),
                    Ok(Event::Incoming(Packet::Publish(message))) => self.incoming(&message).await,
                    Ok(_) => {}
                    Err(error) => {
                        let delay = self.lost(&error).await;
                        tokio::select! {
                            () = shutdown.recv() => break,
                            () = tokio::time::sleep(delay) => {}
                        }
                    }
                },
                _ = self.replay.tick(), if self.born && self.replay_end.is_some() => self.replay_step().await,
                _ = self.stored.settled(), if self.born && self.replay_end.is_none() => {
                    self.task.forward(&self.client, &mut self.node, &mut self.confirmations, &mut self.bites, Step::Live).await;
                    self.task.announce_mill_captures(&self.client, &mut self.node, &mut self.confirmations, &mut self.bites, &mut self.announced).await;
                }
                () = tokio::time::sleep_until(self.rebirths.due()), if self.born && self.rebirths.wanted() => self.rebirth().await,
                _ = self.data.tick(), if self.born => {
                    let data = self.node.data(&self.task.board.results(), now_ms());
                    self.task.publish(&self.client, &mut self.confirmations, data);
                }
            }
            confirmed.store(self.confirmations.confirmed(), Ordering::Relaxed);
        }
        if self.born {
            self.stop().await;
        }
        confirmed.store(self.confirmations.confirmed(), Ordering::Relaxed);
    }

    /// The broker's CONNACK: subscribe to the NCMD topic (after clearing a retained
    /// NCMD when an oversized packet ended the last session), then the births, or the
    /// primary host's STATE subscription that waits for it.
    async fn accepted(&mut self) {
        let task = self.task;
        self.last_failure = None;
        self.rebirths.forget();
        tracing::info!(broker = %self.broker(), bd_seq = self.bd_seq, "Sparkplug session up");
        self.connected = true;
        task.status.session_up();
        let command_topic = self.node.command_topic();
        if std::mem::take(&mut self.clear_retained_command) {
            // The broker handles a client's packets in order: the retained message is
            // gone before the subscription.
            tracing::warn!(topic = command_topic, "clearing any retained NCMD on the broker (a packet over the size limit ended the last session; NCMDs are never retained)");
            if let Err(error) =
                self.client
                    .try_publish(command_topic.clone(), QoS::AtLeastOnce, true, Vec::new())
            {
                tracing::warn!(%error, "Sparkplug retained NCMD clear not queued");
            }
        }
        if let Err(error) = self.client.try_subscribe(command_topic, self.command_qos) {
            tracing::warn!(%error, "Sparkplug NCMD subscription not queued");
        }
        match &self.state_topic {
            Some(topic) => {
                if let Err(error) = self.client.try_subscribe(topic.clone(), QoS::AtLeastOnce) {
                    tracing::warn!(%error, "Sparkplug STATE subscription not queued");
                }
            }
            None => self.births().await,
        }
    }

    /// The session's births; the backlog's replay starts.
    async fn births(&mut self) {
        self.replay_end = self
            .task
            .births(
                &self.client,
                &mut self.node,
                &mut self.confirmations,
                &mut self.bites,
            )
            .await;
        self.replay.reset_immediately();
        self.born = true;
        self.rebirths.born();
    }

    /// A message on a subscribed topic: an NCMD, or the primary host's STATE.
    async fn incoming(&mut self, message: &rumqttc::Publish) {
        if message.topic == self.node.command_topic() {
            if self.command(message) && self.born {
                let requests = &self.task.status.rebirth_requests;
                requests.fetch_add(1, Ordering::Relaxed);
                self.rebirths.requested();
            }
            return;
        }
        if self.state_topic.as_deref() != Some(message.topic.as_str()) {
            return;
        }
        let host = &self.task.config.primary_host_id;
        match node::host_online(&message.payload) {
            Some(true) if !self.born => {
                tracing::info!(?host, "primary host online");
                self.births().await;
            }
            Some(false) if self.born => {
                // The specification: NDEATH and disconnect; the next session waits for
                // the host again.
                tracing::warn!(?host, "primary host offline: ending the session");
                let death = self.node.death(now_ms());
                self.task.send(
                    &self.client,
                    &mut self.confirmations,
                    death,
                    QoS::AtLeastOnce,
                    None,
                );
                let _ = self.client.try_disconnect();
                self.born = false;
            }
            Some(false) if self.task.config.brokers.len() > 1 => {
                // Sparkplug 3.0: with several servers, a primary host offline on this
                // one sends the node on to the next.
                tracing::warn!(?host, broker = %self.broker(), "primary host offline on this MQTT server: moving on to the next");
                let _ = self.client.try_disconnect();
            }
            Some(_) => {}
            None => tracing::warn!(topic = %message.topic, "unreadable Sparkplug STATE"),
        }
    }

    /// Whether the NCMD `message` asks for a rebirth; a retained, oversized or
    /// undecodable one is refused: counted, warned (once per [`WARN_PERIOD`] with the
    /// number suppressed), and the session goes on.
    fn command(&mut self, message: &rumqttc::Publish) -> bool {
        let reason = if message.retain {
            "retained (Sparkplug NCMDs are never retained): clear it on the broker".to_owned()
        } else if message.payload.len() > MAX_COMMAND_BYTES {
            format!(
                "{} bytes, more than {MAX_COMMAND_BYTES}",
                message.payload.len()
            )
        } else {
            match node::is_rebirth(&message.payload) {
                Ok(rebirth) => return rebirth,
                Err(error) => format!("undecodable: {error}"),
            }
        };
        let refused = &self.task.status.commands_refused;
        refused.fetch_add(1, Ordering::Relaxed);
        if let Some(suppressed) = self.command_warnings.occurred(Instant::now()) {
            tracing::warn!(topic = %message.topic, suppressed, "Sparkplug NCMD refused: {reason}");
        }
        false
    }

    /// The connection failed or the session ended: counted and logged, what the
    /// session had queued dropped, a new bdSeq (and Will) after a session the broker
    /// had accepted or a CONNECT it may have taken
    /// ([`ConnectFailure::may_have_registered_will`]).
    /// Returns the wait before the next connection.
    async fn lost(&mut self, error: &rumqttc::ConnectionError) -> Duration {
        let task = self.task;
        let broker = self.broker().to_owned();
        let failure = ConnectFailure::of(error);
        // A session that was up, or a new kind of failure, is logged at info or above;
        // the same failure again (every server down) at debug.
        let news = self.connected || self.last_failure != Some(failure);
        // A packet over the limit (a huge NCMD, retained perhaps, that the broker
        // sends at every subscription) ends each session: wait longer each time rather
        // than reconnect every second.
        let oversize = is_oversize(error);
        let delay = self.reconnect.delay(oversize);
        if oversize {
            tracing::warn!(%error, limit = MAX_INCOMING_PACKET, next_attempt_s = delay.as_secs(), "Sparkplug session ended by a packet over the size limit (a retained NCMD on the broker? clear it there)");
            self.clear_retained_command = true;
        }
        let slot = ConnectFailure::ALL
            .iter()
            .position(|&f| f == failure)
            .unwrap_or(0);
        task.status.failures[slot].fetch_add(1, Ordering::Relaxed);
        if self.connected {
            tracing::warn!(%error, %broker, "Sparkplug session ended");
        } else if news {
            tracing::warn!(%error, %broker, reason = failure.name(), "Sparkplug broker connection failed, retrying every {} s: {}", RECONNECT_DELAY.as_secs(), failure.hint());
        } else {
            tracing::debug!(%error, %broker, "Sparkplug broker connection failed again");
        }
        self.last_failure = Some(failure);
        // What the dead session had queued belongs to it: its seq numbers mean nothing
        // in the next session. Its unacknowledged bites are replayed from the history.
        self.events.clean();
        self.events.pending.clear();
        self.confirmations.session_lost();
        self.replay_end = None;
        // A new bdSeq after every CONNECT the broker may have taken (Sparkplug 3.0: one
        // bdSeq per CONNECT): a CONNECT that timed out can still be read by a broker that
        // was only slow, which then registers its Will and publishes that NDEATH when the
        // socket closes. With the same bdSeq the next session would be declared dead by it.
        if self.connected || ConnectFailure::may_have_registered_will(error) {
            self.bd_seq = task.next_bd_seq(self.bd_seq).await;
            self.node.new_session(self.bd_seq);
            task.status.bd_seq.store(self.bd_seq, Ordering::Relaxed);
        }
        // With a server set, the next connection goes to the next server.
        let servers = task.config.brokers.len();
        if servers > 1 {
            self.server = (self.server + 1) % servers;
            task.status.switched_to(self.server);
            let next = self.broker();
            if news {
                tracing::info!(from = %broker, to = %next, next_attempt_ms = delay.as_millis(), "Sparkplug moving on to the next MQTT server");
            } else {
                tracing::debug!(from = %broker, to = %next, "Sparkplug moving on to the next MQTT server");
            }
        }
        // The next CONNECT's server and Will (this session's bdSeq).
        self.events.mqtt_options = task.options(self.server, self.node.death(now_ms()));
        self.connected = false;
        self.born = false;
        task.status.session_down();
        delay
    }

    /// The server in use, `host:port`.
    fn broker(&self) -> &str {
        &self.task.config.brokers[self.server]
    }

    /// The next batch of the backlog, flagged historical; the replay ends with it.
    async fn replay_step(&mut self) {
        if let Some(end) = self.replay_end {
            let step = Step::Replay {
                batch: self.replay_batch,
                end,
            };
            self.task
                .forward(
                    &self.client,
                    &mut self.node,
                    &mut self.confirmations,
                    &mut self.bites,
                    step,
                )
                .await;
        }
        if self
            .replay_end
            .is_some_and(|end| self.confirmations.read() >= end)
        {
            let replayed = self.task.status.replayed.load(Ordering::Relaxed);
            tracing::info!(replayed, "Sparkplug backlog replayed");
            self.replay_end = None;
        }
    }

    /// Every rebirth request since the last births, answered by one rebirth.
    async fn rebirth(&mut self) {
        self.rebirths.born();
        tracing::info!("Sparkplug rebirth on command");
        let task = self.task;
        task.status.rebirths.fetch_add(1, Ordering::Relaxed);
        let captures = newest_captures(&mut self.bites, capture_subjects(&task.board)).await;
        let births = self.node.births(&task.board.results(), &captures, now_ms());
        task.publish(&self.client, &mut self.confirmations, births);
    }

    /// A clean stop: the PUBACKs of the bites in flight (so the next start does not
    /// replay them), the NDEATH the Will would have sent, then DISCONNECT (which
    /// discards the Will).
    async fn stop(&mut self) {
        let (events, confirmations) = (&mut self.events, &mut self.confirmations);
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
        let death = self.node.death(now_ms());
        let _ = self
            .client
            .try_publish(death.topic, QoS::AtLeastOnce, false, death.payload);
        let _ = self.client.try_disconnect();
        let flush = async {
            while let Ok(event) = self.events.poll().await {
                if matches!(event, Event::Outgoing(Outgoing::Disconnect)) {
                    break;
                }
            }
        };
        let _ = tokio::time::timeout(Duration::from_secs(2), flush).await;
    }
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
