//! Prometheus `/metrics`: build information, the process' resources and the
//! catalogue's figures of the gateway, per source, driveline, tandem mill, rod mill
//! and span, followed by the
//! families each part writes of its own counters ([`Families`]: the acquisition's in
//! `field/metrics.rs`, the history's in `history/metrics.rs`, each output's in the
//! `metrics.rs` beside it), in the text exposition format (version 0.0.4, written by
//! [`crate::exposition`]).
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

use std::sync::Arc;
use std::time::Duration;

use axum::http::{header, HeaderValue};
use axum::response::IntoResponse;
use axum::routing::get;
use axum::Router;
use millgate_config::{Config, MetricsOutput};
use tokio::net::TcpListener;

use crate::exposition::{Exposition, Families, Kind, Labels};
use crate::outputs::http::{self, Limits};
use crate::shutdown::Shutdown;
use crate::state::board::Board;
use crate::state::catalogue::{self, Figure, FigureInfo, FigureType, Subject, Value};

/// Time a client has to send its whole request head.
pub(crate) const HEAD_TIMEOUT: Duration = Duration::from_secs(5);
/// Scrapes answered at once; Prometheus sends one at a time.
pub(crate) const MAX_SCRAPES: usize = 16;
/// A warning when `settings` binds an address other hosts can reach (`/metrics`
/// shows the plant's figures and the gateway's state without authentication).
pub(crate) fn exposure_warning(settings: &MetricsOutput) -> Option<String> {
    (!settings.bind.ip().is_loopback()).then(|| {
        format!(
            "outputs.metrics.bind: {} accepts clients from other hosts: anyone who reaches it \
             reads /metrics without authentication (read-only)",
            settings.bind
        )
    })
}

/// The content type of the text exposition format.
pub(crate) const CONTENT_TYPE: &str = "text/plain; version=0.0.4; charset=utf-8";

/// A catalogue unit as `/metrics` writes it: in Prometheus' base unit, named in words
/// at the end of the family's name (its naming guide; its linter refuses the
/// abbreviations `s` and `m`).
#[derive(Debug, Clone, Copy, PartialEq)]
struct BaseUnit {
    /// The catalogue's unit.
    unit: &'static str,
    /// How a catalogue key in that unit ends (`gap_mrad`), or, with a leading `*`,
    /// begins (`*days_`: `days_to_gap_alarm`).
    key: &'static str,
    /// The name's ending in the base unit.
    words: &'static str,
    /// Base units per catalogue unit (1000 N*m per kN*m), as `times / per`: a
    /// value is multiplied by `times` and divided by `per`, so that 2.5 mrad is
    /// 0.0025 rad, not 0.0025000000000000005 (2.5 times 0.001).
    times: f64,
    /// See `times`.
    per: f64,
}

/// Seconds per day.
const DAY_S: f64 = 86_400.0;

/// The units `/metrics` writes in base units. The first three were so from the start;
/// the others were written in the catalogue's units before (`_knm`, `_mrad`, `_hz`,
/// `_c`, days), and those names are still written beside the new ones, deprecated
/// (kept one release, said in their HELP: [`deprecated_metric_name`]).
const BASE_UNITS: [BaseUnit; 10] = [
    BaseUnit::same("s", "_s", "_seconds"),
    BaseUnit::same("m/s", "_m_s", "_meters_per_second"),
    BaseUnit::same("1/s", "_per_s", "_per_second"),
    BaseUnit {
        times: 1.0e3,
        ..BaseUnit::same("kN*m", "_knm", "_newton_meters")
    },
    BaseUnit {
        per: 1.0e3,
        ..BaseUnit::same("mrad", "_mrad", "_radians")
    },
    BaseUnit {
        per: 1.0e3 * DAY_S,
        ..BaseUnit::same("mrad/d", "_mrad_per_day", "_radians_per_second")
    },
    BaseUnit::same("Hz", "_hz", "_hertz"),
    BaseUnit::same("degC", "_c", "_celsius"),
    BaseUnit {
        times: DAY_S,
        ..BaseUnit::same("d", "*days_", "_seconds")
    },
    // A fraction of a life per day: `fatigue_rate_per_day` -> `..._rate_per_second`.
    BaseUnit {
        per: DAY_S,
        ..BaseUnit::same("1/d", "_per_day", "_per_second")
    },
];

