//! The report's drivelines: each one's part read ([`read`]), the summary table of
//! all, and per driveline its section: the plot over time, the TAF over static torque,
//! the fatigue ledger (its tables and plots) and the captured traces of its last alarm
//! bites.

use std::path::Path;

use super::data::PLOT_BUCKETS;
use super::data::{self, DrivelineData, Forecast};
use super::document::{fmt, Block};
use super::period::Period;
use super::plots::{
    damage_svg, range, taf_svg, time_svg, trace_svg, DamageGrid, TimeAxis, TimePanel,
};
use crate::cli::progress::Progress;
use crate::history::query::HistoryReader;
use crate::state::results::{ForecastState, GapForecast, GapGrowth, GapResults};
use crate::state::time::UtcTime;

/// Alarm bites whose captured trace the report draws, per driveline: the newest.
pub const ALARM_TRACES: u32 = 5;

/// The part of each of the period's drivelines, in order, showing how far on
/// `progress`.
pub(super) fn read(
    reader: &HistoryReader,
    period: &Period,
    progress: &mut Progress,
) -> anyhow::Result<Vec<DrivelineData>> {
    let mut read = Vec::with_capacity(period.drivelines.len());
    for (index, name) in period.drivelines.iter().enumerate() {
        let of = period.drivelines.len();
        progress.update(|| format!("report: {name} ({} of {of})", index + 1));
        let setting = period.setting(name);
        let saved = period
            .state
            .drivelines
            .iter()
            .find(|d| &d.name == name)
            .and_then(|d| d.gap_trend.as_deref());
        read.push(data::read(
            reader,
            name,
            (period.since, period.until),
            (setting, saved),
            progress,
        )?);
    }
    Ok(read)
}

/// The drivelines' heading and summary table: per driveline, its bites, TAF, state
/// now and gap.
pub(super) fn summary(period: &Period, read: &[DrivelineData], blocks: &mut Vec<Block>) {
    blocks.push(Block::Heading(2, "Drivelines".into()));
    blocks.push(Block::Text(
        "TAF figures are of clean windows (degraded ones left out); \"now\" is the \
         state a restart would restore; the gap is the last estimate in the period \
         with its 90% interval and coupling (model index, 0 = motor side), its trend \
         the least-squares slope over the four weeks before the period's end \
         (deprecated: the growth replaces it); the growth (90% interval) and the date \
         the gap is expected to reach its alarm threshold (90% interval, UTC) are the \
         wear trend's after that estimate. Rows by the expected date, soonest first \
         (none last)."
            .into(),
    ));
    let mut rows: Vec<(Option<i64>, Vec<String>)> = period
        .drivelines
        .iter()
        .zip(read)
        .map(|(name, data)| {
            let date = last_gap(data).and_then(|g| g.forecast?.date_unix_ms);
            (date, summary_row(period, name, data))
        })
        .collect();
    // Stable: drivelines without a date keep their order, after the others.
    rows.sort_by_key(|(date, _)| (date.is_none(), *date));
    let rows = rows.into_iter().map(|(_, row)| row).collect();
    blocks.push(Block::Table(
        [
            "driveline",
            "bites",
            "degraded",
            "TAF median",
            "TAF p95",
            "TAF max",
            "wear trend now",
            "TAF alarm",
            "bite counter",
            "gap, mrad",
            "90% interval, mrad",
            "coupling",
            "gap trend, mrad/week",
            "growth, mrad/day (90%)",
            "gap alarm expected (90%)",
        ]
        .map(String::from)
        .to_vec(),
        rows,
    ));
}

