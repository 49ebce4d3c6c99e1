//! The configured detector's verdict on each update: warning, alarm and the slow-down
//! request with its hysteresis.
//!
//! **Slow-down request** ([`SlowDown`]): set by the configured detector's alarm (gain
//! ratio >= 1, or both synchronization conditions), cleared only after the alarm
//! figure stayed below `slow_down_release` for `slow_down_hold_s` of trusted windows.
//! A restart or an unevaluable window neither sets nor clears it: it holds, and the time
//! below the release level starts again (the mill is not sped up on data the gateway
//! cannot read; the stale bit tells the PLC why).
//!
//! **Weld hold** ([`WeldHold`]): a weld passing the stands excites them louder, and
//! when it has passed the chatter band (carried by weakly damped roots) decays over
//! seconds while the reference band drops at once, so the gain ratio rises for about
//! the gain window without chatter. While the PLC's weld bit is set, and for
//! `weld_settle_s` of trusted windows after it fell, the band-gain alarm (and with it
//! the slow-down request) needs `weld_alarm_factor` times the alarm level instead of
//! the level itself: chatter that starts during or right after a weld is still caught,
//! at a higher figure, never ignored. The warning is not gated, the release of a
//! request already set is not changed (a request is never cleared sooner because of a
//! weld), and a window whose alarm the hold kept off is marked ([`Verdict::held_off`]).
//! Without a weld bit (none configured, stale or invalid) nothing is held off.
//!
//! **Per stand** (`context.weld_stands`, a bit per stand): each stand's band-gain ratio
//! is judged against its own level, raised while the weld is in *that* stand and
//! `weld_settle_s` after its bit fell ([`SlowDown::weld_at`]); the other stands keep
//! their plain level, so chatter at a stand the weld has left (or not reached) is
//! caught as without a weld. The mill's bit ([`SlowDown::weld`]) raises every stand's.

use millgate_config::ChatterDetectorKind;
use millgate_dsp::chatter::{ChatterResult, MAX_STANDS};

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
    /// The weld hold kept this window's alarm off: the figure reached the alarm level
    /// but not the hold's higher one (a gating decision, counted and recorded).
    pub held_off: bool,
}

/// The weld hold of one mill's slow-down request (see the module docs): the alarm
/// level is raised by `alarm_factor` while a weld is in the mill and for `settle_s`
/// of trusted windows after the weld bit was last seen set.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WeldHold {
    /// Time after the weld bit fell during which the alarm level stays raised, s, >= 0.
    pub settle_s: f64,
    /// Factor on the alarm level during the hold, >= 1.
    pub alarm_factor: f64,
}

impl WeldHold {
    /// No hold: the alarm level never changes.
    pub const NONE: WeldHold = WeldHold {
        settle_s: 0.0,
        alarm_factor: 1.0,
    };
}

/// The slow-down request of one mill, with hysteresis (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SlowDown {
    release: f64,
    hold_s: f64,
    requested: bool,
    /// Time the alarm figure has stayed below the release level while requested, s.
    below_s: f64,
    weld: WeldHold,
    /// Per stand (index in the mill), trusted time since its weld bit (or the mill's)
    /// was last seen set, s; `None`: no weld seen.
    since_weld_s: [Option<f64>; MAX_STANDS],
}

impl SlowDown {
    /// Not requested; clears after `hold_s` below `release` (a fraction of the alarm
    /// level, 0..1).
    pub fn new(release: f64, hold_s: f64) -> Self {
        Self::with_weld_hold(release, hold_s, WeldHold::NONE)
    }

    /// As [`Self::new`], with the alarm level raised around welds by `weld`.
    pub fn with_weld_hold(release: f64, hold_s: f64, weld: WeldHold) -> Self {
        Self {
            release,
            hold_s,
            requested: false,
            below_s: 0.0,
            weld,
            since_weld_s: [None; MAX_STANDS],
        }
    }

    /// The PLC's weld bit for the mill was seen set since the previous window: the
    /// hold starts (or goes on) at every stand, its settle time counts from the next
    /// window.
    pub fn weld(&mut self) {
        self.since_weld_s = [Some(0.0); MAX_STANDS];
    }

    /// The weld bit of stand `stand` (index in the mill) was seen set since the
    /// previous window: as [`Self::weld`] for that stand only (another index is
    /// ignored).
    pub fn weld_at(&mut self, stand: usize) {
        if let Some(since) = self.since_weld_s.get_mut(stand) {
            *since = Some(0.0);
        }
    }

