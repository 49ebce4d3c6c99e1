//! The JSON API: live figures from the board's snapshot, history from the file.
//!
//! Every error is `{"error": "..."}` with its status: 400 for a bad parameter (naming
//! it and its allowed range), 404 for an unknown driveline or without a history, 503
//! when the history cannot be read in time.
//!
//! `live`: the live figures (overview, drivelines) and their server-sent events;
//! `history`: bites, the wear series and alarms from the file; `maps`: the gap
//! maps' curves. This file holds the request plumbing they share.

mod history;
mod live;
mod maps;

pub(crate) use history::{alarms, bites, wear};
pub(crate) use live::{driveline, drivelines, events, live_json, overview};
pub use live::{
    figures_json, DrivelineView, Overview, RodMillView, SourceView, TandemMillView, ThresholdsView,
};
pub(crate) use maps::gap_maps;
pub use maps::{CouplingCurves, EstimateCurves, GapMapView, MapCurve};

use std::collections::BTreeSet;
use std::ops::RangeInclusive;
use std::time::Duration;

use axum::extract::rejection::QueryRejection;
use axum::extract::Query;
use axum::http::StatusCode;

use super::shared::WebState;
use crate::outputs::history::query::HistoryReader;
use crate::outputs::history::HistoryError;
use crate::state::time::UtcTime;
/// Default and largest `limit` of `/api/drivelines/{name}/bites` and `/api/alarms`.
pub const LIMIT_DEFAULT: u32 = 100;
/// Largest `limit`.
pub const LIMIT_MAX: u32 = 10_000;
/// Default `points` of `/api/drivelines/{name}/wear`.
pub const POINTS_DEFAULT: u32 = 300;
/// Outages counted on the overview: those that started in this window.
pub const OUTAGE_WINDOW: Duration = Duration::from_secs(24 * 3600);

/// A refused request: its status and a sentence saying why.
#[derive(Debug)]
pub struct ApiError {
    /// 400, 404, 500 or 503.
    pub status: StatusCode,
    /// What was wrong, naming the parameter and its allowed range.
    pub message: String,
}

impl ApiError {
    fn bad(message: String) -> Self {
        Self {
            status: StatusCode::BAD_REQUEST,
            message,
        }
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

/// Run `work` on a reader of the history file on the blocking pool, within the
/// request timeout. 404 without a history, 503 when the file cannot be read or the
/// query takes too long (it then finishes on its own; its result is dropped).
async fn with_history<T: Send + 'static>(
    state: &WebState,
    work: impl FnOnce(&HistoryReader) -> Result<T, ApiError> + Send + 'static,
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
    let query = tokio::task::spawn_blocking(move || {
        let reader = HistoryReader::open(&path).map_err(|error| ApiError {
            status: StatusCode::SERVICE_UNAVAILABLE,
            message: error.to_string(),
        })?;
        work(&reader)
    });
    match tokio::time::timeout(state.request_timeout, query).await {
        Ok(Ok(answer)) => answer,
        Ok(Err(_)) => Err(unavailable("the history query failed".into())),
        Err(_) => Err(unavailable(format!(
            "the history query took longer than {} ms (outputs.web.request_timeout_ms)",
            state.request_timeout.as_millis()
        ))),
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
