//! The DAQ cable pulled: the virtual DAQ is stopped mid-run and restarted on the
//! same port. The source goes stale and comes back, the counters show the gap, the
//! gateway keeps running, and no sample is invented.

use std::net::SocketAddr;
use std::time::{Duration, Instant};

use millgate::field::source_health::SourceStatus;
use millgate_config::{Config, RegisterTable};
use millgate_sim::devices::modbus_bank::{Running, ServeOptions};
use millgate_sim::devices::virtual_daq::{DaqChannel, Placement, Publish, VirtualDaq};
use millgate_tests::{scrape, wait_for};
use tokio::net::TcpListener;

const SAMPLES_PER_BLOCK: u16 = 100;

fn daq(config: &Config) -> VirtualDaq {
    let channel = &config.channels[0];
    let signal = (0..200_000).map(|i| f64::from(i % 1000) * 0.05).collect();
    VirtualDaq::new(
        channel.sample_rate_hz,
        SAMPLES_PER_BLOCK,
        vec![DaqChannel {
            placement: Placement {
                table: RegisterTable::Input,
                address: 0,
                scale: channel.scale,
                offset: channel.offset,
            },
            publish: Publish::Block,
            signal,
        }],
    )
}

async fn start_daq(config: &Config, address: SocketAddr) -> anyhow::Result<Running> {
    let options = ServeOptions {
        unit_id: 1,
        single_connection: true,
    };
    Ok(daq(config).spawn(TcpListener::bind(address).await?, options))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn daq_restart_goes_stale_then_ok_and_counts_the_gap() -> anyhow::Result<()> {
    let mut config = millgate_sim::devices::demo::setup(1.0, 0.0, 1)?.config;
    config.outputs.plc = None;
    config.outputs.server = None;
    config.outputs.metrics = Some(millgate_config::MetricsOutput {
        bind: "127.0.0.1:0".parse()?,
    });
    // Reserve a port for both lives of the DAQ.
    let address = TcpListener::bind("127.0.0.1:0").await?.local_addr()?;
    config.modbus_sources[0].address = address.to_string();

    let daq_device = start_daq(&config, address).await?;
    let gateway = millgate::Service::new(config.clone())?.spawn().await?;
    let metrics = gateway.bound().metrics.expect("metrics configured");
    let counters = gateway.counters()[0].clone();
    let publisher = gateway.publisher();
    let status = || publisher.results().sources[0];

    wait_for("first blocks", Duration::from_secs(5), || {
        counters.snapshot().blocks_read >= 5 && status() == Some(SourceStatus::Ok)
    })
    .await;

    daq_device.stop().await?;
    let pulled = Instant::now();
    wait_for(
        "stale after the DAQ stopped",
        Duration::from_secs(5),
        || matches!(status(), Some(SourceStatus::Stale | SourceStatus::Lost)),
    )
    .await;
    let before_restart = counters.snapshot();
    tokio::time::sleep(Duration::from_millis(1500).saturating_sub(pulled.elapsed())).await;

    let daq_device = start_daq(&config, address).await?;
    wait_for("ok again after restart", Duration::from_secs(10), || {
        status() == Some(SourceStatus::Ok)
            && counters.snapshot().blocks_read > before_restart.blocks_read + 3
    })
    .await;
    let after = counters.snapshot();
    assert!(!gateway.is_finished(), "the gateway kept running");
    assert!(
        after.blocks_missed >= 10,
        "a 1.5 s outage at 50 ms blocks: {after:?}"
    );
    assert_eq!(
        after.samples,
        after.blocks_read * u64::from(SAMPLES_PER_BLOCK),
        "samples passed on are exactly those of the blocks read: {after:?}"
    );

    // The same counters on the Prometheus endpoint, per channel and per source.
    let page = scrape(metrics).await?;
    let missed = "millgate_channel_blocks_missed_total{channel=\"spindle_top\"} ";
    let line = page
        .lines()
        .find(|l| l.starts_with(missed))
        .unwrap_or_else(|| panic!("{page}"));
    let shown: u64 = line[missed.len()..].parse()?;
    assert!(shown >= after.blocks_missed, "{line} vs {after:?}");
    assert!(
        page.contains("millgate_source_status{source=\"daq1\",status=\"ok\"} 0"),
        "{page}"
    );
    assert!(
        page.contains("millgate_source_connects_total{source=\"daq1\"} 2"),
        "{page}"
    );

    tokio::time::timeout(Duration::from_secs(10), gateway.stop()).await??;
    daq_device.stop().await?;
    Ok(())
}
