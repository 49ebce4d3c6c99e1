//! `millgate demo`: the whole path on one machine, with nothing to set up.
//!
//! A virtual DAQ streams a simulated rolling schedule (one bite per bar, from the
//! Table 2 driveline with a gap in the spindles that opens further bar by bar) over
//! Modbus TCP on loopback; the gateway reads it, analyses every bite, estimates the
//! opened gap against the driveline model and writes its results into a virtual PLC,
//! also on loopback. Each bite is printed beside its simulated truth (TAF and gap);
//! the PLC's registers are printed at the end.
//!
//! The gateway keeps an event history (`--history FILE`, by default a new file in a
//! temporary folder; the path is printed at start); a second run on the same file
//! continues the bite counter, the wear trend and the pooled gap estimate.
//!
//! Beside it, unless `--no-tandem`, a five-stand tandem cold mill of the project's
//! tandem model runs online in real time (`millgate_sim::devices::demo_tandem`): its
//! chock accelerations on a second virtual DAQ, a weld passing the stands 2 s in (the
//! PLC's weld bit, in one of the virtual PLC's holding registers, read by the gateway
//! over Modbus TCP as a context tag), then, once the weld hold is over, the operator's
//! ramp past the critical speed. The console prints the weld, the alarms the weld hold
//! kept off, the ramp and the slow-down request the gateway raises (the PLC slows the
//! mill); the page, the API and `/metrics` show the mill's figures. The closed loop's
//! outcome holds in real time: the summary says whether the loop ran so (no PLC cycle
//! handed over late, no block of the stands' DAQ missed by the gateway) or what broke
//! it on a busy machine.
//!
//! The maintenance page is served while the demo runs (`--web HOST:PORT`, by default
//! a free loopback port; its address is printed at start), and the Prometheus metrics
//! (`--metrics HOST:PORT`, the same); with the `opcua` feature,
//! `--opcua HOST:PORT` serves the results over OPC UA too (security none, anonymous,
//! its certificates in `opcua-pki` beside the history).

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant};

use millgate_config::Config;
use millgate_sim::devices::demo::{
    setup, DemoDevices, DemoSetup, BARS_PER_CYCLE, GAP_COUPLING, SAMPLES_PER_BLOCK,
};
use millgate_sim::devices::demo_tandem::{
    setup_with_tandem, PreparedTandem, TandemDemo, TandemMoment, TandemScript,
};
use millgate_sim::devices::tandem_rig::{RigError, RigRun};

use millgate_sim::schedule::{BiteTruth, Schedule};

use crate::analysis::driveline::BiteReport;
use crate::field::counters::ChannelCounters;
use crate::history::query::HistoryReader;
use crate::outputs::modbus::register_map::RegisterMap;
use crate::service::{Bound, RunningService};
use crate::state::results::TandemMillResults;
use crate::state::time::UtcTime;

/// Arguments of `millgate demo`.
#[derive(Debug, Clone, clap::Args)]
pub struct DemoArgs {
    /// How long to run, s.
    #[arg(long, default_value_t = 20.0)]
    pub duration: f64,
    /// Measurement noise added by the virtual DAQ, kN*m RMS.
    #[arg(long, default_value_t = 0.5)]
    pub noise_rms: f64,
    /// Seed of the noise.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// The event history file (created when missing; a run on an existing file
    /// continues its counters and wear trend). Default: a new file in a temporary
    /// folder.
    #[arg(long)]
    pub history: Option<PathBuf>,
    /// Publish the demo's Sparkplug B edge node to this MQTT broker (plain MQTT).
    #[arg(long, value_name = "HOST:PORT")]
    pub mqtt: Option<std::net::SocketAddr>,
    /// Sparkplug group id with `--mqtt`.
    #[arg(long, default_value = "millgate", value_parser = sparkplug_id)]
    pub group: String,
    /// Sparkplug edge node id with `--mqtt`.
    #[arg(long, default_value = "demo", value_parser = sparkplug_id)]
    pub node: String,
    /// Serve the maintenance page on this address (default: a free loopback port).
    #[arg(long, value_name = "HOST:PORT", default_value = "127.0.0.1:0")]
    pub web: std::net::SocketAddr,
    /// Serve the Prometheus metrics (`/metrics`) on this address (default: a free
    /// loopback port).
    #[arg(long, value_name = "HOST:PORT", default_value = "127.0.0.1:0")]
    pub metrics: std::net::SocketAddr,
    /// The OPC UA server (`--opcua`, with the `opcua` feature).
    #[command(flatten)]
    pub opcua: crate::outputs::opcua::DemoOption,
    /// Leave out the tandem mill (its real-time simulation of five stands takes about
    /// a core while the demo runs): the driveline only.
    #[arg(long)]
    pub no_tandem: bool,
}

