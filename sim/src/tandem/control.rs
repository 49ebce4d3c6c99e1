//! The mill's speed automation obeying a chatter slow-down request, as a PLC program
//! of a tandem mill does it: the operator's setpoint is approached at the normal
//! acceleration; on the request the mill decelerates at a set rate by a set drop below
//! the lower of its speed now and its speed `lookback_s` ago (the request comes from a
//! window of past samples: a mill still accelerating has gained speed since the trouble
//! began), holds, drops again if the request persists, and once the request is released
//! waits, then re-accelerates slowly toward the setpoint. Speeds are the last stand's
//! exit strip speed, m/s.
//!
//! ```text
//!  Operator ──request──▶ SlowingDown ──at target──▶ Holding ──released──▶ Waiting
//!     ▲                     ▲    ▲                     │ still requested      │ resume_after_s
//!     │                     │    └── drop again ───────┘ escalate_after_s     ▼
//!     └──── at setpoint ────┼──────────────── request ──────────────────── Resuming
//! ```
//!
//! Each request that starts a deceleration from `Operator`, `Waiting` or `Resuming` is
//! one [`SlowDownEvent`]; a further drop while it is still requested belongs to it.
//! Pure and synchronous: the closed loop ([`super::online`]) and the virtual PLC call
//! `SpeedControl::step` once per PLC cycle with the request bit they read.

/// Longest [`SlowDownPolicy::lookback_s`], s.
pub const MAX_LOOKBACK_S: f64 = 60.0;

use std::collections::VecDeque;

/// How the automation answers a slow-down request (the PLC program's settings).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SlowDownPolicy {
    /// Acceleration toward the operator's setpoint, m/s^2, > 0.
    pub accel_m_s2: f64,
    /// Deceleration on a request, m/s^2, > 0 (mills use 0.5-2).
    pub decel_m_s2: f64,
    /// Speed drop per request, m/s, > 0.
    pub drop_m_s: f64,
    /// The drop is from the lower of the speed now and the speed this long ago, s, >= 0
    /// (at most [`MAX_LOOKBACK_S`]).
    pub lookback_s: f64,
    /// A request still set this long after the lower speed was reached drops the speed
    /// again, s, > 0.
    pub escalate_after_s: f64,
    /// Time at the lower speed after the request is released, s, >= 0.
    pub resume_after_s: f64,
    /// Re-acceleration toward the setpoint after a slow-down, m/s^2, > 0.
    pub resume_accel_m_s2: f64,
    /// Lowest speed a slow-down goes to, m/s, > 0.
    pub min_speed_m_s: f64,
}

impl Default for SlowDownPolicy {
    /// 1 m/s^2 down to 150 m/min below the speed of 3 s before, again after 5 s if
    /// still requested, 5 s wait after the release, back up at 0.2 m/s^2, never below
    /// 5 m/s; the operator's ramps at 1 m/s^2.
    fn default() -> Self {
        SlowDownPolicy {
            accel_m_s2: 1.0,
            decel_m_s2: 1.0,
            drop_m_s: 2.5,
            lookback_s: 3.0,
            escalate_after_s: 5.0,
            resume_after_s: 5.0,
            resume_accel_m_s2: 0.2,
            min_speed_m_s: 5.0,
        }
    }
}

/// A policy setting outside its range.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
#[error("{key}: {value} is not allowed (must be {allowed})")]
pub struct PolicyError {
    /// The setting, e.g. `decel_m_s2`.
    pub(crate) key: &'static str,
    /// Its value.
    pub(crate) value: f64,
    /// The allowed range with its unit.
    pub(crate) allowed: &'static str,
}

impl SlowDownPolicy {
    /// Checks every setting against its range.
    pub(crate) fn validate(&self) -> Result<(), PolicyError> {
        let check = |key, value: f64, ok: bool, allowed| {
            if ok && value.is_finite() {
                Ok(())
            } else {
                Err(PolicyError {
                    key,
                    value,
                    allowed,
                })
            }
        };
        check(
            "accel_m_s2",
            self.accel_m_s2,
            self.accel_m_s2 > 0.0,
            "> 0 m/s^2",
        )?;
        check(
            "decel_m_s2",
            self.decel_m_s2,
            self.decel_m_s2 > 0.0,
            "> 0 m/s^2",
        )?;
        check("drop_m_s", self.drop_m_s, self.drop_m_s > 0.0, "> 0 m/s")?;
        check(
            "lookback_s",
            self.lookback_s,
            (0.0..=MAX_LOOKBACK_S).contains(&self.lookback_s),
            ">= 0 and <= 60 s",
        )?;
        check(
            "escalate_after_s",
            self.escalate_after_s,
            self.escalate_after_s > 0.0,
            "> 0 s",
        )?;
        check(
            "resume_after_s",
            self.resume_after_s,
            self.resume_after_s >= 0.0,
            ">= 0 s",
        )?;
        check(
            "resume_accel_m_s2",
            self.resume_accel_m_s2,
            self.resume_accel_m_s2 > 0.0,
            "> 0 m/s^2",
        )?;
        check(
            "min_speed_m_s",
            self.min_speed_m_s,
            self.min_speed_m_s > 0.0,
            "> 0 m/s",
        )
    }
}

