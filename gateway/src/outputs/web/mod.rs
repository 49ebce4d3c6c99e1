//! The maintenance web page and its JSON API (`[outputs.web]`): read-only HTTP/1.1
//! on axum, for a maintenance engineer's browser and for tools that poll.
//!
//! - **Pages** ([`page`]): an overview, one page per driveline and the alarm list,
//!   each a small server-rendered HTML shell that the page's own script
//!   (`assets/web/app.js`) fills from the JSON API, plotting with the vendored uPlot
//!   (`assets/uplot`, MIT). Everything is compiled into the binary: no CDN, no fonts.
//! - **API** ([`api`]): `/api/overview`, `/api/drivelines[/{name}[/bites|/wear|/map]]`,
//!   `/api/alarms` and `/api/events` (server-sent events: the live results, sent when
//!   they change). Live figures come from the [`Publisher`]'s snapshot; history
//!   figures from the history file through a read-only [`HistoryReader`] of the
//!   request's own, on the blocking pool, bounded by `request_timeout`.
//! - **Bounded and read-only**: GET and HEAD only (405 otherwise), no request body
//!   (413), headers within 16 KiB (431) and within `header_timeout` (the connection
//!   is closed: a slow client cannot hold it), at most `max_connections` connections
//!   (a further one is answered 503 and closed). Every response carries the security
//!   headers of [`security_headers`]. None of this runs on the analysis task: the
//!   server only reads the published snapshot and the file.
//!
//! [`HistoryReader`]: crate::outputs::history::query::HistoryReader

pub mod api;
pub mod page;

use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use axum::extract::Request;
use axum::http::{header, HeaderValue, Method, StatusCode};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use axum::Router;
use hyper_util::rt::{TokioIo, TokioTimer};
use hyper_util::service::TowerToHyperService;
use millgate_config::{Config, WebOutput};
use tokio::net::TcpListener;
use tokio::sync::{watch, Semaphore};
use tokio::task::JoinSet;

use crate::outputs::accept::AcceptFailures;
use crate::outputs::publisher::Publisher;
use crate::shutdown::Shutdown;
use crate::warn_limit::WarnLimit;

/// Largest request head (request line and headers) read, bytes; a larger one is
/// answered 431. hyper's smallest allowed buffer is 8 KiB.
pub const MAX_HEAD_BYTES: usize = 16 * 1024;

/// How often the live results are compared with what `/api/events` last sent.
pub const LIVE_PERIOD: Duration = Duration::from_millis(200);

/// The Content-Security-Policy of every response: the page's own scripts, styles and
/// connections only (no inline script, no other origin), no frames, no forms.
pub const CONTENT_SECURITY_POLICY: &str = "default-src 'none'; script-src 'self'; \
     style-src 'self'; img-src 'self' data:; connect-src 'self'; base-uri 'none'; \
     form-action 'none'; frame-ancestors 'none'";

/// Answer to a connection past `max_connections` (written without waiting).
const BUSY_RESPONSE: &[u8] = b"HTTP/1.1 503 Service Unavailable\r\n\
content-type: application/json\r\nconnection: close\r\ncontent-length: 57\r\n\r\n\
{\"error\": \"too many connections to the maintenance page\"}";

/// Connections past `max_connections` answered 503 at once; more are closed unanswered.
const REFUSALS: usize = 8;

/// How long a refused connection's request is read (and dropped) before the close:
/// closing a socket with unread data sends a reset, which loses the 503 answer.
const REFUSAL_DRAIN: Duration = Duration::from_millis(200);

/// How often a full server is logged at most.
const WARN_PERIOD: Duration = Duration::from_secs(60);

/// What the configuration says about a driveline, for the pages.
#[derive(Debug, Clone)]
pub struct DrivelineInfo {
    /// Its name.
    pub name: String,
    /// TAF warning and alarm thresholds.
    pub taf_warning: f64,
    /// TAF alarm threshold.
    pub taf_alarm: f64,
    /// Gap warning threshold, mrad.
    pub gap_warning_mrad: f64,
    /// Gap alarm threshold, mrad.
    pub gap_alarm_mrad: f64,
    /// Whether it has a model (the gap diagnosis runs only with one).
    pub has_model: bool,
}

