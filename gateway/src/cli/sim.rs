//! `millgate sim ...`: run the driveline simulator from the command line.
//!
//! - `millgate sim transient --model M.toml [--noise-rms KNM] [--seed S] --out FILE.csv`
//! - `millgate sim modes --model M.toml [--format text|json]`
//! - `millgate sim wear-map --model M.toml --out DIR`
//! - `millgate sim fatigue-gap --model M.toml --out DIR [...]`: damage per bar over the
//!   opened gap ([`super::fatigue_gap`])
//! - `millgate sim tandem --schedule S.toml [--speed F] [--ramp TO,ACCEL] --out FILE.csv`

use std::fmt::Write as _;
use std::path::PathBuf;

use anyhow::Context as _;
use clap::{Args, Subcommand, ValueEnum};
use millgate_sim::chain::simulate_with_noise;
use millgate_sim::modal;
use millgate_sim::model::Model;
use millgate_sim::plot::wear_map_svg;
use millgate_sim::tandem::simulate::{simulate, Accelerometer, Excitation, RunSettings, SpeedRamp};
use millgate_sim::tandem::truth::{ground_truth, mill_critical_speed};
use millgate_sim::tandem::{PassSchedule, TandemMill};
use millgate_sim::wear_map::{wear_map, WearMap, WearMapSpec};

use super::shell::print;

/// Arguments of `millgate sim`.
#[derive(Debug, Args)]
pub struct SimArgs {
    /// What to compute.
    #[command(subcommand)]
    pub command: SimCommand,
}

/// The `millgate sim` subcommands.
#[derive(Debug, Subcommand)]
pub enum SimCommand {
    /// Simulate the bite transient and write `t,torque` (s, kN*m) as CSV.
    Transient {
        /// Driveline model (TOML).
        #[arg(long)]
        model: PathBuf,
        /// RMS of added Gaussian noise, kN*m (>= 0).
        #[arg(long, default_value_t = 0.0)]
        noise_rms: f64,
        /// Seed of the noise generator.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Output CSV file.
        #[arg(long)]
        out: PathBuf,
    },
    /// Natural frequencies and mass-normalised mode shapes (rigid-body mode first).
    Modes {
        /// Driveline model (TOML).
        #[arg(long)]
        model: PathBuf,
        /// Output format.
        #[arg(long, value_enum, default_value_t = ModesFormat::Text)]
        format: ModesFormat,
    },
    /// TAF and first-period shift over static torque x opened gap: CSV and SVG.
    WearMap {
        /// Driveline model (TOML).
        #[arg(long)]
        model: PathBuf,
        /// Output directory (created if missing): wear-map.csv and wear-map.svg.
        #[arg(long)]
        out: PathBuf,
    },
    /// A tandem cold mill's chock accelerations (`sim::tandem`): CSV `t,s1_vib,..`;
    /// prints the critical speed, the onset and when chatter developed.
    Tandem(TandemArgs),
    /// Damage per bar over the opened gap (rainflow and Miner on simulated bars): CSV
    /// and SVG.
    FatigueGap(super::fatigue_gap::FatigueGapArgs),
}

/// Arguments of `millgate sim tandem`.
#[derive(Debug, Args)]
pub struct TandemArgs {
    /// Pass schedule (TOML), e.g. sim/schedules/lu2019-5stand.toml.
    #[arg(long)]
    pub schedule: PathBuf,
    /// Speed factor at the start (times the schedule's roll speeds).
    #[arg(long, default_value_t = 0.9)]
    pub speed: f64,
    /// After `--hold`, ramp to speed factor TO at ACCEL m/s^2 of the last stand's exit
    /// speed: `--ramp 1.4,1.0`.
    #[arg(long, value_delimiter = ',', value_name = "TO,ACCEL")]
    pub ramp: Option<Vec<f64>>,
    /// Time at the start speed before the ramp, s.
    #[arg(long, default_value_t = 20.0)]
    pub hold: f64,
    /// Length of the record, s.
    #[arg(long, default_value_t = 40.0)]
    pub duration: f64,
    /// Accelerometer sample rate, Hz (500-20000).
    #[arg(long, default_value_t = 2500.0)]
    pub sample_rate: f64,
    /// Factor on the force noise and the incoming gauge noise.
    #[arg(long, default_value_t = 1.0)]
    pub noise_scale: f64,
    /// RMS of the accelerometers' own noise, m/s^2.
    #[arg(long, default_value_t = 0.02)]
    pub sensor_noise: f64,
    /// Sample without the anti-alias low-pass.
    #[arg(long)]
    pub no_anti_alias: bool,
    /// Seed of every random source.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Add the speed factor and the interstand tension deviations (MPa) as columns.
    #[arg(long)]
    pub truth: bool,
    /// Output CSV file.
    #[arg(long)]
    pub out: PathBuf,
}

