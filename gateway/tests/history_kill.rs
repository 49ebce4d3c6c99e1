//! Acceptance of the event history: the real `millgate run` binary, between the demo's
//! virtual DAQ and PLC, is killed with SIGKILL right after a bite reached the PLC and
//! started again on the same file. Every bite the PLC saw is in the file; the bite
//! counter, the wear trend and the latched alarm continue; restored values carry the
//! "restored" flag until the next bite.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use millgate::analysis::wear::next_trend;
use millgate::outputs::history::query::{BiteRow, Filter, HistoryReader};
use millgate::outputs::register_map::{decode_f32, decode_u32, driveline_flags, RegisterMap};
use millgate_sim::devices::demo::{setup, DemoDevices};
use millgate_sim::devices::virtual_plc::VirtualPlc;

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// Registers of the driveline block read from the virtual PLC.
struct Plc<'a> {
    plc: &'a VirtualPlc,
    map: &'a RegisterMap,
}

impl Plc<'_> {
    fn at(&self, name: &str) -> usize {
        let register = self.map.registers().iter().find(|r| r.name == name);
        usize::from(
            register
                .unwrap_or_else(|| panic!("no register {name}"))
                .address,
        )
    }

    fn counter(&self) -> u32 {
        let words = self.plc.holding();
        decode_u32(&words[self.at("F1.bite_counter")..]).unwrap_or(0)
    }

    fn flags(&self) -> u16 {
        self.plc.holding()[self.at("F1.flags")]
    }

    fn taf(&self) -> f32 {
        decode_f32(&self.plc.holding()[self.at("F1.taf")..]).unwrap_or(f32::NAN)
    }
}

