//! The gateway against pymodbus, an independent Modbus implementation: it writes its
//! map into a pymodbus PLC, and a pymodbus HMI reads the gateway's server.

use std::io::{BufRead, BufReader, Write};
use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::time::Duration;

use millgate::outputs::modbus::register_map::{decode_f32, decode_u32, RegisterMap};
use millgate_sim::devices::demo::setup;
use millgate_tests::kit::{demo_devices, free_port};

fn peer(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("peers")
        .join(name)
}

fn address_of(map: &RegisterMap, name: &str) -> usize {
    usize::from(
        map.registers()
            .iter()
            .find(|r| r.name == name)
            .unwrap()
            .address,
    )
}

/// The pymodbus PLC's holding registers 0..len, read over Modbus.
async fn read_plc(port: u16, len: u16) -> anyhow::Result<Vec<u16>> {
    use tokio_modbus::client::Reader;
    let address = std::net::SocketAddr::from(([127, 0, 0, 1], port));
    let mut client =
        tokio_modbus::client::tcp::connect_slave(address, tokio_modbus::Slave(1)).await?;
    let mut words = Vec::new();
    for start in (0..len).step_by(125) {
        words.extend(
            client
                .read_holding_registers(start, (len - start).min(125))
                .await??,
        );
    }
    Ok(words)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn gateway_writes_its_map_into_a_pymodbus_plc() -> anyhow::Result<()> {
    writes_its_map_into_a_pymodbus_plc(1).await
}

/// The same with `requests_in_flight = 8` and four drivelines (each bite changes four
/// driveline blocks, more than one FC 16 request holds). pymodbus 3.16's server takes
/// one request at a time: of several sent before their answers it answers the first
/// at most and drops the rest. The writer's first write of several requests then gets
/// no answer in time, and it goes on one request at a time: the PLC gets the map and
/// the bites all the same, a timeout later.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_pymodbus_plc_that_takes_one_request_at_a_time_still_gets_the_map() -> anyhow::Result<()>
{
    writes_its_map_into_a_pymodbus_plc(8).await
}

async fn writes_its_map_into_a_pymodbus_plc(requests_in_flight: usize) -> anyhow::Result<()> {
    let demo = setup(2.0, 0.5, 3)?;
    let mut config = demo.config;
    if requests_in_flight > 1 {
        // Three more drivelines on the demo's torque channel.
        let first = config.drivelines[0].clone();
        config
            .drivelines
            .extend((2..=4).map(|k| millgate_config::Driveline {
                name: format!("F{k}"),
                ..first.clone()
            }));
    }
    // A kit port, below the kernel's ephemeral range: no outgoing connection is given
    // it before the Python PLC binds it.
    let port = free_port();
    let map = RegisterMap::new(&config);
    let mut plc = Command::new("python3")
        .arg(peer("pymodbus_plc.py"))
        .args([port.to_string(), map.len().to_string()])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .spawn()?;
    let mut plc_out = BufReader::new(plc.stdout.take().unwrap());
    let mut line = String::new();
    plc_out.read_line(&mut line)?;
    assert_eq!(line.trim(), "ready", "pymodbus PLC did not start");
    // The DAQ streams from now on: started after the Python PLC (whose start-up can
    // take longer than the first bar's idle time), so the gateway sees the first bite
    // from its idle level.
    let devices = demo_devices(&mut config, &demo.schedule).await?;
    let output = config.outputs.plc.as_mut().unwrap();
    output.address = format!("127.0.0.1:{port}");
    output.requests_in_flight = requests_in_flight;
    // A timeout of a fraction of the default's 1 s: the first write's wait for the
    // answers pymodbus drops.
    output.timeout = Duration::from_millis(300);
    assert!(
        requests_in_flight == 1 || map.len() > 2 * 123,
        "the map has {} registers: one request's worth",
        map.len()
    );

    let mut gateway = millgate::Service::new(config)?.spawn().await?;
    let mut received =
        vec![tokio::time::timeout(Duration::from_secs(10), gateway.bites().recv()).await??];
    // Read the pymodbus PLC live, as its program would, once a write has brought it
    // the bite (waited for: two write periods, 300 ms, were too few on a loaded
    // machine).
    let counter_at = address_of(&map, "F1.bite_counter");
    let started = std::time::Instant::now();
    let live = loop {
        let live = read_plc(port, map.len()).await?;
        if decode_u32(&live[counter_at..]).is_some_and(|counter| counter >= 1) {
            break live;
        }
        anyhow::ensure!(
            started.elapsed() < Duration::from_secs(20),
            "no bite in the pymodbus PLC within 20 s"
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    };
    // On a loaded machine more bars may have been analysed meanwhile: the PLC holds the
    // last one, so compare against the bite with the PLC's bite counter.
    while let Ok(bite) = gateway.bites().try_recv() {
        received.push(bite);
    }
    tokio::time::timeout(Duration::from_secs(10), gateway.stop()).await??;
    devices.stop().await?;

    drop(plc.stdin.take());
    line.clear();
    plc_out.read_line(&mut line)?;
    plc.wait()?;
    let after_stop: Vec<u16> = serde_json::from_str(&line)?;
    assert_eq!(after_stop.len(), usize::from(map.len()));
    assert_eq!(
        after_stop[address_of(&map, "gateway_status")] & 0b10,
        0b10,
        "final write: stopped"
    );

    assert!(live[address_of(&map, "heartbeat")] > 1, "several writes");
    assert_eq!(live[address_of(&map, "gateway_status")] & 1, 1, "running");
    let counter = decode_u32(&live[address_of(&map, "F1.bite_counter")..]).unwrap();
    assert!(
        counter >= 1 && counter as usize <= received.len(),
        "counter {counter}"
    );
    let bite = &received[counter as usize - 1];
    let taf = f64::from(decode_f32(&live[address_of(&map, "F1.taf")..]).unwrap());
    let truth = demo
        .schedule
        .nearest_truth(bite.transient.static_torque_knm)
        .unwrap();
    assert!(
        (taf - truth.taf).abs() < 0.02 * truth.taf,
        "TAF {taf} vs truth {}",
        truth.taf
    );
    Ok(())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn pymodbus_hmi_reads_the_map_and_gets_exception_codes() -> anyhow::Result<()> {
    let mut config = setup(1.0, 0.0, 1)?.config;
    config.modbus_sources[0].address = "127.0.0.1:1".into();
    config.outputs.plc = None;
    config.outputs.server.as_mut().unwrap().bind = "127.0.0.1:0".parse()?;
    let gateway = millgate::Service::new(config)?.spawn().await?;
    let address = gateway.bound().server.unwrap();
    let map = (*gateway.register_map()).clone();
    tokio::time::sleep(Duration::from_millis(100)).await;

    let args = [
        address.port().to_string(),
        map.len().to_string(),
        address_of(&map, "command.acknowledge_alarms").to_string(),
        address_of(&map, "F1.taf").to_string(),
    ];
    let output = tokio::task::spawn_blocking(move || {
        Command::new("python3")
            .arg(peer("pymodbus_hmi.py"))
            .args(args)
            .output()
    })
    .await??;
    let said = String::from_utf8_lossy(&output.stdout).to_string()
        + &String::from_utf8_lossy(&output.stderr);
    assert!(output.status.success(), "{said}");
    let report: serde_json::Value = serde_json::from_slice(&output.stdout)?;
    assert_eq!(
        report["head"][1].as_u64().map(|s| s & 1),
        Some(1),
        "running: {said}"
    );
    assert_eq!(report["read_past_map"], 2, "illegal data address: {said}");
    assert_eq!(
        report["write_result_register"], 2,
        "results read-only: {said}"
    );
    assert_eq!(
        report["write_ack"],
        serde_json::Value::Null,
        "command accepted: {said}"
    );
    assert_eq!(
        report["write_bad_ack_value"], 3,
        "illegal data value: {said}"
    );
    // The function codes docs/register-map.md lists, and no other: FC 04 reads the
    // map as FC 03 does (the heartbeat may move between the two reads), FC 16 takes
    // a command as FC 06 does, every other one is refused with exception 01.
    assert_eq!(
        report["head_fc04"][1], report["head"][1],
        "FC 04 reads the map: {said}"
    );
    assert_eq!(
        report["write_ack_fc16"],
        serde_json::Value::Null,
        "FC 16 command accepted: {said}"
    );
    for fc in ["01", "02", "05", "15", "22", "23"] {
        assert_eq!(
            report["other_functions"][fc], 1,
            "FC {fc}: illegal function: {said}"
        );
    }

    tokio::time::timeout(Duration::from_secs(10), gateway.stop()).await??;
    let _ = std::io::stdout().flush();
    Ok(())
}
