//! The maintenance page in a real browser: Debian's headless chromium driven through
//! chromedriver (WebDriver, fantoccini) against a real service with a history. The
//! overview lists the driveline, the driveline page's gap plot is a uPlot canvas with
//! data and the API's forecast (the cone up to its end, the expected date or the
//! forecast's words written on it), its TAF plot carries the wear map's curves and the estimate's, its bite trace
//! is a captured bite's samples beside the model's response (the capture and response
//! APIs' numbers; another row's "plot" switches to that bite), and a new bite
//! shows on the open overview and driveline page without a reload (the time it took is
//! printed: the README's "within 2 s" is a figure of a quiet machine, not asserted on a
//! loaded CI machine). Then, in the same browser at a phone's 390 px, every page and the
//! `report` command's `report.html` fit the width (no sideways scrolling), and each
//! plot has a text alternative that gives its figures, and axe-core (npm, installed by
//! `scripts/test`) finds no violation on any of them. A tandem mill's page plots a
//! chatter episode written into the history before the start: the band RMS and the
//! spectra as `/api/captures/{id}/bands` gives them; its "capture" button (with
//! `allow_commands`) has the gateway accept a manual capture of the stands.
//!
//! Every read of the page is one script call (`until_js`): the live updates re-render
//! the tables, so an element found in one WebDriver call can be stale in the next.
//!
//! Skipped (it says so on stderr) when `chromium` or `chromedriver` is not installed;
//! `scripts/test` installs both (`apt-get install chromium chromium-driver`).
//! `MILLGATE_SCREENSHOTS=DIR` saves the overview and the driveline page as PNG there
//! (the README's picture: `docs/img`).

mod common;

use std::os::unix::process::CommandExt as _;
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use common::episode::{stands, write_chatter_capture};
use common::tandem::modbus_source;
use common::{free_port, web_ready, Plc, Setup, MILLGATE};
use fantoccini::{Client, ClientBuilder};
use hyper_util::client::legacy::connect::HttpConnector;
use millgate::state::results::ForecastState;
use millgate::state::time::UtcTime;

/// `program` on the PATH.
fn which(program: &str) -> Option<PathBuf> {
    std::env::var_os("PATH").and_then(|paths| {
        std::env::split_paths(&paths)
            .map(|folder| folder.join(program))
            .find(|path| path.is_file())
    })
}

/// chromedriver on a free loopback port in a process group of its own, which is killed
/// on drop: the chromium it started goes too, also when a failing test never closed
/// its session.
struct Driver {
    child: Child,
    port: u16,
}

impl Drop for Driver {
    fn drop(&mut self) {
        let group = rustix::process::Pid::from_child(&self.child);
        let _ = rustix::process::kill_process_group(group, rustix::process::Signal::KILL);
        let _ = self.child.wait();
    }
}

