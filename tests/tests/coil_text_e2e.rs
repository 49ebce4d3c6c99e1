//! A coil id as ASCII text from PLC registers, end to end (issue 39 item 1): a virtual
//! DAQ streams bars of the Table 2 driveline, and a virtual PLC, polled over Modbus
//! TCP, serves each bar's coil id as 8 characters in 4 holding registers, low byte
//! first (`type = "ascii"`, `byte_order = "low_first"`). Each bite's context carries
//! the text; the history keeps it in the `coil` column, the JSON of `capture list`
//! gives it as a string, and pyarrow reads it from the capture's Parquet metadata and
//! CSV sidecar. A coil id of digits with leading zeros keeps them (the history's
//! `coil` column would otherwise take it for a number), and `capture list --coil` and
//! `history --coil` find its evidence by it. A bar whose registers hold a byte that is
//! no printable ASCII makes the context invalid: no coil kept, the reason in the
//! capture's note, the bite counted on `/metrics`.

use std::path::PathBuf;
use std::time::Duration;

use millgate::cli::capture::{CaptureCommand, KindArg, ListArgs, Selection};
use millgate::cli::OutputFormat;
use millgate::history::query::{CaptureRow, Filter, HistoryReader, StoredCoil};
use millgate::state::context::{Coil, ContextError};
use millgate_config::text::{encode_ascii, AsciiText, ByteOrder, TextError};
use millgate_sim::devices::modbus_bank::ServeOptions;
use millgate_sim::devices::virtual_plc::VirtualPlc;
use millgate_sim::model::Model;
use millgate_sim::schedule::{rolling_schedule_with_gap, BarTiming};
use millgate_tests::kit::process_plc::{context_config, pyarrow_checks_export, MODELS};
use millgate_tests::kit::{demo_devices, scrape, scratch};
use tokio::net::TcpListener;

/// Idle time between bars long enough that the test sets the next bar's coil (read
/// every 100 ms) well before that bar's bite completes.
const TIMING: BarTiming = BarTiming {
    idle_s: 1.5,
    rolling_s: 0.8,
};
/// The coil's registers on the process PLC (holding 0..=3).
const COIL_REGISTERS: usize = 4;
/// Per bar: static torque (kN*m), and the coil's bytes as the PLC holds them.
const BARS: [(f64, &[u8]); 3] = [
    (60.0, b"CH-4711"),
    // A byte no ASCII text has (a PLC string in another code page, a torn write).
    (140.0, b"CH-\xFF712"),
    // Digits with leading zeros, ended by a NUL: a text, not the number 4713.
    (80.0, b"004713\0\0"),
];
/// The junk byte's error.
const JUNK: TextError = TextError::NotPrintable {
    position: 3,
    byte: 0xFF,
};

