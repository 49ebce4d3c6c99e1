//! What the page reads from the history file: a driveline's bites and wear series,
//! the alarm events, and the captures (a driveline's list, one capture's samples).

use std::sync::Arc;

use axum::extract::rejection::{PathRejection, QueryRejection};
use axum::extract::{Path, Query, State};
use axum::http::{header, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::Json;
use millgate_sim::discrepancy::calibration::aligned_response;
use millgate_sim::discrepancy::Measured;

use super::{
    driveline_index, history_error, with_history, with_history_streamed, ApiError, BodyWriter,
    DrivelineName, Params, LIMIT_DEFAULT, LIMIT_MAX, POINTS_DEFAULT,
};
use crate::history::capture_files::{self, CaptureHeader, ExportFormat};
use crate::history::captures::Capture;
use crate::history::fatigue_series::FatigueSeries;
use crate::history::query::{AlarmRow, BiteRow, CaptureRow, Filter, Record};
use crate::history::series::{WearPoint, MAX_SERIES_POINTS};
use crate::history::summary::ProductSummary;
use crate::history::HistoryError;
use crate::outputs::web::shared::WebState;

/// `GET /api/drivelines/{name}/bites?since=&until=&limit=&product=&coil=`: the newest
/// `limit` bites in the range (of product code `product`, of coil `coil`, when
/// given), oldest first.
pub(crate) async fn bites(
    State(state): State<Arc<WebState>>,
    DrivelineName(name): DrivelineName,
    query: Result<Query<Vec<(String, String)>>, QueryRejection>,
) -> Result<Json<Vec<BiteRow>>, ApiError> {
    let params = Params::of(query, &["since", "until", "limit", "product", "coil"])?;
    driveline_index(&state, &name)?;
    Ok(Json(newest(&state, &params, Some(name)).await?))
}

/// `GET /api/drivelines/{name}/captures?since=&until=&limit=&product=&coil=`: the newest
/// `limit` captures of the driveline in the range (of product code `product` when
/// given; their rows with the context of their time, not their samples), oldest
/// first.
pub(crate) async fn captures(
    State(state): State<Arc<WebState>>,
    DrivelineName(name): DrivelineName,
    query: Result<Query<Vec<(String, String)>>, QueryRejection>,
) -> Result<Json<Vec<serde_json::Value>>, ApiError> {
    let params = Params::of(query, &["since", "until", "limit", "product", "coil"])?;
    driveline_index(&state, &name)?;
    let rows: Vec<CaptureRow> = newest(&state, &params, Some(name)).await?;
    Ok(Json(
        rows.iter()
            .map(crate::history::captures::row_json)
            .collect(),
    ))
}

/// `GET /api/captures/{id}`: one capture with its samples: the row, and per channel
/// its name, unit and samples (`t` of sample k is k / `sample_rate_hz` s after
/// `first_sample_unix_ns`), and a driveline's extra channel's own `timing` (null for
/// the torque; its rows without a sample are null). 404 for an id the file does not
/// hold. Written as it is sent, in the query slot (a manual capture of 40 stands for
/// 255 s is 25 M samples: built whole, its JSON took about 40 bytes a sample).
pub(crate) async fn capture(
    State(state): State<Arc<WebState>>,
    id: Result<Path<i64>, PathRejection>,
) -> Result<Response, ApiError> {
    // A bad id gets the API's JSON error, not axum's plain-text one.
    let id = capture_id(id)?;
    let ((), body) = with_history_streamed(&state, move |reader| {
        let capture = read_capture(reader, id)?;
        let write: BodyWriter = Box::new(move |out| {
            serde_json::to_writer(out, &CaptureJson::of(&capture)).map_err(std::io::Error::from)
        });
        Ok(((), write))
    })
    .await?;
    Ok((
        [(
            header::CONTENT_TYPE,
            HeaderValue::from_static("application/json"),
        )],
        body,
    )
        .into_response())
}

/// A capture as `GET /api/captures/{id}` answers it: its row's keys and `channels`.
#[derive(serde::Serialize)]
struct CaptureJson<'a> {
    #[serde(flatten)]
    row: serde_json::Value,
    channels: Vec<ChannelJson<'a>>,
}

/// A channel of [`CaptureJson`].
#[derive(serde::Serialize)]
struct ChannelJson<'a> {
    name: &'a str,
    unit: &'a str,
    samples: &'a [f64],
    timing: &'a Option<crate::state::captures::ChannelTiming>,
}

impl<'a> CaptureJson<'a> {
    fn of(capture: &'a Capture) -> Self {
        Self {
            row: crate::history::captures::row_json(&capture.row),
            channels: capture
                .channels
                .iter()
                .map(|channel| ChannelJson {
                    name: &channel.name,
                    unit: &channel.unit,
                    samples: &channel.samples,
                    timing: &channel.timing,
                })
                .collect(),
        }
    }
}