async fn start_driver(chromedriver: &PathBuf) -> Driver {
    let port = free_port();
    let child = Command::new(chromedriver)
        .args([format!("--port={port}"), "--allowed-ips=127.0.0.1".into()])
        .process_group(0)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("start chromedriver");
    let driver = Driver { child, port };
    let start = Instant::now();
    while tokio::net::TcpStream::connect(("127.0.0.1", port))
        .await
        .is_err()
    {
        assert!(
            start.elapsed() < Duration::from_secs(20),
            "chromedriver not up in 20 s"
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    driver
}

async fn browser(driver: &Driver, chromium: &PathBuf) -> Client {
    let mut capabilities = serde_json::Map::new();
    capabilities.insert(
        "goog:chromeOptions".into(),
        serde_json::json!({
            "binary": chromium,
            // CI runs as root: no sandbox.
            "args": ["--headless=new", "--no-sandbox", "--disable-gpu",
                     "--disable-dev-shm-usage", "--window-size=1280,1000"],
        }),
    );
    ClientBuilder::new(HttpConnector::new())
        .capabilities(capabilities)
        .connect(&format!("http://127.0.0.1:{}", driver.port))
        .await
        .expect("a chromium session through chromedriver")
}

/// Counts the page's fetches from now on by kind: `window.fetched.{overview, wear,
/// bites}`.
const COUNT_FETCHES: &str = "window.fetched = { overview: 0, wear: 0, bites: 0 }; \
    const fetchOriginal = window.fetch; \
    window.fetch = (url, options) => { \
      const path = String(url); \
      if (path.startsWith('/api/overview')) window.fetched.overview++; \
      if (path.includes('/wear')) window.fetched.wear++; \
      if (path.includes('/bites')) window.fetched.bites++; \
      return fetchOriginal(url, options); \
    }; \
    return true;";

/// Longest wait for a live update: a page that does not update live never shows the
/// bite; one that does takes ~0.2-1 s on a quiet machine, longer on a loaded one.
const LIVE: Duration = Duration::from_secs(15);

/// The PLC sees a new bite, and `script` (the bite counter the page shows) passes it
/// without a reload of the `page`; prints how long that took.
async fn new_bite_shows_live(client: &Client, plc: &Plc<'_>, script: &str, page: &str) {
    let plc_before = plc.counter();
    plc.bites_after_now(1).await;
    let seen = Instant::now();
    until_js(client, script, LIVE, |v| {
        v.as_u64() > Some(u64::from(plc_before))
    })
    .await;
    eprintln!(
        "the {page} showed the bite {:.2} s after the PLC",
        seen.elapsed().as_secs_f64()
    );
    let kept = client
        .execute("return window.notReloaded === true;", vec![])
        .await
        .unwrap();
    assert_eq!(kept, serde_json::Value::Bool(true), "the {page} reloaded");
}

/// Wait until the page fetched `kind` again (counted since [`COUNT_FETCHES`]), then
/// check it fetched no gap series.
async fn refetched_without_series(client: &Client, kind: &str) {
    let count = format!("return window.fetched.{kind};");
    until_js(client, &count, Duration::from_secs(10), |v| {
        v.as_u64() >= Some(1)
    })
    .await;
    let fetched = client
        .execute("return window.fetched;", vec![])
        .await
        .unwrap();
    assert_eq!(fetched["wear"], 0, "{fetched}");
}

/// Evaluate `script` (a `return ...` body) until `done` holds for its value, at most
/// `limit`; the last value.
async fn until_js(
    client: &Client,
    script: &str,
    limit: Duration,
    done: impl Fn(&serde_json::Value) -> bool,
) -> serde_json::Value {
    let start = Instant::now();
    loop {
        let value = client.execute(script, vec![]).await.expect(script);
        if done(&value) {
            return value;
        }
        assert!(start.elapsed() < limit, "{script}: {value} after {limit:?}");
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

/// Whether `a` and `b` are the same numbers (to JSON's round trip through the browser).
fn same_numbers(a: &serde_json::Value, b: &serde_json::Value) -> bool {
    let (Some(a), Some(b)) = (a.as_array(), b.as_array()) else {
        return false;
    };
    a.len() == b.len()
        && a.iter()
            .zip(b)
            .all(|(x, y)| match (x.as_f64(), y.as_f64()) {
                (Some(x), Some(y)) => (x - y).abs() <= 1e-12 * x.abs().max(1.0),
                _ => false,
            })
}

/// The cone's means of a driveline's `gap_cone` as the page's plot holds them: one per
/// time (a cone of a gap at the alarm already has all its points at the last bite).
fn cone_means(cone: &serde_json::Value) -> serde_json::Value {
    let mut means: Vec<(String, serde_json::Value)> = Vec::new();
    for point in cone["points"].as_array().into_iter().flatten() {
        let time = point["time"].as_str().unwrap_or("").to_owned();
        match means.last_mut() {
            Some(last) if last.0 == time => last.1 = point["mean_mrad"].clone(),
            _ => means.push((time, point["mean_mrad"].clone())),
        }
    }
    serde_json::Value::Array(means.into_iter().map(|(_, mean)| mean).collect())
}

/// `/api/drivelines/F1` and the driveline page's gap plot (its forecast series, its
/// forecast text, the note under it, its last time, whether it has the forecast's
/// band) once they agree: read until two API reads around the page's see the same
/// bite and the page draws that answer's cone.
async fn agreeing_forecast(client: &Client, port: u16) -> (serde_json::Value, serde_json::Value) {
    let read_page = "const p = window.millgatePlots.gap; \
        if (!p) return null; \
        const i = p.series.findIndex((s) => s.label === 'forecast'); \
        return [p.data[i].filter((v) => v !== null && v !== undefined), p.millgateForecast || null, \
          document.getElementById('gap-forecast').textContent, p.data[0][p.data[0].length - 1], \
          p.series.findIndex((s) => s.label === 'forecast 90% high') > 0];";
    let start = Instant::now();
    loop {
        let before = common::http(port, "GET", "/api/drivelines/F1").await.json();
        let page = client.execute(read_page, vec![]).await.unwrap();
        let after = common::http(port, "GET", "/api/drivelines/F1").await.json();
        let cone = &after["gap_cone"];
        if before["bite_counter"] == after["bite_counter"]
            && !cone.is_null()
            && !page.is_null()
            && same_numbers(&page[0], &cone_means(cone))
        {
            return (after, page);
        }
        assert!(
            start.elapsed() < Duration::from_secs(60),
            "the page's forecast {page} never matched the API's {after}"
        );
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
}

/// The driveline page's gap plot carries the API's forecast of `/api/drivelines/F1`:
/// the cone's mean as its `forecast` series up to the cone's end, its band, and what
/// the forecast says written on the plot and under it: the state's words while it
/// gives no days, then (more bites asked of the `plc`: the demo's gap opens fast)
/// the expected date of the gap alarm with its interval.
async fn gap_plot_has_the_forecast(client: &Client, port: u16, plc: &Plc<'_>) {
    for round in 0.. {
        let (api, page) = agreeing_forecast(client, port).await;
        let points = api["gap_cone"]["points"].as_array().unwrap();
        let end = UtcTime::parse(points[points.len() - 1]["time"].as_str().unwrap()).unwrap();
        assert_eq!(
            page[3].as_f64(),
            Some(end.unix_ms() as f64 / 1000.0),
            "{page}"
        );
        assert_eq!(page[4], true, "the forecast's band: {page}");
        let said = page[1]
            .as_str()
            .unwrap_or_else(|| panic!("no forecast text: {page}"));
        assert!(
            page[2].as_str().is_some_and(|note| note.contains(said)),
            "{page}"
        );
        // A state figure carries its value; the catalogue names it.
        let state = api["gap_forecast"]
            .as_u64()
            .and_then(|value| ForecastState::NAMES.get(value as usize))
            .unwrap_or_else(|| panic!("gap_forecast of {api}"));
        eprintln!(
            "the gap plot's forecast after bite {}: {said} ({state})",
            api["bite_counter"]
        );
        let words = match *state {
            "forecast" => {
                let date = &api["gap_alarm_date"].as_str().unwrap()[..10];
                let expected = format!("alarm expected {date} (");
                assert!(said.starts_with(&expected), "{said:?} for {api}");
                return;
            }
            "at_alarm" => "at the alarm",
            "not_growing" => "not growing",
            "beyond_horizon" => "beyond the horizon",
            "too_few_bites" => "too few bites",
            other => panic!("gap_forecast {other}"),
        };
        assert_eq!(said, words, "{api}");
        assert!(
            round < 10,
            "no forecast with days after {round} more bites: {api}"
        );
        plc.bites_after_now(1).await;
    }
}

/// The driveline page's bite trace: the newest captured bite's torque samples as the
/// capture API gives them, the model's response as the response API gives it, on the
/// capture's time grid; the bite's row links its capture's downloads, and its "plot"
/// button on another bite's row plots that bite's capture.
/// The fatigue panel lists the web API's components, plots each component's life used
/// over time (a line per component, from `/fatigue/history`, and the life limit) and
/// the damage per bite over TAF, and its reset button resets the component (the API
/// then gives it a later installation, and `/fatigue/history` the reset).
async fn fatigue_panel_is_the_ledger_and_resets(client: &Client, port: u16) {
    let long = Duration::from_secs(10);
    let panel = until_js(
        client,
        "const s = document.getElementById('fatigue'); \
         const rows = document.querySelectorAll('#fatigue-components tbody tr'); \
         const p = window.millgatePlots || {}; \
         return s && !s.classList.contains('hidden') && rows.length === 2 && p.fatigueLife \
           ? [Array.from(rows).map((r) => r.cells[0].textContent), \
              p.fatigueLife.data[1].filter((v) => v !== null).length, \
              p.fatigueDamage.data[0].length, \
              document.querySelectorAll('#fatigue-components button.fatigue-reset').length, \
              p.fatigueLife.series.map((s) => s.label), \
              p.fatigueLife.data.slice(1).map((c) => c.filter((v) => v !== null).length), \
              p.fatigueLife.data[p.fatigueLife.data.length - 1][0], \
              document.getElementById('fatigue-life-plot').getAttribute('aria-label')] : null;",
        long,
        |v| !v.is_null(),
    )
    .await;
    assert_eq!(
        panel[0],
        serde_json::json!(["spindle", "coupling"]),
        "{panel}"
    );
    let bites = common::http(port, "GET", "/api/drivelines/F1/bites?limit=500")
        .await
        .json();
    let with_life = bites
        .as_array()
        .unwrap()
        .iter()
        .filter(|b| b["fatigue_life_used"].is_number())
        .count();
    assert!(
        panel[1].as_u64() >= Some(2) && panel[1].as_u64() <= Some(with_life as u64 + 1),
        "{panel} vs {with_life} stored bites with a life"
    );
    assert!(panel[2].as_u64() >= Some(1), "{panel}");
    assert_eq!(panel[3].as_u64(), Some(2), "a reset button per component");
    // A line per component and the limit, as the history API gives them.
    let history = common::http(port, "GET", "/api/drivelines/F1/fatigue/history?points=400")
        .await
        .json();
    assert_eq!(
        history["components"],
        serde_json::json!(["spindle", "coupling"]),
        "{history}"
    );
    let stored = history["points"].as_array().unwrap().len() as u64;
    assert!(stored >= 2, "{history}");
    assert_eq!(
        panel[4],
        serde_json::json!([
            "time (UTC)",
            "spindle, life used %",
            "coupling, life used %",
            "life limit %"
        ]),
        "{panel}"
    );
    // The page read the series a moment before: as many buckets or fewer, and the
    // live figures' point after them.
    for drawn in panel[5].as_array().unwrap() {
        let drawn = drawn.as_u64().unwrap();
        assert!(drawn >= 2 && drawn <= stored + 1, "{panel} vs {history}");
    }
    let limit = history["life_limit"].as_f64().unwrap();
    assert!(
        (panel[6].as_f64().unwrap() - 100.0 * limit).abs() < 1e-9,
        "{panel}"
    );
    let label = panel[7].as_str().unwrap();
    assert!(
        label.contains("spindle") && label.contains("coupling") && label.contains("life limit"),
        "{label}"
    );
    // The reset button (confirmed) resets the coupling.
    let installed = || async {
        common::http(port, "GET", "/api/drivelines/F1").await.json()["fatigue_components"][1]
            ["installed_unix_ms"]
            .as_i64()
    };
    let before = installed().await;
    assert!(before.is_some());
    client
        .execute(
            "window.confirm = () => true; \
             document.querySelector('button.fatigue-reset[data-component=\"coupling\"]').click(); \
             return true;",
            vec![],
        )
        .await
        .unwrap();
    let start = std::time::Instant::now();
    loop {
        let now = installed().await;
        if now > before {
            break;
        }
        assert!(start.elapsed() < long, "not reset: installed {now:?}");
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    let said = until_js(
        client,
        "return document.getElementById('fatigue-said').textContent;",
        long,
        |v| v.as_str().is_some_and(|t| !t.is_empty()),
    )
    .await;
    assert!(said.as_str().unwrap().contains("coupling"), "{said}");
    let start = std::time::Instant::now();
    loop {
        let history = common::http(port, "GET", "/api/drivelines/F1/fatigue/history")
            .await
            .json();
        if history["resets"][0]["component"] == "coupling" {
            break;
        }
        assert!(start.elapsed() < long, "no reset in the history: {history}");
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

async fn trace_is_the_captures_samples_beside_the_model(client: &Client, port: u16) {
    let long = Duration::from_secs(20);
    let trace = until_js(
        client,
        "const p = window.millgatePlots.trace; \
         return p ? [p.millgateCapture, p.data, p.series.length] : null;",
        long,
        |v| !v.is_null() && v[2].as_u64() == Some(3),
    )
    .await;
    let id = trace[0].as_i64().expect("the plotted capture's id");
    let capture = common::http(port, "GET", &format!("/api/captures/{id}")).await;
    assert_eq!(capture.status, 200, "{}", capture.body);
    let capture = capture.json();
    assert_eq!(capture["kind"], "bite");
    let samples = &capture["channels"][0]["samples"];
    assert!(samples.as_array().unwrap().len() > 100, "{capture}");
    assert!(
        same_numbers(&trace[1][1], samples),
        "the trace is not the capture's samples"
    );
    let rate = capture["sample_rate_hz"].as_f64().unwrap();
    let grid: Vec<f64> = (0..samples.as_array().unwrap().len())
        .map(|k| k as f64 / rate)
        .collect();
    assert!(
        same_numbers(&trace[1][0], &serde_json::json!(grid)),
        "time grid"
    );
    let response = common::http(port, "GET", &format!("/api/captures/{id}/response")).await;
    assert_eq!(response.status, 200, "{}", response.body);
    let response = response.json();
    assert!(
        same_numbers(&trace[1][2], &response["response"]["torque_knm"]),
        "the model's series is not the response API's"
    );
    // The aligned model's static torque is the bite's as the gateway measured it
    // (another computation: the bite detector's settled mean), and the model explains
    // most of the measured transient: its residual is small beside the samples' own
    // spread about that static torque. (Not beside the static torque: the demo's
    // spindles wear by design, so the residual grows bite by bite, and which bite the
    // page plots depends on how fast the machine is; 5.19 kN*m at bite 5 once.)
    let bites = common::http(port, "GET", "/api/drivelines/F1/bites?limit=500").await;
    let bite_counter = capture["bite_counter"].as_i64().unwrap();
    let bite = bites
        .json()
        .as_array()
        .unwrap()
        .iter()
        .find(|b| b["bite_counter"].as_i64() == Some(bite_counter))
        .cloned()
        .expect("the plotted bite in the bites API");
    let measured_knm = bite["static_torque_knm"].as_f64().unwrap();
    let aligned_knm = response["response"]["static_torque_knm"].as_f64().unwrap();
    let residual_knm = response["response"]["residual_rms_knm"].as_f64().unwrap();
    let values: Vec<f64> = samples
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    let spread_knm = (values
        .iter()
        .map(|v| (v - aligned_knm).powi(2))
        .sum::<f64>()
        / values.len() as f64)
        .sqrt();
    eprintln!(
        "bite {bite_counter}: static torque {measured_knm:.1} kN*m measured, \
         {aligned_knm:.1} kN*m aligned; residual {residual_knm:.2} kN*m RMS, \
         the samples' spread about it {spread_knm:.2} kN*m RMS"
    );
    assert!(
        (aligned_knm / measured_knm - 1.0).abs() < 0.05,
        "{aligned_knm} vs {measured_knm}"
    );
    assert!(
        residual_knm < 0.5 * spread_knm,
        "{residual_knm} against a spread of {spread_knm}"
    );
    // The row links the capture's files; another row's button plots its capture.
    let links = client
        .execute(
            &format!(
                "const r = document.querySelector('#bites tbody tr[data-bite=\"{bite_counter}\"]'); \
                 return r ? Array.from(r.querySelectorAll('a')).map((a) => a.getAttribute('href')) : null;"
            ),
            vec![],
        )
        .await
        .unwrap();
    assert_eq!(
        links,
        serde_json::json!([
            format!("/api/captures/{id}/file?format=csv"),
            format!("/api/captures/{id}/file?format=parquet")
        ])
    );
    let other = client
        .execute(
            &format!(
                "const b = Array.from(document.querySelectorAll('#bites button.plot-capture')) \
                   .find((b) => Number(b.dataset.capture) !== {id}); \
                 if (!b) return null; b.click(); return Number(b.dataset.capture);"
            ),
            vec![],
        )
        .await
        .unwrap();
    let other = other.as_i64().expect("a second captured bite in the table");
    let shown = until_js(
        client,
        "const p = window.millgatePlots.trace; return [p.millgateCapture, p.data[1]];",
        long,
        |v| v[0].as_i64() == Some(other),
    )
    .await;
    let theirs = common::http(port, "GET", &format!("/api/captures/{other}"))
        .await
        .json();
    assert!(same_numbers(&shown[1], &theirs["channels"][0]["samples"]));
}

/// The tandem mill's page: its episode listed with its downloads, and plotted: the
/// band plot's series are the stands' band RMS as `/api/captures/{id}/bands` gives
/// it, the spectra plot's the stands' PSD, and their descriptions give the peaks.
async fn episode_plots_are_the_bands_api(client: &Client, port: u16) {
    client
        .goto(&format!("http://127.0.0.1:{port}/tandem_mills/TCM"))
        .await
        .unwrap();
    let shown = until_js(
        client,
        "const p = window.millgatePlots; \
         const rows = document.querySelectorAll('#episodes tbody tr'); \
         return p.band && p.spectrum && rows.length > 0 \
           ? [p.band.millgateCapture, p.band.data, p.spectrum.data, \
              document.getElementById('spectrum-plot').getAttribute('aria-label'), \
              rows[0].querySelector('a').getAttribute('href'), rows.length, \
              rows[0].cells[6].textContent, rows[0].cells[5].textContent] : null;",
        Duration::from_secs(20),
        |v| !v.is_null(),
    )
    .await;
    let id = shown[0].as_i64().expect("the plotted capture's id");
    assert_eq!(shown[5].as_u64(), Some(1), "{shown}");
    // The context the episode was captured in, beside it, and the product group whose
    // thresholds judged it (schema v15).
    assert_eq!(
        shown[6].as_str(),
        Some("coil 4711, product 205, 1200 m/min"),
        "{shown}"
    );
    assert_eq!(
        shown[7].as_str(),
        Some(common::episode::THRESHOLDS_GROUP),
        "{shown}"
    );
    assert_eq!(
        shown[4].as_str(),
        Some(format!("/api/captures/{id}/file?format=csv").as_str())
    );
    let bands = common::http(port, "GET", &format!("/api/captures/{id}/bands")).await;
    let bands: serde_json::Value = serde_json::from_str(&bands.body).unwrap();
    assert!(
        same_numbers(&shown[1][0], &bands["band_rms"][0]["t_s"]),
        "{shown}"
    );
    assert!(
        same_numbers(&shown[2][0], &bands["spectra"][0]["frequency_hz"]),
        "{shown}"
    );
    for stand in 0..3 {
        assert!(
            same_numbers(&shown[1][stand + 1], &bands["band_rms"][stand]["max"]),
            "band RMS of stand {stand}: {} vs {}",
            shown[1][stand + 1],
            bands["band_rms"][stand]["max"]
        );
        assert!(same_numbers(
            &shown[2][stand + 1],
            &bands["spectra"][stand]["max"]
        ));
        let peak = format!(
            "s{}_vib peak at {:.1} Hz",
            stand + 1,
            bands["spectra"][stand]["peak_hz"].as_f64().unwrap()
        );
        assert!(
            shown[3].as_str().unwrap().contains(&peak),
            "{peak}: {shown}"
        );
    }
    // The capture button (allow_commands) asks the gateway through POST /api/captures.
    let said = until_js(
        client,
        "const b = document.getElementById('capture-request'); \
         if (!b) return null; \
         if (!window.asked) { window.asked = true; b.click(); } \
         return document.getElementById('capture-said').textContent;",
        Duration::from_secs(20),
        |v| v.as_str().is_some_and(|t| !t.is_empty()),
    )
    .await;
    assert!(
        said.as_str()
            .is_some_and(|t| t.contains("asked: the next 10 s of TCM")),
        "{said}"
    );
}

/// A phone's viewport width, CSS px (an iPhone 12 to 15's).
const PHONE_WIDTH: u32 = 390;

/// Measures the open page in one script call (a live update cannot re-render it
/// between two reads): the document's width, the viewport's, the elements that
/// stick out of the viewport (outside a box that scrolls them), and each plot's role
/// and accessible name. The sections hidden for want of such mills (tandem, rod) are
/// shown while it measures: their tables' headers are among the widest rows.
const MEASURE: &str = "const hidden = Array.from(document.querySelectorAll('.hidden')); \
    hidden.forEach((e) => e.classList.remove('hidden')); \
    const inner = window.innerWidth; \
    const width = document.documentElement.scrollWidth; \
    const clipped = (e) => { \
      for (let a = e.parentElement; a; a = a.parentElement) { \
        if (['auto', 'scroll', 'hidden'].includes(getComputedStyle(a).overflowX)) return true; \
      } \
      return false; \
    }; \
    const out = Array.from(document.body.querySelectorAll('*')) \
      .filter((e) => e.getBoundingClientRect().right > inner + 0.5 && !clipped(e)) \
      .slice(0, 8) \
      .map((e) => e.tagName.toLowerCase() + (e.id ? '#' + e.id : '') \
        + (e.className && e.className.baseVal === undefined ? '.' + e.className : '') \
        + ' ' + Math.round(e.getBoundingClientRect().right)); \
    hidden.forEach((e) => e.classList.add('hidden')); \
    const plots = Array.from(document.querySelectorAll('.plot')) \
      .map((p) => [p.id, p.getAttribute('role'), p.getAttribute('aria-label')]); \
    return [width, inner, out, plots];";

/// axe-core's script, as `scripts/test` installs it (`npm ci --prefix tests/browser`);
/// `None` (said on stderr) where it is not installed.
fn axe_source() -> Option<String> {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../tests/browser/node_modules/axe-core/axe.min.js");
    let source = std::fs::read_to_string(&path).ok();
    if source.is_none() {
        eprintln!(
            "axe-core is not installed ({}): its rules are not run (npm ci --prefix tests/browser)",
            path.display()
        );
    }
    source
}

/// The violations axe-core finds on the open page: `[rule, impact, nodes, first
/// targets]` each.
async fn axe_violations(client: &Client, axe: &str) -> serde_json::Value {
    client.execute(axe, vec![]).await.expect("load axe-core");
    client
        .execute_async(
            "const done = arguments[arguments.length - 1]; \
             axe.run(document).then( \
               (r) => done(r.violations.map((v) => [v.id, v.impact, v.nodes.length, \
                 v.nodes.slice(0, 3).map((n) => n.target.join(' '))])), \
               (e) => done(['axe failed', String(e)]));",
            vec![],
        )
        .await
        .expect("run axe-core")
}

/// How many `<main>` a page has, and the elements of its body outside the landmarks
/// (`header`, `nav`, `main`, `footer`, `aside`; scripts and `noscript` do not show).
const LANDMARKS: &str = "const landmarks = ['HEADER', 'NAV', 'MAIN', 'FOOTER', 'ASIDE', \
     'SCRIPT', 'NOSCRIPT']; \
     return [document.querySelectorAll('main').length, \
       Array.from(document.body.children) \
         .filter((e) => !landmarks.includes(e.tagName)) \
         .map((e) => e.tagName + (e.id ? '#' + e.id : ''))];";

/// At a phone's width every page, and `report.html` of the test's history, shows no
/// horizontal overflow: `document.documentElement.scrollWidth <= window.innerWidth`
/// (tables scroll in their own box, plots are as wide as the screen, the menu and long
/// names wrap); each has one `<main>` and nothing outside its landmarks
/// ([`LANDMARKS`]), and axe-core finds no violation of its rules. And every plot on the pages is `role="img"` with a name that gives
/// its figures (a drawn plot's, not the shell's placeholder).
async fn pages_fit_a_phone_and_plots_are_described(client: &Client, port: u16, setup: &Setup) {
    let long = Duration::from_secs(20);
    let axe = axe_source();
    let report = setup.scratch.join("report");
    let made = common::MILLGATE
        .command()
        .args(["report", "--db"])
        .arg(&setup.history)
        .arg("--out")
        .arg(&report)
        .output()
        .expect("run millgate report");
    assert!(made.status.success(), "{made:?}");
    client.set_window_size(PHONE_WIDTH, 844).await.unwrap();
    let base = format!("http://127.0.0.1:{port}");
    // Each page, and when it is filled: its tables' rows and its plots drawn.
    let pages = [
        (
            format!("{base}/"),
            "return !!document.querySelector('#driveline-F1') \
               && !!window.millgatePlots.overviewGap \
               && document.querySelectorAll('#sources tbody tr').length > 0;",
        ),
        (
            format!("{base}/drivelines/F1"),
            "const p = window.millgatePlots; \
             return !!(p.gap && p.taf && p.trace) \
               && document.querySelectorAll('#bites tbody tr').length > 0 \
               && document.querySelectorAll('#cards .card').length > 0;",
        ),
        (
            format!("{base}/tandem_mills/TCM"),
            "const p = window.millgatePlots; \
             return !!(p.band && p.spectrum) \
               && document.querySelectorAll('#episodes tbody tr').length > 0 \
               && document.querySelectorAll('#mill-state .card').length === 5 \
               && document.querySelector('#mill-state').textContent.includes('Thresholds');",
        ),
        (
            format!("{base}/alarms"),
            "return document.querySelectorAll('#alarms tbody tr').length > 0;",
        ),
        (
            // A name longer than the screen, without a place to break.
            format!(
                "{base}/drivelines/{}",
                "NoSuchDrivelineWithANameLongerThanAPhone".repeat(2)
            ),
            "return document.readyState === 'complete';",
        ),
        (
            format!("file://{}", report.join("report.html").display()),
            "return document.readyState === 'complete' \
               && document.querySelectorAll('figure svg').length > 0;",
        ),
    ];
    for (url, filled) in &pages {
        client.goto(url).await.unwrap();
        until_js(client, filled, long, |v| {
            v == &serde_json::Value::Bool(true)
        })
        .await;
        let measured = client.execute(MEASURE, vec![]).await.unwrap();
        let (width, inner) = (measured[0].as_u64(), measured[1].as_u64());
        eprintln!("{url} at {PHONE_WIDTH} px: {measured}");
        assert_eq!(inner, Some(u64::from(PHONE_WIDTH)), "{url}: {measured}");
        assert!(width <= inner, "{url} overflows sideways: {measured}");
        // Landmarks (axe's `landmark-one-main` and `region` rules): one <main>, and
        // every element of the body in a landmark.
        let landmarks = client.execute(LANDMARKS, vec![]).await.unwrap();
        assert_eq!(landmarks[0], 1, "{url}: one <main>: {landmarks}");
        assert_eq!(
            landmarks[1],
            serde_json::json!([]),
            "{url}: content outside the landmarks: {landmarks}"
        );
        // And every rule of axe-core itself (WCAG 2 A/AA and best practices).
        if let Some(axe) = &axe {
            let violations = axe_violations(client, axe).await;
            assert_eq!(
                violations,
                serde_json::json!([]),
                "{url}: axe: {violations}"
            );
        }
        for plot in measured[3].as_array().unwrap() {
            assert_eq!(plot[1], "img", "{url}: {plot}");
            let name = plot[2].as_str().unwrap_or("");
            assert!(
                !name.contains("not drawn yet") && name.contains(|c: char| c.is_ascii_digit()),
                "{url}: plot without a description of its figures: {plot}"
            );
        }
    }
    // The report's plots are figures with a caption.
    let captions = client
        .execute(
            "return Array.from(document.querySelectorAll('figure')) \
               .map((f) => f.querySelector('figcaption') ? f.querySelector('figcaption').textContent : '');",
            vec![],
        )
        .await
        .unwrap();
    let captions = captions.as_array().unwrap();
    assert!(!captions.is_empty());
    assert!(
        captions
            .iter()
            .all(|c| c.as_str().is_some_and(|c| !c.is_empty())),
        "{captions:?}"
    );
}

async fn screenshot(client: &Client, name: &str) {
    if let Some(folder) = std::env::var_os("MILLGATE_SCREENSHOTS") {
        let png = client.screenshot().await.expect("screenshot");
        std::fs::write(PathBuf::from(folder).join(name), png).expect("write screenshot");
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_pages_list_the_drivelines_plot_the_gap_and_show_a_new_bite_live() {
    let (Some(chromium), Some(chromedriver)) = (which("chromium"), which("chromedriver")) else {
        eprintln!(
            "skipped: chromium or chromedriver not installed (scripts/test installs them: \
             apt-get install chromium chromium-driver)"
        );
        return;
    };
    let setup = Setup::new(MILLGATE, "web-browser", "history").await;
    let port = free_port();
    // With manual captures through the API: the pages offer the button.
    setup.append_config(&format!(
        "\n[outputs.web]\nbind = \"127.0.0.1:{port}\"\nallow_commands = true\n"
    ));
    // A tandem mill (its DAQ absent) with a chatter episode already in the history.
    write_chatter_capture(&setup.history, "TCM").expect("write the episode");
    setup.append_config(&(modbus_source("tcm") + &stands("tcm", "TCM").toml()));
    // A fatigue ledger of two components on the driveline: the page's fatigue panel.
    let text = std::fs::read_to_string(&setup.config).unwrap();
    let text = text.replace(
        "wear = { gap_step_mrad",
        "fatigue = { gate_knm = 2.0, components = [\n  \
         { name = \"spindle\", m = 5, ref_cycles = 1e6, ref_range_knm = 112 },\n  \
         { name = \"coupling\", m = 3, ref_cycles = 1e7, ref_range_knm = 150 },\n] }\n\
         wear = { gap_step_mrad",
    );
    assert!(text.contains("name = \"coupling\""), "demo.toml changed");
    std::fs::write(&setup.config, text).unwrap();
    let service = setup.spawn("web-browser.log");
    web_ready(port).await;
    let plc = setup.plc();
    plc.bites_after_now(2).await;
    let driver = start_driver(&chromedriver).await;
    let client = browser(&driver, &chromium).await;
    let long = Duration::from_secs(10);

    // The overview lists the driveline.
    client
        .goto(&format!("http://127.0.0.1:{port}/"))
        .await
        .unwrap();
    // Read in one script call: a live update re-renders the rows, so an element found
    // in one WebDriver call can be gone by the next (StaleElementReference, issue 28).
    let listed = until_js(
        &client,
        "const row = document.querySelector('#driveline-F1'); \
         return row ? [row.textContent.trim(), \
           document.querySelectorAll('#drivelines tbody tr').length] : null;",
        long,
        |v| !v.is_null(),
    )
    .await;
    assert!(
        listed[0]
            .as_str()
            .is_some_and(|text| text.starts_with("F1")),
        "{listed}"
    );
    assert_eq!(listed[1].as_u64(), Some(1), "{listed}");
    // A new bite shows without a reload.
    client
        .execute("window.notReloaded = true; return true;", vec![])
        .await
        .unwrap();
    let counter =
        "return Number(document.querySelector('#driveline-F1 .bite-counter').textContent);";
    let shown = until_js(&client, counter, long, |v| v.as_u64() > Some(0)).await;
    assert!(shown.as_u64().unwrap() <= u64::from(plc.counter()) + 1);
    new_bite_shows_live(&client, &plc, counter, "overview").await;
    // Its gap plot: every driveline's estimates from the history.
    until_js(
        &client,
        "const p = window.millgatePlots.overviewGap; \
         return p ? p.data[1].filter((v) => v !== null).length : 0;",
        long,
        |v| v.as_u64() >= Some(2),
    )
    .await;
    // A later bite's estimate is appended from the live figures, without fetching the
    // history's series again (they scan the file; refetched every 5 min at most).
    client.execute(COUNT_FETCHES, vec![]).await.unwrap();
    let estimates = "const p = window.millgatePlots.overviewGap; \
                     return p.data[1].filter((v) => v !== null && v !== undefined).length;";
    let shown = client.execute(estimates, vec![]).await.unwrap();
    plc.bites_after_now(1).await;
    until_js(&client, estimates, LIVE, |v| v.as_u64() > shown.as_u64()).await;
    // The overview itself is fetched again 1 s after the bite; the series are not.
    refetched_without_series(&client, "overview").await;
    screenshot(&client, "maintenance-overview.png").await;

    // The driveline page: the gap plot is a canvas with the history's data.
    client
        .goto(&format!("http://127.0.0.1:{port}/drivelines/F1"))
        .await
        .unwrap();
    let points = until_js(
        &client,
        "const p = window.millgatePlots && window.millgatePlots.gap; \
         return p ? p.data[1].filter((v) => v !== null).length : 0;",
        long,
        |v| v.as_u64() >= Some(2),
    )
    .await;
    assert!(points.as_u64().unwrap() >= 2);
    let canvas = client
        .execute(
            "const c = document.querySelector('#gap-plot canvas'); \
             return c ? [c.width, c.height] : null;",
            vec![],
        )
        .await
        .unwrap();
    assert!(
        canvas[0].as_u64() > Some(300) && canvas[1].as_u64() > Some(100),
        "{canvas}"
    );
    gap_plot_has_the_forecast(&client, port, &plc).await;
    fatigue_panel_is_the_ledger_and_resets(&client, port).await;
    trace_is_the_captures_samples_beside_the_model(&client, port).await;
    let taf_points = until_js(
        &client,
        "const p = window.millgatePlots.taf; return p ? p.data[0].length : 0;",
        long,
        |v| v.as_u64() >= Some(3),
    )
    .await;
    assert!(taf_points.as_u64().unwrap() >= 3);
    // On the wear map's curves: one per whole mrad (0..=8) of the coupling the
    // estimate names (or its likeliest), and the estimate's own curve with data.
    let curves = until_js(
        &client,
        "const p = window.millgatePlots.taf; \
         return p ? p.series.filter((s) => String(s.label).startsWith('map, gap')).length : 0;",
        long,
        |v| v.as_u64() == Some(9),
    )
    .await;
    assert_eq!(curves.as_u64(), Some(9));
    let coupling = || async {
        common::http(port, "GET", "/api/drivelines/F1/map")
            .await
            .json()["estimate"]["coupling"]
            .clone()
    };
    let before = coupling().await;
    let estimate = client
        .execute(
            "const p = window.millgatePlots.taf; \
             const i = p.series.findIndex((s) => String(s.label).startsWith('estimate')); \
             return i < 0 ? null : [p.millgateCoupling, \
               p.data[i].filter((v) => v !== null && v !== undefined).length, \
               document.querySelectorAll('#taf-coupling option').length];",
            vec![],
        )
        .await
        .unwrap();
    // (Compared only when no bite moved the estimate meanwhile.)
    if before == coupling().await {
        assert_eq!(estimate[0], before, "{estimate}");
    }
    assert_eq!(estimate[1].as_u64(), Some(12), "{estimate}");
    assert_eq!(estimate[2].as_u64(), Some(2), "{estimate}");
    // A new bite heads the table without a reload.
    client
        .execute("window.notReloaded = true; return true;", vec![])
        .await
        .unwrap();
    client.execute(COUNT_FETCHES, vec![]).await.unwrap();
    let newest = "const r = document.querySelector('#bites tbody tr[data-bite]'); \
                  return r ? Number(r.dataset.bite) : 0;";
    until_js(&client, newest, long, |v| v.as_u64() > Some(0)).await;
    new_bite_shows_live(&client, &plc, newest, "driveline page").await;
    // The stored rows come again after the bite, the gap series does not.
    refetched_without_series(&client, "bites").await;
    if std::env::var_os("MILLGATE_SCREENSHOTS").is_some() {
        // Let the stored rows replace the live one, for the picture.
        tokio::time::sleep(Duration::from_millis(1800)).await;
    }
    screenshot(&client, "maintenance-driveline.png").await;

    episode_plots_are_the_bands_api(&client, port).await;
    pages_fit_a_phone_and_plots_are_described(&client, port, &setup).await;
    client.close().await.unwrap();
    drop(driver);
    drop(service);
    setup.finish().await;
}

/// The Thresholds card of a tandem mill whose product comes from the PLC (issue 39):
/// a virtual DAQ streams the tandem model's stable rolling, a virtual PLC the product
/// code; product 7 is in the group "tight" (a quarter of the mill's thresholds),
/// product 8 in none. Read from the rendered card: product 7 shows the group's name and
/// its thresholds, product 8 the fallback ("mill's") and the mill's thresholds.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_thresholds_card_names_the_products_group_and_its_thresholds() {
    use millgate_sim::devices::virtual_plc::VirtualPlc;
    use millgate_tests::kit::tandem::{
        product_groups_toml, serve_daq_and_plc, stable_rolling_daq, tight_thresholds,
        GAIN_THRESHOLDS,
    };

    let (Some(chromium), Some(chromedriver)) = (which("chromium"), which("chromedriver")) else {
        eprintln!(
            "skipped: chromium or chromedriver not installed (scripts/test installs them: \
             apt-get install chromium chromium-driver)"
        );
        return;
    };
    let tight = tight_thresholds();
    // `values`, each as `write` gives it, comma-separated.
    let joined = |values: &[f64], write: fn(&f64) -> String| {
        values.iter().map(write).collect::<Vec<_>>().join(", ")
    };
    let port = free_port();
    let text = product_groups_toml("thresholds card")
        + &format!("[outputs.web]\nbind = \"127.0.0.1:{port}\"\n");
    let mut config =
        millgate_config::from_toml_str(&text, "thresholds-card.toml", std::path::Path::new("."))
            .unwrap_or_else(|e| panic!("{e}"));
    let daq = stable_rolling_daq().expect("the tandem model's rolling");
    let process = VirtualPlc::new(4);
    let set_product = |code: u16| process.bank().lock().holding[0] = code;
    set_product(7);
    let (daq_running, process_running) =
        serve_daq_and_plc(&mut config, daq, &process).await.unwrap();
    let gateway = millgate::Service::new(config)
        .unwrap()
        .spawn()
        .await
        .unwrap();
    web_ready(port).await;
    let driver = start_driver(&chromedriver).await;
    let client = browser(&driver, &chromium).await;
    client
        .goto(&format!("http://127.0.0.1:{port}/tandem_mills/TCM"))
        .await
        .unwrap();
    // The card's value and its line below, read in one script call (a live update
    // re-renders the cards).
    const CARD: &str = "const card = Array.from(document.querySelectorAll('#mill-state .card')) \
          .find((c) => c.querySelector('.label').textContent === 'Thresholds'); \
        return card ? [card.querySelector('.value').textContent, \
          card.querySelector('.sub').textContent] : null;";
    // As the card shows them.
    let shown = |values: &[f64]| joined(values, |t| format!("{t:.3}"));
    let long = Duration::from_secs(30);
    let group = until_js(&client, CARD, long, |v| v[0] == "tight").await;
    assert!(
        group[1]
            .as_str()
            .is_some_and(|sub| sub.contains(&shown(&tight))),
        "product 7: {group}"
    );
    set_product(8);
    let fallback = until_js(&client, CARD, long, |v| v[0] == "mill's").await;
    assert!(
        fallback[1]
            .as_str()
            .is_some_and(|sub| sub.contains(&shown(&GAIN_THRESHOLDS))),
        "product 8: {fallback}"
    );
    client.close().await.unwrap();
    drop(driver);
    tokio::time::timeout(Duration::from_secs(10), gateway.stop())
        .await
        .unwrap()
        .unwrap();
    daq_running.stop().await.unwrap();
    process_running.stop().await.unwrap();
}