/// The bites by product, a table of every driveline's products (rows of drivelines
/// in `read`'s order); nothing when no bite of the period has a product, so reports
/// without a process context stay as they were.
pub(super) fn products(period: &Period, read: &[DrivelineData], blocks: &mut Vec<Block>) {
    let rows: Vec<Vec<String>> = period
        .drivelines
        .iter()
        .zip(read)
        .flat_map(|(name, data)| {
            data.products.iter().map(move |p| {
                vec![
                    name.clone(),
                    p.product.to_string(),
                    p.bites.to_string(),
                    p.not_pooled.to_string(),
                    fmt(p.taf_mean, 3),
                    fmt(p.taf_max, 3),
                    fmt(p.static_torque_mean_knm, 1),
                    fmt(p.gap_mean_mrad, 2),
                ]
            })
        })
        .collect();
    if rows.is_empty() {
        return;
    }
    blocks.push(Block::Heading(3, "Bites by product".into()));
    blocks.push(Block::Text(format!(
        "Each driveline's bites in the period by the product code the PLC gave          (drivelines[].context; bites without one left out; at most {} products per          driveline, those with the most bites): bites not pooled into the wear trend (the          mill's state or speed), the TAF and static torque of the clean bites, and the          mean of the wear trend's gap after the product's pooled bites.",
        crate::history::summary::MAX_PRODUCTS
    )));
    blocks.push(Block::Table(
        [
            "driveline",
            "product",
            "bites",
            "not pooled",
            "TAF mean",
            "TAF max",
            "static torque mean, kN*m",
            "gap mean, mrad",
        ]
        .map(String::from)
        .to_vec(),
        rows,
    ));
}

/// The gap estimate after `data`'s last bite in the period.
fn last_gap(data: &DrivelineData) -> Option<GapResults> {
    data.last.as_ref().and_then(|b| b.figures.gap)
}

/// Driveline `name`'s row of the summary table, from its `data`.
fn summary_row(period: &Period, name: &str, data: &DrivelineData) -> Vec<String> {
    let now = period.state.drivelines.iter().find(|d| d.name == name);
    let gap = last_gap(data);
    let last_bite = data.last.as_ref().and_then(|b| b.figures.last_bite_unix_ms);
    vec![
        name.to_owned(),
        data.summary.bites.to_string(),
        data.summary.degraded.to_string(),
        fmt(data.summary.taf_median, 3),
        fmt(data.summary.taf_p95, 3),
        fmt(data.summary.taf_max, 3),
        fmt(now.and_then(|d| d.results.wear_trend), 4),
        now.map_or("-".into(), |d| {
            if d.results.taf_alarm {
                "latched".into()
            } else {
                "no".into()
            }
        }),
        now.map_or("-".into(), |d| d.results.bite_counter.to_string()),
        fmt(gap.map(|g| g.gap_mrad), 2),
        gap.map_or("-".into(), |g| {
            format!(
                "{}..{}",
                fmt(Some(g.low_mrad), 2),
                fmt(Some(g.high_mrad), 2)
            )
        }),
        gap.map_or("-".into(), |g| {
            g.coupling
                .map_or_else(|| "undetermined".into(), |c| c.to_string())
        }),
        data.trend
            .as_ref()
            .map_or("-".into(), |t| format!("{:+.3}", t.mrad_per_week)),
        growth_text(gap.and_then(|g| g.growth)),
        match (gap.and_then(|g| g.forecast), last_bite) {
            (Some(forecast), Some(last)) => expected_text(&forecast, UtcTime::from_unix_ms(last)),
            _ => "-".into(),
        },
    ]
}

/// A growth with its 90% interval: `+0.0286 (+0.0257..+0.0314)`, `-` for none.
fn growth_text(growth: Option<GapGrowth>) -> String {
    growth.map_or("-".into(), |g| {
        format!(
            "{:+.4} ({:+.4}..{:+.4})",
            g.mrad_per_day, g.low_mrad_per_day, g.high_mrad_per_day
        )
    })
}

/// When `forecast` (made at the bite of `last_bite`) expects the gap at its alarm:
/// the date with the dates of its 90% interval, `2027-03-14 (2027-03-02..2027-04-01)`
/// (the late end `beyond the horizon` when it has none), or what the forecast says
/// instead (`at the alarm`, `not growing`, `beyond the horizon`, `too few bites`), as
/// the web page says it.
fn expected_text(forecast: &GapForecast, last_bite: UtcTime) -> String {
    let date = |days: f64| last_bite.plus_days(days).to_string()[..10].to_owned();
    match (forecast.state, forecast.days) {
        (ForecastState::Forecast, Some(days)) => format!(
            "{} ({}..{})",
            date(days),
            forecast.days_low.map_or("-".into(), date),
            forecast.days_high.map_or("beyond the horizon".into(), date)
        ),
        (ForecastState::AtAlarm, _) => "at the alarm".into(),
        (ForecastState::NotGrowing, _) => "not growing".into(),
        (ForecastState::BeyondHorizon, _) => "beyond the horizon".into(),
        (ForecastState::TooFewBites, _) => "too few bites".into(),
        (ForecastState::Forecast, None) => "-".into(),
    }
}