/// The `{id}` of a capture's route; a bad one gets the API's JSON error, not axum's
/// plain-text one.
pub(super) fn capture_id(id: Result<Path<i64>, PathRejection>) -> Result<i64, ApiError> {
    let Path(id) =
        id.map_err(|rejection| ApiError::bad(format!("capture id: {}", rejection.body_text())))?;
    Ok(id)
}

/// Capture `id` of the file; 404 when the file does not hold it, 500 when its stored
/// samples are damaged (no use trying again).
pub(super) fn read_capture(
    reader: &crate::history::query::HistoryReader,
    id: i64,
) -> Result<Capture, ApiError> {
    reader
        .capture(id)
        .map_err(|error| match error {
            HistoryError::Capture { .. } => ApiError {
                status: StatusCode::INTERNAL_SERVER_ERROR,
                message: error.to_string(),
            },
            error => history_error(error),
        })?
        .ok_or_else(|| ApiError {
            status: StatusCode::NOT_FOUND,
            message: format!("no capture {id} in the history"),
        })
}

/// `GET /api/captures/{id}/file?format=csv|parquet|json`: the capture as the file
/// `millgate capture export --id {id} --format ...` writes (the same writer, byte for
/// byte), as a download named as the export names it; `json` is the header the export
/// writes beside its CSV (`<name>.json`). Written as it is sent, in the query slot:
/// the memory it takes is the capture's samples, not its file.
pub(crate) async fn capture_file(
    State(state): State<Arc<WebState>>,
    id: Result<Path<i64>, PathRejection>,
    query: Result<Query<Vec<(String, String)>>, QueryRejection>,
) -> Result<Response, ApiError> {
    let id = capture_id(id)?;
    let params = Params::of(query, &["format"])?;
    // The CSV's header file is `format=json`: the CSV's name with `.json`.
    let (format, header_only) = match params.get("format") {
        Some("csv") | None => (ExportFormat::Csv, false),
        Some("parquet") => (ExportFormat::Parquet, false),
        Some("json") => (ExportFormat::Csv, true),
        Some(other) => {
            return Err(ApiError::bad(format!(
                "format `{other}`: expected csv, parquet or json"
            )))
        }
    };
    let (name, body) = with_history_streamed(&state, move |reader| {
        let capture = read_capture(reader, id)?;
        let run = capture_files::run_config(reader, capture.row.run_id).map_err(history_error)?;
        let header = CaptureHeader::of(&capture, run);
        capture_files::check_writable(&capture, format).map_err(|error| ApiError {
            status: StatusCode::INTERNAL_SERVER_ERROR,
            message: format!("capture {id}: {error}"),
        })?;
        let name = capture_files::file_name(&capture, format);
        if header_only {
            let name = capture_files::sidecar_path(std::path::Path::new(&name));
            let write: BodyWriter = Box::new(move |out| {
                capture_files::write_sidecar(&header, out).map_err(std::io::Error::other)
            });
            return Ok((name.display().to_string(), write));
        }
        let write: BodyWriter = Box::new(move |out| {
            capture_files::write(&capture, &header, format, out).map_err(std::io::Error::other)
        });
        Ok((name, write))
    })
    .await?;
    let content_type = match format {
        _ if header_only => "application/json",
        ExportFormat::Csv => "text/csv; charset=utf-8",
        ExportFormat::Parquet => "application/vnd.apache.parquet",
    };
    // The name holds ASCII letters, digits, `-`, `_` and `.` only (`file_name`).
    let disposition = HeaderValue::from_str(&format!("attachment; filename=\"{name}\""))
        .map_err(|_| ApiError::bad(format!("capture {id}: no file name")))?;
    Ok((
        [
            (header::CONTENT_TYPE, HeaderValue::from_static(content_type)),
            (header::CONTENT_DISPOSITION, disposition),
        ],
        body,
    )
        .into_response())
}

