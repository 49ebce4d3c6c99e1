//! Prometheus `/metrics` endpoint: acquisition counters per channel and health per
//! source, in the text exposition format (version 0.0.4).
//!
//! A minimal HTTP/1.1 responder on tokio: it reads the whole request head (at most
//! 8 KiB within 5 s, [`crate::outputs::http_head`]), answers `GET /metrics`, 404 for
//! another path, 405 for another method, 400 for a malformed head, one request per
//! connection, at most 16 at once. Pulling in an HTTP framework for one read-only
//! page on loopback would add far more than it saves.

use std::fmt::Write as _;
use std::sync::Arc;

use millgate_config::Config;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};

use crate::field::counters::{CanCounters, CanCounts, ChannelCounters, ChannelCountersSnapshot};
use crate::field::source_health::SourceHealth;
use crate::outputs::history::HistoryStatus;
use crate::outputs::hmi_server::{ServerCounters, ServerCounts};
use crate::outputs::http_head::{self, HeadError};
use crate::outputs::publisher::Publisher;
use crate::warn_limit::{WarnLimit, WARN_PERIOD};

/// Time a client has to send its whole request head.
pub const HEAD_TIMEOUT: std::time::Duration = std::time::Duration::from_secs(5);
/// Scrapes answered at once; Prometheus sends one at a time.
pub const MAX_SCRAPES: usize = 16;
use crate::outputs::results::{DrivelineResults, MillResults};
use crate::outputs::sparkplug::{SparkplugCounts, SparkplugStatus};
use crate::shutdown::Shutdown;

/// Reads one counter out of a snapshot.
type CounterOf = fn(&ChannelCountersSnapshot) -> u64;

/// Reads one counter out of CAN counts.
type CanCounterOf = fn(&CanCounts) -> u64;

/// A per-CAN-source metric: name, type, help, value as printed.
type CanMetric = (
    &'static str,
    &'static str,
    &'static str,
    fn(&CanCounts) -> String,
);

/// What the metrics page shows.
#[derive(Debug)]
pub struct Metrics {
    channel_names: Vec<String>,
    source_names: Vec<String>,
    counters: Vec<Arc<ChannelCounters>>,
    health: Vec<Arc<SourceHealth>>,
    can_names: Vec<String>,
    can_counters: Vec<Arc<CanCounters>>,
    publisher: Arc<Publisher>,
    server: Option<Arc<ServerCounters>>,
    sparkplug: Option<Arc<SparkplugStatus>>,
}

/// Writes one metric family, `(name, type, help)`: HELP, TYPE and one sample per
/// labelled row that has a value.
fn family<'a>(
    out: &mut String,
    (metric, kind, help): (&str, &str, &str),
    label: &str,
    rows: impl Iterator<Item = (&'a str, Option<f64>)>,
) {
    let _ = writeln!(out, "# HELP {metric} {help}");
    let _ = writeln!(out, "# TYPE {metric} {kind}");
    for (name, value) in rows {
        if let Some(value) = value {
            let _ = writeln!(out, "{metric}{{{label}=\"{}\"}} {value}", escape(name));
        }
    }
}

