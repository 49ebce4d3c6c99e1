//! `SIGHUP` to the real `millgate run` between the demo's virtual DAQ and PLC, while
//! bites stream (round-4 audit, finding 11: a hang-up ended the service with no final
//! write, the PLC's status left "running", the run `unclean`; issue 41: a reload
//! applies what it can): a file with errors is refused with them; new thresholds take
//! effect at the next bite and are recorded in the history; the maintenance page is
//! started, then moved to another port (the old one closes); a change of a bite
//! setting is named as needing a restart while the rest applies; `/metrics` counts
//! each outcome. The service runs on throughout, no bite id is missing from the
//! history, and it stops cleanly afterwards. `millgate reload` finds the service by
//! its pid file, refuses a file with errors itself and a stale pid file.
//!
//! A tandem mill's chatter thresholds by `SIGHUP` (issue 41): a virtual DAQ streams two
//! stands of steady tones, one in the chatter band and one in the reference band; the
//! mill's `gain_thresholds`, raised tenfold, divide its gain ratio by ten from the next
//! window on and the slow-down request clears after its hold, while its windows run on;
//! a window change is named as needing a restart.
//!
//! A driveline added within `outputs.driveline_slots` (issue 41): the PLC is written the
//! reserved block as zeros; a `SIGHUP` adding the driveline applies it without a
//! restart: its bites reach the history, the PLC in the reserved block, the HMI
//! server and `/metrics`, while every register of the running driveline keeps its
//! address and its bite ids run on without a gap. A driveline beyond the slots is
//! named as needing a restart and changes nothing.
//!
//! A driveline with a `model` added the same way (issue 41): a model file that is no
//! model refuses the reload (as it refuses a start); the demo's model starts live, its
//! gap maps built as the service runs (`building` with progress, then `ready` on the
//! web API, stored in the cache), its gap reaching its block in the PLC, while F1's
//! bites run on without a gap in their ids.
//!
//! A channel added on the running source (issue 41): its reader takes the channel
//! between two polls, on the connection it has, and the running channel misses no
//! block.
//!
//! A driveline added again under a name the history knows: F1 and F2 (with F1's model)
//! run; F2's removal waits for a restart, and after it a `SIGHUP` adding F2 again
//! resumes what the history kept of it, as a start would: its bite counter on the
//! PLC, the HMI server, `/metrics` and the web API continues from the kept one, its
//! bite ids in the history run on without a repeat, its first bite continues the wear
//! trend it had and its gap trend holds its earlier bites.

mod common;

use std::time::Duration;

use common::tandem::{modbus_source, Stands, FS};
use common::{
    answered_by_sighup, applied_by_sighup, bite_ids, free_port, hang_up, http, millgate, reloads,
    scratch, terminate, text, wait_for, KillOnDrop, Setup, MILLGATE,
};
use millgate_config::RegisterTable;
use millgate_sim::devices::modbus_bank::ServeOptions;
use millgate_sim::devices::virtual_daq::{DaqChannel, Placement, Publish, VirtualDaq};

use millgate::history::query::{Filter, HistoryReader};
use millgate::outputs::modbus::register_map::{decode_u32, RegisterMap};

