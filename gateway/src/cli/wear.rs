//! `millgate wear --input FILE.csv --model MODEL.toml [--channel NAME] [--alarm-mrad X]
//! [--horizon-days D] [--format text|json] [--plot FILE.svg]`, or `millgate wear --db
//! FILE --driveline NAME`: the service's gap diagnosis and wear forecast on a record, or
//! from a history.
//!
//! The same code as the service: bites are detected and analysed with a driveline's
//! setup ([`BiteSetup`]: the default capture, 0.1 s before and 0.5 s after the trigger,
//! and `--threshold-knm`), the gap maps of the model are built by the same job (cached
//! like the service's, progress on stderr) over the static torques the record's bites
//! span, and every bite is folded into the wear trend ([`GapTrend`]) in time order.
//! A record may hold bites recorded apart: `t` then jumps (by at least
//! [`csv::SEGMENT_JUMP_S`]) between uniformly sampled runs, and `t` in Unix seconds
//! (UTC, after 2000) dates the forecast; a `# reset` comment line marks a wear reset.
//! With `--db` the trend the service kept after its last bite is read back.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

use anyhow::{bail, Context as _};
use millgate_config::{BiteSettings, WearSettings};
use millgate_sim::model::Model;
use serde_json::{json, Value};

use super::OutputFormat;
use crate::analysis::bite_window::analyze_window;
use crate::analysis::driveline::BiteSetup;
use crate::analysis::gap_estimate::{estimate, GapObservation};
use crate::analysis::gap_map_cache;
use crate::analysis::gap_monitor::{GapMapJob, MapsOrigin};
use crate::analysis::gap_trend::{GapTrend, EARLY_GROWTH_SD, MIN_TREND_BITES, MIN_TREND_SPAN_DAYS};
use crate::history::query::{Filter, HistoryReader};
use crate::records::csv;
use crate::state::gap_maps::{GapMapSpec, GapMaps};
use crate::state::results::{ForecastState, GapForecast, GapResults};
use crate::state::time::UtcTime;

/// Capture before the trigger, s (the configuration's default).
const PRE_TRIGGER_S: f64 = 0.1;
/// Capture after the trigger, s (the configuration's default).
const POST_TRIGGER_S: f64 = 0.5;
/// The maps span the record's bites' static torques widened by this fraction.
const RANGE_MARGIN: f64 = 0.1;
/// Idle time put before the record beyond the pre-trigger capture, s (as the maps'
/// simulated bites have it).
const IDLE_MARGIN_S: f64 = 0.05;
/// Samples averaged for the idle level the record is padded with.
const IDLE_LEVEL_SAMPLES: usize = 20;

/// Arguments of `millgate wear`.
#[derive(Debug, Clone, clap::Args)]
#[command(group(clap::ArgGroup::new("from").required(true).args(["input", "db"])))]
pub struct WearArgs {
    /// Recorded bites: CSV with a header, first column `t` (s; Unix seconds date the
    /// forecast), other columns torque (kN*m).
    #[arg(long, requires = "model", conflicts_with = "db")]
    pub input: Option<PathBuf>,
    /// The driveline model (TOML) to diagnose against, as `drivelines[].model`.
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// A history file: the wear trend the service kept for `--driveline`.
    #[arg(long, requires = "driveline")]
    pub db: Option<PathBuf>,
    /// The driveline of `--db`.
    #[arg(long, requires = "db")]
    pub driveline: Option<String>,
    /// Channel to use (default: the first after `t`).
    #[arg(long)]
    pub channel: Option<String>,
    /// Deprecated, no effect: the gap is now the wear trend of every bite (accepted
    /// for one release).
    #[arg(long, hide = true, value_parser = clap::value_parser!(u16).range(1..=1000))]
    pub pool: Option<u16>,
    /// The gap alarm the forecast is for, mrad (`thresholds.gap_alarm_mrad`; with
    /// `--db` the history's last run's, else 4).
    #[arg(long)]
    pub alarm_mrad: Option<f64>,
    /// How far ahead the forecast looks, days (`wear.horizon_days`).
    #[arg(long, default_value_t = WearSettings::default().horizon_days)]
    pub horizon_days: f64,
    /// Bites within this of the trend's first (or of a jump) are one gap, s; the
    /// growth comes from bites further apart (`wear.growth_span_s`; 0 for bites
    /// compressed in time, as the demo's).
    #[arg(long, default_value_t = WearSettings::default().growth_span_s)]
    pub growth_span_s: f64,
    /// Rise above the baseline that marks a bite, kN*m.
    #[arg(long, default_value_t = 20.0)]
    pub threshold_knm: f64,
    /// Gap step of the maps, mrad (coarser builds faster: 0.25 halves the time).
    #[arg(long, default_value_t = WearSettings::default().gap_step_mrad)]
    pub gap_step_mrad: f64,
    /// Largest gap of the maps, mrad.
    #[arg(long, default_value_t = WearSettings::default().max_gap_mrad)]
    pub max_gap_mrad: f64,
    /// Folder of the cached gap maps (default: the user's cache folder).
    #[arg(long)]
    pub cache_dir: Option<PathBuf>,
    /// Output format.
    #[arg(long, value_enum, default_value_t = OutputFormat::Text)]
    pub format: OutputFormat,
    /// Draw the bites' TAF over static torque on the map's curves, the estimated gap's
    /// curve highlighted, into this SVG file.
    #[cfg(feature = "sim-tools")]
    #[arg(long)]
    pub plot: Option<PathBuf>,
}

