//! `millgate demo`: the whole path on one machine, with nothing to set up.
//!
//! A virtual DAQ streams a simulated rolling schedule (one bite per bar, from the
//! Table 2 driveline with an opened gap) over Modbus TCP on loopback; the gateway
//! reads it, analyses every bite and writes its results into a virtual PLC, also on
//! loopback. Each bite is printed beside its simulated truth; the PLC's registers
//! are printed at the end.

use std::time::{Duration, Instant};

use anyhow::Context as _;
use millgate_config::{ChannelSource, Config};
use millgate_sim::daq::{DaqChannel, Placement, Publish, VirtualDaq};
use millgate_sim::modbus_bank::{Running, ServeOptions};
use millgate_sim::model::Model;
use millgate_sim::plc::VirtualPlc;
use millgate_sim::schedule::{rolling_schedule, BarTiming, Schedule};
use tokio::net::TcpListener;

use crate::registers::RegisterMap;

/// The demo's configuration (addresses are replaced by the loopback ports taken at start).
const DEMO_CONFIG: &str = include_str!("../../config/examples/demo.toml");
/// The driveline the virtual DAQ simulates.
const DEMO_MODEL: &str = include_str!("../../sim/models/table2-adjusted-backlash.toml");
/// Static torques of successive bars, kN*m: light and heavy passes alternate so the
/// effect of the gap on TAF shows.
const BAR_STATIC_TORQUES_KNM: [f64; 6] = [112.0, 60.0, 150.0, 80.0, 130.0, 45.0];
const BAR_TIMING: BarTiming = BarTiming {
    idle_s: 0.6,
    rolling_s: 1.2,
};
/// Samples per DAQ block: 50 ms at 2 kHz.
const SAMPLES_PER_BLOCK: u16 = 100;

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
}

/// The demo configuration, its model and the schedule the DAQ will play.
pub struct DemoSetup {
    pub config: Config,
    pub schedule: Schedule,
}

/// Build the demo's configuration and simulated schedule for `duration_s`.
pub fn setup(duration_s: f64, noise_rms_knm: f64, seed: u64) -> anyhow::Result<DemoSetup> {
    let config =
        millgate_config::from_toml_str(DEMO_CONFIG, "demo.toml", std::path::Path::new("."))
            .map_err(|e| anyhow::anyhow!("{e}"))?;
    let mut model = Model::from_toml_str(DEMO_MODEL, "table2-adjusted-backlash.toml")?;
    let torque = &config.channels[config.drivelines[0].torque];
    model.measurement.sample_rate = torque.sample_rate_hz;
    let bar_s = BAR_TIMING.idle_s + BAR_TIMING.rolling_s + millgate_sim::schedule::TAIL_OUT_S;
    let bars = (duration_s / bar_s).ceil() as usize + 1;
    let torques: Vec<f64> = BAR_STATIC_TORQUES_KNM
        .iter()
        .copied()
        .cycle()
        .take(bars)
        .collect();
    let schedule = rolling_schedule(&model, &torques, BAR_TIMING, noise_rms_knm, seed)?;
    Ok(DemoSetup { config, schedule })
}

/// The virtual DAQ that plays `schedule` on the driveline's torque channel of `config`.
pub fn virtual_daq(config: &Config, schedule: &Schedule) -> anyhow::Result<VirtualDaq> {
    let torque = &config.channels[config.drivelines[0].torque];
    let ChannelSource::ModbusBlock { table, base, .. } = torque.source else {
        anyhow::bail!("the demo's torque channel must be a Modbus block channel");
    };
    let channel = DaqChannel {
        placement: Placement {
            table,
            address: base,
            scale: torque.scale,
            offset: torque.offset,
        },
        publish: Publish::Block,
        signal: schedule.torque_knm.clone(),
    };
    Ok(VirtualDaq::new(
        torque.sample_rate_hz,
        SAMPLES_PER_BLOCK,
        vec![channel],
    ))
}

/// The truth of the bar whose static torque is nearest `static_knm`.
pub fn nearest_truth(
    schedule: &Schedule,
    static_knm: f64,
) -> Option<&millgate_sim::schedule::BiteTruth> {
    schedule.bites.iter().min_by(|a, b| {
        let da = (a.static_torque_knm - static_knm).abs();
        let db = (b.static_torque_knm - static_knm).abs();
        da.total_cmp(&db)
    })
}

