//! A recording of a mill's stands through the service's own monitor, window by
//! window, away from the live analysis: what `millgate chatter` reports, what
//! `chatter commission` calibrates from and what the tandem mill's page plots of a
//! captured episode ([`episode_bands`]: the band RMS per window and the spectra
//! around the warning).

use std::sync::Arc;
use std::time::{Duration, Instant};

use millgate_config::Config;
use millgate_dsp::band_gain::BandGainWindow;
use millgate_dsp::chatter::{ChatterResult, MAX_STANDS};
use rustfft::num_complex::Complex;
use rustfft::FftPlanner;

use super::capture::ANCHOR_BLOCK;
use super::monitor::{ChatterMonitor, ChatterSetupError, ChatterUpdate};
use super::verdict::Verdict;
use crate::state::captures::{CaptureBands, ChatterEpisode, StandSpectrum};
use crate::state::context::{any_weld, ContextError, ProcessContext, RawContext};

/// One recording of a tandem mill's stands (read by `crate::records::stands` from
/// a CSV or a capture, or simulated by the experiments).
#[derive(Debug, Clone, PartialEq)]
pub struct Recording {
    /// Where it comes from (the file, as given), for messages.
    pub name: String,
    /// Time of each sample, s.
    pub time_s: Vec<f64>,
    /// Per stand of the mill, in its order, the samples (the channels' unit).
    pub stands: Vec<Vec<f64>>,
    /// The speed column's name and values, when one was asked for.
    pub speed: Option<(String, Vec<f64>)>,
    /// The process context recorded beside the stands (a CSV's `weld`, `speed_mpm`,
    /// `coil` and `product` columns), per sample.
    pub context: ContextColumns,
}

/// A recording's process-context columns, each per sample when recorded.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ContextColumns {
    /// The PLC's weld-tracking bit (0/1).
    pub weld: Option<Vec<f64>>,
    /// The PLC's weld-tracking bits per stand (a CSV's `weld_1` .. `weld_N`, stand 1
    /// first), each 0/1: 1 while the weld is in that stand.
    pub weld_stands: Option<Vec<Vec<f64>>>,
    /// Mill speed, m/min.
    pub speed_mpm: Option<Vec<f64>>,
    /// Coil id.
    pub coil: Option<Vec<f64>>,
    /// Product code.
    pub product: Option<Vec<f64>>,
    /// The file's line of each sample (for messages), when read from a file.
    pub lines: Option<Vec<usize>>,
}

impl ContextColumns {
    /// The column names read when present, in this order (the per-stand weld bits
    /// after `weld`: [`Self::weld_stand_column`]).
    pub const NAMES: [&'static str; 4] = ["weld", "speed_mpm", "coil", "product"];

    /// The name of stand `stand`'s weld-bit column (index in the mill; `weld_1` is
    /// the first stand's).
    pub fn weld_stand_column(stand: usize) -> String {
        format!("weld_{}", stand + 1)
    }

    /// The names of the columns recorded, in [`Self::NAMES`] order.
    pub fn names(&self) -> Vec<String> {
        let mut names = Vec::new();
        if self.weld.is_some() {
            names.push("weld".to_owned());
        }
        for stand in 0..self.weld_stands.as_ref().map_or(0, Vec::len) {
            names.push(Self::weld_stand_column(stand));
        }
        for (name, present) in Self::NAMES[1..].iter().zip([
            self.speed_mpm.is_some(),
            self.coil.is_some(),
            self.product.is_some(),
        ]) {
            if present {
                names.push((*name).to_owned());
            }
        }
        names
    }

    /// Stand `stand`'s weld bit at sample `k`, when recorded.
    pub fn stand_weld(&self, stand: usize, k: usize) -> Option<f64> {
        self.weld_stands
            .as_ref()
            .and_then(|stands| stands.get(stand))
            .and_then(|column| column.get(k).copied())
    }

    /// True when no context column was recorded.
    pub fn is_empty(&self) -> bool {
        self.weld.is_none()
            && self.weld_stands.is_none()
            && self.speed_mpm.is_none()
            && self.coil.is_none()
            && self.product.is_none()
    }

    /// The values at sample `k`; `weld` is the mill's bit and the stands' combined
    /// ([`any_weld`]: 1 when any is).
    pub fn at(&self, k: usize) -> RawContext {
        let value = |column: &Option<Vec<f64>>| column.as_ref().and_then(|c| c.get(k).copied());
        let stands = self.weld_stands.as_ref().map_or(0, Vec::len);
        let weld = (0..stands).fold(value(&self.weld), |weld, stand| {
            any_weld(weld, self.stand_weld(stand, k))
        });
        RawContext {
            weld,
            speed_mpm: value(&self.speed_mpm),
            coil: value(&self.coil),
            product: value(&self.product),
            ..RawContext::default()
        }
    }
}

/// Samples whose context was invalid ([`RawContext::check`]): not used for the
/// gating, counted.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct InvalidContext {
    /// Samples with an impossible context value.
    pub samples: usize,
    /// The first: its sample index and why.
    pub first: Option<(usize, ContextError)>,
}

