//! `millgate chatter commission --config MILL.toml --input STABLE.csv [--input ...]
//! [--mill NAME] [--margin PCT] [--speed-column NAME] [--format text|json]`: a tandem
//! mill's chatter thresholds from recordings of its stable rolling.
//!
//! Every recording goes through the service's own monitor (as `millgate chatter`
//! does, [`super::recording::windows`]); over every window whose gain window is full,
//! each stand's largest chatter-band gain, plus `--margin` percent (10 by default, the
//! tandem-model race's margin), rounded up to 0.001, is its threshold: printed as the
//! TOML line `gain_thresholds = [...]` to paste into the mill's `[[tandem_mills]]`
//! entry. Beside it: how many windows and seconds the recordings gave, the speeds they
//! covered (with `--speed-column`, a column of the recordings holding the mill's
//! speed), the largest band RMS per stand (the usual vibration alarm's figure, plus the
//! margin) and, for `detector = "paper"`, `k_max`: the largest K_mean seen, moved the
//! margin of the way to 1.
//!
//! **Release level.** The slow-down request clears once the gain ratio stayed below
//! `slow_down_release` for `slow_down_hold_s`: a release below where stable rolling sits
//! never clears it, and the mill is held slow (a stand whose gain hardly changes with
//! speed sits at 1 / (1 + margin) of its threshold and above; the closed loop on the
//! tandem model showed it). So the command also prints `slow_down_release`: the 99th
//! percentile of the stable windows' gain ratio plus [`RELEASE_ROOM`], at least
//! [`RELEASE_FLOOR`] (the configuration's default), and says so when that comes above
//! [`RELEASE_CEILING`] (then the margin is too small for a release with room below the
//! alarm: raise `--margin`).
//!
//! Refused, with the file and the reason: a recording too short for one gain window; a
//! recording that shows chatter: a stand whose gain rises above [`CHATTER_FACTOR`]
//! times its median over the recording; a stand column missing, or a sample rate other
//! than the stand channels'. A stand above [`NOTE_FACTOR`] times its median is noted
//! with the time, for the engineer to look at. Where the factors come from, on the
//! tandem model (`sim::tandem`): stable rolling at a constant speed up to 95% of the
//! critical speed, with welds and tension steps, stayed within 2.5 times the median;
//! the end of an acceleration into 95% of the critical speed raised the gain for a
//! second or two, up to 3.9 times (at 0.5 m/s^2); a ramp past the critical speed
//! reached 14-28 times its median by the time chatter had developed. The thresholds
//! hold up to the highest speed recorded: record stable rolling up to the highest
//! allowed speed, accelerations to it included.

use std::path::PathBuf;

use anyhow::Context;
use serde::Serialize;

use super::recording::{mill_index, windows, Recording, BLOCK};
use crate::cli::capture::Picked;
use crate::cli::OutputFormat;

/// The margin when `--margin` is not given, percent.
pub const DEFAULT_MARGIN_PERCENT: f64 = 10.0;
/// Largest allowed `--margin`, percent.
pub const MAX_MARGIN_PERCENT: f64 = 200.0;
/// A stand's gain above this many times its median over a recording means the
/// recording shows chatter (see the module docs for where the factor comes from).
pub const CHATTER_FACTOR: f64 = 8.0;
/// A stand's gain above this many times its median is noted (an acceleration's
/// transient, or the start of chatter: see the module docs).
pub const NOTE_FACTOR: f64 = 3.0;
/// Lowest `slow_down_release` printed: the configuration's default.
pub const RELEASE_FLOOR: f64 = 0.8;
/// Highest `slow_down_release` printed (the alarm is at 1).
pub const RELEASE_CEILING: f64 = 0.95;
/// The release level's room above the stable windows' 99th percentile ratio.
pub const RELEASE_ROOM: f64 = 0.05;

