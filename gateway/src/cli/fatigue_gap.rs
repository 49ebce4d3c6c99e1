//! `millgate sim fatigue-gap --model M.toml --out DIR [--bars N] [--max-gap-mrad G]
//! [--step-mrad S] [--gate-knm G] [--noise-rms R] [--seed S]`: the physics of the
//! fatigue ledger. Bars of the model are simulated (entry, ring-down, rolling, exit:
//! [`rolling_schedule_with_gap`]) with an opened gap of 0 ..= `max_gap_mrad` in its
//! measured coupling, the same noise for every gap, and the whole measured torque is
//! counted as the service counts it (rainflow with the gate, the residue as half
//! cycles). Written: `fatigue-gap.csv` (per gap: TAF, largest range, damage per bar on
//! the curve m = 5, `ref_cycles` 1e6 at the model's static torque, and the damage
//! relative to the closed gap for m = 3, 5 and 8) and `fatigue-gap.svg` (the relative
//! damage over the gap).

use std::fmt::Write as _;
use std::path::PathBuf;

use anyhow::{bail, Context as _};
use millgate_dsp::miner::{EnduranceRule, MeanCorrection, SnCurve, SnCurveSettings};
use millgate_dsp::rainflow::{Rainflow, RainflowSettings};
use millgate_sim::model::Model;
use millgate_sim::plot::{curves_svg, CurvesPlot};
use millgate_sim::schedule::{rolling_schedule_with_gap, BarTiming};

use crate::analysis::fatigue::STACK;

/// The Basquin exponents compared (welded joints about 3, shafts in torsion 5 to 8).
const EXPONENTS: [f64; 3] = [3.0, 5.0, 8.0];
/// The exponent of the absolute damage column.
const ABSOLUTE_M: f64 = 5.0;
/// Cycles to failure at the model's static torque as range (the absolute column's
/// reference; the relative columns do not depend on it).
const REF_CYCLES: f64 = 1e6;
/// Each bar: idle, then rolling until tail-out (the ring-down has died out).
const TIMING: BarTiming = BarTiming {
    idle_s: 1.0,
    rolling_s: 3.0,
};

/// Arguments of `millgate sim fatigue-gap`.
#[derive(Debug, Clone, clap::Args)]
pub struct FatigueGapArgs {
    /// Driveline model (TOML); the gap opens in its measured coupling.
    #[arg(long)]
    pub model: PathBuf,
    /// Output directory (created if missing).
    #[arg(long)]
    pub out: PathBuf,
    /// Bars per gap, at the model's static torque (1..=100).
    #[arg(long, default_value_t = 6, value_parser = clap::value_parser!(u16).range(1..=100))]
    pub bars: u16,
    /// Largest gap, mrad (> 0, <= 20).
    #[arg(long, default_value_t = 4.0)]
    pub max_gap_mrad: f64,
    /// Gap step, mrad (> 0, at most 100 steps).
    #[arg(long, default_value_t = 0.5)]
    pub step_mrad: f64,
    /// Hysteresis gate of the count, kN*m (>= 0).
    #[arg(long, default_value_t = 4.0)]
    pub gate_knm: f64,
    /// RMS of the added noise, kN*m (>= 0).
    #[arg(long, default_value_t = 1.0)]
    pub noise_rms: f64,
    /// Seed of the noise (the same for every gap).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
}

/// One gap's account.
struct GapRow {
    gap_mrad: f64,
    taf: f64,
    max_range_knm: f64,
    /// Damage per bar for each of [`EXPONENTS`].
    damage_per_bar: [f64; EXPONENTS.len()],
}