/// Driveline `name`'s section, from its `data`: the plot over time, the TAF over
/// static torque, the captured traces of its last alarm bites (read by `reader` from
/// the history `db`).
pub(super) fn section(
    reader: &HistoryReader,
    db: &Path,
    period: &Period,
    (name, data): (&str, &DrivelineData),
    blocks: &mut Vec<Block>,
) -> anyhow::Result<()> {
    blocks.push(Block::Heading(3, name.to_owned()));
    over_time(period, name, data, blocks)?;
    gap_over_time(period, name, data, blocks)?;
    taf_over_torque(name, data, blocks)?;
    fatigue(reader, period, name, blocks)?;
    alarm_traces(reader, db, period, name, blocks)
}

/// Days of damage per day the report's fatigue section lists.
const FATIGUE_DAYS: u32 = 14;

/// `name`'s fatigue ledger as the history keeps it (nothing without one): each
/// component's life used and installation (the state a restart continues), the
/// resets, and the damage per UTC day of the last days with bites.
fn fatigue(
    reader: &HistoryReader,
    period: &Period,
    name: &str,
    blocks: &mut Vec<Block>,
) -> anyhow::Result<()> {
    let Some(saved) = period
        .state
        .drivelines
        .iter()
        .find(|d| d.name == name)
        .and_then(|d| d.fatigue_ledger.as_deref())
    else {
        return Ok(());
    };
    let lives = crate::analysis::fatigue_ledger::saved_lives(saved)?;
    blocks.push(Block::Text(format!(
        "Fatigue ledger of {name} (the service's count of the whole torque stream, as a \
         restart continues it): life used since each component's installation (Miner's \
         sum; 1 is its S-N curve's failure)."
    )));
    blocks.push(Block::Table(
        ["component", "life used", "installed (UTC)"]
            .map(String::from)
            .to_vec(),
        lives
            .iter()
            .map(|c| {
                vec![
                    c.name.clone(),
                    format!("{:.4}%", 100.0 * c.life_used),
                    UtcTime::from_unix_ms(c.installed_unix_ms).to_string(),
                ]
            })
            .collect(),
    ));
    let history = reader.fatigue(name, FATIGUE_DAYS)?;
    if !history.resets.is_empty() {
        blocks.push(Block::Table(
            ["reset (UTC)", "component", "life used until then", "by"]
                .map(String::from)
                .to_vec(),
            history
                .resets
                .iter()
                .map(|r| {
                    vec![
                        r.time.clone(),
                        r.component.clone(),
                        format!("{:.4}%", 100.0 * r.life_used),
                        r.origin.clone(),
                    ]
                })
                .collect(),
        ));
    }
    let limit = crate::analysis::fatigue_ledger::saved_life_limit(saved)?;
    life_over_time(reader, period, name, limit, blocks)?;
    damage_over_taf(reader, period, name, blocks)?;
    if !history.days.is_empty() {
        blocks.push(Block::Text(format!(
            "Damage per UTC day (the last {FATIGUE_DAYS} days with bites; untrusted \
             bites' damage left out)."
        )));
        blocks.push(Block::Table(
            ["day", "component", "damage", "bites"]
                .map(String::from)
                .to_vec(),
            history
                .days
                .iter()
                .map(|d| {
                    vec![
                        d.day.clone(),
                        d.component.clone(),
                        format!("{:.3e}", d.damage),
                        d.bites.to_string(),
                    ]
                })
                .collect(),
        ));
    }
    Ok(())
}