/// Arguments of `millgate chatter commission`.
#[derive(Debug, Clone, clap::Args)]
pub struct CommissionArgs {
    /// Gateway configuration with the `[[tandem_mills]]` entry (`gain_thresholds` may
    /// be left out: they are what this computes).
    #[arg(long)]
    pub config: PathBuf,
    /// A CSV of stable rolling, header `t,<stand channel>,...` (as `millgate chatter`
    /// reads); once per recording.
    #[arg(long = "input", required_unless_present = "db")]
    pub inputs: Vec<PathBuf>,
    /// Also take recordings from this history file's captures of the mill's stands
    /// (with --captures).
    #[arg(long, requires = "captures")]
    pub db: Option<PathBuf>,
    /// Which captures (with --db): `LAST:N` (the mill's newest N) or capture ids,
    /// comma-separated (`12,15`); manual captures of stable rolling, or chatter-free
    /// ones (a capture that shows chatter is refused as a CSV is).
    #[arg(long, requires = "db", value_parser = Picked::captures)]
    pub captures: Option<Picked>,
    /// Name of the tandem mill (default: the first one).
    #[arg(long)]
    pub mill: Option<String>,
    /// Margin above the largest stable gain, percent.
    #[arg(long, default_value_t = DEFAULT_MARGIN_PERCENT)]
    pub margin: f64,
    /// A column of the recordings holding the mill's speed (any unit), to report the
    /// speeds the recordings covered.
    #[arg(long)]
    pub speed_column: Option<String>,
    /// Output format.
    #[arg(long, value_enum, default_value = "text")]
    pub format: OutputFormat,
}

/// Why recordings cannot commission the mill.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CommissionError {
    /// No recording.
    #[error("no recording given (--input STABLE.csv, once per recording)")]
    NoRecording,
    /// `--margin` out of range.
    #[error("--margin: {0} is not allowed (must be >= 0 and <= {MAX_MARGIN_PERCENT} percent)")]
    Margin(f64),
    /// A recording gives no full gain window.
    #[error(
        "{recording}: {duration_s:.3} s is too short for the gain window: the first gain needs \
         {needed_s:.3} s of samples (the first {BLOCK}-sample block, then gain_window_s = \
         {gain_window_s} s and a hop of {hop_s} s)"
    )]
    TooShort {
        /// The recording.
        recording: String,
        /// Its length, s.
        duration_s: f64,
        /// Length the first gain needs, s.
        needed_s: f64,
        /// The mill's gain window, s.
        gain_window_s: f64,
        /// The monitor's hop, s.
        hop_s: f64,
    },
    /// A recording shows chatter.
    #[error(
        "{recording}: shows chatter: the chatter-band gain of stand {stand} (`{channel}`) \
         reaches {largest:.3} at t = {largest_at_s:.2} s, {factor:.1} times its median \
         {median:.3} over the recording (stable rolling stays below {CHATTER_FACTOR} times); \
         it first passed {CHATTER_FACTOR} times at t = {first_at_s:.2} s: commission from \
         stable rolling only (cut the recording before then)"
    )]
    Chatter {
        /// The recording.
        recording: String,
        /// The stand, 1-based.
        stand: usize,
        /// The stand's channel.
        channel: String,
        /// Its largest gain.
        largest: f64,
        /// When, s (the recording's time).
        largest_at_s: f64,
        /// Its median gain over the recording.
        median: f64,
        /// Largest over median.
        factor: f64,
        /// When the gain first passed the factor, s.
        first_at_s: f64,
    },
}

/// The speeds some windows covered, from a speed column of the recordings.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SpeedCoverage {
    /// The column.
    pub column: String,
    /// Lowest speed at a window's end.
    pub lowest: f64,
    /// Highest speed at a window's end.
    pub highest: f64,
}

/// One recording's part.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RecordingFigures {
    /// The recording.
    pub recording: String,
    /// Its length, s.
    pub duration_s: f64,
    /// Windows with a full gain window.
    pub windows: usize,
    /// Per stand, the largest gain over the median gain.
    pub largest_over_median: Vec<f64>,
    /// Per stand, when its largest gain was, s (the recording's time).
    pub largest_at_s: Vec<f64>,
    /// The speeds its windows covered.
    pub speeds: Option<SpeedCoverage>,
}

/// One stand's figures over every recording.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct StandFigures {
    /// The stand's channel.
    pub channel: String,
    /// Largest chatter-band gain.
    pub largest_gain: f64,
    /// Largest chatter-band RMS, channel unit.
    pub largest_band_rms: f64,
}

