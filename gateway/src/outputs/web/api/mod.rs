//! The JSON API: live figures from the board's snapshot, history from the file.
//!
//! Every error is `{"error": "..."}` with its status: 400 for a bad parameter (naming
//! it and its allowed range), 404 for an unknown driveline or without a history, 503
//! with `Retry-After` when the history cannot be read in time, its query slots are
//! busy or the live-update streams are all taken.
//!
//! `live.rs`: the live figures (overview, drivelines) and their server-sent events;
//! `history.rs`: bites, the wear series and alarms from the file; `episodes.rs`: a
//! tandem mill's captures and their band signals and spectra; `commands.rs`: the
//! manual-capture request (POST); `maps.rs`: the gap
//! maps' curves. This file holds the request plumbing they share.

mod commands;
mod episodes;
mod history;
mod live;
mod maps;

pub(crate) use commands::{request_capture, reset_fatigue};
pub(crate) use episodes::{capture_bands, tandem_mill_captures, tandem_mill_episodes};
pub(crate) use history::{
    alarms, bites, capture, capture_file, capture_response, captures, fatigue_history, products,
    wear,
};
pub(crate) use live::{driveline, drivelines, events, live_json, overview};
pub(crate) use maps::gap_maps;

use std::collections::BTreeSet;
use std::ops::RangeInclusive;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use axum::extract::rejection::QueryRejection;
use axum::extract::{FromRequestParts, Path, Query};
use axum::http::request::Parts;
use axum::http::StatusCode;
use millgate_config::text::MAX_TEXT_LEN;

use super::shared::WebState;
use crate::history::query::HistoryReader;
use crate::history::HistoryError;
use crate::state::time::UtcTime;

/// Default and largest `limit` of `/api/drivelines/{name}/bites` and `/api/alarms`.
pub(crate) const LIMIT_DEFAULT: u32 = 100;
/// Largest `limit`.
pub(crate) const LIMIT_MAX: u32 = 10_000;
/// Default `points` of `/api/drivelines/{name}/wear`.
pub(crate) const POINTS_DEFAULT: u32 = 300;
/// Outages counted on the overview: those that started in this window.
pub(crate) const OUTAGE_WINDOW: Duration = Duration::from_secs(24 * 3600);

/// A refused request: its status and a sentence saying why.
#[derive(Debug)]
pub(crate) struct ApiError {
    /// 400, 404, 500 or 503.
    pub status: StatusCode,
    /// What was wrong, naming the parameter and its allowed range.
    pub message: String,
}

impl ApiError {
    pub(super) fn bad(message: String) -> Self {
        Self {
            status: StatusCode::BAD_REQUEST,
            message,
        }
    }
}

/// The `{name}` of a driveline's route; a name that is not UTF-8 once decoded
/// (`%ff%fe`) is refused with the API's JSON error, not axum's plain-text one.
#[derive(Debug)]
pub(crate) struct DrivelineName(pub(crate) String);

impl<S: Send + Sync> FromRequestParts<S> for DrivelineName {
    type Rejection = ApiError;

    async fn from_request_parts(parts: &mut Parts, state: &S) -> Result<Self, ApiError> {
        Path::<String>::from_request_parts(parts, state)
            .await
            .map(|Path(name)| Self(name))
            .map_err(|rejection| {
                ApiError::bad(format!("driveline name: {}", rejection.body_text()))
            })
    }
}

/// The query parameters of a request, checked against what its route takes.
#[derive(Debug)]
struct Params(Vec<(String, String)>);

impl Params {
    /// The parameters, refusing names `allowed` does not list and repeated names.
    fn of(
        query: Result<Query<Vec<(String, String)>>, QueryRejection>,
        allowed: &[&str],
    ) -> Result<Self, ApiError> {
        let Query(pairs) = query.map_err(|rejection| ApiError::bad(rejection.body_text()))?;
        let mut seen = BTreeSet::new();
        for (name, _) in &pairs {
            if !allowed.contains(&name.as_str()) {
                return Err(ApiError::bad(format!(
                    "unknown parameter \"{name}\" (allowed: {})",
                    allowed.join(", ")
                )));
            }
            if !seen.insert(name.as_str()) {
                return Err(ApiError::bad(format!("parameter {name} given twice")));
            }
        }
        Ok(Self(pairs))
    }

    fn get(&self, name: &str) -> Option<&str> {
        self.0
            .iter()
            .find(|(key, _)| key == name)
            .map(|(_, value)| value.as_str())
    }

    /// An RFC 3339 / ISO-8601 UTC time (or Unix seconds).
    fn time(&self, name: &str) -> Result<Option<UtcTime>, ApiError> {
        self.get(name)
            .map(|text| {
                UtcTime::parse(text).map_err(|error| ApiError::bad(format!("{name}: {error}")))
            })
            .transpose()
    }

