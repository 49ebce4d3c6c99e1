//! A driveline's bite reports into the published results and the history, under the
//! board's lock: the figures (none of a degraded bite), the wear trend, the gap
//! estimate, the bite's record with its capture, and the warning and alarm changes.

use millgate_dsp::transient::TransientQuality;

use super::analyzer::DrivelineAnalyzer;
use super::report::BiteReport;
use crate::analysis::fatigue_ledger::LedgerBite;
use crate::analysis::wear;
use crate::state::board::Board;
use crate::state::captures::{CapturedBite, KeepClass};
use crate::state::commands::CommandOrigin;
use crate::state::context::BiteGate;
use crate::state::events::{
    AlarmEvent, AlarmKind, AlarmRecord, BiteRecord, FatigueResetRecord, HistoryEvent, PooledBite,
    StateRecord, SubjectResults, WearState,
};
use crate::state::results::{DrivelineResults, GapResults, Results};
use crate::state::time::UtcTime;

impl DrivelineAnalyzer {
    /// Record `report`, a bite of this driveline, in the published results and the
    /// history (the bite, and its warning and alarm changes).
    ///
    /// A degraded bite (its window held a gap, a saturated or a non-finite sample) is
    /// counted and dated, and flagged degraded, but its values are not valid: they are
    /// published with their quality bits clear (registers 0), raise no TAF warning or
    /// alarm, and do not move the wear trend. Nothing computed from data that cannot be
    /// trusted reads as a result.
    ///
    /// `results` and `events` are the board's under its lock: the caller publishes
    /// the bites of the shares that ended together ([`publish_bites`]).
    pub(crate) fn publish(
        &self,
        results: &mut Results,
        events: &mut Vec<HistoryEvent>,
        report: &BiteReport,
    ) {
        let driveline = &mut results.drivelines[report.driveline];
        let was = (driveline.taf_warning, driveline.taf_alarm);
        let time = UtcTime::from_system(report.time);
        let taf = self.publish_figures(driveline, report, time);
        let gap = report
            .gap
            .as_ref()
            .and_then(|gap| Some((self.gap.as_ref()?, gap.trend?)));
        let mut gap_alarms = Vec::new();
        if let Some((monitor, estimate)) = gap {
            let subject = (report.driveline_name.as_str(), time);
            monitor.publish(driveline, &estimate, subject, &mut gap_alarms);
        }
        driveline.restored = false;
        let mut record = bite_record(
            report,
            driveline,
            gap.map(|(monitor, estimate)| monitor.verdict(&estimate)),
        );
        record.fatigue_ledger = self.fatigue_saved();
        let keep = self.keep_class(driveline, taf, &gap_alarms);
        let bite = CapturedBite {
            counter: driveline.bite_counter,
            time,
        };
        events.push(match report.capture(bite, keep) {
            Some(capture) => HistoryEvent::CapturedBite(Box::new(record), Box::new(capture)),
            None => HistoryEvent::Bite(Box::new(record)),
        });
        self.taf_alarms(report, driveline, was, time, events);
        events.extend(gap_alarms);
    }

    /// Count and date `report`, a bite at `time`, in `driveline`'s results and publish
    /// its figures, the TAF warning and alarm and the wear trend (none from a degraded
    /// bite); returns its TAF when it can be trusted.
    fn publish_figures(
        &self,
        driveline: &mut DrivelineResults,
        report: &BiteReport,
        time: UtcTime,
    ) -> Option<f64> {
        let t = &report.transient;
        let valid = !report.degraded;
        let trusted = |value: Option<f64>| value.filter(|_| valid);
        driveline.bite_counter = driveline.bite_counter.wrapping_add(1);
        driveline.degraded_bites = driveline
            .degraded_bites
            .wrapping_add(u32::from(report.degraded));
        driveline.last_bite_unix_ms = Some(time.unix_ms());
        window_figures(driveline, report, valid);
        driveline.last_bite_degraded = report.degraded;
        let taf = trusted(t.taf);
        driveline.taf_warning = taf.is_some_and(|taf| taf >= self.taf_warning);
        driveline.taf_alarm |= taf.is_some_and(|taf| taf >= self.taf_alarm);
        if let Some(ledger) = &report.fatigue {
            driveline.fatigue = Some(ledger.worst);
            driveline.fatigue_components = ledger.components.clone();
            driveline.fatigue_stream_cuts = ledger.stream_cuts;
        }
        driveline.wear_index = trusted(report.wear.map(|wear| wear.index));
        let pooled = gate_figures(driveline, report);
        if let Some(index) = driveline.wear_index.filter(|_| pooled) {
            driveline.wear_trend = Some(wear::next_trend(driveline.wear_trend, index));
        }
        taf
    }

