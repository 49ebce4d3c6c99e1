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
        format: millgate::export::Format,
    },
    /// Detect and analyse every bite of a recorded CSV (TAF, periods, eq. (1) fit).
    Analyze(millgate::offline::analyze::AnalyzeArgs),
    /// Stiffness adjustment, paper eq. (2): natural frequencies <-> C12, C23.
    Stiffness(millgate::offline::stiffness::StiffnessArgs),
    /// Where a model and a measured transient disagree, and the effect the model lacks.
    Discrepancy(millgate::offline::discrepancy::DiscrepancyArgs),
    /// Driveline simulator: transients, modes, wear maps.
    Sim(millgate::simcmd::SimArgs),
    /// Rod mills: parametric stability of every pass (Mathieu, Ince-Strutt).
    Rod(millgate::rodcmd::RodArgs),
    /// Self-contained demo: a virtual DAQ and PLC on loopback, the gateway between them.
    Demo(millgate::demo::DemoArgs),
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
    let config = millgate_config::load(&config).map_err(|e| anyhow::anyhow!("{e}"))?;
    let (trigger, shutdown) = millgate::shutdown::channel();
    let service = tokio::spawn(millgate::run(config, shutdown));
    wait_for_signal().await?;
    tracing::info!("shutdown requested");
    trigger.trigger();
    service.await??;
    Ok(())
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
        Command::Check { config } => match millgate::check::check(&config) {
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
            .map_err(|e| anyhow::anyhow!("{e}"))
            .map(|config| {
                let map = millgate::registers::RegisterMap::new(&config);
                print!("{}", millgate::export::export(&map, format));
            }),
        Command::Analyze(args) => {
            init_tracing("warn");
            millgate::offline::analyze::run(&args).map(emit)
        }
        Command::Stiffness(args) => millgate::offline::stiffness::run(&args).map(emit),
        Command::Discrepancy(args) => millgate::offline::discrepancy::run(&args).map(emit),
        Command::Sim(args) => millgate::simcmd::run(args),
        Command::Rod(args) => millgate::rodcmd::run(args).map(emit),
        Command::Run { config } => {
            init_tracing("info");
            runtime().block_on(run_service(config))
        }
        Command::Demo(args) => {
            init_tracing("warn");
            runtime().block_on(millgate::demo::run(args))
        }
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(error) => {
            eprintln!("millgate: {error:#}");
            ExitCode::FAILURE
        }
    }
}