    /// Whether the weld hold raises the alarm level of any stand now.
    pub fn weld_holding(&self) -> bool {
        (0..MAX_STANDS).any(|stand| self.stand_holding(stand))
    }

    /// Whether the weld hold raises stand `stand`'s alarm level now.
    pub fn stand_holding(&self, stand: usize) -> bool {
        self.since_weld_s
            .get(stand)
            .copied()
            .flatten()
            .is_some_and(|since| since <= self.weld.settle_s)
    }

    /// The alarm level of a figure for the whole mill now, relative to the configured
    /// one: the hold's factor while any stand is held, else 1.
    pub fn alarm_scale(&self) -> f64 {
        if self.weld_holding() {
            self.weld.alarm_factor
        } else {
            1.0
        }
    }

    /// Stand `stand`'s alarm level now, relative to the configured one: the hold's
    /// factor while the weld hold holds that stand, else 1.
    pub fn stand_alarm_scale(&self, stand: usize) -> f64 {
        if self.stand_holding(stand) {
            self.weld.alarm_factor
        } else {
            1.0
        }
    }

    /// Whether a stand's ratio of `stand_ratios` (per stand, in the mill's order,
    /// relative to its alarm level) reaches its level now ([`Self::stand_alarm_scale`]).
    pub fn stand_alarm(&self, stand_ratios: &[f64]) -> bool {
        stand_ratios
            .iter()
            .enumerate()
            .any(|(stand, &ratio)| ratio >= self.stand_alarm_scale(stand))
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
    /// During a weld hold the request is set only at the hold's raised level
    /// ([`Self::alarm_scale`]); its release is unchanged.
    pub fn window(&mut self, level: f64, step_s: f64) -> bool {
        let alarm = level >= self.alarm_scale();
        self.judged(level, alarm, step_s)
    }

    /// As [`Self::window`] for a figure per stand (`stand_ratios`, each relative to its
    /// stand's alarm level): set when a stand reaches its own level
    /// ([`Self::stand_alarm`]), released by the largest.
    pub fn window_by_stand(&mut self, stand_ratios: &[f64], step_s: f64) -> bool {
        let alarm = self.stand_alarm(stand_ratios);
        let level = stand_ratios
            .iter()
            .copied()
            .fold(f64::NEG_INFINITY, f64::max);
        self.judged(level, alarm, step_s)
    }

    /// One trusted window whose alarm figure is `level` and whose alarm was `alarm`
    /// (judged before the window moves the hold on).
    fn judged(&mut self, level: f64, alarm: bool, step_s: f64) -> bool {
        for since in self.since_weld_s.iter_mut().flatten() {
            *since += step_s;
        }
        if alarm {
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

    /// The release level, hold and weld hold of `settings` (a reload), this request's
    /// state kept: a request set stays set, the time below the release level and
    /// since the weld bit go on.
    pub fn retune(&mut self, settings: &SlowDown) {
        self.release = settings.release;
        self.hold_s = settings.hold_s;
        self.weld = settings.weld;
    }

    /// A fresh request with the same release level and hold.
    pub fn fresh(&self) -> Self {
        Self::with_weld_hold(self.release, self.hold_s, self.weld)
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
            held_off: false,
        };
    };
    // The alarm of this window, against the levels before the window moves the hold
    // on: each stand's band-gain ratio against its own.
    let stand_ratios = gain.as_ref().map_or(&[][..], GainReading::stand_ratios);
    let held_alarm = slow_down.stand_alarm(stand_ratios);
    match (kind, alarm_level(kind, gain, slow_down.release, result)) {
        (ChatterDetectorKind::BandGain, Some(_)) => {
            slow_down.window_by_stand(stand_ratios, hop_s);
        }
        (ChatterDetectorKind::Paper, Some(level)) => {
            slow_down.window(level, hop_s);
        }
        (_, None) => slow_down.untrusted(),
    }
    let (warning, alarm, ungated_alarm) = match kind {
        ChatterDetectorKind::BandGain => {
            let ratio = gain.and_then(|g| g.ratio).map(|(ratio, _)| ratio);
            (
                ratio.is_some_and(|r| r >= slow_down.release),
                held_alarm,
                ratio.is_some_and(|r| r >= 1.0),
            )
        }
        // The paper's figure is 0, the release level or 1: no higher level to hold
        // it to (the monitor gives it no hold; its conditions ignored the welds).
        ChatterDetectorKind::Paper => (
            result.frequencies_locked,
            result.synchronized,
            result.synchronized,
        ),
    };
    Verdict {
        warning,
        alarm,
        slow_down: slow_down.requested(),
        held_off: ungated_alarm && !alarm,
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

    #[test]
    fn a_weld_raises_the_alarm_level_for_its_settle_time_and_never_hastens_a_release() {
        let step = 0.25;
        let hold = WeldHold {
            settle_s: 1.0,
            alarm_factor: 2.0,
        };
        let mut slow_down = SlowDown::with_weld_hold(0.8, 1.0, hold);
        assert!(!slow_down.weld_holding());
        slow_down.weld();
        assert_eq!(slow_down.alarm_scale(), 2.0);
        // During the weld and its settle time the alarm level is 2: 1.5 is held off.
        for _ in 0..4 {
            slow_down.weld();
            assert!(!slow_down.window(1.5, step));
        }
        // The bit fell: 1 s (4 windows) of settle time, then the hold ends.
        for _ in 0..4 {
            assert!(!slow_down.window(1.5, step), "held off in the settle time");
        }
        assert!(!slow_down.weld_holding());
        assert!(
            slow_down.window(1.0, step),
            "the plain level after the hold"
        );
        // Chatter during a weld is still caught at the raised level.
        let mut caught = SlowDown::with_weld_hold(0.8, 1.0, hold);
        caught.weld();
        assert!(caught.window(2.0, step));
        // A request set before the weld is released only as without it.
        let mut set = SlowDown::with_weld_hold(0.8, 1.0, hold);
        assert!(set.window(1.2, step));
        set.weld();
        for _ in 0..20 {
            assert!(set.window(0.9, step), "between release and alarm it holds");
        }
        assert_eq!(
            set.fresh().alarm_scale(),
            1.0,
            "a fresh request has no weld"
        );
    }

    #[test]
    fn a_weld_at_one_stand_raises_that_stands_level_only_for_its_settle_time() {
        let step = 0.25;
        let hold = WeldHold {
            settle_s: 1.0,
            alarm_factor: 2.0,
        };
        // Stand 1 of three welding: its ratio 1.5 is held off, the same at stand 2 is
        // an alarm (the weld is not there).
        let mut slow_down = SlowDown::with_weld_hold(0.8, 1.0, hold);
        slow_down.weld_at(1);
        assert!(slow_down.stand_holding(1) && !slow_down.stand_holding(0));
        assert!(slow_down.weld_holding());
        assert_eq!(
            (
                slow_down.stand_alarm_scale(0),
                slow_down.stand_alarm_scale(1)
            ),
            (1.0, 2.0)
        );
        assert!(!slow_down.window_by_stand(&[0.5, 1.5, 0.5], step));
        assert!(!slow_down.stand_alarm(&[0.9, 1.9, 0.9]));
        let mut elsewhere = slow_down;
        assert!(
            elsewhere.window_by_stand(&[0.5, 0.5, 1.5], step),
            "chatter at a stand without the weld is judged at its plain level"
        );
        // The weld moves on to stand 2: stand 1 settles for 1 s (4 windows), stand 2
        // is held from now.
        for _ in 0..4 {
            slow_down.weld_at(2);
            assert!(!slow_down.window_by_stand(&[0.5, 1.5, 1.5], step));
        }
        assert!(!slow_down.stand_holding(1), "stand 1's settle time is over");
        assert!(slow_down.stand_holding(2));
        assert!(
            slow_down.window_by_stand(&[0.5, 1.5, 1.5], step),
            "stand 1 at its plain level again"
        );
        // Chatter at the welding stand is still caught at the raised level; the
        // release goes by the largest ratio as without a weld.
        let mut caught = SlowDown::with_weld_hold(0.8, 0.5, hold);
        caught.weld_at(0);
        assert!(caught.window_by_stand(&[2.0, 0.1], step));
        assert!(
            caught.window_by_stand(&[0.1, 0.85], step),
            "0.85 >= release"
        );
        assert!(caught.window_by_stand(&[0.1, 0.5], step));
        assert!(
            !caught.window_by_stand(&[0.1, 0.5], step),
            "released after 0.5 s"
        );
        // The mill's bit holds every stand; an index past the stands is ignored.
        let mut mill = SlowDown::with_weld_hold(0.8, 1.0, hold);
        mill.weld_at(MAX_STANDS);
        assert!(!mill.weld_holding());
        mill.weld();
        assert!((0..MAX_STANDS).all(|stand| mill.stand_holding(stand)));
        assert!(!mill.window_by_stand(&[1.5, 1.5, 1.5], step));
    }
}
