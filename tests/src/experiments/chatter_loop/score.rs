//! The loop's scores and the README's closed-loop table; a run's plot.

use millgate_sim::tandem::control::SlowDownEvent;

use super::run::run_loop;
use super::{Detector, LoopPlan, Mill, Outcome, Run, Scenario};
use crate::experiments::chatter_eval::{parallel, quartiles};

/// One detector's closed-loop figures.
#[derive(Debug, Clone, PartialEq)]
pub struct LoopScore {
    /// The detector.
    pub detector: Detector,
    /// Accelerated runs that developed chatter with the loop closed.
    pub developed: usize,
    /// Accelerated runs.
    pub accelerated: usize,
    /// Slow-downs in the accelerated runs that did not develop chatter.
    pub events: Vec<SlowDownEvent>,
    /// Per event, the time below the speed at the request, s: until it was back, or
    /// the next request, or the run's end.
    pub reduced_s: Vec<f64>,
    /// False slow-downs in the stable runs' scored time, and those hours.
    pub false_stable: (usize, f64),
    /// Weld runs with a slow-down in their scored time, and weld runs.
    pub false_welds: (usize, usize),
    /// Ramps with a weld before the critical speed that developed chatter with the
    /// loop closed, and those ramps.
    pub weld_ramps: (usize, usize),
    /// Whether the monitor read the weld bit.
    pub weld_bit: bool,
}

/// The time each event of `outcome` spent below its speed at the request, s.
pub fn reduced_times(outcome: &Outcome) -> Vec<f64> {
    outcome
        .events
        .iter()
        .enumerate()
        .map(|(k, event)| {
            let end = outcome
                .events
                .get(k + 1)
                .map_or(outcome.duration_s, |next| next.requested_s);
            event.recovered_s.unwrap_or(end).min(end) - event.requested_s
        })
        .collect()
}

/// Every closed-loop figure of `detector` over `runs` (the open loop's in
/// [`open_loop_developed`]).
pub fn score(
    plan: &LoopPlan,
    mills: &[Mill],
    runs: &[Run],
    detector: Detector,
) -> anyhow::Result<(LoopScore, Vec<Outcome>)> {
    let outcomes = parallel(plan.threads, runs, |run| {
        run_loop(plan, &mills[run.mill], run, Some(detector), false)
    })?;
    let mut score = LoopScore {
        detector,
        developed: 0,
        accelerated: 0,
        events: Vec::new(),
        reduced_s: Vec::new(),
        false_stable: (0, 0.0),
        false_welds: (0, 0),
        weld_ramps: (0, 0),
        weld_bit: plan.weld_bit.is_some(),
    };
    for (run, outcome) in runs.iter().zip(&outcomes) {
        match run.scenario {
            Scenario::Accelerated { .. } => {
                score.accelerated += 1;
                if outcome.developed_s.is_some() {
                    score.developed += 1;
                } else {
                    score.events.extend_from_slice(&outcome.events);
                    score.reduced_s.extend(reduced_times(outcome));
                }
            }
            Scenario::Stable { .. } => {
                score.false_stable.0 += outcome.events_from(plan.settle_s);
                score.false_stable.1 += (outcome.duration_s - plan.settle_s) / 3600.0;
            }
            Scenario::Weld { .. } => {
                score.false_welds.0 += usize::from(outcome.events_from(plan.settle_s) > 0);
                score.false_welds.1 += 1;
            }
            Scenario::WeldRamp { .. } => {
                score.weld_ramps.0 += usize::from(outcome.developed_s.is_some());
                score.weld_ramps.1 += 1;
            }
        }
    }
    Ok((score, outcomes))
}

/// Accelerated runs of `runs` that develop chatter with the request ignored, and how
/// many accelerated runs there are.
pub fn open_loop_developed(
    plan: &LoopPlan,
    mills: &[Mill],
    runs: &[Run],
) -> anyhow::Result<(usize, usize)> {
    let accelerated: Vec<&Run> = runs
        .iter()
        .filter(|r| matches!(r.scenario, Scenario::Accelerated { .. }))
        .collect();
    let outcomes = parallel(plan.threads, &accelerated, |run| {
        run_loop(plan, &mills[run.mill], run, None, false)
    })?;
    Ok((
        outcomes.iter().filter(|o| o.developed_s.is_some()).count(),
        outcomes.len(),
    ))
}

