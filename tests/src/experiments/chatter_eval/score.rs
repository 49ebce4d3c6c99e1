//! The race's scores: false alarms per hour, warnings before developed chatter, one
//! detector against another, the README's table.

use super::detectors::{alarms, calibrate, scored, Detector, Figure};
use super::{RunKind, RunResult, WINDOW_S};

/// False alarms in one set of stable runs.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct FalseAlarms {
    /// Alarm episodes (a window alarming after one that did not).
    pub episodes: usize,
    /// Scored hours of rolling.
    pub hours: f64,
    /// (index of the run, time s) of each episode's start.
    pub at: Vec<(usize, f64)>,
    /// Largest figure / threshold over the set's windows (amplitude figures only).
    pub peak_ratio: f64,
}

impl FalseAlarms {
    /// Episodes per hour.
    pub fn per_hour(&self) -> f64 {
        self.episodes as f64 / self.hours.max(1e-9)
    }
}

/// One detector's line of the table.
#[derive(Debug, Clone, PartialEq)]
pub struct Score {
    /// The detector.
    pub detector: Detector,
    /// Its thresholds (per stand where it has one per stand).
    pub thresholds: Vec<f64>,
    /// In the held-out runs.
    pub held_out: FalseAlarms,
    /// In the confirmation runs.
    pub confirmation: FalseAlarms,
    /// Ramps that developed chatter.
    pub developed: usize,
    /// Of those, alarmed before developed.
    pub detected: usize,
    /// Developed minus alarm time per detected ramp, s.
    pub lead_s: Vec<f64>,
    /// Alarm minus onset time per detected ramp, s.
    pub after_onset_s: Vec<f64>,
    /// First alarm per ramp (None: none before developed), in ramp order.
    pub first_alarm_s: Vec<Option<f64>>,
}

/// Scores every detector with thresholds `margin` beyond calibration (see
/// [`calibrate`]).
pub fn score(runs: &[RunResult], settle_s: f64, margin: f64) -> Vec<Score> {
    let monitored = runs.iter().any(|r| !r.paper.is_empty());
    Detector::ALL
        .iter()
        .filter(|d| monitored || !d.from_monitor())
        .map(|&detector| {
            let thresholds = calibrate(detector, runs, settle_s, margin);
            let mut score = Score {
                detector,
                thresholds: thresholds.clone(),
                held_out: FalseAlarms::default(),
                confirmation: FalseAlarms::default(),
                developed: 0,
                detected: 0,
                lead_s: Vec::new(),
                after_onset_s: Vec::new(),
                first_alarm_s: Vec::new(),
            };
            let amplitude = matches!(
                detector.figure,
                Figure::BandRms | Figure::BandRmsLong | Figure::BandGain | Figure::BandGainLong
            );
            for (index, run) in runs.iter().enumerate() {
                let times = alarms(detector, run, &thresholds, settle_s);
                let set = match run.scenario.kind {
                    RunKind::Calibration => continue,
                    RunKind::HeldOut => &mut score.held_out,
                    RunKind::Confirmation => &mut score.confirmation,
                    RunKind::Ramp => {
                        let Some(developed) = run.truth.developed_s else {
                            score.first_alarm_s.push(None);
                            continue;
                        };
                        score.developed += 1;
                        let first = times.first().copied().filter(|t| *t <= developed);
                        score.first_alarm_s.push(first);
                        if let Some(alarm) = first {
                            score.detected += 1;
                            score.lead_s.push(developed - alarm);
                            if let Some(onset) = run.truth.onset_s {
                                score.after_onset_s.push(alarm - onset);
                            }
                        }
                        continue;
                    }
                };
                let hop = WINDOW_S / 2.0;
                set.at.extend(
                    times
                        .iter()
                        .enumerate()
                        .filter(|(i, t)| *i == 0 || **t - times[i - 1] > 1.5 * hop)
                        .map(|(_, t)| (index, *t)),
                );
                set.episodes = set.at.len();
                set.hours += (run.scenario.settings.duration_s - settle_s) / 3600.0;
                if amplitude {
                    for (_, figures) in scored(run, settle_s, detector.figures(run)) {
                        for (f, t) in figures.iter().zip(&thresholds) {
                            set.peak_ratio = set.peak_ratio.max(f / t);
                        }
                    }
                }
            }
            score
        })
        .collect()
}