impl Recording {
    /// Samples in the recording (per stand).
    pub fn len(&self) -> usize {
        self.time_s.len()
    }

    /// True when the recording holds no sample.
    pub fn is_empty(&self) -> bool {
        self.time_s.is_empty()
    }

    /// Length, s (first to last sample).
    pub fn duration_s(&self) -> f64 {
        match (self.time_s.first(), self.time_s.last()) {
            (Some(first), Some(last)) => last - first,
            _ => 0.0,
        }
    }
}

/// One evaluated window of a recording.
#[derive(Debug, Clone, PartialEq)]
pub struct Window {
    /// Time of the window's last sample, s (the recording's time axis).
    pub t_s: f64,
    /// Index of the window's last sample in the recording.
    pub last_sample: usize,
    /// The spectra's result (principal frequencies, sigma_n, K_mean).
    pub result: ChatterResult,
    /// The band gain's window per stand (band RMS, gain); `None` until it is full.
    pub gain: Option<BandGainWindow>,
    /// Largest gain / threshold; `None` until the gain's window is full or without
    /// thresholds.
    pub gain_ratio: Option<f64>,
    /// The configured detector's verdict after this window.
    pub verdict: Verdict,
    /// Whether the weld hold raised the alarm level for this window.
    pub weld_hold: bool,
    /// The context at the window's last sample; `None` without context columns or
    /// when it was invalid.
    pub context: Option<ProcessContext>,
    /// The product group whose thresholds judged the window (index in the mill's
    /// `product_groups`); `None`: the mill's `gain_thresholds`.
    pub thresholds_group: Option<usize>,
}

/// `stands` (per stand of mill `index` of `config`, in its order, equally long, with
/// the time of each sample in `time_s`, s) through the mill's monitor in
/// [`ANCHOR_BLOCK`]-sample blocks (a Modbus DAQ's), each stamped with its own sample
/// time, every window judged as the service judges it.
pub fn windows(
    config: &Config,
    index: usize,
    time_s: &[f64],
    stands: &[Vec<f64>],
) -> Result<Vec<Window>, ChatterSetupError> {
    windows_in_context(config, index, time_s, stands, &ContextColumns::default())
        .map(|(windows, _)| windows)
}

