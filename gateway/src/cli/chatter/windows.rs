//! `millgate chatter --input stands.csv --config MILL.toml [--mill NAME] [--format
//! text|json] [--plot FILE.svg]`: a recorded (or simulated, `millgate sim tandem`) CSV
//! of a tandem mill's stand vibrations through the service's own chatter monitor,
//! offline.
//!
//! The CSV's columns are named after the mill's stand channels (`t,s1_vib,...`); its
//! sample rate must be the channels'. The samples go to the monitor in 120-sample
//! blocks (a Modbus DAQ's), stamped with their own sample time, and every evaluated
//! window is judged as the service judges it ([`ChatterMonitor::judge`]): one row per
//! window with per stand the principal frequency, the chatter-band RMS and the
//! chatter-band gain (what commissioning reads), sigma_n, K_mean, the gain ratio (the
//! early-warning figure) and the flags; the first warning and alarm times at the end.
//! The configuration may leave out `gain_thresholds` (a mill not yet commissioned):
//! the gains are then reported without a ratio. `--plot FILE.svg` (with the default
//! `sim-tools` feature) draws the per-stand band RMS and gain, the gain ratio and the
//! flags over time.
//!
//! **Process context.** Columns `weld` (the PLC's weld-tracking bit, 0/1: 1 from the
//! weld reaching the first stand until it has left the last), `weld_1` .. `weld_N`
//! (a bit per stand, stand 1 first: 1 while the weld is in that stand; all N or
//! none), `speed_mpm`, `coil` and `product` are read when present. With `weld` the
//! slow-down request is gated as the service gates it: while the bit is set and for
//! the mill's `weld_settle_s` after, the band-gain alarm needs `weld_alarm_factor`
//! times its level (chatter during or right after a weld is still caught, at the
//! higher level); with `weld_1` .. `weld_N` each stand's gain ratio is held so by its
//! own bit only (the row's context `weld` is 1 when any stand's is); a window the hold kept from the
//! alarm is marked `held_off`, and `first_alarm_s` is the first alarm (= slow-down
//! request) after the gating. A row with an impossible context value (weld not 0/1, a
//! negative speed, a coil or product that is not a whole number) is not used for the
//! gating and is counted (`invalid_context`, with its line); the analysis goes on.
//! With the mill's `product_groups`, each window is judged by the thresholds of the
//! group holding the `product` column's value at the end of its last block (the mill's
//! `gain_thresholds` for a product in no group, or without a valid one), as the
//! service does with the PLC's product; each row names the group (`thresholds_group`,
//! and in the text the flag `group=NAME`).
//!
//! [`ChatterMonitor::judge`]: crate::analysis::chatter::ChatterMonitor::judge

use std::path::PathBuf;

#[cfg(feature = "sim-tools")]
use anyhow::Context;
use serde::Serialize;

use super::mill::mill_index;
use crate::analysis::chatter::windows_in_context;
use crate::cli::OutputFormat;
use crate::records::stands;
use crate::state::context::ProcessContext;

/// Arguments of `millgate chatter` (without a subcommand).
#[derive(Debug, Clone, clap::Args)]
pub struct WindowsArgs {
    /// CSV with a header `t,<stand channel>,...` (t in s, accelerations in the
    /// channels' unit).
    #[arg(long)]
    pub input: PathBuf,
    /// Gateway configuration with the `[[tandem_mills]]` entry (`gain_thresholds` may
    /// be left out).
    #[arg(long)]
    pub config: PathBuf,
    /// Name of the tandem mill (default: the first one).
    #[arg(long)]
    pub mill: Option<String>,
    /// Output format.
    #[arg(long, value_enum, default_value = "text")]
    pub format: OutputFormat,
    /// Also draw the per-stand band RMS and gain, the gain ratio and the flags over
    /// time (SVG).
    #[cfg(feature = "sim-tools")]
    #[arg(long)]
    pub plot: Option<PathBuf>,
}

/// One stand in one window.
#[derive(Debug, Clone, Serialize)]
pub struct StandRow {
    /// Principal frequency in the chatter band, Hz.
    pub principal_hz: f64,
    /// Chatter-band RMS over the gain's window, channel unit; `None` until it is full.
    pub band_rms: Option<f64>,
    /// Chatter-band gain (chatter-band RMS / reference-band RMS) over the gain's
    /// window; `None` until it is full.
    pub gain: Option<f64>,
}

