//! The maintenance web page against a real service (`millgate run` between the demo's
//! virtual DAQ and PLC) over real HTTP on loopback: the JSON API's answers and
//! limits (the gap forecast's cone against the same answer's figures), the security
//! headers, requests refused (bad parameters, methods, bodies, oversized, malformed
//! and slow requests), the connection limit with the Modbus path answering
//! meanwhile, live updates, and the page without a history; gzip and the assets'
//! ETags as curl(1) sees them.

mod common;

use std::time::{Duration, Instant};

use common::{free_port, http, http_raw, web_ready, HttpAnswer, Setup, MILLGATE};
use millgate::history::query::{BiteRow, Filter, HistoryReader};
use millgate::history::series::TREND_WINDOW;
use millgate::state::time::UtcTime;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

fn assert_security_headers(answer: &HttpAnswer, what: &str) {
    let csp = answer
        .header("content-security-policy")
        .unwrap_or_else(|| panic!("{what}: no content-security-policy"));
    for directive in [
        "default-src 'none'",
        "script-src 'self'",
        "style-src 'self'",
        "connect-src 'self'",
        "frame-ancestors 'none'",
    ] {
        assert!(
            csp.contains(directive),
            "{what}: CSP {csp:?} lacks {directive}"
        );
    }
    assert!(
        !csp.contains("unsafe"),
        "{what}: CSP {csp:?} allows unsafe sources"
    );
    assert_eq!(
        answer.header("x-content-type-options"),
        Some("nosniff"),
        "{what}"
    );
    assert_eq!(
        answer.header("referrer-policy"),
        Some("no-referrer"),
        "{what}"
    );
    assert_eq!(answer.header("x-frame-options"), Some("DENY"), "{what}");
    assert!(
        answer.header("cache-control").is_some(),
        "{what}: no cache-control"
    );
}

/// Longest wait for what a live service does at once (an event, an answer, a freed
/// connection): a hang guard, not a speed requirement.
const LIVE: Duration = Duration::from_secs(15);
/// `points` (`[x, y]`, x ascending) at `x`, linear between neighbours; `None`
/// outside.
fn at(points: &[serde_json::Value], x: f64) -> Option<f64> {
    let xy = |p: &serde_json::Value| (p[0].as_f64().unwrap(), p[1].as_f64().unwrap());
    points.windows(2).find_map(|pair| {
        let ((x0, y0), (x1, y1)) = (xy(&pair[0]), xy(&pair[1]));
        (x0..=x1)
            .contains(&x)
            .then(|| y0 + (y1 - y0) * (x - x0) / (x1 - x0))
    })
}