/// What commissioning found.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Commissioning {
    /// The tandem mill.
    pub mill: String,
    /// Margin over the largest stable figures, percent.
    pub margin_percent: f64,
    /// Per stand, the largest gain plus the margin, rounded up to 0.001: the
    /// `gain_thresholds` to paste.
    pub gain_thresholds: Vec<f64>,
    /// Per stand, the largest band RMS plus the margin, rounded up to 0.001 (what a
    /// band-RMS alarm would be set to).
    pub band_rms_thresholds: Vec<f64>,
    /// 99th percentile over the stable windows of the largest gain / threshold.
    pub stable_ratio_p99: f64,
    /// The release level of the slow-down request for these thresholds (see the
    /// module docs): `slow_down_release` to paste.
    pub slow_down_release: f64,
    /// Whether the release would have to be above [`RELEASE_CEILING`] (a margin too
    /// small).
    pub release_cramped: bool,
    /// The same release for a band-RMS alarm at `band_rms_thresholds`.
    pub band_rms_release: f64,
    /// Largest K_mean over every window.
    pub largest_k_mean: f64,
    /// For `detector = "paper"`: the largest K_mean moved the margin of the way to 1,
    /// rounded up to 0.001 (at most 0.999).
    pub k_max: f64,
    /// Per stand.
    pub stands: Vec<StandFigures>,
    /// Windows with a full gain window, over every recording.
    pub windows: usize,
    /// Seconds of recordings.
    pub duration_s: f64,
    /// The speeds every recording's windows covered.
    pub speeds: Option<SpeedCoverage>,
    /// Per recording.
    pub recordings: Vec<RecordingFigures>,
}

/// Runs `millgate chatter commission`: returns what it prints.
pub fn run(args: &CommissionArgs) -> anyhow::Result<String> {
    let config = millgate_config::load_uncommissioned(&args.config)?;
    let index = mill_index(&config, args.mill.as_deref(), &args.config)?;
    let mut recordings = args
        .inputs
        .iter()
        .map(|path| Recording::read(path, &config, index, args.speed_column.as_deref()))
        .collect::<anyhow::Result<Vec<_>>>()?;
    if let (Some(db), Some(selection)) = (&args.db, &args.captures) {
        recordings.extend(captured(db, &config, index, selection)?);
    }
    let commissioning = commission(&config, index, &recordings, args.margin)?;
    Ok(match args.format {
        OutputFormat::Json => serde_json::to_string_pretty(&commissioning)? + "\n",
        OutputFormat::Text => text(&commissioning),
    })
}

