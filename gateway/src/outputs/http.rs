//! The gateway's one HTTP stack, shared by the maintenance page and `/metrics`:
//! read-only HTTP/1.1 on hyper and axum, served by a bounded accept loop.
//!
//! - GET and HEAD only (405 otherwise), no request body (413), except POST on the
//!   paths a server names in [`Limits::post_paths`] (the page's commands, the manual
//!   capture and the fatigue reset, whose handlers check and bound their body); the head within
//!   16 KiB (431) and within the listener's header timeout (the connection
//!   is closed: a slow client cannot hold it).
//! - At most `max_connections` connections. When all are taken, a new one evicts an
//!   idle connection (waiting for a request head, or between requests; never one
//!   answering): the oldest idle one of the other peer address holding the most
//!   connections, so clients that hold slow or idle connections lose them first. A
//!   new connection from an address that already holds more than any other, or with
//!   none idle to evict, is answered 503 and closed (a bounded number of such
//!   answers at once, the rest closed unanswered).
//! - A listener whose `accept` keeps failing ends the loop with the error
//!   (the accept policy it shares with the HMI server), so the service sees the output
//!   fail.
//! - Every answer carries the security headers (a strict Content-Security-Policy, no
//!   sniffing, no referrer, no framing).

use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

use axum::extract::Request;
use axum::http::{header, HeaderValue, Method, StatusCode};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use axum::Json;
use axum::Router;
use hyper_util::rt::{TokioIo, TokioTimer};
use hyper_util::service::TowerToHyperService;
use tokio::net::TcpListener;
use tokio::sync::Semaphore;
use tokio::task::JoinSet;

use crate::outputs::accept::AcceptFailures;
use crate::shutdown::Shutdown;
use crate::warn_limit::WarnLimit;

/// Largest request head (request line and headers) read, bytes; a larger one is
/// answered 431. hyper's smallest allowed buffer is 8 KiB.
pub(crate) const MAX_HEAD_BYTES: usize = 16 * 1024;

/// The Content-Security-Policy of every response: the page's own scripts, styles and
/// connections only (no inline script, no other origin), no frames, no forms.
pub(crate) const CONTENT_SECURITY_POLICY: &str = "default-src 'none'; script-src 'self'; \
     style-src 'self'; img-src 'self' data:; connect-src 'self'; base-uri 'none'; \
     form-action 'none'; frame-ancestors 'none'";

/// Answer to a connection past `max_connections` (written without waiting).
const BUSY_RESPONSE: &[u8] = b"HTTP/1.1 503 Service Unavailable\r\n\
content-type: application/json\r\nconnection: close\r\ncontent-length: 35\r\n\r\n\
{\"error\": \"too many connections\"}\r\n";

/// Connections past `max_connections` answered 503 at once; more are closed unanswered.
const REFUSALS: usize = 8;

/// How long a refused connection's request is read (and dropped) before the close:
/// closing a socket with unread data sends a reset, which loses the 503 answer.
const REFUSAL_DRAIN: Duration = Duration::from_millis(200);

/// How long a new connection waits for the slot an evicted one frees.
const EVICTION_WAIT: Duration = Duration::from_millis(500);

/// How often a full server is logged at most.
const WARN_PERIOD: Duration = Duration::from_secs(60);

/// A listener's bounds.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Limits {
    /// Connections served at once.
    pub(crate) max_connections: usize,
    /// Time a client has to send a request head.
    pub(crate) header_timeout: Duration,
    /// Paths that also take POST, with a body (their handler bounds it); every other
    /// path is read-only. A segment `*` stands for any one segment
    /// (`/api/drivelines/*/fatigue/reset`).
    pub(crate) post_paths: &'static [&'static str],
}

/// `{"error": message}` with `status`.
pub(crate) fn error(status: StatusCode, message: &str) -> Response {
    #[derive(serde::Serialize)]
    struct Body<'a> {
        error: &'a str,
    }
    (status, Json(Body { error: message })).into_response()
}

