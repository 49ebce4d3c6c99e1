//! What a driveline keeps of its samples for the history's captures ([`Captures`]):
//! each bite window's torque ([`BiteSamples`], with the extra channels over it from
//! their rings), and the manual captures the engineer asks for
//! (`Command::CaptureTorque`).

use std::sync::Arc;
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use millgate_config::Channel;
use millgate_dsp::bite::BiteEvent;

use crate::analysis::bite_window::WINDOW_CAPACITY;
use crate::analysis::extra_channels::ExtraRing;
use crate::state::captures::{
    unix_ns, BiteWindowAnalysis, CaptureChannel, CaptureGap, CaptureKind, CaptureRecord,
    CapturedBite, KeepClass,
};
use crate::state::context::ContextReading;

/// A bite window's samples as the analysis read them: what its capture keeps.
#[derive(Debug, Clone, PartialEq)]
pub struct BiteSamples {
    /// The torque channel with the window's samples.
    pub torque: CaptureChannel,
    /// Time of the window's first sample.
    pub first_sample: SystemTime,
    /// That time is counted back from a CAN kernel receive timestamp.
    pub kernel_time: bool,
    /// A gap ended the window (the capture's end).
    pub gap: Option<CaptureGap>,
    /// Trigger, baseline and the settings it was analysed with.
    pub analysis: BiteWindowAnalysis,
    /// Sample rate, Hz.
    pub sample_rate_hz: f64,
    /// The driveline's extra channels over the window, row for row with the torque
    /// (filled when the bite is released to the history).
    pub extra: Vec<CaptureChannel>,
}

impl BiteSamples {
    /// The capture of these samples as the history keeps it, of a bite of driveline
    /// `subject`, the bite `bite`, kept as `keep`, rolled in `context`.
    pub(super) fn record(
        &self,
        subject: &str,
        bite: CapturedBite,
        keep: KeepClass,
        context: Option<ContextReading>,
    ) -> CaptureRecord {
        CaptureRecord {
            kind: CaptureKind::Bite,
            subject: subject.to_owned(),
            bite: Some(bite),
            first_sample_unix_ns: unix_ns(self.first_sample),
            kernel_time: self.kernel_time,
            sample_rate_hz: self.sample_rate_hz,
            channels: std::iter::once(&self.torque)
                .chain(&self.extra)
                .cloned()
                .collect(),
            gaps: self.gap.into_iter().collect(),
            analysis: Some(self.analysis),
            episode: None,
            keep,
            context,
        }
    }
}

/// What one driveline keeps for the captures.
#[derive(Debug)]
pub(super) struct Captures {
    /// The torque channel's sample rate, Hz.
    sample_rate_hz: f64,
    /// The torque channel as a capture describes it, when captures are kept.
    torque: Option<CaptureChannel>,
    /// A manual capture being taken (`Command::CaptureTorque`).
    manual: Option<ManualCapture>,
    /// The extra channels' latest samples, when captures are kept.
    extras: Vec<ExtraRing>,
}

/// A manual capture of a driveline's torque while it is being taken.
#[derive(Debug)]
struct ManualCapture {
    /// Samples still to take.
    remaining: usize,
    /// The samples taken.
    samples: Vec<f64>,
    /// Time of the first sample.
    first_sample: Option<SystemTime>,
    /// Whether that time is the kernel's (CAN).
    kernel_time: bool,
    /// Where data was lost.
    gaps: Vec<CaptureGap>,
    /// The driveline's process context when it was asked for (`None` without context
    /// tags).
    context: Option<ContextReading>,
}

impl Captures {
    /// Nothing kept (until [`Self::keep`]) of a torque channel sampled at
    /// `sample_rate_hz`.
    pub(super) fn new(sample_rate_hz: f64) -> Self {
        Self {
            sample_rate_hz,
            torque: None,
            manual: None,
            extras: Vec::new(),
        }
    }

    /// Keep each bite window's samples, describing the torque channel as `torque`;
    /// with `extra` (the driveline's `extra_channels`), each kept in a ring of
    /// `ring_capacity` samples.
    pub(super) fn keep(&mut self, torque: &Channel, extra: &[&Channel], ring_capacity: usize) {
        let describe = CaptureChannel::described;
        self.torque = Some(describe(torque));
        self.extras = extra
            .iter()
            .map(|channel| ExtraRing::new(describe(channel), channel.sample_rate_hz, ring_capacity))
            .collect();
    }

    /// Start keeping the next `seconds` s of torque as a manual capture (a capture
    /// already running starts again) with the driveline's `context` of now; false when
    /// captures are not kept.
    pub(super) fn start_manual(&mut self, seconds: f64, context: Option<ContextReading>) -> bool {
        if self.torque.is_none() {
            return false;
        }
        self.manual = Some(ManualCapture {
            remaining: (seconds * self.sample_rate_hz).ceil().max(1.0) as usize,
            samples: Vec::new(),
            first_sample: None,
            kernel_time: false,
            gaps: Vec::new(),
            context,
        });
        true
    }