const WARNING: &str = "millgate_driveline_taf_warning{driveline=\"F1\"}";

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sighup_applies_what_it_can_names_the_rest_and_loses_no_bite() {
    let setup = Setup::new(MILLGATE, "reload", "db").await;
    let plc = setup.plc();
    let original = std::fs::read_to_string(&setup.config).unwrap();
    let pid_file = setup.scratch.join("millgate.pid");
    let pid_arg = pid_file.to_str().unwrap();
    let mut service = setup.spawn_with(MILLGATE.command(), "run.log", &["--pid-file", pid_arg]);
    plc.bites_after_now(1).await;
    // The demo's bites pass the test's TAF warning threshold, 1.1.
    let limit = Duration::from_secs(40);
    setup.until_metric(WARNING, 1.0, limit).await;

    let (first_web, second_web) = (free_port(), free_port());
    let calm = original.replace(
        "taf_warning = 1.1, taf_alarm = 1.15,",
        "taf_warning = 40.0, taf_alarm = 50.0,",
    );
    assert_ne!(
        calm, original,
        "the test's thresholds are no longer in the file"
    );
    let web = |port: u16| format!("\n[outputs.web]\nbind = \"127.0.0.1:{port}\"\n");
    let later_bites = calm.replace("threshold_knm = 20.0", "threshold_knm = 21.0");
    assert_ne!(later_bites, calm, "the demo's bite threshold changed");
    let cases = [
        (
            original.replace("taf_alarm = 1.15,", "taf_alarm = -1.0,"),
            "reload refused: the configuration has errors",
        ),
        (
            calm.clone() + &web(first_web),
            "reload: applied outputs.web, drivelines.F1.thresholds outcome",
        ),
        (
            later_bites.clone() + &web(second_web),
            "reload: applied outputs.web; changed drivelines.F1.bite: applying them needs a restart",
        ),
        (
            later_bites + &web(second_web),
            "reload: changed drivelines.F1.bite: applying them needs a restart",
        ),
    ];
    for (index, (file, said)) in cases.into_iter().enumerate() {
        let before = setup.log_text("run.log").matches(said).count();
        std::fs::write(&setup.config, file).unwrap();
        if index < 3 {
            hang_up(service.id());
        } else {
            // The same through `millgate reload`, which checks the file first.
            let config = setup.config.to_str().unwrap();
            let asked = millgate(&["reload", "--pid-file", pid_arg, "--config", config]);
            assert!(asked.status.success(), "{}", text(&asked));
            assert!(text(&asked).contains(&format!("pid {}", service.id())));
        }
        wait_for(said, Duration::from_secs(20), || {
            setup.log_text("run.log").matches(said).count() > before
        })
        .await;
        assert!(
            service.try_wait().unwrap().is_none(),
            "SIGHUP ended the service"
        );
        match index {
            1 => {
                // The page runs, and the next bite is judged by the new thresholds.
                let page = http(first_web, "GET", "/api/overview").await;
                assert_eq!(page.status, 200, "{}", page.body);
                setup.until_metric(WARNING, 0.0, limit).await;
            }
            2 => {
                let page = http(second_web, "GET", "/api/overview").await;
                assert_eq!(page.status, 200, "{}", page.body);
                let old = tokio::net::TcpStream::connect(("127.0.0.1", first_web)).await;
                assert!(old.is_err(), "the page's old port still answers");
            }
            _ => {}
        }
    }
    let log = setup.log_text("run.log");
    assert!(
        log.contains("taf_alarm"),
        "the refusal names the key: {log}"
    );
    // `millgate reload` refuses a file with errors itself: the service is not asked.
    let broken = setup.scratch.join("broken.toml");
    std::fs::write(
        &broken,
        original.replace("taf_alarm = 1.15,", "taf_alarm = -1.0,"),
    )
    .unwrap();
    let refused = millgate(&[
        "reload",
        "--pid-file",
        pid_arg,
        "--config",
        broken.to_str().unwrap(),
    ]);
    assert!(!refused.status.success());
    assert!(text(&refused).contains("taf_alarm"), "{}", text(&refused));
    for (outcome, count) in [("applied", 1.0), ("refused", 1.0), ("needs_restart", 2.0)] {
        assert_eq!(
            setup.metric(&reloads(outcome)).await,
            Some(count),
            "{outcome}"
        );
    }
    // Still analysing and writing the PLC; the alarm latched before stays latched.
    plc.bites_after_now(2).await;
    assert_eq!(setup.metric(WARNING).await, Some(0.0));
    terminate(&mut service);
    assert!(!pid_file.exists(), "the pid file outlived the service");
    // A stale pid file (a killed service's, its pid reused) is not signalled.
    std::fs::write(&pid_file, format!("{}\n", std::process::id())).unwrap();
    let stale = millgate(&["reload", "--pid-file", pid_arg]);
    assert!(!stale.status.success());
    assert!(
        text(&stale).contains("not a running millgate"),
        "{}",
        text(&stale)
    );

    let history = HistoryReader::open(&setup.history).unwrap();
    let runs = history.runs(&Filter::default()).unwrap();
    let ends: Vec<Option<&str>> = runs.iter().map(|r| r.ended.as_deref()).collect();
    assert_eq!(ends, [Some("stopped")]);
    // Every bite the PLC saw is in the history, none missing around the reloads.
    let ids: Vec<u32> = history
        .bites(&Filter::default())
        .unwrap()
        .iter()
        .map(|bite| bite.figures.bite_counter)
        .collect();
    let last = plc.counter();
    assert!(ids.len() >= 4, "{ids:?}");
    assert_eq!(
        ids,
        (1..=last).collect::<Vec<_>>(),
        "bite ids in the history"
    );
    // The thresholds as applied, after the run's own.
    let settings: Vec<(f64, f64)> = history
        .settings(&Filter::default())
        .unwrap()
        .iter()
        .filter(|row| row.driveline == "F1")
        .map(|row| (row.taf_warning, row.taf_alarm))
        .collect();
    assert_eq!(settings, [(1.1, 1.15), (40.0, 50.0)]);
    setup.stop(service).await;
}

/// The value of `/metrics`' line for `name` (labels after it), when published.
async fn tandem_metric(port: u16, name: &str) -> Option<f64> {
    let page = http(port, "GET", "/metrics").await.body;
    page.lines()
        .find_map(|line| line.strip_prefix(name)?.strip_prefix('{'))
        .and_then(|rest| rest.rsplit(' ').next()?.parse().ok())
        .filter(|value: &f64| value.is_finite())
}

