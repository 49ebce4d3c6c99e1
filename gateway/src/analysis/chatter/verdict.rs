//! The configured detector's verdict on each update: warning, alarm and the slow-down
//! request with its hysteresis.
//!
//! **Slow-down request** ([`SlowDown`]): set by the configured detector's alarm (gain
//! ratio >= 1, or both synchronization conditions), cleared only after the alarm
//! figure stayed below `slow_down_release` for `slow_down_hold_s` of trusted windows.
//! A restart or an unevaluable window neither sets nor clears it: it holds, and the time
//! below the release level starts again (the mill is not sped up on data the gateway
//! cannot read; the stale bit tells the PLC why).

use millgate_config::ChatterDetectorKind;
use millgate_dsp::chatter::ChatterResult;

use super::gain::GainReading;

/// The configured detector's bits after one update ([`super::ChatterMonitor::judge`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Verdict {
    /// The detector's warning in this window (not latched).
    pub warning: bool,
    /// The detector's alarm condition in this window (the published bit latches it).
    pub alarm: bool,
    /// The slow-down request after this update.
    pub slow_down: bool,
}

/// The slow-down request of one mill, with hysteresis (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SlowDown {
    release: f64,
    hold_s: f64,
    requested: bool,
    /// Time the alarm figure has stayed below the release level while requested, s.
    below_s: f64,
}

impl SlowDown {
    /// Not requested; clears after `hold_s` below `release` (a fraction of the alarm
    /// level, 0..1).
    pub fn new(release: f64, hold_s: f64) -> Self {
        Self {
            release,
            hold_s,
            requested: false,
            below_s: 0.0,
        }
    }

    /// Whether the slow-down is requested.
    pub fn requested(&self) -> bool {
        self.requested
    }

    /// The release level, a fraction of the alarm level.
    pub fn release(&self) -> f64 {
        self.release
    }

    /// One trusted window: `level` is the alarm figure relative to its alarm level
    /// (1 = alarm), `step_s` the time since the previous window. Returns the request.
    pub fn window(&mut self, level: f64, step_s: f64) -> bool {
        if level >= 1.0 {
            self.requested = true;
            self.below_s = 0.0;
        } else if self.requested {
            if level < self.release {
                self.below_s += step_s;
                if self.below_s >= self.hold_s {
                    self.requested = false;
                    self.below_s = 0.0;
                }
            } else {
                self.below_s = 0.0;
            }
        }
        self.requested
    }

    /// A window that could not be trusted: the request holds, the time below the
    /// release level starts again.
    pub fn untrusted(&mut self) {
        self.below_s = 0.0;
    }

    /// A fresh request with the same release level and hold.
    pub fn fresh(&self) -> Self {
        Self::new(self.release, self.hold_s)
    }
}

/// The alarm figure of detector `kind` for an evaluation with `result`, relative to
/// its alarm level (>= 1: alarm): the gain ratio of `gain`, or for the paper's
/// detector 1 when synchronized, `release` when only the frequencies lock (it holds a
/// slow-down request), else 0. `None` when the figure is not available (no gain
/// window yet, or no thresholds).
pub(super) fn alarm_level(
    kind: ChatterDetectorKind,
    gain: Option<GainReading>,
    release: f64,
    result: &ChatterResult,
) -> Option<f64> {
    match kind {
        ChatterDetectorKind::BandGain => gain.and_then(|g| g.ratio).map(|(r, _)| r),
        ChatterDetectorKind::Paper => Some(if result.synchronized {
            1.0
        } else if result.frequencies_locked {
            release
        } else {
            0.0
        }),
    }
}

/// Detector `kind`'s verdict on an update that evaluated a window into `evaluated`, or
/// `None` for one that did not (a restart, a window that could not be evaluated):
/// moves `slow_down` (windows `hop_s` apart) and returns the warning and alarm of this
/// window; both false without an evaluation.
pub(super) fn judge(
    kind: ChatterDetectorKind,
    gain: Option<GainReading>,
    hop_s: f64,
    evaluated: Option<&ChatterResult>,
    slow_down: &mut SlowDown,
) -> Verdict {
    let Some(result) = evaluated else {
        slow_down.untrusted();
        return Verdict {
            warning: false,
            alarm: false,
            slow_down: slow_down.requested(),
        };
    };
    match alarm_level(kind, gain, slow_down.release, result) {
        Some(level) => {
            slow_down.window(level, hop_s);
        }
        None => slow_down.untrusted(),
    }
    let (warning, alarm) = match kind {
        ChatterDetectorKind::BandGain => {
            let ratio = gain.and_then(|g| g.ratio).map(|(ratio, _)| ratio);
            (
                ratio.is_some_and(|r| r >= slow_down.release),
                ratio.is_some_and(|r| r >= 1.0),
            )
        }
        ChatterDetectorKind::Paper => (result.frequencies_locked, result.synchronized),
    };
    Verdict {
        warning,
        alarm,
        slow_down: slow_down.requested(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn slow_down_request_has_hysteresis_and_holds_through_untrusted_data() {
        let mut slow_down = SlowDown::new(0.8, 1.0);
        let step = 0.25;
        // Below the alarm level: nothing requested, however long.
        for level in [0.5, 0.9, 0.99, 0.0] {
            assert!(!slow_down.window(level, step));
        }
        assert!(slow_down.window(1.0, step), "set at the alarm level");
        // Between release and alarm the request holds indefinitely.
        for _ in 0..20 {
            assert!(slow_down.window(0.85, step));
        }
        // Below release: cleared after 1 s = 4 windows, not before.
        for _ in 0..3 {
            assert!(slow_down.window(0.5, step));
        }
        // Untrusted data restarts the time below release.
        slow_down.untrusted();
        for _ in 0..3 {
            assert!(slow_down.window(0.5, step));
        }
        // A window back above release restarts it as well.
        assert!(slow_down.window(0.8, step));
        for _ in 0..3 {
            assert!(slow_down.window(0.79, step));
        }
        assert!(
            !slow_down.window(0.79, step),
            "cleared after 4 windows below"
        );
        assert!(!slow_down.requested());
    }
}
