//! A tandem mill's captures (chatter episodes, manual captures of its stands) and
//! what its page plots of one: the stands' chatter-band signal over time and their
//! spectra around the warning.

use std::sync::Arc;

use axum::extract::rejection::{PathRejection, QueryRejection};
use axum::extract::{Path, Query, State};
use axum::http::StatusCode;
use axum::Json;

use super::history::{capture_id, newest, read_capture};
use super::{ApiError, DrivelineName, Params, POINTS_DEFAULT};
use crate::history::query::{CaptureRow, ChatterRow};
use crate::history::series::MAX_SERIES_POINTS;
use crate::outputs::web::shared::WebState;

/// `GET /api/tandem_mills/{name}/captures?since=&until=&limit=&product=&coil=`: the newest
/// `limit` captures of the mill in the range (of product code `product` when given;
/// chatter episodes and manual captures of its stands: their rows with the context of
/// their time, not their samples), oldest first.
pub(crate) async fn tandem_mill_captures(
    State(state): State<Arc<WebState>>,
    DrivelineName(name): DrivelineName,
    query: Result<Query<Vec<(String, String)>>, QueryRejection>,
) -> Result<Json<Vec<serde_json::Value>>, ApiError> {
    let params = Params::of(query, &["since", "until", "limit", "product", "coil"])?;
    mill_index(&state, &name)?;
    let rows: Vec<CaptureRow> = newest(&state, &params, Some(name)).await?;
    Ok(Json(
        rows.iter()
            .map(crate::history::captures::row_json)
            .collect(),
    ))
}

/// `GET /api/tandem_mills/{name}/episodes?since=&until=&limit=&product=&coil=`: the newest
/// `limit` chatter episodes of the mill that started in the range (of product code
/// `product` when given), oldest first, each with the context of its start (table
/// `chatter_episodes`' columns).
pub(crate) async fn tandem_mill_episodes(
    State(state): State<Arc<WebState>>,
    DrivelineName(name): DrivelineName,
    query: Result<Query<Vec<(String, String)>>, QueryRejection>,
) -> Result<Json<Vec<ChatterRow>>, ApiError> {
    let params = Params::of(query, &["since", "until", "limit", "product", "coil"])?;
    mill_index(&state, &name)?;
    Ok(Json(newest(&state, &params, Some(name)).await?))
}

