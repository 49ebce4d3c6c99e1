//! The JSON API: live figures from the board's snapshot, history from the file.
//!
//! Every error is `{"error": "..."}` with its status: 400 for a bad parameter (naming
//! it and its allowed range), 404 for an unknown driveline or without a history, 503
//! when the history cannot be read in time.

use std::collections::BTreeSet;
use std::convert::Infallible;
use std::ops::RangeInclusive;
use std::sync::Arc;
use std::time::Duration;

use axum::extract::rejection::QueryRejection;
use axum::extract::{Path, Query, State};
use axum::http::{header, HeaderValue, StatusCode};
use axum::response::sse::{Event, KeepAlive, Sse};
use axum::response::{IntoResponse, Response};
use axum::Json;
use serde::Serialize;
use serde_json::{Map, Value as JsonValue};
use tokio_stream::wrappers::WatchStream;
use tokio_stream::{Stream, StreamExt};

use super::shared::{DrivelineInfo, TrendCache, WebState};
use crate::field::source_health::SourceStatus;
use crate::outputs::history::query::{AlarmRow, BiteRow, Filter, HistoryReader, OutageRow, Record};
use crate::outputs::history::series::{WearPoint, MAX_SERIES_POINTS};
use crate::outputs::history::HistoryError;
use crate::state::catalogue::{self, Figure, Subject, Value};
use crate::state::gap_maps::{GapMapState, GapMaps};
use crate::state::results::{
    DrivelineResults, GapResults, GatewayState, Results, RodMillResults, TandemMillResults,
};
use crate::state::time::UtcTime;

/// Default and largest `limit` of `/api/drivelines/{name}/bites` and `/api/alarms`.
pub const LIMIT_DEFAULT: u32 = 100;
/// Largest `limit`.
pub const LIMIT_MAX: u32 = 10_000;
/// Default `points` of `/api/drivelines/{name}/wear`.
pub const POINTS_DEFAULT: u32 = 300;
/// The gap trend is fitted to the estimates of this window before the last bite.
pub const TREND_WINDOW: Duration = Duration::from_secs(28 * 86_400);
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

/// A driveline's thresholds.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct ThresholdsView {
    /// TAF warning.
    pub taf_warning: f64,
    /// TAF alarm.
    pub taf_alarm: f64,
    /// Gap warning, mrad.
    pub gap_warning_mrad: f64,
    /// Gap alarm, mrad.
    pub gap_alarm_mrad: f64,
}

/// The figures of `subject` as JSON, one member per catalogue key: its value while good
/// or last usable (the page marks a stale source beside it), `null` while it has none.
/// A time is ISO-8601 UTC text.
pub fn figures_json<R: Subject>(figures: &[Figure<R>], subject: &R) -> Map<String, JsonValue> {
    figures
        .iter()
        .map(|figure| {
            let value = match figure.read(subject).usable() {
                None => JsonValue::Null,
                Some(Value::Real(v)) => {
                    serde_json::Number::from_f64(v).map_or(JsonValue::Null, JsonValue::Number)
                }
                Some(Value::Count(v) | Value::Index(v)) => JsonValue::from(v),
                Some(Value::Bool(v)) => JsonValue::Bool(v),
                Some(Value::Time(ms)) => JsonValue::String(UtcTime::from_unix_ms(ms).to_string()),
            };
            (figure.key.to_owned(), value)
        })
        .collect()
}

/// `ok`, `warning` or `alarm` of a warning flag and a (latched) alarm flag.
fn state_of(warning: bool, alarm: bool) -> &'static str {
    match (warning, alarm) {
        (_, true) => "alarm",
        (true, false) => "warning",
        _ => "ok",
    }
}

/// A driveline's live figures (every catalogue figure by its key) and, on the overview
/// and its own endpoint, the gap trend from the history.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct DrivelineView {
    /// Name.
    pub name: String,
    /// Whether it has a model (the gap diagnosis runs only with one).
    pub has_model: bool,
    /// The catalogue's driveline figures by key ([`catalogue::DRIVELINE`]).
    #[serde(flatten)]
    pub figures: Map<String, JsonValue>,
    /// Gap trend, mrad per week, from the history (least squares over the estimates
    /// of the 4 weeks before the last bite, after the last wear reset); `None` on
    /// live updates, without a history or with fewer than 5 estimates.
    pub gap_trend_mrad_per_week: Option<f64>,
    /// `ok`, `warning` or `alarm` of the TAF.
    pub taf_state: &'static str,
    /// `ok`, `warning`, `alarm` of the gap, or `unknown` without an estimate.
    pub wear_state: &'static str,
    /// Thresholds.
    pub thresholds: ThresholdsView,
}

