//! `millgate stiffness`: paper eq. (2) forward (stiffness -> natural frequencies) or
//! inverse (measured frequencies -> every stiffness pair), SI units.

use anyhow::{bail, Context as _};
use millgate_dsp::stiffness::{
    forward, inverse, Inertias, NaturalFrequencies, Stiffness, StiffnessError,
};
use serde_json::json;
use std::fmt::Write as _;

use super::OutputFormat;

/// Arguments of `millgate stiffness`.
#[derive(Debug, Clone, clap::Args)]
#[command(group(clap::ArgGroup::new("given").required(true).args(["freq", "stiffness"])))]
pub struct StiffnessArgs {
    /// Inertias Q1,Q2,Q3 (motor, gear/pinion, rolls), kg*m^2, referred to roll speed.
    #[arg(long, value_delimiter = ',', required = true)]
    pub inertia: Vec<f64>,
    /// Measured natural frequencies B1,B2, Hz (inverse problem).
    #[arg(long, value_delimiter = ',')]
    pub freq: Option<Vec<f64>>,
    /// Coupling stiffnesses C12,C23, N*m/rad (forward problem).
    #[arg(long, value_delimiter = ',')]
    pub stiffness: Option<Vec<f64>>,
    /// Drawing stiffnesses C12,C23, N*m/rad: the inverse lists the nearest root first.
    #[arg(long, value_delimiter = ',')]
    pub drawing: Option<Vec<f64>>,
    /// Output format.
    #[arg(long, value_enum, default_value_t = OutputFormat::Text)]
    pub format: OutputFormat,
}

fn pair(values: &[f64], option: &str) -> anyhow::Result<[f64; 2]> {
    match values {
        [a, b] => Ok([*a, *b]),
        _ => bail!(
            "--{option} takes two comma-separated values, got {}",
            values.len()
        ),
    }
}

/// `error` as a sentence naming the command-line option and the value at fault.
fn option_error(error: StiffnessError, args: &StiffnessArgs) -> anyhow::Error {
    let list = |values: &Option<Vec<f64>>| {
        values
            .as_deref()
            .unwrap_or_default()
            .iter()
            .map(f64::to_string)
            .collect::<Vec<_>>()
            .join(",")
    };
    let inertia = list(&Some(args.inertia.clone()));
    let (option, given, rule) = match error {
        StiffnessError::Q1 => ("inertia", inertia, "Q1 must be finite and > 0 kg*m^2"),
        StiffnessError::Q2 => ("inertia", inertia, "Q2 must be finite and > 0 kg*m^2"),
        StiffnessError::Q3 => ("inertia", inertia, "Q3 must be finite and > 0 kg*m^2"),
        StiffnessError::C12 => (
            "stiffness",
            list(&args.stiffness),
            "C12 must be finite and > 0 N*m/rad",
        ),
        StiffnessError::C23 => (
            "stiffness",
            list(&args.stiffness),
            "C23 must be finite and > 0 N*m/rad",
        ),
        StiffnessError::Beta1 => ("freq", list(&args.freq), "B1 must be finite and > 0 Hz"),
        StiffnessError::Beta2 => (
            "freq",
            list(&args.freq),
            "B2 must be finite and greater than B1",
        ),
        StiffnessError::Drawing => (
            "drawing",
            list(&args.drawing),
            "C12 and C23 must be finite and > 0 N*m/rad",
        ),
    };
    anyhow::anyhow!("--{option} {given}: {rule}")
}

