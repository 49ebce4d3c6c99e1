//! Modbus faults the gateway must ride out: a PLC that appears only after the
//! gateway started, or vanishes and returns; a DAQ that sends malformed and truncated
//! replies; HMI clients that send frames meant to break a server, hold connections
//! open or trickle bytes; metrics requests in pieces or malformed; start-up failures.

use std::time::Duration;

use millgate::outputs::modbus::register_map::RegisterMap;
use millgate_sim::devices::demo::setup;
use millgate_sim::devices::modbus_bank::ServeOptions;
use millgate_sim::devices::virtual_plc::VirtualPlc;
use millgate_tests::kit::{free_port, scrape, until_scraped_at_least, wait_for};
use std::time::Instant;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};

/// The PLC writer's failed connections on `/metrics`.
const PLC_CONNECT_FAILURES: &str = "millgate_plc_write_failures_total{reason=\"connect\"}";

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn plc_unreachable_at_start_gets_registers_when_it_appears() -> anyhow::Result<()> {
    let mut config = setup(1.0, 0.0, 1)?.config;
    // Below the kernel's ephemeral range: while no PLC listens, no outgoing connection
    // (the writer's own retries to it among them) is given the port.
    let plc_address = SocketAddr::from(([127, 0, 0, 1], free_port()));
    config.modbus_sources[0].address = "127.0.0.1:1".into();
    config.outputs.server = None;
    config.outputs.metrics = Some(millgate_config::MetricsOutput {
        bind: "127.0.0.1:0".parse()?,
    });
    let plc_output = config.outputs.plc.as_mut().unwrap();
    plc_output.address = plc_address.to_string();
    plc_output.register_base = 100;
    let map = RegisterMap::new(&config);

    let gateway = millgate::Service::new(config)?.spawn().await?;
    let metrics = gateway.bound().metrics.expect("metrics");
    // Unreachable at start: the writer has tried and retried before the PLC appears.
    until_scraped_at_least(metrics, PLC_CONNECT_FAILURES, 3.0, Duration::from_secs(20)).await;

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
    wait_for("heartbeat moves", Duration::from_secs(10), || {
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

// ---------------------------------------------------------------- the HMI server

use std::net::SocketAddr;

use millgate::Service;

/// A gateway with the demo configuration, DAQ and PLC unreachable, its server on a
/// free loopback port with at most `max_connections` clients and `idle_ms` idle time,
/// and metrics.
async fn server_gateway(
    max_connections: usize,
    idle_ms: u64,
) -> anyhow::Result<(millgate::service::RunningService, SocketAddr)> {
    let mut config = setup(1.0, 0.0, 1)?.config;
    config.modbus_sources[0].address = "127.0.0.1:1".into();
    config.outputs.plc = None;
    let server = config.outputs.server.as_mut().unwrap();
    server.bind = "127.0.0.1:0".parse()?;
    server.max_connections = max_connections;
    server.idle_timeout = Duration::from_millis(idle_ms);
    config.outputs.metrics = Some(millgate_config::MetricsOutput {
        bind: "127.0.0.1:0".parse()?,
    });
    let gateway = Service::new(config)?.spawn().await?;
    let address = gateway.bound().server.expect("server");
    Ok((gateway, address))
}

/// Send `frame`, read the reply (MBAP header and PDU), or `None` when none comes
/// within 500 ms.
async fn exchange(stream: &mut TcpStream, frame: &[u8]) -> anyhow::Result<Option<Vec<u8>>> {
    stream.write_all(frame).await?;
    let mut header = [0u8; 7];
    match tokio::time::timeout(Duration::from_millis(500), stream.read_exact(&mut header)).await {
        Err(_) => return Ok(None),
        Ok(read) => read?,
    };
    let length = usize::from(u16::from_be_bytes([header[4], header[5]]));
    let mut pdu = vec![0u8; length - 1];
    stream.read_exact(&mut pdu).await?;
    Ok(Some([&header[..], &pdu].concat()))
}

/// A frame with transaction id 0x0001 for `unit` carrying `pdu`.
fn frame(unit: u8, pdu: &[u8]) -> Vec<u8> {
    let mut frame = vec![0, 1, 0, 0];
    frame.extend(((pdu.len() + 1) as u16).to_be_bytes());
    frame.push(unit);
    frame.extend_from_slice(pdu);
    frame
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn hostile_frames_get_exceptions_and_the_connection_stays_open() -> anyhow::Result<()> {
    let (gateway, address) = server_gateway(8, 60_000).await?;
    let board = gateway.board();
    let mut hmi = TcpStream::connect(address).await?;
    let read_status = frame(1, &[0x03, 0x00, 0x01, 0x00, 0x01]);
    let expect = |reply: Option<Vec<u8>>, function: u8, code: u8, what: &str| {
        let reply = reply.unwrap_or_else(|| panic!("{what}: no reply"));
        assert_eq!(
            &reply[7..],
            &[function | 0x80, code],
            "{what}: {reply:02x?}"
        );
    };
    // The frame that panicked tokio-modbus 0.17.0's coil unpacking.
    let fc15 = [
        0x00, 0x01, 0x00, 0x00, 0x00, 0x07, 0x01, 0x0f, 0x00, 0x00, 0x00, 0x10, 0x00,
    ];
    expect(
        exchange(&mut hmi, &fc15).await?,
        0x0f,
        0x01,
        "FC 15 quantity 16, 0 bytes",
    );
    expect(
        exchange(&mut hmi, &frame(1, &[0x10, 0x00, 0x08, 0x00, 0x00, 0x00])).await?,
        0x10,
        0x03,
        "FC 16 quantity 0",
    );
    let quantity_124 = [&[0x10, 0x00, 0x08, 0x00, 124, 248][..], &[0u8; 248]].concat();
    expect(
        exchange(&mut hmi, &frame(1, &quantity_124)).await?,
        0x10,
        0x03,
        "FC 16 quantity 124",
    );
    expect(
        exchange(
            &mut hmi,
            &frame(1, &[0x10, 0x00, 0x08, 0x00, 0x01, 0x04, 0, 1, 0, 0]),
        )
        .await?,
        0x10,
        0x03,
        "FC 16 byte count mismatch",
    );
    expect(
        exchange(&mut hmi, &frame(7, &[0x03, 0x00, 0x01, 0x00, 0x01])).await?,
        0x03,
        0x0b,
        "another unit id",
    );
    // A broadcast acknowledge: no reply, no action.
    board.update(|results| results.drivelines[0].taf_alarm = true);
    let broadcast = exchange(&mut hmi, &frame(0, &[0x06, 0x00, 0x08, 0x00, 0x01])).await?;
    assert_eq!(broadcast, None, "a broadcast is never answered");
    assert!(board.results().drivelines[0].taf_alarm, "nor acted on");
    // After all that, the same connection still reads the map.
    let reply = exchange(&mut hmi, &read_status).await?.expect("a reply");
    assert_eq!(&reply[7..9], &[0x03, 0x02], "{reply:02x?}");
    let page = scrape(gateway.bound().metrics.expect("metrics")).await?;
    assert!(
        page.contains("millgate_server_exceptions_total 5"),
        "{page}"
    );
    assert!(
        page.contains("millgate_server_broadcasts_total 1"),
        "{page}"
    );
    tokio::time::timeout(Duration::from_secs(10), gateway.stop()).await??;
    Ok(())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn slowloris_and_connection_floods_are_bounded() -> anyhow::Result<()> {
    // Two clients at most, 2 s idle time: before, 1 000 one-byte connections were
    // held open for ever. The idle time is the window the test's steps must fall in
    // (the third client comes and the trickler starts before the first two idle out):
    // 2 s, not 300 ms, so that a loaded machine's scheduling does not close them first.
    let (gateway, address) = server_gateway(2, 2000).await?;
    let mut idle = TcpStream::connect(address).await?;
    let mut trickle = TcpStream::connect(address).await?;
    tokio::time::sleep(Duration::from_millis(50)).await;
    // A third client takes the place of the one connected first (neither sent a
    // request): that one is closed at once.
    let mut third = TcpStream::connect(address).await?;
    let mut byte = [0u8; 1];
    let closed = tokio::time::timeout(Duration::from_secs(10), idle.read(&mut byte)).await;
    assert!(matches!(closed, Ok(Ok(0)) | Ok(Err(_))), "{closed:?}");
    // The trickler sends a request one byte every 400 ms: the request must be whole
    // within the idle time, so it is closed as the idle one is.
    let request = frame(1, &[0x03, 0x00, 0x01, 0x00, 0x01]);
    let started = Instant::now();
    let mut trickle_closed = false;
    for &b in &request {
        if trickle.write_all(&[b]).await.is_err() {
            trickle_closed = true;
            break;
        }
        tokio::time::sleep(Duration::from_millis(400)).await;
    }
    let ended = tokio::time::timeout(Duration::from_secs(10), trickle.read(&mut byte)).await;
    trickle_closed |= matches!(ended, Ok(Ok(0)) | Ok(Err(_)));
    assert!(
        trickle_closed,
        "slowloris still served after {:?}",
        started.elapsed()
    );
    // The third never sends a request: closed after the first-request time (here
    // the idle time).
    let ended = tokio::time::timeout(Duration::from_secs(10), third.read(&mut byte)).await;
    assert!(
        matches!(ended, Ok(Ok(0)) | Ok(Err(_))),
        "silent client not closed"
    );
    // The slots are free again: a real client is served.
    let mut hmi = TcpStream::connect(address).await?;
    let reply = exchange(&mut hmi, &request).await?.expect("served");
    assert_eq!(&reply[7..9], &[0x03, 0x02]);
    let page = scrape(gateway.bound().metrics.expect("metrics")).await?;
    for expected in [
        "millgate_server_refused_connections_total 0",
        "millgate_server_evicted_connections_total 1",
        "millgate_server_idle_closed_connections_total 2",
        "millgate_server_silent_closed_connections_total 1",
    ] {
        assert!(page.contains(expected), "{expected}: {page}");
    }
    tokio::time::timeout(Duration::from_secs(10), gateway.stop()).await??;
    Ok(())
}

/// A connection to `server` from the loopback address `local` (127.0.0.x: each a
/// peer of its own to the server).
async fn connect_from(local: [u8; 4], server: SocketAddr) -> anyhow::Result<TcpStream> {
    let socket = tokio::net::TcpSocket::new_v4()?;
    socket.bind(SocketAddr::from((local, 0)))?;
    Ok(socket.connect(server).await?)
}

/// Whether the server has closed `stream` (within 2 s).
async fn closed(stream: &mut TcpStream) -> bool {
    let mut byte = [0u8; 1];
    let read = tokio::time::timeout(Duration::from_secs(2), stream.read(&mut byte)).await;
    matches!(read, Ok(Ok(0)) | Ok(Err(_)))
}

/// Issue 30, finding 5: eight idle connections locked every HMI out for the idle
/// time, renewable for ever. Now one address holds at most `max_connections_per_peer`
/// (its own oldest make room), a full server makes room by closing the connection
/// idle longest, and silent connections are closed after 5 s.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn idle_connections_never_lock_an_hmi_out() -> anyhow::Result<()> {
    // The defaults: 8 clients, 4 per address, 60 s idle time.
    let (gateway, address) = server_gateway(8, 60_000).await?;
    let metrics = gateway.bound().metrics.expect("metrics");
    // One host opens eight silent connections: it keeps its last four.
    let mut first_host = Vec::new();
    for _ in 0..8 {
        first_host.push(connect_from([127, 0, 0, 2], address).await?);
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    for (k, stream) in first_host.iter_mut().take(4).enumerate() {
        assert!(
            closed(stream).await,
            "connection {k} of the first host kept"
        );
    }
    // A second host opens four more, and makes a request on the first: full.
    let mut second_host = Vec::new();
    for _ in 0..4 {
        second_host.push(connect_from([127, 0, 0, 3], address).await?);
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    let request = frame(1, &[0x03, 0x00, 0x01, 0x00, 0x01]);
    let reply = exchange(&mut second_host[0], &request)
        .await?
        .expect("served");
    assert_eq!(&reply[7..9], &[0x03, 0x02]);
    // The HMI is served: the oldest silent connection (the first host's fifth) makes
    // room, not the one that made a request.
    let mut hmi = TcpStream::connect(address).await?;
    let reply = exchange(&mut hmi, &request)
        .await?
        .expect("the HMI is served");
    assert_eq!(&reply[7..9], &[0x03, 0x02]);
    assert!(
        closed(&mut first_host[4]).await,
        "the oldest silent one kept"
    );
    let reply = exchange(&mut second_host[0], &request).await?;
    assert!(
        reply.is_some(),
        "the connection that made a request was evicted"
    );
    let page = scrape(metrics).await?;
    for expected in [
        "millgate_server_refused_connections_total 0",
        "millgate_server_evicted_connections_total 5",
    ] {
        assert!(page.contains(expected), "{expected}: {page}");
    }
    // Silent connections go after 5 s, not the 60 s idle time: the first host's last
    // three and the second host's three.
    let started = Instant::now();
    loop {
        let page = scrape(metrics).await?;
        if page.contains("millgate_server_silent_closed_connections_total 6") {
            break;
        }
        assert!(
            started.elapsed() < Duration::from_secs(15),
            "silent connections not closed: {page}"
        );
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
    for stream in first_host
        .iter_mut()
        .skip(5)
        .chain(second_host.iter_mut().skip(1))
    {
        assert!(closed(stream).await, "a silent connection kept");
    }
    assert!(
        !closed(&mut hmi).await,
        "the HMI that made a request was closed"
    );
    tokio::time::timeout(Duration::from_secs(10), gateway.stop()).await??;
    Ok(())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_metrics_endpoint_reads_the_whole_head_and_refuses_malformed_ones() -> anyhow::Result<()>
{
    let (gateway, _) = server_gateway(8, 60_000).await?;
    let metrics = gateway.bound().metrics.expect("metrics");
    async fn ask(address: SocketAddr, parts: &[&[u8]]) -> anyhow::Result<String> {
        let mut stream = TcpStream::connect(address).await?;
        for part in parts {
            stream.write_all(part).await?;
            stream.flush().await?;
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
        let mut response = String::new();
        tokio::time::timeout(Duration::from_secs(5), stream.read_to_string(&mut response))
            .await??;
        Ok(response)
    }
    // A head in three segments: the first read() held only "GET /met".
    let split = ask(
        metrics,
        &[b"GET /met", b"rics HTTP/1.1\r\nHo", b"st: x\r\n\r\n"],
    )
    .await?;
    assert!(split.starts_with("HTTP/1.1 200 OK"), "{split}");
    assert!(split.contains("millgate_heartbeat"));
    // HEAD: the same answer without the body.
    let head = ask(
        metrics,
        &[b"HEAD /metrics HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n"],
    )
    .await?;
    assert!(head.starts_with("HTTP/1.1 200 OK"), "{head}");
    assert!(head.contains("text/plain; version=0.0.4"), "{head}");
    assert!(!head.contains("millgate_heartbeat"), "no body: {head}");
    for (request, status) in [
        (&b"GARBAGE\r\n\r\n"[..], "HTTP/1.1 400 Bad Request"),
        (
            b"GET /metrics HTTP/1.1\r\nbroken header\r\n\r\n",
            "HTTP/1.1 400 Bad Request",
        ),
        (
            b"POST /metrics HTTP/1.1\r\n\r\n",
            "HTTP/1.1 405 Method Not Allowed",
        ),
        (b"GET /other HTTP/1.1\r\n\r\n", "HTTP/1.1 404 Not Found"),
    ] {
        let response = ask(metrics, &[request]).await?;
        assert!(response.starts_with(status), "{request:?}: {response}");
    }
    // Past the HTTP stack's 16 KiB head limit.
    let long = [&b"GET /metrics HTTP/1.1\r\nX: "[..], &[b'a'; 17_000]].concat();
    let response = ask(metrics, &[&long]).await?;
    assert!(response.starts_with("HTTP/1.1 431"), "{response}");
    tokio::time::timeout(Duration::from_secs(10), gateway.stop()).await??;
    Ok(())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_plc_that_vanishes_and_returns_gets_registers_again() -> anyhow::Result<()> {
    let mut config = setup(1.0, 0.0, 1)?.config;
    config.modbus_sources[0].address = "127.0.0.1:1".into();
    config.outputs.server = None;
    config.outputs.metrics = Some(millgate_config::MetricsOutput {
        bind: "127.0.0.1:0".parse()?,
    });
    // The PLC's two lives on a port below the ephemeral range (as above).
    let plc_address = SocketAddr::from(([127, 0, 0, 1], free_port()));
    config.outputs.plc.as_mut().unwrap().address = plc_address.to_string();
    let map = RegisterMap::new(&config);
    let plc = VirtualPlc::new(usize::from(map.len()));
    let first_life = plc.spawn(
        TcpListener::bind(plc_address).await?,
        ServeOptions::default(),
    );
    let gateway = Service::new(config)?.spawn().await?;
    let metrics = gateway.bound().metrics.expect("metrics");
    wait_for("first writes", Duration::from_secs(20), || {
        plc.writes() >= 3
    })
    .await;
    first_life.stop().await?;
    // Gone until the writer has failed to reconnect three times (0.3 s of backoff at
    // least): the gateway keeps running, the heartbeat keeps moving.
    let beat = gateway.board().results().heartbeat;
    until_scraped_at_least(metrics, PLC_CONNECT_FAILURES, 3.0, Duration::from_secs(20)).await;
    wait_for("heartbeat moves", Duration::from_secs(10), || {
        gateway.board().results().heartbeat != beat
    })
    .await;
    assert!(!gateway.is_finished());
    let writes = plc.writes();
    let second_life = plc.spawn(
        TcpListener::bind(plc_address).await?,
        ServeOptions::default(),
    );
    // The backoff grows to 5 s at most.
    wait_for("writes again", Duration::from_secs(20), || {
        plc.writes() > writes + 2
    })
    .await;
    assert_eq!(plc.holding()[1] & 1, 1, "running");
    tokio::time::timeout(Duration::from_secs(10), gateway.stop()).await??;
    assert_eq!(plc.holding()[1] & 0b11, 0b10, "final write: stopped");
    second_life.stop().await?;
    Ok(())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn start_up_failures_are_errors_not_silence() -> anyhow::Result<()> {
    // A port already taken: spawning fails with the reason, it does not run without
    // its server.
    let taken = TcpListener::bind("127.0.0.1:0").await?;
    let mut config = setup(1.0, 0.0, 1)?.config;
    config.outputs.server.as_mut().unwrap().bind = taken.local_addr()?;
    let error = Service::new(config.clone())?.spawn().await.unwrap_err();
    assert!(
        error.to_string().starts_with(&format!(
            "cannot bind the Modbus server to {}",
            taken.local_addr()?
        )),
        "{error}"
    );
    // A register base that runs the map past 65535.
    config.outputs.server = None;
    config.outputs.plc.as_mut().unwrap().register_base = 65_500;
    let error = Service::new(config).unwrap_err();
    assert!(
        error
            .to_string()
            .starts_with("outputs.plc.register_base: 65500 is not allowed"),
        "{error}"
    );
    Ok(())
}