/// The captures of mill `index` of `config` that `selection` names in the history
/// `db`, oldest first, as recordings of its stands (each named `db#capture ID`).
/// Errors name the file and the capture: one that is not the mill's, lacks a stand, or
/// is a chatter episode (the chatter check of [`commission`] then runs on the rest).
fn captured(
    db: &std::path::Path,
    config: &millgate_config::Config,
    index: usize,
    selection: &Picked,
) -> anyhow::Result<Vec<Recording>> {
    use crate::history::query::{CaptureRow, Filter, HistoryReader};
    let mill = &config.tandem_mills[index];
    let reader = HistoryReader::open(db)?;
    let mut rows: Vec<CaptureRow> = Vec::new();
    reader.for_each(
        &Filter::default(),
        |row: CaptureRow| -> anyhow::Result<()> {
            let wanted = match selection {
                Picked::Last(_) => row.subject == mill.name,
                Picked::Numbers(ids) => ids.contains(&row.id),
            };
            if wanted {
                rows.push(row);
            }
            Ok(())
        },
    )?;
    match selection {
        Picked::Last(n) => {
            if rows.len() < *n as usize {
                anyhow::bail!(
                    "{}: --captures LAST:{n}: tandem mill \"{}\" has {} captures",
                    db.display(),
                    mill.name,
                    rows.len()
                );
            }
            rows.drain(..rows.len() - *n as usize);
        }
        Picked::Numbers(ids) => {
            for id in ids {
                match rows.iter().find(|r| r.id == *id) {
                    None => anyhow::bail!(
                        "{}: --captures: no capture {id} (see `millgate capture list --db {}`)",
                        db.display(),
                        db.display()
                    ),
                    Some(row) if row.subject != mill.name => anyhow::bail!(
                        "{}: --captures: capture {id} is of \"{}\", not of tandem mill \"{}\"",
                        db.display(),
                        row.subject,
                        mill.name
                    ),
                    Some(_) => {}
                }
            }
        }
    }
    let mut recordings = Vec::with_capacity(rows.len());
    for row in rows {
        if row.kind == "chatter" {
            // The gateway warned in it: not stable rolling, however far it developed
            // (a slowed-down episode may stay below the chatter factor).
            anyhow::bail!(
                "{}#capture {}: a chatter episode (the gateway warned at {}): commission from \
                 stable rolling only (manual captures of the stands, `command.manual_capture`)",
                db.display(),
                row.id,
                row.started_at
            );
        }
        let capture = reader.capture_of(row)?;
        let name = format!("{}#capture {}", db.display(), capture.row.id);
        let rate_hz = config.channels[mill.stands[0]].sample_rate_hz;
        if (capture.row.sample_rate_hz / rate_hz - 1.0).abs() > super::recording::RATE_TOLERANCE {
            anyhow::bail!(
                "{name}: sampled at {} Hz, the stand channels sample at {rate_hz} Hz",
                capture.row.sample_rate_hz
            );
        }
        let mut stands = Vec::with_capacity(mill.stands.len());
        for &channel in &mill.stands {
            let wanted = &config.channels[channel].name;
            let found = capture
                .channels
                .iter()
                .find(|c| c.name == *wanted)
                .ok_or_else(|| {
                    anyhow::anyhow!(
                        "{name}: no channel `{wanted}` for a stand of \"{}\"",
                        mill.name
                    )
                })?;
            stands.push(found.samples.clone());
        }
        recordings.push(Recording {
            name,
            time_s: (0..stands[0].len()).map(|k| capture.time_s(k)).collect(),
            stands,
            speed: None,
        });
    }
    Ok(recordings)
}