/// The plot of `name`'s fatigue components' life used over time (the last bite of
/// each of [`PLOT_BUCKETS`] time buckets), with the life limit `limit` the ledger
/// was saved with and a mark at each reset; a sentence instead when the period has
/// no bite of the ledger.
fn life_over_time(
    reader: &HistoryReader,
    period: &Period,
    name: &str,
    limit: Option<f64>,
    blocks: &mut Vec<Block>,
) -> anyhow::Result<()> {
    let series = reader.fatigue_series(name, period.since, period.until, PLOT_BUCKETS)?;
    if series.points.is_empty() {
        blocks.push(Block::Text(
            "No bite of the fatigue ledger in the period: no plot of the life used.".into(),
        ));
        return Ok(());
    }
    let axis = &period.axis;
    let lines: Vec<(&str, Vec<(f64, f64)>)> = series
        .components
        .iter()
        .enumerate()
        .map(|(k, label)| {
            let line = series
                .points
                .iter()
                .filter_map(|p| Some((axis.x_of(p.time), 100.0 * p.life_used[k]?)))
                .collect();
            (label.as_str(), line)
        })
        .collect();
    let marks: Vec<(f64, String)> = series
        .resets
        .iter()
        .filter_map(|r| Some((axis.x(&r.time)?, format!("{} replaced", r.component))))
        .collect();
    let panel = |y_label, thresholds| TimePanel {
        y_label,
        lines: lines.clone(),
        bands: Vec::new(),
        thresholds,
        marks: marks.clone(),
        legend_lower_right: false,
    };
    let mut panels = vec![panel(
        "life used, % of the S-N life",
        limit.map_or_else(Vec::new, |l| vec![("life limit, %", 100.0 * l)]),
    )];
    // Lives far under the limit are a flat line at 0 beside it: a second panel
    // zoomed to them.
    let most = lines
        .iter()
        .flat_map(|(_, line)| line.iter().map(|(_, y)| *y))
        .fold(0.0, f64::max);
    let zoomed = limit.is_some_and(|l| most < 10.0 * l);
    if zoomed {
        panels.push(panel("life used, % (zoomed to the lives)", Vec::new()));
    }
    let file = format!("{}-fatigue-life.svg", file_stem(name));
    let title = format!("{name}: fatigue life used per component over time");
    blocks.push(Block::Figure {
        svg: time_svg(&title, axis, &panels)?,
        file,
        title,
    });
    blocks.push(Block::Text(format!(
        "Each component's life used after the last bite of each time bucket ({} \
         buckets with bites); a replaced component's line starts again at 0 at its \
         reset (marked).{} {}",
        series.points.len(),
        if zoomed {
            " Below, the same lines zoomed to the lives: under a tenth of the limit."
        } else {
            ""
        },
        limit.map_or_else(
            || "The ledger was saved without its life limit: none drawn.".to_owned(),
            |l| format!("The life limit: {:.0}%.", 100.0 * l)
        )
    )));
    Ok(())
}

/// The plot of `name`'s fatigue components' damage per bite over the bite's TAF
/// (trusted bites: a clean window, the damage recorded), binned as read in two
/// passes over the period's bites (the ranges, then the cells).
fn damage_over_taf(
    reader: &HistoryReader,
    period: &Period,
    name: &str,
    blocks: &mut Vec<Block>,
) -> anyhow::Result<()> {
    let (mut tafs, mut damages) = ((f64::MAX, f64::MIN), (f64::MAX, f64::MIN));
    reader.for_each_fatigue_damage::<anyhow::Error>(name, period.since, period.until, |p| {
        tafs = (tafs.0.min(p.taf), tafs.1.max(p.taf));
        if p.damage > 0.0 {
            damages = (damages.0.min(p.damage), damages.1.max(p.damage));
        }
        Ok(())
    })?;
    if tafs.0 > tafs.1 || damages.0 > damages.1 {
        blocks.push(Block::Text(
            "No trusted bite with fatigue damage in the period: no plot of the damage \
             per bite."
                .into(),
        ));
        return Ok(());
    }
    // A tenth of a decade of room, half a decade each way for a single value.
    let pad = if damages.1 > damages.0 {
        10f64.powf(0.1)
    } else {
        10f64.powf(0.5)
    };
    let mut grid = DamageGrid::new(
        range([tafs.0, tafs.1].into_iter()),
        (damages.0 / pad, damages.1 * pad),
    );
    reader.for_each_fatigue_damage::<anyhow::Error>(name, period.since, period.until, |p| {
        grid.add(p);
        Ok(())
    })?;
    // The components' names in index order: those of the period's last bite.
    let names = reader
        .fatigue_series(name, period.since, period.until, 1)?
        .components;
    let file = format!("{}-fatigue-damage.svg", file_stem(name));
    let title = format!("{name}: fatigue damage per bite over the bite's TAF");
    blocks.push(Block::Figure {
        svg: damage_svg(&title, &grid, &names)?,
        file,
        title,
    });
    blocks.push(Block::Text(format!(
        "{} component damages of trusted bites (a clean window, the torque since the \
         bite before not cut), a dot per cell of the TAF and the damage's logarithm, \
         darker for more bites; {} with no damage (every cycle under the endurance \
         limit) not drawn.",
        grid.drawn, grid.without_damage
    )));
    Ok(())
}