fn config(history: &std::path::Path) -> anyhow::Result<millgate_config::Config> {
    context_config(
        "coil-text.toml",
        "[[channels]]\nname = \"coil_id\"\nkind = \"process_value\"\nunit = \"1\"\n\
         source = { modbus = \"process_plc\", table = \"holding\", address = 0, \
         type = \"ascii\", registers = 4, byte_order = \"low_first\" }\n\n",
        "context = { coil = \"coil_id\" }",
        history,
    )
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_coil_id_read_as_text_tags_the_evidence_and_junk_makes_the_context_invalid(
) -> anyhow::Result<()> {
    let scratch = scratch("coil-text");
    let db = scratch.path().join("history.db");
    let model = Model::load(PathBuf::from(MODELS).join("table2-adjusted.toml"))?;
    let torques: Vec<f64> = BARS.iter().map(|bar| bar.0).collect();
    let gaps = vec![1e-3; BARS.len()];
    let schedule = rolling_schedule_with_gap(&model, &torques, TIMING, 0.5, 21, 1, &gaps)?;
    let mut config = config(&db)?;
    config.cache_dir = Some(scratch.path().to_path_buf());

    let process = VirtualPlc::new(COIL_REGISTERS);
    let set = |bar: usize| {
        let words = encode_ascii(BARS[bar].1, COIL_REGISTERS, ByteOrder::LowFirst);
        process.bank().lock().holding.copy_from_slice(&words);
    };
    set(0);
    let listener = TcpListener::bind("127.0.0.1:0").await?;
    config.modbus_sources[1].address = listener.local_addr()?.to_string();
    let process_running = process.spawn(listener, ServeOptions::default());
    let devices = demo_devices(&mut config, &schedule).await?;
    let mut gateway = millgate::Service::new(config)?.spawn().await?;

    let text = |s: &str| AsciiText::new(s).expect("a text");
    let expected = [
        Ok(Some(Coil::Text(text("CH-4711")))),
        Err(ContextError::CoilText(JUNK)),
        Ok(Some(Coil::Text(text("004713")))),
    ];
    for (bar, expected) in expected.iter().enumerate() {
        let bite = tokio::time::timeout(Duration::from_secs(15), gateway.bites().recv()).await??;
        if bar + 1 < BARS.len() {
            set(bar + 1);
        }
        let context = bite.context.expect("a driveline with context tags");
        println!("bar {bar}: {context:?}");
        assert_eq!(
            &context.context.map(|c| c.coil),
            expected,
            "bar {bar}: {context:?}"
        );
    }
    let page = scrape(gateway.bound().metrics.expect("metrics")).await?;
    let line = "millgate_driveline_bites_context_invalid_total{driveline=\"F1\"} 1";
    assert!(page.lines().any(|l| l == line), "{line} not in:\n{page}");

    tokio::time::timeout(Duration::from_secs(10), gateway.stop()).await??;
    devices.stop().await?;
    process_running.stop().await?;

    // The history: the text in the coil column of the bites and their captures.
    let reader = HistoryReader::open(&db)?;
    let bites = reader.bites(&Filter::default())?;
    let coils: Vec<Option<Coil>> = bites.iter().map(|row| row.context.coil).collect();
    assert_eq!(
        coils,
        [
            Some(Coil::Text(text("CH-4711"))),
            None,
            Some(Coil::Text(text("004713")))
        ]
    );
    assert_eq!(serde_json::to_value(&bites[0])?["coil"], "CH-4711");
    let captures: Vec<CaptureRow> = reader.rows(&Filter::default())?;
    let captures: Vec<&CaptureRow> = captures.iter().filter(|c| c.kind == "bite").collect();
    let kept: Vec<_> = captures
        .iter()
        .map(|c| (c.coil.clone(), c.context_status.as_deref()))
        .collect();
    assert_eq!(
        kept,
        [
            (Some(StoredCoil::Text("CH-4711".into())), Some("valid")),
            (None, Some("invalid")),
            (Some(StoredCoil::Text("004713".into())), Some("valid")),
        ]
    );
    assert_eq!(
        captures[1].context_note.as_deref(),
        Some(
            "coil text character 3 is byte 0xFF (must be printable ASCII 0x20..=0x7E, the \
             text ending at a NUL)"
        )
    );
    // `capture list` as JSON: the coil a string.
    let selection = Selection {
        db: db.clone(),
        driveline: None,
        kind: Some(KindArg::Bite),
        since: None,
        until: None,
        product: None,
        coil: None,
    };
    let listed = millgate::cli::capture::run(&CaptureCommand::List(ListArgs {
        selection: selection.clone(),
        format: OutputFormat::Json,
    }))?;
    let listed: Vec<serde_json::Value> = serde_json::from_str(&listed)?;
    let listed: Vec<&serde_json::Value> = listed.iter().map(|c| &c["coil"]).collect();
    assert_eq!(
        listed,
        [
            &serde_json::json!("CH-4711"),
            &serde_json::Value::Null,
            &serde_json::json!("004713")
        ]
    );
    // Found by its coil, as the PLC gave it; `4713` is another coil.
    let of_coil = |coil: &str| Selection {
        coil: Some(coil.to_owned()),
        ..selection.clone()
    };
    let listed = millgate::cli::capture::run(&CaptureCommand::List(ListArgs {
        selection: of_coil("004713"),
        format: OutputFormat::Json,
    }))?;
    let listed: Vec<serde_json::Value> = serde_json::from_str(&listed)?;
    let ids: Vec<i64> = listed.iter().filter_map(|c| c["id"].as_i64()).collect();
    assert_eq!(ids, [captures[2].id]);
    let other = millgate::cli::capture::run(&CaptureCommand::List(ListArgs {
        selection: of_coil("4713"),
        format: OutputFormat::Json,
    }))?;
    assert_eq!(other, "[]", "captures of coil 4713");
    let mut csv = Vec::new();
    millgate::cli::history::export(
        &millgate::cli::history::HistoryArgs {
            db: db.clone(),
            kind: millgate::cli::history::Kind::Bites,
            driveline: None,
            source: None,
            since: None,
            until: None,
            limit: None,
            product: None,
            coil: Some("004713".to_owned()),
            format: millgate::cli::history::Format::Csv,
        },
        &mut csv,
    )?;
    let csv = String::from_utf8(csv)?;
    let rows: Vec<&str> = csv.lines().skip(1).collect();
    assert_eq!(rows.len(), 1, "{csv}");
    assert!(rows[0].split(',').any(|cell| cell == "004713"), "{csv}");
    // pyarrow reads the text from bar 0's Parquet metadata, and the CSV's sidecar
    // says the same.
    pyarrow_checks_export(
        &selection,
        captures[0].id,
        scratch.path().join("export"),
        r#"{"context_status": "valid", "coil": "CH-4711", "context_note": null}"#,
    )?;
    Ok(())
}