/// What the automation is doing.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum Mode {
    /// Following the operator's setpoint.
    Operator,
    /// Decelerating to `target_m_s` on a request.
    SlowingDown {
        /// The lower speed, m/s.
        target_m_s: f64,
    },
    /// At the lower speed while requested, since `since_s`.
    Holding {
        /// When the lower speed was reached (or the last drop), s.
        since_s: f64,
    },
    /// Released at `since_s`, waiting before re-accelerating.
    Waiting {
        /// When the request was released, s.
        since_s: f64,
    },
    /// Re-accelerating toward the setpoint after a slow-down.
    Resuming,
}

/// One slow-down: from a request to the next one (or the run's end).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SlowDownEvent {
    /// When the automation saw the request, s.
    pub requested_s: f64,
    /// Speed then, m/s.
    pub speed_at_request_m_s: f64,
    /// Lowest speed during the event, m/s.
    pub(crate) lowest_m_s: f64,
    /// Speed drops: 1, plus one per escalation.
    pub drops: u32,
    /// When the request was released, s (`None`: not within the event).
    pub released_s: Option<f64>,
    /// When the speed was back at `speed_at_request_m_s`, s (`None`: not within the
    /// event: a further request came first, or the run ended).
    pub recovered_s: Option<f64>,
}

impl SlowDownEvent {
    /// Speed shed: speed at the request less the lowest speed, m/s.
    pub fn shed_m_s(&self) -> f64 {
        self.speed_at_request_m_s - self.lowest_m_s
    }
}

/// The speed automation (see the module docs).
#[derive(Debug, Clone, PartialEq)]
pub struct SpeedControl {
    policy: SlowDownPolicy,
    setpoint_m_s: f64,
    speed_m_s: f64,
    mode: Mode,
    time_s: f64,
    events: Vec<SlowDownEvent>,
    /// (time, speed) at each cycle's start over the last `lookback_s`, oldest first.
    recent: VecDeque<(f64, f64)>,
}

impl SpeedControl {
    /// At `speed_m_s`, following the operator's `setpoint_m_s`, at time 0.
    pub fn new(
        policy: SlowDownPolicy,
        speed_m_s: f64,
        setpoint_m_s: f64,
    ) -> Result<SpeedControl, PolicyError> {
        policy.validate()?;
        for (key, value) in [("speed_m_s", speed_m_s), ("setpoint_m_s", setpoint_m_s)] {
            if !(value > 0.0 && value.is_finite()) {
                return Err(PolicyError {
                    key,
                    value,
                    allowed: "> 0 m/s",
                });
            }
        }
        Ok(SpeedControl {
            policy,
            setpoint_m_s,
            speed_m_s,
            mode: Mode::Operator,
            time_s: 0.0,
            events: Vec::new(),
            recent: VecDeque::new(),
        })
    }

    /// The policy.
    pub(crate) fn policy(&self) -> &SlowDownPolicy {
        &self.policy
    }

    /// The speed now, m/s.
    pub fn speed_m_s(&self) -> f64 {
        self.speed_m_s
    }

    /// The operator's setpoint, m/s.
    pub fn setpoint_m_s(&self) -> f64 {
        self.setpoint_m_s
    }

    /// The operator sets a new speed (followed in `Operator` mode and when resuming).
    pub fn set_setpoint(&mut self, setpoint_m_s: f64) {
        self.setpoint_m_s = setpoint_m_s;
    }

    /// The slow-downs so far, oldest first.
    pub fn events(&self) -> &[SlowDownEvent] {
        &self.events
    }

