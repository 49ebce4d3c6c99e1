//! Captures through the real `millgate run` binary between the demo's virtual DAQ and
//! PLC:
//!
//! - killed with SIGKILL right after a bite reached the PLC: every bite the PLC saw
//!   has its capture in the file, and the file passes `PRAGMA integrity_check`
//!   (Debian's `sqlite3`);
//! - each bite's capture exported as CSV (`millgate capture export`) and run through
//!   `millgate analyze` prints the static torque, TAF and natural frequencies the
//!   gateway stored for that bite, to the printed digits;
//! - the Parquet export of the same captures holds the same samples as the CSV and
//!   its metadata (pyarrow reads both, `capture_parquet.py`);
//! - the web API's download of a capture (`/api/captures/{id}/file`, the page's link)
//!   is the exported CSV and Parquet file byte for byte, under the export's name;
//! - `millgate discrepancy --db ... --bites LAST:3` takes the captured bites, names the
//!   demo's opening gap and writes a calibrated model;
//! - an export of a range without captures and of an unknown driveline, more bites
//!   than were captured, an export to a full disk (a 16 KiB tmpfs in a private mount
//!   namespace, `unshare -rm`): clear errors naming what and why, and no half-written
//!   file left.

mod common;

use std::path::Path;
use std::process::Command;
use std::time::Duration;

use common::{free_port, http, millgate, text, wait_for, web_ready, Setup, MILLGATE};

use millgate::history::query::{BiteRow, CaptureRow, Filter, HistoryReader};