/// Everything the handlers share.
#[derive(Debug)]
pub struct WebState {
    /// The configuration's name.
    pub(crate) config_name: String,
    pub(crate) drivelines: Vec<DrivelineInfo>,
    /// Tandem mills: name and stand channel names.
    pub(crate) mills: Vec<(String, Vec<String>)>,
    /// Rod mills by name.
    pub(crate) rod_mills: Vec<String>,
    /// Sources: name and kind (`modbus`, `can`), Modbus first as in the results.
    pub(crate) sources: Vec<(String, &'static str)>,
    pub(crate) publisher: Arc<Publisher>,
    /// The history file, `None` without `[history]`.
    pub(crate) history: Option<PathBuf>,
    pub(crate) request_timeout: Duration,
    /// The live results as `/api/events` sends them (JSON), newest.
    pub(crate) live: watch::Receiver<Arc<String>>,
    /// Gap trends as last fitted, per driveline ([`api`]'s `gap_trend`).
    pub(crate) trends: api::TrendCache,
}

/// The web page server.
#[derive(Debug)]
pub struct WebServer {
    settings: WebOutput,
    state: Arc<WebState>,
    live: watch::Sender<Arc<String>>,
}

impl WebServer {
    /// A server for `config`'s `[outputs.web]` (`settings`) reading `publisher` and the
    /// history file (`config.history`).
    pub fn new(config: &Config, settings: WebOutput, publisher: Arc<Publisher>) -> Self {
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
            mills: config
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
                .modbus_sources
                .iter()
                .map(|s| (s.name.clone(), "modbus"))
                .chain(config.can_sources.iter().map(|s| (s.name.clone(), "can")))
                .collect(),
            publisher,
            history: config.history.as_ref().map(|h| h.path.clone()),
            request_timeout: settings.request_timeout,
            live: live_rx,
            trends: api::TrendCache::default(),
        };
        let state = Arc::new(state);
        live.send_replace(Arc::new(api::live_json(&state)));
        Self {
            settings,
            state,
            live,
        }
    }

    /// The routes, with the method filter and the security headers.
    pub fn router(&self) -> Router {
        router(Arc::clone(&self.state))
    }

    /// Serve `listener` until `shutdown`; an error when accepting fails for good.
    pub async fn run(self, listener: TcpListener, mut shutdown: Shutdown) -> std::io::Result<()> {
        let local = listener.local_addr()?;
        tracing::info!(%local, max_connections = self.settings.max_connections, "maintenance page listening");
        let router = self.router();
        let slots = Arc::new(Semaphore::new(self.settings.max_connections));
        let refusal_slots = Arc::new(Semaphore::new(REFUSALS));
        let mut connections = JoinSet::new();
        let mut refusals = WarnLimit::new(WARN_PERIOD);
        let mut accept_failures = AcceptFailures::default();
        let mut live_tick = tokio::time::interval(LIVE_PERIOD);
        live_tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        loop {
            let accepted = tokio::select! {
                accepted = listener.accept() => accepted,
                () = shutdown.recv() => break,
                _ = live_tick.tick() => {
                    let live = api::live_json(&self.state);
                    if **self.live.borrow() != live {
                        self.live.send_replace(Arc::new(live));
                    }
                    continue;
                }
                Some(_) = connections.join_next(), if !connections.is_empty() => continue,
            };
            let Some((stream, peer)) = accept_failures.check(accepted, "maintenance page").await?
            else {
                continue;
            };
            let Ok(slot) = Arc::clone(&slots).try_acquire_owned() else {
                // Answered 503 by a refusal task of its own while there are refusal
                // slots (bounded too), else closed at once.
                if let Ok(refusal) = Arc::clone(&refusal_slots).try_acquire_owned() {
                    connections.spawn(async move {
                        refuse(stream).await;
                        drop(refusal);
                    });
                }
                if let Some(suppressed) = refusals.occurred(tokio::time::Instant::now()) {
                    tracing::warn!(%peer, max = self.settings.max_connections, suppressed, "maintenance page full, connection refused");
                }
                continue;
            };
            connections.spawn(serve_connection(
                stream,
                peer,
                router.clone(),
                self.settings.header_timeout,
                slot,
            ));
        }
        connections.shutdown().await;
        Ok(())
    }
}

