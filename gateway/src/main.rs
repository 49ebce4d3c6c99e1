//! The `millgate` command line: parses arguments, sets up logging, calls the library.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand};

#[derive(Debug, Parser)]
#[command(
    name = "millgate",
    version,
    about = "Edge gateway for vibration diagnostics of steel rolling mills"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Validate a configuration file and print a summary.
    Check {
        /// The configuration file (TOML).
        #[arg(long)]
        config: PathBuf,
    },
    /// Run the gateway service until SIGINT or SIGTERM.
    Run {
        /// The configuration file (TOML).
        #[arg(long)]
        config: PathBuf,
    },
    /// Export the register map of a configuration.
    Registers {
        /// The configuration file (TOML).
        #[arg(long)]
        config: PathBuf,
        /// Output format.
        #[arg(long, value_enum, default_value = "md")]
        format: millgate::cli::registers::Format,
    },
    /// Export the event history (bites, wear, alarms, outages, chatter, runs).
    History(millgate::cli::history::HistoryArgs),
    #[cfg(feature = "plot")]
    /// Write a maintenance report (Markdown, HTML, SVG plots) from the event history.
    Report(millgate::cli::report::ReportArgs),
    /// Detect and analyse every bite of a recorded CSV (TAF, periods, eq. (1) fit).
    Analyze(millgate::cli::analyze::AnalyzeArgs),
    /// Stiffness adjustment, paper eq. (2): natural frequencies <-> C12, C23.
    Stiffness(millgate::cli::stiffness::StiffnessArgs),
    /// The opened gap from recorded bites: in mrad, where, and how sure.
    Wear(millgate::cli::wear::WearArgs),
    #[cfg(feature = "sim-tools")]
    /// Where a model and a measured transient disagree, and the effect the model lacks.
    Discrepancy(millgate::cli::discrepancy::DiscrepancyArgs),
    #[cfg(feature = "sim-tools")]
    /// Simulators: driveline transients, modes, wear maps; tandem-mill chatter.
    Sim(millgate::cli::sim::SimArgs),
    #[cfg(feature = "sim-tools")]
    /// Rod mills: parametric stability of every pass (Mathieu, Ince-Strutt).
    Rod(millgate::cli::rod::RodArgs),
    #[cfg(feature = "sim-tools")]
    /// Self-contained demo: a virtual DAQ and PLC on loopback, the gateway between them.
    Demo(millgate::cli::demo::DemoArgs),
}

fn init_tracing(default_level: &str) {
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(default_level));
    // Colours only on a terminal: journald and log files get plain text.
    let ansi = std::io::IsTerminal::is_terminal(&std::io::stderr());
    tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_ansi(ansi)
        .init();
}

async fn wait_for_signal() -> std::io::Result<()> {
    use tokio::signal::unix::{signal, SignalKind};
    let mut terminate = signal(SignalKind::terminate())?;
    tokio::select! {
        result = tokio::signal::ctrl_c() => result,
        _ = terminate.recv() => Ok(()),
    }
}

async fn run_service(config: PathBuf) -> anyhow::Result<()> {
    let config = millgate_config::load(&config)?;
    let (trigger, shutdown) = millgate::shutdown::channel();
    let service = tokio::spawn(millgate::run(config, shutdown));
    wait_for_signal().await?;
    tracing::info!("shutdown requested");
    trigger.trigger();
    service.await??;
    Ok(())
}

/// `error` and its causes as one line: each cause is appended unless the text so far
/// already says it (an error that shows its source in its own message, as ours do so
/// that log lines read whole, would otherwise repeat it).
fn sentence(error: &anyhow::Error) -> String {
    let mut text = error.to_string();
    for cause in error.chain().skip(1) {
        let cause = cause.to_string();
        if !text.contains(&cause) {
            text.push_str(": ");
            text.push_str(&cause);
        }
    }
    text
}

/// Print a command's report, ending it with exactly one newline.
fn emit(text: String) {
    println!("{}", text.trim_end());
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let runtime = || {
        tokio::runtime::Builder::new_multi_thread()
            .enable_all()
            .build()
            .expect("cannot start the tokio runtime")
    };
    let result = match cli.command {
        Command::Check { config } => match millgate::cli::check::check(&config) {
            Ok(summary) => {
                println!("{}", summary.trim_end());
                Ok(())
            }
            Err(error) => {
                eprintln!("{error}");
                return ExitCode::FAILURE;
            }
        },
        Command::Registers { config, format } => millgate_config::load(&config)
            .map_err(anyhow::Error::from)
            .map(|config| {
                let map = millgate::outputs::register_map::RegisterMap::new(&config);
                print!("{}", millgate::cli::registers::export(&map, format));
            }),
        Command::Analyze(args) => {
            init_tracing("warn");
            millgate::cli::analyze::run(&args).map(emit)
        }
        Command::Stiffness(args) => millgate::cli::stiffness::run(&args).map(emit),
        Command::Wear(args) => {
            init_tracing("warn");
            millgate::cli::wear::run(&args).map(emit)
        }
        Command::History(args) => millgate::cli::history::run(&args).map(|text| print!("{text}")),
        #[cfg(feature = "plot")]
        Command::Report(args) => millgate::cli::report::run(&args).map(emit),
        #[cfg(feature = "sim-tools")]
        Command::Discrepancy(args) => millgate::cli::discrepancy::run(&args).map(emit),
        #[cfg(feature = "sim-tools")]
        Command::Sim(args) => millgate::cli::sim::run(args),
        #[cfg(feature = "sim-tools")]
        Command::Rod(args) => millgate::cli::rod::run(args).map(emit),
        Command::Run { config } => {
            init_tracing("info");
            runtime().block_on(run_service(config))
        }
        #[cfg(feature = "sim-tools")]
        Command::Demo(args) => {
            init_tracing("warn");
            runtime().block_on(millgate::cli::demo::run(args))
        }
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(error) => {
            eprintln!("millgate: {}", sentence(&error));
            ExitCode::FAILURE
        }
    }
}
