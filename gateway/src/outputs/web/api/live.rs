//! The live figures: every driveline, tandem mill, rod mill and source by the
//! catalogue's keys, with what the history adds (gap trends, outages), and the
//! server-sent events that carry them to open pages.

use std::convert::Infallible;
use std::future::Future as _;
use std::sync::Arc;
use std::time::Duration;

use axum::extract::rejection::QueryRejection;
use axum::extract::{Query, State};
use axum::http::{header, HeaderValue};
use axum::response::sse::{Event, KeepAlive, Sse};
use axum::response::{IntoResponse, Response};
use axum::Json;
use serde::Serialize;
use serde_json::{Map, Value as JsonValue};
use tokio_stream::wrappers::WatchStream;
use tokio_stream::{Stream, StreamExt};

use super::{
    driveline_index, history_error, with_history, ApiError, DrivelineName, Params, OUTAGE_WINDOW,
};
use crate::history::query::{Filter, HistoryReader, OutageRow};
use crate::history::series::TREND_WINDOW;
use crate::history::HistoryError;
use crate::outputs::web::shared::{DrivelineInfo, TrendCache, WebState};
use crate::state::catalogue::{self, Figure, Subject, Value};
use crate::state::results::{
    ComponentLife, DrivelineResults, GapResults, Results, RodMillResults, TandemMillResults,
};
use crate::state::time::UtcTime;

/// A driveline's thresholds.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub(crate) struct ThresholdsView {
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
pub(crate) fn figures_json<R: Subject>(
    figures: &[Figure<R>],
    subject: &R,
) -> Map<String, JsonValue> {
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
pub(crate) struct DrivelineView {
    /// Name.
    pub name: String,
    /// Whether it has a model (the gap diagnosis runs only with one).
    pub has_model: bool,
    /// The catalogue's driveline figures by key ([`catalogue::DRIVELINE`]).
    #[serde(flatten)]
    pub figures: Map<String, JsonValue>,
    /// Gap trend, mrad per week, from the history (least squares over the estimates
    /// of the 4 weeks before the last bite, after the last wear reset); `None` on
    /// live updates, without a history or with fewer than 5 estimates. Deprecated:
    /// the wear trend's `gap_growth_mrad_per_day` replaces it (kept for one release).
    pub gap_trend_mrad_per_week: Option<f64>,
    /// The gap forecast's cone and the fitted growth line, dated, for drawing; `None`
    /// until the wear trend has a growth.
    pub gap_cone: Option<GapConeView>,
    /// `ok`, `warning` or `alarm` of the TAF.
    pub taf_state: &'static str,
    /// `ok`, `warning`, `alarm` of the gap, or `unknown` without an estimate.
    pub wear_state: &'static str,
    /// Thresholds.
    pub thresholds: ThresholdsView,
    /// The fatigue ledger per component (config order) as of the last bite or reset:
    /// name, installation, life used, last bite's damage, rate, forecast; empty
    /// without `drivelines[].fatigue` (the catalogue's `fatigue_*` figures are the
    /// worst component's).
    pub fatigue_components: Vec<ComponentLife>,
    /// Its nameplate from `drivelines[].identification` (the keys set; `{}` without
    /// one), as the OPC UA server's `Identification` gives it.
    pub identification: Map<String, JsonValue>,
}

impl DrivelineView {
    fn new(info: &DrivelineInfo, results: &DrivelineResults) -> Self {
        Self {
            name: info.name.clone(),
            has_model: info.has_model,
            figures: figures_json(catalogue::DRIVELINE, results),
            gap_trend_mrad_per_week: None,
            gap_cone: results
                .gap
                .zip(results.last_bite_unix_ms)
                .and_then(|(gap, last)| GapConeView::new(&gap, last)),
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
            fatigue_components: results.fatigue_components.clone(),
            identification: info.identification.clone(),
        }
    }
}

/// A driveline's gap forecast as the page draws it (`gap_cone`): the band the gap is
/// expected in after the last bite, and the growth line fitted before it.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub(crate) struct GapConeView {
    /// The band at evenly spaced times from the last bite to beyond the late end of
    /// the forecast (or its horizon).
    pub points: Vec<ConePointView>,
    /// The fitted growth: the gap at the last bite and the growth back over (at most)
    /// the last four weeks since the last wear reset.
    pub fitted_line: FittedLineView,
}

/// One point of a [`GapConeView`].
#[derive(Debug, Clone, Serialize, PartialEq)]
pub(crate) struct ConePointView {
    /// The last bite's time plus the point's days, UTC.
    pub time: UtcTime,
    /// The trend's gap, mrad.
    pub mean_mrad: f64,
    /// The late (low) end of its 90% band, mrad.
    pub low_mrad: f64,
    /// The early (high) end of its 90% band, mrad.
    pub high_mrad: f64,
}

