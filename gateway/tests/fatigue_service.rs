//! The fatigue ledger in the running service, end to end: the demo's virtual DAQ
//! streams four simulated bars of the Table 2 driveline with a 2 mrad gap over Modbus
//! TCP (the real field path: i16 blocks, the block reader), the service counts the
//! whole torque stream, and
//!
//! - the life used equals the same count of the same samples (as the DAQ quantised
//!   them) by the dsp crate, and `millgate fatigue --input` (checked against the
//!   Python `rainflow` package in `fatigue.rs`) gives that plus the residue's half
//!   cycles;
//! - `command.reset_fatigue` resets one component, is recorded in the history with its
//!   origin, and the registers, `/metrics` and the web API agree;
//! - a restart on the same history continues every component's life;
//! - `/api/drivelines/F1/fatigue/history` gives each component's life used over time
//!   and the reset, and `millgate report` draws them (life used per component over
//!   time with the limit and the reset; damage per bite over TAF);
//! - a restart with the driveline's `fatigue` section removed publishes no fatigue
//!   figure (registers' quality bit, `/metrics`, web API) while the saved ledger stays
//!   in the history, and one with the section back resumes the ledger.

mod common;

use std::time::Duration;

use common::{free_port, http, millgate, scratch, web_ready};
use millgate::outputs::modbus::register_map::{decode_f32, RegisterMap};
use millgate_dsp::miner::{EnduranceRule, MeanCorrection, SnCurve, SnCurveSettings};
use millgate_dsp::rainflow::{Rainflow, RainflowSettings};
use millgate_sim::model::Model;
use millgate_sim::schedule::{rolling_schedule, BarTiming};
use tokio_modbus::client::{Reader, Writer};
use tokio_modbus::prelude::Slave;

const MODEL: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../sim/models/table2-adjusted-backlash.toml"
);
const BARS_KNM: [f64; 4] = [112.0, 80.0, 112.0, 100.0];
const TIMING: BarTiming = BarTiming {
    idle_s: 0.6,
    rolling_s: 1.2,
};
/// The gate: 4 noise RMS.
const GATE_KNM: f64 = 2.0;
/// The spindle's S-N curve (the measured shaft: share 1).
const SPINDLE: (f64, f64, f64) = (5.0, 1e6, 112.0);

fn curve((m, ref_cycles, ref_range_knm): (f64, f64, f64)) -> SnCurve {
    SnCurve::new(SnCurveSettings {
        m,
        ref_cycles,
        ref_range_knm,
        torque_share: 1.0,
        endurance_knm: None,
        endurance_rule: EnduranceRule::Cutoff,
        mean_correction: MeanCorrection::None,
    })
    .unwrap()
}

/// The demo's configuration without its model, with a fatigue ledger of two
/// components, the web page (commands allowed), `/metrics` and a history in `folder`.
fn config_text(folder: &std::path::Path, web: u16, metrics: u16) -> String {
    let (m, n, s) = SPINDLE;
    let demo = std::fs::read_to_string(common::repo().join("config/examples/demo.toml")).unwrap();
    let text = demo
        .replace("model = \"table2-adjusted.toml\"\n", "")
        .replace(
            "wear = { gap_step_mrad",
            &format!(
                "fatigue = {{ gate_knm = {GATE_KNM}, components = [\n  \
                 {{ name = \"spindle\", m = {m}, ref_cycles = {n}, ref_range_knm = {s} }},\n  \
                 {{ name = \"coupling\", m = 3, ref_cycles = 1e7, ref_range_knm = 150 }},\n] }}\n\
                 wear = {{ gap_step_mrad"
            ),
        );
    assert!(
        text.contains("fatigue = {") && !text.contains("table2-adjusted.toml"),
        "demo.toml changed"
    );
    text + &format!(
        "\n[outputs.web]\nbind = \"127.0.0.1:{web}\"\nallow_commands = true\n\
         \n[outputs.metrics]\nbind = \"127.0.0.1:{metrics}\"\n\
         \n[history]\npath = \"{}\"\n",
        folder.join("history.db").display()
    )
}

/// The web API's driveline: its JSON.
async fn driveline(web: u16) -> serde_json::Value {
    let answer = http(web, "GET", "/api/drivelines/F1").await;
    serde_json::from_str(&answer.body).unwrap_or_else(|_| panic!("{}", answer.body))
}

