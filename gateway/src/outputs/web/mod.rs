//! The maintenance web page and its JSON API (`[outputs.web]`): read-only HTTP/1.1
//! on axum, for a maintenance engineer's browser and for tools that poll.
//!
//! - **Pages** ([`page`]): an overview, one page per driveline and the alarm list,
//!   each a small server-rendered HTML shell that the page's own script
//!   (`assets/web/app.js`) fills from the JSON API, plotting with the vendored uPlot
//!   (`assets/uplot`, MIT). Everything is compiled into the binary: no CDN, no fonts.
//! - **API** ([`api`]): `/api/overview`, `/api/drivelines[/{name}[/bites|/wear|/map]]`,
//!   `/api/alarms` and `/api/events` (server-sent events: the live results, sent when
//!   they change). Live figures come from the [`Board`]'s snapshot; history
//!   figures from the history file through a read-only [`HistoryReader`] of the
//!   request's own, on the blocking pool, bounded by `request_timeout`.
//! - **Bounded and read-only**: served by the gateway's one HTTP stack
//!   ([`crate::outputs::http`]: GET and HEAD only, no body, bounded heads, header
//!   timeout and connections, security headers). None of this runs on the analysis
//!   task: the server only reads the published snapshot and the file.
//!
//! [`HistoryReader`]: crate::outputs::history::query::HistoryReader

pub mod api;
pub mod page;
mod shared;

pub use shared::{DrivelineInfo, WebState};

use std::sync::Arc;
use std::time::Duration;

use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use axum::Router;
use millgate_config::{Config, WebOutput};
use tokio::net::TcpListener;
use tokio::sync::watch;

use crate::outputs::http::{self, Limits};
use crate::shutdown::Shutdown;
use crate::state::board::Board;

/// How often the live results are compared with what `/api/events` last sent.
pub const LIVE_PERIOD: Duration = Duration::from_millis(200);

/// The web page server.
#[derive(Debug)]
pub struct WebServer {
    settings: WebOutput,
    state: Arc<WebState>,
    live: watch::Sender<Arc<String>>,
}

impl WebServer {
    /// A server for `config`'s `[outputs.web]` (`settings`) reading `board` and the
    /// history file (`config.history`).
    pub fn new(config: &Config, settings: WebOutput, board: Arc<Board>) -> Self {
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
            request_timeout: settings.request_timeout,
            live: live_rx,
            trends: shared::TrendCache::default(),
        };
        let state = Arc::new(state);
        live.send_replace(Arc::new(api::live_json(&state)));
        Self {
            settings,
            state,
            live,
        }
    }

    /// Serve `listener` until `shutdown`; an error when accepting fails for good.
    pub async fn run(self, listener: TcpListener, shutdown: Shutdown) -> std::io::Result<()> {
        let limits = Limits {
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

/// Compare the live results with what `/api/events` last sent every [`LIVE_PERIOD`],
/// and send them when they changed.
async fn live_updates(
    state: &WebState,
    live: &watch::Sender<Arc<String>>,
) -> std::convert::Infallible {
    let mut tick = tokio::time::interval(LIVE_PERIOD);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    loop {
        tick.tick().await;
        let json = api::live_json(state);
        if **live.borrow() != json {
            live.send_replace(Arc::new(json));
        }
    }
}

/// The routes of `state` (the HTTP stack adds the method filter and the security
/// headers).
pub(crate) fn router(state: Arc<WebState>) -> Router {
    Router::new()
        .route("/", get(page::overview))
        .route("/drivelines/{name}", get(page::driveline))
        .route("/alarms", get(page::alarms))
        .route("/assets/{file}", get(page::asset))
        .route("/api/overview", get(api::overview))
        .route("/api/drivelines", get(api::drivelines))
        .route("/api/drivelines/{name}", get(api::driveline))
        .route("/api/drivelines/{name}/bites", get(api::bites))
        .route("/api/drivelines/{name}/wear", get(api::wear))
        .route("/api/drivelines/{name}/map", get(api::gap_maps))
        .route("/api/alarms", get(api::alarms))
        .route("/api/events", get(api::events))
        .fallback(|| async { http::error(StatusCode::NOT_FOUND, "no such page") })
        .with_state(state)
}

/// A warning when `settings` binds an address other hosts can reach (the page
/// shows the plant's state without authentication).
pub fn exposure_warning(settings: &WebOutput) -> Option<String> {
    (!settings.bind.ip().is_loopback()).then(|| {
        format!(
            "outputs.web.bind: {} accepts clients from other hosts: anyone who reaches it \
             reads the maintenance page and its API without authentication (read-only)",
            settings.bind
        )
    })
}

impl IntoResponse for api::ApiError {
    fn into_response(self) -> Response {
        http::error(self.status, &self.message)
    }
}
