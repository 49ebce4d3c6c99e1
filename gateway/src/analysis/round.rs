//! One analysis round for the drivelines: the blocks drained together, split into
//! each driveline's share ([`Step`]s in the order of the blocks), each share run on
//! the pool ([`super::pool`]) against the driveline's own analyser. A driveline's
//! state depends only on its own steps in their order, so its bites are the same,
//! in the same order, whatever the number of workers and however the drivelines'
//! shares interleave.

use std::time::{Instant, SystemTime};

use super::context::TagValue;
use super::driveline::{BiteReport, DrivelineAnalyzer};
use crate::field::acquired::Acquired;
use crate::state::board::Board;
use crate::state::events::HistoryEvent;

/// What one message asks of one driveline.
#[derive(Debug, Clone, Copy)]
pub(super) enum Step<'a> {
    /// Samples of its torque, the last received at `received` (when known), handed
    /// over by the reader at `handed`.
    Torque {
        values: &'a [f64],
        received: Option<SystemTime>,
        handed: Instant,
    },
    /// Samples of its extra channel `extra` (position in `extra_channels`).
    Extra {
        extra: usize,
        values: &'a [f64],
        received: Option<SystemTime>,
    },
    /// Samples of its torque were lost.
    TorqueGap { missed: Option<u64> },
    /// Samples of its extra channel `extra` were lost.
    ExtraGap { extra: usize },
    /// A value of its "metal in stand" trigger.
    Trigger { value: f64 },
    /// A value of its context channel `channel`, taken up at `now`.
    Context {
        channel: usize,
        value: TagValue,
        now: Instant,
    },
}

/// Which drivelines each channel feeds, and how (the analysis' routing tables).
pub(super) struct Routes<'r> {
    pub(super) by_torque: &'r [Vec<usize>],
    pub(super) by_trigger: &'r [Vec<usize>],
    pub(super) by_context: &'r [Vec<usize>],
    pub(super) by_extra: &'r [Vec<(usize, usize)>],
}

impl Routes<'_> {
    /// Each driveline's steps (of `drivelines`) from `messages`, in their order; a
    /// message's extra samples before its torque, a process value's trigger before
    /// its context (as one message at a time was handled).
    pub(super) fn steps<'m>(
        &self,
        messages: &'m [Acquired],
        drivelines: usize,
    ) -> Vec<Vec<Step<'m>>> {
        let mut steps = vec![Vec::new(); drivelines];
        for message in messages {
            match message {
                Acquired::Samples {
                    channel,
                    values,
                    received,
                    handed,
                } => {
                    for &(d, extra) in &self.by_extra[*channel] {
                        steps[d].push(Step::Extra {
                            extra,
                            values,
                            received: *received,
                        });
                    }
                    for &d in &self.by_torque[*channel] {
                        steps[d].push(Step::Torque {
                            values,
                            received: *received,
                            handed: *handed,
                        });
                    }
                }
                Acquired::Gap {
                    channel,
                    missed_samples,
                } => {
                    for &(d, extra) in &self.by_extra[*channel] {
                        steps[d].push(Step::ExtraGap { extra });
                    }
                    for &d in &self.by_torque[*channel] {
                        steps[d].push(Step::TorqueGap {
                            missed: *missed_samples,
                        });
                    }
                }
                Acquired::ProcessValue { channel, value } => {
                    for &d in &self.by_trigger[*channel] {
                        steps[d].push(Step::Trigger { value: *value });
                    }
                    let now = Instant::now();
                    for &d in &self.by_context[*channel] {
                        steps[d].push(Step::Context {
                            channel: *channel,
                            value: TagValue::Number(*value),
                            now,
                        });
                    }
                }
                Acquired::Text { channel, text } => {
                    let now = Instant::now();
                    for &d in &self.by_context[*channel] {
                        steps[d].push(Step::Context {
                            channel: *channel,
                            value: TagValue::Text(*text),
                            now,
                        });
                    }
                }
            }
        }
        steps
    }
}

impl DrivelineAnalyzer {
    /// Whether `steps` may complete a bite window, so that their job may take a
    /// bite's analysis (some hundreds of microseconds) rather than the few it takes
    /// to take samples in: their torque samples reach the detector's window end
    /// ([`millgate_dsp::bite::BiteDetector::samples_to_window_end`]), or a gap may end
    /// a window.
    pub(super) fn may_complete_a_window(&self, steps: &[Step<'_>]) -> bool {
        let mut torque = 0;
        for step in steps {
            match step {
                Step::Torque { values, .. } => torque += values.len(),
                Step::TorqueGap { .. } => return true,
                _ => {}
            }
        }
        torque >= self.samples_to_window_end()
    }

    /// Take `steps` in order; returns the bites they completed, analysed. A manual
    /// capture whose samples are all in is recorded in `board`'s history.
    pub(super) fn run_steps(&mut self, steps: &[Step<'_>], board: &Board) -> Vec<BiteReport> {
        let mut reports = Vec::new();
        for step in steps {
            match *step {
                Step::Torque {
                    values,
                    received,
                    handed,
                } => {
                    self.samples(values, (received, handed), &mut reports);
                    if let Some(capture) = self.take_manual_capture() {
                        tracing::info!(driveline = %capture.subject, samples = capture.samples(), "manual capture kept");
                        board
                            .history()
                            .record(HistoryEvent::Capture(Box::new(capture)));
                    }
                }
                Step::Extra {
                    extra,
                    values,
                    received,
                } => self.extra_samples(extra, values, received),
                Step::TorqueGap { missed } => self.gap(missed, &mut reports),
                Step::ExtraGap { extra } => self.extra_gap(extra),
                Step::Trigger { value } => self.trigger_value(value),
                Step::Context {
                    channel,
                    value,
                    now,
                } => self.context_value(channel, value, now),
            }
        }
        reports
    }
}