/// The fitted growth line of a [`GapConeView`]: from `from_time` (the last bite minus
/// the cone's `back_days`) to the last bite.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub(crate) struct FittedLineView {
    /// Its start, UTC.
    pub from_time: UtcTime,
    /// The gap there on the line: the gap minus the growth times the days back, mrad.
    pub from_mrad: f64,
    /// Its end: the last bite's time, UTC.
    pub to_time: UtcTime,
    /// The gap at the last bite, mrad.
    pub to_mrad: f64,
}

impl GapConeView {
    /// The cone of `gap` dated from the last bite at `last_bite_unix_ms`; `None`
    /// without a growth or a cone.
    fn new(gap: &GapResults, last_bite_unix_ms: i64) -> Option<Self> {
        let growth = gap.growth?;
        let cone = gap.forecast?.cone?;
        let last = UtcTime::from_unix_ms(last_bite_unix_ms);
        Some(Self {
            points: cone
                .points
                .iter()
                .map(|point| ConePointView {
                    time: last.plus_days(point.days),
                    mean_mrad: point.mean_mrad,
                    low_mrad: point.low_mrad,
                    high_mrad: point.high_mrad,
                })
                .collect(),
            fitted_line: FittedLineView {
                from_time: last.plus_days(-cone.back_days),
                from_mrad: gap.gap_mrad - growth.mrad_per_day * cone.back_days,
                to_time: last,
                to_mrad: gap.gap_mrad,
            },
        })
    }
}

/// A tandem mill's chatter state and figures (every catalogue figure by its key).
#[derive(Debug, Clone, Serialize, PartialEq)]
pub(crate) struct TandemMillView {
    /// Name.
    pub name: String,
    /// Stand channels, rolling order.
    pub stands: Vec<String>,
    /// `ok`, `warning`, `alarm`, `stale` or `unknown` (no window yet).
    pub chatter_state: &'static str,
    /// The stand channel of `worst_stand`.
    pub worst_stand_channel: Option<String>,
    /// The product group whose thresholds judged the last window (`thresholds_group`
    /// by name); `None`: the mill's `gain_thresholds`.
    pub thresholds_group_name: Option<String>,
    /// The `gain_thresholds` that judged the last window, per stand (the group's or
    /// the mill's); `None` before the first window.
    pub gain_thresholds_in_use: Option<Vec<f64>>,
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
            thresholds_group_name: results.thresholds_group_name.clone(),
            gain_thresholds_in_use: results
                .gain_thresholds_in_use
                .as_deref()
                .map(<[f64]>::to_vec),
            figures: figures_json(catalogue::TANDEM_MILL, results),
        }
    }
}

