//! Bite gating end to end (issue 39 item 2): a virtual DAQ streams bars of the Table 2
//! driveline with a growing spindle gap, and a second virtual PLC, polled over Modbus
//! TCP, carries the mill's state and speed (`drivelines[].context`). Bites while the
//! mill threads or is in maintenance, or rolled outside `pool_speed_range_mpm`, are
//! recorded but not pooled into the wear trend; a state code the PLC does not define
//! makes the context invalid (counted, the bite pooled as without context). The test
//! checks each bite's gate and context as the gateway read them, the pooled count in
//! the PLC's registers, the counters on `/metrics` and, in the history, each bite's
//! `gated` column and the context it was rolled in (issue 39 item 3).

use std::path::PathBuf;
use std::time::Duration;

use millgate::history::query::{Filter, HistoryReader};
use millgate::state::context::{BiteGate, MillState};
use millgate_sim::devices::modbus_bank::ServeOptions;
use millgate_sim::devices::virtual_plc::VirtualPlc;
use millgate_sim::model::Model;
use millgate_sim::schedule::{rolling_schedule_with_gap, BarTiming};
use millgate_tests::kit::{demo_devices, scrape, scratch, wait_for, Plc};
use tokio::net::TcpListener;

const MODELS: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../sim/models");
/// Idle time between bars long enough that the test sets the next bar's context
/// (read every 100 ms) well before that bar's bite completes.
const TIMING: BarTiming = BarTiming {
    idle_s: 1.5,
    rolling_s: 0.8,
};
/// Holding registers of the process PLC: the state code and the speed, m/min.
const STATE_REGISTER: usize = 0;
const SPEED_REGISTER: usize = 1;
/// Per bar: static torque (kN*m), spindle gap (mrad), state code, speed (m/min), and
/// the gate the gateway must give its bite (`None`: an invalid context, pooled).
const BARS: [(f64, f64, u16, u16, Option<BiteGate>); 6] = [
    (60.0, 1.0, 2, 250, Some(BiteGate::Pooled)),
    (140.0, 1.2, 1, 250, Some(BiteGate::State)),
    (50.0, 1.4, 2, 250, Some(BiteGate::Pooled)),
    (110.0, 1.6, 2, 600, Some(BiteGate::Speed)),
    (80.0, 1.8, 3, 0, Some(BiteGate::State)),
    (120.0, 2.0, 7, 250, None),
];

