//! [`ChatterAnalysis`]: every tandem mill's monitor, fed by the analysis task, and
//! what each update publishes (the mill's results in the register map, the PLC
//! writes, the HMI server and `/metrics`).

use std::sync::Arc;
use std::time::Instant;

use millgate_config::Config;

use super::align::RestartCause;
use super::capture::EpisodeRecorder;
use super::history::record_episode;
use super::monitor::{ChatterMonitor, ChatterSetupError, ChatterUpdate};
use super::spectra::chatter_frequency_hz;
use super::verdict::{SlowDown, Verdict};
use crate::field::acquired::Acquired;
use crate::state::board::Board;
use crate::state::captures::CaptureRecord;
use crate::state::events::{AlarmKind, AlarmRecord, HistoryEvent};
use crate::state::results::TandemMillResults;
use crate::state::time::UtcTime;

/// Every tandem mill's monitor, fed by the analysis task; results go to the
/// register map (PLC writes, HMI server) and `/metrics`.
///
/// Published per mill after each evaluation: sigma_n, K_mean, the chatter frequency
/// (mean of the stands' principal frequencies), the chatter-band gain, band RMS and
/// gain ratio with its stand, and the configured detector's bits: warning (band gain:
/// gain ratio >= `slow_down_release` in this window; paper: sigma_n <= sigma_min),
/// alarm (band gain: ratio >= 1; paper: both conditions; latched until acknowledged,
/// like the driveline alarms) and the slow-down request ([`SlowDown`]). A restart
/// clears the values and sets "source stale" until the next full window.
#[derive(Debug)]
pub struct ChatterAnalysis {
    monitors: Vec<ChatterMonitor>,
    /// Per mill, the slow-down request.
    slow_downs: Vec<SlowDown>,
    /// Per mill, its chatter-episode captures (with `[history]` and captures on).
    captures: Vec<Option<EpisodeRecorder>>,
    /// Per channel: the (mill, stand) pairs it feeds.
    by_channel: Vec<Vec<(usize, usize)>>,
    board: Arc<Board>,
}

impl ChatterAnalysis {
    /// Monitors for every tandem mill of `config`.
    pub fn new(config: &Config, board: Arc<Board>) -> Result<Self, ChatterSetupError> {
        let mut by_channel = vec![Vec::new(); config.channels.len()];
        let mut monitors = Vec::new();
        for (m, mill) in config.tandem_mills.iter().enumerate() {
            monitors.push(ChatterMonitor::new(config, m)?);
            for (s, &channel) in mill.stands.iter().enumerate() {
                by_channel[channel].push((m, s));
            }
        }
        let keep_captures = config
            .history
            .as_ref()
            .is_some_and(|history| history.captures.enabled);
        let captures = monitors
            .iter()
            .enumerate()
            .map(|(m, monitor)| keep_captures.then(|| EpisodeRecorder::new(config, m, monitor)))
            .collect();
        Ok(Self {
            slow_downs: monitors.iter().map(ChatterMonitor::slow_down).collect(),
            captures,
            monitors,
            by_channel,
            board,
        })
    }

    /// Keep mill `mill`'s stands' next `seconds` s as a capture of kind `manual`;
    /// false when the mill does not exist or captures are not kept.
    pub(crate) fn start_manual_capture(&mut self, mill: usize, seconds: f64) -> bool {
        match self.captures.get_mut(mill) {
            Some(Some(recorder)) => {
                recorder.start_manual(seconds);
                true
            }
            _ => false,
        }
    }

    /// The monitors, in config order.
    pub fn monitors(&self) -> &[ChatterMonitor] {
        &self.monitors
    }

    /// Route one reader message to the mills whose stand it is, and publish what
    /// changed.
    pub fn handle(&mut self, message: &Acquired) {
        let channel = match message {
            Acquired::Samples { channel, .. } | Acquired::Gap { channel, .. } => *channel,
            Acquired::ProcessValue { .. } => return,
        };
        let Some(stands) = self.by_channel.get(channel) else {
            return;
        };
        let now = Instant::now();
        for &(mill, stand) in stands {
            let monitor = &mut self.monitors[mill];
            let recorder = &mut self.captures[mill];
            let mut done = Vec::new();
            let change = match message {
                Acquired::Samples {
                    values, received, ..
                } => {
                    let change = monitor.samples(stand, values, now);
                    if let Some((recorder, next)) = recorder
                        .as_mut()
                        .zip(monitor.stand_next_index(stand))
                        .filter(|_| !values.is_empty())
                    {
                        done.extend(recorder.samples(stand, next, values, *received));
                        if let Some(ChatterUpdate::Restarted(RestartCause::Realigned { .. })) =
                            change
                        {
                            done.extend(recorder.lost(None));
                        }
                    }
                    change
                }
                Acquired::Gap { missed_samples, .. } => {
                    if let Some(recorder) = recorder.as_mut() {
                        done.extend(recorder.lost(*missed_samples));
                    }
                    monitor.gap(stand, *missed_samples)
                }
                Acquired::ProcessValue { .. } => None,
            };
            if let Some(change) = change {
                let warning = publish(
                    &self.board,
                    mill,
                    monitor,
                    &mut self.slow_downs[mill],
                    &change,
                );
                if let Some(recorder) = recorder.as_mut() {
                    done.extend(recorder.warning(warning, monitor.last_window_end()));
                }
            }
            for capture in done {
                keep(&self.board, capture);
            }
        }
    }
}

