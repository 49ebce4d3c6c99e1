//! The pages: small HTML shells (names escaped, no inline script or style) that the
//! page's own script fills from the API, and the assets compiled into the binary.

use std::sync::{Arc, LazyLock};

use axum::extract::{Path, State};
use axum::http::{header, HeaderMap, HeaderValue, StatusCode};
use axum::response::{Html, IntoResponse, Response};

use super::encoding::Asset;
use super::shared::WebState;

/// uPlot's version, vendored in `gateway/assets/uplot` (MIT, its LICENSE beside it).
pub(crate) const UPLOT_VERSION: &str = "1.6.32";

/// The assets: path under `/assets/`, content type, bytes, Cache-Control; each with
/// its gzipped form and their ETags, made on first use.
static ASSETS: LazyLock<[Asset; 6]> = LazyLock::new(|| {
    [
        Asset::new(
            "app.js",
            "text/javascript; charset=utf-8",
            include_bytes!("../../../assets/web/app.js"),
            "no-cache",
        ),
        Asset::new(
            "app.css",
            "text/css; charset=utf-8",
            include_bytes!("../../../assets/web/app.css"),
            "no-cache",
        ),
        Asset::new(
            FAVICON,
            "image/svg+xml",
            include_bytes!("../../../assets/web/favicon.svg"),
            "no-cache",
        ),
        // Named with their version: a browser may keep them for a day.
        Asset::new(
            "uPlot-1.6.32.min.js",
            "text/javascript; charset=utf-8",
            include_bytes!("../../../assets/uplot/uPlot.iife.min.js"),
            "public, max-age=86400",
        ),
        Asset::new(
            "uPlot-1.6.32.min.css",
            "text/css; charset=utf-8",
            include_bytes!("../../../assets/uplot/uPlot.min.css"),
            "public, max-age=86400",
        ),
        Asset::new(
            "uPlot-LICENSE.txt",
            "text/plain; charset=utf-8",
            include_bytes!("../../../assets/uplot/LICENSE"),
            "public, max-age=86400",
        ),
    ]
});

/// The page's icon under `/assets/` (also answered at `/favicon.ico`, where browsers
/// look without a `<link rel=icon>`, e.g. on the JSON API).
const FAVICON: &str = "favicon.svg";

/// `text` with `& < > " '` escaped for HTML text and attribute values.
pub(crate) fn escape(text: &str) -> String {
    let mut escaped = String::with_capacity(text.len());
    for c in text.chars() {
        match c {
            '&' => escaped.push_str("&amp;"),
            '<' => escaped.push_str("&lt;"),
            '>' => escaped.push_str("&gt;"),
            '"' => escaped.push_str("&quot;"),
            '\'' => escaped.push_str("&#39;"),
            c => escaped.push(c),
        }
    }
    escaped
}

/// A whole page: `title` and `body` (already escaped), the page kind and driveline
/// (or tandem mill) for the script.
fn layout(state: &WebState, title: &str, page: &str, driveline: &str, body: &str) -> Response {
    let plant = escape(&state.config_name);
    let nav: String = state
        .drivelines
        .iter()
        .map(|d| {
            let name = escape(&d.name);
            format!("<a href=\"/drivelines/{name}\">{name}</a>")
        })
        .chain(state.tandem_mills.iter().map(|(mill, _)| {
            let name = escape(mill);
            format!("<a href=\"/tandem_mills/{name}\">{name}</a>")
        }))
        .collect();
    let html = format!(
        "<!doctype html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n\
         <meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">\n\
         <title>{title} · {plant} · millgate</title>\n\
         <link rel=\"icon\" href=\"/assets/{FAVICON}\" type=\"image/svg+xml\">\n\
         <link rel=\"stylesheet\" href=\"/assets/uPlot-{UPLOT_VERSION}.min.css\">\n\
         <link rel=\"stylesheet\" href=\"/assets/app.css\">\n\
         <script src=\"/assets/uPlot-{UPLOT_VERSION}.min.js\" defer></script>\n\
         <script src=\"/assets/app.js\" defer></script>\n</head>\n\
         <body data-page=\"{page}\" data-driveline=\"{driveline}\">\n\
         <header><a class=\"brand\" href=\"/\">millgate</a><span class=\"plant\">{plant}</span>\
         <nav><a href=\"/\">Overview</a>{nav}<a href=\"/alarms\">Alarms</a></nav>\
         <span id=\"live\" class=\"live\">connecting</span></header>\n\
         <main>\n{body}\n<noscript><p class=\"note\">This page needs JavaScript; the same \
         figures are in the JSON API under <a href=\"/api/overview\">/api/overview</a>.</p>\
         </noscript>\n</main>\n<footer>millgate {version} · read-only · \
         <a href=\"/api/overview\">JSON API</a> · plots by \
         <a href=\"/assets/uPlot-LICENSE.txt\">uPlot {UPLOT_VERSION}</a> (MIT)</footer>\n\
         </body>\n</html>\n",
        version = env!("CARGO_PKG_VERSION"),
    );
    let mut response = Html(html).into_response();
    response
        .headers_mut()
        .insert(header::CACHE_CONTROL, HeaderValue::from_static("no-cache"));
    response
}

