//! Modbus acquisition throughput: samples per second the real `DaqReader` takes from
//! one block channel on loopback, against a plain tokio-modbus client loop reading
//! the same registers from the same server in the same run.
//!
//! The server is a "firehose": every read of the block returns a new block, its
//! sequence one higher than the last (n = 120), so neither side waits for the
//! device's block period and every read the reader makes is one new block
//! (`blocks_missed` stays 0). The reader's poll period is set to 1 us, below what the
//! configuration allows (1 ms), so it polls as fast as it can. Each side runs twice,
//! alternating; both run as tasks on the same two-worker runtime as the server.
//!
//!     cargo bench -p millgate --bench modbus_acquisition

use std::net::SocketAddr;
use std::sync::atomic::{AtomicU16, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{ensure, Context as _};
use millgate::field::acquired::Acquired;
use millgate::field::counters::ChannelCounters;
use millgate::field::modbus::DaqReader;
use millgate::field::source_health::SourceHealth;
use millgate_config::layout::{BLOCK_REGISTERS, MAX_BLOCK_SAMPLES};
use millgate_config::{ChannelSource, RegisterTable};
use tokio::net::{TcpListener, TcpStream};
use tokio_modbus::client::Reader;
use tokio_modbus::prelude::{ExceptionCode, Request, Response, Slave, SlaveRequest};
use tokio_modbus::server::tcp::Server;

/// How long each side reads.
const RUN: Duration = Duration::from_secs(3);
const UNIT_ID: u8 = 1;

/// One block channel whose every read is a new block of `MAX_BLOCK_SAMPLES` samples.
struct Firehose {
    base: u16,
    sequence: AtomicU16,
}

impl Firehose {
    fn block(&self) -> Vec<u16> {
        let sequence = self
            .sequence
            .fetch_add(1, Ordering::Relaxed)
            .wrapping_add(1);
        let mut registers = Vec::with_capacity(usize::from(BLOCK_REGISTERS));
        registers.push(sequence);
        registers.push(MAX_BLOCK_SAMPLES);
        // A ramp that moves with the sequence, so no two blocks are alike.
        registers.extend((0..MAX_BLOCK_SAMPLES).map(|i| sequence.wrapping_add(i) & 0x7fff));
        registers
    }
}

impl tokio_modbus::server::Service for Firehose {
    type Request = SlaveRequest<'static>;
    type Response = Response;
    type Exception = ExceptionCode;
    type Future = std::future::Ready<Result<Response, ExceptionCode>>;

    fn call(&self, request: Self::Request) -> Self::Future {
        std::future::ready(match request.request {
            Request::ReadInputRegisters(address, BLOCK_REGISTERS) if address == self.base => {
                Ok(Response::ReadInputRegisters(self.block()))
            }
            Request::ReadInputRegisters(..) => Err(ExceptionCode::IllegalDataAddress),
            _ => Err(ExceptionCode::IllegalFunction),
        })
    }
}

/// Serve a firehose block at `base` on `listener`, a fresh sequence per connection.
async fn serve_firehose(
    listener: TcpListener,
    base: u16,
    mut shutdown: millgate::shutdown::Shutdown,
) -> std::io::Result<()> {
    let on_connected = |stream: TcpStream, _peer: SocketAddr| async move {
        let _ = stream.set_nodelay(true);
        let service = Firehose {
            base,
            sequence: AtomicU16::new(0),
        };
        Ok(Some((service, stream)))
    };
    let on_process_error = |_error| {};
    Server::new(listener)
        .serve_until(&on_connected, on_process_error, async move {
            shutdown.recv().await
        })
        .await
        .map(|_| ())
}

/// Requests per second of a plain client loop, and the samples per second they carry.
async fn raw_loop(server: SocketAddr, base: u16) -> anyhow::Result<(f64, f64)> {
    let stream = TcpStream::connect(server).await?;
    // As the gateway's client does.
    stream.set_nodelay(true)?;
    let mut context = tokio_modbus::client::tcp::attach_slave(stream, Slave(UNIT_ID));
    let mut requests = 0u64;
    let mut samples = 0u64;
    let start = Instant::now();
    while start.elapsed() < RUN {
        let registers = context
            .read_input_registers(base, BLOCK_REGISTERS)
            .await??;
        requests += 1;
        samples += u64::from(registers[1]);
    }
    let elapsed_s = start.elapsed().as_secs_f64();
    Ok((requests as f64 / elapsed_s, samples as f64 / elapsed_s))
}

/// Samples per second through the real `DaqReader`, from its counters.
async fn gateway(mut config: millgate_config::Config, channel: usize) -> anyhow::Result<f64> {
    let counters: Vec<Arc<ChannelCounters>> = config
        .channels
        .iter()
        .map(|_| Arc::new(ChannelCounters::default()))
        .collect();
    let health = Arc::new(SourceHealth::new(
        Duration::from_secs(3600),
        Duration::from_secs(3600),
    ));
    // Below the configuration's 1 ms floor: poll as fast as the reader can.
    config.modbus_sources[0].poll_period = Duration::from_micros(1);
    let reader = DaqReader::new(&config, 0, &counters, Arc::clone(&health));
    let (samples_tx, mut samples_rx) = tokio::sync::mpsc::channel(1024);
    let (stop, shutdown) = millgate::shutdown::channel();
    let reader = tokio::spawn(reader.run(samples_tx, shutdown));
    let received = Arc::new(AtomicU64::new(0));
    let (first_tx, first_rx) = tokio::sync::oneshot::channel();
    let drain = tokio::spawn({
        let received = Arc::clone(&received);
        async move {
            let mut first_tx = Some(first_tx);
            let mut gaps = 0u64;
            while let Some(message) = samples_rx.recv().await {
                match message {
                    Acquired::Samples { values, .. } => {
                        received.fetch_add(values.len() as u64, Ordering::Relaxed);
                        if let Some(first) = first_tx.take() {
                            let _ = first.send(());
                        }
                    }
                    Acquired::Gap { .. } => gaps += 1,
                    Acquired::ProcessValue { .. } | Acquired::Text { .. } => {}
                }
            }
            gaps
        }
    });
    tokio::time::timeout(Duration::from_secs(5), first_rx)
        .await
        .context("DaqReader read no block")??;

    let counters = &counters[channel];
    let before = counters.snapshot();
    let start = Instant::now();
    tokio::time::sleep(RUN).await;
    let after = counters.snapshot();
    let elapsed_s = start.elapsed().as_secs_f64();
    stop.trigger();
    reader.await?;
    let gaps = drain.await?;

    let total = counters.snapshot();
    ensure!(
        total.blocks_missed == 0 && gaps == 0,
        "firehose blocks lost: {total:?}, {gaps} gaps"
    );
    ensure!(
        total.samples == total.blocks_read * u64::from(MAX_BLOCK_SAMPLES),
        "samples and blocks disagree: {total:?}"
    );
    ensure!(
        received.load(Ordering::Relaxed) == total.samples,
        "counted {} samples, received {}",
        total.samples,
        received.load(Ordering::Relaxed)
    );
    ensure!(
        total.errors == 0 && total.timeouts == 0,
        "errors: {total:?}"
    );
    ensure!(
        health.connects() == 1,
        "reconnected {} times",
        health.connects()
    );
    Ok((after.samples - before.samples) as f64 / elapsed_s)
}

#[tokio::main(flavor = "multi_thread", worker_threads = 2)]
async fn main() -> anyhow::Result<()> {
    let mut config = millgate_sim::devices::demo::setup(1.0, 0.0, 1)?.config;
    let channel = config.drivelines[0].torque;
    let ChannelSource::ModbusBlock {
        source: 0,
        table: RegisterTable::Input,
        base,
    } = config.channels[channel].source
    else {
        anyhow::bail!("the demo's torque channel must be an input-register block of source 0");
    };

    let listener = TcpListener::bind("127.0.0.1:0").await?;
    let server = listener.local_addr()?;
    config.modbus_sources[0].address = server.to_string();
    let (stop_server, server_shutdown) = millgate::shutdown::channel();
    let server_task = tokio::spawn(serve_firehose(listener, base, server_shutdown));

    println!(
        "Modbus acquisition on loopback, {BLOCK_REGISTERS} input registers per read, \
         {MAX_BLOCK_SAMPLES} samples per block, {} s per run",
        RUN.as_secs_f64()
    );
    let mut raw_rates = Vec::new();
    for round in 1..=2 {
        // Both sides run as spawned tasks on the runtime's workers, not on the
        // `block_on` thread, so they are scheduled alike.
        let (requests_per_s, raw_samples_per_s) = tokio::spawn(raw_loop(server, base)).await??;
        let gateway_samples_per_s = gateway(config.clone(), channel).await?;
        println!(
            "round {round}: raw tokio-modbus loop: {requests_per_s:.0} req/s = \
             {raw_samples_per_s:.0} samples/s; DaqReader: {gateway_samples_per_s:.0} samples/s \
             ({:.1}% of raw)",
            100.0 * gateway_samples_per_s / raw_samples_per_s
        );
        raw_rates.push((raw_samples_per_s, gateway_samples_per_s));
    }
    let raw_mean = raw_rates.iter().map(|r| r.0).sum::<f64>() / raw_rates.len() as f64;
    let gateway_mean = raw_rates.iter().map(|r| r.1).sum::<f64>() / raw_rates.len() as f64;
    println!(
        "mean: raw {raw_mean:.0} samples/s, DaqReader {gateway_mean:.0} samples/s ({:.1}% of raw; target >= 80%)",
        100.0 * gateway_mean / raw_mean
    );

    stop_server.trigger();
    server_task.await??;
    Ok(())
}
