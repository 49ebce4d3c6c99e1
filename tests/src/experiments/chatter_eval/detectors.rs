//! The detectors of the race: what each reads from a window ([`Figure`]), its
//! thresholds from the calibration runs ([`calibrate`]) and its alarms.

use super::{PaperFigures, RunKind, RunResult, CONFIGURED_K_MAX, WINDOW_S};

/// A detector's figure: what it reads from each window.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Figure {
    /// Chatter-band RMS, one per stand.
    BandRms,
    /// The same over [`LONG_WINDOW_S`](super::LONG_WINDOW_S).
    BandRmsLong,
    /// Chatter-band gain, one per stand.
    BandGain,
    /// The same over [`LONG_WINDOW_S`](super::LONG_WINDOW_S).
    BandGainLong,
    /// The paper's two conditions, K_max calibrated: K_mean where sigma_n <= sigma_min.
    PaperCalibrated,
    /// The paper's two conditions with the configured K_max (1 alarm, 0 none).
    PaperConfigured,
    /// The paper's warning alone, frequencies locked (1 alarm, 0 none).
    PaperWarning,
    /// Minus the least damping ratio of an in-band pole over the stands.
    ModeDamping,
}

/// A detector: a figure, and how many consecutive windows it must exceed its
/// threshold (1: the first window alarms; more is an on-delay that rides out
/// transients such as a reel-tension step).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Detector {
    /// What it reads.
    pub figure: Figure,
    /// Consecutive windows over the threshold to alarm, >= 1.
    pub windows: usize,
}

/// Windows of a 1 s on-delay at the 0.25 s hop.
pub const ON_DELAY_WINDOWS: usize = 4;

impl Detector {
    /// Every detector, in table order.
    pub const ALL: [Detector; 10] = [
        Detector {
            figure: Figure::BandRms,
            windows: 1,
        },
        Detector {
            figure: Figure::BandRms,
            windows: ON_DELAY_WINDOWS,
        },
        Detector {
            figure: Figure::BandRmsLong,
            windows: 1,
        },
        Detector {
            figure: Figure::BandGain,
            windows: 1,
        },
        Detector {
            figure: Figure::BandGain,
            windows: ON_DELAY_WINDOWS,
        },
        Detector {
            figure: Figure::BandGainLong,
            windows: 1,
        },
        Detector {
            figure: Figure::PaperCalibrated,
            windows: 1,
        },
        Detector {
            figure: Figure::PaperConfigured,
            windows: 1,
        },
        Detector {
            figure: Figure::PaperWarning,
            windows: 1,
        },
        Detector {
            figure: Figure::ModeDamping,
            windows: 1,
        },
    ];

    /// The band-RMS detector the others are compared with (what mills use).
    pub const RMS: Detector = Detector {
        figure: Figure::BandRms,
        windows: 1,
    };

    /// Its name in the table.
    pub fn name(self) -> String {
        let figure = match self.figure {
            Figure::BandRms => "band RMS (100-300 Hz) per stand, 0.5 s",
            Figure::BandRmsLong => "band RMS (100-300 Hz) per stand, 2 s",
            Figure::BandGain => "band gain (100-300 / 450-900 Hz RMS) per stand, 0.5 s",
            Figure::BandGainLong => "band gain (100-300 / 450-900 Hz RMS) per stand, 2 s",
            Figure::PaperCalibrated => {
                "paper: sigma_n <= sigma_min and K_mean > K_max (calibrated)"
            }
            Figure::PaperConfigured => {
                "paper: sigma_n <= sigma_min and K_mean >= 0.25 (as configured)"
            }
            Figure::PaperWarning => "paper warning: sigma_n <= sigma_min",
            Figure::ModeDamping => "mode damping ratio (matrix pencil) per stand, 0.5 s",
        };
        if self.windows > 1 {
            format!(
                "{figure}, {:.2} s on-delay",
                (self.windows - 1) as f64 * WINDOW_S / 2.0
            )
        } else {
            figure.to_owned()
        }
    }

