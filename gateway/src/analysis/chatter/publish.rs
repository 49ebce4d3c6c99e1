//! [`ChatterAnalysis`]: every tandem mill's monitor, fed by the analysis task, and
//! what each update publishes (the mill's results in the register map, the PLC
//! writes, the HMI server and `/metrics`).

use std::sync::Arc;
use std::time::{Duration, Instant};

use millgate_config::text::{AsciiText, TextError};
use millgate_config::{Config, TandemMill};

use super::align::RestartCause;
use super::capture::EpisodeRecorder;
use super::history::record_episode;
use super::monitor::{ChatterMonitor, ChatterSetupError, ChatterUpdate};
use super::spectra::chatter_frequency_hz;
use super::verdict::{SlowDown, Verdict};
use crate::analysis::context::{ContextTracker, TagValue};
use crate::field::acquired::Acquired;
use crate::state::board::Board;
use crate::state::captures::CaptureRecord;
use crate::state::context::{ContextError, ContextReading, RawContext};
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
///
/// **The weld bit** (a mill's `context.weld` tag): each value read that is 1 starts or
/// continues the mill's weld hold ([`SlowDown::weld`]), and so does every window
/// evaluated while the latest value is 1 and younger than `WELD_BIT_POLLS` poll
/// periods of its channel (a bit the PLC no longer delivers, its source stale, holds
/// nothing off). A value that is not 0 or 1 is not used and is counted
/// (`context_invalid`); a window whose alarm the hold kept off is counted
/// (`weld_held_off`). **Per stand** (`context.weld_stands`): each stand's bit does the
/// same for that stand's level only ([`SlowDown::weld_at`]); the counts are the
/// mill's, as with the mill's bit.
///
/// **The product** (a mill's `context.product` tag, with `product_groups`): one reading
/// of the mill's context (`ContextTracker::reading`) serves each message: its product
/// picks the thresholds the windows are judged by ([`ChatterMonitor::use_product`]:
/// its group's, else the mill's), and the same reading is the context the episodes and
/// captures carry. The product tag's value is used while younger than its source's
/// stale time (the context's rule: three poll periods or two Modbus timeouts). A code outside the context's
/// `products` (or not a whole number) is not used and is counted (`context_invalid`);
/// an invalid context (any impossible value) gives no product. A window judged by the
/// mill's thresholds because no valid, fresh product was there is counted
/// (`product_fallback`). The thresholds in use are published (`thresholds_group`, and
/// the group's name on the page). A product change while the alarm or the slow-down
/// request is set leaves both set: the latched alarm waits for its acknowledgement
/// as ever, and the request clears by the release level and hold against the new
/// group's thresholds (as after a reload).
#[derive(Debug)]
pub struct ChatterAnalysis {
    monitors: Vec<ChatterMonitor>,
    /// Per mill, the slow-down request.
    slow_downs: Vec<SlowDown>,
    /// Per mill, its chatter-episode captures (with `[history]` and captures on).
    captures: Vec<Option<EpisodeRecorder>>,
    /// Per channel: the (mill, stand) pairs it feeds.
    by_channel: Vec<Vec<(usize, usize)>>,
    /// Per channel: the weld bits it is (mill, index in `weld_bits[mill]`).
    weld_by_channel: Vec<Vec<(usize, usize)>>,
    /// Per mill, its weld bits: the mill's, or one per stand.
    weld_bits: Vec<Vec<WeldBit>>,
    /// Per mill with context tags, their latest values: the context its episodes and
    /// captures carry, and the product that picks its thresholds.
    contexts: Vec<Option<ContextTracker>>,
    /// Per channel: the mills whose context tag it is.
    context_by_channel: Vec<Vec<usize>>,
    /// Per channel: the mills whose product tag it is (its impossible values counted).
    product_by_channel: Vec<Vec<usize>>,
    /// Per mill, its context's known product codes (empty: any).
    known_products: Vec<Vec<u32>>,
    board: Arc<Board>,
}

/// Poll periods of its channel after which the latest weld bit (or product code) is
/// no longer used.
pub(super) const WELD_BIT_POLLS: f64 = 3.0;