/// `/api/drivelines/F1/map`: the wear maps' curves once the build is done, the live
/// estimate on them, and the pooled bites near the estimate's curve.
async fn wear_map_on_the_page(port: u16, setup: &Setup) {
    let start = Instant::now();
    // The map and the live figures of one bite (read again when a bite came between).
    let (map, live) = loop {
        let before = http(port, "GET", "/api/drivelines/F1").await.json();
        let answer = http(port, "GET", "/api/drivelines/F1/map").await;
        let live = http(port, "GET", "/api/drivelines/F1").await.json();
        assert_eq!(answer.status, 200, "{}", answer.body);
        assert_security_headers(&answer, "/api/drivelines/F1/map");
        let map = answer.json();
        let same_bite = before["bite_counter"] == live["bite_counter"];
        if map["state"] != "building" && same_bite {
            break (map, live);
        }
        if map["state"] != "building" {
            continue;
        }
        assert!(
            map["message"].as_str().unwrap().contains("wear maps"),
            "{map}"
        );
        assert!(
            start.elapsed() < Duration::from_secs(60),
            "maps still building: {map}"
        );
        tokio::time::sleep(Duration::from_millis(200)).await;
    };
    assert_eq!(map["state"], "ready", "{map}");
    assert_eq!(
        map["model"], "Table 2 driveline, stiffness adjusted to measurement",
        "{map}"
    );
    let couplings = map["couplings"].as_array().unwrap();
    // The demo's model has 2 couplings, both candidates; gaps 0..=8 mrad (defaults).
    assert_eq!(couplings.len(), 2, "{map}");
    for coupling in couplings {
        let curves = coupling["curves"].as_array().unwrap();
        let gaps: Vec<f64> = curves
            .iter()
            .map(|c| c["gap_mrad"].as_f64().unwrap())
            .collect();
        assert_eq!(gaps, (0..=8).map(f64::from).collect::<Vec<_>>());
        for curve in curves {
            let points = curve["points"].as_array().unwrap();
            assert_eq!(points.len(), 12, "torque_points of the demo");
            assert!(points
                .windows(2)
                .all(|p| p[0][0].as_f64() < p[1][0].as_f64()));
        }
        // A backlash gap raises the TAF (the paper's premise): at every grid torque
        // the 8 mrad curve lies above the linear one.
        let (linear, widest) = (&curves[0]["points"], &curves[8]["points"]);
        for (a, b) in linear
            .as_array()
            .unwrap()
            .iter()
            .zip(widest.as_array().unwrap())
        {
            assert!(
                b[1].as_f64() > a[1].as_f64(),
                "coupling {}: TAF at 8 mrad {} not above the linear {}",
                coupling["coupling"],
                b[1],
                a[1]
            );
        }
    }
    // The estimate on its map is the live one.
    let estimate = &map["estimate"];
    // The driveline's figures: the catalogue's keys.
    let gap = &live;
    if gap["gap_mrad"].is_null() {
        assert!(estimate.is_null(), "{map}");
        return;
    }
    let named = gap["gap_coupling"]
        .as_u64()
        .or(gap["likeliest_coupling"].as_u64());
    assert_eq!(estimate["coupling"].as_u64(), named, "{estimate} vs {gap}");
    assert_eq!(estimate["determined"], !gap["gap_coupling"].is_null());
    let mrad = |v: &serde_json::Value| v["gap_mrad"].as_f64().unwrap();
    assert_eq!(mrad(&estimate["gap"]), mrad(gap));
    assert_eq!(estimate["low"]["gap_mrad"], gap["gap_low_mrad"]);
    assert_eq!(estimate["high"]["gap_mrad"], gap["gap_high_mrad"]);
    assert!(mrad(&estimate["low"]) <= mrad(&estimate["gap"]));
    assert!(mrad(&estimate["gap"]) <= mrad(&estimate["high"]));
    // The pooled bites (measured by the bite pipeline on the simulated mill, whose
    // gap opens) lie nearer the estimate's curve than the linear driveline's: the
    // page draws the two on one scale.
    let curve = estimate["gap"]["points"].as_array().unwrap();
    let coupling = couplings
        .iter()
        .find(|c| c["coupling"] == estimate["coupling"])
        .unwrap();
    let linear = coupling["curves"][0]["points"].as_array().unwrap();
    let pooled = gap["bites_pooled"].as_u64().unwrap() as u32;
    let (mut to_estimate, mut to_linear) = (Vec::new(), Vec::new());
    for bite in newest_bites(setup, pooled) {
        let (Some(taf), Some(s), false) = (
            bite.figures.taf,
            bite.figures.static_torque_knm,
            bite.figures.last_bite_degraded,
        ) else {
            continue;
        };
        if let (Some(on_estimate), Some(on_linear)) = (at(curve, s), at(linear, s)) {
            eprintln!(
                "bite {}: static {s:.0} kN*m, TAF {taf:.3}; map at {:.2} mrad {on_estimate:.3}, \
                 linear {on_linear:.3}",
                bite.figures.bite_counter,
                mrad(&estimate["gap"])
            );
            to_estimate.push((taf - on_estimate).abs());
            to_linear.push((taf - on_linear).abs());
        }
    }
    assert!(!to_estimate.is_empty(), "no pooled bite inside the map");
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    assert!(
        mean(&to_estimate) < 0.05 && mean(&to_estimate) < mean(&to_linear),
        "bites off the estimate's curve: {to_estimate:?} (linear {to_linear:?})"
    );
}

/// The overview's gap trend (kept between bites) equals the history's fit over the
/// file, before and after a new bite.
async fn gap_trend_follows_the_file(port: u16, setup: &Setup) {
    let file_trend = || {
        HistoryReader::open(&setup.history)
            .unwrap()
            .gap_trend("F1", None, TREND_WINDOW)
            .unwrap()
            .map(|t| t.mrad_per_week)
    };
    let start = Instant::now();
    let mut seen = Vec::new();
    while seen.len() < 2 {
        assert!(
            start.elapsed() < Duration::from_secs(60),
            "no gap trend twice: {seen:?}"
        );
        // The page's trend between two reads of the file that agree (no bite between).
        let before = file_trend();
        let page = http(port, "GET", "/api/overview").await.json()["drivelines"][0]
            ["gap_trend_mrad_per_week"]
            .as_f64();
        if before.is_none() || before != file_trend() || seen.contains(&before) {
            tokio::time::sleep(Duration::from_millis(200)).await;
            continue;
        }
        let file = before.unwrap();
        let page = page.unwrap_or_else(|| panic!("no trend on the page, {file} in the file"));
        assert!(
            (page - file).abs() <= 1e-9 * file.abs(),
            "page {page} mrad/week, file {file}"
        );
        seen.push(before);
    }
}