impl DrivelineView {
    fn new(info: &DrivelineInfo, results: &DrivelineResults) -> Self {
        Self {
            name: info.name.clone(),
            has_model: info.has_model,
            figures: figures_json(catalogue::DRIVELINE, results),
            gap_trend_mrad_per_week: None,
            taf_state: state_of(results.taf_warning, results.taf_alarm),
            wear_state: if results.gap.is_none() && !results.gap_alarm {
                "unknown"
            } else {
                state_of(results.gap_warning, results.gap_alarm)
            },
            thresholds: ThresholdsView {
                taf_warning: info.taf_warning,
                taf_alarm: info.taf_alarm,
                gap_warning_mrad: info.gap_warning_mrad,
                gap_alarm_mrad: info.gap_alarm_mrad,
            },
        }
    }
}

/// A tandem mill's chatter state and figures (every catalogue figure by its key).
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct TandemMillView {
    /// Name.
    pub name: String,
    /// Stand channels, rolling order.
    pub stands: Vec<String>,
    /// `ok`, `warning`, `alarm`, `stale` or `unknown` (no window yet).
    pub chatter_state: &'static str,
    /// The stand channel of `worst_stand`.
    pub worst_stand_channel: Option<String>,
    /// The catalogue's tandem mill figures by key ([`catalogue::TANDEM_MILL`]): a stale
    /// stand withdraws the window's (as the PLC gets them).
    #[serde(flatten)]
    pub figures: Map<String, JsonValue>,
}

impl TandemMillView {
    fn new((name, stands): &(String, Vec<String>), results: &TandemMillResults) -> Self {
        Self {
            name: name.clone(),
            stands: stands.clone(),
            chatter_state: if results.chatter_alarm {
                "alarm"
            } else if results.source_stale {
                "stale"
            } else if results.chatter_warning {
                "warning"
            } else if results.evaluations == 0 {
                "unknown"
            } else {
                "ok"
            },
            worst_stand_channel: results
                .worst_stand
                .filter(|_| !results.source_stale)
                .and_then(|stand| stands.get(stand).cloned()),
            figures: figures_json(catalogue::TANDEM_MILL, results),
        }
    }
}

/// A rod mill's state, figures and spans.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct RodMillView {
    /// Name.
    pub name: String,
    /// `stable`, `near_tongue`, `unstable`, `refused` (inputs out of range),
    /// `stale` or `unknown` (not evaluated).
    pub state: &'static str,
    /// The catalogue's rod mill figures by key ([`catalogue::ROD_MILL`]).
    #[serde(flatten)]
    pub figures: Map<String, JsonValue>,
    /// Each span's figures ([`catalogue::ROD_SPAN`]), rolling order.
    pub spans: Vec<Map<String, JsonValue>>,
}

impl RodMillView {
    fn new(name: &str, results: &RodMillResults) -> Self {
        let valid = results.spans.iter().filter(|span| span.valid);
        let state = if results.source_stale {
            "stale"
        } else if results.input_refused {
            "refused"
        } else if valid.clone().any(|span| span.unstable) {
            "unstable"
        } else if valid.clone().any(|span| span.near_tongue) {
            "near_tongue"
        } else if valid.count() == 0 {
            "unknown"
        } else {
            "stable"
        };
        Self {
            name: name.to_owned(),
            state,
            figures: figures_json(catalogue::ROD_MILL, results),
            spans: (0..results.spans.len())
                .map(|span| figures_json(catalogue::ROD_SPAN, &results.published_span(span)))
                .collect(),
        }
    }
}

/// A source's status and outages.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct SourceView {
    /// Name.
    pub name: String,
    /// `modbus` or `can`.
    pub kind: &'static str,
    /// `ok`, `stale`, `lost` or `unknown`.
    pub status: &'static str,
    /// Outages that started in the last 24 h (history only).
    pub outages_24h: Option<u32>,
    /// Start of the last outage, UTC ISO-8601 (history only).
    pub last_outage_start: Option<String>,
    /// Its end; `None` while it lasts.
    pub last_outage_end: Option<String>,
}

