//! `millgate wear --input FILE.csv --model MODEL.toml [--channel NAME] [--pool N]
//! [--format text|json] [--plot FILE.svg]`: the service's gap diagnosis on a recording.
//!
//! The same code as the service: bites are detected and analysed with a driveline's
//! setup ([`BiteSetup`]: the default capture, 0.1 s before and 0.5 s after the trigger,
//! and `--threshold-knm`), the gap maps of the model are built by the same job (cached
//! like the service's, progress on stderr) over the static torques the record's bites
//! span, and the last `--pool` bites are pooled into one estimate.

use std::fmt::Write as _;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

use anyhow::{bail, Context as _};
use millgate_config::{BiteSettings, WearSettings};
use millgate_sim::model::Model;
use serde_json::{json, Value};

use super::OutputFormat;
use crate::analysis::bite_window::analyze_window;
use crate::analysis::driveline::BiteSetup;
use crate::analysis::gap_estimate::{estimate, GapEstimate, GapObservation};
use crate::analysis::gap_map_cache;
use crate::analysis::gap_monitor::{GapMapJob, MapsOrigin};
use crate::records::csv;
use crate::state::gap_maps::{GapMapSpec, GapMaps};

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
pub struct WearArgs {
    /// Recorded bites: CSV with a header, first column `t` (s), other columns torque
    /// (kN*m).
    #[arg(long)]
    pub input: PathBuf,
    /// The driveline model (TOML) to diagnose against, as `drivelines[].model`.
    #[arg(long)]
    pub model: PathBuf,
    /// Channel to use (default: the first after `t`).
    #[arg(long)]
    pub channel: Option<String>,
    /// Bites pooled into the estimate: the last N of the record.
    #[arg(long, default_value_t = 20, value_parser = clap::value_parser!(u16).range(1..=1000))]
    pub pool: u16,
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

/// One bite of the record.
struct Bite {
    t_bite_s: f64,
    observation: GapObservation,
}

/// Runs the command, printing progress to stderr; returns the text to print.
pub fn run(args: &WearArgs) -> anyhow::Result<String> {
    let input = args.input.display().to_string();
    check_numbers(args)?;
    let table = csv::read(&args.input).with_context(|| input.clone())?;
    let (channel, signal) = table
        .pick_torque(args.channel.as_deref())
        .map_err(|e| anyhow::anyhow!("{input}: {e}"))?;
    let rate = table
        .sample_rate_hz()
        .map_err(|e| anyhow::anyhow!("{input}: {e}"))?;
    let model = Model::load(&args.model)?;
    let capture = BiteSettings {
        threshold_knm: args.threshold_knm,
        pre_trigger_s: PRE_TRIGGER_S,
        post_trigger_s: POST_TRIGGER_S,
    };
    let unlimited = (f64::NEG_INFINITY, f64::INFINITY);
    let setup = BiteSetup::new(0, &input, &capture, rate, unlimited, Some(&model))
        .map_err(|e| anyhow::anyhow!("{input}: {e}"))?;
    let bites = detect(&table.time_s, signal, &setup);
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
        &args.model,
        setup.simulator(&model),
        spec,
        &cache_dir,
    );
    let maps = build_maps(&job)?;
    let observations: Vec<GapObservation> = bites.iter().map(|b| b.observation).collect();
    let pooled = &observations[observations.len().saturating_sub(usize::from(args.pool))..];
    let result = estimate(&maps, pooled);
    #[cfg(feature = "sim-tools")]
    if let Some(path) = &args.plot {
        let svg = plot(&maps, &model, &observations, result.as_ref())?;
        std::fs::write(path, svg).with_context(|| format!("writing {}", path.display()))?;
        eprintln!("wear: wrote {}", path.display());
    }
    Ok(match args.format {
        OutputFormat::Json => json_report(&maps, &bites, result.as_ref()).to_string(),
        OutputFormat::Text => text_report(
            &input,
            channel,
            rate,
            &model,
            &maps,
            &bites,
            result.as_ref(),
        )?,
    })
}

