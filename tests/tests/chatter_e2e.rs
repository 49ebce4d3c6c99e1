//! Chatter end to end: virtual DAQ(s) stream five stands of a tandem mill over
//! Modbus TCP on loopback, the gateway evaluates the synchronization conditions and
//! writes the mill's block into a virtual PLC, read back from the PLC's bank.

use std::time::{Duration, Instant};

use millgate::outputs::register_map::{decode_f32, RegisterMap};
use millgate_config::{Config, RegisterTable};
use millgate_sim::devices::modbus_bank::{Running, ServeOptions};
use millgate_sim::devices::virtual_daq::{DaqChannel, Placement, Publish, VirtualDaq};
use millgate_sim::devices::virtual_plc::VirtualPlc;
use millgate_sim::stands::{Regime, Stands, StandsSettings};
use millgate_tests::{scrape, wait_for};
use tokio::net::TcpListener;

const FS: f64 = 2500.0;
/// 48 ms blocks, as the example configuration's DAQ.
const SAMPLES_PER_BLOCK: u16 = 120;
/// The stands' own frequencies in the 100-300 Hz band, Hz.
const NATURAL_HZ: [f64; 5] = [150.0, 172.0, 196.0, 221.0, 248.0];
/// Where synchronization pulls them, Hz.
const COMMON_HZ: f64 = 187.0;
const K_MAX: f64 = 0.25;
/// sigma_min: the spectrum step of a 0.5 s window, Hz.
const SIGMA_MIN_HZ: f64 = 2.0;

const WARNING: u16 = 1 << 0;
const ALARM: u16 = 1 << 1;
const STALE: u16 = 1 << 2;

/// Five stands at 2500 Hz, each on DAQ `daq_of_stand[i]` (0 or 1), window 0.5 s.
fn config(daq_of_stand: [usize; 5]) -> anyhow::Result<Config> {
    let mut text = String::from("name = \"chatter e2e\"\n");
    for daq in 0..2 {
        text += &format!(
            "[[sources.modbus]]\nname = \"daq{daq}\"\naddress = \"127.0.0.1:1\"\npoll_period_ms = 20\n"
        );
    }
    for (stand, daq) in daq_of_stand.iter().enumerate() {
        text += &format!(
            "[[channels]]\nname = \"s{}_vib\"\nkind = \"acceleration\"\nunit = \"m/s^2\"\n\
             scale = 0.01\nsample_rate_hz = {FS}\n\
             source = {{ modbus = \"daq{daq}\", table = \"input\", block = {} }}\n",
            stand + 1,
            stand * 122
        );
    }
    text += &format!(
        "[[tandem_mills]]\nname = \"TCM\"\n\
         stands = [\"s1_vib\", \"s2_vib\", \"s3_vib\", \"s4_vib\", \"s5_vib\"]\n\
         chatter_band_hz = [100.0, 300.0]\nwindow_s = 0.5\nk_max = {K_MAX}\n\
         [outputs.plc]\naddress = \"127.0.0.1:1\"\nwrite_period_ms = 50\n\
         [outputs.metrics]\nbind = \"127.0.0.1:0\"\n"
    );
    millgate_config::from_toml_str(&text, "chatter-e2e.toml", std::path::Path::new("."))
        .map_err(|e| anyhow::anyhow!("{e}"))
}

/// `duration_s` of the five stands' vibration in `regime`.
fn stand_signals(regime: Regime, duration_s: f64, seed: u64) -> anyhow::Result<Vec<Vec<f64>>> {
    let stands = Stands::new(
        StandsSettings {
            sample_rate_hz: FS,
            natural_hz: NATURAL_HZ.to_vec(),
            amplitude: 2.0,
            linewidth_hz: 0.5,
            noise_rms: 0.5,
        },
        regime,
    )?;
    Ok(stands.generate(duration_s, seed)?)
}

