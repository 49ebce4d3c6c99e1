//! The `millgate` command line: parses arguments, sets up logging, calls the library.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{CommandFactory, Parser, Subcommand};

#[derive(Debug, Parser)]
#[command(
    name = "millgate",
    version,
    about = "Edge gateway for vibration diagnostics of steel rolling mills",
    after_long_help = millgate::cli::shell::exit_status_help()
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
    /// How log lines are written on stderr: text (`LEVEL target: message key=value`)
    /// or json (one object per line: timestamp, level, target, and the message and
    /// every field as JSON values, for a log shipper). For `run` the default is the
    /// configuration's `log_format`, else text.
    #[arg(long, global = true, value_enum)]
    log_format: Option<LogFormat>,
}

/// `--log-format`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum LogFormat {
    /// Text lines.
    Text,
    /// JSON lines.
    Json,
}

impl From<LogFormat> for millgate_config::LogFormat {
    fn from(format: LogFormat) -> Self {
        match format {
            LogFormat::Text => Self::Text,
            LogFormat::Json => Self::Json,
        }
    }
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Validate a configuration file and print a summary.
    Check {
        /// The configuration file (TOML).
        #[arg(long)]
        config: PathBuf,
        /// Output format: text (the summary, or the problems on stderr), or one JSON
        /// document on stdout either way (file, ok, summary, problems, warnings) for
        /// CI. The exit code is the same.
        #[arg(long, value_enum, default_value = "text")]
        format: millgate::cli::OutputFormat,
    },
    /// Run the gateway service until SIGINT or SIGTERM (SIGHUP reloads the
    /// configuration file: what can change live is applied, the rest is named).
    Run {
        /// The configuration file (TOML).
        #[arg(long)]
        config: PathBuf,
        /// Keep this process' id in FILE while it runs (for `millgate reload`).
        #[arg(long, value_name = "FILE")]
        pid_file: Option<PathBuf>,
    },
    /// Ask a running service to reload its configuration file (as SIGHUP does):
    /// found by its pid file; with --config the file is checked first.
    Reload(millgate::cli::reload::ReloadArgs),
    /// Export the register map of a configuration (0-based PDU addresses: the map's
    /// offsets and, with a PLC output, register_base + offset).
    Registers {
        /// The configuration file (TOML).
        #[arg(long)]
        config: PathBuf,
        /// Output format.
        #[arg(long, value_enum, default_value = "md")]
        format: millgate::cli::registers::Format,
        /// List instead what the PLC must provide for the process-context tags
        /// (`context` of tandem mills and drivelines): source, register, encoding and
        /// the values the gateway accepts.
        #[arg(long)]
        context: bool,
    },
    /// Print the catalogue of published figures: each figure's unit, type, quality
    /// guard and stale rule, and its register, Sparkplug metric, /metrics family and
    /// history column.
    Figures {
        /// Output format.
        #[arg(long, value_enum, default_value = "md")]
        format: millgate::cli::registers::Format,
    },
    #[cfg(feature = "opcua")]
    /// The OPC UA server's address space of a configuration, as a Markdown table.
    AddressSpace {
        /// The configuration file (TOML).
        #[arg(long)]
        config: PathBuf,
    },
    /// Export the event history (bites, wear, alarms, outages, chatter, runs).
    History(millgate::cli::history::HistoryArgs),
    /// List or export the captures (bite windows, chatter episodes, manual) a history keeps.
    #[command(subcommand)]
    Capture(millgate::cli::capture::CaptureCommand),
    #[cfg(feature = "plot")]
    /// Write a maintenance report (Markdown, HTML, SVG plots) from the event history.
    Report(millgate::cli::report::ReportArgs),
    /// Detect and analyse every bite of a recorded CSV (TAF, periods, eq. (1) fit).
    Analyze(millgate::cli::analyze::AnalyzeArgs),
    /// Stiffness adjustment, paper eq. (2): natural frequencies <-> C12, C23.
    Stiffness(millgate::cli::stiffness::StiffnessArgs),
    /// A tandem mill's recorded stand vibrations through the chatter monitor, per window.
    Chatter(millgate::cli::chatter::ChatterArgs),
    /// The opened gap from recorded bites: in mrad, where, and how sure.
    Wear(millgate::cli::wear::WearArgs),
    /// Rainflow count (ASTM E1049-85) and Miner's damage of a torque record or history.
    Fatigue(millgate::cli::fatigue::FatigueArgs),
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
    /// Print the shell completion script (bash, zsh, fish, elvish, powershell).
    Completions(millgate::cli::shell::CompletionsArgs),
    /// Print the manual page (roff), or write every command's page into a folder.
    Man(millgate::cli::shell::ManArgs),
}

