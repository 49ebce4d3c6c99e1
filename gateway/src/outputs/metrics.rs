//! Prometheus `/metrics`: the catalogue's figures per driveline, tandem mill, rod mill
//! and span, the acquisition counters per channel and source, the outputs' own counters
//! (PLC writes, HMI server, history, Sparkplug), build information and the process'
//! resources, in the text exposition format (version 0.0.4).
//!
//! Served by the gateway's one HTTP stack (`outputs::http`: GET and HEAD, a
//! bounded accept loop that gives up, and so ends the service, when accepting keeps
//! failing). The text is written here rather than through a Prometheus client crate:
//! every family but the process' is derived from state the gateway already keeps (the
//! catalogue's figures read at scrape time), which a client's registry would copy into
//! a second set of metric objects on every change.
//!
//! Names follow Prometheus' conventions (`promtool check metrics` passes): counters end
//! in `_total`, a figure of the catalogue is `millgate_<subject>_<key>` (a time
//! `..._timestamp_seconds`), a gauge is sampled only while its value is valid (the
//! stale rule's "good"), so a withdrawn or last-usable value is a missing series, never
//! a frozen one.

use std::fmt::Write as _;
use std::sync::Arc;
use std::time::Duration;

use axum::http::{header, HeaderValue};
use axum::response::IntoResponse;
use axum::routing::get;
use axum::Router;
use millgate_config::{Config, MetricsOutput};
use tokio::net::TcpListener;

use crate::field::counters::{CanCounters, CanCounts, ChannelCounters, ChannelCountersSnapshot};
use crate::field::source_health::SourceHealth;
use crate::outputs::http::{self, Limits};
use crate::outputs::modbus::hmi_server::{ServerCounters, ServerCounts};
use crate::outputs::modbus::plc_writer::{PlcCounters, PlcFailure};
use crate::outputs::sparkplug::{ConnectFailure, SparkplugCounts, SparkplugStatus};
use crate::outputs::web::QuerySlots;
use crate::shutdown::Shutdown;
use crate::state::board::Board;
use crate::state::catalogue::{self, Figure, FigureInfo, FigureType, Subject, Value};
use crate::state::history::HistoryStatus;

/// Time a client has to send its whole request head.
pub const HEAD_TIMEOUT: Duration = Duration::from_secs(5);
/// Scrapes answered at once; Prometheus sends one at a time.
pub const MAX_SCRAPES: usize = 16;
/// A warning when `settings` binds an address other hosts can reach (`/metrics`
/// shows the plant's figures and the gateway's state without authentication).
pub fn exposure_warning(settings: &MetricsOutput) -> Option<String> {
    (!settings.bind.ip().is_loopback()).then(|| {
        format!(
            "outputs.metrics.bind: {} accepts clients from other hosts: anyone who reaches it \
             reads /metrics without authentication (read-only)",
            settings.bind
        )
    })
}

/// The content type of the text exposition format.
pub const CONTENT_TYPE: &str = "text/plain; version=0.0.4; charset=utf-8";

/// Prometheus' metric type of a family.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Kind {
    Counter,
    Gauge,
}

/// A page of the exposition format being written.
#[derive(Debug, Default)]
struct Exposition {
    out: String,
}

/// A sample's labels: `(name, value)` pairs.
type Labels<'a> = Vec<(&'static str, &'a str)>;

impl Exposition {
    /// One family: HELP, TYPE and one sample per row.
    fn family<'a>(
        &mut self,
        name: &str,
        kind: Kind,
        help: &str,
        samples: impl IntoIterator<Item = (Labels<'a>, f64)>,
    ) {
        let kind = match kind {
            Kind::Counter => "counter",
            Kind::Gauge => "gauge",
        };
        let help = help.replace('\\', "\\\\").replace('\n', "\\n");
        let _ = writeln!(self.out, "# HELP {name} {help}");
        let _ = writeln!(self.out, "# TYPE {name} {kind}");
        for (labels, value) in samples {
            let _ = write!(self.out, "{name}");
            if !labels.is_empty() {
                let labels: Vec<String> = labels
                    .iter()
                    .map(|(label, value)| format!("{label}=\"{}\"", escape(value)))
                    .collect();
                let _ = write!(self.out, "{{{}}}", labels.join(","));
            }
            let _ = writeln!(self.out, " {}", number(value));
        }
    }

    /// A family of one sample without labels.
    fn scalar(&mut self, name: &str, kind: Kind, help: &str, value: f64) {
        self.family(name, kind, help, [(Vec::new(), value)]);
    }

    /// A family of one sample without labels per `(name, kind, help, value)`.
    fn scalars<'a>(&mut self, rows: impl IntoIterator<Item = (&'a str, Kind, &'a str, f64)>) {
        for (name, kind, help, value) in rows {
            self.scalar(name, kind, help, value);
        }
    }
}

