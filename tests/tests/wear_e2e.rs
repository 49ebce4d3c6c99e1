//! Wear index end to end: a virtual DAQ streams simulated bars of the Table 2
//! driveline over Modbus TCP, the gateway (with the driveline model) analyses them,
//! and an HMI reads `wear_index` / `wear_trend` from the gateway's Modbus server and
//! resets the trend with `command.reset_wear_trend` (tokio-modbus, then `mbpoll`).

use std::net::SocketAddr;
use std::path::PathBuf;
use std::process::Command;
use std::time::Duration;

use millgate::analysis::driveline::BiteReport;
use millgate::outputs::modbus::register_map::{decode_f32, RegisterMap};
use millgate::service::RunningService;
use millgate_sim::devices::demo::DemoDevices;
use millgate_sim::model::Model;
use millgate_sim::schedule::{rolling_schedule, BarTiming};
use millgate_tests::kit::demo_devices;
use tokio_modbus::client::{Context, Reader, Writer};
use tokio_modbus::prelude::{ExceptionCode, Slave};

const MODEL: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../sim/models/table2-adjusted-backlash.toml"
);
/// Static torques of the bars, kN*m.
const BARS_KNM: [f64; 3] = [112.0, 60.0, 112.0];
const TIMING: BarTiming = BarTiming {
    idle_s: 0.6,
    rolling_s: 1.2,
};
/// Bound on |wear index| of a driveline without gap (0.5 kN*m RMS noise).
const NO_GAP_BOUND: f64 = 0.03;
const WEAR_INDEX_BIT: u16 = 1 << 7;
const WEAR_TREND_BIT: u16 = 1 << 8;

fn address(map: &RegisterMap, name: &str) -> u16 {
    map.registers()
        .iter()
        .find(|r| r.name == name)
        .unwrap_or_else(|| panic!("no register {name}"))
        .address
}

/// A running gateway with the driveline model, fed bars simulated with a gap of
/// `gap_rad` in the spindles.
struct Mill {
    devices: DemoDevices,
    server: SocketAddr,
    map: RegisterMap,
    gateway: RunningService,
}

impl Mill {
    async fn start(gap_rad: f64) -> anyhow::Result<Self> {
        let mut model = Model::load(MODEL)?;
        model.couplings[1].backlash = gap_rad;
        let schedule = rolling_schedule(&model, &BARS_KNM, TIMING, 0.5, 11)?;
        let mut config = millgate_sim::devices::demo::setup(1.0, 0.5, 1)?.config;
        config.drivelines[0].model = Some(PathBuf::from(MODEL));
        let devices = demo_devices(&mut config, &schedule).await?;
        let gateway = millgate::Service::new(config)?.spawn().await?;
        Ok(Self {
            devices,
            server: gateway.bound().server.expect("server configured"),
            map: (*gateway.register_map()).clone(),
            gateway,
        })
    }

    async fn next_bite(&mut self) -> anyhow::Result<BiteReport> {
        Ok(tokio::time::timeout(Duration::from_secs(10), self.gateway.bites().recv()).await??)
    }

    async fn hmi(&self) -> anyhow::Result<Context> {
        Ok(tokio_modbus::client::tcp::connect_slave(self.server, Slave(1)).await?)
    }

    async fn stop(self) -> anyhow::Result<()> {
        tokio::time::timeout(Duration::from_secs(10), self.gateway.stop()).await??;
        Ok(self.devices.stop().await?)
    }
}

/// Read an f32 register and the driveline's quality word over Modbus.
async fn read_f32(hmi: &mut Context, map: &RegisterMap, name: &str) -> anyhow::Result<f32> {
    let words = hmi.read_holding_registers(address(map, name), 2).await??;
    decode_f32(&words).ok_or_else(|| anyhow::anyhow!("{name}: not an f32"))
}

async fn quality(hmi: &mut Context, map: &RegisterMap) -> anyhow::Result<u16> {
    Ok(hmi
        .read_holding_registers(address(map, "F1.quality"), 1)
        .await??[0])
}

