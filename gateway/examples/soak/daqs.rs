//! The load point's field devices: the generated channels (the drivelines' simulated
//! bars, the stands' seeded noise), the virtual DAQs that stream them, and the
//! configuration the gateway reads them with.

use std::net::{SocketAddr, TcpListener as StdListener};
use std::path::{Path, PathBuf};

use anyhow::Context as _;
use millgate_config::layout::BLOCK_REGISTERS;
use millgate_config::RegisterTable;
use millgate_sim::devices::demo::setup;
use millgate_sim::devices::virtual_daq::{DaqChannel, Placement, Publish, VirtualDaq};
use rand::SeedableRng as _;
use rand_distr::Distribution as _;

use crate::options::Options;
use crate::probe::free_port;

/// Channels per virtual DAQ (one Modbus source each).
pub(crate) const CHANNELS_PER_DAQ: usize = 8;
/// Stands per tandem mill.
const STANDS_PER_MILL: usize = 5;
/// Driveline torque sample rate, Hz, and samples per DAQ block (50 ms).
pub(crate) const DRIVELINE_RATE_HZ: f64 = 2000.0;
pub(crate) const DRIVELINE_BLOCK: u16 = 100;
/// Samples per block of the stands' DAQs.
const STAND_BLOCK: u16 = 120;
/// The drivelines' bite window after the trigger, s (as the demo's).
pub(crate) const POST_TRIGGER_S: f64 = 0.5;
/// Seconds of simulated bars each driveline's DAQ plays over and over.
const BARS_S: f64 = 60.0;
/// Delay between two drivelines' copies of the bars, s.
const STAGGER_S: f64 = 0.2;
/// Seconds of noise each stand's DAQ plays over and over.
const STAND_NOISE_S: f64 = 4.0;
/// RMS of the stands' noise, m/s^2.
const STAND_NOISE_RMS: f64 = 2.0;

/// A channel of the generated configuration on a virtual DAQ.
struct GeneratedChannel {
    toml: String,
    daq_channel: DaqChannel,
}

/// The virtual DAQs of one rate and their `[[sources.modbus]]` tables (with
/// `requests_in_flight` when given).
fn daqs(
    prefix: &str,
    rate_hz: f64,
    block: u16,
    channels: Vec<GeneratedChannel>,
    (log_reads, requests_in_flight): (bool, Option<u32>),
    config: &mut String,
    listeners: &mut Vec<(VirtualDaq, std::net::TcpListener)>,
) -> anyhow::Result<()> {
    let block_ms = f64::from(block) / rate_hz * 1e3;
    let poll_ms = (block_ms / 3.0).floor().min(20.0);
    let mut channels = channels.into_iter().peekable();
    let mut daq = 0;
    while channels.peek().is_some() {
        let listener = StdListener::bind("127.0.0.1:0")?;
        let name = format!("{prefix}{daq}");
        config.push_str(&format!(
            "[[sources.modbus]]\nname = \"{name}\"\naddress = \"{}\"\n\
             poll_period_ms = {poll_ms}\ntimeout_ms = 500\n{}\n",
            listener.local_addr()?,
            requests_in_flight.map_or(String::new(), |n| format!("requests_in_flight = {n}\n"))
        ));
        let mut played = Vec::new();
        for (slot, channel) in channels.by_ref().take(CHANNELS_PER_DAQ).enumerate() {
            let base = slot as u16 * BLOCK_REGISTERS;
            config.push_str(&channel.toml.replace(
                "SOURCE",
                &format!("{{ modbus = \"{name}\", table = \"input\", block = {base} }}"),
            ));
            let mut daq_channel = channel.daq_channel;
            daq_channel.placement.address = base;
            played.push(daq_channel);
        }
        let device = VirtualDaq::new(rate_hz, block, played).looped();
        let device = if log_reads {
            device.logging_reads()
        } else {
            device
        };
        listeners.push((device, listener));
        daq += 1;
    }
    Ok(())
}