/// As [`windows`], with the process context recorded beside the stands: a block in
/// which the weld bit was set starts (or continues) the weld hold of the slow-down
/// request, as the service does with the live bit ([`super::SlowDown::weld`]; a
/// stand's bit for that stand only, [`super::SlowDown::weld_at`]); the
/// product of a block's last valid sample picks the thresholds its windows are judged
/// by (its product group's, else the mill's: [`ChatterMonitor::use_product`]; a block
/// whose last sample is invalid falls back to the mill's, as a stale product does in
/// the service); a sample whose context is invalid is not used and is counted.
pub fn windows_in_context(
    config: &Config,
    index: usize,
    time_s: &[f64],
    stands: &[Vec<f64>],
    context: &ContextColumns,
) -> Result<(Vec<Window>, InvalidContext), ChatterSetupError> {
    let mut invalid = InvalidContext::default();
    let mut monitor = ChatterMonitor::new(config, index)?;
    let mut slow_down = monitor.slow_down();
    let rate_hz = config.channels[config.tandem_mills[index].stands[0]].sample_rate_hz;
    let period = Duration::from_secs_f64(ANCHOR_BLOCK as f64 / rate_hz);
    let t0 = Instant::now();
    let samples = time_s.len();
    let mut windows = Vec::new();
    for (b, start) in (0..samples).step_by(ANCHOR_BLOCK).enumerate() {
        let end = (start + ANCHOR_BLOCK).min(samples);
        let mut last_context = None;
        if !context.is_empty() {
            let mut weld = false;
            let mut stand_welds = [false; MAX_STANDS];
            for k in start..end {
                match context.at(k).check(&[]) {
                    Ok(checked) => {
                        // Checked: every bit recorded is 0 or 1.
                        weld |= context.weld.as_ref().and_then(|c| c.get(k)) == Some(&1.0);
                        for (stand, set) in stand_welds.iter_mut().enumerate() {
                            *set |= context.stand_weld(stand, k) == Some(1.0);
                        }
                        last_context = Some(checked);
                    }
                    Err(error) => {
                        invalid.samples += 1;
                        invalid.first.get_or_insert((k, error));
                        last_context = None;
                    }
                }
            }
            if weld {
                slow_down.weld();
            }
            for (stand, _) in stand_welds.iter().enumerate().filter(|(_, set)| **set) {
                slow_down.weld_at(stand);
            }
        }
        monitor.use_product(last_context.and_then(|c| c.product));
        for (s, values) in stands.iter().enumerate() {
            let Some(change) = monitor.samples(s, &values[start..end], t0 + period * b as u32)
            else {
                continue;
            };
            let weld_hold = slow_down.weld_holding();
            let verdict = monitor.judge(&change, &mut slow_down);
            let ChatterUpdate::Evaluated(result) = change else {
                continue;
            };
            let last = usize::try_from(monitor.last_window_end() - 1)
                .unwrap_or(0)
                .min(samples - 1);
            windows.push(Window {
                t_s: time_s[last],
                last_sample: last,
                result,
                gain: monitor.gain_window().cloned(),
                gain_ratio: monitor.gain().and_then(|g| g.ratio).map(|(ratio, _)| ratio),
                verdict,
                weld_hold,
                context: last_context,
                thresholds_group: monitor.thresholds_group(),
            });
        }
    }
    Ok((windows, invalid))
}

/// Windows of the monitor on each side of the warning whose samples the spectra of
/// [`episode_bands`] average.
pub const SPECTRUM_WINDOWS_EACH_SIDE: usize = 2;

/// What the page plots of a capture of mill `index`'s stands (`stands`, sampled at
/// `sample_rate_hz`): the monitor's chatter-band RMS per stand after each window
/// ([`windows`]: the band gain's band-pass over its `gain_window_s`), and per stand
/// the Welch PSD ([`welch_psd`], segments of the monitor's window) of the samples
/// from [`SPECTRUM_WINDOWS_EACH_SIDE`] windows before the end of the warning's
/// window to as many after it (the whole capture without an `episode`, clipped to
/// the capture).
pub fn episode_bands(
    config: &Config,
    index: usize,
    sample_rate_hz: f64,
    stands: &[Vec<f64>],
    episode: Option<&ChatterEpisode>,
) -> Result<CaptureBands, ChatterSetupError> {
    let mill = &config.tandem_mills[index];
    let samples = stands.first().map_or(0, Vec::len);
    let time_s: Vec<f64> = (0..samples).map(|k| k as f64 / sample_rate_hz).collect();
    let windows = windows(config, index, &time_s, stands)?;
    let mut window_end_s = Vec::new();
    let mut band_rms = vec![Vec::new(); stands.len()];
    for window in &windows {
        let Some(gain) = &window.gain else { continue };
        window_end_s.push(window.t_s);
        for (series, &rms) in band_rms.iter_mut().zip(&gain.band_rms) {
            series.push(rms);
        }
    }
    let window = (mill.window_s * sample_rate_hz).round() as usize;
    let (start, end) = match episode {
        Some(e) => (
            e.warning_sample
                .saturating_sub((SPECTRUM_WINDOWS_EACH_SIDE + 1) * window),
            (e.warning_sample + SPECTRUM_WINDOWS_EACH_SIDE * window).min(samples),
        ),
        None => (0, samples),
    };
    let spectra = stands
        .iter()
        .map(|values| {
            welch_psd(&values[start.min(end)..end], sample_rate_hz, window).map(|psd| {
                StandSpectrum {
                    frequency_step_hz: sample_rate_hz / window as f64,
                    psd,
                }
            })
        })
        .collect::<Option<Vec<_>>>()
        .unwrap_or_default();
    Ok(CaptureBands {
        chatter_band_hz: mill.chatter_band_hz,
        window_end_s,
        band_rms,
        spectrum_span_s: (start as f64 / sample_rate_hz, end as f64 / sample_rate_hz),
        spectra,
    })
}

