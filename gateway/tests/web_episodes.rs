//! A tandem mill's captured episode on the page's API, through the service: a chatter
//! capture of three stands written with the history's writer, then served by
//! `millgate::Service`'s web page. `/api/tandem_mills/{name}/captures` lists it, and
//! `/api/captures/{id}/bands` gives the monitor's chatter-band RMS and the stands'
//! spectra around the warning, checked against numpy on the capture's CSV download
//! (`capture_bands.py`: an FFT band-pass RMS and a Welch PSD of its own) and against
//! the signal's own figures (the in-band sine's RMS, its frequency).

mod common;

use std::path::PathBuf;

use common::{free_port, http, web_ready};
use millgate::outputs::history::writer::{connect, insert, insert_run};
use millgate::outputs::history::RunInfo;
use millgate::state::captures::{
    CaptureChannel, CaptureKind, CaptureRecord, ChatterEpisode, KeepClass,
};
use millgate::state::events::HistoryEvent;
use millgate::state::time::UtcTime;

const FS: f64 = 2500.0;
/// The band gain's window (`gain_window_s`, the default), s.
const GAIN_WINDOW_S: f64 = 2.0;
/// The capture's length, s.
const LENGTH_S: f64 = 12.0;
/// The chatter tone of stand `s`, Hz (on the spectra's 2 Hz grid, in the 100..300 Hz
/// band).
fn tone_hz(stand: usize) -> f64 {
    180.0 + 20.0 * stand as f64
}
/// Amplitude of stand `s`'s chatter tone at `t`, m/s^2: low, growing from 4 s to 8 s,
/// falling back by 10 s.
fn amplitude(stand: usize, t: f64) -> f64 {
    let top = 0.5 + 0.1 * stand as f64;
    let low = 0.05;
    match t {
        t if t < 4.0 => low,
        t if t < 8.0 => low + (top - low) * (t - 4.0) / 4.0,
        t if t < 10.0 => top - (top - low) * (t - 8.0) / 2.0,
        _ => low,
    }
}

/// Stand `stand`'s samples as a 0.01 m/s^2-per-count DAQ gives them: the chatter
/// tone, a 30 Hz roll-eccentricity tone (outside the band) and a little noise.
fn stand_samples(stand: usize) -> Vec<f64> {
    let mut state = 0x9e37_79b9_7f4a_7c15u64 ^ stand as u64;
    let n = (LENGTH_S * FS) as usize;
    (0..n)
        .map(|k| {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            let noise = ((state >> 33) as f64 / f64::from(1u32 << 31) - 0.5) * 0.02;
            let t = k as f64 / FS;
            let phase = std::f64::consts::TAU * t;
            let value = amplitude(stand, t) * (phase * tone_hz(stand)).sin()
                + 0.1 * (phase * 30.0 + stand as f64).sin()
                + noise;
            (value / 0.01).round() * 0.01
        })
        .collect()
}

fn config_text(history: &std::path::Path, web_port: u16) -> String {
    let mut text = String::from(
        "name = \"episodes\"\n[[sources.modbus]]\nname = \"daq\"\naddress = \"127.0.0.1:1\"\npoll_period_ms = 20\n",
    );
    for stand in 0..3 {
        text += &format!(
            "[[channels]]\nname = \"s{}_vib\"\nkind = \"acceleration\"\nunit = \"m/s^2\"\n\
             scale = 0.01\nsample_rate_hz = {FS}\n\
             source = {{ modbus = \"daq\", table = \"input\", block = {} }}\n",
            stand + 1,
            stand * 122
        );
    }
    text += &format!(
        "[[tandem_mills]]\nname = \"TCM\"\nstands = [\"s1_vib\", \"s2_vib\", \"s3_vib\"]\n\
         chatter_band_hz = [100.0, 300.0]\nwindow_s = 0.5\nk_max = 0.25\n\
         gain_thresholds = [2.0, 2.0, 2.0]\n\
         [history]\npath = {:?}\n[outputs.web]\nbind = \"127.0.0.1:{web_port}\"\n",
        history.display().to_string()
    );
    text
}

struct Scratch(PathBuf);

impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_episodes_band_signal_and_spectra_match_numpy_on_its_csv() -> anyhow::Result<()> {
    let scratch =
        Scratch(std::env::temp_dir().join(format!("millgate-web-episodes-{}", std::process::id())));
    let _ = std::fs::remove_dir_all(&scratch.0);
    std::fs::create_dir_all(&scratch.0)?;
    let db = scratch.0.join("history.db");
    let window = (0.5 * FS) as usize;
    let episode = ChatterEpisode {
        warning_sample: (6.0 * FS) as usize,
        cleared_sample: Some((10.5 * FS) as usize),
        window_samples: window,
        hop_samples: window / 2,
        cut: false,
    };
    {
        let mut connection = connect(&db)?;
        let start = UtcTime::parse("2026-11-27T08:00:00Z").map_err(anyhow::Error::msg)?;
        let run = insert_run(
            &connection,
            start,
            &RunInfo {
                version: "test".into(),
                config_name: "episodes".into(),
                config_hash: String::new(),
                drivelines: vec![],
            },
        )?;
        let capture = CaptureRecord {
            kind: CaptureKind::Chatter,
            subject: "TCM".into(),
            bite: None,
            first_sample_unix_ns: start.unix_ms() * 1_000_000,
            kernel_time: false,
            sample_rate_hz: FS,
            channels: (0..3)
                .map(|s| CaptureChannel {
                    name: format!("s{}_vib", s + 1),
                    unit: "m/s^2".into(),
                    scale: 0.01,
                    offset: 0.0,
                    samples: stand_samples(s),
                })
                .collect(),
            gaps: vec![],
            analysis: None,
            episode: Some(episode),
            keep: KeepClass::Important,
        };
        let transaction = connection.transaction()?;
        insert(&transaction, run, &HistoryEvent::Capture(Box::new(capture)))?;
        transaction.commit()?;
    }

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
    let csv_path = scratch.0.join("capture.csv");
    std::fs::write(&csv_path, csv.body)?;
    let bands_path = scratch.0.join("bands.json");
    std::fs::write(&bands_path, &bands.body)?;
    let script = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/capture_bands.py");
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