impl BaseUnit {
    /// A unit whose values stay as they are (only its name changes).
    const fn same(unit: &'static str, key: &'static str, words: &'static str) -> Self {
        Self {
            unit,
            key,
            words,
            times: 1.0,
            per: 1.0,
        }
    }

    /// `value` (in the catalogue's unit) in the base unit.
    fn convert(&self, value: f64) -> f64 {
        value * self.times / self.per
    }
}

/// How many of [`BASE_UNITS`] the names before base units used.
const BASE_UNITS_BEFORE: usize = 3;

/// `key` with its unit written as `base` says, when `key` is in that unit.
fn in_base_unit(key: &str, unit: &str, base: &BaseUnit) -> Option<String> {
    if unit != base.unit {
        return None;
    }
    match base.key.strip_prefix('*') {
        // `days_to_gap_alarm` -> `time_to_gap_alarm_seconds`.
        Some(prefix) => key
            .strip_prefix(prefix)
            .map(|rest| format!("time_{rest}{}", base.words)),
        None => key
            .strip_suffix(base.key)
            .map(|stem| format!("{stem}{}", base.words)),
    }
}

/// The `/metrics` name of a catalogue figure with the units of `units`, and that
/// unit (`None`: values as they are).
fn name_in(figure: &FigureInfo, units: &[BaseUnit]) -> (String, Option<BaseUnit>) {
    if let Some(name) = figure.metric {
        return (name.to_owned(), None);
    }
    let (key, unit) = units
        .iter()
        .find_map(|base| in_base_unit(figure.key, figure.unit, base).map(|key| (key, *base)))
        .map_or_else(
            || (figure.key.to_owned(), None),
            |(key, unit)| (key, Some(unit)),
        );
    let base = format!("millgate_{}_{key}", figure.subject.name());
    let name = if figure.is_counter() {
        format!("{base}_total")
    } else if figure.figure_type == FigureType::Time {
        format!("{}_timestamp_seconds", base.trim_end_matches("_time"))
    } else {
        base
    };
    (name, unit)
}

/// The `/metrics` name of a catalogue figure: `millgate_<subject>_<key>` with its unit
/// in Prometheus' base unit and words ([`BASE_UNITS`]: `_newton_meters`, `_radians`,
/// `_hertz`, `_celsius`, `_seconds`, `_meters_per_second`, `_per_second`), a counter
/// with `_total`, a time as `..._timestamp_seconds`, unless the catalogue names it.
pub(crate) fn metric_name(figure: &FigureInfo) -> String {
    name_in(figure, &BASE_UNITS).0
}

/// Figures that came after `/metrics` moved to base units: they never had a name in
/// the catalogue's units, so none is kept for them.
const NEW_IN_BASE_UNITS: [&str; 2] = ["fatigue_rate_per_day", "days_to_fatigue_limit"];

/// The name the figure had on `/metrics` before base units, when it differs from
/// [`metric_name`]: written too, in the catalogue's unit, deprecated (kept one
/// release).
pub(crate) fn deprecated_metric_name(figure: &FigureInfo) -> Option<String> {
    if NEW_IN_BASE_UNITS.contains(&figure.key) {
        return None;
    }
    let (old, _) = name_in(figure, &BASE_UNITS[..BASE_UNITS_BEFORE]);
    (old != metric_name(figure)).then_some(old)
}

/// A good value as a sample: a time in Unix seconds.
fn sample(value: Value) -> f64 {
    match value {
        Value::Time(ms) => ms as f64 / 1000.0,
        other => other.as_f64(),
    }
}

