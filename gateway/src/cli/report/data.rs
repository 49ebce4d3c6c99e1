//! What the report reads of one driveline, without holding its bites: counts and TAF
//! quantiles, the last gap estimate and its trend, the time series in buckets (the
//! web page's [`HistoryReader::wear_series`] and the wear index in the same buckets),
//! the gap forecast's cone (recomputed from the wear trend the history saved, see
//! [`Forecast`]) and the bites binned over static torque and TAF ([`TafGrid`]).

use super::plots::{range, wear_curves, Curve, TafGrid};
use crate::analysis::gap_trend;
use crate::cli::progress::{percent, Progress};
use crate::history::query::{BiteRow, Filter, HistoryReader, SettingsRow};
use crate::history::series::TREND_WINDOW;
use crate::history::series::{GapTrend, WearIndexPoint, WearPoint};
use crate::history::summary::{BiteSummary, ProductSummary};
use crate::state::results::GapResults;
use crate::state::time::UtcTime;

/// Time buckets of the plots over time: 2 px each of a 900 px wide panel.
pub(super) const PLOT_BUCKETS: usize = 450;

/// One driveline's part of the report.
#[derive(Debug)]
pub(super) struct DrivelineData {
    /// Counts and TAF quantiles of its bites in the period.
    pub(super) summary: BiteSummary,
    /// Its bites in the period by product (empty without a product context).
    pub(super) products: Vec<ProductSummary>,
    /// Its last bite in the period (with the gap estimate after it).
    pub(super) last: Option<BiteRow>,
    /// The gap's growth over the four weeks before the period's end (or its last bite).
    pub(super) trend: Option<GapTrend>,
    /// Gap and TAF per time bucket.
    pub(super) wear: Vec<WearPoint>,
    /// Wear index per time bucket.
    pub(super) index: Vec<WearIndexPoint>,
    /// Its settings in the last run that recorded them (thresholds, model).
    pub(super) setting: Option<SettingsRow>,
    /// The wear map's curves over its static torque range, or why there are none.
    pub(super) curves: Result<Vec<Curve>, String>,
    /// Its bites over static torque and TAF.
    pub(super) grid: TafGrid,
    /// The gap forecast after its last bite, when the history saved its wear trend
    /// and that bite lies in the period; why not drawn, when the saved trend cannot
    /// be used.
    pub(super) forecast: Result<Option<Forecast>, String>,
}

/// The gap forecast after a driveline's last bite: its wear trend as the history
/// saved it (`driveline_state.gap_trend`), continued by
/// [`gap_trend::GapTrend::restore`], asked
/// for the alarm threshold of the last run's settings. The horizon is not stored: the
/// default's ([`millgate_config::WearSettings`], 365 days) decides where a cone
/// without a crossing ends.
#[derive(Debug)]
pub(super) struct Forecast {
    /// The last bite the trend holds.
    pub(super) last_bite: UtcTime,
    /// The gap alarm threshold asked for, mrad.
    pub(super) alarm_mrad: f64,
    /// The trend's gap, growth and forecast (with its cone) at the last bite.
    pub(super) gap: GapResults,
}

/// The forecast of the wear trend `saved` (a state row's `gap_trend`) for the alarm
/// threshold of `setting`, when its last bite lies in the period `[since, until)`;
/// `Ok(None)` without a saved trend or a bite, or when the trend's last bite lies
/// outside the period.
fn forecast(
    saved: Option<&str>,
    setting: Option<&SettingsRow>,
    (since, until): (Option<UtcTime>, Option<UtcTime>),
) -> Result<Option<Forecast>, String> {
    let Some(saved) = saved else {
        return Ok(None);
    };
    let alarm_mrad = setting.and_then(|s| s.gap_alarm_mrad).ok_or_else(|| {
        "the last run's settings have no gap alarm threshold (driveline_settings.gap_alarm_mrad)"
            .to_owned()
    })?;
    let horizon_days = millgate_config::WearSettings::default().horizon_days;
    let trend = gap_trend::GapTrend::restored(horizon_days, saved)
        .map_err(|error| format!("the saved wear trend: {error}"))?;
    let Some(last_bite) = trend.last_bite_unix_ms().map(UtcTime::from_unix_ms) else {
        return Ok(None);
    };
    if since.is_some_and(|since| last_bite < since) || until.is_some_and(|until| last_bite >= until)
    {
        return Ok(None);
    }
    Ok(trend.results(alarm_mrad).map(|gap| Forecast {
        last_bite,
        alarm_mrad,
        gap,
    }))
}

