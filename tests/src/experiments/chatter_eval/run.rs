//! One run of the race: its windows through the gateway's monitor and the detectors'
//! figures ([`run`]); the race commissioned as `millgate chatter commission` does
//! ([`commissioned_race`]).

use std::time::{Duration, Instant};

use millgate::analysis::chatter::commission::{commission, Commissioning};
use millgate::analysis::chatter::{windows, ChatterMonitor, ChatterUpdate, Window};
use millgate_config::Config;
use millgate_dsp::band_gain::{BandGain, BandGainSettings};
use millgate_dsp::mode_damping::least_damped;
use millgate_sim::tandem::simulate::Record;
use millgate_sim::tandem::truth::ground_truth;

use super::{
    monitor_config, monitor_config_with, parallel, recording_from, simulated, EvalPlan, Figures,
    PaperFigures, RunKind, RunResult, Scenario, BLOCK, CHATTER_BAND_HZ, CONFIGURED_K_MAX,
    LONG_WINDOW_S, MARGIN, PENCIL_DECIMATION, REFERENCE_BAND_HZ, SAMPLE_RATE_HZ, WINDOW_S,
};

/// What `millgate chatter commission` makes of the race's calibration runs, and what
/// the gateway's monitor with its thresholds does in the held-out runs.
#[derive(Debug, Clone, PartialEq)]
pub struct CommissionedRace {
    /// The commissioning (thresholds, release, windows) from the calibration runs'
    /// records after the settling time.
    pub commissioning: Commissioning,
    /// Windows of the held-out and confirmation runs after the settling time in which
    /// the monitor (`detector = "band_gain"`, those thresholds and release) raised its
    /// alarm: (run index, window end s).
    pub alarms: Vec<(usize, f64)>,
    /// Scored hours of those runs.
    pub hours: f64,
}

/// Commission the band gain from the calibration runs of `scenarios` with the
/// command's code (`millgate chatter commission`, margin 10%), then run the gateway's
/// monitor with the result over every held-out and confirmation run.
pub fn commissioned_race(
    plan: &EvalPlan,
    scenarios: &[Scenario],
) -> anyhow::Result<CommissionedRace> {
    let from = (plan.settle_s * SAMPLE_RATE_HZ) as usize;
    let calibration: Vec<&Scenario> = scenarios
        .iter()
        .filter(|s| s.kind == RunKind::Calibration)
        .collect();
    let recordings = parallel(plan.threads, &calibration, |scenario| {
        let (_, record) = simulated(scenario)?;
        Ok(recording_from(
            format!("calibration seed {}", scenario.settings.seed),
            &record,
            from,
        ))
    })?;
    let stands = recordings.first().map_or(0, |r| r.stands.len());
    let commissioning = commission(
        &monitor_config_with(
            stands,
            &format!("k_max = {CONFIGURED_K_MAX}\ndetector = \"paper\"\n"),
        )?,
        0,
        &recordings,
        MARGIN * 100.0,
    )?;
    let list: Vec<String> = commissioning
        .gain_thresholds
        .iter()
        .map(|t| t.to_string())
        .collect();
    let config = monitor_config_with(
        stands,
        &format!(
            "k_max = {CONFIGURED_K_MAX}\ngain_thresholds = [{}]\nslow_down_release = {}\n",
            list.join(", "),
            commissioning.slow_down_release
        ),
    )?;
    let held_out: Vec<(usize, &Scenario)> = scenarios
        .iter()
        .enumerate()
        .filter(|(_, s)| matches!(s.kind, RunKind::HeldOut | RunKind::Confirmation))
        .collect();
    let alarms = parallel(plan.threads, &held_out, |&(index, scenario)| {
        let (_, record) = simulated(scenario)?;
        let windows = monitored_windows(&config, &record)?;
        Ok(windows
            .into_iter()
            .filter(|w| w.t_s >= plan.settle_s && w.verdict.alarm)
            .map(|w| (index, w.t_s))
            .collect::<Vec<_>>())
    })?;
    Ok(CommissionedRace {
        commissioning,
        alarms: alarms.into_iter().flatten().collect(),
        hours: held_out
            .iter()
            .map(|(_, s)| (s.settings.duration_s - plan.settle_s) / 3600.0)
            .sum(),
    })
}

