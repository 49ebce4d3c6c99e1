//! `millgate analyze`: detect every bite in a recorded CSV and analyse it (transient
//! measures and the eq. (1) fit), or analyse one given time window as one event.
//!
//! Detection uses fixed offline settings: a rise of [`THRESHOLD_KNM`] above the
//! baseline (EMA with a 0.5 s time constant), re-arm within [`REARM_KNM`] after a
//! 0.5 s hold-off, 0.1 s before and 0.6 s after the trigger (within the gateway's
//! window capacity). `t_bite_s` is the load onset: the last sample before the trigger
//! within [`ONSET_KNM`] of the baseline, where eq. (1) has t = 0.
//!
//! A capture exported by `millgate capture export` (the JSON file beside it, or the
//! `# millgate capture` line of an export written before, holds how the gateway read
//! the window) is analysed as the gateway did: one event
//! with the window's trigger, baseline, onset and transient settings, at the stored
//! sample rate, so the figures are the ones the gateway published for that bite.

use std::fmt::Write as _;
use std::path::PathBuf;
use std::str::FromStr;

use anyhow::{bail, Context as _};
use millgate_dsp::bite::{BiteDetector, BiteSettings};
use millgate_dsp::fit::{Eq1Fit, FitStatus};
use millgate_dsp::transient::{TransientQuality, TransientSettings};
use serde_json::{json, Value};

use super::OutputFormat;
use crate::analysis::bite_window::{
    analyze_window, WindowAnalysis, PRE_TRIGGER_CAPACITY, WINDOW_CAPACITY,
};
use crate::records::csv;
use crate::state::captures::BiteWindowAnalysis;

/// Rise above the baseline that marks a bite, kN*m.
pub const THRESHOLD_KNM: f64 = 20.0;
/// Distance to the baseline that re-arms the detector, kN*m.
pub const REARM_KNM: f64 = 10.0;
/// Distance to the baseline under which a sample still counts as before the load
/// onset, kN*m. Small, so that eq. (1)'s t = 0 falls on the start of the rise: an
/// origin a few ms late biases f1 by about 1% on the Table 1 curve.
pub const ONSET_KNM: f64 = 2.0;

/// A time window `START,END` in seconds, START < END.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TimeWindow {
    /// Start, s.
    pub start_s: f64,
    /// End, s (inclusive).
    pub end_s: f64,
}

impl FromStr for TimeWindow {
    type Err = String;

    fn from_str(text: &str) -> Result<Self, Self::Err> {
        let (start, end) = text
            .split_once(',')
            .ok_or_else(|| format!("expected START,END in seconds, got `{text}`"))?;
        let parse = |s: &str| {
            s.trim()
                .parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| format!("`{s}` is not a time in seconds"))
        };
        let window = Self {
            start_s: parse(start)?,
            end_s: parse(end)?,
        };
        if window.start_s >= window.end_s {
            return Err(format!("START must be before END, got `{text}`"));
        }
        Ok(window)
    }
}

/// Arguments of `millgate analyze`.
#[derive(Debug, Clone, clap::Args)]
pub struct AnalyzeArgs {
    /// CSV with a header: first column `t` (s), other columns channels (kN*m).
    #[arg(long)]
    pub input: PathBuf,
    /// Channel to analyse (default: the first after `t`).
    #[arg(long)]
    pub channel: Option<String>,
    /// Analyse START,END (s) as one event starting at START (records cut at the bite).
    #[arg(long)]
    pub window: Option<TimeWindow>,
    /// Output format.
    #[arg(long, value_enum, default_value_t = OutputFormat::Text)]
    pub format: OutputFormat,
}

/// One analysed event.
struct Event {
    t_bite_s: f64,
    analysis: WindowAnalysis,
}

fn transient_settings(rate: f64) -> TransientSettings {
    TransientSettings {
        sample_rate_hz: rate,
        period_lowpass_hz: 40.0_f64.min(0.4 * rate),
        peak_lowpass_hz: Some(60.0_f64.min(0.4 * rate)),
        settled_fraction: 0.3,
        min_static_knm: 1.0,
        reference_shift_s: None,
    }
}