/// Serve `router` on `listener` within `limits` until `shutdown`; `name` names the
/// listener in the log. An error when accepting fails for good.
pub(crate) async fn serve(
    name: &'static str,
    listener: TcpListener,
    router: Router,
    limits: Limits,
    mut shutdown: Shutdown,
) -> std::io::Result<()> {
    let router = router.layer(axum::middleware::from_fn_with_state(
        limits.post_paths,
        read_only,
    ));
    let local = listener.local_addr()?;
    tracing::info!(%local, max_connections = limits.max_connections, "{name} listening");
    let slots = Arc::new(Semaphore::new(limits.max_connections));
    let refusal_slots = Arc::new(Semaphore::new(REFUSALS));
    let registry = Arc::new(Registry::default());
    let mut connections = JoinSet::new();
    let mut refusals = WarnLimit::new(WARN_PERIOD);
    let mut accept_failures = AcceptFailures::default();
    loop {
        let accepted = tokio::select! {
            accepted = listener.accept() => accepted,
            () = shutdown.recv() => break,
            Some(_) = connections.join_next(), if !connections.is_empty() => continue,
        };
        let Some((stream, peer)) = accept_failures.check(accepted, name).await? else {
            continue;
        };
        let slot = match Arc::clone(&slots).try_acquire_owned() {
            Ok(slot) => Some(slot),
            Err(_) => {
                if let Some(suppressed) = refusals.occurred(tokio::time::Instant::now()) {
                    tracing::warn!(%peer, max = limits.max_connections, suppressed, "{name} full: an idle connection is evicted or the new one refused");
                }
                None
            }
        };
        if let Some(slot) = slot {
            connections.spawn(serve_connection(
                stream,
                peer,
                router.clone(),
                limits.header_timeout,
                (slot, Arc::clone(&registry)),
            ));
            continue;
        }
        // Full: evict an idle connection and take its slot, or answer 503 (both in a
        // task holding a refusal slot, bounded too; without one, closed at once).
        let Ok(refusal) = Arc::clone(&refusal_slots).try_acquire_owned() else {
            continue;
        };
        let evicted = registry.evict_one(peer.ip());
        let (slots, registry, router) = (Arc::clone(&slots), Arc::clone(&registry), router.clone());
        connections.spawn(async move {
            let freed = match evicted {
                true => tokio::time::timeout(EVICTION_WAIT, slots.acquire_owned())
                    .await
                    .ok()
                    .and_then(Result::ok),
                false => None,
            };
            match freed {
                Some(slot) => {
                    drop(refusal);
                    serve_connection(
                        stream,
                        peer,
                        router,
                        limits.header_timeout,
                        (slot, registry),
                    )
                    .await;
                }
                None => {
                    refuse(stream).await;
                    drop(refusal);
                }
            }
        });
    }
    connections.shutdown().await;
    Ok(())
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
/// [`MAX_HEAD_BYTES`]. Registered while served, so that a full server can evict it
/// while it is idle; it ends then.
async fn serve_connection(
    stream: tokio::net::TcpStream,
    peer: SocketAddr,
    router: Router,
    header_timeout: Duration,
    (slot, registry): (tokio::sync::OwnedSemaphorePermit, Arc<Registry>),
) {
    let activity = registry.add(peer.ip());
    let tracked = Arc::clone(&activity);
    let router = router.layer(axum::middleware::from_fn(
        move |mut request: Request, next: Next| {
            // The client's address, for a handler that records who asked.
            request
                .extensions_mut()
                .insert(axum::extract::ConnectInfo(peer));
            let busy = Busy::new(Arc::clone(&tracked));
            async move {
                let response = next.run(request).await;
                response.map(|body| axum::body::Body::new(TrackedBody { body, _busy: busy }))
            }
        },
    ));
    let served = hyper::server::conn::http1::Builder::new()
        .timer(TokioTimer::new())
        .header_read_timeout(header_timeout)
        .max_buf_size(MAX_HEAD_BYTES)
        .serve_connection(TokioIo::new(stream), TowerToHyperService::new(router));
    tokio::select! {
        served = served => if let Err(error) = served {
            tracing::debug!(%peer, %error, "HTTP connection ended");
        },
        () = activity.evict.notified() => tracing::debug!(%peer, "idle HTTP connection evicted"),
    }
    registry.remove(&activity);
    drop(slot);
}

/// The connections being served, for the eviction of an idle one when all slots are
/// taken.
#[derive(Debug, Default)]
struct Registry(std::sync::Mutex<Vec<Arc<Activity>>>);

/// What a connection is doing.
#[derive(Debug)]
struct Activity {
    peer: std::net::IpAddr,
    /// Requests in progress, their answers' bodies included (a live-update stream
    /// stays busy).
    busy: std::sync::atomic::AtomicUsize,
    /// When it last became idle: accepted, or its last answer ended.
    idle_since: std::sync::Mutex<tokio::time::Instant>,
    /// Chosen for eviction (not chosen again).
    evicted: std::sync::atomic::AtomicBool,
    /// Ends the connection.
    evict: tokio::sync::Notify,
}

impl Registry {
    fn add(&self, peer: std::net::IpAddr) -> Arc<Activity> {
        let activity = Arc::new(Activity {
            peer,
            busy: std::sync::atomic::AtomicUsize::new(0),
            idle_since: std::sync::Mutex::new(tokio::time::Instant::now()),
            evicted: std::sync::atomic::AtomicBool::new(false),
            evict: tokio::sync::Notify::new(),
        });
        crate::lock(&self.0).push(Arc::clone(&activity));
        activity
    }

    fn remove(&self, activity: &Arc<Activity>) {
        crate::lock(&self.0).retain(|other| !Arc::ptr_eq(other, activity));
    }

    /// Make room for a new connection from `newcomer`: evict the oldest idle
    /// connection of the other peer address holding the most connections (of any
    /// other address when that one has none idle; of `newcomer`'s own when it is the
    /// only address). An address that already holds more connections than any other
    /// evicts nothing: its new connection is refused, so one client cannot push the
    /// others out. Whether one was evicted.
    fn evict_one(&self, newcomer: std::net::IpAddr) -> bool {
        use std::sync::atomic::Ordering;
        let connections = crate::lock(&self.0);
        let held = |peer: std::net::IpAddr| connections.iter().filter(|c| c.peer == peer).count();
        let greediest_other = connections
            .iter()
            .map(|c| c.peer)
            .filter(|&peer| peer != newcomer)
            .max_by_key(|&peer| held(peer));
        let oldest_idle = |of: &dyn Fn(std::net::IpAddr) -> bool| {
            connections
                .iter()
                .filter(|c| {
                    c.busy.load(Ordering::Acquire) == 0 && !c.evicted.load(Ordering::Acquire)
                })
                .filter(|c| of(c.peer))
                .min_by_key(|c| *crate::lock(&c.idle_since))
        };
        let victim = match greediest_other {
            Some(greediest) if held(newcomer) > held(greediest) => None,
            Some(greediest) => oldest_idle(&|peer| peer == greediest)
                .or_else(|| oldest_idle(&|peer| peer != newcomer)),
            None => oldest_idle(&|peer| peer == newcomer),
        };
        match victim {
            Some(victim) => {
                victim.evicted.store(true, Ordering::Release);
                // A permit is stored if it is not waiting yet: the eviction is not lost.
                victim.evict.notify_one();
                true
            }
            None => false,
        }
    }
}

/// A request in progress on its connection (from its head to its answer's end).
#[derive(Debug)]
struct Busy(Arc<Activity>);

impl Busy {
    fn new(activity: Arc<Activity>) -> Self {
        activity
            .busy
            .fetch_add(1, std::sync::atomic::Ordering::AcqRel);
        Self(activity)
    }
}

impl Drop for Busy {
    fn drop(&mut self) {
        *crate::lock(&self.0.idle_since) = tokio::time::Instant::now();
        self.0
            .busy
            .fetch_sub(1, std::sync::atomic::Ordering::AcqRel);
    }
}

/// An answer's body that keeps its connection busy until it is sent or dropped.
struct TrackedBody {
    body: axum::body::Body,
    _busy: Busy,
}

impl http_body::Body for TrackedBody {
    type Data = axum::body::Bytes;
    type Error = axum::Error;

    fn poll_frame(
        mut self: std::pin::Pin<&mut Self>,
        context: &mut std::task::Context<'_>,
    ) -> std::task::Poll<Option<Result<http_body::Frame<Self::Data>, Self::Error>>> {
        std::pin::Pin::new(&mut self.body).poll_frame(context)
    }

    fn is_end_stream(&self) -> bool {
        self.body.is_end_stream()
    }

    fn size_hint(&self) -> http_body::SizeHint {
        self.body.size_hint()
    }
}

/// Whether `path` is `pattern`, whose segments `*` stand for any one non-empty segment.
fn path_matches(pattern: &str, path: &str) -> bool {
    let (mut pattern, mut path) = (pattern.split('/'), path.split('/'));
    loop {
        match (pattern.next(), path.next()) {
            (None, None) => return true,
            (Some("*"), Some(segment)) if !segment.is_empty() => {}
            (Some(want), Some(segment)) if want == segment => {}
            _ => return false,
        }
    }
}

/// Refuses what a read-only server does not take (any method but GET and HEAD: 405;
/// a request body: 413), then adds [`security_headers`] to the answer.
async fn read_only(
    axum::extract::State(post_paths): axum::extract::State<&'static [&'static str]>,
    request: Request,
    next: Next,
) -> Response {
    let path = request.uri().path();
    let postable = post_paths.iter().any(|pattern| path_matches(pattern, path));
    let mut response = if postable && request.method() == Method::POST {
        next.run(request).await
    } else if request.method() != Method::GET && request.method() != Method::HEAD {
        let mut refused = error(
            StatusCode::METHOD_NOT_ALLOWED,
            "read-only: only GET and HEAD are allowed",
        );
        let allow = if postable {
            "GET, HEAD, POST"
        } else {
            "GET, HEAD"
        };
        refused
            .headers_mut()
            .insert(header::ALLOW, HeaderValue::from_static(allow));
        refused
    } else if has_body(&request) {
        error(StatusCode::PAYLOAD_TOO_LARGE, "a request here has no body")
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
pub(crate) fn security_headers(headers: &mut axum::http::HeaderMap) {
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