    /// `since` and `until`, `since` before `until`.
    /// `coil`: a coil or bar id as the context gives it, 1 to [`MAX_TEXT_LEN`] printable
    /// ASCII characters (a numeric coil's digits, or a text coil's characters).
    fn coil(&self) -> Result<Option<String>, ApiError> {
        let Some(coil) = self.get("coil") else {
            return Ok(None);
        };
        if coil.is_empty()
            || coil.len() > MAX_TEXT_LEN
            || !coil.bytes().all(|b| (0x20..=0x7E).contains(&b))
        {
            return Err(ApiError::bad(format!(
                "coil must be 1..={MAX_TEXT_LEN} printable ASCII characters (a coil or bar id \
                 as the PLC gives it), not {coil:?}"
            )));
        }
        Ok(Some(coil.to_owned()))
    }

    fn range(&self) -> Result<(Option<UtcTime>, Option<UtcTime>), ApiError> {
        let (since, until) = (self.time("since")?, self.time("until")?);
        if let (Some(since), Some(until)) = (since, until) {
            if since >= until {
                return Err(ApiError::bad(format!(
                    "since ({since}) must be before until ({until})"
                )));
            }
        }
        Ok((since, until))
    }

    /// A count in `range`, `default` when absent.
    fn count(&self, name: &str, range: RangeInclusive<u32>, default: u32) -> Result<u32, ApiError> {
        let Some(text) = self.get(name) else {
            return Ok(default);
        };
        match text.parse::<u32>() {
            Ok(value) if range.contains(&value) => Ok(value),
            _ => Err(ApiError::bad(format!(
                "{name}: \"{text}\" is not allowed (must be an integer in {}..={})",
                range.start(),
                range.end()
            ))),
        }
    }
}

/// How long a history request waits for a free query slot
/// (`outputs.web.history_queries`) before it is answered 503.
pub(crate) const SLOT_WAIT: Duration = Duration::from_secs(1);

/// Run `work` on a reader of the history file, in one of the page's query slots,
/// within the request timeout. The query runs on one of the page's query threads
/// ([`QueryThreads`](super::shared::QueryThreads): as many as slots, at the lowest
/// CPU priority, not tokio's blocking pool) and is interrupted by SQLite when its
/// deadline passes or its request is dropped (the client went away); the slot is
/// free again only once the query has ended, so the slots bound the work, not only
/// the requests. 404 without a history; 503 (with `Retry-After`) when no slot frees
/// within [`SLOT_WAIT`], the file cannot be read or the query takes too long.
async fn with_history<T: Send + 'static>(
    state: &WebState,
    work: impl FnOnce(&HistoryReader) -> Result<T, ApiError> + Send + 'static,
) -> Result<T, ApiError> {
    with_history_then(
        state,
        move |reader| work(reader).map(|answer| (answer, ())),
        drop,
    )
    .await
}

/// An answer's body written on the query thread after its head was answered.
type BodyWriter = Box<dyn FnOnce(&mut (dyn std::io::Write + Send)) -> std::io::Result<()> + Send>;

/// Bytes of a streamed answer sent at a time.
const STREAM_CHUNK: usize = 64 * 1024;
/// Chunks of a streamed answer waiting for the client at most: with
/// [`STREAM_CHUNK`], what a slow client costs the gateway.
const STREAM_QUEUE: usize = 4;

/// [`with_history`] for an answer too large to build in memory: `work` gives the
/// head (the answer's own figures) and a writer of the body, which then runs on the
/// same query thread, in the same slot, sending the body in [`STREAM_CHUNK`]s as the
/// client takes them (at most [`STREAM_QUEUE`] waiting). A client that takes no chunk
/// within the request timeout, or goes away, ends the writing and frees the slot; an
/// error while writing cuts the answer short (the client sees it incomplete).
async fn with_history_streamed<T: Send + 'static>(
    state: &WebState,
    work: impl FnOnce(&HistoryReader) -> Result<(T, BodyWriter), ApiError> + Send + 'static,
) -> Result<(T, axum::body::Body), ApiError> {
    let (chunks, body) = tokio::sync::mpsc::channel(STREAM_QUEUE);
    let sink = ChunkSink {
        chunks,
        pending: Vec::with_capacity(STREAM_CHUNK),
        runtime: tokio::runtime::Handle::current(),
        patience: state.request_timeout,
    };
    let head = with_history_then(state, work, move |write: BodyWriter| {
        let mut sink = sink;
        let written = write(&mut sink).and_then(|()| sink.flush_pending());
        if let Err(error) = written {
            // The client sees the answer end early; it may have gone already.
            let _ = sink.send(Err(error));
        }
    })
    .await?;
    let body = axum::body::Body::from_stream(tokio_stream::wrappers::ReceiverStream::new(body));
    Ok((head, body))
}

/// Where a streamed answer's body is written, on a query thread: chunks to the
/// response's stream.
struct ChunkSink {
    chunks: tokio::sync::mpsc::Sender<std::io::Result<axum::body::Bytes>>,
    pending: Vec<u8>,
    runtime: tokio::runtime::Handle,
    /// How long a chunk waits for the client.
    patience: Duration,
}