/// `/api/overview` (and, without the history parts, each `/api/events` message).
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct Overview {
    /// The configuration's name.
    pub name: String,
    /// `starting`, `running` or `stopped`.
    pub state: &'static str,
    /// Whether a history is configured (plots need it).
    pub history: bool,
    /// Drivelines, config order.
    pub drivelines: Vec<DrivelineView>,
    /// Tandem mills, config order.
    pub tandem_mills: Vec<TandemMillView>,
    /// Rod mills, config order.
    pub rod_mills: Vec<RodMillView>,
    /// Sources: Modbus, then CAN.
    pub sources: Vec<SourceView>,
}

fn live_overview(state: &WebState, results: &Results) -> Overview {
    Overview {
        name: state.config_name.clone(),
        state: match results.state {
            GatewayState::Starting => "starting",
            GatewayState::Running => "running",
            GatewayState::Stopped => "stopped",
        },
        history: state.history.is_some(),
        drivelines: state
            .drivelines
            .iter()
            .zip(&results.drivelines)
            .map(|(info, results)| DrivelineView::new(info, results))
            .collect(),
        tandem_mills: state
            .tandem_mills
            .iter()
            .zip(&results.tandem_mills)
            .map(|(mill, results)| TandemMillView::new(mill, results))
            .collect(),
        rod_mills: state
            .rod_mills
            .iter()
            .zip(&results.rod_mills)
            .map(|(name, results)| RodMillView::new(name, results))
            .collect(),
        sources: state
            .sources
            .iter()
            .zip(&results.sources)
            .map(|((name, kind), status)| SourceView {
                name: name.clone(),
                kind,
                status: match status {
                    Some(SourceStatus::Ok) => "ok",
                    Some(SourceStatus::Stale) => "stale",
                    Some(SourceStatus::Lost) => "lost",
                    None => "unknown",
                },
                outages_24h: None,
                last_outage_start: None,
                last_outage_end: None,
            })
            .collect(),
    }
}

/// The live overview as `/api/events` sends it.
pub(crate) fn live_json(state: &WebState) -> String {
    let overview = live_overview(state, &state.board.results());
    serde_json::to_string(&overview).unwrap_or_default()
}

/// Add what the history knows to `overview`: gap trends and source outages.
fn add_history(
    reader: &HistoryReader,
    trends: &TrendCache,
    overview: &mut Overview,
) -> Result<(), ApiError> {
    let now = UtcTime::now();
    for source in &mut overview.sources {
        let outages = reader
            .outages(&Filter {
                name: Some(source.name.clone()),
                since: Some(now.minus(OUTAGE_WINDOW)),
                ..Filter::default()
            })
            .map_err(history_error)?;
        source.outages_24h = Some(u32::try_from(outages.len()).unwrap_or(u32::MAX));
        let last = reader
            .newest::<OutageRow>(&Filter {
                name: Some(source.name.clone()),
                limit: Some(1),
                ..Filter::default()
            })
            .map_err(history_error)?;
        if let Some(last) = last.into_iter().next() {
            source.last_outage_start = Some(last.started_at);
            source.last_outage_end = last.ended_at;
        }
    }
    for driveline in &mut overview.drivelines {
        driveline.gap_trend_mrad_per_week = gap_trend(reader, trends, &driveline.name)?;
    }
    Ok(())
}

/// The gap trend of `driveline` over the [`TREND_WINDOW`] before its last bite,
/// mrad/week, from `trends` when no bite came since; `None` with too few estimates,
/// or when the file does not know the driveline yet (no run recorded it).
fn gap_trend(
    reader: &HistoryReader,
    trends: &TrendCache,
    driveline: &str,
) -> Result<Option<f64>, ApiError> {
    let Some((_, last)) = reader.bite_span(driveline).map_err(history_error)? else {
        return Ok(None);
    };
    let last_ms = last.unix_ms();
    if let Some(&(at, trend)) = crate::lock(&trends.0).get(driveline) {
        if at == last_ms {
            return Ok(trend);
        }
    }
    let until = UtcTime::from_unix_ms(last_ms + 1);
    let trend = match reader.gap_trend(driveline, Some(until), TREND_WINDOW) {
        Ok(trend) => trend.map(|trend| trend.mrad_per_week),
        Err(HistoryError::UnknownDriveline { .. }) => None,
        Err(error) => return Err(history_error(error)),
    };
    crate::lock(&trends.0).insert(driveline.to_owned(), (last_ms, trend));
    Ok(trend)
}