/// `value` as `millgate analyze` prints it with `digits` decimals.
fn printed(value: Option<f64>, digits: usize) -> String {
    value.map_or_else(|| "-".to_owned(), |v| format!("{v:.digits$}"))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sigkill_keeps_every_capture_the_plc_saw_and_analyze_reproduces_the_bites() {
    let setup = Setup::new(MILLGATE, "captures", "db").await;
    let history = setup.history.clone();
    let web_port = free_port();
    setup.append_config(&format!(
        "\n[outputs.web]\nbind = \"127.0.0.1:{web_port}\"\n"
    ));
    let plc = setup.plc();

    let mut service = setup.spawn("run.log");
    wait_for("3 bites in the PLC", Duration::from_secs(40), || {
        plc.counter() >= 3
    })
    .await;
    // The web API lists the driveline's captures and gives one's samples.
    web_ready(web_port).await;
    let listed = http(web_port, "GET", "/api/drivelines/F1/captures?limit=2").await;
    assert_eq!(listed.status, 200, "{}", listed.body);
    let listed = listed.json();
    let first = &listed.as_array().unwrap()[0];
    assert_eq!(first["kind"], "bite");
    assert_eq!(first["meta"]["channels"][0]["name"], "spindle_top");
    let id = first["id"].as_i64().unwrap();
    let one = http(web_port, "GET", &format!("/api/captures/{id}")).await;
    assert_eq!(one.status, 200, "{}", one.body);
    let one = one.json();
    assert_eq!(
        one["channels"][0]["samples"].as_array().unwrap().len() as i64,
        first["samples"].as_i64().unwrap()
    );
    let missing = http(web_port, "GET", "/api/captures/999999").await;
    assert_eq!(missing.status, 404, "{}", missing.body);
    // Its download, as the page links it: compared with `capture export` below.
    let download = |format: &'static str| {
        let path = format!("/api/captures/{id}/file?format={format}");
        async move {
            let answer = http(web_port, "GET", &path).await;
            assert_eq!(answer.status, 200, "{path}: {}", answer.body);
            answer
        }
    };
    let downloads = [
        download("csv").await,
        download("parquet").await,
        download("json").await,
    ];
    assert_eq!(
        downloads[0].header("content-type"),
        Some("text/csv; charset=utf-8")
    );
    assert_eq!(
        downloads[1].header("content-type"),
        Some("application/vnd.apache.parquet")
    );
    assert_eq!(
        downloads[2].header("content-type"),
        Some("application/json")
    );
    let bad = http(
        web_port,
        "GET",
        &format!("/api/captures/{id}/file?format=xls"),
    )
    .await;
    assert_eq!(bad.status, 400, "{}", bad.body);
    assert!(bad.json()["error"]
        .as_str()
        .unwrap()
        .contains("csv, parquet or json"));
    let downloaded_bite = first["bite_counter"].as_i64().unwrap();
    let seen = plc.counter();
    wait_for("another bite in the PLC", Duration::from_secs(20), || {
        plc.counter() > seen
    })
    .await;
    service.kill().unwrap();
    service.wait().unwrap();
    let in_plc = i64::from(plc.counter());

    // Every bite the PLC saw has its capture, linked to its bite row.
    let reader = HistoryReader::open(&history).unwrap();
    let bites: Vec<BiteRow> = reader.bites(&Filter::default()).unwrap();
    let captures: Vec<CaptureRow> = reader.rows(&Filter::default()).unwrap();
    for counter in 1..=in_plc {
        let bite = bites
            .iter()
            .find(|b| i64::from(b.figures.bite_counter) == counter)
            .unwrap_or_else(|| panic!("bite {counter} is not in the file"));
        let capture = captures
            .iter()
            .find(|c| c.bite_counter == Some(counter))
            .unwrap_or_else(|| panic!("bite {counter} reached the PLC; its capture is missing"));
        assert_eq!(capture.kind, "bite");
        assert_eq!(capture.subject, "F1");
        assert_eq!(capture.bite_id, Some(bite.id));
        assert_eq!(capture.bite_time.as_deref(), Some(bite.time().as_str()));
        assert!(capture.started_at <= bite.time(), "{capture:?} {bite:?}");
        assert!(capture.samples > 100 && capture.bytes > 0, "{capture:?}");
    }
    let sqlite3 = Command::new("sqlite3")
        .args([history.to_str().unwrap(), "PRAGMA integrity_check;"])
        .output()
        .expect("Debian's sqlite3 (scripts/test installs it)");
    assert_eq!(String::from_utf8_lossy(&sqlite3.stdout).trim(), "ok");

    // Each bite's CSV through `millgate analyze` gives what the gateway stored.
    let out = setup.scratch.join("export");
    let db = history.as_path();
    let mut parquet_pairs = Vec::new();
    for bite in bites
        .iter()
        .filter(|b| i64::from(b.figures.bite_counter) <= in_plc)
    {
        let csv = MILLGATE.export_bite(db, &out, bite.figures.bite_counter, "csv");
        let analyzed = millgate(&["analyze", "--input", &csv]);
        assert!(analyzed.status.success(), "{}", text(&analyzed));
        let printed_text = String::from_utf8_lossy(&analyzed.stdout).into_owned();
        assert!(printed_text.contains("1 event(s)"), "{printed_text}");
        let expected = format!(
            "static_torque = {:.2} kN*m, peak_torque = {:.2} kN*m, taf = {}",
            bite.figures.static_torque_knm.unwrap(),
            bite.figures.peak_torque_knm.unwrap(),
            printed(bite.figures.taf, 3)
        );
        assert!(
            printed_text.contains(&expected),
            "bite {}: expected `{expected}` in\n{printed_text}",
            bite.figures.bite_counter
        );
        if let (Some(f1), Some(f2)) = (bite.figures.beta1_hz, bite.figures.beta2_hz) {
            let fit = format!("f1_hz = {f1:.3}, f2_hz = {f2:.3}");
            assert!(
                printed_text.contains(&fit),
                "bite {}: expected `{fit}` in\n{printed_text}",
                bite.figures.bite_counter
            );
        }
        let parquet = MILLGATE.export_bite(db, &out, bite.figures.bite_counter, "parquet");
        if i64::from(bite.figures.bite_counter) == downloaded_bite {
            // The page's download is the exported file, byte for byte, under its name.
            let sidecar = Path::new(&csv).with_extension("json").display().to_string();
            for (answer, path) in downloads.iter().zip([&csv, &parquet, &sidecar]) {
                let file = String::from_utf8_lossy(&std::fs::read(path).unwrap()).into_owned();
                assert_eq!(answer.body, file, "{path}");
                let name = Path::new(path).file_name().unwrap().to_str().unwrap();
                assert_eq!(
                    answer.header("content-disposition"),
                    Some(format!("attachment; filename=\"{name}\"").as_str())
                );
            }
        }
        // Counts at 0.01 kN*m are written as the decimals they mean (shortest
        // round-trip text of the decimal-exact decoding), never `0.5700000000000001`.
        let csv_text = std::fs::read_to_string(&csv).unwrap();
        for artefact in ["00000000", "99999999"] {
            assert!(
                !csv_text.contains(artefact),
                "{csv}: `{artefact}` in {:?}",
                csv_text.lines().find(|line| line.contains(artefact))
            );
        }
        parquet_pairs.push((csv, parquet));
    }
    assert!(
        bites.iter().any(|b| b.figures.beta1_hz.is_some()),
        "no fit compared"
    );

    // pyarrow reads the Parquet files: the CSV's samples and the metadata, with the
    // hash of the configuration the service ran, as `millgate check` prints it.
    let checked = millgate(&[
        "check",
        "--config",
        setup.config.to_str().unwrap(),
        "--format",
        "json",
    ]);
    assert!(checked.status.success(), "{}", text(&checked));
    let checked: serde_json::Value = serde_json::from_slice(&checked.stdout).unwrap();
    let config_hash = checked["config_hash"].as_str().unwrap().to_owned();
    assert_eq!(config_hash.len(), 64, "{checked}");
    let script = common::peer("capture_parquet.py");
    let mut python = Command::new("python3");
    python
        .arg(&script)
        .env("MILLGATE_CONFIG_HASH", &config_hash);
    for (csv, parquet) in &parquet_pairs {
        python.args([csv, parquet]);
    }
    let checked = python.output().expect("python3");
    assert!(checked.status.success(), "{}", text(&checked));

    // Commissioning from the captures: the last 3 bites against the drawings' model
    // (the demo's driveline is the adjusted model with an opening gap).
    let models = Path::new(env!("CARGO_MANIFEST_DIR")).join("../sim/models");
    let drawings = models.join("table2-drawings.toml");
    let report = setup.scratch.join("commissioning");
    let discrepancy = millgate(&[
        "discrepancy",
        "--db",
        db.to_str().unwrap(),
        "--driveline",
        "F1",
        "--bites",
        "LAST:3",
        "--model",
        drawings.to_str().unwrap(),
        "--report",
        report.to_str().unwrap(),
        "--format",
        "json",
    ]);
    assert!(discrepancy.status.success(), "{}", text(&discrepancy));
    let found: serde_json::Value = serde_json::from_slice(&discrepancy.stdout).unwrap();
    assert_eq!(found["bites"].as_array().unwrap().len(), 3, "{found}");
    assert_eq!(found["effect"], "backlash", "{found}");
    let calibrated =
        millgate_sim::model::Model::load(report.join("calibrated-model.toml")).unwrap();
    let drawn = millgate_sim::model::Model::load(&drawings).unwrap();
    // The drawings' first stiffness is 3x the demo driveline's: the calibration moves
    // it (with the demo's gap open from the start it cannot tell stiffness from gap
    // alone, so only that it moved is asserted here).
    let moved = calibrated.couplings[0].stiffness / drawn.couplings[0].stiffness - 1.0;
    assert!(moved.abs() > 0.1, "calibrated stiffness moved {moved:+.3}");
    let too_many = millgate(&[
        "discrepancy",
        "--db",
        db.to_str().unwrap(),
        "--driveline",
        "F1",
        "--bites",
        "LAST:99",
        "--model",
        drawings.to_str().unwrap(),
    ]);
    assert!(!too_many.status.success());
    assert!(
        text(&too_many).contains(&format!(
            "--bites LAST:99: F1 has {} captured bites",
            captures.len()
        )),
        "{}",
        text(&too_many)
    );

    // Bad selections: clear errors naming what is missing.
    let empty = millgate(&[
        "capture",
        "export",
        "--db",
        db.to_str().unwrap(),
        "--since",
        "2001-01-01",
        "--until",
        "2001-01-02",
        "--format",
        "csv",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(!empty.status.success());
    let message = text(&empty);
    assert!(
        message.contains("no captures since 2001-01-01 until 2001-01-02")
            && message.contains(&format!("the file holds {} captures", captures.len())),
        "{message}"
    );
    let unknown = millgate(&[
        "capture",
        "list",
        "--db",
        db.to_str().unwrap(),
        "--driveline",
        "F9",
    ]);
    assert!(!unknown.status.success());
    assert!(
        text(&unknown).contains("no driveline \"F9\" in the file"),
        "{}",
        text(&unknown)
    );
    // An export to a full disk: the file and the reason named, nothing half-written.
    let full = setup.scratch.join("full");
    std::fs::create_dir_all(&full).unwrap();
    let exported = Command::new("unshare")
        .args([
            "-rm",
            "sh",
            "-c",
            "mount -t tmpfs -o size=16k tmpfs \"$1\" && shift && \"$@\"; code=$?; \
             ls -A \"$0\"; exit $code",
        ])
        .arg(&full)
        .arg(&full)
        .arg(env!("CARGO_BIN_EXE_millgate"))
        .args(["capture", "export", "--db", db.to_str().unwrap()])
        .args(["--format", "csv", "--out", full.to_str().unwrap()])
        .output()
        .expect("unshare (util-linux)");
    assert!(!exported.status.success(), "{}", text(&exported));
    let said = text(&exported);
    assert!(
        said.contains(&format!("{}/capture-", full.display()))
            && said.contains("not exported (the part written was removed)")
            && said.contains("No space left on device"),
        "{said}"
    );
    // The file that did not fit is not among those `ls -A` found in the tmpfs after.
    let prefix = format!("{}/", full.display());
    let failed = said
        .split(&prefix)
        .nth(1)
        .and_then(|rest| rest.split(':').next())
        .unwrap();
    let left = String::from_utf8_lossy(&exported.stdout).into_owned();
    assert!(
        failed.starts_with("capture-") && !left.lines().any(|name| name == failed),
        "{failed} left in {left}"
    );
    let listed = millgate(&[
        "capture",
        "list",
        "--db",
        db.to_str().unwrap(),
        "--format",
        "json",
    ]);
    assert!(listed.status.success(), "{}", text(&listed));
    let listed: serde_json::Value = serde_json::from_slice(&listed.stdout).unwrap();
    assert_eq!(listed.as_array().unwrap().len(), captures.len());
    assert_eq!(listed[0]["meta"]["channels"][0]["unit"], "kN*m");

    setup.stop(service).await;
}

/// `command.manual_capture` over the gateway's Modbus server (tokio-modbus as the
/// HMI): the next seconds of F1's torque kept as a capture of kind `manual`, as many
/// samples as the seconds at the channel's rate, and holding, sample for sample, the
/// window of each bite captured meanwhile (the same samples the analysis saw); a
/// driveline that does not exist is refused (exception 03) and changes nothing.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_manual_capture_command_keeps_the_next_seconds_of_torque() {
    use tokio_modbus::client::Writer;
    let setup = Setup::new(MILLGATE, "manual-capture", "db").await;
    let history = setup.history.clone();
    let plc = setup.plc();
    let service = setup.spawn("run.log");
    wait_for("a bite in the PLC", Duration::from_secs(40), || {
        plc.counter() >= 1
    })
    .await;
    let server = std::net::SocketAddr::from(([127, 0, 0, 1], setup.server_port));
    let mut hmi = tokio_modbus::client::tcp::connect_slave(server, tokio_modbus::Slave(1))
        .await
        .unwrap();
    let command = plc.at("command.manual_capture") as u16;
    let refused = hmi
        .write_single_register(command, (8 << 8) | 9)
        .await
        .unwrap();
    assert_eq!(
        refused,
        Err(tokio_modbus::ExceptionCode::IllegalDataValue),
        "driveline 9 does not exist"
    );
    let seconds = 8u16;
    let asked_ns = millgate::state::captures::unix_ns(std::time::SystemTime::now());
    hmi.write_single_register(command, (seconds << 8) | 1)
        .await
        .unwrap()
        .unwrap();
    let manual = |reader: &HistoryReader| -> Vec<CaptureRow> {
        let rows: Vec<CaptureRow> = reader.rows(&Filter::default()).unwrap();
        rows.into_iter().filter(|r| r.kind == "manual").collect()
    };
    wait_for(
        "the manual capture in the file",
        Duration::from_secs(30),
        || !manual(&HistoryReader::open(&history).unwrap()).is_empty(),
    )
    .await;
    drop(service);

    let reader = HistoryReader::open(&history).unwrap();
    let rows = manual(&reader);
    assert_eq!(rows.len(), 1, "{rows:?}");
    let row = rows[0].clone();
    assert_eq!(
        (row.subject.as_str(), row.bite_counter, row.keep),
        ("F1", None, 2)
    );
    assert_eq!(row.samples as f64, f64::from(seconds) * row.sample_rate_hz);
    // Its first sample after the command (less one DAQ block's worth of time).
    assert!(
        row.first_sample_unix_ns > asked_ns - 1_000_000_000
            && row.first_sample_unix_ns < asked_ns + 5_000_000_000,
        "{row:?}"
    );
    let capture = reader.capture_of(row.clone()).unwrap();
    let samples = &capture.channels[0].samples;
    // The bites captured inside it: each window is a run of the manual samples.
    let end_ns = row.first_sample_unix_ns + (row.duration_s * 1e9) as i64;
    let bites: Vec<CaptureRow> = reader
        .rows::<CaptureRow>(&Filter::default())
        .unwrap()
        .into_iter()
        .filter(|c| c.kind == "bite" && c.sample_rate_hz == row.sample_rate_hz)
        .filter(|c| {
            let bite_end = c.first_sample_unix_ns + (c.duration_s * 1e9) as i64;
            c.first_sample_unix_ns > row.first_sample_unix_ns + 300_000_000
                && bite_end < end_ns - 300_000_000
        })
        .collect();
    assert!(!bites.is_empty(), "no bite inside the {seconds} s captured");
    for bite in bites {
        let window = reader.capture_of(bite.clone()).unwrap().channels[0]
            .samples
            .clone();
        assert_eq!(capture.channels[0].name, "spindle_top");
        assert!(
            samples
                .windows(window.len())
                .any(|run| run == window.as_slice()),
            "bite {:?}'s window is not in the manual capture",
            bite.bite_counter
        );
    }
    // `capture list --kind manual` shows it.
    let listed = millgate(&[
        "capture",
        "list",
        "--db",
        history.to_str().unwrap(),
        "--kind",
        "manual",
        "--format",
        "json",
    ]);
    assert!(listed.status.success(), "{}", text(&listed));
    let listed: serde_json::Value = serde_json::from_slice(&listed.stdout).unwrap();
    assert_eq!(listed[0]["id"].as_i64(), Some(row.id));
    setup.finish().await;
}