/// Runs the command; returns the text to print. The inverse problem with no positive
/// stiffness pair is an error: the tool has no result.
pub fn run(args: &StiffnessArgs) -> anyhow::Result<String> {
    let [q1, q2, q3] = match args.inertia.as_slice() {
        [a, b, c] => [*a, *b, *c],
        other => bail!(
            "--inertia takes three comma-separated values, got {}",
            other.len()
        ),
    };
    let inertias = Inertias {
        q1_kgm2: q1,
        q2_kgm2: q2,
        q3_kgm2: q3,
    };
    let mut out = String::new();
    if let Some(values) = &args.stiffness {
        let [c12, c23] = pair(values, "stiffness")?;
        let stiffness = Stiffness {
            c12_nm_per_rad: c12,
            c23_nm_per_rad: c23,
        };
        let beta = forward(&inertias, &stiffness).map_err(|e| option_error(e, args))?;
        match args.format {
            OutputFormat::Json => {
                out = json!({"beta1_hz": beta.beta1_hz, "beta2_hz": beta.beta2_hz}).to_string();
            }
            OutputFormat::Text => {
                writeln!(out, "beta1_hz = {:.4}", beta.beta1_hz)?;
                writeln!(out, "beta2_hz = {:.4}", beta.beta2_hz)?;
            }
        }
        return Ok(out);
    }
    let values = args
        .freq
        .as_ref()
        .context("one of --freq or --stiffness is required")?;
    let [beta1_hz, beta2_hz] = pair(values, "freq")?;
    let drawing = match &args.drawing {
        Some(values) => {
            let [c12, c23] = pair(values, "drawing")?;
            Some(Stiffness {
                c12_nm_per_rad: c12,
                c23_nm_per_rad: c23,
            })
        }
        None => None,
    };
    let roots = inverse(
        &inertias,
        &NaturalFrequencies { beta1_hz, beta2_hz },
        drawing.as_ref(),
    )
    .map_err(|e| option_error(e, args))?;
    if roots.is_empty() {
        bail!(
            "--freq {beta1_hz},{beta2_hz}: no positive stiffness pair C12, C23 gives these \
             frequencies with inertias {q1},{q2},{q3} kg*m^2 (the frequencies are too close \
             together, or the inertias are not the driveline's)"
        );
    }
    match args.format {
        OutputFormat::Json => {
            let solutions: Vec<_> = roots
                .iter()
                .map(|c| json!({"c12": c.c12_nm_per_rad, "c23": c.c23_nm_per_rad}))
                .collect();
            out = json!({ "solutions": solutions }).to_string();
        }
        OutputFormat::Text => {
            for (i, c) in roots.iter().enumerate() {
                let note = if i == 0 && drawing.is_some() {
                    "  (nearest to drawing)"
                } else {
                    ""
                };
                writeln!(
                    out,
                    "c12 = {:.4e} N*m/rad, c23 = {:.4e} N*m/rad{note}",
                    c.c12_nm_per_rad, c.c23_nm_per_rad
                )?;
            }
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        args: StiffnessArgs,
    }

    fn run_cli(line: &[&str]) -> anyhow::Result<String> {
        let cli = Cli::try_parse_from(std::iter::once("stiffness").chain(line.iter().copied()))?;
        run(&cli.args)
    }

    #[test]
    fn forward_json_reproduces_table2() {
        let out = run_cli(&[
            "--inertia",
            "46.70e3,11.85e3,2.48e3",
            "--stiffness",
            "214.10e6,30.68e6",
            "--format",
            "json",
        ])
        .unwrap();
        let value: serde_json::Value = serde_json::from_str(&out).unwrap();
        assert!((value["beta1_hz"].as_f64().unwrap() - 16.66).abs() < 0.01);
        assert!((value["beta2_hz"].as_f64().unwrap() - 25.98).abs() < 0.01);
    }

    #[test]
    fn inverse_json_lists_adjusted_row() {
        let out = run_cli(&[
            "--inertia",
            "46.70e3,11.85e3,2.48e3",
            "--freq",
            "12.03,21.09",
            "--drawing",
            "214.10e6,30.68e6",
            "--format",
            "json",
        ])
        .unwrap();
        let value: serde_json::Value = serde_json::from_str(&out).unwrap();
        let solutions = value["solutions"].as_array().unwrap();
        assert_eq!(solutions.len(), 2);
        assert!(solutions.iter().any(|s| {
            (s["c12"].as_f64().unwrap() / 68.77e6 - 1.0).abs() < 0.005
                && (s["c23"].as_f64().unwrap() / 32.81e6 - 1.0).abs() < 0.005
        }));
    }

    #[test]
    fn bad_arguments_are_refused() {
        assert!(run_cli(&["--inertia", "1,2,3"]).is_err());
        assert!(run_cli(&["--inertia", "1,2,3", "--freq", "1,2", "--stiffness", "1,2"]).is_err());
        let error = run_cli(&["--inertia", "1,2", "--freq", "1,2"]).unwrap_err();
        assert!(error.to_string().contains("--inertia"));
        let error = run_cli(&["--inertia", "1,-2,3", "--stiffness", "1,2"]).unwrap_err();
        assert_eq!(
            format!("{error:#}"),
            "--inertia 1,-2,3: Q2 must be finite and > 0 kg*m^2"
        );
        let error = run_cli(&["--inertia", "1,2,3", "--freq", "21,12"]).unwrap_err();
        assert_eq!(
            format!("{error:#}"),
            "--freq 21,12: B2 must be finite and greater than B1"
        );
        let error =
            run_cli(&["--inertia", "1,2,3", "--freq", "12,21", "--drawing", "0,1"]).unwrap_err();
        assert_eq!(
            format!("{error:#}"),
            "--drawing 0,1: C12 and C23 must be finite and > 0 N*m/rad"
        );
    }

    #[test]
    fn no_positive_root_is_an_error_in_both_formats() {
        // 12 and 13 Hz on the Table 2 inertias: the quadratic in C12 has no positive root.
        for format in ["text", "json"] {
            let error = run_cli(&[
                "--inertia",
                "46.70e3,11.85e3,2.48e3",
                "--freq",
                "12,13",
                "--format",
                format,
            ])
            .unwrap_err();
            assert!(
                format!("{error:#}").starts_with("--freq 12,13: no positive stiffness pair"),
                "{error:#}"
            );
        }
    }
}
