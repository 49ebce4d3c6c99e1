//! The messages the analysis takes up together, split into each driveline's share
//! ([`Step`]s in the order of the messages), each share run against the driveline's
//! own analyser (on the pool, [`super::pool`], after the driveline's previous share).
//! A driveline's state depends only on its own steps in their order, so its bites
//! are the same, in the same order, whatever the number of workers and however the
//! drivelines' shares interleave.

use std::sync::Arc;
use std::time::Instant;

use super::context::TagValue;
use super::driveline::{BiteReport, DrivelineAnalyzer};
use crate::field::acquired::Acquired;
use crate::state::board::Board;
use crate::state::events::HistoryEvent;

/// What one message asks of one driveline. A step owns what it takes (a block's
/// samples shared with the other drivelines and mills it feeds), so a driveline's
/// share can wait for its previous one while the analysis takes up the next
/// messages.
#[derive(Debug, Clone)]
pub(super) enum Step {
    /// Samples of its torque: an [`Acquired::Samples`].
    Torque(Arc<Acquired>),
    /// Samples of its extra channel `extra` (position in `extra_channels`): an
    /// [`Acquired::Samples`].
    Extra {
        extra: usize,
        samples: Arc<Acquired>,
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
    pub(super) fn steps(&self, messages: &[Arc<Acquired>], drivelines: usize) -> Vec<Vec<Step>> {
        let mut steps = vec![Vec::new(); drivelines];
        for message in messages {
            match &**message {
                Acquired::Samples { channel, .. } => {
                    for &(d, extra) in &self.by_extra[*channel] {
                        steps[d].push(Step::Extra {
                            extra,
                            samples: Arc::clone(message),
                        });
                    }
                    for &d in &self.by_torque[*channel] {
                        steps[d].push(Step::Torque(Arc::clone(message)));
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
                    self.context(&mut steps, *channel, TagValue::Number(*value));
                }
                Acquired::Text { channel, text } => {
                    self.context(&mut steps, *channel, TagValue::Text(*text));
                }
            }
        }
        steps
    }

    /// The context value `value` of `channel`, taken up now, as a step of each
    /// driveline whose context tag it is.
    fn context(&self, steps: &mut [Vec<Step>], channel: usize, value: TagValue) {
        let now = Instant::now();
        for &d in &self.by_context[channel] {
            steps[d].push(Step::Context {
                channel,
                value,
                now,
            });
        }
    }
}

impl DrivelineAnalyzer {
    /// Whether `steps` may complete a bite window, so that their job may take a
    /// bite's analysis (some hundreds of microseconds) rather than the few it takes
    /// to take samples in: their torque samples reach the detector's window end
    /// ([`millgate_dsp::bite::BiteDetector::samples_to_window_end`]), or a gap may end
    /// a window.
    pub(super) fn may_complete_a_window(&self, steps: &[Step]) -> bool {
        let mut torque = 0;
        for step in steps {
            match step {
                Step::Torque(samples) => torque += values_of(samples).0.len(),
                Step::TorqueGap { .. } => return true,
                _ => {}
            }
        }
        torque >= self.samples_to_window_end()
    }

    /// Take `steps` in order; returns the bites they completed, analysed. A manual
    /// capture whose samples are all in is recorded in `board`'s history.
    pub(super) fn run_steps(&mut self, steps: &[Step], board: &Board) -> Vec<BiteReport> {
        let mut reports = Vec::new();
        for step in steps {
            match *step {
                Step::Torque(ref samples) => {
                    let (values, received, handed) = values_of(samples);
                    self.samples(values, (received, handed), &mut reports);
                    if let Some(capture) = self.take_manual_capture() {
                        tracing::info!(driveline = %capture.subject, samples = capture.samples(), "manual capture kept");
                        board
                            .history()
                            .record(HistoryEvent::Capture(Box::new(capture)));
                    }
                }
                Step::Extra { extra, ref samples } => {
                    let (values, received, _) = values_of(samples);
                    self.extra_samples(extra, values, received);
                }
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

/// A block's samples, when the last was received (when known) and when its reader
/// handed it over; no samples for a message of another kind (a step of samples is
/// built only from an [`Acquired::Samples`]).
fn values_of(message: &Acquired) -> (&[f64], Option<std::time::SystemTime>, Instant) {
    match message {
        Acquired::Samples {
            values,
            received,
            handed,
            ..
        } => (values, *received, *handed),
        _ => (&[], None, Instant::now()),
    }
}
