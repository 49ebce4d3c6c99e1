//! The gateway's Modbus server as an HMI sees it: the map is readable, results are
//! read-only, only command registers take writes, bad requests get the documented
//! exception codes. Peers: the tokio-modbus client here, `mbpoll` (Debian) below.

use std::net::SocketAddr;
use std::process::Command;
use std::sync::Arc;
use std::time::Duration;

use millgate::outputs::modbus::register_map::RegisterMap;
use millgate_sim::devices::demo::setup;
use millgate_tests::kit::wait_for;
use tokio_modbus::client::{Context, Reader, Writer};
use tokio_modbus::prelude::{ExceptionCode, Slave};

struct Running {
    address: SocketAddr,
    map: RegisterMap,
    board: std::sync::Arc<millgate::state::board::Board>,
    gateway: millgate::service::RunningService,
}

/// A gateway with the demo configuration, its DAQ unreachable and its PLC
/// unreachable (`plc`) or not configured (the server must work regardless), its
/// Modbus server on a free loopback port.
async fn gateway(plc: bool) -> anyhow::Result<Running> {
    let mut config = setup(1.0, 0.0, 1)?.config;
    config.modbus_sources[0].address = "127.0.0.1:1".into();
    if let Some(output) = config.outputs.plc.as_mut() {
        output.address = "127.0.0.1:1".into();
    }
    if !plc {
        config.outputs.plc = None;
    }
    config.outputs.server.as_mut().unwrap().bind = "127.0.0.1:0".parse()?;
    let gateway = millgate::Service::new(config)?.spawn().await?;
    let board = gateway.board();
    Ok(Running {
        address: gateway.bound().server.expect("server configured"),
        map: (*gateway.register_map()).clone(),
        board,
        gateway,
    })
}

async fn client(address: SocketAddr) -> anyhow::Result<Context> {
    Ok(tokio_modbus::client::tcp::connect_slave(address, Slave(1)).await?)
}

#[tokio::test]
async fn map_reads_and_command_writes_with_exception_codes() -> anyhow::Result<()> {
    let running = gateway(true).await?;
    let mut hmi = client(running.address).await?;
    let len = running.map.len();

    let whole = hmi.read_holding_registers(0, len.min(125)).await??;
    assert_eq!(whole.len(), usize::from(len.min(125)));
    assert_eq!(whole[1] & 1, 1, "status: running");
    assert_eq!(whole[4] & 1, 1, "source 0 (unreachable DAQ) is lost");
    let input = hmi.read_input_registers(0, 5).await??;
    assert_eq!(input[1], whole[1], "FC 04 serves the same map");

    assert_eq!(
        hmi.read_holding_registers(len - 1, 2).await?,
        Err(ExceptionCode::IllegalDataAddress),
        "read past the map"
    );
    let taf = running
        .map
        .registers()
        .iter()
        .find(|r| r.name == "F1.taf")
        .unwrap();
    assert_eq!(
        hmi.write_single_register(taf.address, 1).await?,
        Err(ExceptionCode::IllegalDataAddress),
        "results are read-only"
    );
    assert_eq!(
        hmi.read_coils(0, 1).await?,
        Err(ExceptionCode::IllegalFunction),
        "no coils"
    );

    running.board.update(|r| r.drivelines[0].taf_alarm = true);
    let ack = running
        .map
        .registers()
        .iter()
        .find(|r| r.name == "command.acknowledge_alarms")
        .unwrap()
        .address;
    assert_eq!(
        hmi.write_single_register(ack, 7).await?,
        Err(ExceptionCode::IllegalDataValue),
        "bad command value"
    );
    assert!(
        running.board.results().drivelines[0].taf_alarm,
        "rejected write changed nothing"
    );
    hmi.write_single_register(ack, 1).await??;
    let board = Arc::clone(&running.board);
    wait_for(
        "acknowledged by the analysis",
        Duration::from_secs(5),
        || !board.results().drivelines[0].taf_alarm,
    )
    .await;

    tokio::time::timeout(Duration::from_secs(10), running.gateway.stop()).await??;
    Ok(())
}

/// Run `mbpoll` once against `server`: 0-based addresses (-0), one poll (-1),
/// unit 1, 2 s timeout, plus `args`; stdout and stderr together.
async fn mbpoll(server: SocketAddr, args: &[&str]) -> anyhow::Result<(bool, String)> {
    let mut command = Command::new("mbpoll");
    command.args([
        "-m",
        "tcp",
        "-p",
        &server.port().to_string(),
        "-a",
        "1",
        "-0",
        "-1",
        "-o",
        "2",
    ]);
    command.args(args).arg(server.ip().to_string());
    let output = tokio::task::spawn_blocking(move || command.output()).await??;
    let text = String::from_utf8_lossy(&output.stdout).to_string()
        + &String::from_utf8_lossy(&output.stderr);
    Ok((output.status.success(), text))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn mbpoll_reads_the_map_and_sees_exceptions() -> anyhow::Result<()> {
    assert!(
        Command::new("mbpoll").arg("-V").output().is_ok(),
        "mbpoll is not installed: scripts/test installs it (apt-get install mbpoll)"
    );
    let running = gateway(true).await?;
    let (ok, text) = mbpoll(running.address, &["-t", "4", "-r", "0", "-c", "5"]).await?;
    assert!(ok, "mbpoll failed: {text}");
    // mbpoll prints "[1]: \t5" for register 1, gateway_status: bit0 running, bit2
    // a source problem (the DAQ here is unreachable on purpose).
    let status: u16 = text
        .lines()
        .find_map(|l| l.trim_start().strip_prefix("[1]:"))
        .and_then(|v| v.trim().parse().ok())
        .unwrap_or_else(|| panic!("no register 1 in {text}"));
    assert_eq!(status, 0b101, "running, source problem");

    let past = (running.map.len() + 10).to_string();
    let (_, text) = mbpoll(running.address, &["-t", "4", "-r", &past, "-c", "1"]).await?;
    assert!(
        text.to_lowercase().contains("illegal data address"),
        "mbpoll said: {text}"
    );

    tokio::time::timeout(Duration::from_secs(10), running.gateway.stop()).await??;
    Ok(())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn heartbeat_moves_with_the_plc_unreachable_or_absent() -> anyhow::Result<()> {
    for plc in [true, false] {
        let running = gateway(plc).await?;
        let mut hmi = client(running.address).await?;
        let first = hmi.read_holding_registers(0, 1).await??[0];
        // The PLC's write period is 100 ms; without a PLC the heartbeat moves each
        // second.
        let deadline = tokio::time::Instant::now() + Duration::from_secs(3);
        let mut now = first;
        while now == first && tokio::time::Instant::now() < deadline {
            tokio::time::sleep(Duration::from_millis(100)).await;
            now = hmi.read_holding_registers(0, 1).await??[0];
        }
        assert_ne!(
            now, first,
            "heartbeat frozen at {first} (PLC configured: {plc})"
        );
        tokio::time::timeout(Duration::from_secs(10), running.gateway.stop()).await??;
    }
    Ok(())
}