/// Runs the command; returns the text to print.
pub fn run(args: &AnalyzeArgs) -> anyhow::Result<String> {
    let table = csv::read(&args.input).with_context(|| args.input.display().to_string())?;
    let (name, signal) = table
        .pick_torque(args.channel.as_deref())
        .map_err(|e| anyhow::anyhow!("{}: {e}", args.input.display()))?;
    let rate = table
        .sample_rate_hz()
        .map_err(|e| anyhow::anyhow!("{}: {e}", args.input.display()))?;
    let capture = table
        .capture_header()
        .map_err(|e| anyhow::anyhow!("{}: {e}", args.input.display()))?;
    let bite_window = capture
        .and_then(|header| Some((header.sample_rate_hz, header.analysis?)))
        .filter(|_| args.window.is_none());
    let (rate, events) = match bite_window {
        Some((rate, analysis)) => (
            rate,
            vec![analyse_capture(&table.time_s, signal, rate, &analysis)?],
        ),
        None => {
            let settings = transient_settings(rate);
            let events = match args.window {
                Some(window) => vec![analyse_window(&table.time_s, signal, window, &settings)?],
                None => detect(&table.time_s, signal, rate, &settings)?,
            };
            (rate, events)
        }
    };
    Ok(match args.format {
        OutputFormat::Json => {
            let events: Vec<Value> = events.iter().map(event_json).collect();
            json!({ "events": events }).to_string()
        }
        OutputFormat::Text => text(name, rate, &events)?,
    })
}

fn analyse_window(
    time_s: &[f64],
    signal: &[f64],
    window: TimeWindow,
    settings: &TransientSettings,
) -> anyhow::Result<Event> {
    let first = time_s.partition_point(|&t| t < window.start_s);
    let end = time_s.partition_point(|&t| t <= window.end_s);
    let samples = &signal[first..end];
    // The transient needs the trigger sample and 4 after it.
    if !(5..=WINDOW_CAPACITY).contains(&samples.len()) {
        bail!(
            "--window {},{}: the window holds {} samples; the analysis needs 5..={WINDOW_CAPACITY}",
            window.start_s,
            window.end_s,
            samples.len()
        );
    }
    let analysis = analyze_window(samples, 0, 0.0, ONSET_KNM, settings)
        .with_context(|| format!("analysing {}..{} s", window.start_s, window.end_s))?;
    Ok(Event {
        t_bite_s: time_s.get(first).copied().unwrap_or(window.start_s),
        analysis,
    })
}

/// A captured bite window, analysed with the settings the gateway read it with.
fn analyse_capture(
    time_s: &[f64],
    signal: &[f64],
    rate: f64,
    capture: &BiteWindowAnalysis,
) -> anyhow::Result<Event> {
    let settings = TransientSettings {
        sample_rate_hz: rate,
        period_lowpass_hz: capture.period_lowpass_hz,
        peak_lowpass_hz: capture.peak_lowpass_hz,
        settled_fraction: capture.settled_fraction,
        min_static_knm: capture.min_static_knm,
        reference_shift_s: None,
    };
    if signal.len() > WINDOW_CAPACITY || capture.trigger_index >= signal.len() {
        bail!(
            "the capture's window holds {} samples with its trigger at {}; the analysis needs              at most {WINDOW_CAPACITY} and the trigger inside",
            signal.len(),
            capture.trigger_index
        );
    }
    let analysis = analyze_window(
        signal,
        capture.trigger_index,
        capture.baseline_knm,
        capture.onset_knm,
        &settings,
    )
    .context("analysing the captured bite window")?;
    Ok(Event {
        t_bite_s: time_s[analysis.fit_start_index],
        analysis,
    })
}