/// Output format of `millgate sim modes`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum ModesFormat {
    /// One line per mode: frequency and shape.
    Text,
    /// `{"frequencies_hz": [...], "modes": [[...], ...]}`, one shape per frequency.
    Json,
}

/// Runs one `millgate sim` subcommand, printing to stdout.
pub fn run(args: SimArgs) -> anyhow::Result<()> {
    match args.command {
        SimCommand::Transient {
            model,
            noise_rms,
            seed,
            out,
        } => {
            let model = Model::load(&model)?;
            let transient = simulate_with_noise(&model, noise_rms, seed)?;
            let mut csv = String::from("t,torque\n");
            for (t, torque) in transient.t.iter().zip(&transient.torque_knm) {
                writeln!(csv, "{t},{torque}")?;
            }
            std::fs::write(&out, csv).with_context(|| format!("writing {}", out.display()))?;
            print(&format!(
                "{}: {} samples\n",
                out.display(),
                transient.t.len()
            ))?;
        }
        SimCommand::Modes { model, format } => print(&modes_report(&model, format)?)?,
        SimCommand::WearMap { model, out } => {
            let model = Model::load(&model)?;
            let spec = WearMapSpec::around(&model);
            let map = wear_map(&model, &spec, |done, total, row| {
                // A closed pipe is said by the last line's print, which ends the
                // command quietly; the progress goes on unprinted until then.
                let _ = print(&format!(
                    "[{done}/{total}] static {:.1} kN*m, gap {:.2} mrad: TAF {:.3}\n",
                    row.static_torque_knm,
                    row.backlash_rad * 1.0e3,
                    row.taf
                ));
            })?;
            check_computed(&map, &model)?;
            std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
            let csv_path = out.join("wear-map.csv");
            let svg_path = out.join("wear-map.svg");
            std::fs::write(&csv_path, map.to_csv())
                .with_context(|| format!("writing {}", csv_path.display()))?;
            std::fs::write(&svg_path, wear_map_svg(&map)?)
                .with_context(|| format!("writing {}", svg_path.display()))?;
            print(&format!(
                "wrote {} and {}\n",
                csv_path.display(),
                svg_path.display()
            ))?;
        }
        SimCommand::Tandem(args) => print(&tandem(&args)?)?,
        SimCommand::FatigueGap(args) => print(&super::fatigue_gap::run(&args)?)?,
    }
    Ok(())
}

/// Lowest TAF of a grid point whose measured coupling carried the load: below it the
/// load never reached the coupling within the record.
const MIN_CARRIED_TAF: f64 = 0.5;

/// Fails unless every grid point of `map` measured a loaded coupling, and at least one
/// measured a period shift: a map of TAF 0.000 (a 200-mass chain whose load does not
/// reach the measured coupling within the record) is no result.
fn check_computed(map: &WearMap, model: &Model) -> anyhow::Result<()> {
    let coupling = map.coupling;
    if let Some(row) = map
        .rows
        .iter()
        .find(|row| !(row.taf.is_finite() && row.taf >= MIN_CARRIED_TAF))
    {
        anyhow::bail!(
            "wear map of \"{}\": at static torque {} kN*m and gap {} mrad the measured \
             coupling (measurement.coupling = {coupling}) peaks at {:.3} x the static torque \
             within the record's {} s: the load does not reach it (at least {MIN_CARRIED_TAF} \
             needed); lengthen measurement.duration or measure a coupling nearer the load; \
             nothing written",
            map.model_name,
            row.static_torque_knm,
            row.backlash_rad * 1.0e3,
            row.taf,
            model.measurement.duration,
        );
    }
    if map.rows.iter().all(|row| row.period_shift_s.is_none()) {
        anyhow::bail!(
            "wear map of \"{}\": no grid point has two oscillation periods on the measured \
             coupling (measurement.coupling = {coupling}) within the record's {} s; nothing \
             written",
            map.model_name,
            model.measurement.duration,
        );
    }
    Ok(())
}