/// Every analysable bite of `signal` with its observation; the load onset as time.
///
/// The record is preceded by idle samples at the level of its first ones, so that a
/// bite soon after the record's start still gets the full pre-trigger capture: the
/// static torque is averaged over the end of the window, and a shorter window would
/// average over a different part of the response than the maps' bites.
/// Refuses a `--threshold-knm`, `--max-gap-mrad` or `--gap-step-mrad` out of range.
fn check_numbers(args: &WearArgs) -> anyhow::Result<()> {
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
/// margin (not below `--threshold-knm`), the pool and the gap grid of `args`.
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
        pool_bites: usize::from(args.pool),
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

fn json_report(maps: &GapMaps, bites: &[Bite], result: Option<&GapEstimate>) -> Value {
    let bites: Vec<Value> = bites
        .iter()
        .map(|bite| {
            let o = &bite.observation;
            json!({
                "t_bite_s": bite.t_bite_s,
                "static_torque": o.static_torque_knm,
                "taf": o.taf,
                "shift_over_linear_s": shift_over_linear_s(maps, o),
                "gap_mrad": estimate(maps, &[*o]).map(|e| e.gap_mrad),
            })
        })
        .collect();
    json!({
        "bites": bites,
        "gap_mrad": result.map(|e| e.gap_mrad),
        "gap_low_mrad": result.map(|e| e.gap_low_mrad),
        "gap_high_mrad": result.map(|e| e.gap_high_mrad),
        "coupling": result.and_then(|e| e.coupling),
        "bites_pooled": result.map_or(0, |e| e.bites_pooled),
    })
}

fn optional(value: Option<f64>, scale: f64, digits: usize) -> String {
    value.map_or_else(|| "-".into(), |v| format!("{:.digits$}", v * scale))
}

fn text_report(
    input: &str,
    channel: &str,
    rate: f64,
    model: &Model,
    maps: &GapMaps,
    bites: &[Bite],
    result: Option<&GapEstimate>,
) -> anyhow::Result<String> {
    let mut out = String::new();
    writeln!(
        out,
        "{input}: channel {channel}, {rate:.1} Hz, {} bite(s); model \"{}\"",
        bites.len(),
        model.name
    )?;
    writeln!(
        out,
        "{:>4} {:>9} {:>12} {:>7} {:>21} {:>9}",
        "bite", "t_bite_s", "static kN*m", "TAF", "shift over linear ms", "gap mrad"
    )?;
    for (index, bite) in bites.iter().enumerate() {
        let o = &bite.observation;
        writeln!(
            out,
            "{:>4} {:>9.4} {:>12.2} {:>7.4} {:>21} {:>9}",
            index + 1,
            bite.t_bite_s,
            o.static_torque_knm,
            o.taf,
            optional(shift_over_linear_s(maps, o), 1e3, 2),
            optional(estimate(maps, &[*o]).map(|e| e.gap_mrad), 1.0, 2)
        )?;
    }
    match result {
        Some(e) => {
            let coupling = match e.coupling {
                Some(c) => format!("in coupling {c} \"{}\"", model.couplings[c].name),
                None => "coupling undetermined (the bites cannot tell the couplings apart)".into(),
            };
            writeln!(
                out,
                "opened gap {:.2} mrad (90% interval {:.2} .. {:.2} mrad) {coupling}; {} bite(s) pooled",
                e.gap_mrad, e.gap_low_mrad, e.gap_high_mrad, e.bites_pooled
            )?;
        }
        None => writeln!(out, "no estimate: no bite inside the maps")?,
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
    result: Option<&GapEstimate>,
) -> anyhow::Result<String> {
    use millgate_sim::plot::{curves_svg, CurvesPlot};
    let coupling = result.map_or(maps.maps()[0].coupling, |e| e.likeliest_coupling);
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
                e.gap_mrad, e.gap_low_mrad, e.gap_high_mrad
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