fn detect(
    time_s: &[f64],
    signal: &[f64],
    rate: f64,
    settings: &TransientSettings,
) -> anyhow::Result<Vec<Event>> {
    let post = ((0.6 * rate) as usize).clamp(1, WINDOW_CAPACITY - PRE_TRIGGER_CAPACITY);
    let detector = BiteDetector::<PRE_TRIGGER_CAPACITY, WINDOW_CAPACITY>::new(BiteSettings {
        threshold_knm: THRESHOLD_KNM,
        rearm_knm: REARM_KNM,
        holdoff_samples: (0.5 * rate) as u32,
        baseline_alpha: (1.0 / (0.5 * rate)).min(1.0),
        saturation_low_knm: f64::NEG_INFINITY,
        saturation_high_knm: f64::INFINITY,
        post_trigger_samples: post,
    })
    .context("detector settings")?;
    let mut state = detector.state();
    let mut windows = Vec::new();
    detector.block(&mut state, signal, |event| windows.push(event));
    // A bite too close to the end of the record for a full window: the end of the
    // record ends the capture like a gap, with the samples there are.
    windows.extend(detector.gap(&mut state, 0));
    let mut events = Vec::new();
    for event in windows {
        // Window sample k is absolute sample trigger_sample - trigger_index + k.
        let start = event.trigger_sample as usize - event.trigger_index;
        match analyze_window(
            &event.window,
            event.trigger_index,
            event.baseline_knm,
            ONSET_KNM,
            settings,
        ) {
            Ok(analysis) => events.push(Event {
                t_bite_s: time_s[start + analysis.fit_start_index],
                analysis,
            }),
            Err(error) => tracing::warn!(
                t_s = time_s[event.trigger_sample as usize],
                %error,
                "bite window not analysed"
            ),
        }
    }
    Ok(events)
}

fn fit_json(fit: &Eq1Fit) -> Value {
    json!({
        "f1_hz": fit.f1_hz,
        "f2_hz": fit.f2_hz,
        "decay1_per_s": fit.decay1_per_s,
        "decay2_per_s": fit.decay2_per_s,
        "zeta1": fit.zeta1,
        "zeta2": fit.zeta2,
        "static": fit.static_torque,
        "rise_per_s": fit.rise_per_s,
        "rmse": fit.rms_residual,
        "iterations": fit.iterations,
        "status": status_tag(fit.status),
        "params": fit.params,
    })
}

fn event_json(event: &Event) -> Value {
    let t = &event.analysis.transient;
    let fit = match &event.analysis.fit {
        Ok(fit) => fit_json(fit),
        Err(error) => json!({ "error": error.to_string() }),
    };
    json!({
        "t_bite_s": event.t_bite_s,
        "static_torque": t.static_torque_knm,
        "peak_torque": t.peak_torque_knm,
        "taf": t.taf,
        "first_period_s": t.first_period_s,
        "second_period_s": t.second_period_s,
        "period_shift_s": t.period_shift_s,
        "quality": quality_tag(t.quality),
        "fit": fit,
    })
}

/// The JSON tag of a fit status.
fn status_tag(status: FitStatus) -> &'static str {
    match status {
        FitStatus::Converged => "converged",
        FitStatus::Stalled => "stalled",
        FitStatus::MaxIterations => "max_iterations",
    }
}

/// What a fit status means, for the text report.
fn status_words(status: FitStatus) -> &'static str {
    match status {
        FitStatus::Converged => "converged",
        FitStatus::Stalled => "stalled at a minimum",
        FitStatus::MaxIterations => "stopped at the iteration limit: not converged",
    }
}

/// The JSON tag of a transient's quality.
fn quality_tag(quality: TransientQuality) -> &'static str {
    match quality {
        TransientQuality::Good => "good",
        TransientQuality::FewCrossings => "few_crossings",
        TransientQuality::LowStatic => "low_static",
    }
}

/// What a transient's quality means, for the text report.
fn quality_words(quality: TransientQuality) -> &'static str {
    match quality {
        TransientQuality::Good => "all measured",
        TransientQuality::FewCrossings => "fewer than three crossings: no periods",
        TransientQuality::LowStatic => "static torque too low: no TAF or periods",
    }
}

fn optional(value: Option<f64>, digits: usize) -> String {
    value.map_or_else(|| "-".to_string(), |v| format!("{v:.digits$}"))
}