/// The one-sided power spectral density of `samples` (unit² / Hz at
/// `sample_rate_hz`), Welch's method as `scipy.signal.welch` computes it by default:
/// segments of `segment` samples overlapping by half (`segment / 2`), each with its
/// mean removed and a periodic Hann window, `|FFT|² / (fs * sum(w²))`, doubled except
/// at 0 Hz and (even `segment`) Nyquist, averaged. Bin `k` is `k * fs / segment` Hz.
/// `None` when `samples` is shorter than one segment or `segment` < 2.
pub fn welch_psd(samples: &[f64], sample_rate_hz: f64, segment: usize) -> Option<Vec<f64>> {
    if segment < 2 || samples.len() < segment {
        return None;
    }
    let step = segment - segment / 2;
    let hann: Vec<f64> = (0..segment)
        .map(|k| 0.5 - 0.5 * (std::f64::consts::TAU * k as f64 / segment as f64).cos())
        .collect();
    let scale = 1.0 / (sample_rate_hz * hann.iter().map(|w| w * w).sum::<f64>());
    let fft: Arc<dyn rustfft::Fft<f64>> = FftPlanner::new().plan_fft_forward(segment);
    let bins = segment / 2 + 1;
    let mut psd = vec![0.0; bins];
    let mut buffer = vec![Complex::new(0.0, 0.0); segment];
    let mut segments = 0usize;
    for start in (0..=samples.len() - segment).step_by(step) {
        let part = &samples[start..start + segment];
        let mean = part.iter().sum::<f64>() / segment as f64;
        for ((slot, x), w) in buffer.iter_mut().zip(part).zip(&hann) {
            *slot = Complex::new((x - mean) * w, 0.0);
        }
        fft.process(&mut buffer);
        for (p, c) in psd.iter_mut().zip(&buffer) {
            *p += c.norm_sqr() * scale;
        }
        segments += 1;
    }
    let last = if segment.is_multiple_of(2) {
        bins - 1
    } else {
        bins
    };
    for (k, p) in psd.iter_mut().enumerate() {
        *p /= segments as f64;
        if k > 0 && k < last {
            *p *= 2.0;
        }
    }
    Some(psd)
}

#[cfg(test)]
mod tests {
    use super::welch_psd;

    #[test]
    fn a_sine_has_its_power_in_the_psd_at_its_frequency() {
        let (fs, f, amplitude, n) = (1000.0, 125.0, 3.0, 256);
        let samples: Vec<f64> = (0..4096)
            .map(|k| amplitude * (std::f64::consts::TAU * f * k as f64 / fs).sin() + 7.0)
            .collect();
        let psd = welch_psd(&samples, fs, n).unwrap();
        let step = fs / n as f64;
        let peak = (0..psd.len())
            .max_by(|&a, &b| psd[a].total_cmp(&psd[b]))
            .unwrap();
        assert_eq!(peak as f64 * step, f);
        // Parseval: the PSD integrates to the sine's power A^2 / 2 (the mean removed).
        let power: f64 = psd.iter().sum::<f64>() * step;
        let expected = amplitude * amplitude / 2.0;
        assert!(
            (power / expected - 1.0).abs() < 0.02,
            "{power} vs {expected}"
        );
        assert!(welch_psd(&samples[..100], fs, n).is_none());
    }
}
