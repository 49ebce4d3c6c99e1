//! `millgate fatigue (--input FILE [--channel NAME] | --db FILE --driveline NAME) --m M
//! --ref-cycles N --ref-range-knm S [--endurance-knm E [--endurance-rule R]]
//! [--gate-knm G] [--format text|json] [--list-cycles]`: the rainflow count (ASTM
//! E1049-85) and Miner's damage of a torque record.
//!
//! Prints the cycle histogram (range x mean bins), the damage (`"damage"` in JSON) on
//! the S-N curve `N(dM) = ref_cycles * (ref_range_knm / dM)^m`, and the cycles whose
//! range exceeds 10% of the largest (`"cycles_over_10pct"`). The counting is
//! `analysis::fatigue` (crate-private), meant for the service's ledger too.
//!
//! - `--input`: a CSV record (`t` then torque columns, kN*m), counted as one stream; a
//!   capture export whose header (the JSON file beside it, or the `# millgate
//!   capture` line of an older export) gives the channel another unit than kN*m is
//!   refused. The gate defaults to 1% of the channel's range (largest minus
//!   smallest sample).
//! - `--db`: the bite captures the history keeps for the driveline, each counted on
//!   its own (never joined: they are windows of a few tenths of a second around each
//!   bite, with seconds to hours between them). That is what the file holds of the
//!   torque: it lacks the bars' entry-to-exit cycles between the windows and the bites
//!   whose captures retention has dropped, so it is a lower bound of the service's
//!   ledger, which counts the whole stream. `--gate-knm` is required (there is no
//!   record to take a range from). Captures are read one at a time, twice.

use std::fmt::Write as _;
use std::path::PathBuf;

use anyhow::{bail, Context as _};
use millgate_dsp::miner::{EnduranceRule, MeanCorrection, SnCurve, SnCurveError, SnCurveSettings};
use millgate_dsp::rainflow::{Rainflow, RainflowSettings};
use serde_json::json;

use super::OutputFormat;
use crate::analysis::fatigue::{account, Account, LARGE_FRACTION, STACK};
use crate::history::query::{CaptureRow, Filter, HistoryReader};
use crate::records::csv;

/// The default gate, as a fraction of the channel's range.
const DEFAULT_GATE_FRACTION: f64 = 0.01;

/// What happens below `--endurance-knm`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum EnduranceArg {
    /// No damage below the limit.
    #[default]
    Cutoff,
    /// The curve goes on with the slope 2m - 1 below the limit.
    Haibach,
}

/// Arguments of `millgate fatigue`.
#[derive(Debug, Clone, clap::Args)]
#[command(group(clap::ArgGroup::new("source").required(true).args(["input", "db"])))]
pub struct FatigueArgs {
    /// A recorded torque: CSV with a header, first column `t` (s), other columns torque
    /// (kN*m).
    #[arg(long)]
    pub input: Option<PathBuf>,
    /// Channel of `--input` to count (default: the first after `t`).
    #[arg(long, requires = "input")]
    pub channel: Option<String>,
    /// A history file (SQLite): count the driveline's kept bite captures.
    #[arg(long, requires = "driveline")]
    pub db: Option<PathBuf>,
    /// The driveline of `--db`.
    #[arg(long, requires = "db")]
    pub driveline: Option<String>,
    /// Basquin exponent m of the S-N curve (> 0). The numeric options take negative
    /// values, so that `--m -3` is refused with the allowed range rather than read
    /// as an unknown option.
    #[arg(long, allow_negative_numbers = true)]
    pub m: f64,
    /// Cycles to failure at the reference range (> 0).
    #[arg(long, allow_negative_numbers = true)]
    pub ref_cycles: f64,
    /// Reference torque range, kN*m (> 0).
    #[arg(long, allow_negative_numbers = true)]
    pub ref_range_knm: f64,
    /// Endurance limit, kN*m (> 0).
    #[arg(long, allow_negative_numbers = true)]
    pub endurance_knm: Option<f64>,
    /// Below the endurance limit: no damage (cutoff) or Haibach's slope 2m - 1.
    #[arg(long, value_enum, default_value_t = EnduranceArg::Cutoff, requires = "endurance_knm")]
    pub endurance_rule: EnduranceArg,
    /// Hysteresis gate of the reversals, kN*m (>= 0 and below the channel's range;
    /// default 1% of the range of `--input`; required with `--db`).
    #[arg(long, allow_negative_numbers = true)]
    pub gate_knm: Option<f64>,
    /// Output format.
    #[arg(long, value_enum, default_value_t = OutputFormat::Text)]
    pub format: OutputFormat,
    /// JSON: list every cycle as [range_knm, mean_knm, count] in counting order
    /// (`--input` only).
    #[arg(long, requires = "input")]
    pub list_cycles: bool,
}