/// Hand a finished chatter-episode (or manual) capture to the history (never waits: a full
/// queue drops and counts it, as for every event).
fn keep(board: &Board, capture: CaptureRecord) {
    tracing::info!(
        mill = %capture.subject,
        samples = capture.samples(),
        stands = capture.channels.len(),
        cut = capture.episode.is_some_and(|e| e.cut),
        kind = capture.kind.name(),
        "tandem mill capture kept"
    );
    board
        .history()
        .record(HistoryEvent::Capture(Box::new(capture)));
}

/// Record one monitor update in the published results, and in the history the
/// chatter episodes (from the warning condition set to it cleared) and the alarm.
/// Returns the warning as published.
fn publish(
    board: &Board,
    mill: usize,
    monitor: &ChatterMonitor,
    slow_down: &mut SlowDown,
    change: &ChatterUpdate,
) -> bool {
    let name = monitor.name();
    let was_requested = slow_down.requested();
    let verdict = monitor.judge(change, slow_down);
    if verdict.slow_down != was_requested {
        tracing::warn!(
            mill = %name,
            requested = slow_down.requested(),
            "chatter slow-down request changed"
        );
    }
    board.update_recorded(|results, events| {
        let Some(published) = results.tandem_mills.get_mut(mill) else {
            return;
        };
        let was_flagged = published.source_stale;
        let was = published.clone();
        let (was_warning, was_alarm) = (published.chatter_warning, published.chatter_alarm);
        match change {
            ChatterUpdate::Evaluated(result) => {
                published.evaluations = monitor.evaluations();
                published.sigma_n_hz = Some(result.sigma_n_hz);
                published.k_mean = Some(result.k_mean);
                published.chatter_frequency_hz = chatter_frequency_hz(result);
                let gain = monitor.gain();
                published.chatter_gain = gain.map(|g| g.max_gain);
                published.band_rms_max = gain.map(|g| g.max_band_rms);
                published.gain_ratio = gain.and_then(|g| g.ratio).map(|(ratio, _)| ratio);
                published.worst_stand = gain.and_then(|g| g.ratio).map(|(_, stand)| stand);
                let Verdict { warning, alarm, .. } = verdict;
                published.chatter_warning = warning;
                if alarm && !published.chatter_alarm {
                    tracing::warn!(
                        mill = %name,
                        detector = ?monitor.detector(),
                        gain_ratio = ?published.gain_ratio,
                        stand = ?published.worst_stand,
                        sigma_n_hz = result.sigma_n_hz,
                        k_mean = result.k_mean,
                        frequency_hz = ?published.chatter_frequency_hz,
                        "chatter alarm"
                    );
                }
                published.chatter_alarm |= alarm;
                published.source_stale = false;
                if was_flagged {
                    tracing::info!(mill = %name, "chatter window complete again");
                }
            }
            ChatterUpdate::Failed(error) => {
                if published.k_mean.is_some() {
                    tracing::warn!(mill = %name, %error, "chatter window not evaluable");
                }
                clear(published);
            }
            ChatterUpdate::Restarted(cause) => {
                if !was_flagged {
                    tracing::warn!(mill = %name, %cause, "chatter window restarted, values invalid");
                }
                clear(published);
                published.source_stale = true;
            }
        }
        published.slow_down_request = verdict.slow_down;
        record_episode(events, name, change, (was_warning, was_alarm), published);
        events.extend(AlarmRecord::flag_changes(
            (&was, &*published),
            &[AlarmKind::SlowDownRequest],
            (name, UtcTime::now()),
            published.gain_ratio,
        ));
    });
    verdict.warning
}

/// Values invalid: never a frozen old value.
fn clear(published: &mut TandemMillResults) {
    published.sigma_n_hz = None;
    published.k_mean = None;
    published.chatter_frequency_hz = None;
    published.chatter_gain = None;
    published.gain_ratio = None;
    published.band_rms_max = None;
    published.worst_stand = None;
    published.chatter_warning = false;
}