/// A block channel placed at 0 (its DAQ places it), scaled 0.01 per LSB.
fn block_channel(signal: Vec<f64>) -> DaqChannel {
    DaqChannel {
        placement: Placement {
            table: RegisterTable::Input,
            address: 0,
            scale: 0.01,
            offset: 0.0,
        },
        publish: Publish::Block,
        signal,
    }
}

/// The configuration of a load point (in `folder`, beside a copy of the demo's
/// model) and the DAQs it reads, bound but not yet serving.
pub(crate) struct LoadPoint {
    pub(crate) config: millgate_config::Config,
    pub(crate) config_path: PathBuf,
    pub(crate) daqs: Vec<(VirtualDaq, std::net::TcpListener)>,
    pub(crate) plc_listener: std::net::TcpListener,
    pub(crate) server: SocketAddr,
    pub(crate) metrics: SocketAddr,
    pub(crate) web: SocketAddr,
}

/// Generates the configuration of a load point in `folder` (beside a copy of the
/// demo's model), with the broker at `broker_port`, the tandem mills' rate of
/// `options`, and its `[analysis] workers` and the PLC's requests in flight when
/// given, and binds the DAQs it reads, the PLC and the gateway's ports.
pub(crate) fn load_point(
    folder: &Path,
    (drivelines, stands): (usize, usize),
    options: &Options,
    broker_port: u16,
) -> anyhow::Result<LoadPoint> {
    let tandem_rate_hz = options.tandem_rate_hz;
    let model = Path::new(env!("CARGO_MANIFEST_DIR")).join("../sim/models/table2-adjusted.toml");
    std::fs::copy(&model, folder.join("table2-adjusted.toml"))
        .with_context(|| format!("copying {}", model.display()))?;
    let mut config = format!("name = \"load bench: {drivelines} drivelines, {stands} stands\"\n\n");
    if let Some(workers) = options.analysis_workers {
        config.push_str(&format!("[analysis]\nworkers = {workers}\n\n"));
    }
    let mut listeners = Vec::new();
    let (torque_channels, driveline_tables) = driveline_channels(drivelines)?;
    daqs(
        "torque_daq",
        DRIVELINE_RATE_HZ,
        DRIVELINE_BLOCK,
        torque_channels,
        (true, options.daq_requests_in_flight),
        &mut config,
        &mut listeners,
    )?;
    daqs(
        "stand_daq",
        tandem_rate_hz,
        STAND_BLOCK,
        stand_channels(stands, tandem_rate_hz)?,
        (false, options.daq_requests_in_flight),
        &mut config,
        &mut listeners,
    )?;
    config.push_str(&driveline_tables);
    config.push_str(&tandem_mill_tables(stands));

    let plc_listener = StdListener::bind("127.0.0.1:0")?;
    let (server, metrics, web) = (free_port()?, free_port()?, free_port()?);
    config.push_str(&format!(
        "[outputs.plc]\naddress = \"{}\"\nregister_base = 0\nwrite_period_ms = 100\n\
         timeout_ms = 500\n{}\n[outputs.server]\nbind = \"{server}\"\n\n\
         [outputs.metrics]\nbind = \"{metrics}\"\n\n[outputs.web]\nbind = \"{web}\"\n\n\
         [history]\npath = \"history.db\"\n\n\
         [outputs.mqtt]\nbroker = \"127.0.0.1:{broker_port}\"\ngroup_id = \"load\"\n\
         node_id = \"bench\"\n",
        plc_listener.local_addr()?,
        options
            .plc_requests_in_flight
            .map_or(String::new(), |n| format!("requests_in_flight = {n}\n"))
    ));
    let config_path = folder.join("mill.toml");
    std::fs::write(&config_path, &config)?;
    let config = millgate_config::load(&config_path)
        .map_err(|error| anyhow::anyhow!("the generated configuration: {error}"))?;
    Ok(LoadPoint {
        config,
        config_path,
        daqs: listeners,
        plc_listener,
        server,
        metrics,
        web,
    })
}

