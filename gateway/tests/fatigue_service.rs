//! The fatigue ledger in the running service, end to end: the demo's virtual DAQ
//! streams four simulated bars of the Table 2 driveline with a 2 mrad gap over Modbus
//! TCP (the real field path: i16 blocks, the block reader), the service counts the
//! whole torque stream, and
//!
//! - the life used equals the same count of the same samples (as the DAQ quantised
//!   them) by the dsp crate, and `millgate fatigue --input` (checked against the
//!   Python `rainflow` package in `fatigue.rs`) gives that plus the residue's half
//!   cycles. The DAQ plays the record from the gateway's first read and logs what it
//!   serves; the test waits until the analysis has taken the record's last block
//!   (`millgate_block_wait_seconds_count`). A loaded machine can make the gateway
//!   miss blocks, which cut the ledger's stream: the offline count is then taken over
//!   the blocks the gateway got, cut where it was, and the test says so;
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

use common::{free_port, http, millgate, scratch, wait_for, web_ready};
use millgate::outputs::modbus::register_map::{decode_f32, RegisterMap};
use millgate_config::ChannelSource;
use millgate_dsp::miner::{EnduranceRule, MeanCorrection, SnCurve, SnCurveSettings};
use millgate_dsp::rainflow::{Rainflow, RainflowSettings};
use millgate_sim::devices::demo::{demo_daq, SAMPLES_PER_BLOCK};
use millgate_sim::devices::modbus_bank::SharedBank;
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

/// The blocks the DAQ served at register `base` since the last call, by sequence,
/// appended to `served` (each once, in order: the gateway's reads of one block
/// repeat its sequence until the next).
fn take_served(reads: &SharedBank, base: u16, served: &mut Vec<u16>) {
    for read in reads.take_read_log() {
        if read.address == base && served.last() != Some(&read.first_word) {
            served.push(read.first_word);
        }
    }
}

/// The value of the first line of the `/metrics` page at port `metrics` that starts
/// with `name` (labels included), 0 when there is none (a histogram without an
/// observation is left out).
async fn metric(metrics: u16, name: &str) -> f64 {
    let page = http(metrics, "GET", "/metrics").await.body;
    page.lines()
        .find_map(|line| line.strip_prefix(name)?.trim().parse().ok())
        .unwrap_or(0.0)
}