/// The quality bits once a reset command written to the HMI is applied, or 5 s
/// after: the analysis applies the command from its command channel, in order with the
/// samples, so at once but after the write's answer (reading the bits right after it
/// raced the analysis, once, in a rehearsal).
async fn after_reset(hmi: &mut Context, map: &RegisterMap) -> anyhow::Result<u16> {
    let applied = tokio::time::Instant::now();
    loop {
        let bits = quality(hmi, map).await?;
        if bits & WEAR_TREND_BIT == 0 || applied.elapsed() > Duration::from_secs(5) {
            return Ok(bits);
        }
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
}

/// Wait until the HMI sees the bite counter at `count`.
async fn wait_bites(hmi: &mut Context, map: &RegisterMap, count: u32) -> anyhow::Result<()> {
    let counter = address(map, "F1.bite_counter");
    tokio::time::timeout(Duration::from_secs(5), async {
        loop {
            let words = hmi.read_holding_registers(counter, 2).await??;
            if millgate::outputs::modbus::register_map::decode_u32(&words) == Some(count) {
                return anyhow::Ok(());
            }
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    })
    .await?
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn wear_index_over_modbus_grows_with_the_gap_and_the_trend_resets() -> anyhow::Result<()> {
    // Both drivelines stream at once (real time: 2 bars take about 4 s).
    let (worn, new) = tokio::join!(Mill::start(2e-3), Mill::start(0.0));
    let (mut worn, mut new) = (worn?, new?);
    let (worn_bite, new_bite) = tokio::join!(worn.next_bite(), new.next_bite());
    let (worn_bite, new_bite) = (worn_bite?, new_bite?);
    let worn_index = worn_bite.wear.expect("wear with a model").index;
    let new_index = new_bite.wear.expect("wear with a model").index;
    assert!(new_index.abs() < NO_GAP_BOUND, "no gap: {new_index}");
    assert!(worn_index > 0.1, "2 mrad gap: {worn_index}");

    // The HMI reads what the analysis found.
    let mut hmi = worn.hmi().await?;
    wait_bites(&mut hmi, &worn.map, 1).await?;
    let published = read_f32(&mut hmi, &worn.map, "F1.wear_index").await?;
    assert_eq!(published, worn_index as f32);
    let trend = read_f32(&mut hmi, &worn.map, "F1.wear_trend").await?;
    assert_eq!(trend, worn_index as f32, "the first index seeds the trend");
    let bits = quality(&mut hmi, &worn.map).await?;
    assert_eq!(
        bits & (WEAR_INDEX_BIT | WEAR_TREND_BIT),
        WEAR_INDEX_BIT | WEAR_TREND_BIT
    );
    let mut new_hmi = new.hmi().await?;
    wait_bites(&mut new_hmi, &new.map, 1).await?;
    let published_new = read_f32(&mut new_hmi, &new.map, "F1.wear_index").await?;
    assert!(published_new < published, "{published_new} vs {published}");

    // Second bar, lighter: a larger index, and the trend moves toward it.
    let second = worn.next_bite().await?.wear.expect("wear").index;
    wait_bites(&mut hmi, &worn.map, 2).await?;
    let trend = f64::from(read_f32(&mut hmi, &worn.map, "F1.wear_trend").await?);
    let expected = millgate::analysis::wear::next_trend(Some(worn_index), second);
    assert!(
        (trend - expected).abs() < 1e-5,
        "trend {trend}, expected {expected}"
    );

    // Reset: bad values are refused and change nothing, 1 (the only driveline) resets.
    let reset = address(&worn.map, "command.reset_wear_trend");
    assert_eq!(
        hmi.write_single_register(reset, 0b10).await?,
        Err(ExceptionCode::IllegalDataValue),
        "no second driveline"
    );
    assert_ne!(quality(&mut hmi, &worn.map).await? & WEAR_TREND_BIT, 0);
    assert_eq!(
        hmi.write_single_register(address(&worn.map, "F1.wear_trend"), 0)
            .await?,
        Err(ExceptionCode::IllegalDataAddress),
        "results are read-only"
    );
    hmi.write_single_register(reset, 1).await??;
    assert_eq!(hmi.read_holding_registers(reset, 1).await??, vec![0]);
    let bits = after_reset(&mut hmi, &worn.map).await?;
    assert_eq!(bits & WEAR_TREND_BIT, 0, "trend invalid after the reset");
    assert_ne!(bits & WEAR_INDEX_BIT, 0, "the last index stays valid");
    assert_eq!(read_f32(&mut hmi, &worn.map, "F1.wear_trend").await?, 0.0);

    // The next bite seeds the trend afresh.
    let third = worn.next_bite().await?.wear.expect("wear").index;
    wait_bites(&mut hmi, &worn.map, 3).await?;
    let trend = read_f32(&mut hmi, &worn.map, "F1.wear_trend").await?;
    assert_eq!(
        trend, third as f32,
        "seeded by the first bite after the reset"
    );

    // An independent Modbus master: mbpoll writes the command too.
    if Command::new("mbpoll").arg("-V").output().is_ok() {
        let port = worn.server.port().to_string();
        let reset = reset.to_string();
        let mbpoll = |value: &'static str| {
            let mut command = Command::new("mbpoll");
            command.args([
                "-m",
                "tcp",
                "-p",
                &port,
                "-a",
                "1",
                "-0",
                "-1",
                "-o",
                "2",
                "-t",
                "4",
                "-r",
                &reset,
                "127.0.0.1",
                value,
            ]);
            command
        };
        let refused = tokio::task::spawn_blocking({
            let mut command = mbpoll("4");
            move || command.output()
        })
        .await??;
        let text = String::from_utf8_lossy(&refused.stdout).to_string()
            + &String::from_utf8_lossy(&refused.stderr);
        assert!(
            text.to_lowercase().contains("illegal data value"),
            "mbpoll said: {text}"
        );
        let accepted = tokio::task::spawn_blocking({
            let mut command = mbpoll("1");
            move || command.output()
        })
        .await??;
        assert!(
            accepted.status.success(),
            "{}",
            String::from_utf8_lossy(&accepted.stderr)
        );
        let bits = after_reset(&mut hmi, &worn.map).await?;
        assert_eq!(bits & WEAR_TREND_BIT, 0, "mbpoll reset the trend");
    } else {
        println!("skipped the mbpoll part: mbpoll is not installed (scripts/test installs it)");
    }

    worn.stop().await?;
    new.stop().await
}