/// The gap alarm when neither `--alarm-mrad` nor a history says (the configuration's
/// default `thresholds.gap_alarm_mrad`).
const DEFAULT_ALARM_MRAD: f64 = 4.0;

/// `t` at or after this (2000-01-01T00:00:00Z) is read as Unix seconds: the forecast
/// gets a date.
const UNIX_SECONDS_FROM: f64 = 946_684_800.0;

/// One bite of the record.
struct Bite {
    t_bite_s: f64,
    observation: GapObservation,
    /// A wear reset stands between the bite before and this one.
    after_reset: bool,
    /// The trend after this bite.
    trend: Option<GapResults>,
}

/// Runs the command, printing progress to stderr; returns the text to print.
pub fn run(args: &WearArgs) -> anyhow::Result<String> {
    check_numbers(args)?;
    if args.pool.is_some() {
        eprintln!("wear: --pool is deprecated and has no effect (the gap is the wear trend of every bite)");
    }
    match (&args.input, &args.model, &args.db, &args.driveline) {
        (Some(input), Some(model), _, _) => from_record(args, input, model),
        (_, _, Some(db), Some(driveline)) => from_history(args, db, driveline),
        _ => bail!("give --input FILE --model MODEL, or --db FILE --driveline NAME"),
    }
}

/// The diagnosis of the record `input` against the model file `model_file`.
fn from_record(args: &WearArgs, input: &Path, model_file: &Path) -> anyhow::Result<String> {
    let input = input.display().to_string();
    let table = csv::read(Path::new(&input)).with_context(|| input.clone())?;
    let (channel, signal) = table
        .pick_torque(args.channel.as_deref())
        .map_err(|e| anyhow::anyhow!("{input}: {e}"))?;
    let segments = table
        .segments()
        .map_err(|e| anyhow::anyhow!("{input}: {e}"))?;
    let rate = segments.rate_hz;
    let model = Model::load(model_file)?;
    let capture = BiteSettings {
        threshold_knm: args.threshold_knm,
        pre_trigger_s: PRE_TRIGGER_S,
        post_trigger_s: POST_TRIGGER_S,
    };
    let unlimited = (f64::NEG_INFINITY, f64::INFINITY);
    let setup = BiteSetup::new(0, &input, &capture, rate, unlimited, Some(&model))
        .map_err(|e| anyhow::anyhow!("{input}: {e}"))?;
    let reset_times: Vec<f64> = table
        .resets
        .iter()
        .filter_map(|&row| table.time_s.get(row).copied())
        .collect();
    let mut bites = Vec::new();
    for range in &segments.ranges {
        bites.extend(detect(
            &table.time_s[range.clone()],
            &signal[range.clone()],
            &setup,
        ));
    }
    mark_resets(&mut bites, &reset_times);
    if bites.is_empty() {
        bail!(
            "{input}: no bite in channel `{channel}` (no analysable rise of {} kN*m above the \
             baseline; --threshold-knm sets it)",
            args.threshold_knm
        );
    }
    let spec = GapMapSpec::new(0, &wear_settings(args, &bites), &model, args.threshold_knm)?;
    let cache_dir = args
        .cache_dir
        .clone()
        .unwrap_or_else(gap_map_cache::default_dir);
    let job = GapMapJob::new(
        0,
        &input,
        model_file,
        setup.simulator(&model),
        spec,
        &cache_dir,
    );
    let maps = build_maps(&job)?;
    let alarm_mrad = args.alarm_mrad.unwrap_or(DEFAULT_ALARM_MRAD);
    let mut trend = GapTrend::new(args.horizon_days)?;
    trend.set_growth_span_s(args.growth_span_s)?;
    for bite in &mut bites {
        if bite.after_reset {
            trend.reset();
        }
        let unix_ms = (bite.t_bite_s * 1e3).round() as i64;
        if let Err(error) = trend.fold(&maps, &bite.observation, unix_ms) {
            bail!("{input}: the bite at t = {} s: {error}", bite.t_bite_s);
        }
        bite.trend = trend.results(alarm_mrad);
    }
    let dated = bites
        .first()
        .is_some_and(|bite| bite.t_bite_s >= UNIX_SECONDS_FROM);
    let outlook = Outlook {
        results: trend.results(alarm_mrad),
        alarm_mrad,
        horizon_days: args.horizon_days,
        dated,
    };
    #[cfg(feature = "sim-tools")]
    if let Some(path) = &args.plot {
        let observations: Vec<GapObservation> = bites.iter().map(|b| b.observation).collect();
        let svg = plot(&maps, &model, &observations, outlook.results.as_ref())?;
        std::fs::write(path, svg).with_context(|| format!("writing {}", path.display()))?;
        eprintln!("wear: wrote {}", path.display());
    }
    Ok(match args.format {
        OutputFormat::Json => {
            let mut report = outlook.json();
            report["bites"] = bites_json(&maps, &bites);
            report["segments"] = json!(segments.ranges.len());
            report["resets"] = json!(bites.iter().filter(|b| b.after_reset).count());
            report.to_string()
        }
        OutputFormat::Text => {
            let mut out = bites_text(
                &input,
                channel,
                rate,
                &model,
                &maps,
                &bites,
                segments.ranges.len(),
            )?;
            out.push_str(&outlook.text(&model_coupling_names(&model)));
            out
        }
    })
}

