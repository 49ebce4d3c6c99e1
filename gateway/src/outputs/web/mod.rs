//! The maintenance web page and its JSON API (`[outputs.web]`): read-only HTTP/1.1
//! on axum, for a maintenance engineer's browser and for tools that poll.
//!
//! - **Pages** (`page.rs`): an overview, one page per driveline and per tandem mill
//!   (its captured chatter episodes) and the alarm list,
//!   each a small server-rendered HTML shell that the page's own script
//!   (`assets/web/app.js`) fills from the JSON API, plotting with the vendored uPlot
//!   (`assets/uplot`, MIT). Everything is compiled into the binary: no CDN, no fonts.
//! - **Encoding** (`encoding.rs`): text answers gzipped by `Accept-Encoding`, the
//!   assets with strong ETags and 304 on `If-None-Match`.
//! - **API** (`api/`): `/api/overview`,
//!   `/api/drivelines[/{name}[/bites|/captures|/wear|/map|/fatigue/history]]`,
//!   `/api/tandem_mills/{name}/captures`,
//!   `/api/captures/{id}[/file|/response|/bands]`,
//!   `/api/alarms` and `/api/events` (server-sent events: the live results, sent when
//!   they change). Live figures come from the [`Board`]'s snapshot; history
//!   figures from the history file through a read-only [`HistoryReader`] of the
//!   request's own, on the blocking pool, bounded by `request_timeout`.
//! - **Bounded and read-only**: served by the gateway's one HTTP stack
//!   (`outputs::http`: GET and HEAD only, no body, bounded heads, header
//!   timeout and connections, security headers). The one exception is
//!   `POST /api/captures` (a manual capture), refused unless
//!   `outputs.web.allow_commands`. None of this runs on the analysis
//!   task: the server only reads the published snapshot and the file.
//!
//! [`HistoryReader`]: crate::history::query::HistoryReader

pub(crate) mod api;
mod encoding;
mod metrics;
pub(crate) mod page;
mod shared;

pub(crate) use shared::{DrivelineInfo, QuerySlots, WebState};

use std::sync::Arc;
use std::time::Duration;

use axum::extract::{Request, State};
use axum::http::{header, HeaderValue, StatusCode};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use axum::Router;
use millgate_config::{Config, WebOutput};
use tokio::net::TcpListener;
use tokio::sync::watch;

use crate::outputs::http::{self, Limits};
use crate::shutdown::Shutdown;
use crate::state::board::Board;

/// The shortest time between two live updates of `/api/events`: changes that come
/// faster are sent together in the next.
pub(crate) const LIVE_PERIOD: Duration = Duration::from_millis(200);

/// The web page server.
#[derive(Debug)]
pub(crate) struct WebServer {
    settings: WebOutput,
    state: Arc<WebState>,
    live: watch::Sender<Arc<String>>,
}

impl WebServer {
    /// A server for `config`'s `[outputs.web]` (`settings`) reading `board` and the
    /// history file (`config.history`), with its history query threads started (an
    /// error when they cannot be).
    pub(crate) fn new(
        config: &Config,
        settings: WebOutput,
        board: Arc<Board>,
    ) -> std::io::Result<Self> {
        let channel = |index: usize| config.channels[index].name.clone();
        let drivelines = config
            .drivelines
            .iter()
            .map(|d| DrivelineInfo {
                name: d.name.clone(),
                taf_warning: d.thresholds.taf_warning,
                taf_alarm: d.thresholds.taf_alarm,
                gap_warning_mrad: d.thresholds.gap_warning_mrad,
                gap_alarm_mrad: d.thresholds.gap_alarm_mrad,
                has_model: d.model.is_some(),
                model: d.model.as_ref().and_then(|path| {
                    // The analysis reports a model that does not load (no wear
                    // diagnosis); the page then shows no simulated response.
                    millgate_sim::model::Model::load(path).ok().map(Arc::new)
                }),
                fatigue_components: d.fatigue.as_ref().map_or_else(Vec::new, |f| {
                    f.components.iter().map(|c| c.name.clone()).collect()
                }),
                fatigue_life_limit: d.fatigue.as_ref().map(|f| f.life_limit),
                identification: shared::identification_json(&d.identification),
            })
            .collect();
        let (live, live_rx) = watch::channel(Arc::new(String::new()));
        let state = WebState {
            config_name: config.name.clone(),
            drivelines,
            tandem_mills: config
                .tandem_mills
                .iter()
                .map(|m| {
                    (
                        m.name.clone(),
                        m.stands.iter().map(|&c| channel(c)).collect(),
                    )
                })
                .collect(),
            rod_mills: config.rod_mills.iter().map(|m| m.name.clone()).collect(),
            sources: config
                .sources()
                .map(|source| (source.name().to_owned(), source.kind()))
                .collect(),
            board,
            history: config.history.as_ref().map(|h| h.path.clone()),
            captures_kept: config.history.as_ref().is_some_and(|h| h.captures.enabled),
            request_timeout: settings.request_timeout,
            query_slots: Arc::new(QuerySlots::new(settings.history_queries)),
            queries: shared::QueryThreads::start(settings.history_queries)?,
            event_streams: Arc::new(tokio::sync::Semaphore::new(settings.max_event_streams)),
            allowed_hosts: settings.allowed_hosts.clone(),
            live: live_rx,
            trends: shared::TrendCache::default(),
            capture_bands: shared::BandsHook::default(),
            allow_commands: settings.allow_commands,
            commands: std::sync::OnceLock::new(),
            command_log: std::sync::Mutex::new(crate::warn_limit::WarnLimit::new(
                crate::warn_limit::WARN_PERIOD,
            )),
        };
        let state = Arc::new(state);
        live.send_replace(Arc::new(api::live_json(&state)));
        Ok(Self {
            settings,
            state,
            live,
        })
    }