/// `GET /api/captures/{id}/bands?points=`: for a chatter or manual capture of a
/// tandem mill's stands, per stand the chatter monitor's band RMS after each window
/// (its band gain's band-pass over `gain_window_s`) and the Welch PSD of the samples
/// around the warning (the whole capture for a manual one), each in at most `points`
/// buckets (first time or frequency of the bucket, min and max). Computed in one of
/// the page's history query slots. 404 for an unknown id, 409 for a capture of no
/// tandem mill.
pub(crate) async fn capture_bands(
    State(state): State<Arc<WebState>>,
    id: Result<Path<i64>, PathRejection>,
    query: Result<Query<Vec<(String, String)>>, QueryRejection>,
) -> Result<Json<serde_json::Value>, ApiError> {
    let id = capture_id(id)?;
    let params = Params::of(query, &["points"])?;
    let max = u32::try_from(MAX_SERIES_POINTS).unwrap_or(u32::MAX);
    let points = params.count("points", 2..=max, POINTS_DEFAULT)? as usize;
    let web = Arc::clone(&state);
    super::with_history(&state, move |reader| {
        let capture = read_capture(reader, id)?;
        let conflict = |why: String| ApiError {
            status: StatusCode::CONFLICT,
            message: format!("capture {id}: {why}"),
        };
        let row = &capture.row;
        if row.kind == "bite" {
            return Err(conflict("a bite's capture, not a tandem mill's".into()));
        }
        let mill = web
            .tandem_mills
            .iter()
            .position(|(name, _)| *name == row.subject)
            .ok_or_else(|| conflict(format!("\"{}\" is no tandem mill", row.subject)))?;
        let analyse = web
            .capture_bands
            .get()
            .ok_or_else(|| conflict("no band analysis in this server".into()))?;
        let stands: Vec<Vec<f64>> = capture.channels.iter().map(|c| c.samples.clone()).collect();
        let episode = capture.meta.episode.as_ref();
        let bands = analyse(mill, row.sample_rate_hz, &stands, episode).map_err(conflict)?;
        let band: Vec<serde_json::Value> = bands
            .band_rms
            .iter()
            .map(|series| {
                let (x, min, max) = envelope(&bands.window_end_s, series, points);
                serde_json::json!({
                    "t_s": x, "min": min, "max": max,
                    "largest": series.iter().copied().fold(f64::NAN, f64::max),
                })
            })
            .collect();
        let spectra: Vec<serde_json::Value> = bands
            .spectra
            .iter()
            .map(|spectrum| {
                let frequency_hz: Vec<f64> = (0..spectrum.psd.len())
                    .map(|k| k as f64 * spectrum.frequency_step_hz)
                    .collect();
                let peak = (0..spectrum.psd.len())
                    .max_by(|&a, &b| spectrum.psd[a].total_cmp(&spectrum.psd[b]))
                    .map(|k| frequency_hz[k]);
                let (x, min, max) = envelope(&frequency_hz, &spectrum.psd, points);
                serde_json::json!({
                    "frequency_hz": x, "min": min, "max": max, "peak_hz": peak,
                    "frequency_step_hz": spectrum.frequency_step_hz,
                })
            })
            .collect();
        let rate = row.sample_rate_hz;
        Ok(serde_json::json!({
            "capture_id": id,
            "tandem_mill": row.subject,
            "kind": row.kind,
            "sample_rate_hz": rate,
            "stands": capture.channels.iter().map(|c| &c.name).collect::<Vec<_>>(),
            "unit": capture.channels.first().map(|c| c.unit.as_str()),
            "chatter_band_hz": [bands.chatter_band_hz.0, bands.chatter_band_hz.1],
            "warning_s": episode.map(|e| e.warning_sample as f64 / rate),
            "cleared_s": episode.and_then(|e| e.cleared_sample).map(|k| k as f64 / rate),
            "band_rms": band,
            "spectrum_span_s": [bands.spectrum_span_s.0, bands.spectrum_span_s.1],
            "spectra": spectra,
        }))
    })
    .await
    .map(Json)
}

/// `y` over `x` in at most `points` buckets of consecutive values: each bucket's
/// first `x`, its smallest and its largest `y` (the values themselves when they fit).
fn envelope(x: &[f64], y: &[f64], points: usize) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    let per = y.len().div_ceil(points.max(1)).max(1);
    let mut out = (Vec::new(), Vec::new(), Vec::new());
    for (xs, ys) in x.chunks(per).zip(y.chunks(per)) {
        out.0.push(xs[0]);
        out.1.push(ys.iter().copied().fold(f64::INFINITY, f64::min));
        out.2
            .push(ys.iter().copied().fold(f64::NEG_INFINITY, f64::max));
    }
    out
}

/// The tandem mill named `name`, or 404.
fn mill_index(state: &WebState, name: &str) -> Result<usize, ApiError> {
    state
        .tandem_mills
        .iter()
        .position(|(mill, _)| mill == name)
        .ok_or_else(|| ApiError {
            status: StatusCode::NOT_FOUND,
            message: format!(
                "no tandem mill \"{name}\" (known: {})",
                state
                    .tandem_mills
                    .iter()
                    .map(|(mill, _)| mill.as_str())
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        })
}

#[cfg(test)]
mod tests {
    use super::envelope;

    #[test]
    fn the_envelope_keeps_each_buckets_extremes() {
        let x: Vec<f64> = (0..10).map(f64::from).collect();
        let y = [3.0, -1.0, 4.0, 1.0, -5.0, 9.0, 2.0, 6.0, 5.0, 3.0];
        let (bx, lo, hi) = envelope(&x, &y, 3);
        assert_eq!(bx, [0.0, 4.0, 8.0]);
        assert_eq!(lo, [-1.0, -5.0, 3.0]);
        assert_eq!(hi, [4.0, 9.0, 5.0]);
        assert_eq!(envelope(&x, &y, 100).1, y);
    }
}
