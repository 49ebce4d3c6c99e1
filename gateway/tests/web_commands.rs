//! `POST /api/captures` through the real binary (`millgate run` with the demo's DAQ
//! and PLC): refused 403 while `outputs.web.allow_commands` is off; with it on, each
//! refusal (no JSON content type, another site's Host, a body too large, a body that
//! is no request, an unknown subject, seconds out of range, POST on another path) is
//! a JSON error saying why, and an accepted request leaves a capture of kind
//! `manual` of the asked seconds in the history, logged with the web origin. The
//! fatigue reset (`POST /api/drivelines/{name}/fatigue/reset`) is refused alike, and
//! names an unknown driveline (404) or component (400).

mod common;

use std::time::Duration;

use common::{
    free_port, http, http_raw, terminate, wait_for, web_ready, HttpAnswer, Setup, MILLGATE,
};
use millgate::history::query::{CaptureRow, Filter, HistoryReader};

/// `POST path` with `body`, `content_type` when given, and `Host: host`.
async fn post(
    port: u16,
    path: &str,
    host: &str,
    content_type: Option<&str>,
    body: &str,
) -> HttpAnswer {
    let content_type = content_type.map_or(String::new(), |t| format!("content-type: {t}\r\n"));
    let raw = format!(
        "POST {path} HTTP/1.1\r\nhost: {host}\r\n{content_type}content-length: {}\r\n\
         connection: close\r\n\r\n{body}",
        body.len()
    );
    http_raw(port, raw.as_bytes()).await
}

/// A refused request: path, `Host`, content type, body; the status and words of its
/// error.
type Refusal<'a> = (&'a str, &'a str, Option<&'a str>, String, u16, &'a str);

/// The answer's status and its JSON `error` (empty when there is none).
fn refusal(answer: &HttpAnswer) -> (u16, String) {
    let error = serde_json::from_str::<serde_json::Value>(&answer.body)
        .ok()
        .and_then(|v| v["error"].as_str().map(str::to_owned))
        .unwrap_or_default();
    (answer.status, error)
}