/// The wear trend `driveline` of the history `db` kept after its last bite.
fn from_history(args: &WearArgs, db: &Path, driveline: &str) -> anyhow::Result<String> {
    let reader = HistoryReader::open(db)?;
    let state = reader.state()?;
    let file = db.display();
    let Some(restored) = state.drivelines.iter().find(|d| d.name == driveline) else {
        let names: Vec<String> = state.drivelines.iter().map(|d| d.name.clone()).collect();
        bail!(
            "{file}: no driveline `{driveline}` (drivelines: {})",
            names.join(", ")
        );
    };
    let Some(saved) = &restored.gap_trend else {
        bail!(
            "{file}: no wear trend kept for `{driveline}` (no bite with a gap estimate since \
             its last wear reset, or a history written before schema version 11: the \
             gateway keeps it from its next bite on)"
        );
    };
    let alarm_mrad = match args.alarm_mrad {
        Some(alarm) => alarm,
        None => {
            let filter = Filter {
                name: Some(driveline.to_owned()),
                ..Filter::default()
            };
            reader
                .settings(&filter)?
                .last()
                .and_then(|settings| settings.gap_alarm_mrad)
                .unwrap_or(DEFAULT_ALARM_MRAD)
        }
    };
    let trend = GapTrend::restored(args.horizon_days, saved)
        .map_err(|error| anyhow::anyhow!("{file}: the wear trend of `{driveline}`: {error}"))?;
    let outlook = Outlook {
        results: trend.results(alarm_mrad),
        alarm_mrad,
        horizon_days: args.horizon_days,
        dated: true,
    };
    Ok(match args.format {
        OutputFormat::Json => outlook.json().to_string(),
        OutputFormat::Text => {
            let mut out = format!(
                "{file}: driveline {driveline}, wear trend after the bite of {}\n",
                trend
                    .last_bite_unix_ms()
                    .map_or("-".into(), |ms| UtcTime::from_unix_ms(ms).to_string())
            );
            out.push_str(&outlook.text(&[]));
            out
        }
    })
}

