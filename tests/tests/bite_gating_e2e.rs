//! Bite gating end to end (issue 39 item 2): a virtual DAQ streams bars of the Table 2
//! driveline with a growing spindle gap, and a second virtual PLC, polled over Modbus
//! TCP, carries the mill's state and speed (`drivelines[].context`). Bites while the
//! mill threads or is in maintenance, or rolled outside `pool_speed_range_mpm`, are
//! recorded but not pooled into the wear trend; a state code the PLC does not define
//! makes the context invalid (counted, the bite pooled as without context). The test
//! checks each bite's gate and context as the gateway read them, the pooled count in
//! the PLC's registers, the counters on `/metrics` and, in the history, each bite's
//! `gated` column and the context it was rolled in (issue 39 item 3). The PLC also
//! serves each bar's coil id and product code: every bite's capture carries them
//! (schema v14), an invalid context's capture none and says so, `capture list
//! --product` finds a product's captures, and pyarrow reads the coil and product from
//! a capture's Parquet metadata. A manual capture of the torque, asked for after the
//! first bite, carries the context of its time too.

use std::path::PathBuf;
use std::time::Duration;

use millgate::cli::capture::{CaptureCommand, KindArg, ListArgs, Selection};
use millgate::cli::OutputFormat;
use millgate::history::query::{CaptureRow, Filter, HistoryReader, StoredCoil};
use millgate::state::commands::{Command, CommandOrigin};
use millgate::state::context::{BiteGate, Coil, MillState};
use millgate_sim::devices::modbus_bank::ServeOptions;
use millgate_sim::devices::virtual_plc::VirtualPlc;
use millgate_sim::model::Model;
use millgate_sim::schedule::{rolling_schedule_with_gap, BarTiming};
use millgate_tests::kit::process_plc::{context_config, pyarrow_checks_export, MODELS};
use millgate_tests::kit::{demo_devices, scrape, scratch, wait_for, Plc};
use tokio::net::TcpListener;