/// The drivelines' torque channels, each a copy of the demo's bars `STAGGER_S` later
/// than the one before, and their `[[drivelines]]` tables.
fn driveline_channels(drivelines: usize) -> anyhow::Result<(Vec<GeneratedChannel>, String)> {
    let bars = setup(BARS_S, 0.5, 1)?.schedule.torque_knm;
    let stagger = (STAGGER_S * DRIVELINE_RATE_HZ) as usize;
    let mut torque_channels = Vec::new();
    let mut driveline_tables = String::new();
    for k in 0..drivelines {
        let mut signal = bars.clone();
        signal.rotate_right((k * stagger) % bars.len());
        torque_channels.push(GeneratedChannel {
            toml: format!(
                "[[channels]]\nname = \"d{k}_torque\"\nkind = \"torque\"\nunit = \"kN*m\"\n\
                 scale = 0.01\nsample_rate_hz = {DRIVELINE_RATE_HZ:.1}\nsource = SOURCE\n\n"
            ),
            daq_channel: block_channel(signal),
        });
        driveline_tables.push_str(&format!(
            "[[drivelines]]\nname = \"D{k}\"\ntorque = \"d{k}_torque\"\n\
             model = \"table2-adjusted.toml\"\n\
             bite = {{ threshold_knm = 20.0, pre_trigger_s = 0.1, post_trigger_s = {POST_TRIGGER_S} }}\n\
             thresholds = {{ taf_warning = 2.2, taf_alarm = 2.6, gap_warning_mrad = 2.0, gap_alarm_mrad = 4.0 }}\n\
             wear = {{ gap_step_mrad = 0.25, torque_points = 12 }}\n\n"
        ));
    }
    Ok((torque_channels, driveline_tables))
}

/// The stands' accelerometer channels: `STAND_NOISE_S` of Gaussian noise each, seeded
/// by the stand's number.
fn stand_channels(stands: usize, tandem_rate_hz: f64) -> anyhow::Result<Vec<GeneratedChannel>> {
    let noise = rand_distr::Normal::new(0.0, STAND_NOISE_RMS)?;
    let mut stand_channels = Vec::new();
    for s in 0..stands {
        let mut rng = rand::rngs::StdRng::seed_from_u64(1000 + s as u64);
        let length = (STAND_NOISE_S * tandem_rate_hz) as usize;
        stand_channels.push(GeneratedChannel {
            toml: format!(
                "[[channels]]\nname = \"s{s}_vib\"\nkind = \"acceleration\"\nunit = \"m/s^2\"\n\
                 scale = 0.01\nsample_rate_hz = {tandem_rate_hz:.1}\nsource = SOURCE\n\n"
            ),
            daq_channel: block_channel((0..length).map(|_| noise.sample(&mut rng)).collect()),
        });
    }
    Ok(stand_channels)
}

/// The `[[tandem_mills]]` tables: the stands in mills of `STANDS_PER_MILL`, the last
/// one with the rest.
fn tandem_mill_tables(stands: usize) -> String {
    let mut tables = String::new();
    for (mill, first) in (0..stands).step_by(STANDS_PER_MILL).enumerate() {
        let names: Vec<String> = (first..stands.min(first + STANDS_PER_MILL))
            .map(|s| format!("\"s{s}_vib\""))
            .collect();
        let thresholds = vec!["3.0"; names.len()].join(", ");
        tables.push_str(&format!(
            "[[tandem_mills]]\nname = \"TCM{mill}\"\nstands = [{}]\n\
             chatter_band_hz = [100.0, 300.0]\nwindow_s = 0.5\nk_max = 0.25\n\
             detector = \"band_gain\"\nreference_band_hz = [450.0, 900.0]\n\
             gain_window_s = 2.0\ngain_thresholds = [{thresholds}]\n\
             slow_down_release = 0.8\nslow_down_hold_s = 5.0\n\n",
            names.join(", ")
        ));
    }
    tables
}