/// One weld-tracking bit of a mill: the mill's (`context.weld`) or a stand's
/// (`context.weld_stands`).
#[derive(Debug, Clone)]
struct WeldBit {
    /// The stand (index in the mill) it tracks; `None`: the whole mill.
    stand: Option<usize>,
    /// The oldest value still used ([`WELD_BIT_POLLS`] poll periods).
    max_age: Duration,
    /// The latest valid value and when it was read.
    latest: Option<(bool, Instant)>,
}

impl WeldBit {
    /// Start (or continue) the weld hold this bit gives in `slow_down`.
    fn hold(&self, slow_down: &mut SlowDown) {
        match self.stand {
            None => slow_down.weld(),
            Some(stand) => slow_down.weld_at(stand),
        }
    }

    /// Hold `slow_down` when the latest value at `now` is a fresh 1.
    fn hold_if_set(&self, slow_down: &mut SlowDown, now: Instant) {
        if let Some((true, at)) = self.latest {
            if now.saturating_duration_since(at) <= self.max_age {
                self.hold(slow_down);
            }
        }
    }
}

impl ChatterAnalysis {
    /// Monitors for every tandem mill of `config`.
    pub fn new(config: &Config, board: Arc<Board>) -> Result<Self, ChatterSetupError> {
        let mut by_channel = vec![Vec::new(); config.channels.len()];
        let mut weld_by_channel = vec![Vec::new(); config.channels.len()];
        let mut product_by_channel = vec![Vec::new(); config.channels.len()];
        let mut weld_bits = Vec::new();
        let mut contexts = Vec::new();
        let mut context_by_channel = vec![Vec::new(); config.channels.len()];
        let mut monitors = Vec::new();
        let max_age = |tag: Option<usize>| {
            let poll_s = tag.map_or(0.0, |channel| 1.0 / config.channels[channel].sample_rate_hz);
            Duration::from_secs_f64(WELD_BIT_POLLS * poll_s)
        };
        for (m, mill) in config.tandem_mills.iter().enumerate() {
            monitors.push(ChatterMonitor::new(config, m)?);
            for (s, &channel) in mill.stands.iter().enumerate() {
                by_channel[channel].push((m, s));
            }
            let bits: Vec<(usize, Option<usize>)> = mill
                .context
                .weld
                .map(|channel| (channel, None))
                .into_iter()
                .chain(
                    mill.context
                        .weld_stands
                        .iter()
                        .enumerate()
                        .map(|(stand, &channel)| (channel, Some(stand))),
                )
                .collect();
            for (slot, &(channel, _)) in bits.iter().enumerate() {
                weld_by_channel[channel].push((m, slot));
            }
            weld_bits.push(
                bits.iter()
                    .map(|&(channel, stand)| WeldBit {
                        stand,
                        max_age: max_age(Some(channel)),
                        latest: None,
                    })
                    .collect(),
            );
            if let Some(product) = mill.context.product {
                product_by_channel[product].push(m);
            }
            let tracker = ContextTracker::new(&mill.context, config, None);
            for channel in tracker.iter().flat_map(ContextTracker::channels) {
                context_by_channel[channel].push(m);
            }
            contexts.push(tracker);
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
            weld_bits,
            monitors,
            by_channel,
            weld_by_channel,
            contexts,
            context_by_channel,
            product_by_channel,
            known_products: config
                .tandem_mills
                .iter()
                .map(|mill| mill.context.products.clone())
                .collect(),
            board,
        })
    }

    /// A process value `value` of `channel`: a context tag of the mills whose tag it
    /// is (the context their episodes and captures carry), and their weld bit or
    /// product.
    fn context_value(&mut self, channel: usize, value: f64, now: Instant) {
        for m in 0..self.product_by_channel.get(channel).map_or(0, Vec::len) {
            let mill = self.product_by_channel[channel][m];
            let check = |value: f64| {
                let raw = RawContext {
                    product: Some(value),
                    ..RawContext::default()
                };
                raw.check(&self.known_products[mill])
            };
            if let Err(error) = check(value) {
                let was_valid = self.contexts[mill]
                    .as_ref()
                    .and_then(|tracker| tracker.latest("product"))
                    .is_some_and(|latest| check(latest).is_ok());
                self.invalid_context(mill, &error, was_valid);
            }
        }
        for &mill in self.context_by_channel.get(channel).into_iter().flatten() {
            if let Some(tracker) = &mut self.contexts[mill] {
                tracker.value(channel, TagValue::Number(value), now);
            }
        }
        for w in 0..self.weld_by_channel.get(channel).map_or(0, Vec::len) {
            let (mill, slot) = self.weld_by_channel[channel][w];
            let weld = &mut self.weld_bits[mill][slot];
            let raw = RawContext {
                weld: Some(value),
                ..RawContext::default()
            };
            match raw.check(&[]) {
                Ok(context) => {
                    let bit = context.weld == Some(true);
                    weld.latest = Some((bit, now));
                    if bit {
                        weld.hold(&mut self.slow_downs[mill]);
                    }
                }
                Err(error) => {
                    let was_valid = weld.latest.take().is_some();
                    self.invalid_context(mill, &error, was_valid);
                }
            }
        }
    }

    /// A text `text` of `channel` (a coil id, or why its registers held none): the
    /// coil of the mills whose tag it is; a text that is none is counted as an
    /// invalid context value.
    fn context_text(&mut self, channel: usize, text: Result<AsciiText, TextError>, now: Instant) {
        for m in 0..self.context_by_channel.get(channel).map_or(0, Vec::len) {
            let mill = self.context_by_channel[channel][m];
            let Some(tracker) = &mut self.contexts[mill] else {
                continue;
            };
            let was_valid = matches!(tracker.latest_value("coil"), Some(TagValue::Text(Ok(_))));
            tracker.value(channel, TagValue::Text(text), now);
            if let Err(error) = text {
                self.invalid_context(mill, &ContextError::CoilText(error), was_valid);
            }
        }
    }

    /// Mill `mill`'s context value was impossible (`error`): counted, and said in the
    /// log when the tag's previous value was valid (`was_valid`).
    fn invalid_context(&self, mill: usize, error: &ContextError, was_valid: bool) {
        if was_valid {
            tracing::warn!(
                mill = %self.monitors[mill].name(),
                %error,
                "context value invalid, not used for the gating"
            );
        }
        self.board.update(|results| {
            if let Some(published) = results.tandem_mills.get_mut(mill) {
                published.context_invalid += 1;
            }
        });
    }

    /// Keep mill `mill`'s stands' next `seconds` s as a capture of kind `manual`;
    /// false when the mill does not exist or captures are not kept.
    pub(crate) fn start_manual_capture(&mut self, mill: usize, seconds: f64) -> bool {
        let context = self.context_at(mill, Instant::now());
        match self.captures.get_mut(mill) {
            Some(Some(recorder)) => {
                recorder.start_manual(seconds, context);
                true
            }
            _ => false,
        }
    }

    /// Mill `mill`'s context at `now`; `None` without context tags.
    fn context_at(&self, mill: usize, now: Instant) -> Option<ContextReading> {
        self.contexts
            .get(mill)?
            .as_ref()
            .map(|tracker| tracker.reading(now))
    }

    /// Judge each mill by its entry of `mills` (config order) from its next window on
    /// (a reload: [`ChatterMonitor::set_thresholds`]); a slow-down request already set
    /// stays set, and clears by the new release level and hold.
    pub fn set_thresholds(&mut self, mills: &[TandemMill]) {
        let monitors = self.monitors.iter_mut().zip(&mut self.slow_downs);
        for ((monitor, slow_down), mill) in monitors.zip(mills) {
            monitor.set_thresholds(mill);
            slow_down.retune(&monitor.slow_down());
        }
    }

    /// The monitors, in config order.
    pub fn monitors(&self) -> &[ChatterMonitor] {
        &self.monitors
    }

    /// Route one reader message to the mills whose stand it is, and publish what
    /// changed.
    pub fn handle(&mut self, message: &Acquired) {
        self.handle_at(message, Instant::now());
    }

    /// [`Self::handle`] with the message arriving at `now` (the analysis' rounds give
    /// a block the instant its reader handed it over; tests replay a DAQ's pace
    /// without waiting for it).
    pub(crate) fn handle_at(&mut self, message: &Acquired, now: Instant) {
        let channel = match message {
            Acquired::Samples { channel, .. } | Acquired::Gap { channel, .. } => *channel,
            Acquired::ProcessValue { channel, value } => {
                self.context_value(*channel, *value, now);
                return;
            }
            Acquired::Text { channel, text } => {
                self.context_text(*channel, *text, now);
                return;
            }
        };
        let Some(stands) = self.by_channel.get(channel) else {
            return;
        };
        for &(mill, stand) in stands {
            // One reading: its product picks the thresholds, and it is the context of
            // an episode or capture this message ends or starts.
            let context = self.context_at(mill, now);
            let product = context.and_then(|reading| reading.trusted().product);
            let monitor = &mut self.monitors[mill];
            monitor.use_product(product);
            let product_fallback = product.is_none() && monitor.has_product_groups();
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
                Acquired::ProcessValue { .. } | Acquired::Text { .. } => None,
            };
            if let Some(change) = change {
                for weld in &self.weld_bits[mill] {
                    weld.hold_if_set(&mut self.slow_downs[mill], now);
                }
                let warning = publish(
                    &self.board,
                    (mill, monitor),
                    &mut self.slow_downs[mill],
                    (&change, context),
                    product_fallback,
                );
                if let Some(recorder) = recorder.as_mut() {
                    done.extend(recorder.warning(warning, monitor.last_window_end(), context));
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
/// chatter episodes (from the warning condition set to it cleared, with the mill's
/// `context` at its start) and the alarm. `product_fallback`: the mill's thresholds
/// judge because no valid, fresh product was there (counted). Returns the warning as
/// published.
fn publish(
    board: &Board,
    (mill, monitor): (usize, &ChatterMonitor),
    slow_down: &mut SlowDown,
    (change, context): (&ChatterUpdate, Option<ContextReading>),
    product_fallback: bool,
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
                published.thresholds_group = Some(monitor.thresholds_group().map_or(0, |g| g + 1));
                if published.thresholds_group_name.as_deref() != monitor.thresholds_group_name() {
                    tracing::info!(
                        mill = %name,
                        group = ?monitor.thresholds_group_name(),
                        "chatter thresholds in use changed (None: the mill's)"
                    );
                    published.thresholds_group_name =
                        monitor.thresholds_group_name().map(str::to_owned);
                }
                if published.gain_thresholds_in_use.as_deref() != Some(monitor.thresholds()) {
                    published.gain_thresholds_in_use = Some(monitor.thresholds().into());
                }
                published.product_fallback += u64::from(product_fallback);
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
                if verdict.held_off {
                    published.weld_held_off += 1;
                    tracing::debug!(
                        mill = %name,
                        gain_ratio = ?published.gain_ratio,
                        "chatter alarm held off: a weld is in the mill or settling"
                    );
                }
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
                let count = match cause {
                    RestartCause::Gap { .. } => &mut published.window_restarts_gap,
                    RestartCause::Lagging { .. } => &mut published.window_restarts_lagging,
                    RestartCause::Realigned { .. } => &mut published.window_restarts_realigned,
                };
                *count += 1;
                if !was_flagged {
                    tracing::warn!(mill = %name, %cause, "chatter window restarted, values invalid");
                }
                clear(published);
                published.source_stale = true;
            }
        }
        published.slow_down_request = verdict.slow_down;
        record_episode(
            events,
            (name, context),
            change,
            (was_warning, was_alarm),
            published,
        );
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::analysis::chatter::testing::{example_with_quiet_group, lines_recording};

    /// The example tandem mill (thresholds from the race: stand 1's is 1.187) with a
    /// weld bit on the PLC; the channel index of the weld bit.
    fn mill_with_weld_bit() -> (Config, usize) {
        let examples = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/examples");
        let text = std::fs::read_to_string(examples.join("tandem-5stand.toml")).expect("example");
        let text = text.replacen(
            "[[tandem_mills]]",
            "[[channels]]\nname = \"weld_in_mill\"\nkind = \"process_value\"\nunit = \"1\"\n\
             source = { modbus = \"mill_plc\", table = \"holding\", address = 10 }\n\n\
             [[tandem_mills]]\ncontext = { weld = \"weld_in_mill\" }",
            1,
        );
        let config = millgate_config::from_toml_str(&text, "tandem.toml", &examples)
            .unwrap_or_else(|error| panic!("{error}"));
        let weld = config.tandem_mills[0].context.weld.expect("the weld tag");
        (config, weld)
    }

    /// 6 s of a chatter-band line at gain 1.6 (0.8 over the reference's 0.5: 1.35
    /// times stand 1's threshold, below the weld hold's 2) through the service's
    /// analysis, `weld` sent as the weld bit before each block when given; the
    /// mill's results after.
    fn run(weld: Option<f64>) -> TandemMillResults {
        let (config, weld_channel) = mill_with_weld_bit();
        run_with(&config, weld_channel, |_| weld).0
    }

    /// The example tandem mill with a product tag on the PLC and the product group
    /// "quiet" (product 7, every threshold 10 times the mill's); the product channel.
    fn mill_with_product_groups() -> (Config, usize) {
        let examples = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/examples");
        let text = example_with_quiet_group("product = \"product_code\", products = [7, 8]");
        let config = millgate_config::from_toml_str(&text, "tandem.toml", &examples)
            .unwrap_or_else(|error| panic!("{error}"));
        let product = config.tandem_mills[0]
            .context
            .product
            .expect("the product tag");
        (config, product)
    }

    /// [`run`]'s line through the analysis of `config`, `context(block)` sent on
    /// channel `context_channel` before each block when given; the mill's results
    /// after, and the gain ratio published after each block.
    fn run_with(
        config: &Config,
        context_channel: usize,
        context: impl Fn(usize) -> Option<f64>,
    ) -> (TandemMillResults, Vec<Option<f64>>) {
        run_with_values(config, |block| {
            context(block)
                .map(|value| (context_channel, value))
                .into_iter()
                .collect()
        })
    }

    /// [`run`]'s line through the analysis of `config`, the `(channel, value)` pairs
    /// of `values(block)` sent before each block; the mill's results after, and the
    /// gain ratio published after each block.
    fn run_with_values(
        config: &Config,
        values: impl Fn(usize) -> Vec<(usize, f64)>,
    ) -> (TandemMillResults, Vec<Option<f64>>) {
        let board = Arc::new(Board::new(config, Vec::new()));
        let mut analysis = ChatterAnalysis::new(config, Arc::clone(&board)).expect("analysis");
        let recording = lines_recording(15_000, |_| 0.8);
        let stands = config.tandem_mills[0].stands.clone();
        let mut ratios = Vec::new();
        // A block every 48 ms, as the DAQ delivers them.
        let t0 = Instant::now();
        for (block, start) in (0..recording.len()).step_by(120).enumerate() {
            let now = t0 + Duration::from_millis(48) * block as u32;
            for (channel, value) in values(block) {
                analysis.handle_at(&Acquired::ProcessValue { channel, value }, now);
            }
            for (stand, &channel) in stands.iter().enumerate() {
                let message = Acquired::Samples {
                    channel,
                    values: recording.stands[stand][start..start + 120].to_vec(),
                    received: None,
                    handed: now,
                };
                analysis.handle_at(&message, now);
            }
            ratios.push(board.results().tandem_mills[0].gain_ratio);
        }
        (board.results().tandem_mills[0].clone(), ratios)
    }

    #[test]
    fn the_plcs_product_picks_its_groups_thresholds_and_a_missing_one_falls_back_counted() {
        let (config, product) = mill_with_product_groups();
        // Product 7, the "quiet" group's: thresholds 10 times the mill's, ratio 0.135.
        let (quiet, _) = run_with(&config, product, |_| Some(7.0));
        assert_eq!(quiet.thresholds_group, Some(1), "{quiet:?}");
        assert_eq!(quiet.thresholds_group_name.as_deref(), Some("quiet"));
        assert!(
            quiet.gain_ratio.is_some_and(|r| r > 0.12 && r < 0.15),
            "{quiet:?}"
        );
        assert!(
            !quiet.chatter_alarm && !quiet.slow_down_request,
            "{quiet:?}"
        );
        assert_eq!((quiet.product_fallback, quiet.context_invalid), (0, 0));

        // Product 8 is known but in no group: the mill's thresholds, no fallback counted.
        let (other, _) = run_with(&config, product, |_| Some(8.0));
        assert_eq!(other.thresholds_group, Some(0), "{other:?}");
        assert_eq!(other.thresholds_group_name, None);
        assert!(other.chatter_alarm && other.slow_down_request, "{other:?}");
        assert_eq!((other.product_fallback, other.context_invalid), (0, 0));

        // No product value at all: the mill's, every window counted as a fallback.
        let (none, _) = run_with(&config, product, |_| None);
        assert_eq!(none.thresholds_group, Some(0));
        assert!(none.chatter_alarm, "{none:?}");
        assert_eq!(none.product_fallback, none.evaluations);

        // An unknown code (9, not in `products`) is invalid: counted, not used.
        let (invalid, _) = run_with(&config, product, |_| Some(9.0));
        assert_eq!(invalid.thresholds_group, Some(0));
        assert_eq!(invalid.context_invalid, 125, "one per block");
        assert_eq!(invalid.product_fallback, invalid.evaluations);

        // Product 7 read once, then the PLC's value goes stale (its source's stale
        // time: two timeouts of the PLC, longer than 3 polls of 100 ms): the group's
        // thresholds until then, the mill's from the next window on, counted.
        let (stale, ratios) = run_with(&config, product, |block| (block == 0).then_some(7.0));
        assert_eq!(stale.thresholds_group, Some(0), "{stale:?}");
        assert!(stale.chatter_alarm, "{stale:?}");
        assert!(
            stale.product_fallback > 0 && stale.product_fallback < stale.evaluations,
            "{stale:?}"
        );
        let stale_after = match config.channels[product].source {
            millgate_config::ChannelSource::ModbusValue { source, .. } => {
                config.modbus_sources[source].timeout * 2
            }
            _ => panic!("the example's product is a PLC register"),
        };
        let raised = ratios.iter().position(|r| r.is_some_and(|r| r > 1.2));
        let raised_at = Duration::from_millis(48) * raised.expect("the mill's thresholds") as u32;
        // A window every 0.25 s (5.2 blocks of 48 ms) after the value went stale.
        assert!(
            raised_at >= stale_after && raised_at <= stale_after + Duration::from_millis(300),
            "{raised_at:?} against {stale_after:?}: {ratios:?}"
        );

        // The product changes mid-coil from 7 to 8 at block 80 (3.84 s): the ratio
        // jumps tenfold with the next window (a hop of 0.25 s is 5.2 blocks), the
        // alarm follows.
        let (switched, ratios) = run_with(&config, product, |block| {
            Some(if block < 80 { 7.0 } else { 8.0 })
        });
        assert!(ratios[79].is_some_and(|r| r < 0.15), "{ratios:?}");
        assert!(ratios[86].is_some_and(|r| r > 1.2), "{ratios:?}");
        assert_eq!(switched.thresholds_group, Some(0));
        assert!(switched.chatter_alarm && switched.slow_down_request);
    }

    /// The example tandem mill with a weld bit per stand on the PLC; their channels.
    fn mill_with_weld_stands() -> (Config, Vec<usize>) {
        let examples = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/examples");
        let text = std::fs::read_to_string(examples.join("tandem-5stand.toml")).expect("example");
        let channels: String = (1..=5)
            .map(|s| {
                format!(
                    "[[channels]]\nname = \"weld_s{s}\"\nkind = \"process_value\"\nunit = \"1\"\n\
                     source = {{ modbus = \"mill_plc\", table = \"holding\", address = {} }}\n\n",
                    10 + s
                )
            })
            .collect();
        let text = text.replacen(
            "[[tandem_mills]]",
            &format!(
                "{channels}[[tandem_mills]]\ncontext = {{ weld_stands = [\"weld_s1\", \"weld_s2\", \
                 \"weld_s3\", \"weld_s4\", \"weld_s5\"] }}"
            ),
            1,
        );
        let config = millgate_config::from_toml_str(&text, "tandem.toml", &examples)
            .unwrap_or_else(|error| panic!("{error}"));
        let welds = config.tandem_mills[0].context.weld_stands.clone();
        (config, welds)
    }

    #[test]
    fn a_stands_live_weld_bit_holds_that_stand_only_and_an_impossible_one_is_counted() {
        // The line at gain 1.6: 1.35 times stand 1's threshold, 1.07 times stand 2's
        // (with margin: 1.0 the hold's 2 would hold both), below the others'.
        let (config, welds) = mill_with_weld_stands();
        let bits = |set: &'static [usize], value: f64| {
            let welds = welds.clone();
            move |_| -> Vec<(usize, f64)> {
                welds
                    .iter()
                    .enumerate()
                    .map(|(stand, &channel)| {
                        (channel, if set.contains(&stand) { value } else { 0.0 })
                    })
                    .collect()
            }
        };
        // The weld in stands 1 and 2: both held, nothing raised, counted.
        let (both, _) = run_with_values(&config, bits(&[0, 1], 1.0));
        assert!(!both.chatter_alarm && !both.slow_down_request, "{both:?}");
        assert!(both.weld_held_off > 10, "{both:?}");
        assert_eq!(both.context_invalid, 0);
        // In stand 1 only: stand 2 is judged at its plain level.
        let (first, _) = run_with_values(&config, bits(&[0], 1.0));
        assert!(first.chatter_alarm && first.slow_down_request, "{first:?}");
        // In stand 3 only: as without a weld (stand 1's ratio raises it).
        let (third, _) = run_with_values(&config, bits(&[2], 1.0));
        assert!(third.slow_down_request, "{third:?}");
        assert_eq!(third.weld_held_off, 0, "{third:?}");
        // Stands 1 and 2 at 0.5: no bit, counted per value, not used.
        let (invalid, _) = run_with_values(&config, bits(&[0, 1], 0.5));
        assert!(invalid.slow_down_request, "{invalid:?}");
        assert_eq!(invalid.context_invalid, 250, "two per block");
        assert_eq!(invalid.weld_held_off, 0);
    }

    /// The product that picks the thresholds is the one of the context reading the
    /// evidence carries: a valid product 7 beside an impossible speed is an invalid
    /// context, with no product; the mill's thresholds judge, counted as a fallback.
    #[test]
    fn an_invalid_context_picks_no_groups_thresholds_as_it_tags_no_product() {
        let examples = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/examples");
        let text = example_with_quiet_group(
            "product = \"product_code\", products = [7, 8], speed_mpm = \"exit_strip_speed\"",
        );
        let config = millgate_config::from_toml_str(&text, "tandem.toml", &examples)
            .unwrap_or_else(|error| panic!("{error}"));
        let tags = &config.tandem_mills[0].context;
        let (product, speed) = (
            tags.product.expect("product"),
            tags.speed_mpm.expect("speed"),
        );
        let (valid, _) = run_with_values(&config, |_| vec![(product, 7.0), (speed, 600.0)]);
        assert_eq!(valid.thresholds_group, Some(1), "{valid:?}");
        assert_eq!(valid.product_fallback, 0);
        let (invalid, _) = run_with_values(&config, |_| vec![(product, 7.0), (speed, -5.0)]);
        assert_eq!(invalid.thresholds_group, Some(0), "{invalid:?}");
        assert_eq!(invalid.thresholds_group_name, None);
        assert!(invalid.chatter_alarm, "{invalid:?}");
        assert_eq!(invalid.product_fallback, invalid.evaluations, "{invalid:?}");
    }

    #[test]
    fn the_live_weld_bit_holds_the_alarm_off_and_an_impossible_bit_is_counted_not_used() {
        let plain = run(None);
        assert!(plain.evaluations > 15, "{plain:?}");
        assert!(
            plain.gain_ratio.is_some_and(|r| r > 1.2 && r < 1.5),
            "{plain:?}"
        );
        assert!(plain.chatter_alarm && plain.slow_down_request, "{plain:?}");
        assert_eq!((plain.weld_held_off, plain.context_invalid), (0, 0));

        let welding = run(Some(1.0));
        assert!(
            !welding.chatter_alarm && !welding.slow_down_request,
            "{welding:?}"
        );
        assert!(welding.weld_held_off > 10, "{welding:?}");
        assert_eq!(welding.context_invalid, 0);

        let not_welding = run(Some(0.0));
        assert!(not_welding.slow_down_request, "{not_welding:?}");
        assert_eq!(not_welding.weld_held_off, 0);

        // 0.5 is no bit: counted, not used (the alarm is raised as without a weld).
        let invalid = run(Some(0.5));
        assert!(invalid.slow_down_request, "{invalid:?}");
        assert_eq!(invalid.context_invalid, 125, "one per block");
        assert_eq!(invalid.weld_held_off, 0);
    }
}