/// A sample value as Prometheus reads it.
fn number(value: f64) -> String {
    if value.is_nan() {
        "NaN".into()
    } else if value.is_infinite() {
        if value > 0.0 { "+Inf" } else { "-Inf" }.into()
    } else if value.fract() == 0.0 && value.abs() < 1e15 {
        format!("{value:.0}")
    } else {
        format!("{value:?}")
    }
}

fn escape(label: &str) -> String {
    label
        .replace('\\', "\\\\")
        .replace('"', "\\\"")
        .replace('\n', "\\n")
}

/// Key suffixes of units Prometheus writes out in base units (its linter refuses the
/// abbreviations `s` and `m`): `(unit, key suffix, metric suffix)`.
const PROMETHEUS_UNITS: [(&str, &str, &str); 3] = [
    ("s", "_s", "_seconds"),
    ("m/s", "_m_s", "_meters_per_second"),
    ("1/s", "_per_s", "_per_second"),
];

/// The `/metrics` name of a catalogue figure: `millgate_<subject>_<key>` (a unit in
/// Prometheus' base-unit words: `_seconds`, `_meters_per_second`, `_per_second`), a
/// counter with `_total`, a time as `..._timestamp_seconds`, unless the catalogue
/// names it.
pub fn metric_name(figure: &FigureInfo) -> String {
    if let Some(name) = figure.metric {
        return name.to_owned();
    }
    let key = PROMETHEUS_UNITS
        .iter()
        .find(|(unit, suffix, _)| figure.unit == *unit && figure.key.ends_with(suffix))
        .map_or_else(
            || figure.key.to_owned(),
            |(_, suffix, words)| {
                format!(
                    "{}{words}",
                    figure.key.strip_suffix(suffix).unwrap_or(figure.key)
                )
            },
        );
    let base = format!("millgate_{}_{key}", figure.subject.name());
    if figure.is_counter() {
        format!("{base}_total")
    } else if figure.figure_type == FigureType::Time {
        format!("{}_timestamp_seconds", base.trim_end_matches("_time"))
    } else {
        base
    }
}

/// A good value as a sample: a time in Unix seconds.
fn sample(value: Value) -> f64 {
    match value {
        Value::Time(ms) => ms as f64 / 1000.0,
        other => other.as_f64(),
    }
}