/// `GET /api/captures/{id}/response`: the driveline model's simulated response to a
/// bite's capture, beside its measured torque (the capture's first channel, as
/// `millgate discrepancy` takes it): the model as configured (`drivelines[].model`),
/// its onset and static torque aligned to the record as the discrepancy workflow's
/// calibration starts
/// ([`millgate_sim::discrepancy::calibration::aligned_response`]),
/// and the residual left (RMS). 404 for an unknown id, 409 for a capture that is no
/// bite of a driveline with a model, or whose record is no load step.
pub(crate) async fn capture_response(
    State(state): State<Arc<WebState>>,
    id: Result<Path<i64>, PathRejection>,
) -> Result<Json<serde_json::Value>, ApiError> {
    let id = capture_id(id)?;
    let web = Arc::clone(&state);
    with_history(&state, move |reader| {
        let capture = read_capture(reader, id)?;
        let conflict = |why: String| ApiError {
            status: StatusCode::CONFLICT,
            message: format!("capture {id}: {why}"),
        };
        let row = &capture.row;
        if row.kind != "bite" {
            return Err(conflict(format!("a {} capture, not a bite's", row.kind)));
        }
        let model = web
            .drivelines
            .iter()
            .find(|d| d.name == row.subject)
            .and_then(|d| d.model.as_deref())
            .ok_or_else(|| conflict(format!("{} has no driveline model", row.subject)))?;
        let torque = capture
            .channels
            .first()
            .ok_or_else(|| conflict("no channel".to_owned()))?;
        let measured = Measured {
            t0_s: 0.0,
            sample_rate_hz: row.sample_rate_hz,
            torque_knm: &torque.samples,
        };
        let response = aligned_response(model, &measured)
            .map_err(|error| conflict(format!("the model cannot simulate this bite: {error}")))?
            .ok_or_else(|| conflict("the record is no load step".to_owned()))?;
        Ok(serde_json::json!({
            "capture_id": id,
            "driveline": row.subject,
            "bite_counter": row.bite_counter,
            "channel": torque.name,
            "unit": torque.unit,
            "sample_rate_hz": row.sample_rate_hz,
            "measured": torque.samples,
            "response": response,
        }))
    })
    .await
    .map(Json)
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

/// `GET /api/drivelines/{name}/fatigue/history?since=&until=&points=`: each fatigue
/// component's life used in at most `points` time buckets (default
/// [`FATIGUE_POINTS_DEFAULT`]), the resets in the range and the configured life limit
/// (null without `drivelines[].fatigue`); a history without a ledger of the driveline
/// gives no components.
pub(crate) async fn fatigue_history(
    State(state): State<Arc<WebState>>,
    DrivelineName(name): DrivelineName,
    query: Result<Query<Vec<(String, String)>>, QueryRejection>,
) -> Result<Json<FatigueHistoryJson>, ApiError> {
    let params = Params::of(query, &["since", "until", "points"])?;
    let index = driveline_index(&state, &name)?;
    let (since, until) = params.range()?;
    let max = u32::try_from(MAX_SERIES_POINTS).unwrap_or(u32::MAX);
    let points = params.count("points", 1..=max, FATIGUE_POINTS_DEFAULT)?;
    let series = with_history(&state, move |reader| {
        match reader.fatigue_series(&name, since, until, points as usize) {
            Ok(series) => Ok(series),
            Err(HistoryError::UnknownDriveline { .. }) => Ok(FatigueSeries::default()),
            Err(error) => Err(history_error(error)),
        }
    })
    .await?;
    Ok(Json(FatigueHistoryJson {
        life_limit: state.drivelines[index].fatigue_life_limit,
        series,
    }))
}

/// Default `points` of `/api/drivelines/{name}/fatigue/history`.
pub(crate) const FATIGUE_POINTS_DEFAULT: u32 = 300;

/// What `GET /api/drivelines/{name}/fatigue/history` answers: the series' keys
/// (`components`, `points`, `resets`) and `life_limit`.
#[derive(serde::Serialize)]
pub(crate) struct FatigueHistoryJson {
    #[serde(flatten)]
    series: FatigueSeries,
    life_limit: Option<f64>,
}

/// `GET /api/drivelines/{name}/products?since=&until=`: the driveline's bites in the
/// range by the product they were rolled in (count, not pooled, TAF mean and max,
/// static torque and gap means), the products with the most bites first.
pub(crate) async fn products(
    State(state): State<Arc<WebState>>,
    DrivelineName(name): DrivelineName,
    query: Result<Query<Vec<(String, String)>>, QueryRejection>,
) -> Result<Json<Vec<ProductSummary>>, ApiError> {
    let params = Params::of(query, &["since", "until"])?;
    driveline_index(&state, &name)?;
    let (since, until) = params.range()?;
    let products = with_history(&state, move |reader| {
        reader
            .product_summaries(&name, since, until)
            .map_err(history_error)
    })
    .await?;
    Ok(Json(products))
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
pub(super) async fn newest<R: Record + Send + 'static>(
    state: &WebState,
    params: &Params,
    name: Option<String>,
) -> Result<Vec<R>, ApiError> {
    let (since, until) = params.range()?;
    let limit = params.count("limit", 1..=LIMIT_MAX, LIMIT_DEFAULT)?;
    let product = params
        .get("product")
        .map(|_| params.count("product", 0..=u32::MAX, 0))
        .transpose()?;
    let coil = params.coil()?;
    let filter = Filter {
        name,
        since,
        until,
        after_id: None,
        limit: Some(limit),
        product,
        coil,
    };
    with_history(state, move |reader| {
        reader.newest(&filter).map_err(history_error)
    })
    .await
}