/// `/api/drivelines/F1`'s `gap_cone` against the same answer's figures (the board's
/// gap, growth and last bite): dated from the last bite, the band around its mean,
/// the fitted line ending at the gap with the growth's slope; null without a growth.
async fn gap_cone_follows_the_board(port: u16) {
    let time = |v: &serde_json::Value| {
        UtcTime::parse(v.as_str().unwrap_or_else(|| panic!("a time: {v}")))
            .unwrap()
            .unix_ms()
    };
    let start = Instant::now();
    let f1 = loop {
        let f1 = http(port, "GET", "/api/drivelines/F1").await.json();
        if !f1["gap_growth_mrad_per_day"].is_null() {
            break f1;
        }
        assert!(f1["gap_cone"].is_null(), "a cone without a growth: {f1}");
        assert!(
            start.elapsed() < Duration::from_secs(60),
            "no gap growth after 60 s: {f1}"
        );
        tokio::time::sleep(Duration::from_millis(200)).await;
    };
    let cone = &f1["gap_cone"];
    assert!(cone.is_object(), "a growth without a cone: {f1}");
    eprintln!(
        "F1 after bite {}: gap {} mrad, growth {} mrad/day, forecast {} ({} days, {}..{}), \
         cone to {}",
        f1["bite_counter"],
        f1["gap_mrad"],
        f1["gap_growth_mrad_per_day"],
        f1["gap_forecast"],
        f1["days_to_gap_alarm"],
        f1["days_to_gap_alarm_low"],
        f1["days_to_gap_alarm_high"],
        cone["points"][15]["time"]
    );
    let last = time(&f1["last_bite_time"]);
    let points = cone["points"].as_array().unwrap();
    assert_eq!(points.len(), 16, "{cone}");
    assert_eq!(time(&points[0]["time"]), last, "{cone}");
    // In time order (all at the last bite when the gap is at the alarm already).
    for pair in points.windows(2) {
        assert!(time(&pair[0]["time"]) <= time(&pair[1]["time"]), "{cone}");
    }
    for point in points {
        let mrad = |key: &str| point[key].as_f64().unwrap();
        assert!(
            mrad("low_mrad") <= mrad("mean_mrad") && mrad("mean_mrad") <= mrad("high_mrad"),
            "{point}"
        );
    }
    // The cone reaches past the late end of the forecast, when there is one.
    if let Some(high) = f1["days_to_gap_alarm_high"].as_f64() {
        let end = time(&points[15]["time"]);
        assert!(
            end as f64 >= last as f64 + high * 86_400_000.0,
            "cone to {end}, late end {high} days after {last}: {f1}"
        );
    }
    let line = &cone["fitted_line"];
    assert_eq!(time(&line["to_time"]), last, "{line}");
    assert_eq!(line["to_mrad"], f1["gap_mrad"], "{line}");
    let back_days = (last - time(&line["from_time"])) as f64 / 86_400_000.0;
    assert!((0.0..=28.0).contains(&back_days), "{line}");
    let slope = f1["gap_growth_mrad_per_day"].as_f64().unwrap();
    let from = f1["gap_mrad"].as_f64().unwrap() - slope * back_days;
    assert!(
        (line["from_mrad"].as_f64().unwrap() - from).abs() <= 1e-6 * (1.0 + from.abs()),
        "{line}: {from} expected"
    );
}

/// A 400 whose JSON error names `words`.
async fn assert_bad(port: u16, path: &str, words: &[&str]) {
    let answer = http(port, "GET", path).await;
    assert_eq!(answer.status, 400, "{path}: {}", answer.body);
    let error = answer.json()["error"].as_str().unwrap().to_owned();
    for word in words {
        assert!(
            error.contains(word),
            "{path}: {error:?} does not name {word:?}"
        );
    }
    assert_security_headers(&answer, path);
}

fn newest_bites(setup: &Setup, limit: u32) -> Vec<BiteRow> {
    HistoryReader::open(&setup.history)
        .unwrap()
        .newest(&Filter {
            name: Some("F1".into()),
            limit: Some(limit),
            ..Filter::default()
        })
        .unwrap()
}

/// The `data:` JSON of every whole `results` event in `text` (chunked framing lines
/// never start with `data: `).
fn events(text: &str) -> Vec<serde_json::Value> {
    text.split('\n')
        .filter_map(|line| line.strip_prefix("data: "))
        .filter_map(|data| serde_json::from_str(data.trim_end()).ok())
        .collect()
}

/// An open `/api/events` stream.
struct EventStream {
    stream: TcpStream,
    text: String,
}

impl EventStream {
    async fn open(port: u16) -> Self {
        let mut stream = TcpStream::connect(("127.0.0.1", port)).await.unwrap();
        stream
            .write_all(
                b"GET /api/events HTTP/1.1\r\nhost: localhost\r\naccept: text/event-stream\r\n\r\n",
            )
            .await
            .unwrap();
        Self {
            stream,
            text: String::new(),
        }
    }