/// The overview with the history's parts when there is a history.
async fn full_overview(state: &Arc<WebState>) -> Result<Overview, ApiError> {
    let mut overview = live_overview(state, &state.board.results());
    if state.history.is_some() {
        let shared = Arc::clone(state);
        overview = with_history(state, move |reader| {
            add_history(reader, &shared.trends, &mut overview)?;
            Ok(overview)
        })
        .await?;
    }
    Ok(overview)
}

/// `GET /api/overview`: every driveline, tandem mill, rod mill and source.
pub(crate) async fn overview(
    State(state): State<Arc<WebState>>,
    query: Result<Query<Vec<(String, String)>>, QueryRejection>,
) -> Result<Json<Overview>, ApiError> {
    Params::of(query, &[])?;
    Ok(Json(full_overview(&state).await?))
}

/// `GET /api/drivelines`: every driveline's live figures.
pub(crate) async fn drivelines(
    State(state): State<Arc<WebState>>,
    query: Result<Query<Vec<(String, String)>>, QueryRejection>,
) -> Result<Json<Vec<DrivelineView>>, ApiError> {
    Params::of(query, &[])?;
    Ok(Json(
        live_overview(&state, &state.board.results()).drivelines,
    ))
}

/// `GET /api/drivelines/{name}`: one driveline with its gap trend.
pub(crate) async fn driveline(
    State(state): State<Arc<WebState>>,
    Path(name): Path<String>,
    query: Result<Query<Vec<(String, String)>>, QueryRejection>,
) -> Result<Json<DrivelineView>, ApiError> {
    Params::of(query, &[])?;
    let index = driveline_index(&state, &name)?;
    let results = state.board.results();
    let mut view = DrivelineView::new(&state.drivelines[index], &results.drivelines[index]);
    if state.history.is_some() {
        let shared = Arc::clone(&state);
        view = with_history(&state, move |reader| {
            view.gap_trend_mrad_per_week = gap_trend(reader, &shared.trends, &view.name)?;
            Ok(view)
        })
        .await?;
    }
    Ok(Json(view))
}

/// One TAF curve of a gap map: TAF over the static torque the analysis measures,
/// at one opened gap.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct MapCurve {
    /// Opened gap, mrad.
    pub gap_mrad: f64,
    /// `[static torque kN*m, TAF]`, static torque ascending.
    pub points: Vec<[f64; 2]>,
}

impl MapCurve {
    fn new(gap_mrad: f64, curve: Vec<(f64, f64)>) -> Self {
        Self {
            gap_mrad,
            points: curve.into_iter().map(|(s, taf)| [s, taf]).collect(),
        }
    }
}

/// A coupling's gap map: its curves at every whole mrad.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct CouplingCurves {
    /// Coupling (model index, 0 = motor side).
    pub coupling: usize,
    /// Its name in the model.
    pub name: String,
    /// Gap 0 (the linear driveline) first.
    pub curves: Vec<MapCurve>,
}

/// The pooled gap estimate on its coupling's map: the curve at the estimate and at
/// the ends of its 90% interval.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct EstimateCurves {
    /// The coupling the estimate names, else the likeliest.
    pub coupling: usize,
    /// Whether the estimate names the coupling (else the bites cannot tell the
    /// couplings apart and `coupling` is only the likeliest).
    pub determined: bool,
    /// At the estimated gap.
    pub gap: MapCurve,
    /// At the interval's lower end.
    pub low: MapCurve,
    /// At its upper end.
    pub high: MapCurve,
}

/// A driveline's gap maps as `/api/drivelines/{name}/map` gives them.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct GapMapView {
    /// `ready`, `building` (read from the cache or simulated), `failed` or `no_model`.
    pub state: &'static str,
    /// What `state` means here (progress, the failure); `None` when ready.
    pub message: Option<String>,
    /// Simulations done and in all while `building` (0 of 0 until the build reports).
    pub simulations: Option<[usize; 2]>,
    /// The model's name, when ready.
    pub model: Option<String>,
    /// The static torque range every curve covers, kN*m, when ready.
    pub static_range_knm: Option<[f64; 2]>,
    /// Every coupling that may carry the gap, in the wear settings' order.
    pub couplings: Vec<CouplingCurves>,
    /// The live pooled estimate on its map; `None` without an estimate.
    pub estimate: Option<EstimateCurves>,
}

impl GapMapView {
    fn not_ready(state: &'static str, message: String, simulations: Option<[usize; 2]>) -> Self {
        Self {
            state,
            message: Some(message),
            simulations,
            model: None,
            static_range_knm: None,
            couplings: Vec::new(),
            estimate: None,
        }
    }