    /// How long the history keeps the capture of a bite with the trusted `taf`, after
    /// which `driveline`'s results are as published with `gap_alarms`.
    fn keep_class(
        &self,
        driveline: &DrivelineResults,
        taf: Option<f64>,
        gap_alarms: &[HistoryEvent],
    ) -> KeepClass {
        let raised_gap_alarm = gap_alarms.iter().any(|event| {
            matches!(event, HistoryEvent::Alarm(a) if a.kind == AlarmKind::GapAlarm && a.event == AlarmEvent::Raised)
        });
        if taf.is_some_and(|taf| taf >= self.taf_alarm) || raised_gap_alarm {
            KeepClass::Important
        } else if driveline.taf_warning || driveline.gap_warning {
            KeepClass::Warning
        } else {
            KeepClass::Ordinary
        }
    }

    /// Into `events`, the TAF warning's change and the TAF alarm's raising by
    /// `report`, a bite at `time`, from the warning and alarm `was` before it to
    /// `driveline`'s now.
    fn taf_alarms(
        &self,
        report: &BiteReport,
        driveline: &DrivelineResults,
        (was_warning, was_alarm): (bool, bool),
        time: UtcTime,
        events: &mut Vec<HistoryEvent>,
    ) {
        let taf = report.transient.taf;
        let alarm = |kind, event, threshold| {
            HistoryEvent::Alarm(AlarmRecord {
                time,
                subject: report.driveline_name.clone(),
                kind,
                event,
                origin: None,
                value: taf,
                threshold: Some(threshold),
            })
        };
        if driveline.taf_warning != was_warning {
            let event = if driveline.taf_warning {
                AlarmEvent::Raised
            } else {
                AlarmEvent::Cleared
            };
            events.push(alarm(AlarmKind::TafWarning, event, self.taf_warning));
        }
        if driveline.taf_alarm && !was_alarm {
            events.push(alarm(
                AlarmKind::TafAlarm,
                AlarmEvent::Raised,
                self.taf_alarm,
            ));
        }
    }

    /// Publish the fatigue ledger's figures `ledger` (restored, or after a component's
    /// reset) and record the driveline's state with the ledger's saved form; with
    /// `reset`, the reset of a component (its index, name and the life it had used)
    /// by `origin` is recorded first.
    pub(crate) fn publish_fatigue(
        &self,
        board: &Board,
        ledger: &LedgerBite,
        reset: Option<(usize, String, f64, CommandOrigin)>,
    ) {
        let saved = self.fatigue_saved();
        board.update_recorded(|results, events| {
            let time = UtcTime::now();
            let driveline = &mut results.drivelines[self.index];
            driveline.fatigue = Some(ledger.worst);
            driveline.fatigue_components = ledger.components.clone();
            driveline.fatigue_stream_cuts = ledger.stream_cuts;
            if let Some((index, component, life_used, origin)) = reset {
                events.push(HistoryEvent::FatigueReset(FatigueResetRecord {
                    time,
                    driveline: self.name.clone(),
                    index,
                    component,
                    life_used,
                    origin,
                }));
            }
            events.push(HistoryEvent::State(StateRecord {
                time,
                subject: self.name.clone(),
                results: SubjectResults::Driveline(Box::new(driveline.clone())),
            }));
            if let Some(saved) = saved {
                events.push(HistoryEvent::FatigueLedger {
                    driveline: self.name.clone(),
                    saved,
                });
            }
        });
    }

    /// Record `estimate` (from maps just installed or a restored trend) in the
    /// results, with the alarm events it makes.
    pub(crate) fn publish_gap(&self, board: &Board, estimate: &GapResults) {
        if let Some(monitor) = &self.gap {
            board.update_recorded(|results, events| {
                let time = UtcTime::now();
                let driveline = &mut results.drivelines[self.index];
                monitor.publish(driveline, estimate, (self.name.as_str(), time), events);
                events.push(HistoryEvent::State(StateRecord {
                    time,
                    subject: self.name.clone(),
                    results: SubjectResults::Driveline(Box::new(driveline.clone())),
                }));
            });
        }
    }
}

/// Publish `bites` (each with its driveline's analyser) in one change of `board`:
/// one update of the results, their history records enqueued together (one commit),
/// one wake-up of the outputs (one PLC write carries them all). Each is logged and
/// sent to the subscribers of `subscribers` (none listening is fine: the demo and
/// tests subscribe, the service need not).
pub(crate) fn publish_bites(
    board: &Board,
    subscribers: &tokio::sync::broadcast::Sender<BiteReport>,
    bites: &[(&DrivelineAnalyzer, &BiteReport)],
) {
    if bites.is_empty() {
        return;
    }
    let handed = bites.iter().map(|(_, report)| report.window_complete);
    board.update_bites_recorded(handed, |results, events| {
        for (analyzer, report) in bites {
            analyzer.publish(results, events, report);
        }
    });
    for (_, report) in bites {
        log_bite(report);
        let _ = subscribers.send((*report).clone());
    }
}