    /// The history query slots, for `/metrics`.
    pub(crate) fn query_slots(&self) -> Arc<QuerySlots> {
        Arc::clone(&self.state.query_slots)
    }

    /// The band analysis of tandem mills' captures (`/api/captures/{id}/bands`), given
    /// by the service (the outputs import no analysis); without it that route
    /// answers 409.
    pub(crate) fn with_capture_bands(
        self,
        analyse: crate::state::captures::CaptureBandsFn,
    ) -> Self {
        let _ = self.state.capture_bands.0.set(analyse);
        self
    }

    /// The analysis' command channel, for `POST /api/captures` (taken only with
    /// `outputs.web.allow_commands`).
    pub(crate) fn with_commands(self, commands: crate::state::commands::CommandSender) -> Self {
        let _ = self.state.commands.set(commands);
        self
    }

    /// Serve `listener` until `shutdown`; an error when accepting fails for good.
    pub(crate) async fn run(
        self,
        listener: TcpListener,
        shutdown: Shutdown,
    ) -> std::io::Result<()> {
        let limits = Limits {
            post_paths: &["/api/captures", "/api/drivelines/*/fatigue/reset"],
            max_connections: self.settings.max_connections,
            header_timeout: self.settings.header_timeout,
        };
        let served = http::serve(
            "maintenance page",
            listener,
            router(Arc::clone(&self.state)),
            limits,
            shutdown,
        );
        tokio::select! {
            served = served => served,
            never = live_updates(&self.state, &self.live) => match never {},
        }
    }
}

/// At each change of the results (at most one per [`LIVE_PERIOD`]: the changes in
/// between are coalesced), send the live results to `/api/events` when they differ from
/// what it last sent.
async fn live_updates(
    state: &WebState,
    live: &watch::Sender<Arc<String>>,
) -> std::convert::Infallible {
    let mut changes = state.board.changes();
    loop {
        changes.results().await;
        let json = api::live_json(state);
        if **live.borrow() != json {
            live.send_replace(Arc::new(json));
        }
        tokio::time::sleep(LIVE_PERIOD).await;
    }
}

/// The routes of `state` (the HTTP stack adds the method filter and the security
/// headers).
pub(crate) fn router(state: Arc<WebState>) -> Router {
    Router::new()
        .route("/", get(page::overview))
        .route("/drivelines/{name}", get(page::driveline))
        .route("/tandem_mills/{name}", get(page::tandem_mill))
        .route("/alarms", get(page::alarms))
        .route("/assets/{file}", get(page::asset))
        .route("/favicon.ico", get(page::favicon))
        .route("/api/overview", get(api::overview))
        .route("/api/drivelines", get(api::drivelines))
        .route("/api/drivelines/{name}", get(api::driveline))
        .route("/api/drivelines/{name}/bites", get(api::bites))
        .route("/api/drivelines/{name}/captures", get(api::captures))
        .route(
            "/api/captures",
            axum::routing::post(api::request_capture).fallback(|| async {
                http::error(
                    StatusCode::METHOD_NOT_ALLOWED,
                    "POST only: {\"subject\": NAME, \"seconds\": S} asks for a manual capture",
                )
            }),
        )
        .route("/api/captures/{id}", get(api::capture))
        .route("/api/captures/{id}/file", get(api::capture_file))
        .route("/api/captures/{id}/response", get(api::capture_response))
        .route("/api/captures/{id}/bands", get(api::capture_bands))
        .route(
            "/api/tandem_mills/{name}/captures",
            get(api::tandem_mill_captures),
        )
        .route(
            "/api/tandem_mills/{name}/episodes",
            get(api::tandem_mill_episodes),
        )
        .route(
            "/api/drivelines/{name}/fatigue/reset",
            axum::routing::post(api::reset_fatigue).fallback(|| async {
                http::error(
                    StatusCode::METHOD_NOT_ALLOWED,
                    "POST only: {\"component\": NAME} resets a fatigue component's life",
                )
            }),
        )
        .route("/api/drivelines/{name}/wear", get(api::wear))
        .route(
            "/api/drivelines/{name}/fatigue/history",
            get(api::fatigue_history),
        )
        .route("/api/drivelines/{name}/products", get(api::products))
        .route("/api/drivelines/{name}/map", get(api::gap_maps))
        .route("/api/alarms", get(api::alarms))
        .route("/api/events", get(api::events))
        .fallback(|| async { http::error(StatusCode::NOT_FOUND, "no such page") })
        .layer(axum::middleware::from_fn(encoding::compress))
        .layer(axum::middleware::from_fn_with_state(
            Arc::clone(&state),
            known_host,
        ))
        .with_state(state)
}