/// One detector's first alarms against another's, ramp by ramp.
#[derive(Debug, Clone, PartialEq)]
pub struct Versus {
    /// Ramps where it alarmed first (or only it did).
    pub earlier: usize,
    /// Same window, or neither alarmed.
    pub same: usize,
    /// Ramps where the other alarmed first (or only the other did).
    pub later: usize,
    /// The other's alarm minus its own, s, where both alarmed.
    pub gained_s: Vec<f64>,
}

impl Versus {
    /// A Markdown row: name, earlier, same, later, median gain.
    pub fn row(&self, name: &str) -> String {
        let (_, median, _) = quartiles(&self.gained_s);
        format!(
            "| {name} | {} | {} | {} | {median:+.2} |",
            self.earlier, self.same, self.later
        )
    }
}

/// `a`'s first alarms against `b`'s, ramp by ramp.
pub fn versus(a: &Score, b: &Score) -> Versus {
    let mut result = Versus {
        earlier: 0,
        same: 0,
        later: 0,
        gained_s: Vec::new(),
    };
    for (a, b) in a.first_alarm_s.iter().zip(&b.first_alarm_s) {
        match (a, b) {
            (Some(a), Some(b)) => {
                result.gained_s.push(b - a);
                if (a - b).abs() < 1e-9 {
                    result.same += 1;
                } else if a < b {
                    result.earlier += 1;
                } else {
                    result.later += 1;
                }
            }
            (Some(_), None) => result.earlier += 1,
            (None, Some(_)) => result.later += 1,
            (None, None) => result.same += 1,
        }
    }
    result
}

/// Median and quartiles (linear interpolation); NaN for no values.
pub fn quartiles(values: &[f64]) -> (f64, f64, f64) {
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    let at = |q: f64| {
        if v.is_empty() {
            return f64::NAN;
        }
        let x = q * (v.len() - 1) as f64;
        let (i, frac) = (x.floor() as usize, x - x.floor());
        v[i] + frac * (v[(i + 1).min(v.len() - 1)] - v[i])
    };
    (at(0.25), at(0.5), at(0.75))
}

/// The table (Markdown) and the comparison of each detector against band RMS.
pub fn table(scores: &[Score]) -> String {
    use std::fmt::Write as _;
    let mut out = String::from(
        "| detector | false alarms / h: held-out, confirmation (largest figure / threshold) | detected before developed | lead before developed, s: median [IQR] | alarm - onset, s: median [IQR] |\n|---|---|---|---|---|\n",
    );
    let ratio = |f: &FalseAlarms| {
        if f.peak_ratio > 0.0 {
            format!(" ({:.2})", f.peak_ratio)
        } else {
            String::new()
        }
    };
    for s in scores {
        let (l1, l2, l3) = quartiles(&s.lead_s);
        let (o1, o2, o3) = quartiles(&s.after_onset_s);
        let _ = writeln!(
            out,
            "| {} | {:.1}{}, {:.1}{} | {}/{} | {l2:.2} [{l1:.2}, {l3:.2}] | {o2:+.2} [{o1:+.2}, {o3:+.2}] |",
            s.detector.name(),
            s.held_out.per_hour(),
            ratio(&s.held_out),
            s.confirmation.per_hour(),
            ratio(&s.confirmation),
            s.detected,
            s.developed,
        );
    }
    if let Some(rms) = scores.iter().find(|s| s.detector == Detector::RMS) {
        let _ = writeln!(
            out,
            "\nAgainst band RMS (0.5 s), ramp by ramp (earlier: alarm before RMS's; a miss counts as never):\n"
        );
        let _ = writeln!(
            out,
            "| detector | earlier | same window | later | median lead gained, s |\n|---|---|---|---|---|"
        );
        for s in scores.iter().filter(|s| s.detector != Detector::RMS) {
            let _ = writeln!(out, "{}", versus(s, rms).row(&s.detector.name()));
        }
    }
    out
}
