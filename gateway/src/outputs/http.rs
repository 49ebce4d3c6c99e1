//! The gateway's one HTTP stack, shared by the maintenance page and `/metrics`:
//! read-only HTTP/1.1 on hyper and axum, served by a bounded accept loop.
//!
//! - GET and HEAD only (405 otherwise), no request body (413), the head within
//!   16 KiB (431) and within the listener's header timeout (the connection
//!   is closed: a slow client cannot hold it).
//! - At most `max_connections` connections; a further one is answered 503 and closed
//!   (a bounded number of such answers at once, the rest closed unanswered).
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

/// How often a full server is logged at most.
const WARN_PERIOD: Duration = Duration::from_secs(60);

/// A listener's bounds.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Limits {
    /// Connections served at once.
    pub(crate) max_connections: usize,
    /// Time a client has to send a request head.
    pub(crate) header_timeout: Duration,
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
    let router = router.layer(axum::middleware::from_fn(read_only));
    let local = listener.local_addr()?;
    tracing::info!(%local, max_connections = limits.max_connections, "{name} listening");
    let slots = Arc::new(Semaphore::new(limits.max_connections));
    let refusal_slots = Arc::new(Semaphore::new(REFUSALS));
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
                tracing::warn!(%peer, max = limits.max_connections, suppressed, "{name} full, connection refused");
            }
            continue;
        };
        connections.spawn(serve_connection(
            stream,
            peer,
            router.clone(),
            limits.header_timeout,
            slot,
        ));
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
        tracing::debug!(%peer, %error, "HTTP connection ended");
    }
    drop(slot);
}

/// Refuses what a read-only server does not take (any method but GET and HEAD: 405;
/// a request body: 413), then adds [`security_headers`] to the answer.
async fn read_only(request: Request, next: Next) -> Response {
    let mut response = if request.method() != Method::GET && request.method() != Method::HEAD {
        let mut refused = error(
            StatusCode::METHOD_NOT_ALLOWED,
            "read-only: only GET and HEAD are allowed",
        );
        refused
            .headers_mut()
            .insert(header::ALLOW, HeaderValue::from_static("GET, HEAD"));
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