impl ChunkSink {
    fn send(&self, chunk: std::io::Result<axum::body::Bytes>) -> std::io::Result<()> {
        // The timeout is made inside the runtime's context (its timer is there).
        let sent = self
            .runtime
            .block_on(async { tokio::time::timeout(self.patience, self.chunks.send(chunk)).await });
        match sent {
            Ok(Ok(())) => Ok(()),
            Ok(Err(_)) => Err(std::io::Error::new(
                std::io::ErrorKind::BrokenPipe,
                "the client went away",
            )),
            Err(_) => Err(std::io::Error::new(
                std::io::ErrorKind::TimedOut,
                "the client took nothing within the request timeout",
            )),
        }
    }

    fn flush_pending(&mut self) -> std::io::Result<()> {
        if self.pending.is_empty() {
            return Ok(());
        }
        let chunk = std::mem::replace(&mut self.pending, Vec::with_capacity(STREAM_CHUNK));
        self.send(Ok(chunk.into()))
    }
}

impl std::io::Write for ChunkSink {
    fn write(&mut self, bytes: &[u8]) -> std::io::Result<usize> {
        let room = STREAM_CHUNK - self.pending.len();
        let taken = bytes.len().min(room);
        self.pending.extend_from_slice(&bytes[..taken]);
        if self.pending.len() == STREAM_CHUNK {
            self.flush_pending()?;
        }
        Ok(taken)
    }

    fn flush(&mut self) -> std::io::Result<()> {
        // Chunks go when full or at the end: a flush of a writer inside (a CSV
        // writer's buffer) must not send small chunks.
        Ok(())
    }
}

/// [`with_history`] whose `work` gives the answer and something `then` does with it on
/// the query thread, in the slot, once the answer was handed over.
async fn with_history_then<T: Send + 'static, R: Send + 'static>(
    state: &WebState,
    work: impl FnOnce(&HistoryReader) -> Result<(T, R), ApiError> + Send + 'static,
    then: impl FnOnce(R) + Send + 'static,
) -> Result<T, ApiError> {
    let Some(path) = state.history.clone() else {
        return Err(ApiError {
            status: StatusCode::NOT_FOUND,
            message: "no history configured (add [history] to the configuration)".into(),
        });
    };
    let unavailable = |message: String| ApiError {
        status: StatusCode::SERVICE_UNAVAILABLE,
        message,
    };
    let Some(slot) = state.query_slots.acquire(SLOT_WAIT).await else {
        return Err(unavailable(format!(
            "every history query slot is busy (outputs.web.history_queries = {}): try again",
            state.query_slots.limit()
        )));
    };
    let deadline = Instant::now() + state.request_timeout;
    // Set when the request ends before its answer (timeout, client gone): the query's
    // progress handler then interrupts it.
    let cancel = Cancel(Arc::new(AtomicBool::new(false)));
    let stop = Arc::clone(&cancel.0);
    let (answer, answered) = tokio::sync::oneshot::channel();
    let job = Box::new(move || {
        let result = HistoryReader::open(&path)
            .map_err(history_error)
            .and_then(|mut reader| {
                reader.interrupt_when(move || {
                    stop.load(Ordering::Relaxed) || Instant::now() >= deadline
                });
                work(&reader)
            });
        match result {
            Ok((head, rest)) => {
                if answer.send(Ok(head)).is_ok() {
                    then(rest);
                }
            }
            Err(error) => {
                let _ = answer.send(Err(error));
            }
        }
        drop(slot);
    });
    if state.queries.run(job).is_err() {
        return Err(unavailable("the history query threads have ended".into()));
    }
    match tokio::time::timeout(state.request_timeout, answered).await {
        Ok(Ok(answer)) => answer,
        Ok(Err(_)) => Err(unavailable("the history query failed".into())),
        Err(_) => Err(unavailable(format!(
            "the history query took longer than {} ms (outputs.web.request_timeout_ms)",
            state.request_timeout.as_millis()
        ))),
    }
}

/// Interrupts a history query when dropped (its request ended, answered or not: an
/// answered query has finished already).
struct Cancel(Arc<AtomicBool>);

impl Drop for Cancel {
    fn drop(&mut self) {
        self.0.store(true, Ordering::Relaxed);
    }
}

fn history_error(error: HistoryError) -> ApiError {
    ApiError {
        status: StatusCode::SERVICE_UNAVAILABLE,
        message: error.to_string(),
    }
}

/// The driveline named `name`, or 404.
fn driveline_index(state: &WebState, name: &str) -> Result<usize, ApiError> {
    state
        .drivelines
        .iter()
        .position(|d| d.name == name)
        .ok_or_else(|| ApiError {
            status: StatusCode::NOT_FOUND,
            message: format!(
                "no driveline \"{name}\" (known: {})",
                state
                    .drivelines
                    .iter()
                    .map(|d| d.name.as_str())
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        })
}