fn sparkplug_id(id: &str) -> Result<String, String> {
    if millgate_config::is_sparkplug_id(id) {
        Ok(id.to_owned())
    } else {
        Err(format!(
            "\"{id}\" is not allowed (must be non-empty, without / + or #)"
        ))
    }
}

/// The history file of a demo run (its folder created when missing).
fn history_file(args: &DemoArgs) -> anyhow::Result<PathBuf> {
    let path = match &args.history {
        Some(path) => path.clone(),
        None => {
            let stamp = UtcTime::now().unix_ms();
            let folder =
                std::env::temp_dir().join(format!("millgate-demo-{}-{stamp}", std::process::id()));
            folder.join("history.db")
        }
    };
    let folder = match path.parent() {
        Some(folder) if !folder.as_os_str().is_empty() => folder.to_path_buf(),
        _ => PathBuf::from("."),
    };
    std::fs::create_dir_all(&folder)
        .map_err(|e| anyhow::anyhow!("--history: cannot create {}: {e}", folder.display()))?;
    Ok(path)
}

/// `println!` that returns the write's error (a reader that closed the pipe, which
/// ends the demo quietly) instead of panicking.
macro_rules! say {
    ($($arg:tt)*) => {
        super::shell::print(&format!("{}\n", format_args!($($arg)*)))
    };
}

fn print_registers(map: &RegisterMap, words: &[u16]) -> std::io::Result<()> {
    use millgate_config::ValueType;
    say!("\nPLC holding registers while running (base 0):")?;
    say!("  {:>7}  {:<28} {:>14}  unit", "address", "name", "value")?;
    for register in map.registers() {
        let start = usize::from(register.address);
        let Some(raw) = millgate_config::layout::decode_value(
            &words[start..],
            register.value_type,
            register.word_order,
        ) else {
            continue;
        };
        let value = raw * register.scale;
        let shown = match register.value_type {
            ValueType::F32 => format!("{value:.4}"),
            _ => format!("{value:.0}"),
        };
        say!(
            "  {:>7}  {:<28} {:>14}  {}",
            register.address,
            register.name,
            shown,
            register.unit
        )?;
    }
    Ok(())
}