/// One evaluated window.
#[derive(Debug, Clone, Serialize)]
pub struct WindowRow {
    /// Time of the window's last sample, s (the CSV's time axis).
    pub t_s: f64,
    /// Per stand, in the mill's order.
    pub stands: Vec<StandRow>,
    /// RMS difference of adjacent principal frequencies, Hz.
    pub sigma_n_hz: f64,
    /// Mean correlation of adjacent stands' chatter-band content.
    pub k_mean: f64,
    /// Largest gain / threshold (the early-warning figure, >= 1 alarm); `None` until
    /// the gain's window is full or without thresholds.
    pub gain_ratio: Option<f64>,
    /// The configured detector's warning in this window.
    pub warning: bool,
    /// The configured detector's alarm condition in this window.
    pub alarm: bool,
    /// The slow-down request after this window.
    pub slow_down: bool,
    /// The weld hold raised the alarm level in this window (a weld in the mill, or
    /// less than `weld_settle_s` since it left).
    pub weld_hold: bool,
    /// The weld hold kept this window's alarm off (the gain ratio reached 1 but not
    /// `weld_alarm_factor`).
    pub held_off: bool,
    /// The context at the window's last sample, with context columns (left out
    /// without, or when invalid there).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub context: Option<ProcessContext>,
    /// The product group whose thresholds judged this window (by the row's `product`
    /// column); `None`: the mill's `gain_thresholds`.
    pub thresholds_group: Option<String>,
}

/// Rows of the CSV whose context was invalid.
#[derive(Debug, Clone, Serialize)]
pub struct InvalidContextReport {
    /// How many rows.
    pub rows: usize,
    /// The first one's line in the file.
    pub first_line: usize,
    /// Why it was invalid.
    pub why: String,
}

/// What `millgate chatter` reports.
#[derive(Debug, Clone, Serialize)]
pub struct ChatterReport {
    /// Every evaluated window, in time order.
    pub windows: Vec<WindowRow>,
    /// End time of the first window with the warning, s.
    pub first_warning_s: Option<f64>,
    /// End time of the first window with the alarm (after the weld gating: the first
    /// slow-down request), s.
    pub first_alarm_s: Option<f64>,
    /// The context columns found in the CSV ([`ContextColumns::names`](crate::analysis::chatter::ContextColumns::names)).
    pub context_columns: Vec<String>,
    /// Windows whose alarm the weld hold kept off.
    pub held_off_windows: usize,
    /// Rows with an impossible context value (not used for the gating); `None` when
    /// there were none.
    pub invalid_context: Option<InvalidContextReport>,
}

/// Runs `millgate chatter`: returns what it prints.
pub fn run(args: &WindowsArgs) -> anyhow::Result<String> {
    let report = analyze(args)?;
    #[cfg(feature = "sim-tools")]
    if let Some(path) = &args.plot {
        std::fs::write(path, plot(&report)?)
            .with_context(|| format!("writing {}", path.display()))?;
    }
    Ok(match args.format {
        OutputFormat::Json => serde_json::to_string_pretty(&report)? + "\n",
        OutputFormat::Text => text(&report),
    })
}