/// The Sparkplug B edge node's families.
fn sparkplug_metrics(out: &mut String, counts: &SparkplugCounts) {
    let scalars: [(&str, &str, &str, u64); 8] = [
        (
            "millgate_sparkplug_connected",
            "gauge",
            "1 while a session with the MQTT broker is up.",
            u64::from(counts.connected),
        ),
        (
            "millgate_sparkplug_bd_seq",
            "gauge",
            "The current session's Sparkplug bdSeq (0..=255).",
            u64::from(counts.bd_seq),
        ),
        (
            "millgate_sparkplug_messages_published_total",
            "counter",
            "Sparkplug messages handed to the broker connection.",
            counts.published,
        ),
        (
            "millgate_sparkplug_bites_published_total",
            "counter",
            "Bites published live as their own DDATA.",
            counts.bites,
        ),
        (
            "millgate_sparkplug_replayed_total",
            "counter",
            "Bites replayed from the history as DDATA flagged historical.",
            counts.replayed,
        ),
        (
            "millgate_sparkplug_backlog_bites",
            "gauge",
            "Bites in the history the broker has not confirmed (PUBACK) yet.",
            counts.backlog,
        ),
        (
            "millgate_sparkplug_sessions_total",
            "counter",
            "Sessions the MQTT broker accepted.",
            counts.connections,
        ),
        (
            "millgate_sparkplug_rebirths_total",
            "counter",
            "Node Control/Rebirth commands obeyed.",
            counts.rebirths,
        ),
    ];
    for (name, kind, help, value) in scalars {
        let _ = writeln!(out, "# HELP {name} {help}");
        let _ = writeln!(out, "# TYPE {name} {kind}");
        let _ = writeln!(out, "{name} {value}");
    }
}

/// The history's families: state, events stored and dropped, commits, retention,
/// the file's size and the last error (as an info metric with the message as label).
fn history_metrics(out: &mut String, status: &HistoryStatus) {
    let scalars: [(&str, &str, &str, String); 8] = [
        (
            "millgate_history_state",
            "gauge",
            "Event history: 0 disabled, 1 ok, 2 failing (see millgate_history_last_error_info).",
            status.state.code().to_string(),
        ),
        (
            "millgate_history_events_stored_total",
            "counter",
            "Events committed to the history file.",
            status.stored.to_string(),
        ),
        (
            "millgate_history_queue_events",
            "gauge",
            "Events waiting for the history writer.",
            status
                .enqueued
                .saturating_sub(status.stored + status.dropped_error)
                .to_string(),
        ),
        (
            "millgate_history_commits_total",
            "counter",
            "History transactions committed (each a group of events).",
            status.commits.to_string(),
        ),
        (
            "millgate_history_commit_seconds_sum",
            "counter",
            "Time spent in history transactions, s.",
            format!("{:.6}", status.commit_seconds_sum),
        ),
        (
            "millgate_history_commit_seconds_max",
            "gauge",
            "Longest history transaction since start, s.",
            format!("{:.6}", status.commit_seconds_max),
        ),
        (
            "millgate_history_retention_deleted_total",
            "counter",
            "Rows deleted by the history's retention (age and size).",
            status.retention_deleted.to_string(),
        ),
        (
            "millgate_history_file_bytes",
            "gauge",
            "Size of the history file at the last retention check, bytes.",
            status.file_bytes.to_string(),
        ),
    ];
    for (name, kind, help, value) in scalars {
        let _ = writeln!(out, "# HELP {name} {help}");
        let _ = writeln!(out, "# TYPE {name} {kind}");
        let _ = writeln!(out, "{name} {value}");
    }
    let _ = writeln!(
        out,
        "# HELP millgate_history_events_dropped_total Events not stored: the queue was full, or the file could not take them."
    );
    let _ = writeln!(out, "# TYPE millgate_history_events_dropped_total counter");
    for (reason, count) in [
        ("queue_full", status.dropped_queue_full),
        ("error", status.dropped_error),
    ] {
        let _ = writeln!(
            out,
            "millgate_history_events_dropped_total{{reason=\"{reason}\"}} {count}"
        );
    }
    let _ = writeln!(
        out,
        "# HELP millgate_history_last_error_info The history's last error (the message is the label), with its Unix time as value."
    );
    let _ = writeln!(out, "# TYPE millgate_history_last_error_info gauge");
    if let Some((time, message)) = &status.last_error {
        let _ = writeln!(
            out,
            "millgate_history_last_error_info{{error=\"{}\"}} {:.3}",
            escape(message),
            time.unix_s()
        );
    }
}

fn escape(label: &str) -> String {
    label
        .replace('\\', "\\\\")
        .replace('"', "\\\"")
        .replace('\n', "\\n")
}