/// A DAQ publishing the stands in `stands` (indices into `signals`) at their blocks.
fn daq(signals: &[Vec<f64>], stands: &[usize]) -> VirtualDaq {
    let channels = stands
        .iter()
        .map(|&stand| DaqChannel {
            placement: Placement {
                table: RegisterTable::Input,
                address: (stand * 122) as u16,
                scale: 0.01,
                offset: 0.0,
            },
            publish: Publish::Block,
            signal: signals[stand].clone(),
        })
        .collect();
    VirtualDaq::new(FS, SAMPLES_PER_BLOCK, channels)
}

/// The mill's registers in a PLC snapshot.
#[derive(Debug, Clone, Copy)]
struct MillWords {
    flags: u16,
    quality: u16,
    sigma_n_hz: f32,
    k_mean: f32,
    chatter_hz: f32,
}

struct Devices {
    plc: VirtualPlc,
    map: RegisterMap,
    running: Vec<Running>,
}

impl Devices {
    fn mill(&self) -> MillWords {
        let words = self.plc.holding();
        let at = |name: &str| {
            let register = self.map.registers().iter().find(|r| r.name == name);
            usize::from(register.unwrap_or_else(|| panic!("{name}")).address)
        };
        let f32_at = |name: &str| decode_f32(&words[at(name)..]).unwrap_or(f32::NAN);
        MillWords {
            flags: words[at("TCM.flags")],
            quality: words[at("TCM.quality")],
            sigma_n_hz: f32_at("TCM.sigma_n"),
            k_mean: f32_at("TCM.k_mean"),
            chatter_hz: f32_at("TCM.chatter_frequency"),
        }
    }
}

/// Start one DAQ per entry of `daqs` and the PLC, and point `config` at them.
async fn start(config: &mut Config, daqs: Vec<VirtualDaq>) -> anyhow::Result<Devices> {
    let map = RegisterMap::new(config);
    let plc = VirtualPlc::new(usize::from(map.len()) + 16);
    let mut running = Vec::new();
    for (index, daq) in daqs.into_iter().enumerate() {
        let listener = TcpListener::bind("127.0.0.1:0").await?;
        config.modbus_sources[index].address = listener.local_addr()?.to_string();
        running.push(daq.spawn(listener, ServeOptions::default()));
    }
    let listener = TcpListener::bind("127.0.0.1:0").await?;
    if let Some(output) = config.outputs.plc.as_mut() {
        output.address = listener.local_addr()?.to_string();
        output.register_base = 0;
    }
    running.push(plc.spawn(listener, ServeOptions::default()));
    Ok(Devices { plc, map, running })
}