fn text(channel: &str, rate: f64, events: &[Event]) -> anyhow::Result<String> {
    let mut out = String::new();
    writeln!(
        out,
        "channel {channel}, {rate:.1} Hz, {} event(s)",
        events.len()
    )?;
    for (i, event) in events.iter().enumerate() {
        let t = &event.analysis.transient;
        writeln!(out, "event {}: t_bite_s = {:.4}", i + 1, event.t_bite_s)?;
        writeln!(
            out,
            "  static_torque = {:.2} kN*m, peak_torque = {:.2} kN*m, taf = {}",
            t.static_torque_knm,
            t.peak_torque_knm,
            optional(t.taf, 3)
        )?;
        writeln!(
            out,
            "  first_period_s = {}, second_period_s = {}, period_shift_s = {} ({})",
            optional(t.first_period_s, 4),
            optional(t.second_period_s, 4),
            optional(t.period_shift_s, 4),
            quality_words(t.quality)
        )?;
        match &event.analysis.fit {
            Ok(fit) => {
                writeln!(
                    out,
                    "  fit: f1_hz = {:.3}, f2_hz = {:.3}, decay1_per_s = {:.2}, decay2_per_s = {:.2}, \
                     zeta1 = {:.4}, zeta2 = {:.4}",
                    fit.f1_hz, fit.f2_hz, fit.decay1_per_s, fit.decay2_per_s, fit.zeta1, fit.zeta2
                )?;
                writeln!(
                    out,
                    "       static = {:.2}, rise_per_s = {:.2}, rmse = {:.3}, iterations = {} ({})",
                    fit.static_torque,
                    fit.rise_per_s,
                    fit.rms_residual,
                    fit.iterations,
                    status_words(fit.status)
                )?;
                let params: Vec<String> = fit.params.iter().map(|p| format!("{p:.4}")).collect();
                writeln!(out, "       params = [{}]", params.join(", "))?;
            }
            Err(error) => writeln!(out, "  fit: failed ({error})")?,
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use millgate_dsp::fit::eq1;

    const TABLE1: [f64; 10] = [
        -147.0, 85.0, 191.0, -31.0, 11.99, 20.91, 22.17, 3.65, 112.0, 36.7,
    ];

    fn write_csv(name: &str, rows: impl Iterator<Item = (f64, f64)>) -> PathBuf {
        let path = std::env::temp_dir().join(format!(
            "millgate-analyze-{}-{name}.csv",
            std::process::id()
        ));
        let mut text = String::from("t,torque\n");
        for (t, v) in rows {
            writeln!(text, "{t:.6},{v:.6}").unwrap();
        }
        std::fs::write(&path, text).unwrap();
        path
    }

    #[test]
    fn window_mode_fits_table1_curve() {
        let path = write_csv(
            "window",
            (0..500).map(|i| (i as f64 / 1000.0, eq1(&TABLE1, i as f64 / 1000.0))),
        );
        let out = run(&AnalyzeArgs {
            input: path.clone(),
            channel: None,
            window: Some("0,0.499".parse().unwrap()),
            format: OutputFormat::Json,
        })
        .unwrap();
        std::fs::remove_file(path).unwrap();
        let value: Value = serde_json::from_str(&out).unwrap();
        let events = value["events"].as_array().unwrap();
        assert_eq!(events.len(), 1);
        let fit = &events[0]["fit"];
        assert!((fit["f1_hz"].as_f64().unwrap() - 11.99).abs() < 1e-3);
        assert!((fit["f2_hz"].as_f64().unwrap() - 20.91).abs() < 1e-3);
        assert_eq!(fit["params"].as_array().unwrap().len(), 10);
        assert!((events[0]["taf"].as_f64().unwrap() - 1.94).abs() < 0.03);
    }

    #[test]
    fn detects_every_bite() {
        // Two bites at 1.0 s and 3.0 s, 2 kHz, offset zero of 4 kN*m. Table 1 starts at
        // a1 + a2 = -62 kN*m; a2 = -a1 makes the load start from zero, as a real record.
        let params = [
            -147.0, 147.0, 191.0, -31.0, 11.99, 20.91, 22.17, 3.65, 112.0, 36.7,
        ];
        let rate = 2000.0;
        let path = write_csv(
            "detect",
            (0..10_000).map(|i| {
                let t = i as f64 / rate;
                let load = [1.0, 3.0]
                    .iter()
                    .filter(|&&s| t >= s && t < s + 1.5)
                    .map(|&s| eq1(&params, t - s))
                    .sum::<f64>();
                (t, 4.0 + load)
            }),
        );
        let out = run(&AnalyzeArgs {
            input: path.clone(),
            channel: Some("torque".into()),
            window: None,
            format: OutputFormat::Text,
        })
        .unwrap();
        let error = run(&AnalyzeArgs {
            input: path.clone(),
            channel: Some("speed".into()),
            window: None,
            format: OutputFormat::Text,
        })
        .unwrap_err();
        std::fs::remove_file(path).unwrap();
        assert!(out.contains("2 event(s)"), "{out}");
        assert!(out.contains("t_bite_s = 1.0000"), "{out}");
        assert!(out.contains("t_bite_s = 3.0000"), "{out}");
        assert_eq!(out.matches("f1_hz = 11.990").count(), 2, "{out}");
        assert_eq!(out.matches("f2_hz = 20.910").count(), 2, "{out}");
        assert!(format!("{error:#}").contains("no column `speed`"));
    }

    #[test]
    fn a_record_with_missing_rows_is_refused_with_the_line() {
        // The Table 1 curve at 2 kHz with 0.1 s of rows (samples 300..500) missing:
        // read at the mean rate it gave f2 = 17.9 Hz for 20.91, exit 0.
        let rate = 2000.0;
        let path = write_csv(
            "missing-rows",
            (0..1200)
                .filter(|i| !(300..500).contains(i))
                .map(|i| (i as f64 / rate, eq1(&TABLE1, i as f64 / rate))),
        );
        let error = run(&AnalyzeArgs {
            input: path.clone(),
            channel: None,
            window: None,
            format: OutputFormat::Text,
        })
        .unwrap_err();
        std::fs::remove_file(&path).unwrap();
        let text = format!("{error:#}");
        // Sample 500 is the 301st row kept: line 302 (line 1 is the header).
        assert!(
            text.contains("line 302, column 1 (`t`): t steps by 0.100500 s"),
            "{text}"
        );
        assert!(text.contains("rows are missing"), "{text}");
    }

    #[test]
    fn reports_say_what_the_statuses_mean_and_windows_name_their_size() {
        let path = write_csv(
            "words",
            (0..500).map(|i| (i as f64 / 1000.0, eq1(&TABLE1, i as f64 / 1000.0))),
        );
        let args = |window: &str, format| AnalyzeArgs {
            input: path.clone(),
            channel: None,
            window: Some(window.parse().unwrap()),
            format,
        };
        let text = run(&args("0,0.499", OutputFormat::Text)).unwrap();
        let json = run(&args("0,0.499", OutputFormat::Json)).unwrap();
        let short = run(&args("0,0.002", OutputFormat::Text)).unwrap_err();
        std::fs::remove_file(&path).unwrap();
        assert!(
            text.contains("(all measured)") && text.contains("(converged)"),
            "{text}"
        );
        assert!(
            !text.contains("Good") && !text.contains("Converged"),
            "{text}"
        );
        let value: Value = serde_json::from_str(&json).unwrap();
        assert_eq!(value["events"][0]["quality"], "good");
        assert_eq!(value["events"][0]["fit"]["status"], "converged");
        assert_eq!(
            format!("{short:#}"),
            "--window 0,0.002: the window holds 3 samples; the analysis needs 5..=2048"
        );
    }

    #[test]
    fn window_argument_is_validated() {
        assert!("0.1,0.2".parse::<TimeWindow>().is_ok());
        assert!("0.2,0.1".parse::<TimeWindow>().is_err());
        assert!("0.2".parse::<TimeWindow>().is_err());
        assert!("a,1".parse::<TimeWindow>().is_err());
    }
}