/// The S-N curve of the arguments; an error names the option and the allowed range.
fn curve(args: &FatigueArgs) -> anyhow::Result<SnCurve> {
    let settings = SnCurveSettings {
        m: args.m,
        ref_cycles: args.ref_cycles,
        ref_range_knm: args.ref_range_knm,
        torque_share: 1.0,
        endurance_knm: args.endurance_knm,
        endurance_rule: match args.endurance_rule {
            EnduranceArg::Cutoff => EnduranceRule::Cutoff,
            EnduranceArg::Haibach => EnduranceRule::Haibach,
        },
        mean_correction: MeanCorrection::None,
    };
    SnCurve::new(settings).map_err(|error| {
        let (option, value) = match error {
            SnCurveError::M => ("m", args.m),
            SnCurveError::RefCycles => ("ref-cycles", args.ref_cycles),
            SnCurveError::RefRangeKnm => ("ref-range-knm", args.ref_range_knm),
            SnCurveError::EnduranceKnm => ("endurance-knm", args.endurance_knm.unwrap_or(0.0)),
            SnCurveError::TorqueShare | SnCurveError::UltimateKnm => ("m", args.m),
        };
        anyhow::anyhow!("--{option} {value}: {error}")
    })
}

/// The gate: given (>= 0, below `range_knm`) or the default fraction of it.
fn gate(args: &FatigueArgs, channel: &str, range_knm: f64) -> anyhow::Result<f64> {
    let gate = args.gate_knm.unwrap_or(DEFAULT_GATE_FRACTION * range_knm);
    if !(gate.is_finite() && gate >= 0.0 && gate < range_knm) {
        bail!(
            "--gate-knm {gate}: must be >= 0 and below the range of channel `{channel}`, \
             {range_knm} kN*m (its largest minus its smallest sample)"
        );
    }
    Ok(gate)
}

/// Runs the command; returns the text to print. A record without a cycle has no
/// result: an error.
pub fn run(args: &FatigueArgs) -> anyhow::Result<String> {
    let curve = curve(args)?;
    let (source, gate_knm, account, cycles) = match (&args.input, &args.db) {
        (Some(input), _) => {
            let (name, gate, account, cycles) = record(args, input, &curve)?;
            (
                format!("{} channel `{name}`", input.display()),
                gate,
                account,
                cycles,
            )
        }
        (None, Some(db)) => {
            let driveline = args.driveline.as_deref().unwrap_or_default();
            let (gate, account) = history(args, db, driveline, &curve)?;
            let source = format!(
                "{} driveline `{driveline}` (kept bite captures)",
                db.display()
            );
            let ledger = service_ledger(db, driveline)?;
            if account.cycles == 0.0 && ledger.is_some() {
                // The service's ledger is the result; the captures add nothing.
                return Ok(match args.format {
                    OutputFormat::Json => json!({ "ledger": ledger }).to_string(),
                    OutputFormat::Text => format!(
                        "{source}: no cycle above the gate of {gate} kN*m\n\n{}",
                        ledger_text(ledger.as_ref())?
                    ),
                });
            }
            return finish(args, (&source, gate, &account, None), ledger);
        }
        (None, None) => bail!("one of --input or --db is required"),
    };
    finish(args, (&source, gate_knm, &account, cycles), None)
}

/// The report of `account` (of `source`, counted with `gate_knm`; `cycles` listed),
/// with the service's `ledger` when there is one. A record without a cycle has no
/// result: an error.
fn finish(
    args: &FatigueArgs,
    (source, gate_knm, account, cycles): (&str, f64, &Account, Option<CycleList>),
    ledger: Option<serde_json::Value>,
) -> anyhow::Result<String> {
    if account.cycles == 0.0 {
        bail!("{source}: no cycle above the gate of {gate_knm} kN*m");
    }
    Ok(match args.format {
        OutputFormat::Json => {
            let mut report = json_report(account, gate_knm, cycles);
            if let Some(ledger) = ledger {
                report["ledger"] = ledger;
            }
            report.to_string()
        }
        OutputFormat::Text => {
            text_report(source, account, gate_knm)? + &ledger_text(ledger.as_ref())?
        }
    })
}