    /// `(end time, figure per channel)` of every window: higher is more alarming; a
    /// detector without a threshold gives 1 for alarm and 0 for none (threshold 0.5).
    /// With an on-delay, each channel's value is its smallest over the last `windows`.
    pub(super) fn figures(self, run: &RunResult) -> Vec<(f64, Vec<f64>)> {
        let locked = |p: &PaperFigures| p.sigma_n_hz <= p.sigma_min_hz;
        let raw: Vec<(f64, Vec<f64>)> = match self.figure {
            Figure::BandRms => run
                .windows
                .iter()
                .map(|w| (w.end_s, w.band_rms.clone()))
                .collect(),
            Figure::BandGain => run
                .windows
                .iter()
                .map(|w| (w.end_s, w.gain.clone()))
                .collect(),
            Figure::BandRmsLong => run
                .windows
                .iter()
                .filter(|w| !w.band_rms_long.is_empty())
                .map(|w| (w.end_s, w.band_rms_long.clone()))
                .collect(),
            Figure::BandGainLong => run
                .windows
                .iter()
                .filter(|w| !w.gain_long.is_empty())
                .map(|w| (w.end_s, w.gain_long.clone()))
                .collect(),
            Figure::ModeDamping => run
                .windows
                .iter()
                .map(|w| (w.end_s, vec![-w.damping]))
                .collect(),
            Figure::PaperCalibrated => run
                .paper
                .iter()
                .map(|p| (p.end_s, vec![if locked(p) { p.k_mean } else { -1.0 }]))
                .collect(),
            Figure::PaperConfigured => run
                .paper
                .iter()
                .map(|p| {
                    let alarm = locked(p) && p.k_mean >= CONFIGURED_K_MAX;
                    (p.end_s, vec![if alarm { 1.0 } else { 0.0 }])
                })
                .collect(),
            Figure::PaperWarning => run
                .paper
                .iter()
                .map(|p| (p.end_s, vec![if locked(p) { 1.0 } else { 0.0 }]))
                .collect(),
        };
        (0..raw.len())
            .filter(|&k| k + 1 >= self.windows)
            .map(|k| {
                let held = &raw[k + 1 - self.windows..=k];
                let channels = raw[k].1.len();
                let smallest = (0..channels)
                    .map(|c| held.iter().map(|(_, f)| f[c]).fold(f64::INFINITY, f64::min))
                    .collect();
                (raw[k].0, smallest)
            })
            .collect()
    }

    /// Whether its figure comes from the gateway's monitor.
    pub fn from_monitor(self) -> bool {
        matches!(
            self.figure,
            Figure::PaperCalibrated | Figure::PaperConfigured | Figure::PaperWarning
        )
    }

    /// Whether the threshold is calibrated (false: fixed at 0.5 on a 0/1 figure).
    pub fn calibrated(self) -> bool {
        !matches!(self.figure, Figure::PaperConfigured | Figure::PaperWarning)
    }
}

/// The scored windows of a run: after the settling time.
pub(super) fn scored(
    run: &RunResult,
    settle_s: f64,
    figures: Vec<(f64, Vec<f64>)>,
) -> Vec<(f64, Vec<f64>)> {
    let from = match run.scenario.kind {
        RunKind::Ramp => run.scenario.settings.ramp.hold_s,
        _ => settle_s,
    };
    figures.into_iter().filter(|(t, _)| *t >= from).collect()
}

/// Per-channel thresholds: the largest figure of each channel over the calibration
/// runs' scored windows (alarm strictly above), moved by `margin` away from the alarm
/// side: times `1 + margin` for the amplitude figures (RMS, gain), a damping ratio
/// `margin` lower, `margin` of the way from K_max to 1.
pub fn calibrate(detector: Detector, runs: &[RunResult], settle_s: f64, margin: f64) -> Vec<f64> {
    if !detector.calibrated() {
        return vec![0.5];
    }
    let mut thresholds: Vec<f64> = Vec::new();
    for run in runs
        .iter()
        .filter(|r| r.scenario.kind == RunKind::Calibration)
    {
        for (_, figures) in scored(run, settle_s, detector.figures(run)) {
            if thresholds.is_empty() {
                thresholds = vec![f64::NEG_INFINITY; figures.len()];
            }
            for (t, f) in thresholds.iter_mut().zip(&figures) {
                *t = t.max(*f);
            }
        }
    }
    for t in &mut thresholds {
        *t = match detector.figure {
            Figure::ModeDamping => *t * (1.0 - margin),
            Figure::PaperCalibrated => *t + margin * (1.0 - *t),
            _ => *t * (1.0 + margin),
        };
    }
    thresholds
}

/// Times of the scored windows where `detector` alarms.
pub(super) fn alarms(
    detector: Detector,
    run: &RunResult,
    thresholds: &[f64],
    settle_s: f64,
) -> Vec<f64> {
    scored(run, settle_s, detector.figures(run))
        .into_iter()
        .filter(|(_, figures)| figures.iter().zip(thresholds).any(|(f, t)| f > t))
        .map(|(t, _)| t)
        .collect()
}