fn print_registers(map: &RegisterMap, words: &[u16]) {
    use millgate_config::ValueType;
    println!("\nPLC holding registers while running (base 0):");
    println!("  {:>7}  {:<28} {:>14}  unit", "address", "name", "value");
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
        println!(
            "  {:>7}  {:<28} {:>14}  {}",
            register.address, register.name, shown, register.unit
        );
    }
}

/// The virtual DAQ and PLC running on loopback.
pub struct Devices {
    pub plc: VirtualPlc,
    running: [Running; 2],
}

impl Devices {
    /// Start a virtual DAQ playing `schedule` and a virtual PLC on free loopback
    /// ports, and point `config`'s first Modbus source and its PLC output at them.
    pub async fn start(config: &mut Config, schedule: &Schedule) -> anyhow::Result<Self> {
        let daq = virtual_daq(config, schedule)?;
        let plc = VirtualPlc::new(usize::from(RegisterMap::new(config).len()) + 16);
        let daq_listener = TcpListener::bind("127.0.0.1:0")
            .await
            .context("bind virtual DAQ")?;
        let plc_listener = TcpListener::bind("127.0.0.1:0")
            .await
            .context("bind virtual PLC")?;
        config.modbus_sources[0].address = daq_listener.local_addr()?.to_string();
        let plc_output = config
            .outputs
            .plc
            .as_mut()
            .context("the demo configuration needs outputs.plc")?;
        plc_output.address = plc_listener.local_addr()?.to_string();
        plc_output.register_base = 0;
        if let Some(server) = config.outputs.server.as_mut() {
            server.bind = "127.0.0.1:0".parse()?;
        }
        let running = [
            daq.spawn(daq_listener, ServeOptions::default()),
            plc.spawn(plc_listener, ServeOptions::default()),
        ];
        Ok(Self { plc, running })
    }

    /// Stop both devices.
    pub async fn stop(self) -> anyhow::Result<()> {
        for device in self.running {
            device.stop().await?;
        }
        Ok(())
    }
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
    } = setup(args.duration, args.noise_rms, args.seed)?;
    let devices = Devices::start(&mut config, &schedule).await?;

    println!(
        "millgate demo: virtual DAQ at {} ({} Hz, blocks of {SAMPLES_PER_BLOCK}), virtual PLC at {}, {} s",
        config.modbus_sources[0].address,
        schedule.sample_rate_hz,
        plc_output_address(&config),
        args.duration
    );
    println!(
        "{:>7}  {:<12} {:>12} {:>11} {:>7} {:>10} {:>7}",
        "time s", "channel", "static kN*m", "peak kN*m", "TAF", "truth TAF", "error"
    );
    let service = crate::Service::new(config.clone())?;
    let mut bites = service.subscribe_bites();
    let publisher = service.publisher();
    let (stop_gateway, gateway_shutdown) = crate::shutdown::channel();
    let gateway = tokio::spawn(service.run(gateway_shutdown));

    let started = Instant::now();
    let deadline = tokio::time::sleep(Duration::from_secs_f64(args.duration));
    tokio::pin!(deadline);
    let mut printed = 0usize;
    loop {
        tokio::select! {
            () = &mut deadline => break,
            bite = bites.recv() => {
                let Ok(bite) = bite else { continue };
                let t = &bite.transient;
                let taf = t.taf.unwrap_or(f64::NAN);
                let truth = nearest_truth(&schedule, t.static_torque_knm);
                let truth_taf = truth.map_or(f64::NAN, |truth| truth.taf);
                println!(
                    "{:>7.2}  {:<12} {:>12.2} {:>11.2} {:>7.3} {:>10.3} {:>6.2}%{}",
                    started.elapsed().as_secs_f64(),
                    bite.channel_name,
                    t.static_torque_knm,
                    t.peak_torque_knm,
                    taf,
                    truth_taf,
                    100.0 * (taf - truth_taf) / truth_taf,
                    if bite.degraded { "  (degraded window)" } else { "" },
                );
                printed += 1;
            }
        }
    }
    let live = devices.plc.holding();
    stop_gateway.trigger();
    gateway.await??;
    let after_stop = devices.plc.holding();
    devices.stop().await?;
    println!(
        "{printed} bites analysed in {:.1} s",
        started.elapsed().as_secs_f64()
    );
    print_registers(publisher.map(), &live);
    let status = crate::registers::Field::GatewayStatus;
    if let Some(register) = publisher
        .map()
        .registers()
        .iter()
        .find(|r| r.field == status)
    {
        println!(
            "after shutdown: gateway_status = {:#06b} (bit1 stopped; values flagged, no longer fresh)",
            after_stop[usize::from(register.address)]
        );
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
