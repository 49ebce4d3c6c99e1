//! What the page reads from the history file: a driveline's bites and wear series,
//! the alarm events, and the captures (a driveline's list, one capture's samples).

use std::sync::Arc;

use axum::extract::rejection::{PathRejection, QueryRejection};
use axum::extract::{Path, Query, State};
use axum::Json;

use super::{
    driveline_index, history_error, with_history, ApiError, DrivelineName, Params, LIMIT_DEFAULT,
    LIMIT_MAX, POINTS_DEFAULT,
};
use crate::outputs::history::query::{AlarmRow, BiteRow, CaptureRow, Filter, Record};
use crate::outputs::history::series::{WearPoint, MAX_SERIES_POINTS};
use crate::outputs::history::HistoryError;
use crate::outputs::web::shared::WebState;

/// `GET /api/drivelines/{name}/bites?since=&until=&limit=`: the newest `limit` bites
/// in the range, oldest first.
pub(crate) async fn bites(
    State(state): State<Arc<WebState>>,
    DrivelineName(name): DrivelineName,
    query: Result<Query<Vec<(String, String)>>, QueryRejection>,
) -> Result<Json<Vec<BiteRow>>, ApiError> {
    let params = Params::of(query, &["since", "until", "limit"])?;
    driveline_index(&state, &name)?;
    Ok(Json(newest(&state, &params, Some(name)).await?))
}

/// `GET /api/drivelines/{name}/captures?since=&until=&limit=`: the newest `limit`
/// captures of the driveline in the range (their rows, not their samples), oldest
/// first.
pub(crate) async fn captures(
    State(state): State<Arc<WebState>>,
    DrivelineName(name): DrivelineName,
    query: Result<Query<Vec<(String, String)>>, QueryRejection>,
) -> Result<Json<Vec<serde_json::Value>>, ApiError> {
    let params = Params::of(query, &["since", "until", "limit"])?;
    driveline_index(&state, &name)?;
    let rows: Vec<CaptureRow> = newest(&state, &params, Some(name)).await?;
    Ok(Json(
        rows.iter()
            .map(crate::outputs::history::captures::row_json)
            .collect(),
    ))
}

/// `GET /api/captures/{id}`: one capture with its samples: the row, and per channel
/// its name, unit and samples (`t` of sample k is k / `sample_rate_hz` s after
/// `first_sample_unix_ns`). 404 for an id the file does not hold.
pub(crate) async fn capture(
    State(state): State<Arc<WebState>>,
    id: Result<Path<i64>, PathRejection>,
) -> Result<Json<serde_json::Value>, ApiError> {
    // A bad id gets the API's JSON error, not axum's plain-text one.
    let Path(id) =
        id.map_err(|rejection| ApiError::bad(format!("capture id: {}", rejection.body_text())))?;
    let capture = with_history(&state, move |reader| {
        reader.capture(id).map_err(history_error)
    })
    .await?
    .ok_or_else(|| ApiError {
        status: axum::http::StatusCode::NOT_FOUND,
        message: format!("no capture {id} in the history"),
    })?;
    let mut value = crate::outputs::history::captures::row_json(&capture.row);
    value["channels"] = capture
        .channels
        .iter()
        .map(|channel| {
            serde_json::json!({
                "name": channel.name,
                "unit": channel.unit,
                "samples": channel.samples,
            })
        })
        .collect();
    Ok(Json(value))
}

/// `GET /api/drivelines/{name}/wear?since=&until=&points=`: the gap estimate (last
/// in each bucket, interval extremes) and TAF (mean, max) in at most `points` time
/// buckets, oldest first; buckets without bites are left out.
pub(crate) async fn wear(
    State(state): State<Arc<WebState>>,
    DrivelineName(name): DrivelineName,
    query: Result<Query<Vec<(String, String)>>, QueryRejection>,
) -> Result<Json<Vec<WearPoint>>, ApiError> {
    let params = Params::of(query, &["since", "until", "points"])?;
    driveline_index(&state, &name)?;
    let (since, until) = params.range()?;
    let max = u32::try_from(MAX_SERIES_POINTS).unwrap_or(u32::MAX);
    let points = params.count("points", 1..=max, POINTS_DEFAULT)?;
    let series = with_history(&state, move |reader| {
        match reader.wear_series(&name, since, until, points as usize) {
            Ok(series) => Ok(series),
            Err(HistoryError::UnknownDriveline { .. }) => Ok(Vec::new()),
            Err(error) => Err(history_error(error)),
        }
    })
    .await?;
    Ok(Json(series))
}

/// `GET /api/alarms?since=&until=&limit=&subject=`: the newest `limit` alarm events
/// in the range, oldest first.
pub(crate) async fn alarms(
    State(state): State<Arc<WebState>>,
    query: Result<Query<Vec<(String, String)>>, QueryRejection>,
) -> Result<Json<Vec<AlarmRow>>, ApiError> {
    let params = Params::of(query, &["since", "until", "limit", "subject"])?;
    let subject = params.get("subject").map(str::to_owned);
    Ok(Json(newest(&state, &params, subject).await?))
}

/// The newest `limit` rows of `name` (all names when `None`) in the parameters'
/// `since`..`until`, oldest first: what `bites` and `alarms` answer.
async fn newest<R: Record + Send + 'static>(
    state: &WebState,
    params: &Params,
    name: Option<String>,
) -> Result<Vec<R>, ApiError> {
    let (since, until) = params.range()?;
    let limit = params.count("limit", 1..=LIMIT_MAX, LIMIT_DEFAULT)?;
    let filter = Filter {
        name,
        since,
        until,
        after_id: None,
        limit: Some(limit),
    };
    with_history(state, move |reader| {
        reader.newest(&filter).map_err(history_error)
    })
    .await
}
