//! The vcan suite's `millgate run` tests, beside the reader's (`tests/tests/vcan.rs`):
//! they need a kernel with SocketCAN and an interface `vcan0` (or the one named by
//! `MILLGATE_VCAN`); `scripts/uml-vcan` runs them (`--test vcan` builds both suites),
//! inside User-Mode Linux when the host kernel has no CAN. The peer is `cansend` from
//! can-utils (`MILLGATE_CANSEND`), run as a process.
//!
//! A CAN source added by `SIGHUP` (issue 41): the real `millgate run` between the
//! demo's virtual DAQ and PLC, its Modbus source streaming bites, gets a CAN source
//! and a channel on it appended to its file. The reload applies them without a
//! restart; every frame `cansend` writes is decoded into a sample (the source's
//! counters and the channel's on `/metrics`: a block read and a sample a frame, a frame
//! too short for the signal an error), the new source is ok; the Modbus source runs on
//! on its one connection, no bite id of it missing from the history.

mod common;

use std::process::Command;
use std::time::Duration;

use common::{applied_by_sighup, bite_ids, terminate, Setup, MILLGATE};
use millgate::history::query::HistoryReader;

/// `cansend interface frame`, `MILLGATE_CANSEND` or the one on `PATH`.
fn cansend(interface: &str, frame: &str) {
    let program = std::env::var("MILLGATE_CANSEND").unwrap_or_else(|_| "cansend".to_owned());
    let status = Command::new(&program)
        .args([interface, frame])
        .status()
        .unwrap_or_else(|error| panic!("running {program} (install can-utils): {error}"));
    assert!(status.success(), "{program} {interface} {frame}: {status}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[ignore = "needs SocketCAN vcan0: run scripts/uml-vcan"]
async fn a_can_source_added_by_sighup_reads_cansend_frames_while_the_modbus_source_runs() {
    let interface = std::env::var("MILLGATE_VCAN").unwrap_or_else(|_| "vcan0".to_owned());
    let setup = Setup::new(MILLGATE, "vcan-reload", "db").await;
    let mut service = setup.spawn("run.log");
    let log_guard = setup.log_on_failure("run.log");
    let plc = setup.plc();
    plc.bites_after_now(1).await;
    let daq1 = "millgate_source_connects_total{source=\"daq1\"}";
    assert_eq!(setup.metric(daq1).await, Some(1.0));

    // StandStatus of the project's DBC (id 0x102, Motorola): RollSpeed in bytes 0..2,
    // 0.1 rpm a count.
    let dbc = concat!(env!("CARGO_MANIFEST_DIR"), "/../config/examples/mill.dbc");
    setup.append_config(&format!(
        "\n[[sources.can]]\nname = \"stand_can\"\ninterface = \"{interface}\"\n\
         dbc = \"{dbc}\"\n\n[[channels]]\nname = \"f1_roll_speed\"\n\
         kind = \"process_value\"\nunit = \"rpm\"\nsample_rate_hz = 100.0\n\
         source = {{ can = \"stand_can\", message = \"StandStatus\", signal = \"RollSpeed\" }}\n"
    ));
    let before_reload = plc.counter();
    let said = "reload: applied sources.stand_can (its reader started live), \
                channels.f1_roll_speed (on a source added live)";
    applied_by_sighup(&setup, &service, said).await;

    // The new reader counts a connect once its socket is bound (a frame sent before
    // would reach no socket); then each frame is decoded into a sample of the channel,
    // counted per source and per channel.
    let can = |family: &str| format!("millgate_can_{family}_total{{source=\"stand_can\"}}");
    let channel =
        |family: &str| format!("millgate_channel_{family}_total{{channel=\"f1_roll_speed\"}}");
    let connects = "millgate_source_connects_total{source=\"stand_can\"}";
    setup
        .until_metric(connects, 1.0, Duration::from_secs(10))
        .await;
    assert_eq!(setup.metric(&can("decoded_frames")).await, Some(0.0));
    assert_eq!(setup.metric(&channel("samples")).await, Some(0.0));
    // One byte: RollSpeed needs two. Sent first, so it is counted once the last good
    // frame's sample is.
    cansend(&interface, "102#13");
    let sent = 20_u8;
    for sequence in 0..sent {
        // 500.0 rpm; the message's Seq in byte 7.
        cansend(&interface, &format!("102#13880000000000{sequence:02X}"));
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    setup
        .until_metric(
            &can("decoded_frames"),
            f64::from(sent),
            Duration::from_secs(10),
        )
        .await;
    // The frame carries one signal of the channel: a sample a frame.
    setup
        .until_metric(
            &channel("samples"),
            f64::from(sent),
            Duration::from_secs(10),
        )
        .await;
    assert_eq!(
        setup.metric(&channel("blocks_read")).await,
        Some(f64::from(sent))
    );
    assert_eq!(setup.metric(&channel("errors")).await, Some(1.0));
    assert_eq!(setup.metric(&channel("saturated_samples")).await, Some(0.0));
    assert_eq!(
        setup.metric(&can("frames")).await,
        Some(f64::from(sent) + 1.0)
    );
    assert_eq!(setup.metric(&can("bad_length_frames")).await, Some(1.0));
    assert_eq!(setup.metric(&can("unknown_id_frames")).await, Some(0.0));
    let status = "millgate_source_status{source=\"stand_can\"}";
    assert_eq!(setup.metric(status).await, Some(0.0), "stand_can not ok");

    // The Modbus source ran on: the same connection, bites on.
    plc.bites_after_now(1).await;
    assert!(plc.counter() > before_reload);
    assert_eq!(setup.metric(daq1).await, Some(1.0), "daq1 reconnected");
    assert!(
        service.try_wait().unwrap().is_none(),
        "SIGHUP ended the service"
    );
    terminate(&mut service);
    let history = HistoryReader::open(&setup.history).unwrap();
    let ids = bite_ids(&history, "F1");
    assert_eq!(
        ids,
        (1..=plc.counter()).collect::<Vec<_>>(),
        "F1's bite ids"
    );
    drop(log_guard);
    setup.stop(service).await;
}