fn config(history: &std::path::Path) -> anyhow::Result<millgate_config::Config> {
    let demo = std::fs::read_to_string(format!(
        "{}/../config/examples/demo.toml",
        env!("CARGO_MANIFEST_DIR")
    ))?;
    let text = demo.replacen(
        "[[drivelines]]",
        "[[sources.modbus]]\nname = \"process_plc\"\naddress = \"127.0.0.1:1\"\n\
         poll_period_ms = 100\ntimeout_ms = 500\n\n\
         [[channels]]\nname = \"mill_state\"\nkind = \"process_value\"\nunit = \"1\"\n\
         source = { modbus = \"process_plc\", table = \"holding\", address = 0 }\n\n\
         [[channels]]\nname = \"mill_speed\"\nkind = \"process_value\"\nunit = \"m/min\"\n\
         source = { modbus = \"process_plc\", table = \"holding\", address = 1 }\n\n\
         [[drivelines]]\ncontext = { state = \"mill_state\", speed_mpm = \"mill_speed\" }\n\
         pool_speed_range_mpm = [100.0, 400.0]",
        1,
    ) + &format!(
        "\n[outputs.metrics]\nbind = \"127.0.0.1:0\"\n\n[history]\npath = {:?}\n",
        history.display().to_string()
    );
    millgate_config::from_toml_str(&text, "gating.toml", std::path::Path::new(MODELS))
        .map_err(|error| anyhow::anyhow!("{error}"))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bites_outside_rolling_or_the_speed_range_are_recorded_not_pooled() -> anyhow::Result<()> {
    let scratch = scratch("bite-gating");
    let db = scratch.path().join("history.db");
    let model = Model::load(PathBuf::from(MODELS).join("table2-adjusted.toml"))?;
    let torques: Vec<f64> = BARS.iter().map(|bar| bar.0).collect();
    let gaps: Vec<f64> = BARS.iter().map(|bar| bar.1 * 1e-3).collect();
    let schedule = rolling_schedule_with_gap(&model, &torques, TIMING, 0.5, 21, 1, &gaps)?;
    let mut config = config(&db)?;
    config.cache_dir = Some(scratch.path().to_path_buf());

    let process = VirtualPlc::new(4);
    let set = |state: u16, speed: u16| {
        let bank = process.bank();
        let mut bank = bank.lock();
        bank.holding[STATE_REGISTER] = state;
        bank.holding[SPEED_REGISTER] = speed;
    };
    set(BARS[0].2, BARS[0].3);
    let listener = TcpListener::bind("127.0.0.1:0").await?;
    config.modbus_sources[1].address = listener.local_addr()?.to_string();
    let process_running = process.spawn(listener, ServeOptions::default());
    let devices = demo_devices(&mut config, &schedule).await?;
    let mut gateway = millgate::Service::new(config)?.spawn().await?;
    let map = (*gateway.register_map()).clone();

    let mut pooled = 0;
    for (bar, &(_, _, state, speed, gate)) in BARS.iter().enumerate() {
        let bite = tokio::time::timeout(Duration::from_secs(15), gateway.bites().recv()).await??;
        // The next bar's context, while this bar tails out and the mill idles.
        if let Some(next) = BARS.get(bar + 1) {
            set(next.2, next.3);
        }
        let context = bite.context.expect("a driveline with context tags");
        println!("bar {bar}: {context:?}");
        match gate {
            Some(gate) => {
                let read = context.context.expect("a valid context");
                assert_eq!(
                    read.state,
                    MillState::from_code(u32::from(state)),
                    "bar {bar}"
                );
                assert_eq!(read.speed_mpm, Some(f64::from(speed)), "bar {bar}");
                assert_eq!(context.gate, gate, "bar {bar}");
            }
            None => {
                assert!(context.context.is_err(), "bar {bar}: state {state}");
                assert_eq!(context.gate, BiteGate::Pooled, "bar {bar}");
            }
        }
        // Not pooled: no gap observation, the trend untouched.
        assert_eq!(bite.gap.is_some(), context.gate.pooled(), "bar {bar}");
        pooled += usize::from(context.gate.pooled());
    }
    assert_eq!(pooled, 3);

    // The PLC's pooled count: the gated bites are not in the trend.
    let plc = Plc {
        plc: &devices.plc,
        map: &map,
    };
    let bites_pooled = plc.at("F1.bites_pooled");
    let counter = plc.at("F1.bite_counter");
    wait_for(
        "the six bites, three pooled, in the PLC",
        Duration::from_secs(20),
        || {
            let words = devices.plc.holding();
            millgate::outputs::modbus::register_map::decode_u32(&words[counter..])
                == Some(BARS.len() as u32)
                && usize::from(words[bites_pooled]) == pooled
        },
    )
    .await;

    // Every decision counted on /metrics.
    let page = scrape(gateway.bound().metrics.expect("metrics")).await?;
    for (family, count) in [
        ("millgate_driveline_bites_gated_state_total", 2),
        ("millgate_driveline_bites_gated_speed_total", 1),
        ("millgate_driveline_bites_context_invalid_total", 1),
    ] {
        let line = format!("{family}{{driveline=\"F1\"}} {count}");
        assert!(page.lines().any(|l| l == line), "{line} not in:\n{page}");
    }
    assert!(
        page.lines()
            .any(|l| l == "millgate_driveline_last_bite_gated{driveline=\"F1\"} 0"),
        "the last bite (invalid context) pooled:\n{page}"
    );

    tokio::time::timeout(Duration::from_secs(10), gateway.stop()).await??;
    devices.stop().await?;
    process_running.stop().await?;

    // Marked in the history: the gate of each bite in its `gated` column.
    let reader = HistoryReader::open(&db)?;
    let rows = reader.bites(&Filter::default())?;
    let gates: Vec<Option<BiteGate>> = rows.iter().map(|r| r.figures.last_bite_gated).collect();
    let expected: Vec<Option<BiteGate>> = BARS
        .iter()
        .map(|bar| Some(bar.4.unwrap_or(BiteGate::Pooled)))
        .collect();
    assert_eq!(gates, expected);
    // Tagged with the context it was rolled in (none for the invalid one).
    for (row, &(_, _, state, speed, gate)) in rows.iter().zip(&BARS) {
        let valid = gate.is_some();
        assert_eq!(
            row.context.state,
            MillState::from_code(u32::from(state)).filter(|_| valid)
        );
        assert_eq!(row.context.speed_mpm, valid.then_some(f64::from(speed)));
    }
    let json = serde_json::to_value(&rows[1])?;
    assert_eq!(
        (&json["gated"], &json["mill_state"], &json["speed_mpm"]),
        (
            &serde_json::json!(1),
            &serde_json::json!("threading"),
            &serde_json::json!(250.0)
        ),
        "{json}"
    );
    Ok(())
}