/// Run the demo for `args.duration` seconds.
pub async fn run(args: DemoArgs) -> anyhow::Result<()> {
    anyhow::ensure!(
        args.duration.is_finite() && args.duration > 0.0,
        "--duration must be > 0 s (got {})",
        args.duration
    );
    let DemoSetup {
        mut config,
        schedule,
    } = if args.no_tandem {
        setup(args.duration, args.noise_rms, args.seed)?
    } else {
        setup_with_tandem(args.duration, args.noise_rms, args.seed)?
    };
    let history_path = history_file(&args)?;
    configure_outputs(&mut config, &args, &history_path);
    if let Some(broker) = args.mqtt {
        say!(
            "Sparkplug B: edge node {}/{} on mqtt://{broker} (topics spBv1.0/{}/#)",
            args.group,
            args.node,
            args.group
        )?;
    }
    print_history(&history_path)?;
    // The PLC holds the whole map and a margin, and its own data past it (the tandem
    // mill's weld bit at 1000).
    let map = RegisterMap::new(&config);
    let plc_registers = (usize::from(map.len()) + 16).max(PLC_OWN_REGISTERS);
    // The tandem mill's simulation is set up before the driveline's DAQ streams.
    let prepared = match config.tandem_mills.first() {
        Some(_) => Some(PreparedTandem::new(&config, args.seed)?),
        None => None,
    };
    let devices = DemoDevices::start(&mut config, &schedule, plc_registers).await?;
    let tandem = match prepared {
        Some(prepared) => {
            let mill = &config.tandem_mills[0];
            let hold = (mill.weld_settle_s, mill.weld_alarm_factor);
            let flags = map
                .named(&format!("{}.flags", mill.name))
                .map(|register| usize::from(register.address))
                .ok_or_else(|| anyhow::anyhow!("the demo's tandem mill has no flags register"))?;
            let (rig, daq) = TandemDemo::start(prepared, &mut config, &devices.plc, flags).await?;
            Some((rig, daq, hold))
        }
        None => None,
    };
    say!(
        "millgate demo: virtual DAQ at {} ({} Hz, blocks of {SAMPLES_PER_BLOCK}), virtual PLC at {}, {} s",
        config.modbus_sources[0].address,
        schedule.sample_rate_hz,
        plc_output_address(&config),
        args.duration
    )?;
    let service = crate::Service::new(config.clone())?;
    let map = service.register_map();
    let mut gateway = service.spawn().await?;
    let board = gateway.board();
    let history = gateway.history().clone();
    // The stands' counters, for the summary: whether the closed loop ran in real time.
    let stand_counters: Vec<_> = config
        .tandem_mills
        .first()
        .map(|mill| {
            mill.stands
                .iter()
                .map(|&channel| Arc::clone(&gateway.counters()[channel]))
                .collect()
        })
        .unwrap_or_default();
    let started = Instant::now();
    let (mut tandem, tandem_daq) = match tandem {
        Some((rig, daq, hold)) => {
            let console = TandemConsole::start(rig, hold, args.duration);
            print_script(&console.script, hold, args.duration)?;
            (Some(console), Some(daq))
        }
        None => (None, None),
    };
    // A reader that closed the pipe ends the printing, not the stop: the gateway and
    // the devices stop in order, then its error ends the command quietly.
    let printed = match print_addresses(gateway.bound()) {
        Ok(()) => {
            print_bites(
                &mut gateway,
                &schedule,
                args.duration,
                started,
                tandem.as_mut(),
            )
            .await
        }
        Err(error) => Err(error),
    };
    let tandem_run = match tandem {
        Some(console) => Some(console.stop().await),
        None => None,
    };
    let live = devices.plc.holding();
    gateway.stop().await?;
    let after_stop = devices.plc.holding();
    devices.stop().await?;
    if let Some(daq) = tandem_daq {
        daq.stop().await?;
    }
    let printed = printed?;
    say!(
        "{printed} bites analysed in {:.1} s",
        started.elapsed().as_secs_f64()
    )?;
    let last = board.results().drivelines[0].clone();
    say!(
        "history: {} ({} events stored; bite counter {}, wear trend {}; \
         `millgate history --db FILE`, `millgate report --db FILE --out DIR` read it)",
        history_path.display(),
        history.stored(),
        last.bite_counter,
        last.wear_trend
            .map_or_else(|| "none".to_owned(), |trend| format!("{trend:.4}"))
    )?;
    if let Some((run, script)) = tandem_run {
        let run = run?;
        print_tandem_summary(&board.results().tandem_mills[0], &run, &script)?;
        print_real_time(&run, &stand_counters)?;
    }
    print_registers(&map, &live)?;
    print_status_after_stop(&map, &after_stop)?;
    Ok(())
}

/// Holding registers of the demo's PLC at least: its own data (the tandem mill's weld
/// bit at 1000) sits past the block the gateway writes.
const PLC_OWN_REGISTERS: usize = 1024;