/// The README's table row of `score` (open loop: `open` developed of `of`).
pub fn table_row(score: &LoopScore, open: (usize, usize)) -> String {
    let shed: Vec<f64> = score.events.iter().map(|e| e.shed_m_s() * 60.0).collect();
    let (s1, s2, s3) = quartiles(&shed);
    let (r1, r2, r3) = quartiles(&score.reduced_s);
    let per_run = score.events.len() as f64 / (score.accelerated - score.developed).max(1) as f64;
    let max_shed = shed.iter().copied().fold(0.0, f64::max);
    format!(
        "| {}{} | {}/{} | {}/{} | {} ({per_run:.1} per run) | {s2:.0} [{s1:.0}, {s3:.0}], max {max_shed:.0} | {r2:.1} [{r1:.1}, {r3:.1}] | {:.1} ({} in {:.2} h) | {}/{} | {}/{} |",
        score.detector.name(),
        if score.weld_bit { ", weld bit" } else { "" },
        score.developed,
        score.accelerated,
        open.0,
        open.1,
        score.events.len(),
        score.false_stable.0 as f64 / score.false_stable.1.max(1e-9),
        score.false_stable.0,
        score.false_stable.1,
        score.false_welds.0,
        score.false_welds.1,
        score.weld_ramps.0,
        score.weld_ramps.1,
    )
}

/// What a weld does to the band gain's figure with the loop open (the request
/// ignored): what the weld hold's settle time and factor are chosen from.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WeldTransient {
    /// Largest gain ratio from the weld's start on, while the weld is in the mill.
    pub peak_during: f64,
    /// Largest gain ratio after the weld has left the mill.
    pub peak_after: f64,
    /// Time from the weld's end to the last window at or above the alarm level, s
    /// (`None`: none after the weld).
    pub last_alarm_after_s: Option<f64>,
}

/// The [`WeldTransient`] of each weld run of `runs` (stable at the top speed), open
/// loop with the band gain's figure.
pub fn weld_transients(
    plan: &LoopPlan,
    mills: &[Mill],
    runs: &[Run],
) -> anyhow::Result<Vec<WeldTransient>> {
    let welds: Vec<&Run> = runs
        .iter()
        .filter(|r| matches!(r.scenario, Scenario::Weld { .. }))
        .collect();
    parallel(plan.threads, &welds, |run| {
        let outcome = run_loop(plan, &mills[run.mill], run, None, true)?;
        let burst = run.scenario.weld().expect("a weld run");
        let end_s = burst.time_s + burst.duration_s;
        let mut transient = WeldTransient {
            peak_during: 0.0,
            peak_after: 0.0,
            last_alarm_after_s: None,
        };
        for row in &outcome.trace {
            let Some(level) = row.level.filter(|_| row.t_s >= burst.time_s) else {
                continue;
            };
            if row.t_s <= end_s {
                transient.peak_during = transient.peak_during.max(level);
            } else {
                transient.peak_after = transient.peak_after.max(level);
            }
            if level >= 1.0 {
                transient.last_alarm_after_s = Some(row.t_s - end_s);
            }
        }
        Ok(transient)
    })
}

/// The table's header.
pub const TABLE_HEADER: &str = "| detector | developed, closed loop | developed, open loop | slow-downs in runs kept below developed | speed shed per slow-down, m/min: median [IQR] | time below the speed at the request, s: median [IQR] | false slow-downs / h at the top speed | welds with a slow-down | ramps with a weld 0-3 s before the critical speed: developed, closed loop |\n|---|---|---|---|---|---|---|---|---|";

/// The SVG of a traced closed-loop run: speed (m/min, the critical speed dashed as a
/// flat line), the detector's figure over its alarm level, the request, and the
/// chatter amplitude (tension swing over its developed limit; 1 = developed).
pub fn plot(outcome: &Outcome, critical_m_min: f64, title: &str) -> anyhow::Result<String> {
    use millgate_sim::plot::time_series_svg;
    let time_s: Vec<f64> = outcome.trace.iter().map(|r| r.t_s).collect();
    let speed = vec![
        (
            "exit speed".to_owned(),
            outcome.trace.iter().map(|r| Some(r.speed_m_min)).collect(),
        ),
        (
            "critical speed".to_owned(),
            outcome.trace.iter().map(|_| Some(critical_m_min)).collect(),
        ),
    ];
    let level = vec![(
        "gain ratio (1 = alarm)".to_owned(),
        outcome.trace.iter().map(|r| r.level).collect(),
    )];
    let request = vec![(
        "slow-down request seen by the PLC".to_owned(),
        outcome
            .trace
            .iter()
            .map(|r| Some(if r.request { 1.0 } else { 0.0 }))
            .collect(),
    )];
    let swing = vec![(
        "tension swing / developed limit".to_owned(),
        outcome.trace.iter().map(|r| Some(r.swing)).collect(),
    )];
    Ok(time_series_svg(
        title,
        &time_s,
        &[
            ("speed, m/min", speed),
            ("gain ratio", level),
            ("request", request),
            ("chatter amplitude", swing),
        ],
    )?)
}

