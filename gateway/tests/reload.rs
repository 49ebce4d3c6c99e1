//! `SIGHUP` to the real `millgate run` between the demo's virtual DAQ and PLC (round-4
//! audit, finding 11: a hang-up ended the service with no final write, the PLC's
//! status left "running", the run `unclean`): the configuration is checked again; a
//! file with errors is refused with them, a changed one is named with what a restart
//! would apply, an unchanged one changes nothing; the service runs on throughout (the
//! PLC's bite counter keeps moving) and stops cleanly afterwards.

mod common;

use std::time::Duration;

use common::{terminate, wait_for, Setup, MILLGATE};

use millgate::history::query::{Filter, HistoryReader};

/// Send SIGHUP to `pid`.
fn hang_up(pid: u32) {
    let sent = std::process::Command::new("kill")
        .args(["-HUP", &pid.to_string()])
        .status()
        .unwrap();
    assert!(sent.success());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sighup_checks_the_configuration_and_the_service_runs_on() {
    let setup = Setup::new(MILLGATE, "reload", "db").await;
    let plc = setup.plc();
    let original = std::fs::read_to_string(&setup.config).unwrap();
    let mut service = setup.spawn("run.log");
    plc.bites_after_now(1).await;

    let cases = [
        (
            original.replace("taf_alarm = 1.15,", "taf_alarm = -1.0,"),
            "reload refused: the configuration has errors",
        ),
        (
            original.replace("taf_alarm = 1.15,", "taf_alarm = 1.2,"),
            "reload: changed drivelines: applying them needs a restart",
        ),
        (original.clone(), "reload: the configuration is unchanged"),
    ];
    for (text, said) in cases {
        std::fs::write(&setup.config, text).unwrap();
        hang_up(service.id());
        wait_for(said, Duration::from_secs(10), || {
            setup.log_text("run.log").contains(said)
        })
        .await;
        assert!(
            service.try_wait().unwrap().is_none(),
            "SIGHUP ended the service"
        );
    }
    let log = setup.log_text("run.log");
    assert!(
        log.contains("taf_alarm"),
        "the refusal names the key: {log}"
    );
    // Still analysing and writing the PLC.
    plc.bites_after_now(1).await;
    terminate(&mut service);
    let runs = HistoryReader::open(&setup.history)
        .unwrap()
        .runs(&Filter::default())
        .unwrap();
    let ends: Vec<Option<&str>> = runs.iter().map(|r| r.ended.as_deref()).collect();
    assert_eq!(ends, [Some("stopped")]);
    setup.stop(service).await;
}