/// The log line of a published bite.
fn log_bite(report: &BiteReport) {
    let trend = report.gap.as_ref().and_then(|gap| gap.trend);
    // Each figure a field of its own type (a number, a bool), left out when the
    // bite has none: `key=value` in the text log, a JSON member in the JSON log.
    tracing::info!(
        driveline = %report.driveline_name,
        static_knm = report.transient.static_torque_knm,
        peak_knm = report.transient.peak_torque_knm,
        taf = report.transient.taf,
        beta1_hz = report.beta_hz.map(|(beta1, _)| beta1),
        beta2_hz = report.beta_hz.map(|(_, beta2)| beta2),
        degraded = report.degraded,
        wear_index = report.wear.map(|wear| wear.index),
        shift_over_linear_s = report.wear.and_then(|wear| wear.shift_excess_s),
        gap_mrad = trend.map(|e| e.gap_mrad),
        gap_low_mrad = trend.map(|e| e.low_mrad),
        gap_high_mrad = trend.map(|e| e.high_mrad),
        gap_coupling = trend.and_then(|e| e.coupling),
        gap_growth_mrad_per_day = trend.and_then(|e| e.growth).map(|g| g.mrad_per_day),
        days_to_gap_alarm = trend.and_then(|e| e.forecast).and_then(|f| f.days),
        "bite"
    );
}

/// Count `report`'s context in `driveline`'s results: its gate (`last_bite_gated`),
/// the gated bites and the invalid contexts; whether the bite is pooled.
fn gate_figures(driveline: &mut DrivelineResults, report: &BiteReport) -> bool {
    let Some(context) = &report.context else {
        return true;
    };
    driveline.last_bite_gated = Some(context.gate);
    match context.gate {
        BiteGate::Pooled => {}
        BiteGate::State => driveline.bites_gated_state += 1,
        BiteGate::Speed => driveline.bites_gated_speed += 1,
    }
    if let Err(error) = &context.context {
        driveline.bites_context_invalid += 1;
        tracing::warn!(driveline = %report.driveline_name, %error, "bite context invalid: not used for the gating");
    }
    context.gate.pooled()
}

/// What `report`'s window measured, as figures of `driveline`: its torques, TAF,
/// periods, natural frequencies and first mode's damping, each only while `valid` (a
/// degraded window's are no values where they are published; the bite's row keeps
/// them).
fn window_figures(driveline: &mut DrivelineResults, report: &BiteReport, valid: bool) {
    let t = &report.transient;
    let trusted = |value: Option<f64>| value.filter(|_| valid);
    driveline.static_torque_knm = trusted(Some(t.static_torque_knm));
    driveline.peak_torque_knm = trusted(Some(t.peak_torque_knm));
    driveline.taf = trusted(t.taf);
    driveline.first_period_s = trusted(t.first_period_s);
    driveline.first_period_shift_s = trusted(t.period_shift_s);
    driveline.beta1_hz = trusted(report.beta_hz.map(|(beta1, _)| beta1));
    driveline.beta2_hz = trusted(report.beta_hz.map(|(_, beta2)| beta2));
    driveline.first_mode_damping = trusted(report.first_mode_damping);
}

/// The history's record of `report` with the driveline's published `state` after it
/// and, when the bite gave a gap estimate, its verdict (what the analysis records;
/// benches store the same).
pub fn bite_record(
    report: &BiteReport,
    state: &DrivelineResults,
    gap_state: Option<WearState>,
) -> BiteRecord {
    let t = &report.transient;
    let reference = report.wear.map(|wear| wear.reference);
    let mut figures = state.clone();
    window_figures(&mut figures, report, true);
    figures.gap = figures.gap.filter(|_| gap_state.is_some());
    BiteRecord {
        driveline: report.driveline_name.clone(),
        channel: report.channel_name.clone(),
        time: UtcTime::from_system(report.time),
        figures,
        second_period_s: t.second_period_s,
        quality: match t.quality {
            TransientQuality::Good => "good",
            TransientQuality::FewCrossings => "few_crossings",
            TransientQuality::LowStatic => "low_static",
        },
        reference_taf: reference.map(|r| r.taf),
        reference_level_knm: reference.map(|r| r.level_knm),
        shift_over_linear_s: report.wear.and_then(|wear| wear.shift_excess_s),
        gap_state,
        gap_trend: report.gap.as_ref().and_then(|gap| gap.saved.clone()),
        fatigue_ledger: None,
        pooled: report.gap.as_ref().map(|gap| {
            let o = gap.observation;
            PooledBite {
                static_torque_knm: o.static_torque_knm,
                taf: o.taf,
                taf_sigma: o.taf_sigma,
                period_shift_s: o.period_shift_s,
                period_shift_sigma_s: o.period_shift_sigma_s,
            }
        }),
        context: report.context.and_then(|context| context.context.ok()),
        state: state.clone(),
    }
}