/// `record` through the gateway's monitor of `config` as `millgate chatter` runs it.
fn monitored_windows(config: &Config, record: &Record) -> anyhow::Result<Vec<Window>> {
    let time_s: Vec<f64> = (0..record.len())
        .map(|k| k as f64 / SAMPLE_RATE_HZ)
        .collect();
    Ok(windows(config, 0, &time_s, &record.acceleration)?)
}

/// Simulates one scenario and runs every detector over it (the gateway's monitor only
/// with `paper`).
pub fn run(scenario: &Scenario, paper: bool) -> anyhow::Result<RunResult> {
    let (mill, record) = simulated(scenario)?;
    let truth = ground_truth(&mill, &scenario.settings.ramp, &record, scenario.critical);
    // Nothing after developed chatter (+ 2 s) is scored.
    let last = truth
        .developed_s
        .map_or(record.len(), |t| ((t + 2.0) * SAMPLE_RATE_HZ) as usize)
        .min(record.len());
    let stands = record.acceleration.len();
    let window = (WINDOW_S * SAMPLE_RATE_HZ).round() as usize;

    let hop = window / 2;
    let detector = |window_hops: usize| {
        BandGain::new(BandGainSettings {
            sample_rate_hz: SAMPLE_RATE_HZ,
            chatter_band_hz: CHATTER_BAND_HZ,
            reference_band_hz: REFERENCE_BAND_HZ,
            hop_samples: hop,
            window_hops,
            stands,
        })
        .map_err(|e| anyhow::anyhow!("{e}"))
    };
    let short = detector(2)?;
    let long = detector((LONG_WINDOW_S * SAMPLE_RATE_HZ / hop as f64).round() as usize)?;
    let (mut short_state, mut long_state) = (short.state(), long.state());
    let mut rings = vec![vec![0.0; window]; stands];
    let mut linear = vec![0.0; window];
    let mut frame = vec![0.0; stands];
    let mut windows = Vec::new();
    for k in 0..last {
        for (slot, signal) in frame.iter_mut().zip(&record.acceleration) {
            *slot = signal[k];
        }
        let done = short
            .process(&mut short_state, &frame)
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        let done_long = long
            .process(&mut long_state, &frame)
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        for (s, ring) in rings.iter_mut().enumerate() {
            ring[k % window] = short.band_sample(&short_state, s);
        }
        if let Some(result) = done {
            let mut damping = f64::INFINITY;
            for ring in &rings {
                for (i, slot) in linear.iter_mut().enumerate() {
                    *slot = ring[(k + 1 + i) % window];
                }
                if let Ok(Some((_, ratio))) =
                    least_damped(&linear, SAMPLE_RATE_HZ, PENCIL_DECIMATION, CHATTER_BAND_HZ)
                {
                    damping = damping.min(ratio);
                }
            }
            let (band_rms_long, gain_long) = done_long
                .map(|w| (w.band_rms.to_vec(), w.gain.to_vec()))
                .unwrap_or_default();
            windows.push(Figures {
                end_s: (k + 1) as f64 / SAMPLE_RATE_HZ,
                band_rms: result.band_rms.to_vec(),
                gain: result.gain.to_vec(),
                band_rms_long,
                gain_long,
                damping,
            });
        }
    }

    let config = monitor_config(stands)?;
    let mut monitor = ChatterMonitor::new(&config, 0)?;
    let t0 = Instant::now();
    let period = Duration::from_secs_f64(BLOCK as f64 / SAMPLE_RATE_HZ);
    let blocks = if paper { last.saturating_sub(BLOCK) } else { 0 };
    let mut paper = Vec::new();
    for (b, start) in (0..blocks).step_by(BLOCK).enumerate() {
        let arrival = t0 + period * b as u32;
        for (s, signal) in record.acceleration.iter().enumerate() {
            if let Some(ChatterUpdate::Evaluated(result)) =
                monitor.samples(s, &signal[start..start + BLOCK], arrival)
            {
                paper.push(PaperFigures {
                    end_s: (start + BLOCK) as f64 / SAMPLE_RATE_HZ,
                    sigma_n_hz: result.sigma_n_hz,
                    sigma_min_hz: result.sigma_min_hz,
                    k_mean: result.k_mean,
                });
            }
        }
    }
    Ok(RunResult {
        scenario: scenario.clone(),
        truth,
        windows,
        paper,
    })
}
