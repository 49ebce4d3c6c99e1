//! Modbus RTU sources against a device that is not ours: pymodbus' RTU server on one
//! end of a socat pseudo-terminal pair, the gateway on the other (parity none: a
//! pseudo-terminal refuses parity settings).
//!
//! - The DAQ reader reads the device's process values and its sample block; the
//!   device is killed (the cable pulled: the source goes stale, then lost, timeouts
//!   counted) and started again with the same clock: the blocks missed meanwhile are
//!   a gap of exactly the samples the device's ramp skipped, and the source is ok.
//! - The whole service with a PLC: a line that answers garbage, then nothing, then a
//!   device again: errors and timeouts counted, the service and its PLC writes go on,
//!   the PLC sees the source lost and then ok.

use std::io::{Read, Write};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use millgate::field::acquired::Acquired;
use millgate::field::counters::ChannelCounters;
use millgate::field::modbus::DaqReader;
use millgate::field::source_health::{SourceHealth, SourceStatus};
use millgate_config::Config;
use millgate_sim::devices::modbus_bank::ServeOptions;
use millgate_sim::devices::virtual_plc::VirtualPlc;
use millgate_tests::kit::serial_line::{
    junk_reply, next_sample, unix_now, PtyPair, RtuDevice, BLOCK_SAMPLES, COUNT_REGISTER,
    SPEED_REGISTER,
};
use millgate_tests::kit::wait_for;
use tokio::net::TcpListener;

const UNIT: u8 = 7;
const BAUD: u32 = 115_200;

/// An RTU source on `device` at 115 200 Bd 8N1 polled every 50 ms, with the device's
/// speed, its count and its sample block (20 samples per 100 ms: 200 Hz); `extra`
/// appended (outputs).
fn config(device: &std::path::Path, extra: &str) -> anyhow::Result<Config> {
    let text = format!(
        r#"
name = "RTU line"

[[sources.modbus]]
name = "drive"
device = "{}"
baud_rate = {BAUD}
parity = "none"
stop_bits = 1
unit_id = {UNIT}
poll_period_ms = 50
timeout_ms = 200

[[channels]]
name = "speed"
kind = "process_value"
unit = "m/s"
source = {{ modbus = "drive", table = "holding", address = {SPEED_REGISTER}, type = "f32" }}

[[channels]]
name = "count"
kind = "process_value"
unit = "1"
source = {{ modbus = "drive", table = "holding", address = {COUNT_REGISTER}, type = "u16" }}

[[channels]]
name = "vibration"
kind = "acceleration"
unit = "m/s^2"
sample_rate_hz = 200.0
source = {{ modbus = "drive", table = "input", block = 0 }}
{extra}"#,
        device.display()
    );
    Ok(millgate_config::from_toml_str(
        &text,
        "rtu.toml",
        std::path::Path::new("."),
    )?)
}

/// What the reader sent, in order.
#[derive(Debug, Default)]
struct Received {
    speed: Vec<f64>,
    count: Vec<f64>,
    /// The block channel's stream: `Ok(sample)`, or `Err(missed)` for a gap of
    /// `missed` samples.
    stream: Vec<Result<i64, u64>>,
}

impl Received {
    fn record(&mut self, message: Acquired) {
        match message {
            Acquired::ProcessValue { channel: 0, value } => self.speed.push(value),
            Acquired::ProcessValue { channel: 1, value } => self.count.push(value),
            Acquired::Samples {
                channel: 2, values, ..
            } => self
                .stream
                .extend(values.into_iter().map(|value| Ok(value as i64))),
            Acquired::Gap {
                channel: 2,
                missed_samples,
            } => self.stream.push(Err(missed_samples.unwrap_or(u64::MAX))),
            other => panic!("unexpected message {other:?}"),
        }
    }

    fn samples(&self) -> usize {
        self.stream.iter().filter(|item| item.is_ok()).count()
    }