/// Directives added to the default log level: async-opcua's lines that any client
/// causes (an INFO per connection and session, a WARN per notification a slow
/// subscriber's queue drops: thousands a second in the round-4 audit) stay out of
/// the journal; the gateway's own OPC UA lines are rate-limited and counted.
/// `RUST_LOG` replaces them (tokio-modbus' lines stay off either way unless it names
/// them: [`millgate::logging::filter`]).
const QUIET_DEPENDENCIES: &str =
    "opcua_server=warn,opcua_server::subscriptions=error,opcua_core=warn";

fn init_tracing(default_level: &str, format: millgate_config::LogFormat) {
    let rust_log = std::env::var("RUST_LOG").ok();
    let filter = millgate::logging::filter(
        rust_log.as_deref(),
        &format!("{default_level},{QUIET_DEPENDENCIES}"),
    );
    millgate::logging::init(filter, format);
}

/// SIGINT or SIGTERM, handled from the moment this is called (before the service is
/// spawned: a signal during the start is a stop, never the default action that kills
/// the process before its final PLC write).
fn stop_signals() -> std::io::Result<impl std::future::Future<Output = ()>> {
    use tokio::signal::unix::{signal, SignalKind};
    let mut terminate = signal(SignalKind::terminate())?;
    let mut interrupt = signal(SignalKind::interrupt())?;
    Ok(async move {
        tokio::select! {
            _ = interrupt.recv() => {}
            _ = terminate.recv() => {}
        }
    })
}

/// `millgate run`: fails at once, with the reason and a non-zero exit, when anything
/// the service must load or bind fails; tells systemd (`sd_notify`, when
/// `NOTIFY_SOCKET` is set) READY=1 once every listener is bound and the first PLC
/// write was attempted, pings its watchdog while the analysis and the outputs make
/// progress (`WATCHDOG_USEC`), and says STOPPING=1 on SIGINT or SIGTERM. A service
/// that ends by itself is a failure.
async fn run_service(config_path: PathBuf, config: millgate_config::Config) -> anyhow::Result<()> {
    use sd_notify::NotifyState;
    let heartbeat = config.outputs.plc.as_ref().map_or(
        millgate::outputs::modbus::heartbeat_period_without_plc(),
        |plc| plc.write_period,
    );
    let watchdog = sd_notify::watchdog_enabled();
    if let Some(period) = watchdog {
        millgate::supervision::check_watchdog(period, heartbeat)
            .map_err(|error| anyhow::anyhow!("{}: {error}", config_path.display()))?;
    }
    let service = millgate::Service::new(config)
        .map_err(|error| anyhow::anyhow!("{}: {error}", config_path.display()))?;
    let signal = stop_signals()?;
    tokio::pin!(signal);
    let mut hang_up = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::hangup())?;
    let mut gateway = service.spawn().await?;
    loop {
        tokio::select! {
            ready = gateway.ready() => break ready?,
            () = &mut signal => {
                tracing::info!("shutdown requested before the service was ready");
                gateway.stop().await?;
                return Ok(());
            }
            // Handled (and logged) by the service once it runs.
            Some(()) = hang_up.recv() => drop(tokio::spawn(gateway.reload(&config_path))),
        }
    }
    tracing::info!("ready");
    notify(&[NotifyState::Ready]);
    let (stop_watchdog, watchdog_shutdown) = millgate::shutdown::channel();
    if let Some(period) = watchdog {
        tokio::spawn(millgate::supervision::watchdog(
            gateway.liveness(),
            gateway.board(),
            period,
            || notify(&[NotifyState::Watchdog]),
            watchdog_shutdown,
        ));
    }
    loop {
        tokio::select! {
            () = &mut signal => {
                tracing::info!("shutdown requested");
                notify(&[NotifyState::Stopping]);
                stop_watchdog.trigger();
                gateway.stop().await?;
                return Ok(());
            }
            ended = gateway.finished() => {
                stop_watchdog.trigger();
                return Err(ended.err().unwrap_or(millgate::service::ServiceError::Ended).into());
            }
            Some(()) = hang_up.recv() => {
                notify(&[NotifyState::Reloading]);
                // The service logs and counts the outcome.
                let _ = gateway.reload(&config_path).await;
                notify(&[NotifyState::Ready]);
            }
        }
    }
}