const OVERVIEW: &str = r#"<h1>Overview</h1>
<section><h2>Drivelines</h2>
<div class="scroll" tabindex="0"><table id="drivelines" class="grid"><thead><tr><th>Driveline</th><th>Last bite</th><th>Bites</th>
<th>TAF</th><th>Opened gap (90% interval)</th><th>Growth · gap alarm expected</th><th>Wear</th></tr></thead>
<tbody></tbody></table></div></section>
<section><h2>Opened gap over time</h2><div id="overview-gap-plot" class="plot" role="img" aria-label="Opened gap over time: not drawn yet"></div>
<p class="note" id="overview-gap-note"></p></section>
<section id="mills-section"><h2>Tandem mills</h2>
<div class="scroll" tabindex="0"><table id="mills" class="grid"><thead><tr><th>Mill</th><th>Chatter</th><th>Early warning (gain / threshold)</th>
<th>Worst stand</th><th>Chatter frequency</th><th>Slow-down request</th></tr></thead><tbody></tbody></table></div></section>
<section id="rod-section"><h2>Rod mills</h2>
<div class="scroll" tabindex="0"><table id="rods" class="grid"><thead><tr><th>Mill</th><th>State</th><th>Worst span</th><th>Speed margin</th>
<th>Pass</th><th>Finishing speed</th></tr></thead><tbody></tbody></table></div></section>
<section><h2>Sources</h2>
<div class="scroll" tabindex="0"><table id="sources" class="grid"><thead><tr><th>Source</th><th>Kind</th><th>Status</th><th>Outages (24 h)</th>
<th>Last outage</th></tr></thead><tbody></tbody></table></div></section>"#;

const ALARMS: &str = r#"<h1>Alarms</h1>
<p class="note" id="alarms-note"></p>
<div class="scroll" tabindex="0"><table id="alarms" class="grid"><thead><tr><th>Time</th><th>Subject</th><th>Alarm</th><th>Event</th>
<th>By</th><th>Value</th><th>Threshold</th></tr></thead><tbody></tbody></table></div>"#;

/// `GET /`: the overview.
pub(crate) async fn overview(State(state): State<Arc<WebState>>) -> Response {
    layout(&state, "Overview", "overview", "", OVERVIEW)
}

/// `GET /alarms`: the alarm list.
pub(crate) async fn alarms(State(state): State<Arc<WebState>>) -> Response {
    layout(&state, "Alarms", "alarms", "", ALARMS)
}

/// The 404 page of a `what` (driveline, tandem mill) named `name` that is not configured.
fn not_found(state: &WebState, what: &str, name: &str) -> Response {
    let mut page = layout(
        state,
        "Not found",
        "missing",
        "",
        &format!(
            "<h1>No {what} “{}”</h1><p><a href=\"/\">Back to the overview</a></p>",
            escape(name)
        ),
    );
    *page.status_mut() = StatusCode::NOT_FOUND;
    page
}