/// Runs `millgate sim tandem`: writes the CSV, returns the summary it prints.
pub fn tandem(args: &TandemArgs) -> anyhow::Result<String> {
    let schedule = PassSchedule::load(&args.schedule)?;
    let mill = TandemMill::new(&schedule)?;
    let ramp = match args.ramp.as_deref() {
        Some(&[to, accel]) => SpeedRamp {
            start: args.speed,
            end: to,
            hold_s: args.hold,
            accel_m_s2: accel,
        },
        None => SpeedRamp::constant(args.speed),
        Some(values) => anyhow::bail!(
            "--ramp: {} values is not allowed (must be TO,ACCEL: the speed factor to ramp to \
             and the acceleration in m/s^2)",
            values.len()
        ),
    };
    let mut excitation = Excitation::default();
    excitation.force_noise_density *= args.noise_scale;
    excitation.entry_gauge_rms_m *= args.noise_scale;
    let settings = RunSettings {
        ramp,
        excitation,
        sensor: Accelerometer {
            sample_rate_hz: args.sample_rate,
            noise_rms: args.sensor_noise,
            anti_alias: !args.no_anti_alias,
        },
        duration_s: args.duration,
        seed: args.seed,
        internal_rate_hz: None,
    };
    let record = simulate(&mill, &settings)?;
    let critical = mill_critical_speed(&mill)?;
    let truth = ground_truth(&mill, &ramp, &record, critical);
    std::fs::write(&args.out, record.to_csv(args.truth))
        .with_context(|| format!("writing {}", args.out.display()))?;
    let exit = mill.exit_speed(mill.stands().len() - 1, 1.0);
    let at = |t: Option<f64>| t.map_or("never".to_owned(), |t| format!("{t:.2} s"));
    Ok(format!(
        "{}: {} samples x {} stands at {} Hz\n\
         critical speed factor {:.3} ({:.2} m/s exit speed), chatter at {:.1} Hz\n\
         onset (ramp passes it): {}\ndeveloped (a tension swings past half its schedule value): {}\n",
        args.out.display(),
        record.len(),
        record.acceleration.len(),
        args.sample_rate,
        critical.speed,
        critical.speed * exit,
        critical.frequency_hz,
        at(truth.onset_s),
        at(truth.developed_s),
    ))
}

