//! Modbus faults the gateway must ride out: a PLC that appears only after the
//! gateway started, and a DAQ that sends malformed and truncated replies.

use std::time::Duration;

use millgate::outputs::register_map::RegisterMap;
use millgate_sim::devices::demo::setup;
use millgate_sim::devices::modbus_bank::ServeOptions;
use millgate_sim::devices::virtual_plc::VirtualPlc;
use millgate_tests::wait_for;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn plc_unreachable_at_start_gets_registers_when_it_appears() -> anyhow::Result<()> {
    let mut config = setup(1.0, 0.0, 1)?.config;
    let plc_address = TcpListener::bind("127.0.0.1:0").await?.local_addr()?;
    config.modbus_sources[0].address = "127.0.0.1:1".into();
    config.outputs.server = None;
    let plc_output = config.outputs.plc.as_mut().unwrap();
    plc_output.address = plc_address.to_string();
    plc_output.register_base = 100;
    let map = RegisterMap::new(&config);

    let gateway = millgate::Service::new(config)?.spawn().await?;
    tokio::time::sleep(Duration::from_millis(800)).await;

    let plc = VirtualPlc::new(100 + usize::from(map.len()));
    let running_plc = plc.spawn(
        TcpListener::bind(plc_address).await?,
        ServeOptions::default(),
    );

    // Reconnect backoff is capped at 5 s; registers must arrive well within that.
    wait_for("registers in the late PLC", Duration::from_secs(8), || {
        let holding = plc.holding();
        holding[100] > 0 && holding[101] & 1 == 1
    })
    .await;
    let holding = plc.holding();
    assert!(
        holding[..100].iter().all(|&w| w == 0),
        "nothing written below the base"
    );
    assert_eq!(holding[104] & 1, 1, "the unreachable DAQ is reported lost");
    let first = holding[100];
    wait_for("heartbeat moves", Duration::from_secs(2), || {
        plc.holding()[100] != first
    })
    .await;

    tokio::time::timeout(Duration::from_secs(10), gateway.stop()).await??;
    assert_eq!(plc.holding()[101] & 0b10, 0b10, "final write: stopped");
    running_plc.stop().await?;
    Ok(())
}

/// A hostile DAQ: answers each request from a script of raw replies, then closes.
/// Each reply is built from the request's transaction header.
async fn serve_script(listener: TcpListener, script: Vec<fn([u8; 7]) -> Vec<u8>>) -> usize {
    let mut served = 0;
    for reply in script {
        let Ok((mut stream, _)) = listener.accept().await else {
            break;
        };
        served += answer_once(&mut stream, reply).await as usize;
    }
    served
}

async fn answer_once(stream: &mut TcpStream, reply: fn([u8; 7]) -> Vec<u8>) -> bool {
    let mut header = [0u8; 7];
    if stream.read_exact(&mut header).await.is_err() {
        return false;
    }
    let length = usize::from(u16::from_be_bytes([header[4], header[5]])) - 1;
    let mut pdu = vec![0u8; length];
    if stream.read_exact(&mut pdu).await.is_err() {
        return false;
    }
    stream.write_all(&reply(header)).await.is_ok()
}

/// An FC 04 reply with `words` as register values, MBAP length computed.
fn fc04_reply(header: [u8; 7], words: &[u16]) -> Vec<u8> {
    let byte_count = (words.len() * 2) as u8;
    let length = 3 + u16::from(byte_count);
    let mut frame = vec![header[0], header[1], 0, 0];
    frame.extend(length.to_be_bytes());
    frame.extend([header[6], 0x04, byte_count]);
    for word in words {
        frame.extend(word.to_be_bytes());
    }
    frame
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn malformed_and_truncated_replies_are_counted_and_survived() -> anyhow::Result<()> {
    let mut config = setup(1.0, 0.0, 1)?.config;
    config.outputs.plc = None;
    config.outputs.server = None;
    let listener = TcpListener::bind("127.0.0.1:0").await?;
    config.modbus_sources[0].address = listener.local_addr()?.to_string();
    config.modbus_sources[0].timeout = Duration::from_millis(300);

    let script: Vec<fn([u8; 7]) -> Vec<u8>> = vec![
        // Truncated: the header promises 247 bytes, 3 arrive, then the line drops.
        |h| vec![h[0], h[1], 0, 0, 0, 247, h[6], 0x04, 244],
        // A Modbus exception: the DAQ refuses (illegal data address).
        |h| vec![h[0], h[1], 0, 0, 0, 3, h[6], 0x84, 0x02],
        // Well-formed Modbus, but the block's sample count is 500 (> 120).
        |h| {
            let mut words = vec![0u16; 122];
            words[..2].copy_from_slice(&[7, 500]);
            fc04_reply(h, &words)
        },
        // Garbage that is not Modbus at all.
        |_| b"HTTP/1.1 400 Bad Request\r\n\r\n".to_vec(),
        // Finally a good block: sequence 9, 3 samples.
        |h| {
            let mut words = vec![0u16; 122];
            words[..5].copy_from_slice(&[9, 3, 100, 200, 300]);
            fc04_reply(h, &words)
        },
    ];
    let daq = tokio::spawn(serve_script(listener, script));

    let gateway = millgate::Service::new(config)?.spawn().await?;
    let counters = gateway.counters()[0].clone();

    wait_for(
        "the good block after the bad ones",
        Duration::from_secs(10),
        || counters.snapshot().blocks_read == 1,
    )
    .await;
    let seen = counters.snapshot();
    assert_eq!(seen.samples, 3, "only the good block's samples: {seen:?}");
    assert!(
        seen.errors + seen.timeouts >= 4,
        "each bad reply counted: {seen:?}"
    );
    assert!(!gateway.is_finished(), "still running");

    tokio::time::timeout(Duration::from_secs(10), gateway.stop()).await??;
    daq.abort();
    Ok(())
}