/// Runs the command; returns the table printed.
pub fn run(args: &FatigueGapArgs) -> anyhow::Result<String> {
    if !(args.max_gap_mrad > 0.0 && args.max_gap_mrad <= 20.0) {
        bail!(
            "--max-gap-mrad {}: must be > 0 and <= 20 mrad",
            args.max_gap_mrad
        );
    }
    let steps = args.max_gap_mrad / args.step_mrad;
    if !(args.step_mrad > 0.0 && steps <= 100.0) {
        bail!(
            "--step-mrad {}: must be > 0 with at most 100 steps up to --max-gap-mrad",
            args.step_mrad
        );
    }
    if !(args.noise_rms.is_finite() && args.noise_rms >= 0.0) {
        bail!(
            "--noise-rms {}: must be finite and >= 0 kN*m",
            args.noise_rms
        );
    }
    let counter = Rainflow::<STACK>::new(RainflowSettings {
        gate_knm: args.gate_knm,
    })
    .map_err(|e| anyhow::anyhow!("--gate-knm {}: {e}", args.gate_knm))?;
    let model = Model::load(&args.model)?;
    let static_knm = model.load.static_torque;
    let curves: Vec<SnCurve> = EXPONENTS
        .iter()
        .map(|&m| {
            SnCurve::new(SnCurveSettings {
                m,
                ref_cycles: REF_CYCLES,
                ref_range_knm: static_knm,
                torque_share: 1.0,
                endurance_knm: None,
                endurance_rule: EnduranceRule::Cutoff,
                mean_correction: MeanCorrection::None,
            })
        })
        .collect::<Result<_, _>>()
        .map_err(|e| anyhow::anyhow!("{}: load.static_torque: {e}", args.model.display()))?;
    let coupling = model.measurement.coupling;
    let bars = usize::from(args.bars);
    let mut rows = Vec::new();
    for step in 0..=steps.floor() as usize {
        let gap_mrad = step as f64 * args.step_mrad;
        let schedule = rolling_schedule_with_gap(
            &model,
            &vec![static_knm; bars],
            TIMING,
            args.noise_rms,
            args.seed,
            coupling,
            &[gap_mrad * 1e-3],
        )?;
        let mut state = counter.state();
        let mut damage = [0.0; EXPONENTS.len()];
        let mut max_range_knm = 0.0_f64;
        let mut add = |cycle: millgate_dsp::rainflow::Cycle| {
            max_range_knm = max_range_knm.max(cycle.range_knm);
            for (sum, curve) in damage.iter_mut().zip(&curves) {
                *sum += curve.damage(&cycle);
            }
        };
        counter.block(&mut state, &schedule.torque_knm, &mut add);
        counter.residue(&state, &mut add);
        let taf = schedule.bites.iter().map(|b| b.taf).sum::<f64>() / bars as f64;
        rows.push(GapRow {
            gap_mrad,
            taf,
            max_range_knm,
            damage_per_bar: damage.map(|d| d / bars as f64),
        });
    }
    write_outputs(args, &model, &rows)
}

fn write_outputs(args: &FatigueGapArgs, model: &Model, rows: &[GapRow]) -> anyhow::Result<String> {
    let closed = &rows[0].damage_per_bar;
    let absolute = EXPONENTS.iter().position(|&m| m == ABSOLUTE_M).unwrap_or(0);
    let mut csv = String::from("gap_mrad,taf,max_range_knm,damage_per_bar_m5");
    for m in EXPONENTS {
        write!(csv, ",relative_m{m}")?;
    }
    csv.push('\n');
    for row in rows {
        write!(
            csv,
            "{},{:.4},{:.2},{:.6e}",
            row.gap_mrad, row.taf, row.max_range_knm, row.damage_per_bar[absolute]
        )?;
        for (damage, zero) in row.damage_per_bar.iter().zip(closed) {
            write!(csv, ",{:.4}", damage / zero)?;
        }
        csv.push('\n');
    }
    let curves = EXPONENTS
        .iter()
        .enumerate()
        .map(|(k, m)| {
            let points = rows
                .iter()
                .map(|row| (row.gap_mrad, row.damage_per_bar[k] / closed[k]))
                .collect();
            (format!("m = {m}"), points)
        })
        .collect();
    let svg = curves_svg(&CurvesPlot {
        title: format!("{}: damage per bar over the opened gap", model.name),
        x_label: format!(
            "opened gap in coupling {} \"{}\", mrad",
            model.measurement.coupling, model.couplings[model.measurement.coupling].name
        ),
        y_label: "damage per bar / damage with the gap closed".into(),
        curves,
        highlighted: None,
        points: (
            "TAF".into(),
            rows.iter().map(|row| (row.gap_mrad, row.taf)).collect(),
        ),
    })?;
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    let csv_path = args.out.join("fatigue-gap.csv");
    let svg_path = args.out.join("fatigue-gap.svg");
    std::fs::write(&csv_path, &csv).with_context(|| format!("writing {}", csv_path.display()))?;
    std::fs::write(&svg_path, svg).with_context(|| format!("writing {}", svg_path.display()))?;
    Ok(format!(
        "{csv}wrote {} and {}\n",
        csv_path.display(),
        svg_path.display()
    ))
}