/// A warning when `settings` binds an address other hosts can reach (the page
/// shows the plant's state without authentication).
pub(crate) fn exposure_warning(settings: &WebOutput) -> Option<String> {
    (!settings.bind.ip().is_loopback()).then(|| {
        format!(
            "outputs.web.bind: {} accepts clients from other hosts: anyone who reaches it \
             reads the maintenance page and its API without authentication ({})",
            settings.bind,
            if settings.allow_commands {
                "and, with allow_commands, asks for manual captures"
            } else {
                "read-only"
            }
        )
    })
}

/// `Retry-After` of a 503 answer, s: a busy history or full streams free up in
/// seconds.
const RETRY_AFTER_S: &str = "2";

impl IntoResponse for api::ApiError {
    fn into_response(self) -> Response {
        let mut response = http::error(self.status, &self.message);
        if self.status == StatusCode::SERVICE_UNAVAILABLE {
            response
                .headers_mut()
                .insert(header::RETRY_AFTER, HeaderValue::from_static(RETRY_AFTER_S));
        }
        response
    }
}

/// Refuses (421) a request whose `Host` header names a host the page does not
/// answer to: against DNS rebinding, where a page from another site reaches the
/// gateway through a name that resolves to it. IP addresses, `localhost` and
/// `outputs.web.allowed_hosts` are answered; a request without `Host` (HTTP/1.0) is
/// too, as no browser sends one.
async fn known_host(State(state): State<Arc<WebState>>, request: Request, next: Next) -> Response {
    let host = request
        .headers()
        .get(header::HOST)
        .map(|host| host.to_str().unwrap_or(""));
    match host {
        Some(host) if !host_allowed(host, &state.allowed_hosts) => http::error(
            StatusCode::MISDIRECTED_REQUEST,
            &format!(
                "Host \"{}\" is not one this page answers to (an IP address, localhost or \
                 outputs.web.allowed_hosts)",
                host.escape_default()
            ),
        ),
        _ => next.run(request).await,
    }
}

/// Whether `host` (a `Host` header: a name or address, with an optional port) is an
/// IP address, `localhost` or one of `allowed` (lower case).
fn host_allowed(host: &str, allowed: &[String]) -> bool {
    let name = match host.strip_prefix('[') {
        Some(bracketed) => {
            return bracketed
                .split_once(']')
                .is_some_and(|(v6, _)| v6.parse::<std::net::Ipv6Addr>().is_ok())
        }
        None => host.rsplit_once(':').map_or(host, |(name, _)| name),
    };
    let name = name.strip_suffix('.').unwrap_or(name).to_ascii_lowercase();
    name.parse::<std::net::Ipv4Addr>().is_ok() || name == "localhost" || allowed.contains(&name)
}

#[cfg(test)]
mod tests {
    use super::host_allowed;

    #[test]
    fn hosts_are_addresses_localhost_or_the_allowed_names() {
        let allowed = ["mill-gw.plant.example".to_owned()];
        for host in [
            "127.0.0.1",
            "127.0.0.1:8080",
            "10.1.2.3:80",
            "[::1]:8080",
            "[fe80::1]",
            "localhost",
            "LOCALHOST:8080",
            "localhost.",
            "mill-gw.plant.example",
            "Mill-GW.plant.example:8080",
        ] {
            assert!(host_allowed(host, &allowed), "{host}");
        }
        for host in [
            "",
            "evil.example",
            "evil.example:8080",
            "127.0.0.1.evil.example",
            "localhost.evil.example",
            "[::1",
            "[evil.example]:80",
            "mill-gw.plant.example.evil.example",
        ] {
            assert!(!host_allowed(host, &allowed), "{host}");
        }
    }
}