/// The report of `args` (see the module docs).
pub fn analyze(args: &WindowsArgs) -> anyhow::Result<ChatterReport> {
    let config = millgate_config::load_uncommissioned(&args.config)?;
    let index = mill_index(&config, args.mill.as_deref(), &args.config)?;
    let recording = stands::read(&args.input, &config, index, None)?;
    let (windows, invalid) = windows_in_context(
        &config,
        index,
        &recording.time_s,
        &recording.stands,
        &recording.context,
    )?;
    let context = &recording.context;
    let invalid_context = invalid.first.map(|(sample, error)| InvalidContextReport {
        rows: invalid.samples,
        first_line: context
            .lines
            .as_ref()
            .and_then(|lines| lines.get(sample).copied())
            .unwrap_or(sample + 2),
        why: error.to_string(),
    });
    let context_columns = context.names();
    let windows: Vec<WindowRow> = windows
        .into_iter()
        .map(|window| WindowRow {
            t_s: window.t_s,
            stands: window
                .result
                .stands
                .iter()
                .enumerate()
                .map(|(stand, metrics)| StandRow {
                    principal_hz: metrics.principal_hz,
                    band_rms: window
                        .gain
                        .as_ref()
                        .and_then(|g| g.band_rms.get(stand).copied()),
                    gain: window
                        .gain
                        .as_ref()
                        .and_then(|g| g.gain.get(stand).copied()),
                })
                .collect(),
            sigma_n_hz: window.result.sigma_n_hz,
            k_mean: window.result.k_mean,
            gain_ratio: window.gain_ratio,
            warning: window.verdict.warning,
            alarm: window.verdict.alarm,
            slow_down: window.verdict.slow_down,
            weld_hold: window.weld_hold,
            held_off: window.verdict.held_off,
            context: window.context,
            thresholds_group: window
                .thresholds_group
                .map(|g| config.tandem_mills[index].product_groups[g].name.clone()),
        })
        .collect();
    let first = |pick: fn(&WindowRow) -> bool| windows.iter().find(|w| pick(w)).map(|w| w.t_s);
    Ok(ChatterReport {
        first_warning_s: first(|w| w.warning),
        first_alarm_s: first(|w| w.alarm),
        held_off_windows: windows.iter().filter(|w| w.held_off).count(),
        context_columns,
        invalid_context,
        windows,
    })
}

/// The report as an SVG: log10 of each stand's band RMS and gain, log10 of the gain
/// ratio (0 is the alarm level) and the flags (warning 1, alarm 2, slow-down 3 when
/// set).
#[cfg(feature = "sim-tools")]
pub fn plot(report: &ChatterReport) -> anyhow::Result<String> {
    use millgate_sim::plot::time_series_svg;
    let time_s: Vec<f64> = report.windows.iter().map(|w| w.t_s).collect();
    let stands = report.windows.first().map_or(0, |w| w.stands.len());
    let log = |v: Option<f64>| v.filter(|&v| v > 0.0).map(f64::log10);
    let per_stand = |pick: fn(&StandRow) -> Option<f64>| {
        (0..stands)
            .map(|s| {
                let values = report
                    .windows
                    .iter()
                    .map(|w| log(pick(&w.stands[s])))
                    .collect();
                (format!("stand {}", s + 1), values)
            })
            .collect()
    };
    let rms = per_stand(|stand| stand.band_rms);
    let gain = per_stand(|stand| stand.gain);
    let ratio = vec![(
        "gain ratio".to_owned(),
        report.windows.iter().map(|w| log(w.gain_ratio)).collect(),
    )];
    let flag = |name: &str, level: f64, pick: fn(&WindowRow) -> bool| {
        let values = report
            .windows
            .iter()
            .map(|w| Some(if pick(w) { level } else { 0.0 }))
            .collect();
        (name.to_owned(), values)
    };
    let flags = vec![
        flag("warning", 1.0, |w| w.warning),
        flag("alarm", 2.0, |w| w.alarm),
        flag("slow-down", 3.0, |w| w.slow_down),
    ];
    Ok(time_series_svg(
        "millgate chatter",
        &time_s,
        &[
            ("log10 chatter-band RMS", rms),
            ("log10 chatter-band gain", gain),
            ("log10 gain ratio (0 = alarm)", ratio),
            ("flags", flags),
        ],
    )?)
}