/// The plot of `name`'s TAF and wear over time, with what it shows.
fn over_time(
    period: &Period,
    name: &str,
    data: &DrivelineData,
    blocks: &mut Vec<Block>,
) -> anyhow::Result<()> {
    let file = format!("{}-time.svg", file_stem(name));
    let title = format!("{name}: TAF and wear over time");
    blocks.push(Block::Figure {
        svg: time_svg(&title, &period.axis, &time_panels(period, data))?,
        file,
        title,
    });
    if let Some(bucket) = data.wear.first() {
        blocks.push(Block::Text(format!(
            "Per time bucket of {}: the range of the bites' values shaded, the mean \
             TAF and the wear trend; on the gap's plot the gap estimate after the \
             bucket's last bite.",
            duration_text(bucket.end.unix_ms() - bucket.start.unix_ms())
        )));
    }
    if data.index.is_empty() {
        blocks.push(Block::Text(
            "No wear index: the driveline has no model (drivelines[].model).".into(),
        ));
    }
    Ok(())
}

/// The plot of `name`'s gap estimates over time with the forecast after its last
/// bite (the axis reaching the cone's end), with what it shows; none when the history
/// holds no gap estimate of it in the period.
fn gap_over_time(
    period: &Period,
    name: &str,
    data: &DrivelineData,
    blocks: &mut Vec<Block>,
) -> anyhow::Result<()> {
    let forecast = data.forecast.as_ref().ok().and_then(Option::as_ref);
    let cone_end = forecast.and_then(|f| {
        let cone = f.gap.forecast?.cone?;
        Some(
            f.last_bite
                .plus_days(cone.points[cone.points.len() - 1].days),
        )
    });
    let axis = TimeAxis::new(
        period.start,
        cone_end.map_or(period.end, |end| end.max(period.end)),
    );
    let Some(panel) = gap_panel(&axis, data, forecast) else {
        return Ok(());
    };
    let file = format!("{}-gap.svg", file_stem(name));
    let title = format!("{name}: opened gap over time and its forecast");
    blocks.push(Block::Figure {
        svg: time_svg(&title, &axis, &[panel])?,
        file,
        title,
    });
    blocks.push(Block::Text(match (&data.forecast, forecast) {
        (Err(why), _) => format!("No forecast drawn: {why}."),
        (Ok(_), None) => "No forecast drawn: the history keeps no wear trend of the \
             driveline after a bite in the period."
            .into(),
        (Ok(_), Some(forecast)) => forecast_text(forecast),
    }));
    Ok(())
}