impl Metrics {
    /// The page for `config`: per channel its `counters`, per source its `health`
    /// (Modbus sources, then CAN sources), per CAN source its `can_counters`, and the
    /// results of `publisher`.
    pub fn new(
        config: &Config,
        counters: Vec<Arc<ChannelCounters>>,
        health: Vec<Arc<SourceHealth>>,
        can_counters: Vec<Arc<CanCounters>>,
        publisher: Arc<Publisher>,
    ) -> Self {
        Self {
            channel_names: config.channels.iter().map(|c| c.name.clone()).collect(),
            source_names: config
                .modbus_sources
                .iter()
                .map(|s| s.name.clone())
                .chain(config.can_sources.iter().map(|s| s.name.clone()))
                .collect(),
            counters,
            health,
            can_names: config.can_sources.iter().map(|s| s.name.clone()).collect(),
            can_counters,
            publisher,
            server: None,
            sparkplug: None,
        }
    }

    /// Show the HMI server's counters too.
    pub fn with_server(mut self, counters: Arc<ServerCounters>) -> Self {
        self.server = Some(counters);
        self
    }

    /// Also show the Sparkplug B edge node's counters.
    pub fn with_sparkplug(mut self, status: Arc<SparkplugStatus>) -> Self {
        self.sparkplug = Some(status);
        self
    }