/// The demo's outputs in `config`: the history at `history_path`, Sparkplug with
/// `--mqtt`, the maintenance page, the Prometheus metrics, OPC UA with `--opcua`.
fn configure_outputs(config: &mut Config, args: &DemoArgs, history_path: &Path) {
    config.history = Some(millgate_config::History {
        path: history_path.to_path_buf(),
        retention_days: 400,
        max_size_mb: 1024,
        captures: millgate_config::CaptureSettings::defaults(1024),
        synchronous: millgate_config::Synchronous::default(),
    });
    if let Some(broker) = args.mqtt {
        config.outputs.mqtt = Some(millgate_config::MqttOutput {
            brokers: vec![broker.to_string()],
            client_id: format!("millgate-{}-{}", args.group, args.node),
            group_id: args.group.clone(),
            node_id: args.node.clone(),
            keep_alive: Duration::from_secs(30),
            data_period: Duration::from_secs(1),
            command_qos: 1,
            primary_host_id: None,
            credentials: None,
            replay_batch: 100,
            replay_period: Duration::from_millis(100),
            tls: None,
            security: vec![millgate_config::MqttSecurity::default()],
        });
    }
    config.outputs.web = Some(millgate_config::WebOutput::on(args.web));
    config.outputs.metrics = Some(millgate_config::MetricsOutput { bind: args.metrics });
    let folder = history_path.parent().unwrap_or(Path::new("."));
    args.opcua.apply(config, folder);
}

/// The history file, and what a run on it continues.
fn print_history(history_path: &Path) -> std::io::Result<()> {
    match HistoryReader::open(history_path).and_then(|reader| reader.state()) {
        Ok(state) => match state.drivelines.first() {
            Some(before) => say!(
                "history: {} (continuing: bite counter {}, wear trend {})",
                history_path.display(),
                before.results.bite_counter,
                before
                    .results
                    .wear_trend
                    .map_or_else(|| "none".to_owned(), |trend| format!("{trend:.4}"))
            )?,
            None => say!("history: {}", history_path.display())?,
        },
        Err(_) => say!("history: {} (new)", history_path.display())?,
    }
    Ok(())
}

/// Where the maintenance page and the OPC UA server listen.
fn print_addresses(bound: Bound) -> std::io::Result<()> {
    if let Some(web) = bound.web {
        say!("maintenance page: http://{web}/")?;
    }
    if let Some(metrics) = bound.metrics {
        say!("Prometheus metrics: http://{metrics}/metrics")?;
    }
    if let Some(opcua) = bound.opcua {
        say!("OPC UA server: opc.tcp://{opcua}/ (security none, anonymous)")?;
    }
    Ok(())
}

/// Print each bite `gateway` analyses beside its truth in `schedule` for `duration_s`
/// s, with the time since `started`; returns how many.
async fn print_bites(
    gateway: &mut RunningService,
    schedule: &Schedule,
    duration_s: f64,
    started: Instant,
    mut tandem: Option<&mut TandemConsole>,
) -> std::io::Result<usize> {
    let board = gateway.board();
    say!(
        "{:>7} {:>12} {:>7} {:>10} {:>7} | {:>10} {:>10} {:>24} {:>9} {:>14} {:>22}",
        "time s",
        "static kN*m",
        "TAF",
        "truth TAF",
        "error",
        "gap truth",
        "this bite",
        "trend gap (90%), mrad",
        "coupling",
        "growth mrad/s",
        "alarm in s (90%)"
    )?;
    let deadline = tokio::time::sleep(Duration::from_secs_f64(duration_s));
    tokio::pin!(deadline);
    let mut printed = 0usize;
    // The bars repeat their static torques but not their gap: a bite is the nearest
    // in static torque among the next cycle of bars after the last one matched.
    let mut next_bar = 0;
    loop {
        tokio::select! {
            () = &mut deadline => break,
            bite = gateway.bites().recv() => {
                let Ok(bite) = bite else { continue };
                let truth = schedule.next_truth(
                    next_bar,
                    BARS_PER_CYCLE,
                    bite.transient.static_torque_knm,
                );
                if let Some((index, _)) = truth {
                    next_bar = index + 1;
                }
                let elapsed_s = started.elapsed().as_secs_f64();
                say!("{}", bite_row(&bite, truth.map(|(_, truth)| truth), elapsed_s))?;
                printed += 1;
            }
            event = tandem_event(tandem.as_deref_mut()) => {
                let Some(console) = tandem.as_deref_mut() else { continue };
                match event {
                    TandemEvent::Ended(ran) => console.ended = Some(ran),
                    TandemEvent::Moment(moment) => {
                        let mill = &board.results().tandem_mills[0];
                        for line in console.lines(&moment, mill) {
                            say!("{:>7.2}  {line}", started.elapsed().as_secs_f64())?;
                        }
                    }
                }
            }
        }
    }
    Ok(printed)
}