/// Read `name`'s part of the report for the period `[since, until)` (open ends: all
/// of the file), with its `setting` and the wear trend its state row `saved`, showing
/// how far on `progress`.
pub(super) fn read(
    reader: &HistoryReader,
    name: &str,
    (since, until): (Option<UtcTime>, Option<UtcTime>),
    (setting, saved): (Option<SettingsRow>, Option<&str>),
    progress: &mut Progress,
) -> anyhow::Result<DrivelineData> {
    step(progress, name, "counting bites");
    let summary = reader.bite_summary(name, since, until)?;
    let products = reader.product_summaries(name, since, until)?;
    let last = reader
        .newest::<BiteRow>(&Filter {
            name: Some(name.to_owned()),
            since,
            until,
            after_id: None,
            limit: Some(1),
            product: None,
            coil: None,
        })?
        .pop();
    let known = last.is_some();
    let trend = if known {
        reader.gap_trend(name, until, TREND_WINDOW)?
    } else {
        None
    };
    step(progress, name, "gap, TAF and wear index over time");
    let (wear, index) = if known {
        (
            reader.wear_series(name, since, until, PLOT_BUCKETS)?,
            reader.wear_index_series(name, since, until, PLOT_BUCKETS)?,
        )
    } else {
        (Vec::new(), Vec::new())
    };
    let torques = match torque_range(&index) {
        None if known => {
            step(progress, name, "static torque range");
            torque_pass(reader, name, since, until)?
        }
        torques => torques,
    };
    let curves = match setting.as_ref().and_then(|s| s.model.as_deref()) {
        Some(model) => {
            step(progress, name, "the wear map's curves");
            wear_curves(model, torques.unwrap_or((0.0, 1.0)))
        }
        None => Ok(Vec::new()),
    };
    let mut grid = empty_grid(torques, &curves, &wear, setting.as_ref());
    if known {
        let bites = summary.bites;
        bin_bites(reader, name, (since, until), bites, &mut grid, progress)?;
    }
    let forecast = forecast(saved, setting.as_ref(), (since, until));
    Ok(DrivelineData {
        summary,
        products,
        last,
        trend,
        wear,
        index,
        setting,
        curves,
        grid,
        forecast,
    })
}

/// Show on `progress` that the report reads `what` of driveline `name`.
fn step(progress: &mut Progress, name: &str, what: &str) {
    progress.update(|| format!("report: {name}: {what}"));
}

/// The static torque range of the wear index's buckets (none without a wear index).
fn torque_range(index: &[WearIndexPoint]) -> Option<(f64, f64)> {
    index
        .iter()
        .map(|p| (p.static_torque_min_knm, p.static_torque_max_knm))
        .reduce(|a, b| (a.0.min(b.0), a.1.max(b.1)))
}

/// The static torque range of `name`'s bites in `[since, until)`, in a pass over them.
fn torque_pass(
    reader: &HistoryReader,
    name: &str,
    since: Option<UtcTime>,
    until: Option<UtcTime>,
) -> anyhow::Result<Option<(f64, f64)>> {
    let mut torques: Option<(f64, f64)> = None;
    reader.for_each_taf_point(name, since, until, |point| {
        let torque = point.static_torque_knm;
        torques = Some(torques.map_or((torque, torque), |(low, high)| {
            (low.min(torque), high.max(torque))
        }));
        Ok::<_, anyhow::Error>(())
    })?;
    Ok(torques)
}

/// The TAF-over-torque grid without bites, over the plot's ranges: the torque range,
/// the clean bites' TAF (the buckets' extremes in `wear`), the `curves` and the
/// thresholds in `setting`. Degraded windows' TAF is not trusted and does not stretch
/// the plot.
fn empty_grid(
    torques: Option<(f64, f64)>,
    curves: &Result<Vec<Curve>, String>,
    wear: &[WearPoint],
    setting: Option<&SettingsRow>,
) -> TafGrid {
    let curve_points = || curves.iter().flatten().flat_map(|(_, c)| c.iter());
    let x_range = range(
        torques
            .into_iter()
            .flat_map(|(low, high)| [low, high])
            .chain(curve_points().map(|p| p.0)),
    );
    let thresholds = setting
        .map(|s| [s.taf_warning, s.taf_alarm])
        .into_iter()
        .flatten();
    let y_range = range(
        wear.iter()
            .flat_map(|p| [p.taf_min, p.taf_max])
            .flatten()
            .chain(curve_points().map(|p| p.1))
            .chain(thresholds),
    );
    TafGrid::new(x_range, y_range)
}

/// Bin `name`'s `bites` bites in `period` into `grid`, showing how far on `progress`.
fn bin_bites(
    reader: &HistoryReader,
    name: &str,
    (since, until): (Option<UtcTime>, Option<UtcTime>),
    bites: u64,
    grid: &mut TafGrid,
    progress: &mut Progress,
) -> anyhow::Result<()> {
    let mut seen: u64 = 0;
    reader.for_each_taf_point(name, since, until, |point| {
        grid.add(point);
        seen += 1;
        progress.update(|| {
            format!(
                "report: {name}: TAF over static torque, {:.0}% of {bites} bites",
                percent(seen, bites),
            )
        });
        Ok::<_, anyhow::Error>(())
    })?;
    Ok(())
}