/// The text `millgate sim modes` prints for the model at `path`.
pub(crate) fn modes_report(path: &std::path::Path, format: ModesFormat) -> anyhow::Result<String> {
    let model = Model::load(path)?;
    let modes = modal::modes(&model)?;
    let shapes: Vec<Vec<f64>> = (0..modes.frequencies_hz.len())
        .map(|index| modes.shape(index))
        .collect();
    Ok(match format {
        ModesFormat::Json => {
            let value = serde_json::json!({
                "frequencies_hz": modes.frequencies_hz,
                "modes": shapes,
            });
            format!("{value}\n")
        }
        ModesFormat::Text => {
            let mut text = String::new();
            for (frequency, shape) in modes.frequencies_hz.iter().zip(&shapes) {
                let shape: Vec<String> = shape.iter().map(|v| format!("{v:+.5e}")).collect();
                writeln!(text, "{frequency:9.3} Hz  [{}]", shape.join(", "))?;
            }
            text
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn model_path(name: &str) -> PathBuf {
        std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../sim/models")
            .join(name)
    }

    #[test]
    fn modes_json_lists_rigid_body_mode_first() -> anyhow::Result<()> {
        let text = modes_report(&model_path("table2-adjusted.toml"), ModesFormat::Json)?;
        let value: serde_json::Value = serde_json::from_str(&text)?;
        let frequencies: Vec<f64> = serde_json::from_value(value["frequencies_hz"].clone())?;
        let modes: Vec<Vec<f64>> = serde_json::from_value(value["modes"].clone())?;
        assert_eq!(frequencies.len(), 3);
        assert!(frequencies[0].abs() < 1e-6);
        assert!((frequencies[1] - 12.03).abs() < 0.01 && (frequencies[2] - 21.09).abs() < 0.01);
        assert_eq!(modes.len(), 3);
        assert!(modes.iter().all(|shape| shape.len() == 3));
        Ok(())
    }

    #[test]
    fn a_wear_map_that_computes_nothing_is_an_error_and_writes_nothing() -> anyhow::Result<()> {
        // A chain of 200 masses: the load at the last one does not reach coupling 1
        // within 0.6 s, and the map was TAF 0.000 everywhere, exit 0.
        let directory =
            std::env::temp_dir().join(format!("millgate-simcmd-chain-{}", std::process::id()));
        std::fs::create_dir_all(&directory)?;
        let mut model = String::from("name = \"chain of 200\"\n");
        for i in 0..200 {
            model.push_str(&format!("[[mass]]\nname = \"m{i}\"\ninertia = 1.0e3\n"));
        }
        for i in 0..199 {
            model.push_str(&format!(
                "[[coupling]]\nname = \"c{i}\"\nstiffness = 50.0e6\ndamping = 1.0e3\n"
            ));
        }
        model.push_str(
            "[motor]\nspeed_kp = 5.0e5\nspeed_ki = 2.0e6\n\
             [load]\nstatic_torque = 112.0\nrise_rate = 36.7\nonset = 0.05\n\
             [measurement]\ncoupling = 1\nsample_rate = 2000.0\nduration = 0.6\n",
        );
        let model_path = directory.join("chain.toml");
        std::fs::write(&model_path, model)?;
        let out = directory.join("map");
        let error = run(SimArgs {
            command: SimCommand::WearMap {
                model: model_path,
                out: out.clone(),
            },
        })
        .unwrap_err();
        let written = out.exists();
        std::fs::remove_dir_all(&directory)?;
        let text = format!("{error:#}");
        assert!(
            text.contains("the load does not reach it")
                && text.contains("measurement.coupling = 1"),
            "{text}"
        );
        assert!(!written, "nothing written");
        Ok(())
    }

    #[test]
    fn tandem_writes_stands_and_reports_the_truth() -> anyhow::Result<()> {
        let out = std::env::temp_dir().join(format!("millgate-tandem-{}.csv", std::process::id()));
        let summary = tandem(&TandemArgs {
            schedule: std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
                .join("../sim/schedules/lu2019-5stand.toml"),
            speed: 1.0,
            ramp: Some(vec![1.6, 2.0]),
            hold: 1.0,
            duration: 12.0,
            sample_rate: 2500.0,
            noise_scale: 1.0,
            sensor_noise: 0.02,
            no_anti_alias: false,
            seed: 2,
            truth: true,
            out: out.clone(),
        })?;
        let text = std::fs::read_to_string(&out)?;
        std::fs::remove_file(&out)?;
        let mut lines = text.lines();
        assert_eq!(
            lines.next(),
            Some("t,s1_vib,s2_vib,s3_vib,s4_vib,s5_vib,speed_factor,tension_1_2_mpa,tension_2_3_mpa,tension_3_4_mpa,tension_4_5_mpa")
        );
        assert_eq!(lines.count(), 30_000);
        // 1.0 -> 1.098 at 2 m/s^2 on a 22.8 m/s exit: 1.1 s after the 1 s hold.
        assert!(summary.contains("critical speed factor 1.098"), "{summary}");
        assert!(summary.contains("onset (ramp passes it): 2.1"), "{summary}");
        assert!(
            !summary.contains("developed (a tension swings past half its schedule value): never"),
            "{summary}"
        );
        Ok(())
    }

    #[test]
    fn transient_and_wear_map_write_their_files() -> anyhow::Result<()> {
        let directory =
            std::env::temp_dir().join(format!("millgate-simcmd-{}", std::process::id()));
        std::fs::create_dir_all(&directory)?;
        let csv = directory.join("transient.csv");
        run(SimArgs {
            command: SimCommand::Transient {
                model: model_path("table2-adjusted-backlash.toml"),
                noise_rms: 0.5,
                seed: 3,
                out: csv.clone(),
            },
        })?;
        let text = std::fs::read_to_string(&csv)?;
        assert!(text.starts_with("t,torque\n"));
        assert_eq!(text.lines().count(), 1 + 1200);
        run(SimArgs {
            command: SimCommand::WearMap {
                model: model_path("table2-adjusted-backlash.toml"),
                out: directory.join("map"),
            },
        })?;
        let map = std::fs::read_to_string(directory.join("map/wear-map.csv"))?;
        assert_eq!(map.lines().count(), 1 + 30);
        assert!(std::fs::read_to_string(directory.join("map/wear-map.svg"))?.starts_with("<svg"));
        std::fs::remove_dir_all(&directory)?;
        Ok(())
    }
}