    /// One PLC cycle of `dt_s`: the request bit as read at its start moves the mode,
    /// then the speed moves for `dt_s`. Returns how: at its rate from the speed at the
    /// cycle's start until the speed at its end.
    pub(crate) fn step(&mut self, dt_s: f64, request: bool) -> SpeedSegment {
        let now = self.time_s;
        let policy = self.policy;
        self.recent.push_back((now, self.speed_m_s));
        while self
            .recent
            .front()
            .is_some_and(|&(t, _)| t < now - policy.lookback_s)
        {
            self.recent.pop_front();
        }
        let before = self.recent.front().map_or(self.speed_m_s, |&(_, v)| v);
        let lower = |speed: f64| (speed.min(before) - policy.drop_m_s).max(policy.min_speed_m_s);
        match self.mode {
            Mode::Operator | Mode::Waiting { .. } | Mode::Resuming if request => {
                self.events.push(SlowDownEvent {
                    requested_s: now,
                    speed_at_request_m_s: self.speed_m_s,
                    lowest_m_s: self.speed_m_s,
                    drops: 1,
                    released_s: None,
                    recovered_s: None,
                });
                self.mode = Mode::SlowingDown {
                    target_m_s: lower(self.speed_m_s),
                };
            }
            Mode::Holding { .. } if !request => {
                if let Some(event) = self.events.last_mut() {
                    event.released_s = Some(now);
                }
                self.mode = Mode::Waiting { since_s: now };
            }
            Mode::Holding { since_s } if now - since_s >= policy.escalate_after_s => {
                if let Some(event) = self.events.last_mut() {
                    event.drops += 1;
                }
                self.mode = Mode::SlowingDown {
                    target_m_s: lower(self.speed_m_s),
                };
            }
            Mode::Waiting { since_s } if now - since_s >= policy.resume_after_s => {
                self.mode = Mode::Resuming;
            }
            _ => {}
        }
        let end = now + dt_s;
        let from_m_s = self.speed_m_s;
        let segment = match self.mode {
            Mode::Operator => {
                SpeedSegment::toward(from_m_s, self.setpoint_m_s, policy.accel_m_s2, dt_s)
            }
            Mode::SlowingDown { target_m_s } => {
                let segment = SpeedSegment::toward(from_m_s, target_m_s, policy.decel_m_s2, dt_s);
                if segment.to_m_s == target_m_s {
                    self.mode = Mode::Holding { since_s: end };
                }
                segment
            }
            Mode::Holding { .. } | Mode::Waiting { .. } => {
                SpeedSegment::toward(from_m_s, from_m_s, 1.0, dt_s)
            }
            Mode::Resuming => {
                let segment = SpeedSegment::toward(
                    from_m_s,
                    self.setpoint_m_s,
                    policy.resume_accel_m_s2,
                    dt_s,
                );
                if segment.to_m_s == self.setpoint_m_s {
                    self.mode = Mode::Operator;
                }
                segment
            }
        };
        self.speed_m_s = segment.to_m_s;
        self.time_s = end;
        if let Some(event) = self.events.last_mut() {
            event.lowest_m_s = event.lowest_m_s.min(self.speed_m_s);
            if event.recovered_s.is_none()
                && event.released_s.is_some()
                && self.speed_m_s >= event.speed_at_request_m_s
            {
                event.recovered_s = Some(end);
            }
        }
        segment
    }
}

/// The speed over one cycle: from `from_m_s` at `rate_m_s2` until `to_m_s`, reached
/// `reach_s` into the cycle, then held.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct SpeedSegment {
    /// Speed at the cycle's start, m/s.
    pub(crate) from_m_s: f64,
    /// Speed at the cycle's end, m/s.
    pub(crate) to_m_s: f64,
    /// Signed rate, m/s^2 (0 when the speed holds).
    pub(crate) rate_m_s2: f64,
    /// When `to_m_s` is reached, s after the cycle's start.
    pub(crate) reach_s: f64,
}

impl SpeedSegment {
    /// From `from` toward `to` at `rate` (> 0) for at most `dt_s`.
    fn toward(from: f64, to: f64, rate: f64, dt_s: f64) -> SpeedSegment {
        let needed_s = (to - from).abs() / rate;
        let (to, reach_s) = if needed_s <= dt_s {
            (to, needed_s)
        } else if to > from {
            (from + rate * dt_s, dt_s)
        } else {
            (from - rate * dt_s, dt_s)
        };
        SpeedSegment {
            from_m_s: from,
            to_m_s: to,
            rate_m_s2: if to == from {
                0.0
            } else {
                rate.copysign(to - from)
            },
            reach_s,
        }
    }