    /// Checks the block stream against the device's ramp: each sample follows the
    /// one before, and after a gap of `m` samples it is `m` steps further on. Returns
    /// the gaps' sizes.
    fn check_ramp(&self) -> Vec<u64> {
        let mut gaps = Vec::new();
        let mut last: Option<i64> = None;
        let mut skipped = 0;
        for item in &self.stream {
            match *item {
                Err(missed) => {
                    gaps.push(missed);
                    skipped += missed;
                }
                Ok(value) => {
                    if let Some(last) = last {
                        let mut expected = next_sample(last);
                        for _ in 0..skipped {
                            expected = next_sample(expected);
                        }
                        assert_eq!(value, expected, "after {last} and a gap of {skipped}");
                    }
                    last = Some(value);
                    skipped = 0;
                }
            }
        }
        gaps
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn reads_a_pymodbus_rtu_device_and_rides_out_a_pulled_cable() -> anyhow::Result<()> {
    let pair = PtyPair::open()?;
    let epoch = unix_now();
    let device = RtuDevice::start(&pair.device, BAUD, 1, UNIT, epoch)?;
    let config = config(&pair.gateway, "")?;
    let counters: Vec<Arc<ChannelCounters>> =
        (0..config.channels.len()).map(|_| Arc::default()).collect();
    let health = Arc::new(SourceHealth::new(
        Duration::from_millis(400),
        Duration::from_millis(1200),
    ));
    let reader = DaqReader::new(&config, 0, &counters, Arc::clone(&health));
    let (samples, mut messages) = tokio::sync::mpsc::channel(1024);
    let (stop, shutdown) = millgate::shutdown::channel();
    let reading = tokio::spawn(reader.run(samples, shutdown));
    let received = Arc::new(Mutex::new(Received::default()));
    let recording = {
        let received = Arc::clone(&received);
        tokio::spawn(async move {
            while let Some(message) = messages.recv().await {
                received.lock().unwrap().record(message);
            }
        })
    };
    let block = Arc::clone(&counters[2]);

    wait_for("ten blocks", Duration::from_secs(10), || {
        block.snapshot().blocks_read >= 10
    })
    .await;
    assert_eq!(health.status(), SourceStatus::Ok);
    {
        let received = received.lock().unwrap();
        assert!(
            received.speed.iter().all(|&speed| speed == 12.5),
            "{:?}",
            received.speed
        );
        assert!(received.count.iter().all(|&count| count == 4242.0));
        assert!(!received.speed.is_empty() && !received.count.is_empty());
        received.check_ramp();
    }

    // The cable pulled: the device gone, the line silent.
    device.stop();
    wait_for("stale", Duration::from_secs(5), || {
        health.status() == SourceStatus::Stale
    })
    .await;
    wait_for("lost", Duration::from_secs(5), || {
        health.status() == SourceStatus::Lost
    })
    .await;
    assert!(block.snapshot().timeouts >= 1, "{:?}", block.snapshot());
    let blocks_before = block.snapshot().blocks_read;

    // Plugged back: the device has gone on sampling meanwhile (its clock from epoch).
    let _device = RtuDevice::start(&pair.device, BAUD, 1, UNIT, epoch)?;
    wait_for("blocks again", Duration::from_secs(10), || {
        block.snapshot().blocks_read >= blocks_before + 5
    })
    .await;
    wait_for("ok again", Duration::from_secs(5), || {
        health.status() == SourceStatus::Ok
    })
    .await;
    stop.trigger();
    tokio::time::timeout(Duration::from_secs(5), reading).await??;
    recording.await?;

    let received = received.lock().unwrap();
    let gaps = received.check_ramp();
    let counts = block.snapshot();
    // The outage lasted over a second: more than ten blocks missed, counted as missed
    // (not as a restart: the device's sequence went on) and marked as one gap whose
    // size the ramp confirms.
    let outage: u64 = gaps.iter().max().copied().unwrap_or(0);
    assert!(outage >= 10 * BLOCK_SAMPLES, "gaps {gaps:?}");
    assert_eq!(counts.sequence_restarts, 0);
    assert_eq!(
        counts.blocks_missed * BLOCK_SAMPLES,
        gaps.iter().sum::<u64>(),
        "{counts:?}"
    );
    assert_eq!(counts.samples, received.samples() as u64);
    assert!(health.connects() >= 2, "reconnected");
    Ok(())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn garbage_and_silence_on_the_line_are_counted_and_the_plc_writes_go_on() -> anyhow::Result<()>
{
    let pair = PtyPair::open()?;
    let plc_listener = TcpListener::bind("127.0.0.1:0").await?;
    let plc_address = plc_listener.local_addr()?;
    let config = config(
        &pair.gateway,
        &format!("\n[outputs.plc]\naddress = \"{plc_address}\"\nwrite_period_ms = 100\n"),
    )?;
    let map = millgate::outputs::modbus::register_map::RegisterMap::new(&config);
    let plc = VirtualPlc::new(usize::from(map.len()));
    let running_plc = plc.spawn(plc_listener, ServeOptions::default());

    // The line's far end answers garbage until told to fall silent.
    let garbage = Arc::new(AtomicBool::new(true));
    let hostile = {
        let garbage = Arc::clone(&garbage);
        let mut line = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .open(&pair.device)?;
        std::thread::spawn(move || {
            let mut buffer = [0u8; 256];
            let mut turn = 0;
            while garbage.load(Ordering::Relaxed) {
                let Ok(read) = line.read(&mut buffer) else {
                    break;
                };
                if !garbage.load(Ordering::Relaxed) {
                    break;
                }
                let _ = line.write_all(&junk_reply(turn, &buffer[..read], UNIT));
                turn += 1;
            }
            turn
        })
    };

    let gateway = millgate::Service::new(config)?.spawn().await?;
    let counters = gateway.counters().to_vec();
    let failures = || {
        counters
            .iter()
            .map(|c| {
                let s = c.snapshot();
                (s.errors, s.timeouts)
            })
            .fold((0, 0), |(e, t), (de, dt)| (e + de, t + dt))
    };
    wait_for("errors and timeouts", Duration::from_secs(15), || {
        let (errors, timeouts) = failures();
        errors >= 3 && timeouts >= 2
    })
    .await;
    let writes = plc.writes();
    wait_for("PLC writes go on", Duration::from_secs(5), || {
        plc.writes() >= writes + 3
    })
    .await;
    assert!(!gateway.is_finished(), "the service runs");
    assert_eq!(plc.holding()[4] & 1, 1, "the PLC sees the source lost");
    assert_eq!(
        counters[2].snapshot().blocks_read,
        0,
        "no garbage read as data"
    );

    // Then silence (the hostile end stops answering; it leaves at its next read).
    garbage.store(false, Ordering::Relaxed);
    let (_, timeouts) = failures();
    wait_for("timeouts in the silence", Duration::from_secs(15), || {
        failures().1 >= timeouts + 2
    })
    .await;
    let turns = hostile
        .join()
        .map_err(|_| anyhow::anyhow!("hostile end panicked"))?;
    assert!(turns >= 5, "{turns} requests answered with garbage");
    let writes = plc.writes();
    wait_for("PLC writes go on", Duration::from_secs(5), || {
        plc.writes() >= writes + 3
    })
    .await;

    // A real device on the line: the source recovers, the PLC sees it ok.
    let _device = RtuDevice::start(&pair.device, BAUD, 1, UNIT, unix_now())?;
    wait_for(
        "the PLC sees the source ok",
        Duration::from_secs(15),
        || {
            let holding = plc.holding();
            holding[2] & 1 == 1 && holding[4] & 1 == 0
        },
    )
    .await;
    assert!(counters[2].snapshot().blocks_read >= 1);
    assert!(gateway.board().results().heartbeat > 0);
    tokio::time::timeout(Duration::from_secs(10), gateway.stop()).await??;
    assert_eq!(plc.holding()[1] & 0b10, 0b10, "final write: stopped");
    running_plc.stop().await?;
    Ok(())
}