/// `GET /drivelines/{name}`: one driveline, or 404.
pub(crate) async fn driveline(
    State(state): State<Arc<WebState>>,
    Path(name): Path<String>,
) -> Response {
    let Some(info) = state.drivelines.iter().find(|d| d.name == name) else {
        return not_found(&state, "driveline", &name);
    };
    let name = escape(&info.name);
    let body = format!(
        "<h1>Driveline {name}</h1>\n<div id=\"cards\" class=\"cards\"></div>\n\
         <section><h2>Opened gap over time</h2><div id=\"gap-plot\" class=\"plot\" role=\"img\" \
         aria-label=\"Opened gap over time: not drawn yet\"></div>\
         <p class=\"note\" id=\"gap-forecast\"></p>\
         <p class=\"note\" id=\"gap-note\"></p></section>\n\
         <section><h2>TAF over static torque</h2>\
         <label class=\"picker hidden\" id=\"taf-coupling-label\">gap map of coupling \
         <select id=\"taf-coupling\"></select></label>\
         <div id=\"taf-plot\" class=\"plot\" role=\"img\" \
         aria-label=\"TAF over static torque: not drawn yet\"></div>\
         <p class=\"note\" id=\"taf-note\"></p></section>\n\
         <section id=\"fatigue\" class=\"hidden\"><h2>Fatigue</h2>\
         <div class=\"scroll\" tabindex=\"0\"><table id=\"fatigue-components\" class=\"grid\"><thead><tr>\
         <th>Component</th><th>Life used</th><th>Last bite's damage</th><th>Rate</th>\
         <th>Life limit</th><th>Since</th><th>Replaced</th></tr></thead><tbody></tbody></table></div>\
         <p class=\"note\" id=\"fatigue-said\"></p>\
         <div id=\"fatigue-life-plot\" class=\"plot\" role=\"img\" \
         aria-label=\"Life used over time: not drawn yet\"></div>\
         <div id=\"fatigue-damage-plot\" class=\"plot\" role=\"img\" \
         aria-label=\"Damage per bite over TAF: not drawn yet\"></div>\
         <p class=\"note\" id=\"fatigue-note\"></p></section>\n\
         <section id=\"products\" class=\"hidden\"><h2>By product</h2>\
         <div class=\"scroll\" tabindex=\"0\"><table id=\"product-table\" class=\"grid\"><thead><tr>\
         <th>Product</th><th>Bites</th><th>Not pooled</th><th>TAF mean</th><th>TAF max</th>\
         <th>Static torque mean</th><th>Gap mean</th></tr></thead><tbody></tbody></table></div>\
         <p class=\"note\">The bites in the history by the product code the PLC gave (the \
         driveline's context): those not pooled into the wear trend (the mill's state or speed), \
         the TAF and static torque of clean bites, the wear trend's gap after the pooled ones.</p>\
         </section>\n\
         <section><h2>Bite trace</h2><div id=\"trace-plot\" class=\"plot\" role=\"img\" \
         aria-label=\"Bite trace: not drawn yet\"></div>\
         <p class=\"note\" id=\"trace-note\"></p></section>\n\
         <section><h2>Last bites</h2><label class=\"picker hidden\" id=\"product-filter-label\">product \
         <select id=\"product-filter\"><option value=\"\">all</option></select></label>\
         <div class=\"scroll\" tabindex=\"0\"><table id=\"bites\" class=\"grid\"><thead><tr>\
         <th>Time</th><th>Bite</th><th>Static torque</th><th>Peak torque</th><th>TAF</th>\
         <th>Period shift</th><th>Gap (90% interval)</th><th>Quality</th><th>Capture</th>\
         </tr></thead><tbody></tbody></table></div></section>"
    );
    layout(
        &state,
        &format!("Driveline {name}"),
        "driveline",
        &name,
        &body,
    )
}

/// `GET /tandem_mills/{name}`: one tandem mill's captured episodes, or 404.
pub(crate) async fn tandem_mill(
    State(state): State<Arc<WebState>>,
    Path(name): Path<String>,
) -> Response {
    let Some((mill, _)) = state.tandem_mills.iter().find(|(mill, _)| *mill == name) else {
        return not_found(&state, "tandem mill", &name);
    };
    let name = escape(mill);
    let body = format!(
        "<h1>Tandem mill {name}</h1>\n\
         <section><h2>State</h2><div id=\"mill-state\" class=\"cards\">\
         <p class=\"note\">waiting for the live state</p></div></section>\n\
         <section><h2>Episodes and captures</h2><p class=\"note\" id=\"episodes-note\"></p>\
         <div class=\"scroll\" tabindex=\"0\"><table id=\"episodes\" class=\"grid\"><thead><tr>\
         <th>Start</th><th>Kind</th><th>Length</th><th>Warning</th><th>Cleared</th>\
         <th>Thresholds</th><th>Context</th><th>Capture</th></tr></thead><tbody></tbody></table></div></section>\n\
         <section id=\"band-section\"><h2>Chatter-band signal</h2><div id=\"band-plot\" class=\"plot\" role=\"img\" \
         aria-label=\"Chatter-band signal: not drawn yet\"></div>\
         <p class=\"note\" id=\"band-note\"></p></section>\n\
         <section id=\"spectrum-section\"><h2>Spectra around the warning</h2><div id=\"spectrum-plot\" class=\"plot\" \
         role=\"img\" aria-label=\"Spectra around the warning: not drawn yet\"></div>\
         <p class=\"note\" id=\"spectrum-note\"></p></section>"
    );
    layout(
        &state,
        &format!("Tandem mill {name}"),
        "tandem_mill",
        &name,
        &body,
    )
}

/// `GET /assets/{file}`: the script, the style sheet, the icon and uPlot (gzipped
/// when accepted; 304 for a matching `If-None-Match`).
pub(crate) async fn asset(Path(file): Path<String>, headers: HeaderMap) -> Response {
    match ASSETS.iter().find(|asset| asset.name == file) {
        Some(asset) => asset.answer(&headers),
        None => crate::outputs::http::error(StatusCode::NOT_FOUND, "no such asset"),
    }
}

/// `GET /favicon.ico`: the page's icon (an SVG).
pub(crate) async fn favicon(headers: HeaderMap) -> Response {
    asset(Path(FAVICON.to_owned()), headers).await
}