/// Days of damage per day `--db` prints.
const LEDGER_DAYS: u32 = 14;

/// The fatigue ledger the service keeps in the history for `driveline`: each
/// component's life used and installation, the resets, the damage per UTC day of the
/// last [`LEDGER_DAYS`] days with bites; `None` without one (no
/// `drivelines[].fatigue`, or a file from before the ledger).
fn service_ledger(
    db: &std::path::Path,
    driveline: &str,
) -> anyhow::Result<Option<serde_json::Value>> {
    let reader = HistoryReader::open(db)?;
    let state = reader.state()?;
    let Some(saved) = state
        .drivelines
        .iter()
        .find(|d| d.name == driveline)
        .and_then(|d| d.fatigue_ledger.as_deref())
    else {
        return Ok(None);
    };
    let components = crate::analysis::fatigue_ledger::saved_lives(saved).with_context(|| {
        format!(
            "{}: the fatigue ledger of `{driveline}` is not readable",
            db.display()
        )
    })?;
    let components: Vec<serde_json::Value> = components
        .iter()
        .map(|c| {
            json!({
                "name": c.name,
                "life_used": c.life_used,
                "installed": crate::state::time::UtcTime::from_unix_ms(c.installed_unix_ms).to_string(),
            })
        })
        .collect();
    let history = reader.fatigue(driveline, LEDGER_DAYS)?;
    Ok(Some(json!({
        "components": components,
        "resets": history.resets,
        "days": history.days,
    })))
}

/// The ledger as text (nothing without one).
fn ledger_text(ledger: Option<&serde_json::Value>) -> anyhow::Result<String> {
    let mut out = String::new();
    let Some(ledger) = ledger else {
        return Ok(out);
    };
    writeln!(
        out,
        "\nthe service's fatigue ledger (the whole torque stream):"
    )?;
    for c in ledger["components"].as_array().into_iter().flatten() {
        writeln!(
            out,
            "  {:<20} life used {:.6e} since {}",
            c["name"].as_str().unwrap_or_default(),
            c["life_used"].as_f64().unwrap_or_default(),
            c["installed"].as_str().unwrap_or_default()
        )?;
    }
    for r in ledger["resets"].as_array().into_iter().flatten() {
        writeln!(
            out,
            "  reset {} of {} (life used {:.6e}) by {}",
            r["time"].as_str().unwrap_or_default(),
            r["component"].as_str().unwrap_or_default(),
            r["life_used"].as_f64().unwrap_or_default(),
            r["origin"].as_str().unwrap_or_default()
        )?;
    }
    for d in ledger["days"].as_array().into_iter().flatten() {
        writeln!(
            out,
            "  {} {:<20} damage {:.6e} over {} bites",
            d["day"].as_str().unwrap_or_default(),
            d["component"].as_str().unwrap_or_default(),
            d["damage"].as_f64().unwrap_or_default(),
            d["bites"]
        )?;
    }
    Ok(out)
}

/// Every cycle of `signal` as [range, mean, count], in counting order.
type CycleList = Vec<[f64; 3]>;