/// Mark the first bite after each reset time.
fn mark_resets(bites: &mut [Bite], reset_times: &[f64]) {
    for &reset in reset_times {
        if let Some(bite) = bites.iter_mut().find(|bite| bite.t_bite_s >= reset) {
            bite.after_reset = true;
        }
    }
}

/// The coupling names of `model`, by index.
fn model_coupling_names(model: &Model) -> Vec<String> {
    model.couplings.iter().map(|c| c.name.clone()).collect()
}

/// The unit a forecast of `days` reads best in, and days' scale to it: days from two
/// days on, else hours, else seconds (a compressed record such as the demo's).
fn span_unit(days: f64) -> (&'static str, f64) {
    if days >= 2.0 {
        ("days", 1.0)
    } else if days >= 1.0 / 24.0 {
        ("hours", 24.0)
    } else {
        ("s", 86_400.0)
    }
}

/// The trend's gap, growth and forecast, as the command reports them.
struct Outlook {
    results: Option<GapResults>,
    alarm_mrad: f64,
    horizon_days: f64,
    /// Whether times are dates (Unix seconds), so the forecast has a date.
    dated: bool,
}

impl Outlook {
    /// Why the forecast gives no days (`None` when it gives them).
    fn reason(&self) -> Option<String> {
        let forecast = self.results.as_ref().and_then(|r| r.forecast);
        let Some(forecast) = forecast else {
            return Some("no estimate: no bite inside the maps".into());
        };
        let bites = self.results.map_or(0, |r| r.bites_pooled);
        match forecast.state {
            ForecastState::Forecast | ForecastState::AtAlarm => None,
            ForecastState::NotGrowing => {
                Some("the gap is not growing: the growth's 90% interval holds 0".into())
            }
            ForecastState::BeyondHorizon => Some(format!(
                "growing, but the gap reaches {} mrad beyond the horizon of {} days",
                self.alarm_mrad, self.horizon_days
            )),
            ForecastState::TooFewBites => Some(format!(
                "too few bites for a trend ({bites} since the last reset; needs {MIN_TREND_BITES}, \
                 and {MIN_TREND_SPAN_DAYS} days of them unless the growth is \
                 {EARLY_GROWTH_SD} standard deviations clear of 0)"
            )),
        }
    }

    fn date(&self, forecast: &GapForecast) -> Option<String> {
        forecast
            .date_unix_ms
            .filter(|_| self.dated)
            .map(|ms| UtcTime::from_unix_ms(ms).to_string())
    }

    fn json(&self) -> Value {
        let r = self.results.as_ref();
        let growth = r.and_then(|r| r.growth);
        let forecast = r.and_then(|r| r.forecast);
        json!({
            "gap_mrad": r.map(|e| e.gap_mrad),
            "gap_low_mrad": r.map(|e| e.low_mrad),
            "gap_high_mrad": r.map(|e| e.high_mrad),
            "coupling": r.and_then(|e| e.coupling),
            "likeliest_coupling": r.and_then(|e| e.likeliest_coupling),
            "bites_pooled": r.map_or(0, |e| e.bites_pooled),
            "trend_mrad_per_day": growth.map(|g| g.mrad_per_day),
            "trend_low_mrad_per_day": growth.map(|g| g.low_mrad_per_day),
            "trend_high_mrad_per_day": growth.map(|g| g.high_mrad_per_day),
            "forecast": {
                "alarm_mrad": self.alarm_mrad,
                "horizon_days": self.horizon_days,
                "state": forecast.map(|f| f.state.name()),
                "days": forecast.and_then(|f| f.days),
                "days_low": forecast.and_then(|f| f.days_low),
                "days_high": forecast.and_then(|f| f.days_high),
                "date": forecast.and_then(|f| self.date(&f)),
                "reason": self.reason(),
            },
        })
    }