    /// The page, in the Prometheus text format.
    pub fn render(&self) -> String {
        let mut out = String::new();
        let snapshots: Vec<_> = self.counters.iter().map(|c| c.snapshot()).collect();
        let counters: [(&str, &str, CounterOf); 8] = [
            ("blocks_read", "Blocks or frames decoded", |s| s.blocks_read),
            ("blocks_missed", "Blocks lost, from sequence gaps", |s| {
                s.blocks_missed
            }),
            ("samples", "Samples passed to analysis", |s| s.samples),
            ("timeouts", "Requests without an answer in time", |s| {
                s.timeouts
            }),
            (
                "errors",
                "Transport errors, device exceptions and malformed replies",
                |s| s.errors,
            ),
            (
                "saturated_samples",
                "Samples at the converter's limits, replaced by gaps",
                |s| s.saturated_samples,
            ),
            (
                "sequence_restarts",
                "Block sequences that went backwards or jumped past the elapsed time (DAQ restarts)",
                |s| s.sequence_restarts,
            ),
            (
                "sequence_stalls",
                "Times the block sequence stood still for 3 block periods while the DAQ answered",
                |s| s.sequence_stalls,
            ),
        ];
        for (name, help, value) in counters {
            let _ = writeln!(out, "# HELP millgate_channel_{name}_total {help}.");
            let _ = writeln!(out, "# TYPE millgate_channel_{name}_total counter");
            for (channel, snapshot) in self.channel_names.iter().zip(&snapshots) {
                let _ = writeln!(
                    out,
                    "millgate_channel_{name}_total{{channel=\"{}\"}} {}",
                    escape(channel),
                    value(snapshot)
                );
            }
        }
        let _ = writeln!(
            out,
            "# HELP millgate_source_status Source status: 0 ok, 1 stale, 2 lost."
        );
        let _ = writeln!(out, "# TYPE millgate_source_status gauge");
        for (source, health) in self.source_names.iter().zip(&self.health) {
            let status = health.status();
            let _ = writeln!(
                out,
                "millgate_source_status{{source=\"{}\",status=\"{}\"}} {}",
                escape(source),
                status.name(),
                status.code()
            );
        }
        let _ = writeln!(
            out,
            "# HELP millgate_source_connects_total Successful connections."
        );
        let _ = writeln!(out, "# TYPE millgate_source_connects_total counter");
        for (source, health) in self.source_names.iter().zip(&self.health) {
            let _ = writeln!(
                out,
                "millgate_source_connects_total{{source=\"{}\"}} {}",
                escape(source),
                health.connects()
            );
        }
        let can: Vec<CanCounts> = self.can_counters.iter().map(|c| c.snapshot()).collect();
        let can_counters: [(&str, &str, CanCounterOf); 9] = [
            ("frames", "CAN frames received", |c| c.frames),
            ("decoded", "CAN data frames decoded into samples", |c| {
                c.decoded
            }),
            (
                "unknown_id",
                "CAN data frames with an id no channel uses",
                |c| c.unknown_id,
            ),
            (
                "bad_length",
                "CAN data frames too short for their signals",
                |c| c.bad_length,
            ),
            ("remote", "CAN remote frames", |c| c.remote_frames),
            ("error", "CAN error frames", |c| c.error_frames),
            (
                "error_passive",
                "CAN error frames reporting error passive",
                |c| c.error_passive,
            ),
            ("bus_off", "CAN error frames reporting bus off", |c| {
                c.bus_off
            }),
            (
                "bad_size",
                "CAN socket reads neither a classic nor an FD frame",
                |c| c.bad_size,
            ),
        ];
        for (name, help, value) in can_counters {
            let _ = writeln!(out, "# HELP millgate_can_{name}_frames_total {help}.");
            let _ = writeln!(out, "# TYPE millgate_can_{name}_frames_total counter");
            for (source, counts) in self.can_names.iter().zip(&can) {
                let _ = writeln!(
                    out,
                    "millgate_can_{name}_frames_total{{source=\"{}\"}} {}",
                    escape(source),
                    value(counts)
                );
            }
        }
        let per_can_source: [CanMetric; 5] = [
            (
                "millgate_can_saturated_samples_total",
                "counter",
                "CAN signal values at the end of their raw range (saturated or not available), passed on as gaps.",
                |c| c.saturated_samples.to_string(),
            ),
            (
                "millgate_can_kernel_drops_total",
                "counter",
                "CAN frames the kernel dropped because the socket receive queue was full (SO_RXQ_OVFL); each drop marks a gap.",
                |c| c.kernel_drops.to_string(),
            ),
            (
                "millgate_can_kernel_timestamps_total",
                "counter",
                "CAN frames that carried a kernel receive timestamp (SO_TIMESTAMPNS); the others are dated on arrival.",
                |c| c.kernel_timestamps.to_string(),
            ),
            (
                "millgate_can_receive_latency_seconds_sum",
                "counter",
                "Sum of the delays from kernel receive timestamp to the reader handling the frame, s.",
                |c| format!("{:.9}", c.receive_latency_sum_ns as f64 * 1e-9),
            ),
            (
                "millgate_can_receive_latency_max_seconds",
                "gauge",
                "Largest delay from kernel receive timestamp to the reader handling the frame, s.",
                |c| format!("{:.9}", c.receive_latency_max_ns as f64 * 1e-9),
            ),
        ];
        for (name, kind, help, value) in per_can_source {
            let _ = writeln!(out, "# HELP {name} {help}");
            let _ = writeln!(out, "# TYPE {name} {kind}");
            for (source, counts) in self.can_names.iter().zip(&can) {
                let _ = writeln!(
                    out,
                    "{name}{{source=\"{}\"}} {}",
                    escape(source),
                    value(counts)
                );
            }
        }
        let _ = writeln!(out, "# HELP millgate_can_bus_state Last reported bus state: 0 error active, 1 error passive, 2 bus off.");
        let _ = writeln!(out, "# TYPE millgate_can_bus_state gauge");
        for (source, counts) in self.can_names.iter().zip(&can) {
            let _ = writeln!(
                out,
                "millgate_can_bus_state{{source=\"{}\"}} {}",
                escape(source),
                counts.bus_state.code()
            );
        }
        let results = self.publisher.results();
        // Per driveline, then per tandem mill; each family grouped (the exposition
        // format wants one block per family), gauges only while their value is valid.
        type DrivelineValueOf = fn(&DrivelineResults) -> Option<f64>;
        let drivelines: [(&str, &str, &str, DrivelineValueOf); 5] = [
            (
                "millgate_bites_total",
                "counter",
                "Bites analysed per driveline.",
                |d| Some(d.bite_counter as f64),
            ),
            (
                "millgate_degraded_bites_total",
                "counter",
                "Bites whose window had a gap, saturated or non-finite samples: counted, values not published.",
                |d| Some(d.degraded_bites as f64),
            ),
            (
                "millgate_taf",
                "gauge",
                "Torque amplification factor of the last bite.",
                |d| d.taf.filter(|_| !d.source_stale),
            ),
            (
                "millgate_wear_index",
                "gauge",
                "Wear index of the last bite (TAF / linear reference TAF - 1).",
                |d| d.wear_index.filter(|_| !d.source_stale),
            ),
            (
                "millgate_wear_trend",
                "gauge",
                "Wear trend (EWMA of the wear index since start or reset).",
                |d| d.wear_trend.filter(|_| !d.source_stale),
            ),
        ];
        let driveline_rows: Vec<_> = results
            .drivelines
            .iter()
            .zip(self.publisher.driveline_names())
            .collect();
        for (metric, kind, help, value) in drivelines {
            let rows = driveline_rows
                .iter()
                .map(|(d, name)| (name.as_str(), value(d)));
            family(&mut out, (metric, kind, help), "driveline", rows);
        }
        type MillValueOf = fn(&MillResults) -> Option<f64>;
        let chatter: [(&str, &str, &str, MillValueOf); 5] = [
            (
                "millgate_chatter_evaluations_total",
                "counter",
                "Chatter windows evaluated per tandem mill.",
                |m| Some(m.evaluations as f64),
            ),
            (
                "millgate_chatter_sigma_n_hz",
                "gauge",
                "RMS deviation of adjacent stands' principal chatter-band frequencies, Hz.",
                |m| m.sigma_n_hz.filter(|_| !m.source_stale),
            ),
            (
                "millgate_chatter_k_mean",
                "gauge",
                "Mean correlation of adjacent stands' chatter-band vibration.",
                |m| m.k_mean.filter(|_| !m.source_stale),
            ),
            (
                "millgate_chatter_gain_ratio",
                "gauge",
                "Largest chatter-band gain / threshold of any stand (>= 1: band-gain alarm).",
                |m| m.gain_ratio.filter(|_| !m.source_stale),
            ),
            (
                "millgate_chatter_slow_down_request",
                "gauge",
                "1 while the gateway requests a slow-down for chatter, else 0.",
                |m| Some(f64::from(u8::from(m.slow_down_request))),
            ),
        ];
        let mill_rows: Vec<_> = results
            .mills
            .iter()
            .zip(self.publisher.mill_names())
            .collect();
        for (metric, kind, help, value) in chatter {
            let rows = mill_rows.iter().map(|(m, name)| (name.as_str(), value(m)));
            family(&mut out, (metric, kind, help), "mill", rows);
        }
        if let Some(server) = &self.server {
            let counts = server.snapshot();
            type ServerCountOf = fn(&ServerCounts) -> u64;
            let families: [(&str, &str, ServerCountOf); 7] = [
                ("connections", "HMI connections accepted", |c| c.connections),
                (
                    "refused_connections",
                    "HMI connections closed at once: max_connections clients were connected",
                    |c| c.refused,
                ),
                (
                    "idle_closed_connections",
                    "HMI connections closed for idling or a request not completed in time",
                    |c| c.idle_closed,
                ),
                (
                    "not_modbus_connections",
                    "HMI connections closed because the stream was not Modbus TCP",
                    |c| c.not_modbus,
                ),
                ("requests", "HMI requests answered", |c| c.requests),
                (
                    "exceptions",
                    "HMI requests answered with a Modbus exception",
                    |c| c.exceptions,
                ),
                (
                    "broadcasts",
                    "HMI broadcast requests (unit 0), never answered nor acted on",
                    |c| c.broadcasts,
                ),
            ];
            for (name, help, value) in families {
                let _ = writeln!(out, "# HELP millgate_server_{name}_total {help}.");
                let _ = writeln!(out, "# TYPE millgate_server_{name}_total counter");
                let _ = writeln!(out, "millgate_server_{name}_total {}", value(&counts));
            }
        }
        let _ = writeln!(
            out,
            "# HELP millgate_heartbeat Heartbeat written to the PLC."
        );
        let _ = writeln!(out, "# TYPE millgate_heartbeat gauge");
        let _ = writeln!(out, "millgate_heartbeat {}", results.heartbeat);
        history_metrics(&mut out, &self.publisher.history().status());
        if let Some(status) = &self.sparkplug {
            sparkplug_metrics(&mut out, &status.counts());
        }
        out
    }