    /// The manual capture of driveline `subject`, once its samples are all in.
    pub(super) fn take_manual(&mut self, subject: &str) -> Option<CaptureRecord> {
        if self.manual.as_ref()?.remaining > 0 {
            return None;
        }
        let manual = self.manual.take()?;
        let torque = self.torque.as_ref()?;
        Some(CaptureRecord {
            kind: CaptureKind::Manual,
            subject: subject.to_owned(),
            bite: None,
            first_sample_unix_ns: unix_ns(manual.first_sample.unwrap_or(UNIX_EPOCH)),
            kernel_time: manual.kernel_time,
            sample_rate_hz: self.sample_rate_hz,
            channels: vec![CaptureChannel {
                samples: manual.samples,
                ..torque.clone()
            }],
            gaps: manual.gaps,
            analysis: None,
            episode: None,
            keep: KeepClass::Important,
            context: manual.context,
        })
    }

    /// Keep what a running manual capture still takes of `values`, the last of which
    /// was received at `received` (when known).
    pub(super) fn manual_samples(&mut self, values: &[f64], received: Option<SystemTime>) {
        let Some(manual) = self.manual.as_mut() else {
            return;
        };
        if manual.first_sample.is_none() {
            // The first sample's time: the last's, or now's without one (a
            // Modbus DAQ), moved back over the block.
            let last = received.unwrap_or_else(SystemTime::now);
            let span = values.len().saturating_sub(1) as f64 / self.sample_rate_hz;
            manual.first_sample = Some(before(last, span));
            manual.kernel_time = received.is_some();
        }
        let take = manual.remaining.min(values.len());
        manual.samples.extend_from_slice(&values[..take]);
        manual.remaining -= take;
    }

    /// Note in a running manual capture that `missed` samples were lost (an unknown
    /// number when `None`).
    pub(super) fn manual_gap(&mut self, missed: Option<u64>) {
        if let Some(manual) = self.manual.as_mut().filter(|m| !m.samples.is_empty()) {
            manual.gaps.push(CaptureGap {
                before_sample: manual.samples.len(),
                missed_samples: missed,
            });
        }
    }

    /// Samples of extra channel `extra` (its position in `extra_channels`), the last
    /// received at `received` (when known).
    pub(super) fn extra_samples(
        &mut self,
        extra: usize,
        values: &[f64],
        received: Option<SystemTime>,
    ) {
        if let Some(ring) = self.extras.get_mut(extra) {
            ring.push(values, received);
        }
    }

    /// Samples of extra channel `extra` were lost.
    pub(super) fn extra_gap(&mut self, extra: usize) {
        if let Some(ring) = self.extras.get_mut(extra) {
            ring.gap();
        }
    }

    /// Whether every extra channel has samples up to the end of the window `samples`
    /// (true without extra channels or captures).
    pub(super) fn extras_reach_window_end(&self, samples: Option<&BiteSamples>) -> bool {
        let Some(samples) = samples else {
            return true;
        };
        let rows = samples.torque.samples.len().saturating_sub(1);
        let end =
            samples.first_sample + Duration::from_secs_f64(rows as f64 / samples.sample_rate_hz);
        self.extras.iter().all(|ring| ring.reaches(end))
    }

    /// Put the extra channels over the window `samples` into them (what the rings
    /// hold of it: missing rows are NaN, see [`ExtraRing::capture`]).
    pub(super) fn capture_extras(&self, samples: Option<&mut Arc<BiteSamples>>) {
        if self.extras.is_empty() {
            return;
        }
        if let Some(samples) = samples {
            let samples = Arc::make_mut(samples);
            let rows = samples.torque.samples.len();
            samples.extra = self
                .extras
                .iter()
                .map(|ring| ring.capture(samples.first_sample, rows))
                .collect();
        }
    }

    /// The samples of `event`'s window, analysed as `analysis`, whose trigger was at
    /// `time`, when captures are kept: a time counted back from a kernel receive
    /// timestamp when `kernel_time`, the window ended by a gap of that many samples
    /// (an unknown number when `None`) when `ended_by_gap`.
    pub(super) fn bite_samples(
        &self,
        event: &BiteEvent<WINDOW_CAPACITY>,
        analysis: BiteWindowAnalysis,
        time: SystemTime,
        kernel_time: bool,
        ended_by_gap: Option<Option<u64>>,
    ) -> Option<Arc<BiteSamples>> {
        let torque = self.torque.as_ref()?;
        Some(Arc::new(BiteSamples {
            torque: CaptureChannel {
                samples: event.window.to_vec(),
                ..torque.clone()
            },
            first_sample: before(time, event.trigger_index as f64 / self.sample_rate_hz),
            kernel_time,
            gap: ended_by_gap.map(|missed_samples| CaptureGap {
                before_sample: event.window.len(),
                missed_samples,
            }),
            analysis,
            sample_rate_hz: self.sample_rate_hz,
            extra: Vec::new(),
        }))
    }
}

/// `time` moved back by `seconds` (>= 0), saturating at the Unix epoch.
pub(super) fn before(time: SystemTime, seconds: f64) -> SystemTime {
    time.checked_sub(Duration::from_secs_f64(seconds.max(0.0)))
        .unwrap_or(UNIX_EPOCH)
}