/// Commission mill `index` of `config` from stable `recordings` with `margin_percent`
/// (see the module docs); the recordings' stands are in the mill's order.
pub fn commission(
    config: &millgate_config::Config,
    index: usize,
    recordings: &[Recording],
    margin_percent: f64,
) -> anyhow::Result<Commissioning> {
    if !(0.0..=MAX_MARGIN_PERCENT).contains(&margin_percent) {
        return Err(CommissionError::Margin(margin_percent).into());
    }
    if recordings.is_empty() {
        return Err(CommissionError::NoRecording.into());
    }
    let mill = &config.tandem_mills[index];
    let channels: Vec<String> = mill
        .stands
        .iter()
        .map(|&c| config.channels[c].name.clone())
        .collect();
    let stands = channels.len();
    let rate_hz = config.channels[mill.stands[0]].sample_rate_hz;
    let margin = margin_percent / 100.0;
    let mut largest_gain = vec![0.0_f64; stands];
    let mut largest_rms = vec![0.0_f64; stands];
    let mut largest_k_mean = f64::NEG_INFINITY;
    let mut figures = Vec::new();
    // Every stable window's gains and band RMS per stand, for the release levels.
    let mut stable_gains: Vec<Vec<f64>> = Vec::new();
    let mut stable_rms: Vec<Vec<f64>> = Vec::new();
    for recording in recordings {
        let evaluated =
            windows(config, index, recording).with_context(|| recording.name.clone())?;
        let full: Vec<_> = evaluated.iter().filter(|w| w.gain.is_some()).collect();
        if full.is_empty() {
            let window = (mill.window_s * rate_hz).round() as usize;
            let hop = (window / 2).max(1);
            let gain = (mill.gain_window_s * rate_hz).round() as usize;
            return Err(CommissionError::TooShort {
                recording: recording.name.clone(),
                duration_s: recording.len() as f64 / rate_hz,
                needed_s: (BLOCK + window.max(gain + hop)) as f64 / rate_hz,
                gain_window_s: mill.gain_window_s,
                hop_s: hop as f64 / rate_hz,
            }
            .into());
        }
        let mut largest_over_median = Vec::with_capacity(stands);
        let mut largest_times = Vec::with_capacity(stands);
        for (stand, channel) in channels.iter().enumerate() {
            let gains: Vec<(f64, f64)> = full
                .iter()
                .filter_map(|w| w.gain.as_ref().map(|g| (w.t_s, g.gain[stand])))
                .collect();
            let mut sorted: Vec<f64> = gains.iter().map(|&(_, g)| g).collect();
            sorted.sort_by(f64::total_cmp);
            let median = sorted[sorted.len() / 2];
            let (largest_at_s, largest) =
                gains
                    .iter()
                    .copied()
                    .fold((0.0, f64::NEG_INFINITY), |best, (t, g)| {
                        if g > best.1 {
                            (t, g)
                        } else {
                            best
                        }
                    });
            if largest > CHATTER_FACTOR * median {
                let first_at_s = gains
                    .iter()
                    .find(|&&(_, g)| g > CHATTER_FACTOR * median)
                    .map_or(largest_at_s, |&(t, _)| t);
                return Err(CommissionError::Chatter {
                    recording: recording.name.clone(),
                    stand: stand + 1,
                    channel: channel.clone(),
                    largest,
                    largest_at_s,
                    median,
                    factor: largest / median,
                    first_at_s,
                }
                .into());
            }
            largest_over_median.push(largest / median);
            largest_times.push(largest_at_s);
            largest_gain[stand] = largest_gain[stand].max(largest);
            for window in &full {
                if let Some(gain) = &window.gain {
                    largest_rms[stand] = largest_rms[stand].max(gain.band_rms[stand]);
                }
            }
        }
        for window in &full {
            if let Some(gain) = &window.gain {
                stable_gains.push(gain.gain.to_vec());
                stable_rms.push(gain.band_rms.to_vec());
            }
        }
        largest_k_mean = evaluated
            .iter()
            .map(|w| w.result.k_mean)
            .fold(largest_k_mean, f64::max);
        let speeds = recording.speed.as_ref().map(|(column, speed)| {
            let at_ends = full.iter().map(|w| speed[w.last_sample]);
            SpeedCoverage {
                column: column.clone(),
                lowest: at_ends.clone().fold(f64::INFINITY, f64::min),
                highest: at_ends.fold(f64::NEG_INFINITY, f64::max),
            }
        });
        figures.push(RecordingFigures {
            recording: recording.name.clone(),
            duration_s: recording.duration_s(),
            windows: full.len(),
            largest_over_median,
            largest_at_s: largest_times,
            speeds,
        });
    }
    let speeds = figures
        .iter()
        .map(|f| f.speeds.clone())
        .collect::<Option<Vec<_>>>()
        .and_then(|all| {
            let column = all.first()?.column.clone();
            Some(SpeedCoverage {
                column,
                lowest: all.iter().map(|s| s.lowest).fold(f64::INFINITY, f64::min),
                highest: all
                    .iter()
                    .map(|s| s.highest)
                    .fold(f64::NEG_INFINITY, f64::max),
            })
        });
    let gain_thresholds: Vec<f64> = largest_gain
        .iter()
        .map(|g| up(g * (1.0 + margin)))
        .collect();
    let band_rms_thresholds: Vec<f64> =
        largest_rms.iter().map(|r| up(r * (1.0 + margin))).collect();
    let (stable_ratio_p99, slow_down_release) = release(&stable_gains, &gain_thresholds);
    let (_, band_rms_release) = release(&stable_rms, &band_rms_thresholds);
    Ok(Commissioning {
        mill: mill.name.clone(),
        margin_percent,
        gain_thresholds,
        band_rms_thresholds,
        stable_ratio_p99,
        release_cramped: stable_ratio_p99 + RELEASE_ROOM > RELEASE_CEILING,
        slow_down_release,
        band_rms_release,
        largest_k_mean,
        k_max: up(largest_k_mean + margin * (1.0 - largest_k_mean)).min(0.999),
        stands: channels
            .into_iter()
            .zip(largest_gain.iter().zip(&largest_rms))
            .map(
                |(channel, (&largest_gain, &largest_band_rms))| StandFigures {
                    channel,
                    largest_gain,
                    largest_band_rms,
                },
            )
            .collect(),
        windows: figures.iter().map(|f| f.windows).sum(),
        duration_s: figures.iter().map(|f| f.duration_s).sum(),
        speeds,
        recordings: figures,
    })
}