    /// The speed `s_into` seconds into the cycle, m/s.
    pub(crate) fn at(&self, s_into: f64) -> f64 {
        if s_into >= self.reach_s {
            self.to_m_s
        } else {
            self.from_m_s + self.rate_m_s2 * s_into.max(0.0)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const DT: f64 = 0.05;

    fn run(control: &mut SpeedControl, seconds: f64, request: bool) -> Vec<f64> {
        let steps = (seconds / DT).round() as usize;
        (0..steps)
            .map(|_| control.step(DT, request).to_m_s)
            .collect()
    }

    #[test]
    fn a_request_slows_down_holds_escalates_then_resumes_to_the_setpoint() {
        let policy = SlowDownPolicy {
            accel_m_s2: 2.0,
            decel_m_s2: 1.0,
            drop_m_s: 2.0,
            lookback_s: 0.0,
            escalate_after_s: 3.0,
            resume_after_s: 1.0,
            resume_accel_m_s2: 0.5,
            min_speed_m_s: 5.0,
        };
        let mut control = SpeedControl::new(policy, 20.0, 24.0).expect("control");
        // The operator's ramp: 2 m/s in 1 s at 2 m/s^2, then at the setpoint.
        let speeds = run(&mut control, 3.0, false);
        assert!((speeds[9] - 21.0).abs() < 1e-9, "{}", speeds[9]);
        assert_eq!(control.speed_m_s(), 24.0);
        // A request: down 2 m/s at 1 m/s^2 (2 s), then held.
        let speeds = run(&mut control, 2.5, true);
        assert!((speeds[19] - 23.0).abs() < 1e-9, "{}", speeds[19]);
        assert_eq!(speeds[39], 22.0);
        assert!(matches!(control.mode, Mode::Holding { .. }));
        // Still requested 3 s after reaching 22 m/s: down again to 20.
        run(&mut control, 3.0, true);
        assert!(matches!(control.mode, Mode::SlowingDown { .. }));
        run(&mut control, 2.5, true);
        assert!((control.speed_m_s() - 20.0).abs() < 1e-9);
        // Released: 1 s at 20, then up at 0.5 m/s^2 to 24 (8 s).
        let speeds = run(&mut control, 1.0, false);
        assert!(speeds.iter().all(|&v| (v - 20.0).abs() < 1e-9));
        let speeds = run(&mut control, 4.0, false);
        assert!((speeds[79] - 22.0).abs() < 1e-6, "{}", speeds[79]);
        run(&mut control, 4.5, false);
        assert_eq!(control.mode, Mode::Operator);
        assert_eq!(control.speed_m_s(), 24.0);

        let events = control.events();
        assert_eq!(events.len(), 1);
        let event = events[0];
        assert_eq!((event.speed_at_request_m_s, event.drops), (24.0, 2));
        assert!((event.shed_m_s() - 4.0).abs() < 1e-9);
        assert!((event.requested_s - 3.0).abs() < 1e-9);
        // Released at 3 + 2.5 + 3 + 2.5 s; back at 24 m/s 1 s + 8 s later.
        assert!((event.released_s.expect("released") - 11.0).abs() < 1e-6);
        assert!((event.recovered_s.expect("recovered") - 20.0).abs() < 0.06);
    }

    #[test]
    fn a_request_while_resuming_is_a_new_event_from_the_speed_then() {
        let mut control = SpeedControl::new(SlowDownPolicy::default(), 20.0, 20.0).unwrap();
        run(&mut control, 1.0, true);
        run(&mut control, 3.0, true);
        run(&mut control, 7.0, false);
        assert_eq!(control.mode, Mode::Resuming);
        let resuming_at = control.speed_m_s();
        assert!(resuming_at > 17.5 && resuming_at < 20.0, "{resuming_at}");
        run(&mut control, 0.05, true);
        let events = control.events();
        assert_eq!(events.len(), 2);
        assert_eq!(events[0].recovered_s, None);
        assert_eq!(events[1].speed_at_request_m_s, resuming_at);
        // Never below the floor.
        let mut control = SpeedControl::new(SlowDownPolicy::default(), 6.0, 6.0).unwrap();
        run(&mut control, 30.0, true);
        assert_eq!(control.speed_m_s(), 5.0);
    }

    #[test]
    fn a_request_while_accelerating_drops_below_the_speed_of_the_lookback_before() {
        // Accelerating at 1 m/s^2 from 20 m/s toward 30: the request comes at 24 m/s,
        // 3 s after the mill passed 21 m/s; the drop is from there: to 18.5 m/s.
        let mut control = SpeedControl::new(SlowDownPolicy::default(), 20.0, 30.0).unwrap();
        run(&mut control, 4.0, false);
        assert!((control.speed_m_s() - 24.0).abs() < 1e-9);
        run(&mut control, 10.0, true);
        let event = control.events()[0];
        assert!((event.lowest_m_s - 18.5).abs() < 0.05 + 1e-9, "{event:?}");
    }

    #[test]
    fn policy_settings_out_of_range_are_named() {
        let policy = SlowDownPolicy {
            decel_m_s2: 0.0,
            ..SlowDownPolicy::default()
        };
        assert_eq!(
            SpeedControl::new(policy, 10.0, 10.0)
                .expect_err("no deceleration")
                .to_string(),
            "decel_m_s2: 0 is not allowed (must be > 0 m/s^2)"
        );
    }
}