fn record(
    args: &FatigueArgs,
    input: &std::path::Path,
    curve: &SnCurve,
) -> anyhow::Result<(String, f64, Account, Option<CycleList>)> {
    let path = input.display().to_string();
    let table = csv::read(input).with_context(|| path.clone())?;
    let (name, signal) = table
        .pick_torque(args.channel.as_deref())
        .map_err(|e| anyhow::anyhow!("{path}: {e}"))?;
    let header = table
        .capture_header()
        .map_err(|e| anyhow::anyhow!("{path}: {e}"))?;
    if let Some(header) = header {
        if let Some(channel) = header.channels.iter().find(|c| c.channel.name == name) {
            if channel.channel.unit != "kN*m" {
                bail!(
                    "{path}: channel `{name}` is in {}, not a torque (kN*m): the fatigue \
                     count takes a torque channel (--channel)",
                    channel.channel.unit
                );
            }
        }
    }
    let finite = signal.iter().copied().filter(|v| v.is_finite());
    let (low, high) = finite.fold((f64::MAX, f64::MIN), |(l, h), v| (l.min(v), h.max(v)));
    let gate_knm = gate(args, name, (high - low).max(0.0))?;
    let mut segments = |each: &mut dyn FnMut(&[f64])| -> anyhow::Result<()> {
        each(signal);
        Ok(())
    };
    let account = account(gate_knm, &[*curve], &mut segments)?;
    let cycles = args.list_cycles.then(|| {
        let counter = Rainflow::<STACK>::new(RainflowSettings { gate_knm })
            .expect("the gate was accepted by the account");
        let mut state = counter.state();
        let mut list = Vec::new();
        let mut push =
            |c: millgate_dsp::rainflow::Cycle| list.push([c.range_knm, c.mean_knm, c.count]);
        counter.block(&mut state, signal, &mut push);
        counter.residue(&state, &mut push);
        list
    });
    Ok((name.to_string(), gate_knm, account, cycles))
}

fn history(
    args: &FatigueArgs,
    db: &std::path::Path,
    driveline: &str,
    curve: &SnCurve,
) -> anyhow::Result<(f64, Account)> {
    let reader = HistoryReader::open(db)?;
    if !reader.drivelines()?.iter().any(|d| d == driveline) {
        bail!(
            "{}: no driveline `{driveline}` (drivelines: {})",
            db.display(),
            reader.drivelines()?.join(", ")
        );
    }
    let Some(gate_knm) = args.gate_knm else {
        bail!("--gate-knm is required with --db (kN*m, >= 0)");
    };
    if !(gate_knm.is_finite() && gate_knm >= 0.0) {
        bail!("--gate-knm {gate_knm}: must be finite and >= 0 kN*m");
    }
    let filter = Filter {
        name: Some(driveline.to_string()),
        ..Default::default()
    };
    let mut segments = |each: &mut dyn FnMut(&[f64])| -> anyhow::Result<()> {
        reader.for_each(&filter, |row: CaptureRow| -> anyhow::Result<()> {
            if row.kind != "bite" {
                return Ok(());
            }
            let capture = reader.capture_of(row)?;
            if let Some(torque) = capture.channels.iter().find(|c| c.unit == "kN*m") {
                each(&torque.samples);
            }
            Ok(())
        })
    };
    Ok((gate_knm, account(gate_knm, &[*curve], &mut segments)?))
}

fn json_report(account: &Account, gate_knm: f64, cycles: Option<CycleList>) -> serde_json::Value {
    let mut report = json!({
        "gate_knm": gate_knm,
        "segments": account.segments,
        "samples": account.samples,
        "non_finite": account.non_finite,
        "overflows": account.overflows,
        "cycles": account.cycles,
        "max_range_knm": account.max_range_knm,
        "cycles_over_10pct": account.cycles_over_10pct,
        "damage": account.damage[0],
        "histogram": {
            "range_edges_knm": account.range_edges_knm(),
            "mean_edges_knm": account.mean_edges_knm(),
            "counts": account.histogram,
        },
    });
    if let Some(list) = cycles {
        report["cycle_list"] = json!(list);
    }
    report
}