    /// Read one request head (whole, within [`HEAD_TIMEOUT`] and
    /// [`http_head::MAX_HEAD_LEN`]) and answer it.
    async fn answer(&self, mut stream: TcpStream) -> std::io::Result<()> {
        let mut received = Vec::with_capacity(1024);
        let head = tokio::time::timeout(HEAD_TIMEOUT, async {
            let mut chunk = [0u8; 1024];
            loop {
                if let Some(end) = http_head::head_end(&received)? {
                    return Ok(end);
                }
                let read = stream
                    .read(&mut chunk)
                    .await
                    .map_err(|_| HeadError::Malformed)?;
                if read == 0 {
                    return Err(HeadError::Malformed);
                }
                received.extend_from_slice(&chunk[..read]);
            }
        })
        .await
        .map_err(|_| std::io::Error::new(std::io::ErrorKind::TimedOut, "request head timed out"))?;
        let parsed = head.and_then(|end| http_head::parse(&received[..end]));
        let text = "text/plain; charset=utf-8";
        let (status, content_type, body) = match parsed {
            Ok(request) if request.method != "GET" => (
                "405 Method Not Allowed",
                text,
                "only GET is served\n".to_owned(),
            ),
            Ok(request) if request.path == "/metrics" => (
                "200 OK",
                "text/plain; version=0.0.4; charset=utf-8",
                self.render(),
            ),
            Ok(_) => (
                "404 Not Found",
                text,
                "only /metrics is served\n".to_owned(),
            ),
            Err(error) => (error.status(), text, format!("{error}\n")),
        };
        let allow = if status.starts_with("405") {
            "Allow: GET\r\n"
        } else {
            ""
        };
        let response = format!(
            "HTTP/1.1 {status}\r\nContent-Type: {content_type}\r\nContent-Length: {}\r\n{allow}Connection: close\r\n\r\n{body}",
            body.len()
        );
        stream.write_all(response.as_bytes()).await?;
        stream.shutdown().await
    }