/// The 99th percentile over `windows` of the largest figure / threshold, and the
/// release level for it (see the module docs).
fn release(windows: &[Vec<f64>], thresholds: &[f64]) -> (f64, f64) {
    let mut ratios: Vec<f64> = windows
        .iter()
        .map(|figures| {
            figures
                .iter()
                .zip(thresholds)
                .map(|(figure, threshold)| figure / threshold)
                .fold(0.0, f64::max)
        })
        .collect();
    ratios.sort_by(f64::total_cmp);
    let p99 = ratios
        .get((ratios.len() as f64 * 0.99) as usize)
        .or(ratios.last())
        .copied()
        .unwrap_or(0.0);
    let level = ((p99 + RELEASE_ROOM) * 100.0).ceil() / 100.0;
    (p99, level.clamp(RELEASE_FLOOR, RELEASE_CEILING))
}

/// `value` rounded up to 0.001, so a printed threshold is never below the computed one.
fn up(value: f64) -> f64 {
    (value * 1000.0 - 1e-9).ceil() / 1000.0
}

/// A list of figures as TOML: `[1.187, 1.492]`.
fn toml_list(values: &[f64]) -> String {
    let items: Vec<String> = values.iter().map(|v| format!("{v:.3}")).collect();
    format!("[{}]", items.join(", "))
}