fn text_report(source: &str, account: &Account, gate_knm: f64) -> anyhow::Result<String> {
    let mut out = String::new();
    writeln!(
        out,
        "{source}: {} samples, gate {gate_knm:.3} kN*m",
        account.samples
    )?;
    writeln!(
        out,
        "cycles {} (largest range {:.1} kN*m; {} over {:.0}% of it)",
        account.cycles,
        account.max_range_knm,
        account.cycles_over_10pct,
        LARGE_FRACTION * 100.0
    )?;
    writeln!(
        out,
        "damage {:.6e} (Miner's sum on the S-N curve)",
        account.damage[0]
    )?;
    if account.overflows > 0 || account.non_finite > 0 {
        writeln!(
            out,
            "{} stack overflows (oldest range counted as a half cycle), {} non-finite samples skipped",
            account.overflows, account.non_finite
        )?;
    }
    let means = account.mean_edges_knm();
    write!(out, "\nrange \\ mean kN*m")?;
    for pair in means.windows(2) {
        write!(out, " {:>9.1}", 0.5 * (pair[0] + pair[1]))?;
    }
    writeln!(out)?;
    let ranges = account.range_edges_knm();
    for (row, pair) in account.histogram.iter().zip(ranges.windows(2)) {
        write!(out, "{:>7.1}..{:<8.1}", pair[0], pair[1])?;
        for count in row {
            write!(out, " {count:>9}")?;
        }
        writeln!(out)?;
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn args(input: PathBuf) -> FatigueArgs {
        FatigueArgs {
            input: Some(input),
            channel: None,
            db: None,
            driveline: None,
            m: 5.0,
            ref_cycles: 1e6,
            ref_range_knm: 100.0,
            endurance_knm: None,
            endurance_rule: EnduranceArg::Cutoff,
            gate_knm: Some(0.0),
            format: OutputFormat::Json,
            list_cycles: false,
        }
    }

    /// A scratch folder of this process and test, removed at the test's end.
    fn folder(test: &str) -> PathBuf {
        let dir =
            std::env::temp_dir().join(format!("millgate-fatigue-{test}-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    fn write(dir: &std::path::Path, name: &str, text: &str) -> PathBuf {
        let path = dir.join(name);
        std::fs::write(&path, text).unwrap();
        path
    }

    #[test]
    fn astm_example_counts_and_damages() -> anyhow::Result<()> {
        // ASTM E1049-85's example, x 10 kN*m: one closed cycle of 40, half cycles of
        // 30, 40, 60, 80, 80 and 90.
        let values = [-2.0, 1.0, -3.0, 5.0, -1.0, 3.0, -4.0, 4.0, -2.0];
        let mut text = String::from("t,torque\n");
        for (i, v) in values.iter().enumerate() {
            writeln!(text, "{},{}", i as f64 * 0.001, v * 10.0)?;
        }
        let dir = folder("astm");
        let report = run(&args(write(&dir, "astm.csv", &text)));
        let _ = std::fs::remove_dir_all(&dir);
        let report: serde_json::Value = serde_json::from_str(&report?)?;
        assert_eq!(report["cycles"], 4.0);
        assert_eq!(report["max_range_knm"], 90.0);
        let expected: f64 = [40.0, 40.0, 30.0, 40.0, 60.0, 80.0, 80.0, 90.0]
            .iter()
            .map(|r: &f64| 0.5 * (r / 100.0).powi(5) / 1e6)
            .sum();
        let damage = report["damage"].as_f64().unwrap();
        assert!(
            (damage / expected - 1.0).abs() < 1e-12,
            "{damage} vs {expected}"
        );
        // Every range is over 10% of the largest (9): 8 entries, 4 cycles.
        assert_eq!(report["cycles_over_10pct"], 4.0);
        Ok(())
    }

    #[test]
    fn bad_curve_gate_and_unit_are_refused_by_option() {
        let text = "t,torque\n0,0\n0.001,10\n0.002,0\n";
        let dir = folder("refused");
        let path = write(&dir, "small.csv", text);
        let mut bad = args(path.clone());
        bad.ref_cycles = 0.0;
        let error = run(&bad).unwrap_err().to_string();
        assert_eq!(error, "--ref-cycles 0: ref_cycles must be finite and > 0");
        let mut bad = args(path.clone());
        bad.gate_knm = Some(12.0);
        let error = run(&bad).unwrap_err().to_string();
        assert!(
            error.starts_with(
                "--gate-knm 12: must be >= 0 and below the range of channel `torque`, 10 kN*m"
            ),
            "{error}"
        );
        let header = r#"# millgate capture {"id":1,"kind":"bite","subject":"F1","bite_counter":1,"bite_time":null,"started_at":"2026-01-01T00:00:00.000Z","first_sample_unix_ns":0,"kernel_time":false,"sample_rate_hz":1000.0,"channels":[{"name":"speed","unit":"rpm","scale":1.0,"offset":0.0,"encoding":"float64"}],"gaps":[],"analysis":null,"episode":null,"gateway_version":"x","config_name":null,"config_hash":null}"#;
        let path = write(
            &dir,
            "speed.csv",
            &format!("{header}\nt,speed\n0,0\n0.001,10\n0.002,0\n"),
        );
        let error = run(&args(path)).unwrap_err().to_string();
        let _ = std::fs::remove_dir_all(&dir);
        assert!(
            error.contains("channel `speed` is in rpm, not a torque (kN*m)"),
            "{error}"
        );
    }
}