/// What the tandem mill did.
enum TandemEvent {
    /// A PLC cycle.
    Moment(TandemMoment),
    /// The run ended.
    Ended(Result<RigRun, RigError>),
}

/// The tandem mill's next cycle or the end of its run; never without a mill.
async fn tandem_event(tandem: Option<&mut TandemConsole>) -> TandemEvent {
    let Some(console) = tandem else {
        return std::future::pending().await;
    };
    if console.ended.is_some() {
        return match console.moments.recv().await {
            Some(moment) => TandemEvent::Moment(moment),
            None => std::future::pending().await,
        };
    }
    tokio::select! {
        ran = &mut console.rig => TandemEvent::Ended(ran),
        Some(moment) = console.moments.recv() => TandemEvent::Moment(moment),
    }
}

/// The demo's tandem mill running beside the gateway, and what the console has said
/// about it.
struct TandemConsole {
    /// The mill's run, polled by the console (the demo's own task: the rig's future
    /// borrows across its publishing, which a spawned task cannot).
    rig: std::pin::Pin<Box<dyn std::future::Future<Output = Result<RigRun, RigError>>>>,
    /// How it ended, once it did.
    ended: Option<Result<RigRun, RigError>>,
    moments: tokio::sync::mpsc::UnboundedReceiver<TandemMoment>,
    script: TandemScript,
    /// The weld hold: settle time, s, and factor on the alarm level.
    hold: (f64, f64),
    last: TandemMoment,
    /// The mill's slow-down request as the gateway published it last.
    requested: bool,
    /// Windows the weld hold kept off, as printed last.
    held_off: u64,
    ramped: bool,
    hold_over: bool,
}

impl TandemConsole {
    /// Runs `rig` in the background for `duration_s`; `hold` the mill's weld hold
    /// (`weld_settle_s`, `weld_alarm_factor`).
    fn start(rig: TandemDemo, hold: (f64, f64), duration_s: f64) -> Self {
        let script = rig.script();
        let cycles = (duration_s / rig.cycle_s()).floor() as usize;
        let (sender, moments) = tokio::sync::mpsc::unbounded_channel();
        let rig = Box::pin(rig.run(cycles, move |moment| {
            // The console may have stopped reading: the mill runs on.
            let _ = sender.send(moment);
        }));
        TandemConsole {
            rig,
            ended: None,
            moments,
            script,
            hold,
            last: TandemMoment::default(),
            requested: false,
            held_off: 0,
            ramped: false,
            hold_over: false,
        }
    }

    /// What the console says about `moment`, given the gateway's latest figures of the
    /// mill.
    fn lines(&mut self, moment: &TandemMoment, mill: &TandemMillResults) -> Vec<String> {
        let mpm = |m_s: f64| m_s * 60.0;
        let (settle_s, factor) = self.hold;
        let mut lines = Vec::new();
        if moment.weld && !self.last.weld {
            lines.push(format!(
                "TCM  weld in the mill at {:.0} m/min: the PLC's weld bit is 1 (holding \
                 register 1000, read by the gateway over Modbus TCP)",
                mpm(moment.speed_m_s)
            ));
        }
        if mill.weld_held_off > self.held_off {
            if self.held_off == 0 {
                lines.push(format!(
                    "TCM  gain ratio {} >= 1 from the weld's excitation: the alarm and the \
                     slow-down request held off (the weld hold needs {factor}x the alarm level)",
                    mill.gain_ratio
                        .map_or_else(|| "-".to_owned(), |ratio| format!("{ratio:.2}"))
                ));
            }
            self.held_off = mill.weld_held_off;
        }
        if !moment.weld && self.last.weld {
            lines.push(format!(
                "TCM  weld has left the mill (weld bit 0): the alarm level stays {factor}x \
                 for {settle_s} s more"
            ));
        }
        let hold_end_s = self.script.weld.time_s + self.script.weld.duration_s + settle_s;
        if !self.hold_over && moment.t_s >= hold_end_s {
            self.hold_over = true;
            lines.push(format!(
                "TCM  weld hold over: {} windows held off, slow-down request {}",
                mill.weld_held_off,
                if mill.slow_down_request {
                    "set"
                } else {
                    "never set"
                }
            ));
        }
        if !self.ramped && moment.setpoint_m_s > self.script.start_m_s {
            self.ramped = true;
            lines.push(format!(
                "TCM  the operator ramps the mill from {:.0} to {:.0} m/min, past its \
                 critical speed {:.0} m/min",
                mpm(moment.speed_m_s),
                mpm(moment.setpoint_m_s),
                mpm(self.script.critical_m_s)
            ));
        }
        if mill.slow_down_request != self.requested {
            self.requested = mill.slow_down_request;
            lines.push(if mill.slow_down_request {
                format!(
                    "TCM  slow-down request raised (gain ratio {}, stand {}) at {:.0} m/min: \
                     the PLC slows the mill",
                    mill.gain_ratio
                        .map_or_else(|| "-".to_owned(), |ratio| format!("{ratio:.2}")),
                    mill.worst_stand
                        .map_or_else(|| "-".to_owned(), |stand| (stand + 1).to_string()),
                    mpm(moment.speed_m_s)
                )
            } else {
                format!(
                    "TCM  slow-down request cleared at {:.0} m/min",
                    mpm(moment.speed_m_s)
                )
            });
        }
        self.last = *moment;
        lines
    }