/// The components' life used on the web API, once `ready` holds of them.
async fn published_lives(
    web: u16,
    ready: impl Fn(&[f64]) -> bool,
) -> (Vec<f64>, serde_json::Value) {
    let start = std::time::Instant::now();
    loop {
        let view = driveline(web).await;
        let lives: Vec<f64> = view["fatigue_components"]
            .as_array()
            .map(|c| c.iter().filter_map(|c| c["life_used"].as_f64()).collect())
            .unwrap_or_default();
        if lives.len() == 2 && ready(&lives) {
            return (lives, view);
        }
        assert!(
            start.elapsed() < Duration::from_secs(20),
            "the web API's ledger: {view}"
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_service_s_ledger_counts_the_stream_resets_and_survives_a_restart() {
    let folder = scratch("fatigue-service");
    let mut model = Model::load(MODEL).unwrap();
    model.couplings[1].backlash = 2e-3;
    model.measurement.sample_rate = 2000.0;
    let schedule = rolling_schedule(&model, &BARS_KNM, TIMING, 0.5, 17).unwrap();
    let (web, metrics) = (free_port(), free_port());
    let text = config_text(folder.path(), web, metrics);
    let mut config = millgate_config::from_toml_str(&text, "fatigue.toml", folder.path()).unwrap();
    let devices = common::demo_devices(&mut config, &schedule).await.unwrap();
    let started = std::time::Instant::now();
    let gateway = millgate::Service::new(config.clone())
        .unwrap()
        .spawn()
        .await
        .unwrap();
    let map: RegisterMap = (*gateway.register_map()).clone();
    let at = |name: &str| {
        map.registers()
            .iter()
            .find(|r| r.name == name)
            .unwrap_or_else(|| panic!("no register {name}"))
            .address
    };
    let server = gateway.bound().server.expect("the HMI server");
    web_ready(web).await;

    // The record plays once (then the DAQ holds its last value): wait for its end.
    let record_s = schedule.torque_knm.len() as f64 / schedule.sample_rate_hz;
    tokio::time::sleep(Duration::from_secs_f64(record_s + 1.0).saturating_sub(started.elapsed()))
        .await;

    // The same count offline: the samples as the DAQ sent them (i16 counts).
    let samples = common::as_daq_sends(&schedule, &config.channels[config.drivelines[0].torque]);
    let counter = Rainflow::<256>::new(RainflowSettings { gate_knm: GATE_KNM }).unwrap();
    let spindle = curve(SPINDLE);
    let (mut closed, mut residue) = (0.0, 0.0);
    let mut state = counter.state();
    counter.block(&mut state, &samples, |c| closed += spindle.damage(&c));
    counter.residue(&state, |c| residue += spindle.damage(&c));
    assert!(closed > 0.0 && residue > 0.0);

    // The HMI resets the coupling (component 2 of driveline 1): its life starts at 0,
    // the spindle's is published with it.
    let mut hmi = tokio_modbus::client::tcp::connect_slave(server, Slave(1))
        .await
        .unwrap();
    let reset = at("command.reset_fatigue");
    assert!(
        hmi.write_single_register(reset, 0x0301)
            .await
            .unwrap()
            .is_err(),
        "no third component"
    );
    hmi.write_single_register(reset, 0x0201)
        .await
        .unwrap()
        .unwrap();
    let (lives, view) = published_lives(web, |l| l[1] == 0.0 && l[0] > 0.0).await;
    // Tolerance: the service begins counting at its first block, a few blocks of
    // idle noise (below the gate) into the record; the closed cycles do not change.
    let relative = (lives[0] - closed).abs() / closed;
    assert!(
        relative < 1e-6,
        "service {} vs offline {closed}: {relative}",
        lives[0]
    );
    println!(
        "spindle: service {:.9e}, offline closed {closed:.9e}, residue {residue:.9e}",
        lives[0]
    );

    // The registers, /metrics and the web API agree on the worst component.
    assert_eq!(view["fatigue_component"], 0);
    let words = hmi
        .read_holding_registers(at("F1.fatigue_life_used"), 2)
        .await
        .unwrap()
        .unwrap();
    assert_eq!(decode_f32(&words), Some(lives[0] as f32));
    let quality = hmi
        .read_holding_registers(at("F1.extension_quality"), 1)
        .await
        .unwrap()
        .unwrap()[0];
    assert_ne!(quality & (1 << 12), 0, "life used valid: {quality:#b}");
    let page = http(metrics, "GET", "/metrics").await.body;
    let metric = page
        .lines()
        .find_map(|line| {
            line.strip_prefix("millgate_driveline_fatigue_life_used{")?
                .split_once("} ")?
                .1
                .parse::<f64>()
                .ok()
        })
        .unwrap_or_else(|| panic!("no fatigue_life_used on /metrics:\n{page}"));
    assert_eq!(metric, lives[0]);

    // The CLI (checked against Python's rainflow) counts the record with its residue.
    let csv = folder.path().join("record.csv");
    let mut rows = String::from("t,torque_knm\n");
    for (i, v) in samples.iter().enumerate() {
        rows += &format!("{},{v}\n", i as f64 / schedule.sample_rate_hz);
    }
    std::fs::write(&csv, rows).unwrap();
    let (m, n, s) = SPINDLE;
    let output = millgate(&[
        "fatigue",
        "--input",
        csv.to_str().unwrap(),
        "--gate-knm",
        &GATE_KNM.to_string(),
        "--m",
        &m.to_string(),
        "--ref-cycles",
        &n.to_string(),
        "--ref-range-knm",
        &s.to_string(),
        "--format",
        "json",
    ]);
    assert!(output.status.success(), "{output:?}");
    let json: serde_json::Value = serde_json::from_slice(&output.stdout).unwrap();
    let cli = json["damage"].as_f64().unwrap();
    assert!(
        ((lives[0] + residue) - cli).abs() < 1e-6 * cli,
        "service + residue {} vs millgate fatigue {cli}",
        lives[0] + residue
    );

    // Restart on the same history: the lives continue.
    tokio::time::timeout(Duration::from_secs(10), gateway.stop())
        .await
        .unwrap()
        .unwrap();
    let history = folder.path().join("history.db");
    {
        let db = rusqlite::Connection::open(&history).unwrap();
        let (component, used, origin): (String, f64, String) = db
            .query_row(
                "SELECT component, life_used, origin FROM fatigue_resets WHERE driveline = 'F1'",
                [],
                |row| Ok((row.get(0)?, row.get(1)?, row.get(2)?)),
            )
            .unwrap();
        // The HMI client is on the PLC's address (loopback): recorded as the PLC.
        assert_eq!((component.as_str(), origin.as_str()), ("coupling", "plc"));
        assert!(used > 0.0);
    }
    let again = millgate::Service::new(config.clone())
        .unwrap()
        .spawn()
        .await
        .unwrap();
    web_ready(web).await;
    let (restored, _) = published_lives(web, |l: &[f64]| l[0] > 0.0).await;
    assert_eq!(restored, lives, "restored as saved");
    let printed = millgate(&[
        "fatigue",
        "--db",
        history.to_str().unwrap(),
        "--driveline",
        "F1",
        "--gate-knm",
        "2",
        "--m",
        "5",
        "--ref-cycles",
        "1e6",
        "--ref-range-knm",
        "112",
        "--format",
        "json",
    ]);
    let json: serde_json::Value =
        serde_json::from_slice(&printed.stdout).unwrap_or_else(|_| panic!("{printed:?}"));
    let ledger = &json["ledger"];
    assert_eq!(ledger["components"][0]["name"], "spindle");
    assert_eq!(
        ledger["components"][0]["life_used"].as_f64(),
        Some(lives[0])
    );
    assert_eq!(ledger["resets"][0]["component"], "coupling");
    life_history_on_the_api(web, &lives).await;
    tokio::time::timeout(Duration::from_secs(10), again.stop())
        .await
        .unwrap()
        .unwrap();
    report_draws_the_ledger(folder.path());

    // Restart without the driveline's fatigue section: no fatigue figure anywhere,
    // the saved ledger kept.
    let mut without = config.clone();
    without.drivelines[0].fatigue = None;
    let bare = millgate::Service::new(without)
        .unwrap()
        .spawn()
        .await
        .unwrap();
    web_ready(web).await;
    let view = driveline(web).await;
    assert!(view["fatigue_life_used"].is_null(), "{view}");
    assert!(view["fatigue_component"].is_null(), "{view}");
    assert!(view["fatigue_rate_per_day"].is_null(), "{view}");
    assert_eq!(view["fatigue_components"], serde_json::json!([]), "{view}");
    let server = bare.bound().server.expect("the HMI server");
    let mut hmi = tokio_modbus::client::tcp::connect_slave(server, Slave(1))
        .await
        .unwrap();
    let quality = hmi
        .read_holding_registers(at("F1.extension_quality"), 1)
        .await
        .unwrap()
        .unwrap()[0];
    assert_eq!(
        quality & (1 << 12),
        0,
        "life used without a value: {quality:#b}"
    );
    let page = http(metrics, "GET", "/metrics").await.body;
    let published: Vec<&str> = page
        .lines()
        .filter(|line| line.starts_with("millgate_driveline_fatigue_life_used{"))
        .collect();
    assert!(published.is_empty(), "{published:?}");
    {
        let db = rusqlite::Connection::open(&history).unwrap();
        let saved: Option<String> = db
            .query_row(
                "SELECT fatigue_ledger FROM driveline_state WHERE driveline = 'F1'",
                [],
                |row| row.get(0),
            )
            .unwrap();
        assert!(
            saved.is_some_and(|s| s.contains("spindle")),
            "the ledger kept"
        );
    }
    tokio::time::timeout(Duration::from_secs(10), bare.stop())
        .await
        .unwrap()
        .unwrap();
    // With the section back, the ledger resumes.
    let back = millgate::Service::new(config)
        .unwrap()
        .spawn()
        .await
        .unwrap();
    web_ready(web).await;
    let (resumed, _) = published_lives(web, |l: &[f64]| l[0] > 0.0).await;
    assert_eq!(resumed, lives, "resumed as saved");
    tokio::time::timeout(Duration::from_secs(10), back.stop())
        .await
        .unwrap()
        .unwrap();
    devices.stop().await.unwrap();
}

/// `/api/drivelines/F1/fatigue/history`: both components over time as the bites
/// stored them (at most the life published since), the coupling's reset, the limit.
async fn life_history_on_the_api(web: u16, lives: &[f64]) {
    let answer = http(web, "GET", "/api/drivelines/F1/fatigue/history?points=50").await;
    let history: serde_json::Value =
        serde_json::from_str(&answer.body).unwrap_or_else(|_| panic!("{}", answer.body));
    assert_eq!(
        history["components"],
        serde_json::json!(["spindle", "coupling"])
    );
    assert_eq!(history["life_limit"], 0.8, "{history}");
    assert_eq!(history["resets"][0]["component"], "coupling", "{history}");
    let points = history["points"].as_array().unwrap();
    assert!(!points.is_empty() && points.len() <= 50, "{history}");
    let mut previous = 0.0;
    for point in points {
        let spindle = point["life_used"][0].as_f64().unwrap();
        assert!(spindle >= previous && spindle <= lives[0], "{history}");
        previous = spindle;
        assert!(point["life_used"][1].is_number(), "{history}");
    }
    assert!(previous > 0.0, "{history}");
    // The coupling was reset after the bites: its stored life is not 0.
    let last = &points[points.len() - 1];
    assert!(last["life_used"][1].as_f64().unwrap() > 0.0, "{history}");
    // Bad parameters are refused with their allowed range.
    let refused = http(web, "GET", "/api/drivelines/F1/fatigue/history?points=0").await;
    assert_eq!(refused.status, 400, "{}", refused.body);
    assert!(refused.body.contains("points"), "{}", refused.body);
    let unknown = http(web, "GET", "/api/drivelines/X9/fatigue/history").await;
    assert_eq!(unknown.status, 404, "{}", unknown.body);
}

/// `millgate report` on the history: each component's life used over time with the
/// limit and the coupling's reset, and the damage per bite over TAF, linked from the
/// HTML with their captions.
fn report_draws_the_ledger(folder: &std::path::Path) {
    let out = folder.join("report");
    let history = folder.join("history.db");
    let written = millgate(&[
        "report",
        "--db",
        history.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(written.status.success(), "{written:?}");
    let life = std::fs::read_to_string(out.join("F1-fatigue-life.svg")).unwrap();
    for text in [
        "spindle",
        "coupling",
        "life limit, % 80",
        "coupling replaced",
        "time, UTC",
    ] {
        assert!(life.contains(text), "no {text:?} in the life plot");
    }
    // Two lines (a polyline each) and the limit's.
    assert!(life.matches("<polyline").count() >= 3, "{life}");
    let damage = std::fs::read_to_string(out.join("F1-fatigue-damage.svg")).unwrap();
    assert!(damage.contains("TAF of the bite"), "{damage}");
    assert!(damage.matches("<circle").count() >= 2, "{damage}");
    let html = std::fs::read_to_string(out.join("report.html")).unwrap();
    for caption in [
        "F1: fatigue life used per component over time",
        "F1: fatigue damage per bite over the bite&#39;s TAF",
    ] {
        assert!(
            html.contains(&format!("<figcaption>{caption}</figcaption>")),
            "{caption}"
        );
    }
    let markdown = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(markdown.contains("(F1-fatigue-life.svg)"), "{markdown}");
    assert!(markdown.contains("(F1-fatigue-damage.svg)"), "{markdown}");
}