/// What the forecast `forecast` says, under its figure.
fn forecast_text(forecast: &Forecast) -> String {
    let gap = &forecast.gap;
    let said = gap.forecast.map_or("no forecast".into(), |f| {
        let expected = expected_text(&f, forecast.last_bite);
        match (f.state, f.days) {
            (ForecastState::Forecast, Some(days)) => {
                format!("alarm expected {expected}, in {days:.0} days")
            }
            _ => format!("no alarm date: {expected}"),
        }
    });
    format!(
        "The wear trend after the bite of {} (as the history saved it), for the \
         gap alarm at {} mrad (the last run's threshold): gap {:.2} mrad ({:.2}..{:.2}), \
         growth {} mrad/day; {said}. Drawn: the gap estimates per time bucket with \
         their 90% interval, the fitted growth line over (at most) the four weeks \
         before the last bite, the forecast's mean and 90% band (orange) up to beyond \
         the late end of the forecast (or the 365-day horizon), the alarm line and the \
         expected date.",
        forecast.last_bite,
        forecast.alarm_mrad,
        gap.gap_mrad,
        gap.low_mrad,
        gap.high_mrad,
        growth_text(gap.growth),
    )
}

/// The gap panel on `axis`: the estimates per bucket of `data` with their interval,
/// the thresholds and, with a `forecast`, its fitted line, cone and date; `None`
/// without a gap estimate in the period.
fn gap_panel(
    axis: &TimeAxis,
    data: &DrivelineData,
    forecast: Option<&Forecast>,
) -> Option<TimePanel<'static>> {
    let gap: Vec<(f64, f64, f64, f64)> = data
        .wear
        .iter()
        .filter_map(|p| {
            Some((
                axis.middle(p.start, p.end),
                p.gap_mrad?,
                p.gap_low_mrad?,
                p.gap_high_mrad?,
            ))
        })
        .collect();
    if gap.is_empty() {
        return None;
    }
    let mut panel = TimePanel {
        y_label: "gap, mrad",
        lines: vec![("gap estimate", gap.iter().map(|g| (g.0, g.1)).collect())],
        bands: vec![(
            "90% interval (lowest..highest)",
            gap.iter().map(|g| (g.0, g.2, g.3)).collect(),
        )],
        thresholds: data
            .setting
            .as_ref()
            .map(|s| {
                [("warning", s.gap_warning_mrad), ("alarm", s.gap_alarm_mrad)]
                    .into_iter()
                    .filter_map(|(label, v)| Some((label, v?)))
                    .collect()
            })
            .unwrap_or_default(),
        marks: Vec::new(),
        legend_lower_right: false,
    };
    let Some(forecast) = forecast else {
        return Some(panel);
    };
    let (Some(growth), Some(predicted)) = (forecast.gap.growth, forecast.gap.forecast) else {
        return Some(panel);
    };
    let x = |days: f64| axis.x_of(forecast.last_bite.plus_days(days));
    if let Some(cone) = predicted.cone {
        // The estimates sit at the left, the cone widens to the right from the gap
        // up: the lower right corner is the free one.
        panel.legend_lower_right = true;
        let gap_mrad = forecast.gap.gap_mrad;
        panel.lines.push((
            "fitted growth",
            vec![
                (
                    x(-cone.back_days),
                    gap_mrad - growth.mrad_per_day * cone.back_days,
                ),
                (x(0.0), gap_mrad),
            ],
        ));
        panel.lines.push((
            "forecast",
            cone.points
                .iter()
                .map(|p| (x(p.days), p.mean_mrad))
                .collect(),
        ));
        panel.bands.push((
            "forecast 90% band",
            cone.points
                .iter()
                .map(|p| (x(p.days), p.low_mrad, p.high_mrad))
                .collect(),
        ));
    }
    if let (ForecastState::Forecast, Some(days)) = (predicted.state, predicted.days) {
        panel.marks.push((
            x(days),
            format!(
                "alarm expected {}",
                expected_text(&predicted, forecast.last_bite)
            ),
        ));
    }
    Some(panel)
}