/// The value of the first line of `page` starting with `prefix`.
fn metric(page: &str, prefix: &str) -> Option<f64> {
    page.lines()
        .find_map(|line| line.strip_prefix(prefix))
        .and_then(|rest| rest.trim().parse().ok())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn stands_that_synchronize_raise_warning_then_alarm() -> anyhow::Result<()> {
    // Independent stands for 4 s, then the strip couples them.
    const SYNC_S: f64 = 4.0;
    let signals = stand_signals(Regime::synchronized(SYNC_S, COMMON_HZ), 20.0, 21)?;
    let mut config = config([0; 5])?;
    config.modbus_sources.truncate(1);
    let devices = start(&mut config, vec![daq(&signals, &[0, 1, 2, 3, 4])]).await?;
    let streaming = Instant::now();
    let gateway = millgate::Service::new(config)?.spawn().await?;

    // Steady rolling: every valid window shows independent stands.
    wait_for("first valid chatter window", Duration::from_secs(5), || {
        devices.mill().quality == 0b111
    })
    .await;
    let mut before = Vec::new();
    while streaming.elapsed().as_secs_f64() < SYNC_S - 0.3 {
        let mill = devices.mill();
        // Steady streaming from one DAQ never restarts the window.
        assert_eq!(mill.flags & STALE, 0, "{mill:?}");
        if mill.quality == 0b111 {
            before.push(mill);
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    assert!(before.len() > 10, "{} snapshots before sync", before.len());
    for mill in &before {
        assert_eq!(mill.flags & (WARNING | ALARM | STALE), 0, "{mill:?}");
        assert!(mill.k_mean.abs() < K_MAX as f32, "{mill:?}");
        assert!(mill.sigma_n_hz > 10.0 * SIGMA_MIN_HZ as f32, "{mill:?}");
    }

    // Chatter builds up: frequencies meet first, then phases lock.
    let mut warned_at = None;
    let mut alarmed = None;
    let limit = Duration::from_secs(12);
    while alarmed.is_none() {
        assert!(
            streaming.elapsed() < limit,
            "no alarm, last {:?}",
            devices.mill()
        );
        let mill = devices.mill();
        if mill.flags & WARNING != 0 {
            warned_at.get_or_insert(streaming.elapsed());
        }
        if mill.flags & ALARM != 0 {
            alarmed = Some((streaming.elapsed(), mill));
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    let (alarmed_at, mill) = alarmed.unwrap_or_else(|| unreachable!());
    let warned_at = warned_at.expect("the warning bit came on, before or with the alarm");
    println!(
        "sync at {SYNC_S} s: warning at {:.2} s, alarm at {:.2} s: {mill:?}",
        warned_at.as_secs_f64(),
        alarmed_at.as_secs_f64()
    );
    assert!(warned_at <= alarmed_at);
    assert!(
        alarmed_at.as_secs_f64() > SYNC_S,
        "alarm before the coupling started"
    );
    assert_eq!(mill.quality, 0b111, "{mill:?}");
    assert_eq!(mill.flags & STALE, 0, "{mill:?}");
    assert!(mill.sigma_n_hz <= SIGMA_MIN_HZ as f32, "{mill:?}");
    assert!(mill.k_mean >= K_MAX as f32, "{mill:?}");
    assert!(
        (f64::from(mill.chatter_hz) - COMMON_HZ).abs() < SIGMA_MIN_HZ,
        "{mill:?}"
    );

    gateway.stop().await?;
    for device in devices.running {
        device.stop().await?;
    }
    Ok(())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn stopped_stand_daq_flags_stale_and_clears_quality() -> anyhow::Result<()> {
    let signals = stand_signals(Regime::Independent, 30.0, 22)?;
    // Stands 1-4 on DAQ 0, stand 5 on DAQ 1.
    let mut config = config([0, 0, 0, 0, 1])?;
    let daqs = vec![daq(&signals, &[0, 1, 2, 3]), daq(&signals, &[4])];
    let mut devices = start(&mut config, daqs).await?;
    let gateway = millgate::Service::new(config)?.spawn().await?;
    let metrics = gateway.bound().metrics.expect("metrics configured");

    wait_for("valid chatter values", Duration::from_secs(5), || {
        devices.mill().quality == 0b111
    })
    .await;
    let mill = devices.mill();
    assert_eq!(mill.flags & STALE, 0, "{mill:?}");
    let page = scrape(metrics).await?;
    let evaluations = metric(&page, "millgate_chatter_evaluations_total{mill=\"TCM\"}");
    assert!(evaluations.is_some_and(|n| n >= 1.0), "{page}");
    assert!(
        metric(&page, "millgate_chatter_k_mean{mill=\"TCM\"}").is_some(),
        "{page}"
    );

    // Stand 5's DAQ goes away; stands 1-4 keep streaming.
    let stand5 = devices.running.remove(1);
    let stopped = Instant::now();
    stand5.stop().await?;
    wait_for("stale bit, quality cleared", Duration::from_secs(5), || {
        let mill = devices.mill();
        mill.flags & STALE != 0 && mill.quality == 0
    })
    .await;
    println!(
        "stale flagged {:.2} s after the DAQ stopped",
        stopped.elapsed().as_secs_f64()
    );
    // Invalid values read 0, never the last good ones, and stay so.
    for _ in 0..10 {
        let mill = devices.mill();
        assert_eq!((mill.flags & STALE, mill.quality), (STALE, 0), "{mill:?}");
        assert_eq!(
            (mill.sigma_n_hz, mill.k_mean, mill.chatter_hz),
            (0.0, 0.0, 0.0)
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    let page = scrape(metrics).await?;
    assert!(
        metric(&page, "millgate_chatter_k_mean{mill=\"TCM\"}").is_none(),
        "no K_mean gauge while stale: {page}"
    );

    gateway.stop().await?;
    for device in devices.running {
        device.stop().await?;
    }
    Ok(())
}