    /// Read until an event satisfies `done`, at most `limit`.
    async fn until(
        &mut self,
        limit: Duration,
        done: impl Fn(&serde_json::Value) -> bool,
    ) -> serde_json::Value {
        let start = Instant::now();
        let mut buffer = [0u8; 8192];
        loop {
            if let Some(event) = events(&self.text).into_iter().rev().find(|e| done(e)) {
                return event;
            }
            let left = limit.saturating_sub(start.elapsed());
            let read = tokio::time::timeout(left, self.stream.read(&mut buffer))
                .await
                .unwrap_or_else(|_| panic!("no such event within {limit:?}: {}", self.text))
                .unwrap();
            assert!(read > 0, "events stream closed: {}", self.text);
            self.text
                .push_str(&String::from_utf8_lossy(&buffer[..read]));
        }
    }
}

/// An answer as curl(1) got it: status, headers (names lower-case) and the body's
/// bytes as sent (curl decodes nothing without `--compressed`).
struct Curled {
    status: u16,
    headers: Vec<(String, String)>,
    body: Vec<u8>,
}

impl Curled {
    fn header(&self, name: &str) -> Option<&str> {
        self.headers
            .iter()
            .find(|(key, _)| key == name)
            .map(|(_, value)| value.as_str())
    }
}

/// `GET path` on the page's port with curl and the request headers `headers`; at
/// most `max_time` s (the event stream does not end by itself).
fn curl(port: u16, path: &str, headers: &[&str], max_time: u32) -> Curled {
    let mut command = std::process::Command::new("curl");
    command.args(["-sS", "-i", "--max-time", &max_time.to_string()]);
    for header in headers {
        command.args(["-H", header]);
    }
    let output = command
        .arg(format!("http://127.0.0.1:{port}{path}"))
        .output()
        .expect("curl (scripts/test installs it)");
    let raw = &output.stdout;
    let split = raw
        .windows(4)
        .position(|w| w == b"\r\n\r\n")
        .unwrap_or_else(|| panic!("{path}: no answer from curl: {output:?}"));
    let head = String::from_utf8_lossy(&raw[..split]).into_owned();
    let mut lines = head.lines();
    let status = lines
        .next()
        .and_then(|line| line.split(' ').nth(1))
        .and_then(|code| code.parse().ok())
        .unwrap_or_else(|| panic!("{path}: no status line in {head:?}"));
    Curled {
        status,
        headers: lines
            .filter_map(|line| line.split_once(':'))
            .map(|(k, v)| (k.trim().to_ascii_lowercase(), v.trim().to_owned()))
            .collect(),
        body: raw[split + 4..].to_vec(),
    }
}

/// `bytes` unpacked by gzip(1), not by the flate2 the server packs with.
fn gunzip(bytes: &[u8]) -> Vec<u8> {
    use std::io::Write as _;
    let mut child = std::process::Command::new("gzip")
        .arg("-dc")
        .stdin(std::process::Stdio::piped())
        .stdout(std::process::Stdio::piped())
        .spawn()
        .expect("gzip");
    child.stdin.take().unwrap().write_all(bytes).unwrap();
    let output = child.wait_with_output().unwrap();
    assert!(output.status.success(), "gzip -dc: {output:?}");
    output.stdout
}