/// The sum of `/metrics`' lines for `name` over its labels.
async fn metric_total(port: u16, name: &str) -> f64 {
    let page = http(port, "GET", "/metrics").await.body;
    page.lines()
        .filter_map(|line| line.strip_prefix(name)?.strip_prefix('{'))
        .filter_map(|rest| rest.rsplit(' ').next()?.parse::<f64>().ok())
        .sum()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sighup_applies_a_tandem_mills_thresholds_at_its_next_window() {
    const RATIO: &str = "millgate_tandem_mill_gain_ratio";
    const REQUEST: &str = "millgate_tandem_mill_slow_down_request";
    const STALE: &str = "millgate_tandem_mill_source_stale";
    const WINDOWS: &str = "millgate_tandem_mill_evaluations_total";
    const MISSED: &str = "millgate_channel_blocks_missed_total";
    let folder = scratch("reload-tandem");
    // Per stand 1 m/s^2 at 200 Hz (chatter band 100-300 Hz) and at 600 Hz (the default
    // reference band, 450-900 Hz): a steady gain near 1. One second loops seamlessly.
    let tones: Vec<f64> = (0..FS as usize)
        .map(|i| {
            let t = i as f64 / FS;
            (std::f64::consts::TAU * 200.0 * t).sin() + (std::f64::consts::TAU * 600.0 * t).sin()
        })
        .collect();
    let channels = (0..2)
        .map(|stand| DaqChannel {
            placement: Placement {
                table: RegisterTable::Input,
                address: stand * 122,
                scale: 0.01,
                offset: 0.0,
            },
            publish: Publish::Block,
            signal: tones.clone(),
        })
        .collect();
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let daq_address = listener.local_addr().unwrap().to_string();
    let _daq = VirtualDaq::new(FS, 120, channels)
        .looped()
        .spawn(listener, ServeOptions::default());
    let metrics = free_port();
    let file = |thresholds: &[f64], keys: &str| {
        String::from("name = \"reload tandem\"\n")
            + &modbus_source("daq").replace("127.0.0.1:1", &daq_address)
            + &Stands::modbus(2, "daq")
                .thresholds(thresholds)
                .keys(&format!("slow_down_hold_s = 0.5\n{keys}"))
                .toml()
            + &format!("[outputs.metrics]\nbind = \"127.0.0.1:{metrics}\"\n")
    };
    let config = folder.path().join("mill.toml");
    std::fs::write(&config, file(&[0.5, 0.5], "")).unwrap();
    let log = folder.path().join("run.log");
    let mut service = KillOnDrop(
        MILLGATE
            .command()
            .args(["run", "--config", config.to_str().unwrap()])
            .env("RUST_LOG", "info")
            .stdout(std::process::Stdio::null())
            .stderr(std::fs::File::create(&log).unwrap())
            .spawn()
            .unwrap(),
    );
    let log_text = || std::fs::read_to_string(&log).unwrap_or_default();
    let limit = Duration::from_secs(30);
    let start = std::time::Instant::now();
    while tokio::net::TcpStream::connect(("127.0.0.1", metrics))
        .await
        .is_err()
    {
        assert!(start.elapsed() < limit, "no /metrics: {}", log_text());
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    // A gain near 1 against thresholds of 0.5: the alarm and the slow-down request.
    loop {
        if tandem_metric(metrics, REQUEST).await == Some(1.0) {
            break;
        }
        assert!(
            start.elapsed() < limit,
            "no slow-down request: {}",
            log_text()
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    let before = tandem_metric(metrics, RATIO).await.expect("a gain ratio");
    assert!((1.5..2.5).contains(&before), "gain ratio {before}");
    let windows = tandem_metric(metrics, WINDOWS).await.unwrap();

    let missed_before = metric_total(metrics, MISSED).await;
    std::fs::write(&config, file(&[5.0, 5.0], "")).unwrap();
    hang_up(service.id());
    let said = "reload: applied tandem_mills.TCM.gain_thresholds";
    wait_for(said, Duration::from_secs(20), || log_text().contains(said)).await;
    // From the next window the ratio is a tenth; the request clears after its hold
    // (0.5 s below the release level). Steady streaming does not restart the window,
    // but a stand may be re-anchored once on a busy machine (`chatter_e2e`): at most
    // one restart is tolerated, and counted.
    let (mut restarts, mut was_stale) = (0, false);
    let start = std::time::Instant::now();
    let after = loop {
        let stale = tandem_metric(metrics, STALE).await == Some(1.0);
        restarts += usize::from(stale && !was_stale);
        was_stale = stale;
        let ratio = tandem_metric(metrics, RATIO).await;
        if let (Some(0.0), Some(ratio)) = (tandem_metric(metrics, REQUEST).await, ratio) {
            break ratio;
        }
        assert!(
            start.elapsed() < limit,
            "the request stayed: {}",
            log_text()
        );
        tokio::time::sleep(Duration::from_millis(20)).await;
    };
    // A stand block lost (a reader descheduled past its block period on a loaded
    // machine) restarts the window whatever the reload: the count is asserted only
    // when none was, and said otherwise.
    let missed = metric_total(metrics, MISSED).await - missed_before;
    if missed == 0.0 {
        assert!(
            restarts <= 1,
            "{restarts} window restarts around the reload"
        );
    } else {
        eprintln!("{missed} stand blocks missed around the reload: {restarts} window restarts");
    }
    assert!(
        (after / (before / 10.0) - 1.0).abs() < 0.02,
        "gain ratio {before} before, {after} after thresholds ten times higher"
    );
    let windows_after = tandem_metric(metrics, WINDOWS).await.unwrap();
    assert!(windows_after > windows, "{windows} -> {windows_after}");
    assert_eq!(
        tandem_metric(metrics, "millgate_tandem_mill_chatter_alarm").await,
        Some(1.0),
        "the alarm latched before stays latched until acknowledged"
    );

    // A window change waits for a restart, named; the thresholds run on.
    std::fs::write(
        &config,
        file(&[5.0, 5.0], "window_s = 1.0\n").replace("window_s = 0.5\n", ""),
    )
    .unwrap();
    hang_up(service.id());
    let said = "reload: changed tandem_mills.TCM.window_s: applying them needs a restart";
    wait_for(said, Duration::from_secs(20), || log_text().contains(said)).await;
    assert!(
        service.try_wait().unwrap().is_none(),
        "SIGHUP ended the service"
    );
    let page = http(metrics, "GET", "/metrics").await.body;
    for (outcome, count) in [("applied", 1), ("needs_restart", 1)] {
        let line = format!("millgate_config_reloads_total{{outcome=\"{outcome}\"}} {count}");
        assert!(page.contains(&line), "{line} not in {page}");
    }
    let ratio = tandem_metric(metrics, RATIO).await.unwrap();
    assert!((ratio / after - 1.0).abs() < 0.02, "{after} -> {ratio}");
    terminate(&mut service);
}

/// The u32 the PLC holds at `address`.
fn u32_in_plc(setup: &Setup, address: u16) -> u32 {
    decode_u32(&setup.devices.plc.holding()[usize::from(address)..]).unwrap_or(0)
}

/// The address of F2's bite counter in `map`, once the PLC holds two bites of F2 there.
async fn f2_bites_in_plc(setup: &Setup, map: &RegisterMap) -> u16 {
    let address = map.named("F2.bite_counter").unwrap().address;
    wait_for("F2's bites in the PLC", Duration::from_secs(40), || {
        u32_in_plc(setup, address) >= 2
    })
    .await;
    address
}

/// `setup`'s configuration in the demo's first layout (no extension blocks) with two
/// driveline slots: `top` (top-level keys) before the demo's file, `more` after the
/// slots. Its register map.
fn two_slots(setup: &Setup, top: &str, more: &str) -> RegisterMap {
    let demo = std::fs::read_to_string(&setup.config).unwrap();
    let first_layout = demo.replace("extension_blocks = true", "extension_blocks = false");
    std::fs::write(&setup.config, format!("{top}{first_layout}")).unwrap();
    setup.append_config(&format!("\n[outputs]\ndriveline_slots = 2\n{more}"));
    map_of(&setup.config)
}

/// Each driveline's bite ids in `setup`'s history are every one from 1 to its last
/// (the PLC's), in order.
fn every_bite_id(setup: &Setup, lasts: &[(&str, u32)]) {
    let history = HistoryReader::open(&setup.history).unwrap();
    for &(name, last) in lasts {
        let expected: Vec<u32> = (1..=last).collect();
        assert_eq!(bite_ids(&history, name), expected, "{name}'s bite ids");
    }
}

/// The register map of the configuration file at `path`.
fn map_of(path: &std::path::Path) -> RegisterMap {
    RegisterMap::new(&millgate_config::load(path).unwrap_or_else(|error| panic!("{error}")))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_driveline_added_within_the_reserved_slots_starts_live_and_moves_no_address() {
    let setup = Setup::new(MILLGATE, "reload-slots", "db").await;
    // The kit's PLC holds the demo's map (16 + 32 + 32 registers and 16 more): with a
    // slot reserved, the first layout (16 + 2 * 32) fits it, the extension blocks not.
    let demo = std::fs::read_to_string(&setup.config).unwrap();
    let first_layout = demo.replace("extension_blocks = true", "extension_blocks = false");
    assert_ne!(
        first_layout, demo,
        "the demo writes the extension blocks no more"
    );
    std::fs::write(&setup.config, first_layout).unwrap();
    setup.append_config("\n[outputs]\ndriveline_slots = 2\n");
    let reserved = map_of(&setup.config);
    let slot = reserved
        .named("driveline_slot2.quality")
        .expect("the reserved block is listed")
        .address
        - 1;
    // `millgate registers` shows the reserved block where the PLC gets it.
    let config = setup.config.to_str().unwrap();
    let listed = millgate(&["registers", "--config", config, "--format", "csv"]);
    assert!(listed.status.success(), "{}", text(&listed));
    let row = format!("driveline_slot2.quality,{},{},u16", slot + 1, slot + 1);
    assert!(text(&listed).contains(&row), "{}", text(&listed));

    let mut service = setup.spawn("run.log");
    let plc = common::Plc {
        plc: &setup.devices.plc,
        map: &reserved,
    };
    plc.bites_after_now(1).await;
    let words = setup.devices.plc.holding();
    let block = usize::from(slot)..usize::from(slot + 32);
    assert!(words[block.clone()].iter().all(|w| *w == 0), "{words:?}");
    // A second driveline on the torque channel read for F1 (without a model), after
    // F1: added by a SIGHUP, without a restart.
    setup.add_driveline("F2");
    let before_reload = plc.counter();
    let said = "reload: applied drivelines.F2 (added in the register block of \
                driveline_slot2: no address moves)";
    applied_by_sighup(&setup, &service, said).await;

    // F2 takes the reserved block; every other register keeps its address.
    let grown = map_of(&setup.config);
    assert_eq!(grown.len(), reserved.len());
    assert_eq!(grown.named("F2.flags").map(|r| r.address), Some(slot));
    for register in reserved.registers() {
        if !register.name.starts_with("driveline_slot2.") {
            assert_eq!(
                grown.named(&register.name).map(|r| r.address),
                Some(register.address),
                "{} moved",
                register.name
            );
        }
    }
    // F2's bites reach the PLC in its block, the HMI server and /metrics, while F1
    // writes where it did: the same process.
    let f2_counter = f2_bites_in_plc(&setup, &grown).await;
    let f2_in_plc = || u32_in_plc(&setup, f2_counter);
    assert!(plc.counter() > before_reload, "F1 writes where it did");
    assert!(common::hmi_u32(setup.server_port, f2_counter).await >= 2);
    let f2_metric = "millgate_driveline_bites_total{driveline=\"F2\"}";
    let f2_bites = setup.metric(f2_metric).await;
    assert!(f2_bites.is_some_and(|bites| bites >= 2.0), "{f2_bites:?}");
    assert!(
        service.try_wait().unwrap().is_none(),
        "SIGHUP ended the service"
    );

    // A third driveline is beyond the two slots (with three slots, or the file is
    // refused): it needs a restart (it would move the blocks after the drivelines')
    // and changes nothing meanwhile.
    let beyond = setup
        .add_driveline("F3")
        .replace("driveline_slots = 2", "driveline_slots = 3");
    std::fs::write(&setup.config, &beyond).unwrap();
    let said = "drivelines (added F3 (beyond the 2 driveline blocks";
    answered_by_sighup(&setup, &service, said, "needs_restart").await;
    let f2_before = f2_in_plc();
    plc.bites_after_now(1).await;
    wait_for("F2's next bite in the PLC", Duration::from_secs(40), || {
        f2_in_plc() > f2_before
    })
    .await;
    let page = setup.metrics().await;
    assert!(!page.contains("driveline=\"F3\""), "{page}");
    terminate(&mut service);

    let history = HistoryReader::open(&setup.history).unwrap();
    let ids = |name: &str| bite_ids(&history, name);
    let (f1, f2, f3) = (ids("F1"), ids("F2"), ids("F3"));
    // Nothing of F1 lost across the reloads: its ids are every one the PLC saw.
    assert_eq!(f1, (1..=plc.counter()).collect::<Vec<_>>(), "F1's bite ids");
    let last_f2 = f2_in_plc();
    assert_eq!(f2, (1..=last_f2).collect::<Vec<_>>(), "F2's bite ids");
    assert!(f3.is_empty(), "F3 is not analysed before a restart: {f3:?}");
    setup.stop(service).await;
}

/// The entry of `file` from the line `first` to the blank line after it.
fn entry<'f>(file: &'f str, first: &str) -> &'f str {
    let start = file
        .find(first)
        .unwrap_or_else(|| panic!("{first} not in {file}"));
    let length = file[start..].find("\n\n").unwrap_or(file.len() - start);
    &file[start..start + length]
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_driveline_on_a_source_added_live_starts_without_a_restart() {
    let setup = Setup::new(MILLGATE, "reload-source", "db").await;
    let reserved = two_slots(&setup, "", "");
    let mut service = setup.spawn("run.log");
    let plc = common::Plc {
        plc: &setup.devices.plc,
        map: &reserved,
    };
    plc.bites_after_now(1).await;
    // A second Modbus source (a second connection to the virtual DAQ), a torque
    // channel on it and F2 on that channel: none read by the running service.
    let original = std::fs::read_to_string(&setup.config).unwrap();
    let source = entry(&original, "[[sources.modbus]]").replace("\"daq1\"", "\"daq2\"");
    let channel = entry(&original, "[[channels]]\nname = \"spindle_top\"")
        .replace("\"spindle_top\"", "\"spindle_f2\"")
        .replace("modbus = \"daq1\"", "modbus = \"daq2\"");
    assert!(
        source.contains("daq2") && channel.contains("daq2"),
        "{source}\n{channel}"
    );
    let f2 = "[[drivelines]]\nname = \"F2\"\ntorque = \"spindle_f2\"\n\
              bite = { threshold_knm = 20.0, pre_trigger_s = 0.1, post_trigger_s = 0.5 }\n\
              thresholds = { taf_warning = 2.2, taf_alarm = 2.6 }\n\n[outputs.plc]";
    let added = format!(
        "{}\n{source}\n\n{channel}\n",
        original.replacen("[outputs.plc]", f2, 1)
    );
    std::fs::write(&setup.config, &added).unwrap();
    let before_reload = plc.counter();
    let said = "reload: applied sources.daq2 (its reader started live), channels.spindle_f2 \
                (on a source added live), drivelines.F2 (added in the register block of \
                driveline_slot2: no address moves)";
    applied_by_sighup(&setup, &service, said).await;

    // F2's bites, read by the new source's reader, reach the PLC in the reserved block
    // and /metrics, with the new source's health and counters; F1 runs on.
    let grown = map_of(&setup.config);
    assert_eq!(grown.len(), reserved.len());
    let f2_counter = f2_bites_in_plc(&setup, &grown).await;
    let f2_in_plc = || u32_in_plc(&setup, f2_counter);
    assert!(plc.counter() > before_reload, "F1 writes where it did");
    let connects = setup
        .metric("millgate_source_connects_total{source=\"daq2\"}")
        .await;
    assert!(connects.is_some_and(|c| c >= 1.0), "{connects:?}");
    let blocks = setup
        .metric("millgate_channel_blocks_read_total{channel=\"spindle_f2\"}")
        .await;
    assert!(blocks.is_some_and(|b| b >= 1.0), "{blocks:?}");
    assert!(
        service.try_wait().unwrap().is_none(),
        "SIGHUP ended the service"
    );
    terminate(&mut service);

    // Nothing of F1 lost across the reload; F2's ids run from 1 to the PLC's last.
    every_bite_id(&setup, &[("F1", plc.counter()), ("F2", f2_in_plc())]);
    setup.stop(service).await;
}

/// The `(sum, count)` of the histogram `name` on the `/metrics` page `page`.
fn histogram(page: &str, name: &str) -> (f64, f64) {
    let value = |suffix: &str| {
        let prefix = format!("{name}_{suffix} ");
        page.lines()
            .find_map(|line| line.strip_prefix(&prefix)?.parse().ok())
            .unwrap_or(0.0)
    };
    (value("sum"), value("count"))
}

/// The mean of the histogram `name` between the `/metrics` pages `before` and
/// `after`, ms, and how many it observed meanwhile.
fn mean_between(before: &str, after: &str, name: &str) -> (f64, f64) {
    let ((sum0, count0), (sum1, count1)) = (histogram(before, name), histogram(after, name));
    let count = count1 - count0;
    (1e3 * (sum1 - sum0) / count.max(1.0), count)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_driveline_with_a_model_added_live_builds_its_gap_maps_as_the_service_runs() {
    let setup = Setup::new(MILLGATE, "reload-model", "db").await;
    let log_on_failure = setup.log_on_failure("run.log");
    let cache = setup.scratch.join("cache");
    let web = free_port();
    let demo = std::fs::read_to_string(&setup.config).unwrap();
    // The gap maps' cache in the scratch folder: F1's built at the start, F2's live.
    let reserved = two_slots(
        &setup,
        &format!("cache_dir = \"{}\"\n", cache.display()),
        &format!("\n[outputs.web]\nbind = \"127.0.0.1:{web}\"\n"),
    );
    let mut service = setup.spawn("run.log");
    let plc = common::Plc {
        plc: &setup.devices.plc,
        map: &reserved,
    };
    plc.bites_after_now(1).await;
    let map_state = move |name: &'static str| async move {
        let answer = http(web, "GET", &format!("/api/drivelines/{name}/map")).await;
        assert_eq!(answer.status, 200, "{}", answer.body);
        answer.json()
    };
    // F1's maps (built at the start) first: what F1 does meanwhile is the baseline.
    let start = std::time::Instant::now();
    while map_state("F1").await["state"] != "ready" {
        assert!(start.elapsed() < Duration::from_secs(60), "F1's maps");
        tokio::time::sleep(Duration::from_millis(50)).await;
    }

    // F2 on F1's torque channel, with the demo's model and maps of another grid than
    // F1's (so they are built, not read from F1's cache file).
    let model_line = demo
        .lines()
        .find(|line| line.starts_with("model = "))
        .expect("F1 names the demo's model")
        .to_owned();
    let with_model = |model: &str| {
        let added = setup.add_driveline("F2");
        let f2 = format!(
            "name = \"F2\"\n{model}\nwear = {{ gap_step_mrad = 0.125, torque_points = 12 }}\n"
        );
        std::fs::write(&setup.config, added.replacen("name = \"F2\"\n", &f2, 1)).unwrap();
    };
    // A model file that is no model: the reload is refused as a start would be, and
    // nothing is added.
    let original = std::fs::read_to_string(&setup.config).unwrap();
    with_model(&format!("model = \"{}\"", setup.config.display()));
    answered_by_sighup(&setup, &service, "drivelines[1].model", "refused").await;
    assert_eq!(http(web, "GET", "/api/drivelines/F2/map").await.status, 404);

    std::fs::write(&setup.config, &original).unwrap();
    with_model(&model_line);
    let before_reload = setup.metrics().await;
    let counter_before = plc.counter();
    let said = "reload: applied drivelines.F2 (added in the register block of \
                driveline_slot2: no address moves; its gap maps read from the cache or \
                built as the service runs)";
    applied_by_sighup(&setup, &service, said).await;
    let applied_at = setup.metrics().await;

    // Building, then ready: the first answer is `building` unless the build was done
    // before it (its log line says so).
    let ready_line = "gap maps ready driveline=F2";
    let first = map_state("F2").await;
    if first["state"] != "ready" || !setup.log_text("run.log").contains(ready_line) {
        assert_eq!(first["state"], "building", "{first}");
        assert!(first["simulations"].is_array(), "{first}");
    }
    let start = std::time::Instant::now();
    let mut progress = Vec::new();
    let map = loop {
        let map = map_state("F2").await;
        if map["state"] != "building" {
            break map;
        }
        progress.push(map["simulations"][0].as_u64().unwrap());
        assert!(
            start.elapsed() < Duration::from_secs(120),
            "F2's maps: {map}"
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    };
    let ready_at = setup.metrics().await;
    assert_eq!(map["state"], "ready", "{map}");
    assert!(progress.windows(2).all(|p| p[0] <= p[1]), "{progress:?}");
    assert_eq!(
        map["model"], "Table 2 driveline, stiffness adjusted to measurement",
        "{map}"
    );
    // Built live (not read from F1's cache file) and stored beside F1's.
    let log = setup.log_text("run.log");
    let built = log
        .lines()
        .find(|line| line.contains(ready_line))
        .unwrap_or_else(|| panic!("no {ready_line}"));
    assert!(built.contains("origin=Built"), "{built}");
    let cached = std::fs::read_dir(&cache).unwrap().count();
    assert_eq!(cached, 2, "F1's and F2's maps in {}", cache.display());

    // F2's bites reach its block in the PLC, and once the maps are in, its gap.
    let grown = map_of(&setup.config);
    assert_eq!(grown.len(), reserved.len());
    f2_bites_in_plc(&setup, &grown).await;
    let f2 = common::Plc {
        plc: &setup.devices.plc,
        map: &grown,
    };
    let gap_valid = 1 << 9;
    wait_for("F2's gap in the PLC", Duration::from_secs(40), || {
        setup.devices.plc.holding()[f2.at("F2.quality")] & gap_valid != 0
    })
    .await;
    let gap = f2.f32_of("F2.gap_mrad");
    assert!((0.0..=8.0).contains(&gap), "F2's gap {gap} mrad");
    let pooled = setup.devices.plc.holding()[f2.at("F2.bites_pooled")];
    assert!(pooled >= 1, "{pooled} bites in F2's wear trend");
    let wear_valid = 1 << 7;
    assert_ne!(
        setup.devices.plc.holding()[f2.at("F2.quality")] & wear_valid,
        0,
        "F2's linear wear index"
    );
    assert!(plc.counter() > counter_before, "F1 writes where it did");
    assert!(
        service.try_wait().unwrap().is_none(),
        "the reload ended the service"
    );
    // What the build cost F1: its bites' latency to the PLC and the blocks' wait for
    // the analysis, before the reload and while F2's maps built (printed, not judged:
    // a figure of one run on a shared machine).
    for family in [
        "millgate_bite_to_plc_seconds",
        "millgate_block_wait_seconds",
    ] {
        let (before_ms, before_n) = mean_between("", &before_reload, family);
        let (during_ms, during_n) = mean_between(&applied_at, &ready_at, family);
        eprintln!(
            "{family}: mean {before_ms:.2} ms over {before_n} before the reload, \
             {during_ms:.2} ms over {during_n} while F2's maps built"
        );
    }
    eprintln!("{built}");
    terminate(&mut service);

    let last_f2 = decode_u32(&setup.devices.plc.holding()[f2.at("F2.bite_counter")..]).unwrap();
    every_bite_id(&setup, &[("F1", plc.counter()), ("F2", last_f2)]);
    drop(log_on_failure);
    setup.stop(service).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_channel_added_on_a_running_source_starts_without_a_restart_or_a_missed_block() {
    // The demo's DAQ serving the torque twice: at block 0 (read for F1) and at block
    // 122 (right after it), which the running service does not read yet.
    let setup = Setup::with_daq(MILLGATE, "reload-channel", "db", |config, schedule| {
        let torque = &config.channels[config.drivelines[0].torque];
        let channels = [0, 122]
            .map(|address| DaqChannel {
                placement: Placement {
                    table: RegisterTable::Input,
                    address,
                    scale: torque.scale,
                    offset: torque.offset,
                },
                publish: Publish::Block,
                signal: schedule.torque_knm.clone(),
            })
            .to_vec();
        let samples = millgate_sim::devices::demo::SAMPLES_PER_BLOCK;
        VirtualDaq::new(torque.sample_rate_hz, samples, channels)
    })
    .await;
    let reserved = two_slots(&setup, "", "");
    let mut service = setup.spawn("run.log");
    let log_guard = setup.log_on_failure("run.log");
    let plc = common::Plc {
        plc: &setup.devices.plc,
        map: &reserved,
    };
    plc.bites_after_now(1).await;
    // A channel on the running source daq1 (its second block) and F2 on it.
    let original = std::fs::read_to_string(&setup.config).unwrap();
    let channel = entry(&original, "[[channels]]\nname = \"spindle_top\"")
        .replace("\"spindle_top\"", "\"spindle_f2\"")
        .replace("block = 0 }", "block = 122 }");
    assert!(channel.contains("block = 122"), "{channel}");
    let f2 = "[[drivelines]]\nname = \"F2\"\ntorque = \"spindle_f2\"\n\
              bite = { threshold_knm = 20.0, pre_trigger_s = 0.1, post_trigger_s = 0.5 }\n\
              thresholds = { taf_warning = 2.2, taf_alarm = 2.6 }\n\n[outputs.plc]";
    let added = format!("{}\n{channel}\n", original.replacen("[outputs.plc]", f2, 1));
    std::fs::write(&setup.config, &added).unwrap();
    let counter = |name: &str, channel: &str| {
        format!("millgate_channel_{name}_total{{channel=\"{channel}\"}}")
    };
    let connects = "millgate_source_connects_total{source=\"daq1\"}";
    let missed_before = setup.metric(&counter("blocks_missed", "spindle_top")).await;
    let read_before = setup.metric(&counter("blocks_read", "spindle_top")).await;
    let connects_before = setup.metric(connects).await;
    assert_eq!(connects_before, Some(1.0), "daq1 connected once");
    let before_reload = plc.counter();
    let said = "reload: applied channels.spindle_f2 (on the running source daq1: its reader \
                takes it between two polls), drivelines.F2 (added in the register block of \
                driveline_slot2: no address moves)";
    applied_by_sighup(&setup, &service, said).await;
    let f2_read = counter("blocks_read", "spindle_f2");
    let start = std::time::Instant::now();
    while !setup.metric(&f2_read).await.is_some_and(|read| read >= 1.0) {
        assert!(
            start.elapsed() < Duration::from_secs(10),
            "spindle_f2 not read"
        );
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    let missed_at_hand_over = setup.metric(&counter("blocks_missed", "spindle_top")).await;

    // The running reader reads the new block, on the connection it had: F2's bites
    // reach the PLC in the reserved block; spindle_top's blocks run on.
    let grown = map_of(&setup.config);
    let f2_counter = f2_bites_in_plc(&setup, &grown).await;
    let f2_in_plc = || u32_in_plc(&setup, f2_counter);
    assert!(plc.counter() > before_reload, "F1 writes where it did");
    let f2_blocks = setup.metric(&counter("blocks_read", "spindle_f2")).await;
    assert!(f2_blocks.is_some_and(|b| b >= 1.0), "{f2_blocks:?}");
    assert_eq!(
        setup.metric(connects).await,
        connects_before,
        "daq1 reconnected"
    );
    let read_after = setup.metric(&counter("blocks_read", "spindle_top")).await;
    assert!(
        read_after > read_before,
        "{read_before:?} -> {read_after:?}"
    );
    // The hand-over itself loses no block (the reader's paused-clock test proves it);
    // on a loaded 2-core machine a reader descheduled for more than a block period
    // (50 ms) misses one whatever the reload: measured here, not asserted.
    let missed_after = setup.metric(&counter("blocks_missed", "spindle_top")).await;
    eprintln!(
        "spindle_top blocks missed: {missed_before:?} before the SIGHUP, \
         {missed_at_hand_over:?} once spindle_f2 was read, {missed_after:?} after F2's bites"
    );
    assert!(
        service.try_wait().unwrap().is_none(),
        "SIGHUP ended the service"
    );
    terminate(&mut service);
    every_bite_id(&setup, &[("F1", plc.counter()), ("F2", f2_in_plc())]);
    drop(log_guard);
    setup.stop(service).await;
}

/// The value of `key` in `object` (a driveline of the web API) as a number.
fn number(object: &serde_json::Value, key: &str) -> Option<f64> {
    object[key].as_f64()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_driveline_added_again_under_a_name_the_history_knows_resumes_its_state() {
    // The demo's bites for as long as the two runs take.
    let setup = Setup::with_daq(MILLGATE, "reload-resume", "db", |config, schedule| {
        millgate_sim::devices::demo::demo_daq(config, schedule)
            .unwrap()
            .looped()
    })
    .await;
    let log_on_failure = setup.log_on_failure("run.log");
    let cache = setup.scratch.join("cache");
    let web = free_port();
    two_slots(
        &setup,
        &format!("cache_dir = \"{}\"\n", cache.display()),
        &format!("\n[outputs.web]\nbind = \"127.0.0.1:{web}\"\n"),
    );
    let without_f2 = std::fs::read_to_string(&setup.config).unwrap();
    // F2: F1 again under another name (its model, wear grid and thresholds: its TAF
    // alarm latches at its first bite, its gap maps are F1's cache file).
    let f1 = entry(&without_f2, "[[drivelines]]");
    let f2 = f1.replace("F1", "F2");
    assert!(f1.contains("model = ") && f2.contains("\"F2\""), "{f1}");
    let with_f2 = without_f2.replacen(f1, &format!("{f1}\n\n{f2}"), 1);
    std::fs::write(&setup.config, &with_f2).unwrap();
    let map = map_of(&setup.config);
    let plc = common::Plc {
        plc: &setup.devices.plc,
        map: &map,
    };
    let f2_counter = plc.at("F2.bite_counter") as u16;
    let f2_in_plc = || u32_in_plc(&setup, f2_counter);
    let gap_valid = 1 << 9;

    // The first run: F1 and F2 from the start, until F2 has bites in its gap trend.
    let mut service = setup.spawn("run.log");
    wait_for("F2's gap in the PLC", Duration::from_secs(90), || {
        f2_in_plc() >= 3 && setup.devices.plc.holding()[plc.at("F2.quality")] & gap_valid != 0
    })
    .await;
    // Removing F2 waits for a restart; the restart applies it.
    std::fs::write(&setup.config, &without_f2).unwrap();
    answered_by_sighup(&setup, &service, "drivelines (removed F2)", "needs_restart").await;
    terminate(&mut service);
    drop(service);
    let history = HistoryReader::open(&setup.history).unwrap();
    let kept = history
        .driveline_state("F2")
        .unwrap()
        .expect("F2's state in the history");
    let kept_bites = kept.results.bite_counter;
    let kept_trend = kept.results.wear_trend.expect("F2's wear trend");
    let kept_pooled = kept.results.gap.expect("F2's gap").bites_pooled;
    assert!(kept_bites >= 3 && kept_pooled >= 1, "{kept:?}");
    assert!(kept.results.taf_alarm, "F2's TAF alarm latched: {kept:?}");
    assert!(kept.gap_trend.is_some(), "F2's saved gap trend");
    assert_eq!(
        bite_ids(&history, "F2"),
        (1..=kept_bites).collect::<Vec<_>>()
    );
    drop(history);

    // The second run, without F2: its block is the reserved slot's zeros.
    let mut service = setup.spawn("run.log");
    wait_for(
        "the reserved block written",
        Duration::from_secs(40),
        || f2_in_plc() == 0,
    )
    .await;
    plc.bites_after_now(1).await;
    // F2 added again by a SIGHUP: it resumes what the history kept of it.
    std::fs::write(&setup.config, &with_f2).unwrap();
    let said = format!(
        "reload: applied drivelines.F2 (added in the register block of driveline_slot2: \
         no address moves; its gap maps read from the cache or built as the service runs; \
         its state resumed from the history: bite counter {kept_bites}, last bite "
    );
    applied_by_sighup(&setup, &service, &said).await;
    let log = setup.log_text("run.log");
    let restored_line = log
        .lines()
        .find(|line| line.contains("state restored from the history") && line.contains("F2"))
        .unwrap_or_else(|| panic!("no state restored for F2 in {log}"));
    assert!(
        restored_line.contains(&format!("bite_counter={kept_bites}")),
        "{restored_line}"
    );
    // From the reload's answer on, every output shows F2's counter at least where the
    // history had it (at it until its next bite, then past it), never from 0.
    let f2_metric = "millgate_driveline_bites_total{driveline=\"F2\"}";
    let bites = setup.metric(f2_metric).await;
    assert!(
        bites.is_some_and(|bites| bites >= f64::from(kept_bites)),
        "{f2_metric} {bites:?}, the history {kept_bites}"
    );
    let api = http(web, "GET", "/api/drivelines/F2").await.json();
    let counter = number(&api, "bite_counter").unwrap_or(0.0);
    assert!(counter >= f64::from(kept_bites), "{api}");
    if counter == f64::from(kept_bites) {
        // Before its next bite: the restored state itself.
        assert_eq!(number(&api, "wear_trend"), Some(kept_trend), "{api}");
        assert_eq!(api["taf_alarm"], true, "{api}");
    }
    wait_for("F2's counter in the PLC", Duration::from_secs(40), || {
        f2_in_plc() != 0
    })
    .await;
    let first_in_plc = f2_in_plc();
    assert!(first_in_plc >= kept_bites, "{first_in_plc} < {kept_bites}");
    wait_for(
        "F2's next bites in the PLC",
        Duration::from_secs(60),
        || {
            f2_in_plc() >= kept_bites + 3
                && setup.devices.plc.holding()[plc.at("F2.quality")] & gap_valid != 0
        },
    )
    .await;
    assert!(common::hmi_u32(setup.server_port, f2_counter).await > kept_bites);
    terminate(&mut service);

    // In the history: F2's ids run on from the kept counter without a repeat; its
    // first bite after the reload continued the wear trend it had, and its gap trend
    // holds more bites than it saw since (the kept ones with them).
    let last = f2_in_plc();
    every_bite_id(&setup, &[("F2", last)]);
    let history = HistoryReader::open(&setup.history).unwrap();
    let filter = Filter {
        name: Some("F2".to_owned()),
        ..Filter::default()
    };
    let rows = history.bites(&filter).unwrap();
    let after: Vec<_> = rows
        .iter()
        .filter(|row| row.figures.bite_counter > kept_bites)
        .collect();
    let first = after.first().expect("F2's bites after the reload");
    assert_eq!(first.figures.bite_counter, kept_bites + 1);
    let expected = match first.figures.wear_index {
        Some(index) => millgate::analysis::wear::next_trend(Some(kept_trend), index),
        None => kept_trend,
    };
    let trend = first.figures.wear_trend.expect("F2's wear trend");
    assert!(
        (trend - expected).abs() <= 1e-9 * expected.abs().max(1.0),
        "{trend} != {expected}"
    );
    let with_gap = after
        .iter()
        .find_map(|row| Some((row.figures.bite_counter - kept_bites, row.figures.gap?)))
        .expect("a gap after the reload");
    assert!(
        with_gap.1.bites_pooled > with_gap.0 as usize,
        "{} bites in F2's gap trend at the {}th bite after the reload (kept {kept_pooled})",
        with_gap.1.bites_pooled,
        with_gap.0
    );
    drop(log_on_failure);
    setup.stop(service).await;
}