/// One family per figure of `figures`, a sample per row whose value is good.
fn catalogue_families<R: Subject>(
    page: &mut Exposition,
    figures: &[Figure<R>],
    rows: &[(Labels<'_>, &R)],
) {
    for figure in figures {
        let kind = if figure.is_counter() {
            Kind::Counter
        } else {
            Kind::Gauge
        };
        let help = if figure.unit.is_empty() {
            format!("{}.", figure.description)
        } else {
            format!("{}, {}.", figure.description, figure.unit)
        };
        let samples = rows.iter().filter_map(|(labels, subject)| {
            let value = figure.read(subject).good()?;
            Some((labels.clone(), sample(value)))
        });
        page.family(&metric_name(&figure.info()), kind, &help, samples);
    }
}

/// Where the acquisition counters come from: per channel, per source (in the order of
/// [`Config::sources`]) and per CAN source.
#[derive(Debug, Clone)]
pub struct Acquisition {
    /// Per channel, indexed like `config.channels`.
    pub counters: Vec<Arc<ChannelCounters>>,
    /// Per source.
    pub health: Vec<Arc<SourceHealth>>,
    /// Per CAN source.
    pub can: Vec<Arc<CanCounters>>,
}

/// What the metrics page shows.
#[derive(Debug)]
pub struct Metrics {
    channel_names: Vec<String>,
    source_names: Vec<String>,
    can_names: Vec<String>,
    rod_span_names: Vec<Vec<String>>,
    acquisition: Acquisition,
    board: Arc<Board>,
    rod_mill_names: Vec<String>,
    server: Option<Arc<ServerCounters>>,
    sparkplug: Option<Arc<SparkplugStatus>>,
    plc: Option<Arc<PlcCounters>>,
    web_slots: Option<Arc<QuerySlots>>,
    #[cfg(feature = "opcua")]
    opcua: Option<crate::outputs::opcua::OpcUaStatus>,
}

impl Metrics {
    /// The page for `config`: its `acquisition` counters and the results of `board`;
    /// `rod_mill_spans` is each rod mill's span count.
    pub fn new(
        config: &Config,
        acquisition: Acquisition,
        board: Arc<Board>,
        rod_mill_spans: &[usize],
    ) -> Self {
        Self {
            channel_names: config.channels.iter().map(|c| c.name.clone()).collect(),
            source_names: config.sources().map(|s| s.name().to_owned()).collect(),
            can_names: config.can_sources.iter().map(|s| s.name.clone()).collect(),
            rod_span_names: rod_mill_spans
                .iter()
                .map(|&spans| (1..=spans).map(|span| span.to_string()).collect())
                .collect(),
            rod_mill_names: config.rod_mills.iter().map(|m| m.name.clone()).collect(),
            acquisition,
            board,
            server: None,
            sparkplug: None,
            plc: None,
            web_slots: None,
            #[cfg(feature = "opcua")]
            opcua: None,
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

    /// Also show the OPC UA server's counters.
    #[cfg(feature = "opcua")]
    pub fn with_opcua(mut self, status: crate::outputs::opcua::OpcUaStatus) -> Self {
        self.opcua = Some(status);
        self
    }

    /// Also show the PLC writer's counters.
    pub fn with_plc(mut self, counters: Arc<PlcCounters>) -> Self {
        self.plc = Some(counters);
        self
    }

    /// Also show the maintenance page's history query slots.
    pub fn with_web(mut self, slots: Arc<QuerySlots>) -> Self {
        self.web_slots = Some(slots);
        self
    }

    /// The page, in the Prometheus text format.
    pub fn render(&self) -> String {
        let mut page = Exposition::default();
        page.family(
            "millgate_build_info",
            Kind::Gauge,
            "The millgate build: its version (always 1).",
            [(vec![("version", env!("CARGO_PKG_VERSION"))], 1.0)],
        );
        process_metrics(&mut page);
        self.figures(&mut page);
        self.acquisition(&mut page);
        if let Some(plc) = &self.plc {
            plc_metrics(&mut page, plc);
        }
        if let Some(server) = &self.server {
            server_metrics(&mut page, &server.snapshot());
        }
        page.scalar(
            "millgate_heartbeat",
            Kind::Gauge,
            "Heartbeat written to the PLC.",
            f64::from(self.board.results().heartbeat),
        );
        history_metrics(&mut page, &self.board.history().status());
        if let Some(slots) = &self.web_slots {
            web_metrics(&mut page, slots);
        }
        if let Some(status) = &self.sparkplug {
            sparkplug_metrics(&mut page, &status.counts());
        }
        #[cfg(feature = "opcua")]
        if let Some(status) = &self.opcua {
            opcua_metrics(&mut page, &status.counts());
        }
        page.out
    }

    /// The catalogue's figures of every driveline, tandem mill, rod mill and span.
    fn figures(&self, page: &mut Exposition) {
        let results = self.board.results();
        let drivelines: Vec<(Labels<'_>, _)> = self
            .board
            .driveline_names()
            .iter()
            .zip(&results.drivelines)
            .map(|(name, d)| (vec![("driveline", name.as_str())], d))
            .collect();
        catalogue_families(page, catalogue::DRIVELINE, &drivelines);
        let mills: Vec<(Labels<'_>, _)> = self
            .board
            .tandem_mill_names()
            .iter()
            .zip(&results.tandem_mills)
            .map(|(name, m)| (vec![("tandem_mill", name.as_str())], m))
            .collect();
        catalogue_families(page, catalogue::TANDEM_MILL, &mills);
        let rods: Vec<(Labels<'_>, _)> = self
            .rod_mill_names
            .iter()
            .zip(&results.rod_mills)
            .map(|(name, r)| (vec![("rod_mill", name.as_str())], r))
            .collect();
        catalogue_families(page, catalogue::ROD_MILL, &rods);
        let spans: Vec<_> =
            self.rod_mill_names
                .iter()
                .zip(&results.rod_mills)
                .zip(&self.rod_span_names)
                .flat_map(|((name, mill), spans)| {
                    spans.iter().enumerate().map(move |(k, span)| {
                        (name.as_str(), span.as_str(), mill.published_span(k))
                    })
                })
                .collect();
        let span_rows: Vec<(Labels<'_>, _)> = spans
            .iter()
            .map(|(mill, span, results)| (vec![("rod_mill", *mill), ("span", *span)], results))
            .collect();
        catalogue_families(page, catalogue::ROD_SPAN, &span_rows);
    }

    /// Per channel, per source and per CAN source.
    fn acquisition(&self, page: &mut Exposition) {
        let snapshots: Vec<_> = self
            .acquisition
            .counters
            .iter()
            .map(|c| c.snapshot())
            .collect();
        type CounterOf = fn(&ChannelCountersSnapshot) -> u64;
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
            let samples = self
                .channel_names
                .iter()
                .zip(&snapshots)
                .map(|(channel, s)| (vec![("channel", channel.as_str())], value(s) as f64));
            page.family(
                &format!("millgate_channel_{name}_total"),
                Kind::Counter,
                &format!("{help}."),
                samples,
            );
        }
        let sources = || {
            self.source_names
                .iter()
                .zip(&self.acquisition.health)
                .map(|(name, health)| (vec![("source", name.as_str())], health))
        };
        page.family(
            "millgate_source_status",
            Kind::Gauge,
            "Source status: 0 ok, 1 stale, 2 lost.",
            sources().map(|(labels, health)| (labels, f64::from(health.status().code()))),
        );
        page.family(
            "millgate_source_connects_total",
            Kind::Counter,
            "Successful connections.",
            sources().map(|(labels, health)| (labels, health.connects() as f64)),
        );
        let can: Vec<CanCounts> = self.acquisition.can.iter().map(|c| c.snapshot()).collect();
        type CanOf = fn(&CanCounts) -> f64;
        let per_can_source: [(&str, Kind, &str, CanOf); 14] = [
            ("millgate_can_frames_total", Kind::Counter, "CAN frames received.", |c| c.frames as f64),
            ("millgate_can_decoded_frames_total", Kind::Counter, "CAN data frames decoded into samples.", |c| c.decoded as f64),
            ("millgate_can_unknown_id_frames_total", Kind::Counter, "CAN data frames with an id no channel uses.", |c| c.unknown_id as f64),
            ("millgate_can_bad_length_frames_total", Kind::Counter, "CAN data frames too short for their signals.", |c| c.bad_length as f64),
            ("millgate_can_remote_frames_total", Kind::Counter, "CAN remote frames.", |c| c.remote_frames as f64),
            ("millgate_can_error_frames_total", Kind::Counter, "CAN error frames.", |c| c.error_frames as f64),
            ("millgate_can_error_passive_frames_total", Kind::Counter, "CAN error frames reporting error passive.", |c| c.error_passive as f64),
            ("millgate_can_bus_off_frames_total", Kind::Counter, "CAN error frames reporting bus off.", |c| c.bus_off as f64),
            ("millgate_can_bad_size_reads_total", Kind::Counter, "CAN socket reads neither a classic nor an FD frame.", |c| c.bad_size as f64),
            ("millgate_can_saturated_samples_total", Kind::Counter, "CAN signal values at the end of their raw range (saturated or not available), passed on as gaps.", |c| c.saturated_samples as f64),
            ("millgate_can_kernel_drops_total", Kind::Counter, "CAN frames the kernel dropped because the socket receive queue was full (SO_RXQ_OVFL); each drop marks a gap.", |c| c.kernel_drops as f64),
            ("millgate_can_kernel_timestamps_total", Kind::Counter, "CAN frames that carried a kernel receive timestamp (SO_TIMESTAMPNS); the others are dated on arrival.", |c| c.kernel_timestamps as f64),
            ("millgate_can_receive_latency_seconds_total", Kind::Counter, "Sum of the delays from kernel receive timestamp to the reader handling the frame, s.", |c| c.receive_latency_sum_ns as f64 * 1e-9),
            ("millgate_can_receive_latency_max_seconds", Kind::Gauge, "Largest delay from kernel receive timestamp to the reader handling the frame, s.", |c| c.receive_latency_max_ns as f64 * 1e-9),
        ];
        for (name, kind, help, value) in per_can_source {
            let samples = self
                .can_names
                .iter()
                .zip(&can)
                .map(|(source, counts)| (vec![("source", source.as_str())], value(counts)));
            page.family(name, kind, help, samples);
        }
        page.family(
            "millgate_can_bus_state",
            Kind::Gauge,
            "Last reported bus state: 0 error active, 1 error passive, 2 bus off.",
            self.can_names.iter().zip(&can).map(|(source, c)| {
                (
                    vec![("source", source.as_str())],
                    f64::from(c.bus_state.code()),
                )
            }),
        );
    }

    /// The routes: `GET`/`HEAD /metrics`, 404 elsewhere.
    fn router(self: Arc<Self>) -> Router {
        Router::new()
            .route(
                "/metrics",
                get(move || {
                    let metrics = Arc::clone(&self);
                    async move {
                        let mut response = metrics.render().into_response();
                        response
                            .headers_mut()
                            .insert(header::CONTENT_TYPE, HeaderValue::from_static(CONTENT_TYPE));
                        response
                    }
                }),
            )
            .fallback(|| async {
                http::error(
                    axum::http::StatusCode::NOT_FOUND,
                    "only /metrics is served here",
                )
            })
    }

    /// Serve `/metrics` on `listener` until shutdown, at most [`MAX_SCRAPES`]
    /// connections at once; an error when accepting fails for good.
    pub async fn run(self, listener: TcpListener, shutdown: Shutdown) -> std::io::Result<()> {
        let limits = Limits {
            post_paths: &[],
            max_connections: MAX_SCRAPES,
            header_timeout: HEAD_TIMEOUT,
        };
        http::serve(
            "metrics endpoint",
            listener,
            Arc::new(self).router(),
            limits,
            shutdown,
        )
        .await
    }
}

/// The PLC writer's families: writes, failures by reason, the last success.
fn plc_metrics(page: &mut Exposition, plc: &PlcCounters) {
    let counts = plc.snapshot();
    page.scalar(
        "millgate_plc_writes_total",
        Kind::Counter,
        "Register maps written to the PLC.",
        counts.writes as f64,
    );
    page.family(
        "millgate_plc_write_failures_total",
        Kind::Counter,
        "Failed PLC connections and writes, by reason: connect, timeout, transport, mismatch (the network) or refused (a Modbus exception from the PLC).",
        PlcFailure::ALL
            .iter()
            .zip(counts.failures)
            .map(|(reason, n)| (vec![("reason", reason.name())], n as f64)),
    );
    page.family(
        "millgate_plc_last_write_success_timestamp_seconds",
        Kind::Gauge,
        "When a register map last reached the PLC, Unix seconds (no sample before the first).",
        (counts.last_success_unix_ms > 0)
            .then(|| (Vec::new(), counts.last_success_unix_ms as f64 / 1000.0)),
    );
}

/// The HMI Modbus server's families.
fn server_metrics(page: &mut Exposition, counts: &ServerCounts) {
    type ServerCountOf = fn(&ServerCounts) -> u64;
    let families: [(&str, &str, ServerCountOf); 9] = [
        ("connections", "HMI connections accepted", |c| c.connections),
        (
            "refused_connections",
            "HMI connections closed at once: the server was full and every connection inside a request",
            |c| c.refused,
        ),
        (
            "evicted_connections",
            "Idle HMI connections closed to make room for a new one (max_connections or max_connections_per_peer reached)",
            |c| c.evicted,
        ),
        (
            "idle_closed_connections",
            "HMI connections closed for idling or a request not completed in time",
            |c| c.idle_closed,
        ),
        (
            "silent_closed_connections",
            "Of those, HMI connections closed for sending no request within 5 s of connecting (or idle_timeout_ms, when shorter)",
            |c| c.silent_closed,
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
        page.scalar(
            &format!("millgate_server_{name}_total"),
            Kind::Counter,
            &format!("{help}."),
            value(counts) as f64,
        );
    }
}

/// The maintenance page's history query slots: how many, how many held, and the
/// requests refused because none freed in time.
fn web_metrics(page: &mut Exposition, slots: &QuerySlots) {
    page.scalars([
        (
            "millgate_web_history_query_slots",
            Kind::Gauge,
            "History query slots of the maintenance page (outputs.web.history_queries).",
            slots.limit() as f64,
        ),
        (
            "millgate_web_history_query_slots_in_use",
            Kind::Gauge,
            "History query slots held by a running query.",
            slots.in_use() as f64,
        ),
        (
            "millgate_web_history_queries_refused_total",
            Kind::Counter,
            "Maintenance page requests answered 503 because no history query slot freed within 1 s.",
            slots.refused() as f64,
        ),
    ]);
}

/// The history's families: state, events stored and dropped, commits, retention,
/// the file's size and the last error (an info metric with the message as label, and
/// its time).
fn history_metrics(page: &mut Exposition, status: &HistoryStatus) {
    let scalars: [(&str, Kind, &str, f64); 8] = [
        (
            "millgate_history_state",
            Kind::Gauge,
            "Event history: 0 disabled, 1 ok, 2 failing (see millgate_history_last_error_info).",
            f64::from(status.state.code()),
        ),
        (
            "millgate_history_events_stored_total",
            Kind::Counter,
            "Events committed to the history file.",
            status.stored as f64,
        ),
        (
            "millgate_history_queue_events",
            Kind::Gauge,
            "Events waiting for the history writer.",
            status
                .enqueued
                .saturating_sub(status.stored + status.dropped_error) as f64,
        ),
        (
            "millgate_history_commits_total",
            Kind::Counter,
            "History transactions committed (each a group of events).",
            status.commits as f64,
        ),
        (
            "millgate_history_commit_seconds_total",
            Kind::Counter,
            "Time spent in history transactions, s.",
            status.commit_seconds_sum,
        ),
        (
            "millgate_history_commit_max_seconds",
            Kind::Gauge,
            "Longest history transaction since start, s.",
            status.commit_seconds_max,
        ),
        (
            "millgate_history_retention_deleted_total",
            Kind::Counter,
            "Rows deleted by the history's retention (age and size).",
            status.retention_deleted as f64,
        ),
        (
            "millgate_history_file_bytes",
            Kind::Gauge,
            "Size of the history file at the last retention check, bytes.",
            status.file_bytes as f64,
        ),
    ];
    page.scalars(scalars);
    page.family(
        "millgate_history_events_dropped_total",
        Kind::Counter,
        "Events not stored: the queue was full, or the file could not take them.",
        [
            (
                vec![("reason", "queue_full")],
                status.dropped_queue_full as f64,
            ),
            (vec![("reason", "error")], status.dropped_error as f64),
        ],
    );
    page.scalar(
        "millgate_history_captures_dropped_total",
        Kind::Counter,
        "Captures (a bite's window with its bite, a chatter episode, a manual request) not stored: the queue was full or the file could not take them; never announced, as nothing reads them from the file.",
        status.captures_dropped as f64,
    );
    let last = status.last_error.as_ref();
    page.family(
        "millgate_history_last_error_info",
        Kind::Gauge,
        "The history's last error: the message is the label (always 1; no sample before the first error).",
        last.map(|(_, message)| (vec![("error", message.as_str())], 1.0)),
    );
    page.family(
        "millgate_history_last_error_timestamp_seconds",
        Kind::Gauge,
        "When the history's last error happened, Unix seconds.",
        last.map(|(time, _)| (Vec::new(), time.unix_s())),
    );
}

/// The Sparkplug B edge node's families.
fn sparkplug_metrics(page: &mut Exposition, counts: &SparkplugCounts) {
    let scalars: [(&str, Kind, &str, f64); 10] = [
        (
            "millgate_sparkplug_connected",
            Kind::Gauge,
            "1 while a session with the MQTT broker is up.",
            f64::from(u8::from(counts.connected)),
        ),
        (
            "millgate_sparkplug_bd_seq",
            Kind::Gauge,
            "The current session's Sparkplug bdSeq (0..=255).",
            f64::from(counts.bd_seq),
        ),
        (
            "millgate_sparkplug_messages_published_total",
            Kind::Counter,
            "Sparkplug messages handed to the broker connection.",
            counts.published as f64,
        ),
        (
            "millgate_sparkplug_bites_published_total",
            Kind::Counter,
            "Bites published live as their own DDATA.",
            counts.bites as f64,
        ),
        (
            "millgate_sparkplug_replayed_total",
            Kind::Counter,
            "Bites replayed from the history as DDATA flagged historical.",
            counts.replayed as f64,
        ),
        (
            "millgate_sparkplug_backlog_bites",
            Kind::Gauge,
            "Bites in the history the broker has not confirmed (PUBACK) yet.",
            counts.backlog as f64,
        ),
        (
            "millgate_sparkplug_sessions_total",
            Kind::Counter,
            "Sessions the MQTT broker accepted.",
            counts.connections as f64,
        ),
        (
            "millgate_sparkplug_rebirths_total",
            Kind::Counter,
            "Rebirths on a Node Control/Rebirth command (at most one per 5 s).",
            counts.rebirths as f64,
        ),
        (
            "millgate_sparkplug_rebirth_requests_total",
            Kind::Counter,
            "Node Control/Rebirth commands received (those within 5 s of the last births answered by one rebirth).",
            counts.rebirth_requests as f64,
        ),
        (
            "millgate_sparkplug_commands_refused_total",
            Kind::Counter,
            "NCMDs refused: retained, over 64 KiB or undecodable.",
            counts.commands_refused as f64,
        ),
    ];
    page.scalars(scalars);
    page.family(
        "millgate_sparkplug_connect_failures_total",
        Kind::Counter,
        "Failed connections to the MQTT broker and lost sessions, by reason (unreachable, tls, not_authorised, refused).",
        ConnectFailure::ALL
            .iter()
            .zip(counts.failures)
            .map(|(failure, count)| (vec![("reason", failure.name())], count as f64)),
    );
}

/// The OPC UA server's families.
#[cfg(feature = "opcua")]
fn opcua_metrics(page: &mut Exposition, counts: &crate::outputs::opcua::OpcUaCounts) {
    let scalars: [(&str, Kind, &str, f64); 12] = [
        (
            "millgate_opcua_connections_total",
            Kind::Counter,
            "TCP connections the OPC UA server accepted.",
            counts.connections as f64,
        ),
        (
            "millgate_opcua_connections_refused_total",
            Kind::Counter,
            "Connections closed at once because max_connections were open.",
            counts.refused as f64,
        ),
        (
            "millgate_opcua_malformed_frames_total",
            Kind::Counter,
            "Connections closed because the client did not speak OPC UA TCP framing.",
            counts.malformed_frames as f64,
        ),
        (
            "millgate_opcua_protocol_errors_total",
            Kind::Counter,
            "ERR messages the server sent (a message its decoder or secure channel refused).",
            counts.protocol_errors as f64,
        ),
        (
            "millgate_opcua_identities_refused_total",
            Kind::Counter,
            "Sign-ins refused (wrong password, unknown user, anonymous where not allowed).",
            counts.identities_refused as f64,
        ),
        (
            "millgate_opcua_security_rejected_requests_total",
            Kind::Counter,
            "Requests refused for security (certificate, signature, session, access).",
            counts.security_rejected_requests as f64,
        ),
        (
            "millgate_opcua_rejected_requests_total",
            Kind::Counter,
            "Requests answered with a bad service result.",
            counts.rejected_requests as f64,
        ),
        (
            "millgate_opcua_acknowledgements_total",
            Kind::Counter,
            "Acknowledge calls carried out.",
            counts.acknowledgements as f64,
        ),
        (
            "millgate_opcua_acknowledgements_refused_total",
            Kind::Counter,
            "Acknowledge calls the guard refused (a remote host, a read-only user).",
            counts.acknowledgements_refused as f64,
        ),
        (
            "millgate_opcua_value_changes_total",
            Kind::Counter,
            "Variable values changed in the address space.",
            counts.value_changes as f64,
        ),
        (
            "millgate_opcua_invalid_updates_total",
            Kind::Counter,
            "Updates refused (wrong type, a non-finite number given as good).",
            counts.invalid_updates as f64,
        ),
        (
            "millgate_opcua_events_total",
            Kind::Counter,
            "Alarm events sent to clients.",
            counts.events as f64,
        ),
    ];
    page.scalars(scalars);
}

/// The process' resources, as Prometheus' client libraries name them, read from
/// `/proc/self` (Linux; nothing elsewhere). Read by hand: five numbers from three
/// files, against a dependency for them.
fn process_metrics(page: &mut Exposition) {
    let Ok(stat) = std::fs::read_to_string("/proc/self/stat") else {
        return;
    };
    // Fields after the command's closing parenthesis: state is field 3, utime 14,
    // stime 15, starttime 22, vsize 23, rss 24 (proc(5)), counted from 1.
    let Some(after) = stat.rsplit_once(')').map(|(_, rest)| rest) else {
        return;
    };
    let fields: Vec<&str> = after.split_whitespace().collect();
    let field = |n: usize| fields.get(n - 3).and_then(|f| f.parse::<f64>().ok());
    // USER_HZ is 100 on every Linux ABI the gateway targets; pages of 4 KiB.
    let ticks = 100.0;
    let page_bytes = 4096.0;
    if let (Some(utime), Some(stime)) = (field(14), field(15)) {
        page.scalar(
            "process_cpu_seconds_total",
            Kind::Counter,
            "Total user and system CPU time spent in seconds.",
            (utime + stime) / ticks,
        );
    }
    if let Some(rss) = field(24) {
        page.scalar(
            "process_resident_memory_bytes",
            Kind::Gauge,
            "Resident memory size in bytes.",
            rss * page_bytes,
        );
    }
    if let Some(vsize) = field(23) {
        page.scalar(
            "process_virtual_memory_bytes",
            Kind::Gauge,
            "Virtual memory size in bytes.",
            vsize,
        );
    }
    if let (Some(start), Some(boot)) = (field(22), boot_time()) {
        page.scalar(
            "process_start_time_seconds",
            Kind::Gauge,
            "Start time of the process since unix epoch in seconds.",
            boot + start / ticks,
        );
    }
    if let Ok(fds) = std::fs::read_dir("/proc/self/fd") {
        page.scalar(
            "process_open_fds",
            Kind::Gauge,
            "Number of open file descriptors.",
            fds.count() as f64,
        );
    }
    let max_fds = std::fs::read_to_string("/proc/self/limits")
        .ok()
        .and_then(|limits| {
            let line = limits.lines().find(|l| l.starts_with("Max open files"))?;
            line.split_whitespace().nth(3)?.parse::<f64>().ok()
        });
    if let Some(max) = max_fds {
        page.scalar(
            "process_max_fds",
            Kind::Gauge,
            "Maximum number of open file descriptors.",
            max,
        );
    }
}

/// The machine's boot time, Unix seconds (`btime` of `/proc/stat`).
fn boot_time() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/stat").ok()?;
    let line = stat.lines().find(|l| l.starts_with("btime "))?;
    line.split_whitespace().nth(1)?.parse().ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn numbers_are_written_as_prometheus_reads_them() {
        assert_eq!(number(3.0), "3");
        assert_eq!(number(0.25), "0.25");
        assert_eq!(number(1e300), "1e300");
        assert_eq!(number(f64::NAN), "NaN");
        assert_eq!(number(f64::NEG_INFINITY), "-Inf");
    }

    fn example(name: &str) -> Config {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../config/examples")
            .join(name);
        millgate_config::load(&path).expect("the example loads")
    }

    /// The page of `config`'s gateway whose results `set` filled.
    fn page_of(
        config: &Config,
        spans: &[usize],
        set: impl FnOnce(&mut crate::state::results::Results),
    ) -> String {
        let health: Vec<Arc<SourceHealth>> = config
            .sources()
            .map(|_| {
                Arc::new(SourceHealth::new(
                    Duration::from_secs(3600),
                    Duration::from_secs(3600),
                ))
            })
            .collect();
        for h in &health {
            h.set_connected(true);
            h.answered();
        }
        let board = Arc::new(Board::new(config, health.clone()));
        board.update(set);
        let acquisition = Acquisition {
            counters: config.channels.iter().map(|_| Arc::default()).collect(),
            health,
            can: config.can_sources.iter().map(|_| Arc::default()).collect(),
        };
        Metrics::new(config, acquisition, board, spans)
            .with_server(Arc::default())
            .with_plc(Arc::default())
            .with_sparkplug(Arc::default())
            .render()
    }

    /// A query slot held shows as in use, a request that found none free as refused,
    /// and the page still passes promtool.
    #[tokio::test(start_paused = true)]
    async fn held_query_slots_show() {
        let config = example("hot-mill.toml");
        let slots = Arc::new(QuerySlots::new(1));
        let metrics = Metrics::new(
            &config,
            Acquisition {
                counters: config.channels.iter().map(|_| Arc::default()).collect(),
                health: Vec::new(),
                can: Vec::new(),
            },
            Arc::new(Board::new(&config, Vec::new())),
            &[],
        )
        .with_web(Arc::clone(&slots));
        let sample = |page: &str, name: &str| -> String {
            page.lines()
                .find_map(|line| line.strip_prefix(&format!("{name} ")))
                .unwrap_or_else(|| panic!("no {name} in\n{page}"))
                .to_owned()
        };
        let page = metrics.render();
        assert_eq!(sample(&page, "millgate_web_history_query_slots"), "1");
        assert_eq!(
            sample(&page, "millgate_web_history_query_slots_in_use"),
            "0"
        );
        let held = slots
            .acquire(Duration::from_secs(1))
            .await
            .expect("a free slot");
        assert!(slots.acquire(Duration::from_secs(1)).await.is_none());
        let page = metrics.render();
        assert_eq!(
            sample(&page, "millgate_web_history_query_slots_in_use"),
            "1"
        );
        assert_eq!(
            sample(&page, "millgate_web_history_queries_refused_total"),
            "1"
        );
        promtool_passes(&page);
        drop(held);
        let page = metrics.render();
        assert_eq!(
            sample(&page, "millgate_web_history_query_slots_in_use"),
            "0"
        );
    }

    /// `promtool check metrics` (Debian's `prometheus`, installed by `scripts/test`)
    /// finds no problem in `page`.
    fn promtool_passes(page: &str) {
        use std::io::Write;
        let mut promtool = std::process::Command::new("promtool")
            .args(["check", "metrics"])
            .stdin(std::process::Stdio::piped())
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .expect(
                "promtool is not installed: scripts/test installs it (apt-get install prometheus)",
            );
        promtool
            .stdin
            .take()
            .unwrap()
            .write_all(page.as_bytes())
            .unwrap();
        let output = promtool.wait_with_output().unwrap();
        assert!(
            output.status.success(),
            "promtool check metrics: {}{}",
            String::from_utf8_lossy(&output.stdout),
            String::from_utf8_lossy(&output.stderr)
        );
    }

    #[test]
    fn every_catalogue_figure_is_a_family_and_a_good_value_a_sample() {
        let hot = example("hot-mill.toml");
        let page = page_of(&hot, &[], |results| {
            let d = &mut results.drivelines[0];
            d.bite_counter = 7;
            d.taf = Some(1.5);
            d.last_bite_unix_ms = Some(1_800_000_000_250);
            d.gap = Some(crate::state::results::GapResults {
                gap_mrad: 2.5,
                low_mrad: 2.0,
                high_mrad: 3.0,
                coupling: Some(1),
                likeliest_coupling: Some(1),
                bites_pooled: 12,
            });
        });
        let tandem = example("tandem-5stand.toml");
        let tandem_page = page_of(&tandem, &[], |results| {
            results.tandem_mills[0].sigma_n_hz = Some(0.5);
        });
        let rod = example("rod-mill.toml");
        let rod_page = page_of(&rod, &[2], |_| {});
        for each in [&page, &tandem_page, &rod_page] {
            promtool_passes(each);
        }
        let all = format!("{page}{tandem_page}{rod_page}");
        for figure in catalogue::all() {
            let name = metric_name(&figure);
            assert!(
                all.contains(&format!("# HELP {name} ")),
                "no family {name} for {} {}",
                figure.subject.name(),
                figure.key
            );
        }
        let label = "{driveline=\"F1 main drive\"}";
        for sample in [
            format!("millgate_driveline_gap_mrad{label} 2.5"),
            format!("millgate_driveline_gap_low_mrad{label} 2"),
            format!("millgate_driveline_gap_coupling{label} 1"),
            format!("millgate_driveline_bites_total{label} 7"),
            format!("millgate_driveline_last_bite_timestamp_seconds{label} 1800000000.25"),
            "millgate_tandem_mill_sigma_n_hz{tandem_mill=\"TCM 2030\"} 0.5".to_owned(),
        ] {
            assert!(all.contains(&sample), "{sample} missing:\n{all}");
        }
        // No value, no sample: the TAF's peak was never computed.
        assert!(
            !page.contains("millgate_driveline_peak_torque_knm{"),
            "{page}"
        );
    }

    #[test]
    fn catalogue_names_follow_prometheus_conventions() {
        for figure in catalogue::DRIVELINE {
            let name = metric_name(&figure.info());
            assert!(name.starts_with("millgate_driveline_"), "{name}");
            assert_eq!(figure.is_counter(), name.ends_with("_total"), "{name}");
            assert!(!name.contains("_counter"), "{name}: a type in the name");
        }
        let time = catalogue::find(catalogue::DRIVELINE, "last_bite_time");
        assert_eq!(
            metric_name(&time.info()),
            "millgate_driveline_last_bite_timestamp_seconds"
        );
    }
}