/// What `commission` prints as text.
fn text(c: &Commissioning) -> String {
    use std::fmt::Write as _;
    let mut out = String::new();
    let _ = writeln!(
        out,
        "tandem mill \"{}\": {} recording(s), {:.1} s, {} windows with a full gain window",
        c.mill,
        c.recordings.len(),
        c.duration_s,
        c.windows
    );
    for r in &c.recordings {
        let speeds = r.speeds.as_ref().map_or(String::new(), |s| {
            format!(", {} {:.2} .. {:.2}", s.column, s.lowest, s.highest)
        });
        let _ = writeln!(
            out,
            "  {}: {:.1} s, {} windows{speeds}",
            r.recording, r.duration_s, r.windows
        );
        for (stand, (&factor, &at_s)) in r
            .largest_over_median
            .iter()
            .zip(&r.largest_at_s)
            .enumerate()
        {
            if factor > NOTE_FACTOR {
                let _ = writeln!(
                    out,
                    "    note: stand {} (`{}`) reaches {factor:.1} times its median gain at t = \
                     {at_s:.2} s (the end of an acceleration, a weld, or the start of chatter: \
                     look at it with `millgate chatter --plot`)",
                    stand + 1,
                    c.stands[stand].channel
                );
            }
        }
    }
    match &c.speeds {
        Some(s) => {
            let _ = writeln!(
                out,
                "speeds covered ({}): {:.2} .. {:.2}; the thresholds hold up to {:.2}: record \
                 stable rolling up to the highest allowed speed",
                s.column, s.lowest, s.highest, s.highest
            );
        }
        None => {
            let _ = writeln!(
                out,
                "speeds covered: not recorded (--speed-column NAME names the recordings' speed \
                 column); the thresholds hold up to the highest speed the recordings reached"
            );
        }
    }
    let _ = writeln!(
        out,
        "{:<16} {:>12} {:>14} {:>16}",
        "stand",
        "largest gain",
        format!("threshold +{}%", c.margin_percent),
        "largest band RMS"
    );
    for (stand, threshold) in c.stands.iter().zip(&c.gain_thresholds) {
        let _ = writeln!(
            out,
            "{:<16} {:>12.3} {:>14.3} {:>16.3}",
            stand.channel, stand.largest_gain, threshold, stand.largest_band_rms
        );
    }
    let _ = writeln!(
        out,
        "# paste into the [[tandem_mills]] entry \"{}\":",
        c.mill
    );
    let _ = writeln!(out, "gain_thresholds = {}", toml_list(&c.gain_thresholds));
    let _ = writeln!(
        out,
        "# the request clears below this (stable rolling stayed below {:.3} of the thresholds \
         in 99% of the windows):",
        c.stable_ratio_p99
    );
    let _ = writeln!(out, "slow_down_release = {:.2}", c.slow_down_release);
    if c.release_cramped {
        let _ = writeln!(
            out,
            "# warning: a release with room below the alarm would be above {RELEASE_CEILING}: \
             with these thresholds the request may never clear in stable rolling; raise \
             --margin (now {}%)",
            c.margin_percent
        );
    }
    let _ = writeln!(
        out,
        "# for detector = \"paper\" (largest K_mean {:.3}, moved {}% of the way to 1):\n\
         # k_max = {:.3}",
        c.largest_k_mean, c.margin_percent, c.k_max
    );
    let _ = writeln!(
        out,
        "# a band-RMS vibration alarm at the largest band RMS + {}%: {}",
        c.margin_percent,
        toml_list(&c.band_rms_thresholds)
    );
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The example tandem mill (five stands at 2500 Hz, window 0.5 s, gain 2 s).
    fn example() -> millgate_config::Config {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../config/examples/tandem-5stand.toml");
        millgate_config::load_uncommissioned(&path).expect("example")
    }

    /// `samples` of a chatter-band line (180 Hz) over a reference-band line (620 Hz)
    /// on every stand, the chatter line `amplitude(t)`.
    fn recording(samples: usize, amplitude: impl Fn(f64) -> f64) -> Recording {
        let time_s: Vec<f64> = (0..samples).map(|k| k as f64 / 2500.0).collect();
        let signal: Vec<f64> = time_s
            .iter()
            .map(|&t| {
                amplitude(t) * (std::f64::consts::TAU * 180.0 * t).sin()
                    + 0.5 * (std::f64::consts::TAU * 620.0 * t).sin()
            })
            .collect();
        Recording {
            name: "lines.csv".into(),
            time_s,
            stands: vec![signal; 5],
            speed: None,
        }
    }

    #[test]
    fn the_first_gain_needs_the_first_block_the_gain_window_and_a_hop() {
        let config = example();
        // 120 + 5000 + 625 samples: one window with a full gain window, gain 4.
        let needed = BLOCK + 5000 + 625;
        let c = commission(&config, 0, &[recording(needed, |_| 2.0)], 10.0).expect("commissioned");
        assert_eq!(c.windows, 1);
        for (threshold, stand) in c.gain_thresholds.iter().zip(&c.stands) {
            assert!((stand.largest_gain - 4.0).abs() < 0.16, "{stand:?}");
            assert_eq!(*threshold, up(stand.largest_gain * 1.1));
        }
        let error = commission(&config, 0, &[recording(needed - 1, |_| 2.0)], 10.0)
            .expect_err("one sample short");
        assert_eq!(
            error.to_string(),
            "lines.csv: 2.298 s is too short for the gain window: the first gain needs 2.298 s \
             of samples (the first 120-sample block, then gain_window_s = 2 s and a hop of 0.25 s)"
        );
    }

    #[test]
    fn a_chatter_line_growing_past_eight_times_its_median_is_refused() {
        let config = example();
        // 20 s steady, then the chatter line grows 20-fold over 5 s.
        let growing = |t: f64| 0.5 * (1.0 + 19.0 * ((t - 20.0) / 5.0).clamp(0.0, 1.0));
        let error =
            commission(&config, 0, &[recording(62_500, growing)], 10.0).expect_err("chatter");
        let message = error.to_string();
        assert!(
            message.starts_with(
                "lines.csv: shows chatter: the chatter-band gain of stand 1 (`s1_vib`)"
            ),
            "{message}"
        );
        assert!(
            message.contains("commission from stable rolling only"),
            "{message}"
        );
        // Growing fourfold: noted, not refused.
        let milder = |t: f64| 0.5 * (1.0 + 3.5 * ((t - 20.0) / 5.0).clamp(0.0, 1.0));
        let c = commission(&config, 0, &[recording(62_500, milder)], 10.0).expect("commissioned");
        let factor = c.recordings[0].largest_over_median[0];
        assert!(factor > NOTE_FACTOR && factor < CHATTER_FACTOR, "{factor}");
        assert!(
            text(&c).contains("note: stand 1 (`s1_vib`) reaches"),
            "{}",
            text(&c)
        );
        assert!(commission(&config, 0, &[], 10.0).is_err());
        assert_eq!(
            commission(&config, 0, &[recording(62_500, milder)], -1.0)
                .expect_err("negative margin")
                .to_string(),
            "--margin: -1 is not allowed (must be >= 0 and <= 200 percent)"
        );
    }
}