    fn new(maps: &GapMaps, gap: Option<&GapResults>) -> Self {
        let couplings = maps
            .maps()
            .iter()
            .enumerate()
            .map(|(index, map)| CouplingCurves {
                coupling: map.coupling,
                name: map.name.clone(),
                curves: maps
                    .whole_mrad_curves(index)
                    .into_iter()
                    .map(|(mrad, curve)| MapCurve::new(f64::from(mrad), curve))
                    .collect(),
            })
            .collect();
        let estimate = gap.and_then(|gap| {
            let coupling = gap.coupling.or(gap.likeliest_coupling)?;
            let index = maps.index_of(coupling)?;
            let curve = |mrad: f64| MapCurve::new(mrad, maps.taf_curve(index, mrad * 1e-3));
            Some(EstimateCurves {
                coupling,
                determined: gap.coupling.is_some(),
                gap: curve(gap.gap_mrad),
                low: curve(gap.low_mrad),
                high: curve(gap.high_mrad),
            })
        });
        let (low, high) = maps.static_range_knm();
        Self {
            state: "ready",
            message: None,
            simulations: None,
            model: Some(maps.data().model_name.clone()),
            static_range_knm: Some([low, high]),
            couplings,
            estimate,
        }
    }
}

/// `GET /api/drivelines/{name}/map`: the gap maps' TAF curves over static torque
/// (what a bite's TAF is at each opened gap, per coupling) and the live estimate on
/// them.
pub(crate) async fn gap_maps(
    State(state): State<Arc<WebState>>,
    Path(name): Path<String>,
    query: Result<Query<Vec<(String, String)>>, QueryRejection>,
) -> Result<Json<GapMapView>, ApiError> {
    Params::of(query, &[])?;
    let index = driveline_index(&state, &name)?;
    let view = match state.board.gap_maps(index) {
        Some(GapMapState::Ready(maps)) => {
            let results = state.board.results();
            GapMapView::new(&maps, results.drivelines[index].gap.as_ref())
        }
        Some(GapMapState::Building { done, total }) => GapMapView::not_ready(
            "building",
            if total == 0 {
                "the gap maps are being read from the cache or built".into()
            } else {
                format!("the gap maps are being built: {done} of {total} simulations")
            },
            Some([done, total]),
        ),
        Some(GapMapState::Failed(why)) => {
            GapMapView::not_ready("failed", format!("no gap maps: {why}"), None)
        }
        Some(GapMapState::NoModel) | None => GapMapView::not_ready(
            "no_model",
            format!("driveline \"{name}\" has no model configured: no gap maps"),
            None,
        ),
    };
    Ok(Json(view))
}

/// `GET /api/drivelines/{name}/bites?since=&until=&limit=`: the newest `limit` bites
/// in the range, oldest first.
pub(crate) async fn bites(
    State(state): State<Arc<WebState>>,
    Path(name): Path<String>,
    query: Result<Query<Vec<(String, String)>>, QueryRejection>,
) -> Result<Json<Vec<BiteRow>>, ApiError> {
    let params = Params::of(query, &["since", "until", "limit"])?;
    driveline_index(&state, &name)?;
    Ok(Json(newest(&state, &params, Some(name)).await?))
}

/// `GET /api/drivelines/{name}/wear?since=&until=&points=`: the gap estimate (last
/// in each bucket, interval extremes) and TAF (mean, max) in at most `points` time
/// buckets, oldest first; buckets without bites are left out.
pub(crate) async fn wear(
    State(state): State<Arc<WebState>>,
    Path(name): Path<String>,
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

/// `GET /api/events`: server-sent events, `event: results` with the live overview
/// (no history parts) at once and whenever it changes (checked every
/// [`super::LIVE_PERIOD`]); a comment every 15 s keeps proxies from closing it.
pub(crate) async fn events(
    State(state): State<Arc<WebState>>,
    query: Result<Query<Vec<(String, String)>>, QueryRejection>,
) -> Result<Response, ApiError> {
    Params::of(query, &[])?;
    let stream: std::pin::Pin<Box<dyn Stream<Item = Result<Event, Infallible>> + Send>> = Box::pin(
        WatchStream::new(state.live.clone())
            .map(|json| Ok(Event::default().event("results").data(json.as_str()))),
    );
    let mut response = Sse::new(stream)
        .keep_alive(KeepAlive::new().interval(Duration::from_secs(15)))
        .into_response();
    response
        .headers_mut()
        .insert(header::CACHE_CONTROL, HeaderValue::from_static("no-store"));
    Ok(response)
}