/// The report as aligned text lines.
fn text(report: &ChatterReport) -> String {
    use std::fmt::Write as _;
    let mut out = String::new();
    let stands = report.windows.first().map_or(0, |w| w.stands.len());
    let _ = write!(out, "{:>8}", "t_s");
    for s in 1..=stands {
        let _ = write!(
            out,
            " {:>8} {:>8} {:>7}",
            format!("f{s}_hz"),
            format!("rms{s}"),
            format!("gain{s}")
        );
    }
    let _ = writeln!(
        out,
        " {:>8} {:>7} {:>7} flags",
        "sigma_n", "K_mean", "gain_r"
    );
    for w in &report.windows {
        let _ = write!(out, "{:>8.3}", w.t_s);
        for stand in &w.stands {
            let figure = |v: Option<f64>| v.map_or("-".to_owned(), |v| format!("{v:.3}"));
            let (rms, gain) = (figure(stand.band_rms), figure(stand.gain));
            let _ = write!(out, " {:>8.2} {rms:>8} {gain:>7}", stand.principal_hz);
        }
        let ratio = w.gain_ratio.map_or("-".to_owned(), |v| format!("{v:.3}"));
        let flags: Vec<&str> = [
            (w.warning, "warning"),
            (w.alarm, "alarm"),
            (w.slow_down, "slow-down"),
            (w.weld_hold, "weld-hold"),
            (w.held_off, "held-off"),
        ]
        .iter()
        .filter(|(set, _)| *set)
        .map(|(_, name)| *name)
        .collect();
        let group = w
            .thresholds_group
            .as_ref()
            .map(|name| format!("group={name}"));
        let flags: Vec<&str> = flags.into_iter().chain(group.as_deref()).collect();
        let line = format!(
            " {:>8.3} {:>7.3} {ratio:>7} {}",
            w.sigma_n_hz,
            w.k_mean,
            flags.join(",")
        );
        let _ = writeln!(out, "{}", line.trim_end());
    }
    let time = |t: Option<f64>| t.map_or("none".to_owned(), |t| format!("{t:.3} s"));
    if !report.context_columns.is_empty() {
        let _ = writeln!(
            out,
            "context columns: {}; windows held off by the weld hold: {}",
            report.context_columns.join(", "),
            report.held_off_windows
        );
    }
    if let Some(invalid) = &report.invalid_context {
        let _ = writeln!(
            out,
            "invalid context in {} rows (not used for the gating), the first at line {}: {}",
            invalid.rows, invalid.first_line, invalid.why
        );
    }
    let _ = writeln!(
        out,
        "first warning: {}, first alarm: {}",
        time(report.first_warning_s),
        time(report.first_alarm_s)
    );
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use millgate_sim::tandem::simulate::{simulate, NoiseBurst, RunSettings};
    use millgate_sim::tandem::truth::{ground_truth, mill_critical_speed};
    use millgate_sim::tandem::{PassSchedule, TandemMill};

    fn example() -> PathBuf {
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../config/examples/tandem-5stand.toml")
    }

    /// `csv` (a simulated record's) with a `weld` column: 1 in `weld_s` (from, to).
    fn with_weld_column(csv: &str, weld_s: (f64, f64)) -> String {
        let mut lines = csv.lines();
        let mut out = format!("{},weld\n", lines.next().unwrap_or_default());
        for line in lines {
            let t: f64 = line.split(',').next().and_then(|t| t.parse().ok()).unwrap();
            let bit = u8::from(t >= weld_s.0 && t < weld_s.1);
            out.push_str(&format!("{line},{bit}\n"));
        }
        out
    }

    /// The JSON report of `csv` on the example mill.
    fn report_of(csv: &str, name: &str) -> anyhow::Result<serde_json::Value> {
        let input = std::env::temp_dir().join(format!(
            "millgate-chatter-{name}-{}.csv",
            std::process::id()
        ));
        std::fs::write(&input, csv)?;
        let args = WindowsArgs {
            input: input.clone(),
            config: example(),
            mill: None,
            format: OutputFormat::Json,
            #[cfg(feature = "sim-tools")]
            plot: None,
        };
        let report = run(&args);
        std::fs::remove_file(&input)?;
        Ok(serde_json::from_str(&report?)?)
    }

    #[test]
    fn each_rows_product_picks_its_groups_thresholds() -> anyhow::Result<()> {
        // The example mill with a product tag and the group "quiet" (product 7, every
        // threshold ten times the mill's).
        let text = crate::analysis::chatter::testing::example_with_quiet_group(
            "product = \"product_code\"",
        );
        let scratch =
            std::env::temp_dir().join(format!("millgate-products-{}", std::process::id()));
        std::fs::create_dir_all(&scratch)?;
        let config = scratch.join("mill.toml");
        std::fs::write(&config, text)?;
        // A chatter-band line at gain 1.6 on every stand (1.35 times stand 1's
        // threshold), product 7 for 6 s, then product 8 (in no group).
        let recording = crate::analysis::chatter::testing::lines_recording(30_000, |_| 0.8);
        let mut csv = String::from("t,s1_vib,s2_vib,s3_vib,s4_vib,s5_vib,product\n");
        for (k, t) in recording.time_s.iter().enumerate() {
            let stands: Vec<String> = recording.stands.iter().map(|s| s[k].to_string()).collect();
            let product = if *t < 6.0 { 7 } else { 8 };
            csv += &format!("{t},{},{product}\n", stands.join(","));
        }
        let input = scratch.join("stands.csv");
        std::fs::write(&input, csv)?;
        let args = WindowsArgs {
            input,
            config,
            mill: None,
            format: OutputFormat::Json,
            #[cfg(feature = "sim-tools")]
            plot: None,
        };
        let report: serde_json::Value = serde_json::from_str(&run(&args)?)?;
        std::fs::remove_dir_all(&scratch)?;
        let windows = report["windows"].as_array().expect("windows");
        for window in windows {
            let t = window["t_s"].as_f64().unwrap_or(f64::NAN);
            let group = &window["thresholds_group"];
            if t < 6.0 {
                assert_eq!(group, "quiet", "{window}");
                assert_eq!(window["alarm"], false, "{window}");
                assert!(
                    window["gain_ratio"].as_f64().is_none_or(|r| r < 0.2),
                    "{window}"
                );
            } else if t > 6.2 {
                assert_eq!(group, &serde_json::Value::Null, "{window}");
            }
        }
        // The first alarm comes with product 8's first window (the mill's thresholds).
        let first_alarm = report["first_alarm_s"].as_f64().expect("an alarm");
        assert!((6.0..6.3).contains(&first_alarm), "{first_alarm}");
        Ok(())
    }

    #[test]
    fn weld_columns_per_stand_hold_their_stands_only_and_come_for_every_stand_or_none(
    ) -> anyhow::Result<()> {
        // A chatter-band line at gain 1.8 on every stand: 1.52 times stand 1's
        // threshold, 1.21 times stand 2's (both below the weld hold's 2), 0.81 times
        // stand 3's.
        let recording = crate::analysis::chatter::testing::lines_recording(15_000, |_| 0.9);
        let csv = |welding: &[usize], columns: usize| {
            let names: Vec<String> = (1..=columns).map(|s| format!("weld_{s}")).collect();
            let mut csv = format!("t,s1_vib,s2_vib,s3_vib,s4_vib,s5_vib,{}\n", names.join(","));
            let bits: Vec<&str> = (0..columns)
                .map(|s| if welding.contains(&s) { "1" } else { "0" })
                .collect();
            for (k, t) in recording.time_s.iter().enumerate() {
                let stands: Vec<String> =
                    recording.stands.iter().map(|s| s[k].to_string()).collect();
                csv += &format!("{t},{},{}\n", stands.join(","), bits.join(","));
            }
            csv
        };
        // The weld in stand 1 holds stand 1; stand 2 alarms at its plain level.
        let first = report_of(&csv(&[0], 5), "weld-stand-1")?;
        assert!(
            first["first_alarm_s"].as_f64().is_some(),
            "{}",
            first["first_alarm_s"]
        );
        assert_eq!(
            first["context_columns"],
            serde_json::json!(["weld_1", "weld_2", "weld_3", "weld_4", "weld_5"])
        );
        // In stands 1 and 2 (a long weld): both held, nothing raised, counted.
        let both = report_of(&csv(&[0, 1], 5), "weld-stands-1-2")?;
        assert!(both["first_alarm_s"].is_null(), "{}", both["first_alarm_s"]);
        assert!(both["held_off_windows"].as_u64() > Some(10), "{both}");
        let windows = both["windows"].as_array().expect("windows");
        assert!(windows.iter().all(|w| w["slow_down"] == false));
        assert_eq!(windows[windows.len() - 1]["context"]["weld"], true);
        // In stand 3 only: stands 1 and 2 alarm as without a weld.
        let third = report_of(&csv(&[2], 5), "weld-stand-3")?;
        assert_eq!(third["held_off_windows"], 0);
        assert!(third["first_alarm_s"].as_f64().is_some());
        // A column for some stands only is refused, naming the first one missing.
        let error = report_of(&csv(&[0], 2), "weld-stands-2-of-5")
            .expect_err("two of five weld columns")
            .to_string();
        assert!(
            error.contains(
                "line 1: no column `weld_3`: weld-bit columns per stand (`weld_1` .. \
                            `weld_5`) must be given for every stand"
            ),
            "{error}"
        );
        Ok(())
    }

    #[test]
    fn the_weld_bit_holds_a_welds_slow_down_off_and_a_ramp_after_a_weld_still_alarms(
    ) -> anyhow::Result<()> {
        // The physical model: at 95% of the critical speed (the highest allowed), a
        // weld (the force noise 3 times louder for 3 s) at 8 s.
        let mill = TandemMill::new(&PassSchedule::example()?)?;
        let critical = mill_critical_speed(&mill)?;
        let mut settings =
            RunSettings::reference_ramp(critical.speed, 0.95, 30.0, 24.0, 2500.0, 11);
        let weld = NoiseBurst {
            time_s: 8.0,
            duration_s: 3.0,
            factor: 3.0,
            stand: None,
        };
        settings.excitation.noise_bursts.push(weld);
        let csv = simulate(&mill, &settings)?.to_csv(false);
        let weld_s = (weld.time_s, weld.time_s + weld.duration_s);
        let without = report_of(&csv, "weld-no-bit")?;
        let alarm = without["first_alarm_s"]
            .as_f64()
            .expect("the weld alarms without its bit");
        assert!(alarm > weld_s.0, "{alarm}");
        assert_eq!(without["held_off_windows"], 0);
        assert_eq!(without["context_columns"], serde_json::json!([]));
        let with = report_of(&with_weld_column(&csv, weld_s), "weld-bit")?;
        assert!(with["first_alarm_s"].is_null(), "{}", with["first_alarm_s"]);
        assert!(
            with["held_off_windows"].as_u64() > Some(0),
            "{}",
            with["held_off_windows"]
        );
        assert_eq!(with["context_columns"], serde_json::json!(["weld"]));
        let windows = with["windows"].as_array().expect("windows");
        assert!(windows.iter().all(|w| w["slow_down"] == false));
        // The hold lasts from the weld to weld_settle_s after it left, no longer.
        let held: Vec<f64> = windows
            .iter()
            .filter(|w| w["weld_hold"] == true)
            .filter_map(|w| w["t_s"].as_f64())
            .collect();
        let settle_s =
            millgate_config::load_uncommissioned(&example())?.tandem_mills[0].weld_settle_s;
        assert!(
            held.first().is_some_and(|&t| t >= weld_s.0)
                && held.last().is_some_and(|&t| t <= weld_s.1 + settle_s + 0.5),
            "{held:?}"
        );
        assert_eq!(windows[windows.len() - 1]["context"]["weld"], false);

        // A ramp whose weld leaves the mill 1 s before the critical speed: the alarm
        // still comes between the onset and developed chatter.
        let mut settings = RunSettings::reference_ramp(critical.speed, 0.9, 6.0, 14.0, 2500.0, 7);
        let at_critical_s = settings
            .ramp
            .time_at(critical.speed, mill.exit_speed(4, 1.0));
        let at_critical_s = at_critical_s.expect("the ramp passes the critical speed");
        let weld = NoiseBurst {
            time_s: at_critical_s - 4.0,
            duration_s: 3.0,
            factor: 3.0,
            stand: None,
        };
        settings.excitation.noise_bursts.push(weld);
        let record = simulate(&mill, &settings)?;
        let truth = ground_truth(&mill, &settings.ramp, &record, critical);
        let (onset, developed) = (
            truth.onset_s.expect("onset"),
            truth.developed_s.expect("developed"),
        );
        let weld_s = (weld.time_s, weld.time_s + weld.duration_s);
        let ramp = report_of(
            &with_weld_column(&record.to_csv(false), weld_s),
            "weld-ramp",
        )?;
        let alarm = ramp["first_alarm_s"].as_f64().expect("an alarm");
        assert!(
            alarm > onset && alarm < developed,
            "alarm {alarm} s, onset {onset} s, developed {developed} s"
        );

        // An impossible weld value is counted with its line, not used, and the analysis
        // goes on.
        let bad = with_weld_column(&csv, weld_s).replacen(",1\n", ",2\n", 1);
        let report = report_of(&bad, "weld-bad")?;
        let invalid = &report["invalid_context"];
        assert_eq!(invalid["rows"], 1);
        let line = invalid["first_line"].as_u64().expect("a line") as usize;
        assert!(
            bad.lines().nth(line - 1).is_some_and(|l| l.ends_with(",2")),
            "{line}"
        );
        assert!(
            invalid["why"]
                .as_str()
                .is_some_and(|w| w.starts_with("weld 2 is not allowed")),
            "{invalid}"
        );
        assert_eq!(
            report["windows"].as_array().map(Vec::len),
            Some(windows.len())
        );
        Ok(())
    }

    #[test]
    fn a_simulated_ramp_alarms_between_onset_and_developed_chatter() -> anyhow::Result<()> {
        // The physical model (not what the detector was built from): 6 s at 90% of the
        // critical speed, then 2 m/s^2, as the end-to-end tests.
        let mill = TandemMill::new(&PassSchedule::example()?)?;
        let critical = mill_critical_speed(&mill)?;
        let settings = RunSettings::reference_ramp(critical.speed, 0.9, 6.0, 14.0, 2500.0, 7);
        let record = simulate(&mill, &settings)?;
        let truth = ground_truth(&mill, &settings.ramp, &record, critical);
        let onset = truth.onset_s.expect("onset");
        let developed = truth.developed_s.expect("developed");
        let input =
            std::env::temp_dir().join(format!("millgate-chatter-{}.csv", std::process::id()));
        std::fs::write(&input, record.to_csv(false))?;
        #[cfg(feature = "sim-tools")]
        let plot = input.with_extension("svg");
        let mut args = WindowsArgs {
            input: input.clone(),
            config: example(),
            mill: None,
            format: OutputFormat::Json,
            #[cfg(feature = "sim-tools")]
            plot: Some(plot.clone()),
        };
        let json: serde_json::Value = serde_json::from_str(&run(&args)?)?;
        let alarm = json["first_alarm_s"].as_f64().expect("an alarm");
        assert!(
            alarm > onset && alarm < developed,
            "alarm {alarm} s, onset {onset} s, developed {developed} s"
        );
        let windows = json["windows"].as_array().expect("windows");
        // One window every 0.25 s after the first 0.5 s (the first block anchors).
        assert!(windows.len() >= 44, "{}", windows.len());
        assert_eq!(windows[0]["stands"].as_array().map(Vec::len), Some(5));
        let last = &windows[windows.len() - 1];
        assert_eq!(last["slow_down"], serde_json::Value::Bool(true));
        // Each stand's gain is reported, and the ratio is the largest gain / threshold
        // of the example's thresholds.
        let thresholds = [1.187, 1.492, 2.209, 3.087, 3.327];
        let mut with_gain = 0;
        for window in windows {
            let gains: Option<Vec<f64>> = window["stands"]
                .as_array()
                .expect("stands")
                .iter()
                .map(|stand| stand["gain"].as_f64())
                .collect();
            let Some(gains) = gains else {
                assert!(window["gain_ratio"].is_null(), "{window}");
                continue;
            };
            with_gain += 1;
            let ratio = gains
                .iter()
                .zip(thresholds)
                .map(|(gain, threshold)| gain / threshold)
                .fold(0.0, f64::max);
            let reported = window["gain_ratio"].as_f64().expect("a ratio with gains");
            assert!((ratio - reported).abs() < 1e-9 * ratio, "{window}");
        }
        assert!(
            with_gain + 9 >= windows.len(),
            "{with_gain} of {}",
            windows.len()
        );
        #[cfg(feature = "sim-tools")]
        {
            let svg = std::fs::read_to_string(&plot)?;
            assert!(
                svg.starts_with("<svg") && svg.contains("gain ratio"),
                "{}",
                &svg[..100]
            );
            std::fs::remove_file(&plot)?;
        }

        args.format = OutputFormat::Text;
        let text = run(&args)?;
        assert!(text.starts_with("     t_s"), "{text}");
        assert!(
            text.trim_end()
                .ends_with(&format!("first alarm: {alarm:.3} s")),
            "{text}"
        );

        args.mill = Some("nowhere".into());
        let error = analyze(&args).expect_err("unknown mill");
        assert!(
            error
                .to_string()
                .contains("--mill nowhere: no such tandem mill"),
            "{error}"
        );
        std::fs::remove_file(&input)?;
        Ok(())
    }
}