/// Tell systemd `states`; without `NOTIFY_SOCKET` nothing is sent. A failure to send
/// is logged: the service itself is fine.
fn notify(states: &[sd_notify::NotifyState<'_>]) {
    if let Err(error) = sd_notify::notify(states) {
        tracing::warn!(%error, "cannot notify the service manager");
    }
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
fn emit(text: String) -> anyhow::Result<()> {
    Ok(millgate::cli::shell::print(&format!(
        "{}\n",
        text.trim_end()
    ))?)
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let log_format = cli
        .log_format
        .map(millgate_config::LogFormat::from)
        .unwrap_or_default();
    let runtime = || {
        tokio::runtime::Builder::new_multi_thread()
            .enable_all()
            .build()
            .expect("cannot start the tokio runtime")
    };
    let result = match cli.command {
        Command::Check {
            config,
            format: millgate::cli::OutputFormat::Json,
        } => {
            let (json, ok) = millgate::cli::check::report_json(&config);
            match emit(json) {
                Err(error) if !millgate::cli::shell::is_broken_pipe(&error) => Err(error),
                _ if ok => Ok(()),
                _ => return ExitCode::FAILURE,
            }
        }
        Command::Check {
            config,
            format: millgate::cli::OutputFormat::Text,
        } => match millgate::cli::check::check(&config) {
            Ok(summary) => emit(summary),
            Err(error) => {
                eprintln!("{error}");
                return ExitCode::FAILURE;
            }
        },
        Command::Registers {
            config,
            format,
            context: true,
        } => millgate_config::load(&config)
            .map_err(anyhow::Error::from)
            .and_then(|config| {
                let table = millgate::cli::registers::context_export(&config, format);
                Ok(millgate::cli::shell::print(&table)?)
            }),
        Command::Registers {
            config,
            format,
            context: false,
        } => millgate_config::load(&config)
            .map_err(anyhow::Error::from)
            .and_then(|config| {
                let map = millgate::outputs::modbus::register_map::RegisterMap::try_new(&config)?;
                let table =
                    millgate::cli::registers::export(&map, config.outputs.plc.as_ref(), format);
                Ok(millgate::cli::shell::print(&table)?)
            }),
        Command::Figures { format } => {
            millgate::cli::shell::print(&millgate::cli::figures::export(format)).map_err(Into::into)
        }
        Command::Completions(args) => {
            let script = millgate::cli::shell::completions(Cli::command(), args.shell);
            millgate::cli::shell::print_bytes(&script).map_err(Into::into)
        }
        Command::Man(args) => match &args.out {
            Some(folder) => millgate::cli::shell::write_man_pages(Cli::command(), folder)
                .map(|written| eprintln!("{} manual pages in {}", written.len(), folder.display())),
            None => millgate::cli::shell::man_page(Cli::command())
                .and_then(|page| millgate::cli::shell::print_bytes(&page))
                .map_err(Into::into),
        },
        #[cfg(feature = "opcua")]
        Command::AddressSpace { config } => millgate_config::load(&config)
            .map_err(anyhow::Error::from)
            .and_then(|config| millgate::cli::address_space::run(&config))
            .and_then(|table| Ok(millgate::cli::shell::print(&table)?)),
        Command::Analyze(args) => {
            init_tracing("warn", log_format);
            millgate::cli::analyze::run(&args).and_then(emit)
        }
        Command::Stiffness(args) => millgate::cli::stiffness::run(&args).and_then(emit),
        Command::Chatter(args) => millgate::cli::chatter::run(&args).and_then(emit),
        Command::Wear(args) => {
            init_tracing("warn", log_format);
            millgate::cli::wear::run(&args).and_then(emit)
        }
        Command::Fatigue(args) => millgate::cli::fatigue::run(&args).and_then(emit),
        Command::History(args) => millgate::cli::history::run(&args),
        Command::Capture(command) => millgate::cli::capture::run(&command).and_then(emit),
        #[cfg(feature = "plot")]
        Command::Report(args) => millgate::cli::report::run(&args).and_then(emit),
        #[cfg(feature = "sim-tools")]
        Command::Discrepancy(args) => millgate::cli::discrepancy::run(&args).and_then(emit),
        #[cfg(feature = "sim-tools")]
        Command::Sim(args) => millgate::cli::sim::run(args),
        #[cfg(feature = "sim-tools")]
        Command::Rod(args) => millgate::cli::rod::run(args).and_then(emit),
        Command::Run {
            config: path,
            pid_file,
        } => match millgate_config::load(&path) {
            Ok(config) => {
                init_tracing("info", cli.log_format.map_or(config.log_format, Into::into));
                pid_file
                    .as_deref()
                    .map(millgate::cli::reload::PidFile::write)
                    .transpose()
                    .and_then(|pid_file| {
                        let ran = runtime().block_on(run_service(path, config));
                        drop(pid_file);
                        ran
                    })
            }
            Err(error) => Err(error.into()),
        },
        Command::Reload(args) => millgate::cli::reload::run(&args).and_then(emit),
        #[cfg(feature = "sim-tools")]
        Command::Demo(args) => {
            init_tracing("warn", log_format);
            runtime().block_on(millgate::cli::demo::run(args))
        }
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        // The reader of stdout went (`millgate figures | head`): the command stops
        // writing, quietly, as other Unix tools do.
        Err(error) if millgate::cli::shell::is_broken_pipe(&error) => ExitCode::SUCCESS,
        Err(error) => {
            eprintln!("millgate: {}", sentence(&error));
            ExitCode::FAILURE
        }
    }
}