/// A rod mill's state, figures and spans.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub(crate) struct RodMillView {
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
pub(crate) struct SourceView {
    /// Name.
    pub name: String,
    /// `modbus` or `can`.
    pub kind: &'static str,
    /// `ok`, `stale`, `lost` (the catalogue's source `status`) or `unknown` (no status
    /// yet).
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
pub(crate) struct Overview {
    /// The configuration's name.
    pub name: String,
    /// `starting`, `running` or `stopped`: the catalogue's gateway `state`.
    pub state: &'static str,
    /// Whether a history is configured (plots need it).
    pub history: bool,
    /// Whether `POST /api/captures` takes manual captures
    /// (`outputs.web.allow_commands`, with a history).
    pub allow_commands: bool,
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
    let gateway_state = catalogue::find(catalogue::GATEWAY, "state");
    let source_status = catalogue::find(catalogue::SOURCE, "status");
    Overview {
        name: state.config_name.clone(),
        state: gateway_state
            .state_name(&results.gateway())
            .unwrap_or("unknown"),
        history: state.history.is_some(),
        allow_commands: state.allow_commands
            && state.history.is_some()
            && state.commands.get().is_some(),
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
            .zip(0..results.sources.len())
            .map(|((name, kind), k)| SourceView {
                name: name.clone(),
                kind,
                status: source_status
                    .state_name(&results.source(k))
                    .unwrap_or("unknown"),
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
    DrivelineName(name): DrivelineName,
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

/// Longest life of one `/api/events` stream: it then ends, and the page's
/// `EventSource` opens a new one (after [`EVENT_RETRY`]), so a held stream cannot
/// keep its slot for ever.
pub(crate) const EVENT_STREAM_LIFETIME: Duration = Duration::from_secs(600);

/// The reconnection delay an `/api/events` stream asks of its `EventSource`.
const EVENT_RETRY: Duration = Duration::from_secs(1);

/// `GET /api/events`: server-sent events, `event: results` with the live overview
/// (no history parts) at once and whenever it changes (at most one update per
/// [`crate::outputs::web::LIVE_PERIOD`]); a comment every 15 s keeps proxies from closing it. At
/// most `outputs.web.max_event_streams` at once (a further one is answered 503 with
/// `Retry-After`), each for [`EVENT_STREAM_LIFETIME`].
pub(crate) async fn events(
    State(state): State<Arc<WebState>>,
    query: Result<Query<Vec<(String, String)>>, QueryRejection>,
) -> Result<Response, ApiError> {
    Params::of(query, &[])?;
    let Ok(slot) = Arc::clone(&state.event_streams).try_acquire_owned() else {
        return Err(ApiError {
            status: axum::http::StatusCode::SERVICE_UNAVAILABLE,
            message: "every live-update stream is taken (outputs.web.max_event_streams)".into(),
        });
    };
    let mut first = true;
    let updates = WatchStream::new(state.live.clone()).map(move |json| {
        let event = Event::default().event("results").data(json.as_str());
        // The first event tells the browser how soon to come back after the end.
        let event = if std::mem::take(&mut first) {
            event.retry(EVENT_RETRY)
        } else {
            event
        };
        Ok(event)
    });
    let stream: std::pin::Pin<Box<dyn Stream<Item = Result<Event, Infallible>> + Send>> =
        Box::pin(Lifetime {
            updates,
            end: Box::pin(tokio::time::sleep(EVENT_STREAM_LIFETIME)),
            _slot: slot,
        });
    let mut response = Sse::new(stream)
        .keep_alive(KeepAlive::new().interval(Duration::from_secs(15)))
        .into_response();
    response
        .headers_mut()
        .insert(header::CACHE_CONTROL, HeaderValue::from_static("no-store"));
    Ok(response)
}

/// A stream of live updates that ends at `end` and holds its stream slot until
/// dropped (when its connection goes or its answer ends).
struct Lifetime<S> {
    updates: S,
    end: std::pin::Pin<Box<tokio::time::Sleep>>,
    _slot: tokio::sync::OwnedSemaphorePermit,
}

impl<S: Stream + Unpin> Stream for Lifetime<S> {
    type Item = S::Item;

    fn poll_next(
        mut self: std::pin::Pin<&mut Self>,
        context: &mut std::task::Context<'_>,
    ) -> std::task::Poll<Option<S::Item>> {
        if self.end.as_mut().poll(context).is_ready() {
            return std::task::Poll::Ready(None);
        }
        std::pin::Pin::new(&mut self.updates).poll_next(context)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::state::results::{
        ConePoint, ForecastState, GapCone, GapForecast, GapGrowth, CONE_POINTS,
    };

    /// A driveline on the board whose last bite (2027-01-10 06:00 UTC) left a gap of
    /// 3 mrad growing 0.1 mrad/day, the forecast's cone over 40 days and a fitted
    /// line 14 days back.
    fn forecasting() -> (DrivelineInfo, DrivelineResults) {
        let last = UtcTime::parse("2027-01-10T06:00:00Z").unwrap().unix_ms();
        let mut points = [ConePoint::default(); CONE_POINTS];
        for (k, point) in points.iter_mut().enumerate() {
            let days = 40.0 * k as f64 / (CONE_POINTS - 1) as f64;
            let spread = 0.1 + 0.02 * days;
            *point = ConePoint {
                days,
                mean_mrad: 3.0 + 0.1 * days,
                low_mrad: 3.0 + 0.1 * days - spread,
                high_mrad: 3.0 + 0.1 * days + spread,
            };
        }
        let gap = GapResults {
            gap_mrad: 3.0,
            low_mrad: 2.9,
            high_mrad: 3.1,
            coupling: Some(1),
            likeliest_coupling: Some(1),
            bites_pooled: 60,
            growth: Some(GapGrowth {
                mrad_per_day: 0.1,
                low_mrad_per_day: 0.08,
                high_mrad_per_day: 0.12,
            }),
            forecast: Some(GapForecast {
                state: ForecastState::Forecast,
                days: Some(30.0),
                days_low: Some(25.0),
                days_high: Some(37.5),
                date_unix_ms: Some(last + 30 * 86_400_000),
                cone: Some(GapCone {
                    points,
                    back_days: 14.0,
                }),
            }),
        };
        let info = DrivelineInfo {
            name: "F1".into(),
            taf_warning: 1.5,
            taf_alarm: 1.8,
            gap_warning_mrad: 4.0,
            gap_alarm_mrad: 6.0,
            has_model: true,
            model: None,
            fatigue_components: Vec::new(),
            fatigue_life_limit: None,
            identification: Map::new(),
        };
        let results = DrivelineResults {
            last_bite_unix_ms: Some(last),
            gap: Some(gap),
            ..DrivelineResults::default()
        };
        (info, results)
    }

    #[test]
    fn the_gap_cone_is_dated_from_the_last_bite_with_the_fitted_line_behind_it() {
        let (info, results) = forecasting();
        let view = serde_json::to_value(DrivelineView::new(&info, &results)).unwrap();
        let cone = &view["gap_cone"];
        let points = cone["points"].as_array().unwrap();
        assert_eq!(points.len(), CONE_POINTS, "{cone}");
        assert_eq!(points[0]["time"], "2027-01-10T06:00:00.000Z", "{cone}");
        // 40 days after the last bite: 2027-02-19 06:00 UTC.
        assert_eq!(points[15]["time"], "2027-02-19T06:00:00.000Z", "{cone}");
        assert_eq!(points[15]["mean_mrad"], 7.0, "{cone}");
        assert_eq!(points[15]["low_mrad"], 7.0 - 0.9, "{cone}");
        assert_eq!(points[15]["high_mrad"], 7.0 + 0.9, "{cone}");
        // Every point at its days, in time order.
        let cone_points = results.gap.unwrap().forecast.unwrap().cone.unwrap().points;
        for (point, on_board) in points.iter().zip(cone_points) {
            let at = UtcTime::parse(point["time"].as_str().unwrap()).unwrap();
            let days = (at.unix_ms() - results.last_bite_unix_ms.unwrap()) as f64 / 86_400_000.0;
            assert!(
                (days - on_board.days).abs() < 1e-6,
                "{point} vs {on_board:?}"
            );
            assert_eq!(point["mean_mrad"], on_board.mean_mrad);
        }
        // The line: 14 days back at 0.1 mrad/day, to the gap at the last bite.
        let line = &cone["fitted_line"];
        assert_eq!(line["from_time"], "2026-12-27T06:00:00.000Z", "{line}");
        assert!(
            (line["from_mrad"].as_f64().unwrap() - 1.6).abs() < 1e-12,
            "{line}"
        );
        assert_eq!(line["to_time"], "2027-01-10T06:00:00.000Z", "{line}");
        assert_eq!(line["to_mrad"], 3.0, "{line}");
        // The catalogue's forecast figures beside it, and the old key kept.
        assert_eq!(view["gap_alarm_date"], "2027-02-09T06:00:00.000Z", "{view}");
        assert_eq!(view["days_to_gap_alarm_high"], 37.5, "{view}");
        assert!(view.get("gap_trend_mrad_per_week").is_some(), "{view}");
    }

    #[test]
    fn no_cone_without_a_growth() {
        let (info, mut results) = forecasting();
        if let Some(gap) = results.gap.as_mut() {
            gap.growth = None;
        }
        let view = serde_json::to_value(DrivelineView::new(&info, &results)).unwrap();
        assert!(view["gap_cone"].is_null(), "{view}");
        let (info, mut results) = forecasting();
        results.gap = results.gap.map(|gap| GapResults {
            forecast: gap.forecast.map(|forecast| GapForecast {
                cone: None,
                ..forecast
            }),
            ..gap
        });
        let view = serde_json::to_value(DrivelineView::new(&info, &results)).unwrap();
        assert!(view["gap_cone"].is_null(), "{view}");
    }

    #[tokio::test(start_paused = true)]
    async fn a_stream_ends_at_its_lifetime_and_frees_its_slot() {
        let slots = Arc::new(tokio::sync::Semaphore::new(1));
        let (_live, receiver) = tokio::sync::watch::channel(Arc::new("{}".to_owned()));
        let mut stream = Lifetime {
            updates: WatchStream::new(receiver),
            end: Box::pin(tokio::time::sleep(EVENT_STREAM_LIFETIME)),
            _slot: Arc::clone(&slots).try_acquire_owned().unwrap(),
        };
        assert!(stream.next().await.is_some(), "the current results at once");
        assert_eq!(slots.available_permits(), 0, "the stream holds its slot");
        tokio::time::advance(EVENT_STREAM_LIFETIME - Duration::from_secs(1)).await;
        let pending = tokio::time::timeout(Duration::from_millis(500), stream.next()).await;
        assert!(pending.is_err(), "nothing new before the end: {pending:?}");
        tokio::time::advance(Duration::from_secs(1)).await;
        assert!(stream.next().await.is_none(), "ended at its lifetime");
        drop(stream);
        assert_eq!(slots.available_permits(), 1, "the slot is free again");
    }
}