/// Idle time between bars long enough that the test sets the next bar's context
/// (read every 100 ms) well before that bar's bite completes.
const TIMING: BarTiming = BarTiming {
    idle_s: 1.5,
    rolling_s: 0.8,
};
/// Holding registers of the process PLC: the state code, the speed (m/min), the coil
/// id and the product code.
const STATE_REGISTER: usize = 0;
const SPEED_REGISTER: usize = 1;
const COIL_REGISTER: usize = 2;
const PRODUCT_REGISTER: usize = 3;
/// Bar `i`'s coil id and product code.
fn coil_and_product(bar: usize) -> (u16, u16) {
    (4711 + bar as u16, [101, 205][bar % 2])
}
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
    context_config(
        "gating.toml",
        "[[channels]]\nname = \"mill_state\"\nkind = \"process_value\"\nunit = \"1\"\n\
         source = { modbus = \"process_plc\", table = \"holding\", address = 0 }\n\n\
         [[channels]]\nname = \"mill_speed\"\nkind = \"process_value\"\nunit = \"m/min\"\n\
         source = { modbus = \"process_plc\", table = \"holding\", address = 1 }\n\n\
         [[channels]]\nname = \"coil_id\"\nkind = \"process_value\"\nunit = \"1\"\n\
         source = { modbus = \"process_plc\", table = \"holding\", address = 2 }\n\n\
         [[channels]]\nname = \"product_code\"\nkind = \"process_value\"\nunit = \"1\"\n\
         source = { modbus = \"process_plc\", table = \"holding\", address = 3 }\n\n",
        "context = { state = \"mill_state\", speed_mpm = \"mill_speed\", \
         coil = \"coil_id\", product = \"product_code\" }\n\
         pool_speed_range_mpm = [100.0, 400.0]",
        history,
    )
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
    let set = |bar: usize| {
        let (coil, product) = coil_and_product(bar);
        let bank = process.bank();
        let mut bank = bank.lock();
        bank.holding[STATE_REGISTER] = BARS[bar].2;
        bank.holding[SPEED_REGISTER] = BARS[bar].3;
        bank.holding[COIL_REGISTER] = coil;
        bank.holding[PRODUCT_REGISTER] = product;
    };
    set(0);
    let listener = TcpListener::bind("127.0.0.1:0").await?;
    config.modbus_sources[1].address = listener.local_addr()?.to_string();
    let process_running = process.spawn(listener, ServeOptions::default());
    let devices = demo_devices(&mut config, &schedule).await?;
    let mut gateway = millgate::Service::new(config)?.spawn().await?;
    let map = (*gateway.register_map()).clone();

    let mut pooled = 0;
    for (bar, &(_, _, state, speed, gate)) in BARS.iter().enumerate() {
        let bite = tokio::time::timeout(Duration::from_secs(15), gateway.bites().recv()).await??;
        if bar == 0 {
            // A manual capture of the torque, asked for just before the PLC moves on
            // to bar 1's context: it carries bar 0's context, or bar 1's should the
            // PLC's next poll reach the analysis first (both valid).
            let sent = gateway.commands().send(Command::CaptureTorque {
                driveline: 0,
                seconds: 1,
                origin: CommandOrigin::Local,
            });
            assert_eq!(sent, Ok(()), "manual capture command");
        }
        // The next bar's context, while this bar tails out and the mill idles.
        if bar + 1 < BARS.len() {
            set(bar + 1);
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
                let (coil, product) = coil_and_product(bar);
                assert_eq!(
                    (read.coil, read.product),
                    (Some(Coil::Number(coil.into())), Some(u32::from(product))),
                    "bar {bar}"
                );
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

    // Each bite's capture carries its bite's context (schema v14): the bar's coil and
    // product, valid; the invalid context's capture no value, and says why.
    let captures: Vec<CaptureRow> = reader.rows(&Filter::default())?;
    let bite_captures: Vec<&CaptureRow> = captures.iter().filter(|c| c.kind == "bite").collect();
    assert_eq!(bite_captures.len(), BARS.len(), "{captures:?}");
    for (bar, capture) in bite_captures.iter().enumerate() {
        let (coil, product) = coil_and_product(bar);
        match BARS[bar].4 {
            Some(_) => {
                assert_eq!(
                    (
                        capture.coil.clone(),
                        capture.product,
                        capture.context_status.as_deref()
                    ),
                    (
                        Some(StoredCoil::Number(coil.into())),
                        Some(i64::from(product)),
                        Some("valid")
                    ),
                    "bar {bar}"
                );
                assert_eq!(capture.speed_mpm, Some(f64::from(BARS[bar].3)));
            }
            None => {
                assert_eq!(
                    (
                        capture.coil.clone(),
                        capture.product,
                        capture.mill_state.as_deref()
                    ),
                    (None, None, None),
                    "bar {bar}: an invalid context keeps no value"
                );
                assert_eq!(capture.context_status.as_deref(), Some("invalid"));
                let note = capture.context_note.as_deref().unwrap_or_default();
                assert!(note.starts_with("state 7 is not allowed"), "{note}");
            }
        }
    }
    // The manual capture carries the context of its time (bar 0's or bar 1's: see
    // above), as the bites' captures do.
    let manual: Vec<&CaptureRow> = captures.iter().filter(|c| c.kind == "manual").collect();
    assert_eq!(manual.len(), 1, "{captures:?}");
    let of_bar = |bar: usize| {
        let (coil, product) = coil_and_product(bar);
        (
            Some(StoredCoil::Number(coil.into())),
            Some(i64::from(product)),
            MillState::from_code(u32::from(BARS[bar].2)).map(|state| state.name().to_owned()),
            Some("valid".to_owned()),
        )
    };
    let carried = (
        manual[0].coil.clone(),
        manual[0].product,
        manual[0].mill_state.clone(),
        manual[0].context_status.clone(),
    );
    assert!(
        carried == of_bar(0) || carried == of_bar(1),
        "the manual capture's context: {:?}",
        manual[0]
    );
    // `capture list --kind bite --product 205`: the bites of product 205 with a
    // trusted product (bars 1 and 3; bar 5's context was invalid).
    let selection = |product| Selection {
        db: db.clone(),
        driveline: None,
        kind: Some(KindArg::Bite),
        since: None,
        until: None,
        product,
        coil: None,
    };
    let listed = millgate::cli::capture::run(&CaptureCommand::List(ListArgs {
        selection: selection(Some(205)),
        format: OutputFormat::Json,
    }))?;
    let listed: Vec<serde_json::Value> = serde_json::from_str(&listed)?;
    let coils: Vec<&serde_json::Value> = listed.iter().map(|c| &c["coil"]).collect();
    assert_eq!(coils, [&serde_json::json!(4712), &serde_json::json!(4714)]);
    // pyarrow reads the coil and product from bar 1's Parquet export, and the
    // context from the CSV's sidecar says the same.
    pyarrow_checks_export(
        &selection(None),
        bite_captures[1].id,
        scratch.path().join("export"),
        r#"{"context_status": "valid", "coil": 4712, "product": 205,
            "speed_mpm": 250, "mill_state": "threading", "context_note": null}"#,
    )?;
    Ok(())
}