/// Text answers come gzipped to a client that accepts it (and the bytes unpack to the
/// plain answer), plain to one that does not, each marked `Vary: Accept-Encoding`; the
/// event stream is never packed; the assets carry strong ETags (one per form) that
/// `If-None-Match` turns into 304, while a changed tag gets the whole asset; the
/// pages say `no-cache` and the API's live JSON `no-store`, neither with a validator;
/// the favicon is served.
async fn compressed_and_validated(port: u16) {
    const GZIP: &str = "Accept-Encoding: gzip, deflate, br";
    for path in [
        "/",
        "/drivelines/F1",
        "/alarms",
        "/assets/app.js",
        "/assets/app.css",
        "/assets/uPlot-1.6.32.min.js",
        "/api/overview",
        "/api/drivelines/F1/bites?limit=500",
    ] {
        // A live answer may change between two requests: compared when the plain
        // answers before and after the packed one are the same.
        let mut compared = false;
        for _ in 0..10 {
            let before = curl(port, path, &[], 10);
            let packed = curl(port, path, &[GZIP], 10);
            let after = curl(port, path, &[], 10);
            assert_eq!((before.status, packed.status), (200, 200), "{path}");
            assert_eq!(before.header("content-encoding"), None, "{path}");
            assert_eq!(packed.header("content-encoding"), Some("gzip"), "{path}");
            for answer in [&before, &packed] {
                assert!(
                    answer
                        .header("vary")
                        .is_some_and(|vary| vary.to_ascii_lowercase().contains("accept-encoding")),
                    "{path}: {:?}",
                    answer.headers
                );
            }
            assert!(packed.body.len() < before.body.len(), "{path}");
            if before.body == after.body {
                assert!(
                    gunzip(&packed.body) == before.body,
                    "{path}: unpacked differs"
                );
                eprintln!(
                    "{path}: {} bytes, {} gzipped",
                    before.body.len(),
                    packed.body.len()
                );
                compared = true;
                break;
            }
        }
        assert!(compared, "{path} changed at every try");
    }
    // The live-update stream goes as it is, even to a gzip client.
    let events = curl(port, "/api/events", &[GZIP], 1);
    assert_eq!(events.status, 200);
    assert!(events
        .header("content-type")
        .is_some_and(|t| t.starts_with("text/event-stream")));
    assert_eq!(events.header("content-encoding"), None);
    // Pages and the API: no validator; the pages are revalidated, the API not stored.
    for (path, cache) in [("/", "no-cache"), ("/api/overview", "no-store")] {
        let answer = curl(port, path, &[], 10);
        assert_eq!(answer.header("cache-control"), Some(cache), "{path}");
        assert_eq!(answer.header("etag"), None, "{path}");
    }
    // The assets' validators.
    let vendored = std::fs::read(common::repo().join("gateway/assets/web/app.js")).unwrap();
    let plain = curl(port, "/assets/app.js", &[], 10);
    let packed = curl(port, "/assets/app.js", &[GZIP], 10);
    assert_eq!(plain.body, vendored);
    let (tag, packed_tag) = (
        plain.header("etag").expect("an ETag").to_owned(),
        packed.header("etag").expect("an ETag").to_owned(),
    );
    assert!(tag.starts_with('"') && tag.ends_with('"'), "strong: {tag}");
    assert!(packed_tag.starts_with('"'), "strong: {packed_tag}");
    assert_ne!(tag, packed_tag, "one tag per form");
    let css_tag = curl(port, "/assets/app.css", &[], 10);
    assert_ne!(
        css_tag.header("etag"),
        Some(tag.as_str()),
        "one tag per asset"
    );
    for (accept, etag) in [(None, &tag), (Some(GZIP), &packed_tag)] {
        let mut headers = vec![format!("If-None-Match: {etag}")];
        headers.extend(accept.map(str::to_owned));
        let headers: Vec<&str> = headers.iter().map(String::as_str).collect();
        let again = curl(port, "/assets/app.js", &headers, 10);
        assert_eq!(again.status, 304, "{headers:?}");
        assert!(again.body.is_empty());
        assert_eq!(again.header("etag"), Some(etag.as_str()));
        // A changed tag (another build's asset) gets the whole asset.
        let changed = format!(
            "If-None-Match: \"0000000000000000\", W/{}x\"",
            &etag[..etag.len() - 1]
        );
        let mut headers = vec![changed.as_str()];
        headers.extend(accept);
        let whole = curl(port, "/assets/app.js", &headers, 10);
        assert_eq!(whole.status, 200, "{headers:?}");
        let body = if accept.is_some() {
            gunzip(&whole.body)
        } else {
            whole.body
        };
        assert!(body == vendored, "{headers:?}");
    }
    // The plain form's tag does not validate the gzipped form.
    let other_form = curl(
        port,
        "/assets/app.js",
        &[&format!("If-None-Match: {tag}"), GZIP],
        10,
    );
    assert_eq!(other_form.status, 200);
    // The icon, where browsers look for it and where the pages link it.
    let icon = std::fs::read(common::repo().join("gateway/assets/web/favicon.svg")).unwrap();
    for path in ["/favicon.ico", "/assets/favicon.svg"] {
        let answer = curl(port, path, &[], 10);
        assert_eq!(answer.status, 200, "{path}");
        assert_eq!(
            answer.header("content-type"),
            Some("image/svg+xml"),
            "{path}"
        );
        assert!(answer.body == icon, "{path}");
    }
    let page = curl(port, "/", &[], 10);
    assert!(String::from_utf8_lossy(&page.body)
        .contains("<link rel=\"icon\" href=\"/assets/favicon.svg\" type=\"image/svg+xml\">"));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_api_answers_from_the_live_results_and_the_history_and_refuses_bad_requests() {
    let setup = Setup::new(MILLGATE, "web-api", "history").await;
    let port = free_port();
    setup.append_config(&format!("\n[outputs.web]\nbind = \"127.0.0.1:{port}\"\n"));
    let service = setup.spawn("web-api.log");
    web_ready(port).await;
    let plc = setup.plc();
    plc.bites_after_now(2).await;

    // Pages and assets.
    let page = http(port, "GET", "/").await;
    assert_eq!(page.status, 200);
    assert!(page
        .header("content-type")
        .unwrap()
        .starts_with("text/html"));
    assert!(page
        .body
        .contains("<script src=\"/assets/app.js\" defer></script>"));
    assert!(!page.body.contains("<script>"), "no inline script");
    assert_security_headers(&page, "/");
    let uplot = http(port, "GET", "/assets/uPlot-1.6.32.min.js").await;
    let vendored =
        std::fs::read_to_string(common::repo().join("gateway/assets/uplot/uPlot.iife.min.js"))
            .unwrap();
    assert_eq!(uplot.status, 200);
    assert_eq!(uplot.body, vendored);
    assert!(uplot
        .header("content-type")
        .unwrap()
        .starts_with("text/javascript"));
    assert_security_headers(&uplot, "uPlot");
    let driveline_page = http(port, "GET", "/drivelines/F1").await;
    assert_eq!(driveline_page.status, 200);
    assert!(driveline_page.body.contains("id=\"gap-plot\""));
    assert_eq!(http(port, "GET", "/drivelines/F9").await.status, 404);
    assert_eq!(http(port, "GET", "/nothing").await.status, 404);
    compressed_and_validated(port).await;

    // The overview against the PLC and the file (outages read before and after: a
    // loaded machine may see the source stall at the start).
    let outages = || {
        HistoryReader::open(&setup.history)
            .unwrap()
            .outages(&Filter {
                name: Some("daq1".into()),
                ..Filter::default()
            })
            .unwrap()
            .len() as u64
    };
    let outages_before = outages();
    let overview = http(port, "GET", "/api/overview").await;
    let outages_after = outages();
    assert_eq!(overview.status, 200);
    assert_eq!(overview.header("cache-control"), Some("no-store"));
    assert_security_headers(&overview, "/api/overview");
    let overview = overview.json();
    assert_eq!(overview["history"], true);
    let f1 = &overview["drivelines"][0];
    assert_eq!(f1["name"], "F1");
    // Every catalogue figure by its key (null while it has none).
    for figure in millgate::state::catalogue::DRIVELINE {
        assert!(
            f1.get(figure.key).is_some(),
            "the page's driveline has no {}: {f1}",
            figure.key
        );
    }
    let counter = f1["bite_counter"].as_u64().unwrap();
    let plc_counter = u64::from(plc.counter());
    assert!(
        counter >= 2 && counter.abs_diff(plc_counter) <= 1,
        "page {counter}, PLC {plc_counter}"
    );
    // The demo's TAFs are above the test's lowered thresholds (1.1 / 1.15).
    assert_eq!(f1["taf_alarm"], true);
    assert_eq!(f1["taf_state"], "alarm");
    assert_eq!(overview["sources"][0]["name"], "daq1");
    assert_eq!(overview["sources"][0]["status"], "ok");
    let outages_24h = overview["sources"][0]["outages_24h"].as_u64().unwrap();
    assert!(
        (outages_before..=outages_after).contains(&outages_24h),
        "page {outages_24h} outages, file {outages_before}..={outages_after}"
    );
    let drivelines = http(port, "GET", "/api/drivelines").await.json();
    assert_eq!(drivelines.as_array().unwrap().len(), 1);
    let one = http(port, "GET", "/api/drivelines/F1").await.json();
    assert_eq!(one["name"], "F1");
    assert_eq!(one["thresholds"]["taf_alarm"], 1.15);
    // The nameplate of the demo's `drivelines[0].identification`, by its file keys.
    assert_eq!(
        one["identification"],
        serde_json::json!({
            "manufacturer": "Example Mill Works",
            "model": "HSM finishing stand drive",
            "serial_number": "F1-0001",
            "product_instance_uri": "urn:example:millgate-demo:F1",
            "year_of_construction": 1998,
        })
    );

    // Bites: the newest, as stored.
    let stored = newest_bites(&setup, 2);
    let bites = http(port, "GET", "/api/drivelines/F1/bites?limit=2").await;
    assert_eq!(bites.status, 200, "{}", bites.body);
    let bites = bites.json();
    let bites = bites.as_array().unwrap();
    assert!(!bites.is_empty() && bites.len() <= 2);
    let last = bites.last().unwrap();
    let newest_id = stored.last().unwrap().id;
    assert!(
        last["id"].as_i64().unwrap() >= newest_id,
        "API's newest bite {} older than the file's {newest_id}",
        last["id"]
    );
    assert_eq!(last["driveline"], "F1");
    // A time range: every row inside it.
    let first_time = stored[0].time().clone();
    let ranged = http(
        port,
        "GET",
        &format!("/api/drivelines/F1/bites?since={first_time}&limit=10000"),
    )
    .await;
    assert_eq!(ranged.status, 200, "{}", ranged.body);
    // No process context here: the bites have no product, none is listed by product.
    assert!(
        last["product"].is_null() && last["gated"].is_null(),
        "{last}"
    );
    let of_product = http(port, "GET", "/api/drivelines/F1/bites?product=101").await;
    assert_eq!(
        (of_product.status, of_product.json()),
        (200, serde_json::json!([]))
    );
    let products = http(port, "GET", "/api/drivelines/F1/products").await;
    assert_eq!(
        (products.status, products.json()),
        (200, serde_json::json!([]))
    );
    assert_bad(
        port,
        "/api/drivelines/F1/bites?product=-1",
        &["product", "0..=4294967295"],
    )
    .await;
    let ranged = ranged.json();
    let ranged = ranged.as_array().unwrap();
    assert!(!ranged.is_empty());
    assert!(ranged
        .iter()
        .all(|b| b["time"].as_str().unwrap() >= first_time.as_str()));
    let before = http(
        port,
        "GET",
        &format!("/api/drivelines/F1/bites?until={first_time}"),
    )
    .await
    .json();
    assert!(before
        .as_array()
        .unwrap()
        .iter()
        .all(|b| b["time"].as_str().unwrap() < first_time.as_str()));
    // Wear series in buckets.
    let wear = http(port, "GET", "/api/drivelines/F1/wear?points=3").await;
    assert_eq!(wear.status, 200, "{}", wear.body);
    let wear = wear.json();
    let wear = wear.as_array().unwrap();
    assert!(!wear.is_empty() && wear.len() <= 3);
    assert!(wear.iter().all(|p| p["bites"].as_u64().unwrap() >= 1));
    // Alarms: the TAF alarm the first bite raised.
    let alarms = http(port, "GET", "/api/alarms?subject=F1").await.json();
    assert!(
        alarms
            .as_array()
            .unwrap()
            .iter()
            .any(|a| a["kind"] == "taf_alarm" && a["event"] == "raised"),
        "{alarms}"
    );

    wear_map_on_the_page(port, &setup).await;
    gap_trend_follows_the_file(port, &setup).await;
    gap_cone_follows_the_board(port).await;

    // Bad parameters, unknown names.
    assert_bad(
        port,
        "/api/drivelines/F1/bites?limit=10001",
        &["limit", "1..=10000"],
    )
    .await;
    assert_bad(
        port,
        "/api/drivelines/F1/bites?limit=0",
        &["limit", "1..=10000"],
    )
    .await;
    assert_bad(port, "/api/drivelines/F1/bites?limit=ten", &["limit"]).await;
    assert_bad(
        port,
        "/api/drivelines/F1/bites?since=yesterday",
        &["since", "ISO-8601"],
    )
    .await;
    assert_bad(
        port,
        "/api/drivelines/F1/bites?since=2026-02-01&until=2026-01-01",
        &["since", "before", "until"],
    )
    .await;
    assert_bad(
        port,
        "/api/drivelines/F1/bites?sort=asc",
        &["sort", "since, until, limit"],
    )
    .await;
    assert_bad(
        port,
        "/api/drivelines/F1/bites?limit=1&limit=2",
        &["limit", "twice"],
    )
    .await;
    assert_bad(
        port,
        "/api/drivelines/F1/wear?points=0",
        &["points", "1..=10000"],
    )
    .await;
    assert_bad(port, "/api/drivelines/F1/map?coupling=1", &["coupling"]).await;
    assert_bad(port, "/api/alarms?until=2026-13-01", &["until"]).await;
    assert_bad(port, "/api/overview?x=1", &["x"]).await;
    let unknown = http(port, "GET", "/api/drivelines/F9/bites").await;
    assert_eq!(unknown.status, 404);
    assert!(unknown.json()["error"].as_str().unwrap().contains("F9"));
    assert_eq!(http(port, "GET", "/api/drivelines/F9").await.status, 404);
    assert_eq!(
        http(port, "GET", "/api/drivelines/F9/map").await.status,
        404
    );

    // Read-only: other methods, bodies.
    for (method, path) in [
        ("POST", "/api/overview"),
        ("DELETE", "/"),
        ("PUT", "/api/alarms"),
        ("POST", "/nothing"),
    ] {
        let answer = http(port, method, path).await;
        assert_eq!(answer.status, 405, "{method} {path}");
        assert_eq!(answer.header("allow"), Some("GET, HEAD"));
        assert!(answer.json()["error"]
            .as_str()
            .unwrap()
            .contains("read-only"));
        assert_security_headers(&answer, method);
    }
    let with_body = http_raw(
        port,
        b"GET /api/overview HTTP/1.1\r\nhost: localhost\r\nconnection: close\r\ncontent-length: 5\r\n\r\nhello",
    )
    .await;
    assert_eq!(with_body.status, 413);
    let head = http(port, "HEAD", "/api/overview").await;
    assert_eq!(head.status, 200);
    assert!(head.body.is_empty());
    // Too large and malformed heads.
    let huge = format!(
        "GET / HTTP/1.1\r\nhost: localhost\r\nx-padding: {}\r\nconnection: close\r\n\r\n",
        "a".repeat(20_000)
    );
    assert_eq!(http_raw(port, huge.as_bytes()).await.status, 431);
    assert_eq!(http_raw(port, b"BLURB\x01 /\r\n\r\n").await.status, 400);

    // Live: the next bite arrives on /api/events (within 2 s of the PLC seeing it on a
    // quiet machine; the time is printed, and the limit only catches a stream that
    // never says it: a loaded CI machine is no place for a speed assertion).
    let mut live = EventStream::open(port).await;
    let first = live.until(LIVE, |_| true).await;
    let seen = first["drivelines"][0]["bite_counter"].as_u64().unwrap();
    let plc_before = plc.counter();
    plc.bites_after_now(1).await;
    let plc_seen = Instant::now();
    assert!(u64::from(plc_before) >= seen);
    let event = live
        .until(LIVE, |e| {
            e["drivelines"][0]["bite_counter"].as_u64() > Some(u64::from(plc_before))
        })
        .await;
    eprintln!(
        "/api/events had the bite {:.2} s after the PLC",
        plc_seen.elapsed().as_secs_f64()
    );
    assert_eq!(event["drivelines"][0]["name"], "F1");
    drop(live);
    setup.stop(service).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn slow_connections_are_closed_excess_streams_refused_while_the_modbus_path_answers_and_no_history_is_said(
) {
    let setup = Setup::new(MILLGATE, "web-limits", "history").await;
    let port = free_port();
    // Without [history]: live figures only.
    let text = std::fs::read_to_string(&setup.config).unwrap();
    let without_history = text.split("\n[history]").next().unwrap().to_owned();
    assert!(!without_history.contains("[history]"));
    std::fs::write(
        &setup.config,
        format!(
            "{without_history}\n[outputs.web]\nbind = \"127.0.0.1:{port}\"\nmax_connections = 3\n\
             max_event_streams = 2\nheader_timeout_ms = 500\n"
        ),
    )
    .unwrap();
    let service = setup.spawn("web-limits.log");
    web_ready(port).await;

    // No history: the API says so; the live figures are there.
    let overview = http(port, "GET", "/api/overview").await;
    assert_eq!(overview.status, 200);
    assert_eq!(overview.json()["history"], false);
    let bites = http(port, "GET", "/api/drivelines/F1/bites").await;
    assert_eq!(bites.status, 404);
    assert!(bites.json()["error"]
        .as_str()
        .unwrap()
        .contains("no history configured"));

    // A connection that sends nothing, and one that sends its head a byte at a time,
    // are closed after the 500 ms header timeout.
    for (what, trickle) in [("silent", false), ("slowloris", true)] {
        let start = Instant::now();
        let mut stream = TcpStream::connect(("127.0.0.1", port)).await.unwrap();
        let closed = async {
            let head = b"GET / HTTP/1.1\r\nhost: localhost\r\nx-slow: aaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaa";
            let mut buffer = [0u8; 1024];
            for byte in head.iter().cycle() {
                if trickle && stream.write_all(&[*byte]).await.is_err() {
                    return;
                }
                match tokio::time::timeout(Duration::from_millis(100), stream.read(&mut buffer))
                    .await
                {
                    Ok(Ok(0)) | Ok(Err(_)) => return,
                    Ok(Ok(_)) => {} // hyper's 408 answer, then the close
                    Err(_) => {}
                }
            }
        };
        tokio::time::timeout(Duration::from_secs(3), closed)
            .await
            .unwrap_or_else(|_| panic!("{what} connection still open after 3 s"));
        let held = start.elapsed();
        assert!(
            held >= Duration::from_millis(400),
            "{what} closed after {held:?}"
        );
    }

    // Two live pages take the two live-update streams (max_event_streams = 2): a
    // third stream is answered 503 with Retry-After, and the third connection still
    // serves everything else.
    let mut pages = Vec::new();
    for _ in 0..2 {
        let mut page = EventStream::open(port).await;
        page.until(Duration::from_secs(2), |_| true).await;
        pages.push(page);
    }
    let refused = http(port, "GET", "/api/events").await;
    assert_eq!(refused.status, 503);
    assert_eq!(refused.header("retry-after"), Some("2"));
    assert!(refused.json()["error"]
        .as_str()
        .unwrap()
        .contains("every live-update stream is taken"));
    assert_eq!(http(port, "GET", "/api/overview").await.status, 200);
    // Meanwhile the PLC gets bites and the Modbus server answers.
    setup.plc().bites_after_now(1).await;
    let mut modbus = TcpStream::connect(("127.0.0.1", setup.server_port))
        .await
        .unwrap();
    // Read holding register 0 (FC 3), unit 1.
    modbus
        .write_all(&[0, 7, 0, 0, 0, 6, 1, 3, 0, 0, 0, 1])
        .await
        .unwrap();
    let mut answer = [0u8; 11];
    tokio::time::timeout(LIVE, modbus.read_exact(&mut answer))
        .await
        .expect("a Modbus answer")
        .unwrap();
    assert_eq!(&answer[..9], &[0, 7, 0, 0, 0, 5, 1, 3, 2]);
    // A page closed frees its stream.
    drop(pages.pop());
    let start = Instant::now();
    loop {
        let mut page = EventStream::open(port).await;
        let mut head = [0u8; 12];
        page.stream.read_exact(&mut head).await.unwrap();
        if &head == b"HTTP/1.1 200" {
            break;
        }
        assert!(start.elapsed() < LIVE, "no stream freed");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    drop(pages);
    setup.stop(service).await;
}