    /// Serve on `listener` until shutdown, at most [`MAX_SCRAPES`] requests at once
    /// (a further connection is closed at once).
    pub async fn run(self, listener: TcpListener, mut shutdown: Shutdown) {
        let metrics = Arc::new(self);
        if let Ok(local) = listener.local_addr() {
            tracing::info!(%local, "metrics endpoint listening on /metrics");
        }
        let slots = Arc::new(tokio::sync::Semaphore::new(MAX_SCRAPES));
        let mut accept_warnings = WarnLimit::new(WARN_PERIOD);
        loop {
            let accepted = tokio::select! {
                accepted = listener.accept() => accepted,
                () = shutdown.recv() => return,
            };
            match accepted {
                Ok((stream, _)) => {
                    let Ok(slot) = Arc::clone(&slots).try_acquire_owned() else {
                        continue;
                    };
                    let metrics = Arc::clone(&metrics);
                    tokio::spawn(async move {
                        if let Err(error) = metrics.answer(stream).await {
                            tracing::debug!(%error, "metrics request failed");
                        }
                        drop(slot);
                    });
                }
                Err(error) => {
                    if let Some(suppressed) = accept_warnings.occurred(tokio::time::Instant::now())
                    {
                        tracing::warn!(%error, suppressed, "metrics accept failed");
                    }
                    tokio::time::sleep(std::time::Duration::from_millis(100)).await;
                }
            }
        }
    }
}