/// The panels of a driveline's plot over time: the TAF and the wear index (with a
/// model); the gap has a plot of its own ([`gap_over_time`]).
fn time_panels(period: &Period, data: &DrivelineData) -> Vec<TimePanel<'static>> {
    let setting = data.setting.as_ref();
    let middle = |start: UtcTime, end: UtcTime| period.axis.middle(start, end);
    let mut panels = vec![TimePanel {
        y_label: "TAF",
        lines: vec![(
            "TAF mean",
            data.wear
                .iter()
                .filter_map(|p| Some((middle(p.start, p.end), p.taf_mean?)))
                .collect(),
        )],
        bands: vec![(
            "TAF min..max",
            data.wear
                .iter()
                .filter_map(|p| Some((middle(p.start, p.end), p.taf_min?, p.taf_max?)))
                .collect(),
        )],
        thresholds: setting
            .map(|s| vec![("warning", s.taf_warning), ("alarm", s.taf_alarm)])
            .unwrap_or_default(),
        marks: Vec::new(),
        legend_lower_right: false,
    }];
    if !data.index.is_empty() {
        panels.push(TimePanel {
            y_label: "wear index",
            lines: vec![(
                "wear trend",
                data.index
                    .iter()
                    .filter_map(|p| Some((middle(p.start, p.end), p.trend?)))
                    .collect(),
            )],
            bands: vec![(
                "wear index min..max",
                data.index
                    .iter()
                    .map(|p| (middle(p.start, p.end), p.index_min, p.index_max))
                    .collect(),
            )],
            thresholds: Vec::new(),
            marks: Vec::new(),
            legend_lower_right: false,
        });
    }
    panels
}

/// The plot of `name`'s bites' TAF over static torque, with the wear map's curves
/// (or why there are none).
fn taf_over_torque(
    name: &str,
    data: &DrivelineData,
    blocks: &mut Vec<Block>,
) -> anyhow::Result<()> {
    let curves = match &data.curves {
        Ok(curves) => curves.as_slice(),
        Err(why) => {
            blocks.push(Block::Text(format!("No wear map curves: {why}.")));
            &[]
        }
    };
    let file = format!("{}-taf.svg", file_stem(name));
    let title = format!("{name}: TAF over static torque");
    blocks.push(Block::Figure {
        svg: taf_svg(&title, &data.grid, data.setting.as_ref(), curves)?,
        file,
        title,
    });
    if data.grid.outside > 0 {
        blocks.push(Block::Text(format!(
            "{} bites lie outside the plot (a degraded window's TAF beyond the clean \
             bites' range).",
            data.grid.outside
        )));
    }
    Ok(())
}

/// The captured traces of `name`'s last [`ALARM_TRACES`] alarm bites in the period,
/// read one capture at a time from the history `db`.
fn alarm_traces(
    reader: &HistoryReader,
    db: &Path,
    period: &Period,
    name: &str,
    blocks: &mut Vec<Block>,
) -> anyhow::Result<()> {
    let rows = reader.alarm_bite_captures(name, period.since, period.until, ALARM_TRACES)?;
    if rows.is_empty() {
        return Ok(());
    }
    blocks.push(Block::Text(format!(
        "The captured torque of the last {} alarm bites (at most {ALARM_TRACES} per \
         driveline, newest first), each reduced to the lowest and highest sample of \
         450 columns; `millgate capture export --db {} --id ID --format csv --out DIR` \
         (or `parquet`) writes a capture's samples.",
        rows.len(),
        db.display()
    )));
    for row in rows {
        let (id, bite, time) = (row.id, row.bite_counter, row.bite_time.clone());
        let capture = reader.capture_of(row)?;
        let title = format!(
            "{name}: alarm bite {} at {} UTC, capture {id}",
            bite.map_or("-".into(), |b| b.to_string()),
            time.unwrap_or_default()
        );
        blocks.push(Block::Figure {
            svg: trace_svg(&title, &capture)?,
            file: format!("{}-capture-{id}.svg", file_stem(name)),
            title,
        });
    }
    Ok(())
}

/// `ms` as a duration a reader takes in: "6 h", "2.5 days", "40 s".
fn duration_text(ms: i64) -> String {
    let s = ms as f64 / 1000.0;
    match s {
        s if s < 120.0 => format!("{s:.0} s"),
        s if s < 7200.0 => format!("{:.0} min", s / 60.0),
        s if s < 172_800.0 => format!("{:.1} h", s / 3600.0),
        s => format!("{:.1} days", s / 86_400.0),
    }
}

/// A file-name-safe form of a driveline name.
fn file_stem(name: &str) -> String {
    name.chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' || c == '_' {
                c
            } else {
                '_'
            }
        })
        .collect()
}