/// One family per figure of `figures`, a sample per row whose value is good, in base
/// units; then, for a figure renamed to base units, the family of its earlier name in its
/// unit, marked deprecated.
fn catalogue_families<R: Subject>(
    page: &mut Exposition,
    figures: &[Figure<R>],
    rows: &[(Labels<'_>, &R)],
) {
    for figure in figures {
        let info = figure.info();
        let kind = if figure.is_counter() {
            Kind::Counter
        } else {
            Kind::Gauge
        };
        let (name, base) = name_in(&info, &BASE_UNITS);
        let renamed = deprecated_metric_name(&info);
        let help = match (&renamed, base) {
            (Some(_), Some(base)) => format!(
                "{}, {} (the other outputs give {}).",
                figure.description,
                base.words.trim_start_matches('_').replace('_', " "),
                figure.unit
            ),
            _ if figure.unit.is_empty() => format!("{}.", figure.description),
            _ => format!("{}, {}.", figure.description, figure.unit),
        };
        let good: Vec<(Labels<'_>, f64)> = rows
            .iter()
            .filter_map(|(labels, subject)| {
                let value = figure.read(subject).good()?;
                Some((labels.clone(), sample(value)))
            })
            .collect();
        let scaled = good.iter().map(|(labels, value)| {
            let value = base.map_or(*value, |base| base.convert(*value));
            (labels.clone(), value)
        });
        page.family(&name, kind, &help, scaled);
        if let Some(old) = renamed {
            let help = format!(
                "Deprecated (kept one release): the name before base units of {name}. \
                 {}, {}.",
                figure.description, figure.unit
            );
            page.family(&old, kind, &help, good);
        }
    }
}

/// What the metrics page shows: the build, the process, the catalogue's figures, then
/// the families of each part added with [`Metrics::with`], in that order.
#[derive(Debug)]
pub(crate) struct Metrics {
    source_names: Vec<String>,
    rod_span_names: Vec<Vec<String>>,
    board: Arc<Board>,
    rod_mill_names: Vec<String>,
    families: Vec<Arc<dyn Families>>,
}

impl Metrics {
    /// The page for `config`: the results of `board`; `rod_mill_spans` is each rod
    /// mill's span count.
    pub(crate) fn new(config: &Config, board: Arc<Board>, rod_mill_spans: &[usize]) -> Self {
        Self {
            source_names: config.sources().map(|s| s.name().to_owned()).collect(),
            rod_span_names: rod_mill_spans
                .iter()
                .map(|&spans| (1..=spans).map(|span| span.to_string()).collect())
                .collect(),
            rod_mill_names: config.rod_mills.iter().map(|m| m.name.clone()).collect(),
            board,
            families: Vec::new(),
        }
    }

    /// Also show `families` (a field source's, the history's or an output's counters),
    /// after those added before.
    pub(crate) fn with(mut self, families: Arc<dyn Families>) -> Self {
        self.families.push(families);
        self
    }

    /// The page, in the Prometheus text format.
    pub(crate) fn render(&self) -> String {
        let mut page = Exposition::new();
        page.family(
            "millgate_build_info",
            Kind::Gauge,
            "The millgate build: its version (always 1).",
            [(vec![("version", env!("CARGO_PKG_VERSION"))], 1.0)],
        );
        process_metrics(&mut page);
        self.figures(&mut page);
        for families in &self.families {
            families.write_families(&mut page);
        }
        page.into_text()
    }

    /// The catalogue's figures of the gateway and of every source, driveline, tandem
    /// mill, rod mill and span.
    fn figures(&self, page: &mut Exposition) {
        let results = self.board.results();
        catalogue_families(
            page,
            catalogue::GATEWAY,
            &[(Vec::new(), &results.gateway())],
        );
        let sources: Vec<_> = (0..self.source_names.len())
            .map(|k| results.source(k))
            .collect();
        let source_rows: Vec<(Labels<'_>, _)> = self
            .source_names
            .iter()
            .zip(&sources)
            .map(|(name, s)| (vec![("source", name.as_str())], s))
            .collect();
        catalogue_families(page, catalogue::SOURCE, &source_rows);
        let driveline_names = self.board.driveline_names();
        let drivelines: Vec<(Labels<'_>, _)> = driveline_names
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
    pub(crate) async fn run(
        self,
        listener: TcpListener,
        shutdown: Shutdown,
    ) -> std::io::Result<()> {
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
    use crate::field::counters::Acquisition;
    use crate::field::metrics::AcquisitionFamilies;
    use crate::field::source_health::SourceHealth;
    use crate::outputs::modbus::hmi_server::ServerCounters;
    use crate::outputs::modbus::plc_writer::PlcCounters;
    use crate::outputs::sparkplug::SparkplugStatus;
    use crate::outputs::web::QuerySlots;

    use crate::testing::example_config as example;

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
        board.latencies().block_taken(Duration::from_micros(300));
        let acquisition = Acquisition {
            counters: config.channels.iter().map(|_| Arc::default()).collect(),
            health,
            can: config.can_sources.iter().map(|_| Arc::default()).collect(),
        };
        let plc: Arc<PlcCounters> = Arc::default();
        let server: Arc<ServerCounters> = Arc::default();
        let sparkplug = Arc::new(SparkplugStatus::for_servers(vec!["127.0.0.1:1883".into()]));
        Metrics::new(config, Arc::clone(&board), spans)
            .with(Arc::new(AcquisitionFamilies::new(config, acquisition)))
            .with(plc)
            .with(Arc::clone(board.latencies()) as Arc<dyn Families>)
            .with(server)
            .with(Arc::new(board.history().clone()))
            .with(sparkplug)
            .render()
    }

    /// A query slot held shows as in use, a request that found none free as refused,
    /// and the page still passes promtool.
    #[tokio::test(start_paused = true)]
    async fn held_query_slots_show() {
        let config = example("hot-mill.toml");
        let slots = Arc::new(QuerySlots::new(1));
        let metrics = Metrics::new(&config, Arc::new(Board::new(&config, Vec::new())), &[])
            .with(Arc::clone(&slots) as Arc<dyn Families>);
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
                growth: None,
                forecast: None,
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
        let label = "{driveline=\"F1 main drive\"}";
        for sample in [
            format!("millgate_driveline_gap_radians{label} 0.0025"),
            format!("millgate_driveline_gap_low_radians{label} 0.002"),
            format!("millgate_driveline_gap_coupling{label} 1"),
            format!("millgate_driveline_bites_total{label} 7"),
            format!("millgate_driveline_last_bite_timestamp_seconds{label} 1800000000.25"),
            "millgate_tandem_mill_sigma_n_hertz{tandem_mill=\"TCM 2030\"} 0.5".to_owned(),
            // The names before base units, in the catalogue's units, kept one release.
            format!("millgate_driveline_gap_mrad{label} 2.5"),
            format!("millgate_driveline_gap_low_mrad{label} 2"),
            "millgate_tandem_mill_sigma_n_hz{tandem_mill=\"TCM 2030\"} 0.5".to_owned(),
        ] {
            assert!(all.contains(&sample), "{sample} missing:\n{all}");
        }
        assert!(
            page.contains(
                "# HELP millgate_driveline_gap_mrad Deprecated (kept one release): the name \
                 before base units of millgate_driveline_gap_radians."
            ),
            "{page}"
        );
        // No value, no family: the TAF's peak was never computed.
        assert!(!page.contains("millgate_driveline_peak_torque_"), "{page}");
        // A driveline-only gateway writes no tandem or rod mill family.
        assert!(!page.contains("millgate_tandem_mill_"), "{page}");
        assert!(!page.contains("millgate_rod_"), "{page}");
        for each in [&page, &tandem_page, &rod_page] {
            every_family_has_a_sample(each);
        }
    }

    /// Every `# TYPE` line of `page` is followed by a sample of its family.
    fn every_family_has_a_sample(page: &str) {
        let lines: Vec<&str> = page.lines().collect();
        for (index, line) in lines.iter().enumerate() {
            if let Some(rest) = line.strip_prefix("# TYPE ") {
                let name = rest.split(' ').next().unwrap();
                let next = lines.get(index + 1).copied().unwrap_or("");
                assert!(
                    next.starts_with(&format!("{name} "))
                        || next.starts_with(&format!("{name}{{"))
                        || next.starts_with(&format!("{name}_bucket{{")),
                    "family {name} without a sample:\n{page}"
                );
            }
        }
    }

    /// Every figure with a unit is named in Prometheus' base unit, and a renamed one
    /// keeps its earlier name beside it.
    #[test]
    fn figures_with_a_unit_are_named_in_base_units() {
        for figure in catalogue::all() {
            let name = metric_name(&figure);
            if figure.unit.is_empty() || figure.metric.is_some() {
                continue;
            }
            let base = BASE_UNITS
                .iter()
                .find(|base| in_base_unit(figure.key, figure.unit, base).is_some())
                .unwrap_or_else(|| {
                    panic!("{name}: no base unit for {} ({})", figure.unit, figure.key)
                });
            assert!(
                name.ends_with(base.words) || name.ends_with(&format!("{}_total", base.words)),
                "{name}"
            );
        }
        let named = |key| {
            let info = catalogue::find(catalogue::DRIVELINE, key).info();
            (metric_name(&info), deprecated_metric_name(&info))
        };
        assert_eq!(
            named("static_torque_knm"),
            (
                "millgate_driveline_static_torque_newton_meters".to_owned(),
                Some("millgate_driveline_static_torque_knm".to_owned())
            )
        );
        assert_eq!(
            named("days_to_gap_alarm"),
            (
                "millgate_driveline_time_to_gap_alarm_seconds".to_owned(),
                Some("millgate_driveline_days_to_gap_alarm".to_owned())
            )
        );
        assert_eq!(
            named("first_period_s"),
            ("millgate_driveline_first_period_seconds".to_owned(), None)
        );
        // A figure that came after the rename has no earlier name.
        assert_eq!(
            named("days_to_fatigue_limit"),
            (
                "millgate_driveline_time_to_fatigue_limit_seconds".to_owned(),
                None
            )
        );
        for key in NEW_IN_BASE_UNITS {
            catalogue::find(catalogue::DRIVELINE, key);
        }
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

    /// The gateway's and the sources' families keep the names, types and labels they
    /// had before the catalogue held them: `millgate_heartbeat` a gauge (it wraps at
    /// 65535), `millgate_source_status{source=...}` 0 ok, 1 stale, 2 lost.
    #[test]
    fn the_heartbeat_is_a_gauge_and_the_source_status_is_labelled_by_source() {
        let config = example("hot-mill.toml");
        let page = page_of(&config, &[], |results| results.heartbeat = 65_535);
        promtool_passes(&page);
        assert!(page.contains("# TYPE millgate_heartbeat gauge\n"), "{page}");
        assert!(page.contains("\nmillgate_heartbeat 65535\n"), "{page}");
        assert!(
            page.contains("# TYPE millgate_source_status gauge\n"),
            "{page}"
        );
        let source = config.sources().next().expect("a source").name().to_owned();
        // page_of's sources have answered: ok.
        let ok = format!("\nmillgate_source_status{{source=\"{source}\"}} 0\n");
        assert!(page.contains(&ok), "{ok} missing:\n{page}");
        let flag = format!("\nmillgate_source_ok{{source=\"{source}\"}} 1\n");
        assert!(page.contains(&flag), "{flag} missing:\n{page}");
        assert_eq!(page.matches("# TYPE millgate_heartbeat ").count(), 1);
        // The latencies: a block waited 0.3 ms, no bite reached a PLC.
        assert!(
            page.contains(
                "# TYPE millgate_block_wait_seconds histogram\n\
                 millgate_block_wait_seconds_bucket{le=\"0.0001\"} 0\n\
                 millgate_block_wait_seconds_bucket{le=\"0.0002\"} 0\n\
                 millgate_block_wait_seconds_bucket{le=\"0.0005\"} 1\n"
            ),
            "{page}"
        );
        assert!(
            page.contains("\nmillgate_block_wait_seconds_count 1\n"),
            "{page}"
        );
        assert!(!page.contains("millgate_bite_to_plc_seconds"), "{page}");
        assert_eq!(page.matches("# TYPE millgate_source_status ").count(), 1);
        // A new figure of the gateway: its state, 0 starting.
        assert!(page.contains("\nmillgate_gateway_state 0\n"), "{page}");
    }
}