/// Answer a connection past the limit with [`BUSY_RESPONSE`] and close it.
async fn refuse(mut stream: tokio::net::TcpStream) {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let answered = async {
        stream.write_all(BUSY_RESPONSE).await?;
        stream.shutdown().await?;
        let mut drain = [0u8; 4096];
        while stream.read(&mut drain).await? > 0 {}
        std::io::Result::Ok(())
    };
    let _ = tokio::time::timeout(REFUSAL_DRAIN, answered).await;
}

/// One connection: HTTP/1.1 with keep-alive; the head must arrive within
/// `header_timeout` (from the connection's start or the previous response) and fit
/// [`MAX_HEAD_BYTES`].
async fn serve_connection(
    stream: tokio::net::TcpStream,
    peer: SocketAddr,
    router: Router,
    header_timeout: Duration,
    slot: tokio::sync::OwnedSemaphorePermit,
) {
    let served = hyper::server::conn::http1::Builder::new()
        .timer(TokioTimer::new())
        .header_read_timeout(header_timeout)
        .max_buf_size(MAX_HEAD_BYTES)
        .serve_connection(TokioIo::new(stream), TowerToHyperService::new(router))
        .await;
    if let Err(error) = served {
        tracing::debug!(%peer, %error, "maintenance page connection ended");
    }
    drop(slot);
}

/// The routes of `state`, with the method filter and the security headers.
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
        .route("/api/drivelines/{name}/map", get(api::wear_map))
        .route("/api/alarms", get(api::alarms))
        .route("/api/events", get(api::events))
        .fallback(|| async { api::error(StatusCode::NOT_FOUND, "no such page") })
        .with_state(state)
        .layer(axum::middleware::from_fn(read_only))
}

/// Refuses what a read-only server does not take (any method but GET and HEAD: 405;
/// a request body: 413), then adds [`security_headers`] to the answer.
async fn read_only(request: Request, next: Next) -> Response {
    let mut response = if request.method() != Method::GET && request.method() != Method::HEAD {
        let mut refused = api::error(
            StatusCode::METHOD_NOT_ALLOWED,
            "the maintenance page is read-only: only GET and HEAD are allowed",
        );
        refused
            .headers_mut()
            .insert(header::ALLOW, HeaderValue::from_static("GET, HEAD"));
        refused
    } else if has_body(&request) {
        api::error(
            StatusCode::PAYLOAD_TOO_LARGE,
            "a request to the maintenance page has no body",
        )
    } else {
        next.run(request).await
    };
    security_headers(response.headers_mut());
    response
}

/// Whether the request announces a body (a length above 0, or chunked).
fn has_body(request: &Request) -> bool {
    let headers = request.headers();
    headers.contains_key(header::TRANSFER_ENCODING)
        || headers
            .get(header::CONTENT_LENGTH)
            .is_some_and(|length| length.as_bytes() != b"0")
}

/// The headers every answer carries: [`CONTENT_SECURITY_POLICY`], no MIME sniffing,
/// no referrer, no framing; `Cache-Control: no-store` unless the route set its own.
pub fn security_headers(headers: &mut axum::http::HeaderMap) {
    headers.insert(
        header::CONTENT_SECURITY_POLICY,
        HeaderValue::from_static(CONTENT_SECURITY_POLICY),
    );
    headers.insert(
        header::X_CONTENT_TYPE_OPTIONS,
        HeaderValue::from_static("nosniff"),
    );
    headers.insert(
        header::REFERRER_POLICY,
        HeaderValue::from_static("no-referrer"),
    );
    headers.insert(header::X_FRAME_OPTIONS, HeaderValue::from_static("DENY"));
    headers
        .entry(header::CACHE_CONTROL)
        .or_insert(HeaderValue::from_static("no-store"));
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
        api::error(self.status, &self.message)
    }
}
