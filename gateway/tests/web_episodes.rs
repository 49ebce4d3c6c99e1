//! A tandem mill's captured episode on the page's API, through the service: a chatter
//! capture of three stands written with the history's writer, then served by
//! `millgate::Service`'s web page. `/api/tandem_mills/{name}/captures` lists it, and
//! `/api/captures/{id}/bands` gives the monitor's chatter-band RMS and the stands'
//! spectra around the warning, checked against numpy on the capture's CSV download
//! (`capture_bands.py`: an FFT band-pass RMS and a Welch PSD of its own) and against
//! the signal's own figures (the in-band sine's RMS, its frequency).

mod common;

use common::episode::{
    amplitude, stands, tone_hz, write_chatter_capture, COIL, FS, GAIN_WINDOW_S, PRODUCT,
    THRESHOLDS_GROUP,
};
use common::tandem::modbus_source;
use common::{free_port, http, peer, scratch, web_ready};

fn config_text(history: &std::path::Path, web_port: u16) -> String {
    String::from("name = \"episodes\"\n")
        + &modbus_source("daq")
        + &stands("daq", "TCM").toml()
        + &format!(
            "[history]\npath = {:?}\n[outputs.web]\nbind = \"127.0.0.1:{web_port}\"\n",
            history.display().to_string()
        )
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_episodes_band_signal_and_spectra_match_numpy_on_its_csv() -> anyhow::Result<()> {
    let scratch = scratch("web-episodes");
    let db = scratch.path().join("history.db");
    write_chatter_capture(&db, "TCM")?;

    let port = free_port();
    let config = millgate_config::from_toml_str(
        &config_text(&db, port),
        "episodes.toml",
        std::path::Path::new("."),
    )
    .map_err(|e| anyhow::anyhow!("{e}"))?;
    let service = millgate::Service::new(config)?.spawn().await?;
    web_ready(port).await;

    let list = http(port, "GET", "/api/tandem_mills/TCM/captures").await;
    assert_eq!(list.status, 200, "{}", list.body);
    let rows: Vec<serde_json::Value> = serde_json::from_str(&list.body)?;
    assert_eq!(rows.len(), 1, "{rows:?}");
    assert_eq!(rows[0]["kind"], "chatter");
    let id = rows[0]["id"].as_i64().expect("an id");
    let unknown = http(port, "GET", "/api/tandem_mills/XYZ/captures").await;
    assert_eq!(unknown.status, 404, "{}", unknown.body);
    assert!(unknown.body.contains("TCM"), "{}", unknown.body);
    // The capture and the episode carry the context they were taken in, and a
    // product filter finds them by it (none of another product).
    assert_eq!(
        (
            &rows[0]["coil"],
            &rows[0]["product"],
            &rows[0]["context_status"]
        ),
        (
            &serde_json::json!(COIL),
            &serde_json::json!(PRODUCT),
            &serde_json::json!("valid")
        ),
        "{rows:?}"
    );
    for (path, rows_of_product) in [
        (
            format!("/api/tandem_mills/TCM/captures?product={PRODUCT}"),
            1,
        ),
        (
            format!("/api/tandem_mills/TCM/episodes?product={PRODUCT}"),
            1,
        ),
        ("/api/tandem_mills/TCM/episodes".to_owned(), 1),
        ("/api/tandem_mills/TCM/captures?product=101".to_owned(), 0),
        ("/api/tandem_mills/TCM/episodes?product=101".to_owned(), 0),
        (format!("/api/tandem_mills/TCM/captures?coil={COIL}"), 1),
        (format!("/api/tandem_mills/TCM/episodes?coil={COIL}"), 1),
        (format!("/api/tandem_mills/TCM/episodes?coil=0{COIL}"), 0),
    ] {
        let answer = http(port, "GET", &path).await;
        assert_eq!(answer.status, 200, "{path}: {}", answer.body);
        let listed: Vec<serde_json::Value> = serde_json::from_str(&answer.body)?;
        assert_eq!(listed.len(), rows_of_product, "{path}: {listed:?}");
        if let Some(row) = listed.first() {
            assert_eq!(row["coil"], serde_json::json!(COIL), "{path}: {row}");
            assert_eq!(row["speed_mpm"], serde_json::json!(1200.0), "{path}: {row}");
        }
    }
    let episodes = http(port, "GET", "/api/tandem_mills/TCM/episodes").await;
    let episodes: Vec<serde_json::Value> = serde_json::from_str(&episodes.body)?;
    assert_eq!(episodes[0]["ended_by"], "analysis", "{episodes:?}");
    // The thresholds that judged it (schema v15).
    assert_eq!(
        episodes[0]["thresholds_group"], THRESHOLDS_GROUP,
        "{episodes:?}"
    );
    for (path, status) in [
        ("/api/tandem_mills/TCM/episodes?product=-1", 400),
        ("/api/tandem_mills/TCM/episodes?grade=1", 400),
        ("/api/tandem_mills/TCM/episodes?coil=", 400),
        ("/api/tandem_mills/TCM/captures?coil=%FF", 400),
        (
            "/api/tandem_mills/TCM/episodes?coil=123456789012345678901234567890123",
            400,
        ),
        ("/api/tandem_mills/XYZ/episodes", 404),
    ] {
        let answer = http(port, "GET", path).await;
        assert_eq!(answer.status, status, "{path}: {}", answer.body);
    }

    // Every point (no bucketing: the spectra have 626 bins, the band 40-odd windows).
    let bands = http(
        port,
        "GET",
        &format!("/api/captures/{id}/bands?points=5000"),
    )
    .await;
    assert_eq!(bands.status, 200, "{}", bands.body);
    let bands_json: serde_json::Value = serde_json::from_str(&bands.body)?;
    let csv = http(port, "GET", &format!("/api/captures/{id}/file?format=csv")).await;
    assert_eq!(csv.status, 200);
    // Its header, the JSON `capture export` writes beside the CSV.
    let header = http(port, "GET", &format!("/api/captures/{id}/file?format=json")).await;
    assert_eq!(header.status, 200, "{}", header.body);
    let bucketed = http(port, "GET", &format!("/api/captures/{id}/bands?points=50")).await;
    let bucketed: serde_json::Value = serde_json::from_str(&bucketed.body)?;
    let bad = http(port, "GET", &format!("/api/captures/{id}/bands?points=1")).await;
    assert_eq!(bad.status, 400, "{}", bad.body);
    service.stop().await?;

    // The signal's own figures: the spectra peak at each stand's tone; the band RMS
    // at its largest is the tone's RMS near its top amplitude.
    for stand in 0..3 {
        let spectrum = &bands_json["spectra"][stand];
        assert_eq!(
            spectrum["peak_hz"].as_f64(),
            Some(tone_hz(stand)),
            "{spectrum}"
        );
        let largest = bands_json["band_rms"][stand]["largest"].as_f64().unwrap();
        // The tone's RMS over the gain window (2 s) ending at each window's end.
        let tone_rms = |end_s: f64| {
            let n = (GAIN_WINDOW_S * FS) as usize;
            let power: f64 = (0..n)
                .map(|k| amplitude(stand, end_s - k as f64 / FS).powi(2) / 2.0)
                .sum();
            (power / n as f64).sqrt()
        };
        let top = bands_json["band_rms"][stand]["t_s"]
            .as_array()
            .unwrap()
            .iter()
            .filter_map(serde_json::Value::as_f64)
            .map(tone_rms)
            .fold(0.0, f64::max);
        assert!(
            (largest / top - 1.0).abs() < 0.1,
            "stand {stand}: band RMS up to {largest}, the tone's over the gain window {top}"
        );
        let max = &bucketed["spectra"][stand]["max"];
        assert!(max.as_array().unwrap().len() <= 50, "bucketed: {max}");
        let peak = max
            .as_array()
            .unwrap()
            .iter()
            .filter_map(serde_json::Value::as_f64)
            .fold(0.0, f64::max);
        let psd_peak = spectrum["max"]
            .as_array()
            .unwrap()
            .iter()
            .filter_map(serde_json::Value::as_f64)
            .fold(0.0, f64::max);
        assert_eq!(peak, psd_peak, "the envelope keeps the peak");
    }
    assert_eq!(bands_json["warning_s"].as_f64(), Some(6.0));
    assert_eq!(bands_json["cleared_s"].as_f64(), Some(10.5));

    // numpy on the CSV download.
    let csv_path = scratch.path().join("capture.csv");
    std::fs::write(&csv_path, csv.body)?;
    std::fs::write(scratch.path().join("capture.json"), header.body)?;
    let bands_path = scratch.path().join("bands.json");
    std::fs::write(&bands_path, &bands.body)?;
    let script = peer("capture_bands.py");
    let checked = std::process::Command::new("python3")
        .arg(&script)
        .arg(&csv_path)
        .arg(&bands_path)
        .arg(GAIN_WINDOW_S.to_string())
        .output()?;
    println!("{}", String::from_utf8_lossy(&checked.stdout));
    assert!(
        checked.status.success(),
        "{}{}",
        String::from_utf8_lossy(&checked.stdout),
        String::from_utf8_lossy(&checked.stderr)
    );
    Ok(())
}