/// The spindle's life used over the blocks the gateway got, `received` (sequences in
/// order; block `s` holds the record's samples from `(s - 1) * SAMPLES_PER_BLOCK`,
/// its last value past its end), counted as the service counts: a sequence gap cuts
/// the stream (the residue counted as half cycles, the count begun afresh). The count
/// stops where the service was when it published: at least `taken` blocks in, `cuts`
/// cuts made (past the record the DAQ holds its last value: no cycle closes until the
/// next cut). `None` when the blocks never reach that point.
fn life_over(samples: &[f64], received: &[u16], taken: usize, cuts: u64) -> Option<f64> {
    let counter = Rainflow::<256>::new(RainflowSettings { gate_knm: GATE_KNM }).unwrap();
    let spindle = curve(SPINDLE);
    let block = usize::from(SAMPLES_PER_BLOCK);
    let at = |i: usize| samples.get(i).or(samples.last()).copied().unwrap();
    let mut state = counter.state();
    let (mut life, mut made) = (0.0, 0);
    for (k, &sequence) in received.iter().enumerate() {
        if k > 0 && sequence != received[k - 1].wrapping_add(1) {
            counter.residue(&state, |c| life += spindle.damage(&c));
            state = counter.state();
            made += 1;
            if k >= taken && made == cuts {
                return Some(life);
            }
        }
        let start = (usize::from(sequence) - 1) * block;
        let values: Vec<f64> = (start..start + block).map(at).collect();
        counter.block(&mut state, &values, |c| life += spindle.damage(&c));
        if k + 1 >= taken && made == cuts {
            return Some(life);
        }
    }
    None
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
    // A read the DAQ answered is one the gateway takes (no timeout on a loaded
    // machine): the DAQ's log of what it served is what the gateway got.
    config.modbus_sources[0].timeout = Duration::from_secs(20);
    let torque = config.drivelines[0].torque;
    let ChannelSource::ModbusBlock { base, .. } = config.channels[torque].source else {
        panic!("the demo's torque is a block channel");
    };
    let daq = demo_daq(&config, &schedule)
        .unwrap()
        .playing_from_first_read()
        .logging_reads();
    let reads = daq.bank();
    let devices = common::demo_devices_with(&mut config, daq).await.unwrap();
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

    // The record plays once (then the DAQ holds its last value): wait until the DAQ
    // has served a block at or past its last sample and the analysis has taken it up
    // (one observation of the block wait per block: the gateway's blocks in order).
    let samples = common::as_daq_sends(&schedule, &config.channels[torque]);
    let last_block = u16::try_from(samples.len().div_ceil(usize::from(SAMPLES_PER_BLOCK))).unwrap();
    let mut received = Vec::new();
    wait_for(
        "the record's last block served",
        Duration::from_secs(60),
        || {
            take_served(&reads, base, &mut received);
            received.last().is_some_and(|&s| s >= last_block)
        },
    )
    .await;
    let taken = received.len();
    let start = std::time::Instant::now();
    while metric(metrics, "millgate_block_wait_seconds_count ").await < taken as f64 {
        assert!(
            start.elapsed() < Duration::from_secs(60),
            "the analysis did not take up {taken} blocks"
        );
        tokio::time::sleep(Duration::from_millis(20)).await;
    }

    // The same count offline: the samples as the DAQ sent them (i16 counts).
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
    // Where the ledger was when it published: its cuts (lost blocks), and the blocks
    // the gateway got (the DAQ played from its first read: from block 1).
    let cuts = metric(
        metrics,
        "millgate_driveline_fatigue_stream_cuts_total{driveline=\"F1\"}",
    )
    .await as u64;
    take_served(&reads, base, &mut received);
    assert_eq!(
        received.first(),
        Some(&1),
        "the record from its first block"
    );
    let counted = gateway.counters()[torque].snapshot();
    assert_eq!(counted.saturated_samples, 0, "no sample at the i16 limits");
    let gaps: Vec<(u16, u16)> = received
        .windows(2)
        .filter(|pair| pair[1] != pair[0].wrapping_add(1))
        .map(|pair| (pair[0], pair[1]))
        .collect();
    if cuts > 0 || counted.blocks_missed > 0 {
        println!(
            "the gateway missed blocks (counted {}, sequence restarts {}; served before and \
             after each gap: {gaps:?}) and its ledger's stream was cut {cuts} times: the \
             offline count is over the blocks it got",
            counted.blocks_missed, counted.sequence_restarts
        );
    }
    let expected = life_over(&samples, &received, taken, cuts).unwrap_or_else(|| {
        panic!(
            "the ledger's {cuts} cuts are not the served blocks' gaps {gaps:?} \
             ({taken} blocks taken; counted {counted:?})"
        )
    });
    let relative = (lives[0] - expected).abs() / expected;
    assert!(
        relative < 1e-6,
        "service {} vs offline {expected}: {relative}",
        lives[0]
    );
    if cuts == 0 {
        // Every block of the record: the count of the whole record.
        assert!(
            (lives[0] - closed).abs() < 1e-6 * closed,
            "{} vs {closed}",
            lives[0]
        );
    }
    println!(
        "spindle: service {:.9e}, offline {expected:.9e} (whole record closed {closed:.9e}, \
         residue {residue:.9e})",
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
        ((closed + residue) - cli).abs() < 1e-6 * cli,
        "offline closed + residue {} vs millgate fatigue {cli}",
        closed + residue
    );
    if cuts == 0 {
        assert!(
            ((lives[0] + residue) - cli).abs() < 1e-6 * cli,
            "service + residue {} vs millgate fatigue {cli}",
            lives[0] + residue
        );
    }

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