fn overview_allows(answer: &HttpAnswer) -> Option<bool> {
    serde_json::from_str::<serde_json::Value>(&answer.body).ok()?["allow_commands"].as_bool()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_capture_asked_through_the_api_is_refused_unless_allowed_and_kept_when_it_is() {
    let setup = Setup::new(MILLGATE, "web-commands", "db").await;
    let port = free_port();
    let web = format!("\n[outputs.web]\nbind = \"127.0.0.1:{port}\"\n");
    let json = Some("application/json");
    let ask = r#"{"subject": "F1", "seconds": 3}"#;

    // Off (the default): 403, and the overview says so.
    setup.append_config(&web);
    let mut service = setup.spawn("off.log");
    web_ready(port).await;
    assert_eq!(
        overview_allows(&http(port, "GET", "/api/overview").await),
        Some(false)
    );
    let (status, error) = refusal(&post(port, "/api/captures", "127.0.0.1", json, ask).await);
    assert_eq!(status, 403, "{error}");
    assert!(
        error.contains("outputs.web.allow_commands = false"),
        "{error}"
    );
    let reset = r#"{"component": "spindle"}"#;
    let path = "/api/drivelines/F1/fatigue/reset";
    let (status, error) = refusal(&post(port, path, "127.0.0.1", json, reset).await);
    assert_eq!(status, 403, "{error}");
    terminate(&mut service);
    drop(service);

    // On.
    setup.append_config("allow_commands = true\n");
    let mut service = setup.spawn("on.log");
    web_ready(port).await;
    assert_eq!(
        overview_allows(&http(port, "GET", "/api/overview").await),
        Some(true)
    );
    let reset = r#"{"component": "spindle"}"#;
    let refusals: [Refusal<'_>; 13] = [
        // The fatigue reset: authorised as the captures are; the demo has no ledger.
        (
            "/api/drivelines/F1/fatigue/reset",
            "127.0.0.1",
            None,
            reset.into(),
            415,
            "application/json",
        ),
        (
            "/api/drivelines/F9/fatigue/reset",
            "127.0.0.1",
            json,
            reset.into(),
            404,
            "no driveline \"F9\"",
        ),
        (
            "/api/drivelines/F1/fatigue/reset",
            "127.0.0.1",
            json,
            reset.into(),
            400,
            "no fatigue component \"spindle\" (known: none: no drivelines[].fatigue)",
        ),
        (
            "/api/captures",
            "127.0.0.1",
            None,
            ask.into(),
            415,
            "application/json",
        ),
        // What a cross-site form can send without a preflight.
        (
            "/api/captures",
            "127.0.0.1",
            Some("text/plain"),
            ask.into(),
            415,
            "application/json",
        ),
        (
            "/api/captures",
            "evil.example",
            json,
            ask.into(),
            421,
            "evil.example",
        ),
        (
            "/api/captures",
            "127.0.0.1",
            json,
            format!(r#"{{"subject": "F1", "pad": "{}"}}"#, "x".repeat(2000)),
            413,
            "1024 bytes",
        ),
        (
            "/api/captures",
            "127.0.0.1",
            json,
            "F1 for 3 s".into(),
            400,
            "\"subject\"",
        ),
        (
            "/api/captures",
            "127.0.0.1",
            json,
            r#"{"subject": "F9", "seconds": 3}"#.into(),
            400,
            "no driveline or tandem mill \"F9\" (known: F1)",
        ),
        (
            "/api/captures",
            "127.0.0.1",
            json,
            r#"{"subject": "F1", "seconds": 0}"#.into(),
            400,
            "seconds: 0 is not allowed (must be an integer in 1..=255)",
        ),
        (
            "/api/captures",
            "127.0.0.1",
            json,
            r#"{"subject": "F1", "seconds": 300}"#.into(),
            400,
            "1..=255",
        ),
        (
            "/api/captures",
            "127.0.0.1",
            json,
            r#"{"subject": "F1", "seconds": 2.5}"#.into(),
            400,
            "1..=255",
        ),
        (
            "/api/overview",
            "127.0.0.1",
            json,
            ask.into(),
            405,
            "read-only",
        ),
    ];
    for (path, host, content_type, body, status, says) in &refusals {
        let answer = post(port, path, host, *content_type, body).await;
        let (got, error) = refusal(&answer);
        assert_eq!(
            (got, error.contains(says)),
            (*status, true),
            "POST {path} (Host {host}, {content_type:?}, {} bytes): {got} {error}",
            body.len()
        );
    }
    let get = http(port, "GET", "/api/captures").await;
    assert_eq!(refusal(&get).0, 405, "{}", get.body);
    assert!(get.body.contains("POST only"), "{}", get.body);
    let history = setup.history.clone();
    let manual = move || -> Vec<CaptureRow> {
        let rows: Vec<CaptureRow> = HistoryReader::open(&history)
            .and_then(|reader| reader.rows(&Filter::default()))
            .unwrap_or_default();
        rows.into_iter().filter(|r| r.kind == "manual").collect()
    };
    assert!(manual().is_empty(), "no refusal asked for a capture");
    let accepted = post(
        port,
        "/api/captures",
        "localhost:1",
        Some("application/json; charset=utf-8"),
        ask,
    )
    .await;
    assert_eq!(accepted.status, 202, "{}", accepted.body);
    let answer: serde_json::Value = serde_json::from_str(&accepted.body).unwrap();
    assert_eq!(answer["kind"], "manual");
    assert_eq!(answer["seconds"], 3);
    wait_for(
        "the manual capture in the file",
        Duration::from_secs(30),
        || !manual().is_empty(),
    )
    .await;
    terminate(&mut service);
    drop(service);
    let rows = manual();
    assert_eq!(rows.len(), 1, "{rows:?}");
    assert_eq!(rows[0].subject, "F1");
    assert_eq!(rows[0].samples as f64, 3.0 * rows[0].sample_rate_hz);
    let log = std::fs::read_to_string(setup.log("on.log")).unwrap();
    assert!(
        log.lines().any(|l| l.contains("manual capture started")
            && l.contains("web")
            && l.contains("127.0.0.1")),
        "the capture's origin is not in the log:\n{log}"
    );
    setup.finish().await;
}
