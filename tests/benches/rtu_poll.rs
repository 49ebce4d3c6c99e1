//! Modbus RTU poll timing: the poll period the real `DaqReader` reaches against a
//! pymodbus RTU device, beside the time the frames and silences take on the line
//! (`millgate_config::serial`: what `millgate check` holds a poll plan against).
//!
//! The line is a [`PacedLine`]: two socat pseudo-terminal pairs joined by relays that
//! hand on each byte no sooner than the baud rate allows, 8N2 (11 bits a character,
//! the specification's format without parity; a pseudo-terminal refuses parity). The
//! device is `peers/pymodbus_rtu_device.py` in its firehose mode, so every read of
//! the block is a new block and every poll is counted. The reader's poll period is
//! set to 1 us after validation, so it polls as fast as the line lets it. One read per
//! poll: a 2-register process value, or a whole 122-register block.
//!
//!     cargo bench -p millgate-tests --bench rtu_poll
//!
//! Columns: baud rate, registers per read, the request and response frames on the
//! line, the two inter-frame silences the reader keeps, their sum (the computed poll
//! time), the measured poll period, and what the measurement adds (the device's
//! turnaround, the relays, tokio's millisecond timer rounding up the silence).

use std::sync::Arc;
use std::time::{Duration, Instant};

use millgate::field::counters::ChannelCounters;
use millgate::field::modbus::DaqReader;
use millgate::field::source_health::SourceHealth;
use millgate_config::serial::{read_response_bytes, READ_REQUEST_BYTES};
use millgate_tests::kit::serial_line::{PacedLine, RtuDevice, SPEED_REGISTER};

const UNIT: u8 = 3;
/// How long each case polls after its first read.
const RUN: Duration = Duration::from_secs(4);

/// A configuration with one RTU source at `baud` Bd 8N2 on `device` and one channel:
/// the f32 process value at `SPEED_REGISTER` or the block at register 0.
fn config(
    device: &std::path::Path,
    baud: u32,
    block: bool,
) -> anyhow::Result<millgate_config::Config> {
    let channel = if block {
        "kind = \"acceleration\"\nunit = \"m/s^2\"\nsample_rate_hz = 10.0\n\
         source = { modbus = \"line\", table = \"input\", block = 0 }"
            .to_owned()
    } else {
        format!(
            "kind = \"process_value\"\nunit = \"1\"\n\
             source = {{ modbus = \"line\", table = \"holding\", address = {SPEED_REGISTER}, type = \"f32\" }}"
        )
    };
    let text = format!(
        "name = \"bench\"\n[[sources.modbus]]\nname = \"line\"\ndevice = \"{}\"\n\
         baud_rate = {baud}\nparity = \"none\"\nstop_bits = 2\nunit_id = {UNIT}\n\
         poll_period_ms = 1000\ntimeout_ms = 2000\n\
         [[channels]]\nname = \"read\"\n{channel}\n",
        device.display()
    );
    let mut config =
        millgate_config::from_toml_str(&text, "bench.toml", std::path::Path::new("."))?;
    config.modbus_sources[0].poll_period = Duration::from_micros(1);
    Ok(config)
}

/// Reads counted over `RUN` after the first: the measured poll period.
async fn measure(baud: u32, block: bool) -> anyhow::Result<(u16, Duration, Duration, Duration)> {
    // The line's settings first, then the line at their pace.
    let mut config = config(std::path::Path::new("/dev/null"), baud, block)?;
    let line = config.modbus_sources[0].serial.expect("an RTU source");
    let paced = PacedLine::open(line.frame_time(1))?;
    config.modbus_sources[0].address = paced.gateway_side.gateway.display().to_string();
    let _device = RtuDevice::firehose(&paced.device_side.device, baud, 2, UNIT)?;
    let counters = vec![Arc::new(ChannelCounters::default())];
    let health = Arc::new(SourceHealth::new(
        Duration::from_secs(5),
        Duration::from_secs(10),
    ));
    let reader = DaqReader::new(&config, 0, &counters, health);
    let (samples, mut messages) = tokio::sync::mpsc::channel(1024);
    let (stop, shutdown) = millgate::shutdown::channel();
    let reading = tokio::spawn(reader.run(samples, shutdown));
    let draining = tokio::spawn(async move { while messages.recv().await.is_some() {} });
    let reads = || counters[0].snapshot().blocks_read;
    let start = Instant::now();
    while reads() == 0 {
        anyhow::ensure!(
            start.elapsed() < Duration::from_secs(20),
            "no read in 20 s: {:?}",
            counters[0].snapshot()
        );
        tokio::time::sleep(Duration::from_millis(1)).await;
    }
    let (first, from) = (reads(), Instant::now());
    tokio::time::sleep(RUN).await;
    let (last, to) = (reads(), Instant::now());
    stop.trigger();
    reading.await?;
    draining.await?;
    let snapshot = counters[0].snapshot();
    anyhow::ensure!(
        snapshot.errors == 0 && snapshot.timeouts == 0,
        "failed reads: {snapshot:?}"
    );
    anyhow::ensure!(last > first, "no reads in {RUN:?}");
    let registers = if block {
        millgate_config::layout::BLOCK_REGISTERS
    } else {
        2
    };
    let frames = line.frame_time(READ_REQUEST_BYTES + read_response_bytes(registers));
    let measured = (to - from) / u32::try_from(last - first)?;
    Ok((registers, frames, line.read_time(registers), measured))
}

#[tokio::main(flavor = "multi_thread", worker_threads = 2)]
async fn main() -> anyhow::Result<()> {
    // `cargo bench` passes --bench; nothing to parse.
    let ms = |duration: Duration| duration.as_secs_f64() * 1e3;
    println!(
        "| baud | registers | frames ms | silences ms | computed ms | measured ms | added ms |"
    );
    println!("|---:|---:|---:|---:|---:|---:|---:|");
    for baud in [9600, 19_200, 115_200] {
        for block in [false, true] {
            let (registers, frames, computed, measured) = measure(baud, block).await?;
            println!(
                "| {baud} | {registers} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} |",
                ms(frames),
                ms(computed - frames),
                ms(computed),
                ms(measured),
                ms(measured) - ms(computed)
            );
        }
    }
    Ok(())
}