    fn text(&self, couplings: &[String]) -> String {
        let Some(e) = &self.results else {
            return "no estimate: no bite inside the maps\n".into();
        };
        let mut out = String::new();
        let coupling = match e.coupling {
            Some(c) => match couplings.get(c) {
                Some(name) => format!("in coupling {c} \"{name}\""),
                None => format!("in coupling {c}"),
            },
            None => "coupling undetermined (the bites cannot tell the couplings apart)".into(),
        };
        let _ = writeln!(
            out,
            "opened gap {:.2} mrad (90% interval {:.2} .. {:.2} mrad) {coupling}; {} bite(s) in the trend",
            e.gap_mrad, e.low_mrad, e.high_mrad, e.bites_pooled
        );
        if let Some(g) = e.growth {
            let _ = writeln!(
                out,
                "growth {:.4} mrad/day (90% interval {:.4} .. {:.4})",
                g.mrad_per_day, g.low_mrad_per_day, g.high_mrad_per_day
            );
        }
        match (e.forecast, self.reason()) {
            (Some(f), None) => {
                let (unit, scale) = span_unit(f.days.unwrap_or(0.0));
                let _ = writeln!(
                    out,
                    "gap alarm {} mrad in {} {unit} (90% interval {} .. {} {unit}){}",
                    self.alarm_mrad,
                    optional(f.days, scale, 1),
                    optional(f.days_low, scale, 1),
                    f.days_high.map_or_else(
                        || format!("beyond {}", self.horizon_days * scale),
                        |d| format!("{:.1}", d * scale)
                    ),
                    self.date(&f)
                        .map_or(String::new(), |date| format!(", expected {date}"))
                );
            }
            (forecast, Some(reason)) => {
                let early = forecast
                    .and_then(|f| f.days_low)
                    .map_or(String::new(), |d| {
                        format!(" (it may reach it in {d:.1} days at the earliest)")
                    });
                let _ = writeln!(
                    out,
                    "no gap alarm forecast ({} mrad): {reason}{early}",
                    self.alarm_mrad
                );
            }
            (None, None) => {}
        }
        out
    }
}

/// Every analysable bite of `signal` with its observation; the load onset as time.
///
/// The record is preceded by idle samples at the level of its first ones, so that a
/// bite soon after the record's start still gets the full pre-trigger capture: the
/// static torque is averaged over the end of the window, and a shorter window would
/// average over a different part of the response than the maps' bites.
/// Refuses a `--threshold-knm`, `--max-gap-mrad` or `--gap-step-mrad` out of range.
fn check_numbers(args: &WearArgs) -> anyhow::Result<()> {
    if let Some(alarm) = args.alarm_mrad {
        if !(alarm > 0.0 && (args.input.is_none() || alarm < args.max_gap_mrad)) {
            bail!(
                "--alarm-mrad {alarm} is not allowed (must be > 0 mrad and < --max-gap-mrad = {} mrad: the gap maps end there)",
                args.max_gap_mrad
            );
        }
    }
    if !(1.0..=3650.0).contains(&args.horizon_days) {
        bail!(
            "--horizon-days {} is not allowed (must be >= 1 and <= 3650 days)",
            args.horizon_days
        );
    }
    let max_span_s = millgate_dsp::wear_trend::MAX_GROWTH_SPAN_DAYS * 86_400.0;
    if !(0.0..=max_span_s).contains(&args.growth_span_s) {
        bail!(
            "--growth-span-s {} is not allowed (must be >= 0 and <= {max_span_s} s, 30 days)",
            args.growth_span_s
        );
    }
    if !(args.threshold_knm.is_finite() && args.threshold_knm > 0.0) {
        bail!(
            "--threshold-knm {} is not allowed (must be > 0 kN*m)",
            args.threshold_knm
        );
    }
    let steps = args.max_gap_mrad / args.gap_step_mrad;
    if !(args.max_gap_mrad > 0.0 && args.max_gap_mrad <= 100.0) {
        bail!(
            "--max-gap-mrad {} is not allowed (must be > 0 and <= 100 mrad)",
            args.max_gap_mrad
        );
    }
    if !(args.gap_step_mrad > 0.0 && (1.0..=400.0).contains(&steps)) {
        bail!(
            "--gap-step-mrad {} is not allowed (must be > 0 mrad, at most --max-gap-mrad and \
             at least --max-gap-mrad / 400)",
            args.gap_step_mrad
        );
    }
    Ok(())
}