    /// Waits for the mill's run to end (a second past its last cycle at most), and
    /// returns it with the script.
    async fn stop(self) -> (anyhow::Result<RigRun>, TandemScript) {
        let run = match self.ended {
            Some(ended) => ended.map_err(anyhow::Error::from),
            None => match tokio::time::timeout(Duration::from_secs(1), self.rig).await {
                Ok(ended) => ended.map_err(anyhow::Error::from),
                // Dropped: its DAQ stops serving with it.
                Err(_) => Err(anyhow::anyhow!(
                    "the tandem mill's simulation fell behind the wall clock"
                )),
            },
        };
        (run, self.script)
    }
}

/// What the tandem mill will do.
fn print_script(script: &TandemScript, hold: (f64, f64), duration_s: f64) -> std::io::Result<()> {
    let (settle_s, _) = hold;
    let weld_end_s = script.weld.time_s + script.weld.duration_s;
    say!(
        "tandem mill TCM (5 stands, the tandem model on a second virtual DAQ): a weld in the \
         mill {:.0}-{weld_end_s:.0} s, its hold until {:.0} s, then the operator's ramp past \
         the critical speed{}",
        script.weld.time_s,
        weld_end_s + settle_s,
        if duration_s < script.ramp_at_s + 4.0 {
            format!(
                " (run --duration {:.0} or more to see it)",
                (script.ramp_at_s + 4.0).ceil()
            )
        } else {
            String::new()
        }
    )
}

/// What the tandem mill did over the demo.
fn print_tandem_summary(
    mill: &TandemMillResults,
    run: &RigRun,
    script: &TandemScript,
) -> std::io::Result<()> {
    let top = run.cycles.iter().map(|c| c.speed_m_s).fold(0.0, f64::max);
    say!(
        "tandem mill TCM: {} windows evaluated, {} held off by the weld hold, {} slow-downs \
         by the PLC; top speed {:.0} m/min (critical {:.0} m/min), chatter {}",
        mill.evaluations,
        mill.weld_held_off,
        run.events.len(),
        top * 60.0,
        script.critical_m_s * 60.0,
        run.developed_s.map_or_else(
            || "never developed".to_owned(),
            |t| format!("developed at {t:.1} s")
        )
    )
}