/// The weld runs of one way of reading the weld tracking (the band gain, the loop
/// closed): [`weld_bits_row`].
#[derive(Debug, Clone, PartialEq)]
pub struct WeldBitsRow {
    /// What the monitor read: `none`, `mill bit`, `stand bits`.
    pub bits: &'static str,
    /// Weld runs at the top speed with a slow-down in their scored time, and weld runs.
    pub false_welds: (usize, usize),
    /// Ramps with a weld before the critical speed that developed chatter with the
    /// loop closed, and those ramps.
    pub ramps_developed: (usize, usize),
    /// Per ramp that developed chatter with the loop open: its open-loop development
    /// time minus the closed loop's first request, s (`None`: no request before the
    /// run's end).
    pub leads_s: Vec<Option<f64>>,
}

/// The [`WeldBitsRow`] of `plan` (its weld bits and hold) over the weld runs of `runs`,
/// `open_developed_s` per run (the open loop's development time of each weld ramp,
/// [`open_loop_weld_ramps`]; `None` for the others).
pub fn weld_bits_row(
    bits: &'static str,
    plan: &LoopPlan,
    mills: &[Mill],
    runs: &[Run],
    open_developed_s: &[Option<f64>],
) -> anyhow::Result<WeldBitsRow> {
    let (score, outcomes) = score(plan, mills, runs, Detector::BandGain)?;
    let leads_s = runs
        .iter()
        .zip(&outcomes)
        .zip(open_developed_s)
        .filter(|((run, _), _)| matches!(run.scenario, Scenario::WeldRamp { .. }))
        .filter_map(|((_, outcome), open)| {
            let open = (*open)?;
            Some(outcome.events.first().map(|e| open - e.requested_s))
        })
        .collect();
    Ok(WeldBitsRow {
        bits,
        false_welds: score.false_welds,
        ramps_developed: score.weld_ramps,
        leads_s,
    })
}

/// Per run of `runs`, for each weld ramp the time its chatter developed with the loop
/// open (the request ignored), `None` when it did not or for another run.
pub fn open_loop_weld_ramps(
    plan: &LoopPlan,
    mills: &[Mill],
    runs: &[Run],
) -> anyhow::Result<Vec<Option<f64>>> {
    parallel(plan.threads, runs, |run| {
        if !matches!(run.scenario, Scenario::WeldRamp { .. }) {
            return Ok(None);
        }
        Ok(run_loop(plan, &mills[run.mill], run, None, false)?.developed_s)
    })
}

/// The table of [`WeldBitsRow`]s: a row each, the leads as median [min, max].
pub fn weld_bits_table(rows: &[WeldBitsRow]) -> String {
    let mut out = String::from(
        "| weld bits read | welds at the top speed with a slow-down | ramps with a weld 0-3 s before the critical speed: developed, closed loop | ramps requested before chatter developed (open loop) | lead of the request, s: median [min, max] |\n|---|---|---|---|---|\n",
    );
    for row in rows {
        let leads: Vec<f64> = row.leads_s.iter().flatten().copied().collect();
        let lead = if leads.is_empty() {
            "-".to_owned()
        } else {
            let (_, median, _) = quartiles(&leads);
            let min = leads.iter().copied().fold(f64::INFINITY, f64::min);
            let max = leads.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            format!("{median:.1} [{min:.1}, {max:.1}]")
        };
        out += &format!(
            "| {} | {}/{} | {}/{} | {}/{} | {lead} |\n",
            row.bits,
            row.false_welds.0,
            row.false_welds.1,
            row.ramps_developed.0,
            row.ramps_developed.1,
            leads.iter().filter(|&&lead| lead > 0.0).count(),
            row.leads_s.len(),
        );
    }
    out
}