/// The wear settings of the maps for `bites`: their static torque range with a
/// margin (not below `--threshold-knm`) and the gap grid of `args`.
fn wear_settings(args: &WearArgs, bites: &[Bite]) -> WearSettings {
    let (low, high) = bites
        .iter()
        .map(|bite| bite.observation.static_torque_knm)
        .fold((f64::INFINITY, 0.0_f64), |(lo, hi), s| {
            (lo.min(s), hi.max(s))
        });
    WearSettings {
        static_torque_knm: Some((
            ((1.0 - RANGE_MARGIN) * low).max(args.threshold_knm),
            (1.0 + RANGE_MARGIN) * high,
        )),
        gap_step_mrad: args.gap_step_mrad,
        max_gap_mrad: args.max_gap_mrad,
        ..WearSettings::default()
    }
}

fn detect(time_s: &[f64], signal: &[f64], setup: &BiteSetup) -> Vec<Bite> {
    let rate = setup.transient.sample_rate_hz;
    let pad = ((PRE_TRIGGER_S + IDLE_MARGIN_S) * rate).ceil() as usize;
    let head = &signal[..signal.len().min(IDLE_LEVEL_SAMPLES)];
    let idle = head.iter().sum::<f64>() / head.len().max(1) as f64;
    let padded: Vec<f64> = std::iter::repeat_n(idle, pad)
        .chain(signal.iter().copied())
        .collect();
    // Time of padded sample k.
    let time = |k: usize| match k.checked_sub(pad) {
        Some(k) => time_s[k],
        None => time_s[0] - (pad - k) as f64 / rate,
    };
    let detector = setup.detector;
    let mut state = detector.state();
    let mut windows = Vec::new();
    detector.block(&mut state, &padded, |event| windows.push(event));
    // A bite too close to the end of the record: the end cuts its window like a gap.
    windows.extend(detector.gap(&mut state, 0));
    let mut bites = Vec::new();
    for event in windows {
        let start = event.trigger_sample as usize - event.trigger_index;
        let t_trigger = time(event.trigger_sample as usize);
        if !event.quality.is_good() {
            tracing::warn!(
                t_s = t_trigger,
                "bite window cut short or with bad samples: not used"
            );
            continue;
        }
        let analysis = match analyze_window(
            &event.window,
            event.trigger_index,
            event.baseline_knm,
            setup.onset_knm,
            &setup.transient,
        ) {
            Ok(analysis) => analysis,
            Err(error) => {
                tracing::warn!(t_s = t_trigger, %error, "bite window not analysable");
                continue;
            }
        };
        let Some(observation) =
            GapObservation::from_window(&event.window, &analysis.transient, &setup.transient)
        else {
            tracing::warn!(t_s = t_trigger, "bite without TAF: not used");
            continue;
        };
        bites.push(Bite {
            t_bite_s: time(start + analysis.fit_start_index),
            observation,
            after_reset: false,
            trend: None,
        });
    }
    bites
}

/// The maps of `job`, from the cache or built with progress on stderr.
fn build_maps(job: &GapMapJob) -> anyhow::Result<GapMaps> {
    let total = job.spec().simulations();
    eprintln!(
        "wear: gap maps of {} ({} couplings, {} gaps x {} static torques)",
        job.model_file.display(),
        job.spec().couplings.len(),
        job.spec().gaps_rad.len(),
        job.spec().static_torques_knm.len()
    );
    let printed = AtomicUsize::new(0);
    let progress = |done: usize, total: usize| {
        let tenth = done * 10 / total.max(1);
        if printed.fetch_max(tenth, Ordering::Relaxed) < tenth {
            eprintln!("wear: gap maps {done}/{total} simulations");
        }
    };
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
    let (maps, origin) = job.run(threads, &AtomicBool::new(false), &progress)?;
    match origin {
        MapsOrigin::Cache(file) => eprintln!("wear: gap maps from {}", file.display()),
        MapsOrigin::Built { seconds, saved } => eprintln!(
            "wear: {total} simulations in {seconds:.1} s{}",
            saved.map_or(String::new(), |file| format!(
                ", cached in {}",
                file.display()
            ))
        ),
    }
    Ok(maps)
}

/// First-period shift over the linear driveline's at the same static torque, s.
fn shift_over_linear_s(maps: &GapMaps, observation: &GapObservation) -> Option<f64> {
    let (_, linear) = maps.linear_at(observation.static_torque_knm)?;
    Some(observation.period_shift_s? - linear?)
}