/// Whether the tandem mill's closed loop ran in real time: every PLC cycle handed
/// over in its time (`run`) and no block of the stands' DAQ missed by the gateway
/// (`stands`, the stand channels' counters: the most any stand missed, and its
/// sequence restarts). A busy machine breaks it, and the chatter outcome may then
/// differ from a quiet machine's: said, not hidden.
fn print_real_time(run: &RigRun, stands: &[Arc<ChannelCounters>]) -> std::io::Result<()> {
    let (missed, restarts) = stands
        .iter()
        .map(|counters| {
            let counted = counters.snapshot();
            (counted.blocks_missed, counted.sequence_restarts)
        })
        .fold((0, 0), |(m, r), (missed, restarts)| {
            (m.max(missed), r.max(restarts))
        });
    if run.late == 0 && missed == 0 && restarts == 0 {
        say!(
            "tandem mill TCM: the closed loop ran in real time (no PLC cycle handed over late, \
             no block of the stands' DAQ missed)"
        )
    } else {
        say!(
            "tandem mill TCM: the closed loop did not run in real time on this busy machine: \
             {} PLC cycles handed over late, {missed} blocks of the stands' DAQ missed, \
             {restarts} sequence restarts (chatter may develop where a quiet machine slows the \
             mill in time)",
            run.late
        )
    }
}

/// The printed row of `bite`, `elapsed_s` s into the demo, beside its `truth`.
fn bite_row(bite: &BiteReport, truth: Option<&BiteTruth>, elapsed_s: f64) -> String {
    let t = &bite.transient;
    let taf = t.taf.unwrap_or(f64::NAN);
    let truth_taf = truth.map_or(f64::NAN, |truth| truth.taf);
    let truth_gap = truth.map_or(f64::NAN, |truth| truth.backlash_rad[GAP_COUPLING] * 1e3);
    let gap = bite.gap.as_ref();
    let this_bite = gap.and_then(|gap| gap.bite).map_or_else(
        || "-".to_owned(),
        |single| format!("{:.2}", single.gap_mrad),
    );
    // The demo compresses months of wear into seconds: growth and forecast in seconds.
    let (trend, coupling, growth, alarm) = match gap.and_then(|gap| gap.trend) {
        None if gap.is_some() => (
            "maps building".to_owned(),
            String::new(),
            String::new(),
            String::new(),
        ),
        None => ("-".to_owned(), String::new(), String::new(), String::new()),
        Some(trend) => (
            format!(
                "{:.2} ({:.2} .. {:.2})",
                trend.gap_mrad, trend.low_mrad, trend.high_mrad
            ),
            trend
                .coupling
                .map_or_else(|| "undet.".to_owned(), |c| c.to_string()),
            trend.growth.map_or_else(
                || "-".to_owned(),
                |g| format!("{:.3}", g.mrad_per_day / SECONDS_PER_DAY),
            ),
            trend.forecast.map_or_else(String::new, |f| match f.days {
                Some(days) => format!(
                    "{:.1} ({} .. {})",
                    days * SECONDS_PER_DAY,
                    seconds(f.days_low),
                    seconds(f.days_high)
                ),
                None => f.state.name().to_owned(),
            }),
        ),
    };
    format!(
        "{:>7.2} {:>12.2} {:>7.3} {:>10.3} {:>6.2}% | {:>10.2} {:>10} {:>24} {:>9} {:>14} {:>22}{}",
        elapsed_s,
        t.static_torque_knm,
        taf,
        truth_taf,
        100.0 * (taf - truth_taf) / truth_taf,
        truth_gap,
        this_bite,
        trend,
        coupling,
        growth,
        alarm,
        if bite.degraded {
            "  (degraded window)"
        } else {
            ""
        },
    )
}

/// Seconds per day: the demo's wear runs in seconds.
const SECONDS_PER_DAY: f64 = 86_400.0;

/// `days` in seconds, `-` without.
fn seconds(days: Option<f64>) -> String {
    days.map_or_else(
        || "-".to_owned(),
        |days| format!("{:.1}", days * SECONDS_PER_DAY),
    )
}

/// The gateway status word the PLC holds in `words` after the gateway stopped.
fn print_status_after_stop(map: &RegisterMap, words: &[u16]) -> std::io::Result<()> {
    let (_, status) = crate::outputs::modbus::register_map::GATEWAY_STATUS;
    if let Some(register) = map.named(status) {
        say!(
            "after shutdown: gateway_status = {:#06b} (bit1 stopped; values flagged, no longer fresh)",
            words[usize::from(register.address)]
        )?;
    }
    Ok(())
}

fn plc_output_address(config: &Config) -> String {
    config
        .outputs
        .plc
        .as_ref()
        .map_or_else(String::new, |plc| plc.address.clone())
}