/// Poll `done` every 5 ms, at most `limit`.
async fn until(what: &str, limit: Duration, mut done: impl FnMut() -> bool) {
    let start = Instant::now();
    while !done() {
        assert!(start.elapsed() < limit, "{what}: not within {limit:?}");
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
}

fn spawn(config: &Path, log: &Path) -> Child {
    let log = std::fs::File::create(log).unwrap();
    Command::new(env!("CARGO_BIN_EXE_millgate"))
        .args(["run", "--config", config.to_str().unwrap()])
        .env("RUST_LOG", "info")
        .stdout(Stdio::null())
        .stderr(log)
        .spawn()
        .expect("start millgate run")
}

fn bites(history: &Path) -> Vec<BiteRow> {
    HistoryReader::open(history)
        .unwrap()
        .bites(&Filter::default())
        .unwrap()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sigkill_loses_no_bite_the_plc_saw_and_the_restart_continues() {
    let scratch =
        std::env::temp_dir().join(format!("millgate-history-kill-{}", std::process::id()));
    std::fs::create_dir_all(&scratch).unwrap();
    let history = scratch.join("history.db");
    let _ = std::fs::remove_file(&history);

    let demo = setup(60.0, 0.5, 5).unwrap();
    let mut config = demo.config;
    let map = RegisterMap::new(&config);
    let devices = DemoDevices::start(&mut config, &demo.schedule, usize::from(map.len()) + 16)
        .await
        .unwrap();
    let server_port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    // The demo's configuration with the driveline model (wear index and trend), TAF
    // thresholds every demo bite passes (the alarm latches at the first bite), and
    // the history.
    let model = repo().join("sim/models/table2-adjusted-backlash.toml");
    let text = std::fs::read_to_string(repo().join("config/examples/demo.toml"))
        .unwrap()
        .replace("127.0.0.1:5020", &config.modbus_sources[0].address)
        .replace(
            "127.0.0.1:5502",
            &config.outputs.plc.as_ref().unwrap().address,
        )
        .replace("127.0.0.1:5503", &format!("127.0.0.1:{server_port}"))
        .replace(
            "torque = \"spindle_top\"",
            &format!("torque = \"spindle_top\"\nmodel = \"{}\"", model.display()),
        )
        .replace(
            "thresholds = { taf_warning = 2.2, taf_alarm = 2.6 }",
            "thresholds = { taf_warning = 1.2, taf_alarm = 1.3 }",
        )
        + &format!("\n[history]\npath = \"{}\"\n", history.display());
    let config_path = scratch.join("mill.toml");
    std::fs::write(&config_path, text).unwrap();
    let plc = Plc {
        plc: &devices.plc,
        map: &map,
    };

    // First run: killed the moment the PLC shows its 4th bite.
    let mut first = spawn(&config_path, &scratch.join("first.log"));
    until("3 bites in the PLC", Duration::from_secs(40), || {
        plc.counter() >= 3
    })
    .await;
    let seen = plc.counter();
    until("another bite in the PLC", Duration::from_secs(20), || {
        plc.counter() > seen
    })
    .await;
    first.kill().unwrap();
    first.wait().unwrap();
    let in_plc = plc.counter();
    let taf_in_plc = plc.taf();
    assert!(
        plc.flags() & driveline_flags::ALARM != 0,
        "the alarm latched"
    );

    let stored = bites(&history);
    let counters: Vec<i64> = stored.iter().map(|b| b.bite_counter).collect();
    for counter in 1..=i64::from(in_plc) {
        assert!(
            counters.contains(&counter),
            "bite {counter} reached the PLC but is not in the file: {counters:?}"
        );
    }
    let last_seen = stored
        .iter()
        .find(|b| b.bite_counter == i64::from(in_plc))
        .unwrap();
    assert_eq!(last_seen.taf.map(|taf| taf as f32), Some(taf_in_plc));
    let before = stored.last().unwrap().clone();
    assert!(
        before.wear_trend.is_some(),
        "the driveline model gives a trend"
    );

    // Second run on the same file: the state comes back before any new bite.
    let mut second = spawn(&config_path, &scratch.join("second.log"));
    // The PLC still holds the killed run's last write; the second run's first writes
    // are the ones with the restored flag.
    until(
        "the second run writes the PLC",
        Duration::from_secs(20),
        || plc.flags() & driveline_flags::RESTORED != 0,
    )
    .await;
    assert_eq!(
        plc.counter(),
        before.bite_counter as u32,
        "the counter restored"
    );
    assert!(
        plc.flags() & driveline_flags::ALARM != 0,
        "the alarm still latched"
    );
    let restored = before.bite_counter as u32;
    until("a bite after the restart", Duration::from_secs(20), || {
        plc.counter() > restored
    })
    .await;
    assert_eq!(
        plc.flags() & driveline_flags::RESTORED,
        0,
        "a new bite clears it"
    );
    assert!(
        plc.flags() & driveline_flags::ALARM != 0,
        "latched until acknowledged"
    );

    // The trend goes on from the restored value: the first bite of the second run
    // with a wear index (not degraded) moved it by one EWMA step.
    until(
        "a bite of the second run with a wear index",
        Duration::from_secs(20),
        || {
            bites(&history).iter().any(|b| {
                b.bite_counter > before.bite_counter && b.wear_index.is_some() && !b.degraded
            })
        },
    )
    .await;
    let after = bites(&history);
    assert!(after.iter().all(|b| b.run_id >= before.run_id));
    let resumed: Vec<&BiteRow> = after
        .iter()
        .filter(|b| b.bite_counter > before.bite_counter)
        .collect();
    assert_eq!(
        resumed[0].bite_counter,
        before.bite_counter + 1,
        "the counter continues"
    );
    let mut trend = before.wear_trend;
    for bite in resumed {
        let expected = match (bite.wear_index, bite.degraded) {
            (Some(index), false) => Some(next_trend(trend, index)),
            _ => trend,
        };
        assert_eq!(bite.wear_trend, expected, "bite {}", bite.bite_counter);
        trend = expected;
    }

    // Acknowledged over the gateway's Modbus server from loopback: the PLC's host.
    {
        use tokio_modbus::client::Writer;
        let server = std::net::SocketAddr::from(([127, 0, 0, 1], server_port));
        let mut hmi = tokio_modbus::client::tcp::connect_slave(server, tokio_modbus::Slave(1))
            .await
            .unwrap();
        let command = plc.at("command.acknowledge_alarms") as u16;
        hmi.write_single_register(command, 1)
            .await
            .unwrap()
            .unwrap();
    }
    until(
        "the acknowledgement in the file",
        Duration::from_secs(10),
        || {
            HistoryReader::open(&history)
                .unwrap()
                .alarms(&Filter::default())
                .unwrap()
                .iter()
                .any(|a| a.event == "acknowledged" && a.origin == "plc")
        },
    )
    .await;

    let term = Command::new("kill")
        .args(["-TERM", &second.id().to_string()])
        .status()
        .unwrap();
    assert!(term.success());
    let status = second.wait().unwrap();
    assert!(status.success(), "{status:?}");
    let runs = HistoryReader::open(&history)
        .unwrap()
        .runs(&Filter::default())
        .unwrap();
    let ends: Vec<Option<&str>> = runs.iter().map(|r| r.ended.as_deref()).collect();
    assert_eq!(ends, [Some("unclean"), Some("stopped")]);
    let alarms = HistoryReader::open(&history)
        .unwrap()
        .alarms(&Filter::default())
        .unwrap();
    let raised = alarms
        .iter()
        .filter(|a| a.kind == "taf_alarm" && a.event == "raised")
        .count();
    assert_eq!(
        raised, 1,
        "latched across the restart, raised once: {alarms:#?}"
    );
    devices.stop().await.unwrap();
    let _ = std::fs::remove_dir_all(&scratch);
}