/// Each bite: its measures, its gap alone, and the trend's gap after it.
fn bites_json(maps: &GapMaps, bites: &[Bite]) -> Value {
    let bites: Vec<Value> = bites
        .iter()
        .map(|bite| {
            let o = &bite.observation;
            json!({
                "t_bite_s": bite.t_bite_s,
                "static_torque": o.static_torque_knm,
                "taf": o.taf,
                "shift_over_linear_s": shift_over_linear_s(maps, o),
                "gap_mrad": estimate(maps, o).map(|e| e.gap_mrad),
                "trend_gap_mrad": bite.trend.map(|t| t.gap_mrad),
                "after_reset": bite.after_reset,
            })
        })
        .collect();
    Value::Array(bites)
}

fn optional(value: Option<f64>, scale: f64, digits: usize) -> String {
    value.map_or_else(|| "-".into(), |v| format!("{:.digits$}", v * scale))
}

fn bites_text(
    input: &str,
    channel: &str,
    rate: f64,
    model: &Model,
    maps: &GapMaps,
    bites: &[Bite],
    segments: usize,
) -> anyhow::Result<String> {
    let mut out = String::new();
    writeln!(
        out,
        "{input}: channel {channel}, {rate:.1} Hz, {} bite(s) in {segments} segment(s); model \"{}\"",
        bites.len(),
        model.name
    )?;
    writeln!(
        out,
        "{:>4} {:>14} {:>12} {:>7} {:>21} {:>9} {:>11}",
        "bite", "t_bite_s", "static kN*m", "TAF", "shift over linear ms", "gap mrad", "trend mrad"
    )?;
    for (index, bite) in bites.iter().enumerate() {
        if bite.after_reset {
            writeln!(out, "---- wear reset")?;
        }
        let o = &bite.observation;
        writeln!(
            out,
            "{:>4} {:>14.4} {:>12.2} {:>7.4} {:>21} {:>9} {:>11}",
            index + 1,
            bite.t_bite_s,
            o.static_torque_knm,
            o.taf,
            optional(shift_over_linear_s(maps, o), 1e3, 2),
            optional(estimate(maps, o).map(|e| e.gap_mrad), 1.0, 2),
            optional(bite.trend.map(|t| t.gap_mrad), 1.0, 2)
        )?;
    }
    Ok(out)
}

/// TAF over static torque: the map rows of the likeliest coupling at whole mrad, the
/// estimated gap's curve, the bites.
#[cfg(feature = "sim-tools")]
fn plot(
    maps: &GapMaps,
    model: &Model,
    observations: &[GapObservation],
    result: Option<&GapResults>,
) -> anyhow::Result<String> {
    use millgate_sim::plot::{curves_svg, CurvesPlot};
    let coupling = result
        .and_then(|e| e.likeliest_coupling)
        .unwrap_or(maps.maps()[0].coupling);
    let index = maps.index_of(coupling).unwrap_or(0);
    let curves = maps
        .whole_mrad_curves(index)
        .into_iter()
        .map(|(mrad, curve)| (format!("gap {mrad} mrad"), curve))
        .collect();
    let highlighted = result.map(|e| {
        (
            format!(
                "estimated {:.2} mrad ({:.2} .. {:.2})",
                e.gap_mrad, e.low_mrad, e.high_mrad
            ),
            maps.taf_curve(index, e.gap_mrad * 1e-3),
        )
    });
    let named = if result.is_some_and(|e| e.coupling.is_some()) {
        ""
    } else {
        ", undetermined: the likeliest"
    };
    Ok(curves_svg(&CurvesPlot {
        title: format!(
            "{}: TAF over static torque, gap in coupling {coupling} \"{}\"{named}",
            model.name, model.couplings[coupling].name
        ),
        x_label: "static torque, kN*m".into(),
        y_label: "TAF (peak / static)".into(),
        curves,
        highlighted,
        points: (
            "bites".into(),
            observations
                .iter()
                .map(|o| (o.static_torque_knm, o.taf))
                .collect(),
        ),
    })?)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_forecast_reads_in_days_hours_or_seconds() {
        assert_eq!(span_unit(22.0), ("days", 1.0));
        assert_eq!(span_unit(1.5), ("hours", 24.0));
        // The demo's 20 s.
        assert_eq!(span_unit(20.0 / 86_400.0), ("s", 86_400.0));
    }
}
