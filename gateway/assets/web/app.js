// millgate maintenance page: fills the server's HTML shell from the JSON API and keeps
// it live through /api/events (server-sent events). No framework; plots by uPlot.
"use strict";

(function () {
  const body = document.body;
  const page = body.dataset.page;
  const driveline = body.dataset.driveline;
  // The plots, for the browser test (it checks their data).
  window.millgatePlots = {};

  // ---- formatting -------------------------------------------------------------
  const num = (v, digits) => (v === null || v === undefined ? "–" : Number(v).toFixed(digits));
  // Every time on the pages is UTC and says so: "2026-11-27 08:14:03 UTC".
  const utc = (text) => (text ? text.replace("T", " ").replace(/\.\d+Z$|Z$/, "") + " UTC" : "–");
  // The process context a capture or chatter episode was taken in (its row's
  // columns, schema v14): the values the gateway trusted, and why not when it did not
  // ("coil 4711, product 205, 0.25 mm, 1200 m/min, pass 3, rolling"); "–" without one.
  function contextText(r) {
    if (!r || !r.context_status) return "–";
    const parts = [];
    if (r.coil !== null && r.coil !== undefined) parts.push("coil " + r.coil);
    if (r.product !== null && r.product !== undefined) parts.push("product " + r.product);
    if (r.thickness_mm !== null && r.thickness_mm !== undefined) parts.push(num(r.thickness_mm, 2) + " mm");
    if (r.speed_mpm !== null && r.speed_mpm !== undefined) parts.push(num(r.speed_mpm, 0) + " m/min");
    if (r.pass !== null && r.pass !== undefined) parts.push("pass " + r.pass);
    if (r.mill_state) parts.push(r.mill_state);
    const values = parts.length ? parts.join(", ") : "no values";
    return r.context_status === "valid" ? values
      : values + " (context " + r.context_status + (r.context_note ? ": " + r.context_note : "") + ")";
  }
  function ago(text) {
    if (!text) return "";
    const s = Math.max(0, (Date.now() - Date.parse(text)) / 1000);
    if (s < 90) return Math.round(s) + " s ago";
    if (s < 5400) return Math.round(s / 60) + " min ago";
    if (s < 172800) return Math.round(s / 3600) + " h ago";
    return Math.round(s / 86400) + " d ago";
  }
  function el(tag, attrs, ...children) {
    const node = document.createElement(tag);
    for (const [k, v] of Object.entries(attrs || {})) {
      if (k === "class") node.className = v;
      else node.setAttribute(k, v);
    }
    for (const child of children) {
      if (child === null || child === undefined) continue;
      node.append(child instanceof Node ? child : document.createTextNode(String(child)));
    }
    return node;
  }
  const badge = (state, text) => el("span", { class: "badge " + state }, text || state.replace("_", " "));
  // A driveline's pooled gap estimate (its gap_mrad, gap_low_mrad, gap_high_mrad).
  const gapText = (d) =>
    d.gap_mrad !== null ? num(d.gap_mrad, 2) + " mrad (" + num(d.gap_low_mrad, 2) + "–" + num(d.gap_high_mrad, 2) + ")" : "–";
  const signed = (v, digits) => (v >= 0 ? "+" : "") + num(v, digits);
  const missing = (v) => v === null || v === undefined;
  // A driveline's gap growth (its gap_growth_mrad_per_day).
  const growthText = (d) => (missing(d.gap_growth_mrad_per_day) ? "–" : signed(d.gap_growth_mrad_per_day, 3) + " mrad/day");
  // The gap forecast's states by the value of a driveline's gap_forecast (the
  // catalogue's order, docs/figures.md); null without a forecast.
  const FORECAST_STATES = ["forecast", "at_alarm", "not_growing", "beyond_horizon", "too_few_bites"];
  const forecastState = (d) => (missing(d.gap_forecast) ? null : FORECAST_STATES[d.gap_forecast] || null);
  // What a gap forecast without days says, by its state.
  const FORECAST_WORDS = {
    at_alarm: "at the alarm", not_growing: "not growing", beyond_horizon: "beyond the horizon", too_few_bites: "too few bites",
  };
  // The expected date of a driveline's gap alarm with its 90% interval, "2027-03-14
  // (03-02 .. 04-01)" (the ends' year only when it differs), UTC; null without one.
  function expectedText(d) {
    if (forecastState(d) !== "forecast" || !d.gap_alarm_date || !d.last_bite_time) return null;
    const date = d.gap_alarm_date.slice(0, 10);
    const day = (days) => new Date(Date.parse(d.last_bite_time) + days * 86400000).toISOString().slice(0, 10);
    const short = (text) => (text.slice(0, 4) === date.slice(0, 4) ? text.slice(5) : text);
    const low = missing(d.days_to_gap_alarm_low) ? "–" : short(day(d.days_to_gap_alarm_low));
    const high = missing(d.days_to_gap_alarm_high) ? "beyond the horizon" : short(day(d.days_to_gap_alarm_high));
    return date + " (" + low + " .. " + high + ")";
  }
  // What a driveline's gap forecast says: "alarm expected <date> (<interval>)" or the
  // state's words; null without a forecast.
  function forecastText(d) {
    const expected = expectedText(d);
    if (expected) return "alarm expected " + expected;
    const state = forecastState(d);
    return state ? FORECAST_WORDS[state] : null;
  }
  // Drivelines by the expected date of their gap alarm, soonest first, those without
  // one last (in their order).
  function byAlarmDate(drivelines) {
    const dated = (d) => forecastState(d) === "forecast" || forecastState(d) === "at_alarm";
    const key = (d) => (dated(d) && d.gap_alarm_date ? Date.parse(d.gap_alarm_date) : Infinity);
    return drivelines.slice().sort((a, b) => key(a) - key(b) || 0);
  }
  function fill(tbody, rows) {
    tbody.replaceChildren(...rows);
  }
  async function getJson(path) {
    const response = await fetch(path, { headers: { Accept: "application/json" } });
    const answer = await response.json();
    if (!response.ok) throw new Error(answer.error || response.statusText);
    return answer;
  }

  // A "capture" button after `after` (a node), when the gateway takes manual captures
  // through its API (outputs.web.allow_commands, told by /api/overview): it asks for
  // the next `seconds` of `subject` (a driveline's torque or a tandem mill's stands)
  // and says what the gateway answered; `done` runs once the span has passed.
  async function offerCapture(subject, after, seconds, done) {
    let overview;
    try {
      overview = await getJson("/api/overview");
    } catch (error) { return; }
    if (!overview.allow_commands) return;
    const said = el("span", { class: "muted", id: "capture-said" });
    const button = el("button", { type: "button", class: "plot-capture", id: "capture-request" },
      "capture the next " + seconds + " s");
    button.addEventListener("click", async () => {
      button.disabled = true;
      try {
        const response = await fetch("/api/captures", {
          method: "POST",
          headers: { "Content-Type": "application/json", Accept: "application/json" },
          body: JSON.stringify({ subject, seconds }),
        });
        const answer = await response.json();
        if (!response.ok) throw new Error(answer.error || response.statusText);
        said.textContent = " asked: the next " + answer.seconds + " s of " + answer.subject
          + " are kept as a manual capture (listed once they have passed).";
        setTimeout(() => { button.disabled = false; done(); }, answer.seconds * 1000 + 2000);
      } catch (error) {
        said.textContent = " " + error.message;
        button.disabled = false;
      }
    });
    after.after(el("p", { class: "note" }, button, said));
  }

  // ---- live updates -------------------------------------------------------------
  const live = document.getElementById("live");
  let lastLive = null;
  const listeners = [];
  let stream = null;
  // A page left for another (kept in the back/forward cache) gives its stream up: a
  // browser holds 6 connections per host, and such idle streams would take them all.
  window.addEventListener("pagehide", () => stream && stream.close());
  window.addEventListener("pageshow", (event) => {
    if (event.persisted) connect();
  });
  function connect() {
    const source = new EventSource("/api/events");
    source.addEventListener("results", (event) => {
      const now = JSON.parse(event.data);
      const before = lastLive;
      lastLive = now;
      live.textContent = "live";
      live.className = "live on";
      for (const listener of listeners) listener(now, before);
    });
    stream = source;
    source.onerror = () => {
      live.textContent = "reconnecting";
      live.className = "live off";
    };
  }
  // Drivelines whose bite counter moved between two live messages.
  function newBites(now, before) {
    if (!before) return [];
    return now.drivelines.filter((d, i) => before.drivelines[i] && d.bite_counter !== before.drivelines[i].bite_counter);
  }

  // The history's time series cost a scan of the file (about 0.3 s per driveline on a
  // year of bites): a page fetches them on load and again at most this often; bites in
  // between are appended from the live figures.
  const SERIES_PERIOD_MS = 5 * 60 * 1000;

  // A plot as wide as its box (a phone's too), never narrower than 200 px.
  function plotWidth(node) {
    return Math.max(200, node.clientWidth || 800);
  }
  // A plot's text alternative (its node is role="img"): what it shows, in numbers.
  function describe(node, text) {
    node.setAttribute("aria-label", text);
  }
  // "a to b unit" over the values that are numbers, or null when there are none.
  function rangeText(values, digits, unit) {
    const numbers = values.filter((v) => v !== null && v !== undefined && Number.isFinite(v));
    if (numbers.length === 0) return null;
    const low = numbers.reduce((a, b) => Math.min(a, b));
    const high = numbers.reduce((a, b) => Math.max(a, b));
    return num(low, digits) + " to " + num(high, digits) + (unit ? " " + unit : "");
  }
  // The time span of a plot's x values (Unix s), UTC.
  function timeSpan(xs) {
    if (xs.length === 0) return "no time yet";
    return "from " + timeLabel(null, xs[0]) + " to " + timeLabel(null, xs[xs.length - 1]);
  }
  // What a gap-over-time plot shows: per series (index i of data) its estimates' range.
  function gapSummary(title, data, names) {
    const parts = names.map((label, i) => {
      const values = data[i + 1] || [];
      const range = rangeText(values, 2, "mrad");
      const count = values.filter((v) => v !== null && v !== undefined).length;
      return label + ": " + (range ? count + " estimates, " + range : "no estimate");
    });
    return title + ", " + timeSpan(data[0]) + "; " + parts.join("; ") + ".";
  }

  // ---- overview -----------------------------------------------------------------
  function overviewPage() {
    let full = null; // the last /api/overview (with the history's outages)
    function render(o) {
      fill(document.querySelector("#drivelines tbody"), byAlarmDate(o.drivelines).map((d) => {
        return el("tr", { id: "driveline-" + d.name },
          el("td", {}, el("a", { href: "/drivelines/" + encodeURIComponent(d.name) }, d.name)),
          el("td", {}, utc(d.last_bite_time), " ", el("span", { class: "muted" }, ago(d.last_bite_time))),
          el("td", { class: "bite-counter" }, d.bite_counter),
          el("td", {}, num(d.taf, 3), " ", badge(d.taf_state)),
          el("td", {}, gapText(d)),
          el("td", { class: "forecast" }, growthText(d), " ", el("span", { class: "muted" }, forecastText(d) || "")),
          el("td", {}, badge(d.wear_state), d.source_stale ? badge("stale", "source stale") : null,
            d.restored ? el("span", { class: "muted" }, " restored") : null));
      }));
      document.getElementById("mills-section").classList.toggle("hidden", o.tandem_mills.length === 0);
      fill(document.querySelector("#mills tbody"), o.tandem_mills.map((m) =>
        el("tr", {},
          el("td", {}, el("a", { href: "/tandem_mills/" + encodeURIComponent(m.name) }, m.name)),
          el("td", {}, badge(m.chatter_state)),
          el("td", {}, num(m.gain_ratio, 2)),
          el("td", {}, m.worst_stand_channel || "–"),
          el("td", {}, m.chatter_frequency_hz === null ? "–" : num(m.chatter_frequency_hz, 1) + " Hz"),
          el("td", {}, m.slow_down_request ? badge("warning", "requested") : "no"))));
      document.getElementById("rod-section").classList.toggle("hidden", o.rod_mills.length === 0);
      fill(document.querySelector("#rods tbody"), o.rod_mills.map((r) =>
        el("tr", {},
          el("td", {}, r.name),
          el("td", {}, badge(r.state)),
          el("td", {}, r.worst_span === null ? "–" : "span " + r.worst_span),
          el("td", {}, r.worst_margin_m_s === null ? "–" : num(r.worst_margin_m_s, 2) + " m/s"),
          el("td", {}, r.pass === null ? "–" : r.pass),
          el("td", {}, r.finishing_speed_m_s === null ? "–" : num(r.finishing_speed_m_s, 1) + " m/s"))));
      fill(document.querySelector("#sources tbody"), o.sources.map((s) => {
        const f = full && full.sources.find((x) => x.name === s.name);
        const last = f && f.last_outage_start
          ? utc(f.last_outage_start) + (f.last_outage_end ? " to " + utc(f.last_outage_end) : " (ongoing)")
          : (o.history ? "none" : "no history configured");
        return el("tr", {},
          el("td", {}, s.name), el("td", {}, s.kind), el("td", {}, badge(s.status)),
          el("td", {}, f && f.outages_24h !== null ? f.outages_24h : "–"), el("td", {}, last));
      }));
    }
    // The opened gap of every driveline over the history, one plot.
    const gapNode = document.getElementById("overview-gap-plot");
    const gapNote = document.getElementById("overview-gap-note");
    let gapPlot = null;
    async function drawGaps(o) {
      if (!o.history) {
        gapNote.textContent = "No history configured: the plot needs [history] in the configuration.";
        describe(gapNode, "Opened gap over time: not drawn, " + gapNote.textContent);
        return;
      }
      const models = o.drivelines.filter((d) => d.has_model);
      if (models.length === 0) {
        gapNote.textContent = "No driveline has a model configured: no gap estimates.";
        describe(gapNode, "Opened gap over time: not drawn, " + gapNote.textContent);
        return;
      }
      const series = await Promise.all(models.map((d) =>
        getJson("/api/drivelines/" + encodeURIComponent(d.name) + "/wear?points=300")));
      const tables = series.map((points) => [points.map((p) => Date.parse(p.end) / 1000), points.map((p) => p.gap_mrad)]);
      const data = tables.length === 1 ? tables[0] : uPlot.join(tables);
      const options = {
        width: plotWidth(gapNode), height: 260, tzDate: utcDate,
        scales: { x: { time: true } },
        series: [{ label: "time (UTC)", value: timeLabel }].concat(models.map((d, i) => ({
          label: d.name, stroke: colours[i % colours.length], width: 2, spanGaps: true, points: quiet,
          value: (u, v) => num(v, 2) + " mrad",
        }))),
        axes: [{ values: utcTicks, incrs: timeIncrs, space: 70, label: "time (UTC)" }, { label: "opened gap, mrad" }],
      };
      if (gapPlot) gapPlot.destroy();
      gapPlot = new uPlot(options, data, gapNode);
      window.millgatePlots.overviewGap = gapPlot;
      describe(gapNode, gapSummary("Opened gap of each driveline over time", data, models.map((d) => d.name)));
      gapNote.textContent = data[0].length ? "" : "No gap estimate in the history yet.";
    }
    let gapsAt = 0;
    async function refresh() {
      try {
        full = await getJson("/api/overview");
        render(lastLive || full);
        if (Date.now() - gapsAt >= SERIES_PERIOD_MS) {
          gapsAt = Date.now();
          await drawGaps(full);
        }
      } catch (error) {
        console.error(error);
        gapNote.textContent = error.message;
      }
    }
    // New bites' gap estimates onto the plot, from the live figures.
    function appendGaps(moved) {
      if (!gapPlot) return;
      const names = gapPlot.series.slice(1).map((s) => s.label);
      const data = gapPlot.data.map((s) => Array.from(s));
      for (const d of moved) {
        const i = names.indexOf(d.name);
        if (i < 0 || d.gap_mrad === null || !d.last_bite_time) continue;
        const t = Date.parse(d.last_bite_time) / 1000;
        const last = data[0].length - 1;
        if (last >= 0 && t < data[0][last]) continue; // older than the plot's end
        if (last < 0 || t > data[0][last]) {
          data[0].push(t);
          for (const series of data.slice(1)) series.push(null);
        }
        data[i + 1][data[0].length - 1] = d.gap_mrad;
        gapNote.textContent = "";
      }
      gapPlot.setData(data);
      describe(gapNode, gapSummary("Opened gap of each driveline over time", data, names));
    }
    window.addEventListener("resize", () => {
      if (gapPlot) gapPlot.setSize({ width: plotWidth(gapNode), height: 260 });
    });
    let pending = null;
    listeners.push((now, before) => {
      render(now);
      const moved = newBites(now, before);
      appendGaps(moved);
      // A bite changes the history's part: fetch the overview again, once.
      if (moved.length > 0 && pending === null) {
        pending = setTimeout(() => { pending = null; refresh(); }, 1000);
      }
    });
    refresh();
    setInterval(refresh, 30000);
    setInterval(() => lastLive && render(lastLive), 10000); // "x s ago"
  }

  // ---- driveline ----------------------------------------------------------------
  // Time axis labels in UTC, 24 h: dates over days, clock times within a day.
  function utcTicks(u, splits) {
    const span = splits.length > 1 ? splits[splits.length - 1] - splits[0] : 0;
    return splits.map((s) => {
      const text = new Date(s * 1000).toISOString();
      if (span > 3 * 86400) return text.slice(0, 10);
      if (span > 7200) return text.slice(11, 16);
      return text.slice(11, 19);
    });
  }
  const quiet = { show: false };
  // Whole seconds at least between time ticks (the bites' times are to the second).
  const timeIncrs = [1, 2, 5, 10, 15, 30, 60, 120, 300, 600, 900, 1800, 3600, 7200, 14400, 21600,
    43200, 86400, 172800, 604800, 2592000, 7776000, 31536000];
  const utcDate = (ts) => uPlot.tzDate(new Date(ts * 1e3), "Etc/UTC");
  const timeLabel = (u, v) => (v === null ? "–" : utc(new Date(v * 1000).toISOString()));
  const colours = ["#1d4ed8", "#0f766e", "#7c3aed", "#c2410c", "#be185d", "#4d7c0f", "#0369a1", "#a16207"];

  function drivelinePage() {
    const name = driveline;
    const gapNode = document.getElementById("gap-plot");
    const tafNode = document.getElementById("taf-plot");
    const gapNote = document.getElementById("gap-note");
    const forecastNote = document.getElementById("gap-forecast");
    const tafNote = document.getElementById("taf-note");
    const tbody = document.querySelector("#bites tbody");
    const traceNode = document.getElementById("trace-plot");
    const traceNote = document.getElementById("trace-note");
    let tracePlot = null;
    let traceShown = null; // the capture id on the trace plot
    let captureOf = new Map(); // bite counter -> capture id
    let info = null;
    let gapPlot = null;
    let tafPlot = null;
    let bites = [];
    const fatigueSection = document.getElementById("fatigue");
    const fatigueBody = document.querySelector("#fatigue-components tbody");
    const fatigueSaid = document.getElementById("fatigue-said");
    const lifeNode = document.getElementById("fatigue-life-plot");
    const damageNode = document.getElementById("fatigue-damage-plot");
    const fatigueNote = document.getElementById("fatigue-note");
    let lifePlot = null;
    let damagePlot = null;
    // /fatigue/history: each component's life used over time (time buckets), the
    // resets and the life limit; fetched with the other series.
    let fatigueSeries = null;
    let allowCommands = false;

    // The fatigue ledger per component (the live figures), with a reset button per
    // component when the page takes commands.
    function fatigueTable(d) {
      const components = d.fatigue_components || [];
      fatigueSection.classList.toggle("hidden", components.length === 0);
      const percent = (v, digits) => (missing(v) ? "–" : num(v * 100, digits) + " %");
      fill(fatigueBody, components.map((c) => {
        const limit = c.forecast === "forecast" && !missing(c.days_to_limit)
          ? "in " + num(c.days_to_limit, 0) + " days (" + new Date(c.limit_date_unix_ms).toISOString().slice(0, 10) + ")"
          : (c.forecast === "at_alarm" ? "reached" : (c.forecast === "not_growing" ? "not consuming" : FORECAST_WORDS[c.forecast] || "–"));
        const reset = allowCommands ? el("button", { type: "button", class: "fatigue-reset", "data-component": c.name }, "replaced: reset") : "";
        if (reset) reset.addEventListener("click", () => resetFatigue(c.name, reset));
        return el("tr", {},
          el("td", {}, c.name),
          el("td", {}, percent(c.life_used, 4)),
          el("td", {}, missing(c.bite_damage) ? "–" : Number(c.bite_damage).toExponential(3)),
          el("td", {}, missing(c.rate_per_day) ? "–" : percent(c.rate_per_day, 5) + "/day"),
          el("td", {}, limit),
          el("td", {}, new Date(c.installed_unix_ms).toISOString().slice(0, 16).replace("T", " ") + " UTC"),
          el("td", {}, reset));
      }));
    }

    async function resetFatigue(component, button) {
      if (!window.confirm("Reset the life used of " + component + " (it was replaced)?")) return;
      button.disabled = true;
      try {
        const response = await fetch("/api/drivelines/" + encodeURIComponent(name) + "/fatigue/reset", {
          method: "POST",
          headers: { "Content-Type": "application/json", Accept: "application/json" },
          body: JSON.stringify({ component }),
        });
        const answer = await response.json();
        if (!response.ok) throw new Error(answer.error || response.statusText);
        fatigueSaid.textContent = "Reset asked: " + answer.component + " starts again at 0 (recorded in the history).";
      } catch (error) {
        fatigueSaid.textContent = error.message;
      }
      button.disabled = false;
    }

    // Each component's life used over time: the history's series (the last stored
    // bite of each time bucket), then the live figures of a bite since it was read.
    function lifeColumns() {
      const series = fatigueSeries || { components: [], points: [] };
      const live = info.fatigue_components || [];
      const names = series.components.concat(live.map((c) => c.name).filter((n) => !series.components.includes(n)));
      const rows = series.points.map((p) => [Date.parse(p.time) / 1000,
        names.map((n, k) => (missing(p.life_used[k]) ? null : p.life_used[k] * 100))]);
      const last = rows.length ? rows[rows.length - 1][0] : -Infinity;
      const at = info.last_bite_time ? Date.parse(info.last_bite_time) / 1000 : null;
      if (at !== null && at > last && live.length) {
        rows.push([at, names.map((n) => {
          const c = live.find((x) => x.name === n);
          return c && !missing(c.life_used) ? c.life_used * 100 : null;
        })]);
      }
      return { names, times: rows.map((r) => r[0]), columns: names.map((n, k) => rows.map((r) => r[1][k])) };
    }

    // Each component's life used over time with the life limit, and the worst
    // component's damage per bite over the bite's TAF (untrusted bites have no damage
    // and are left out).
    function drawFatigue() {
      if (!(info.fatigue_components || []).length) return;
      const life = lifeColumns();
      const limit = fatigueSeries && !missing(fatigueSeries.life_limit) ? fatigueSeries.life_limit * 100 : null;
      const lifeSeries = [{ label: "time (UTC)", value: timeLabel }].concat(life.names.map((n, k) => (
        { label: n + ", life used %", stroke: colours[k % colours.length], width: 2, spanGaps: true, points: quiet, value: (u, v) => num(v, 4) })));
      const lifeData = [life.times].concat(life.columns);
      if (limit !== null) {
        lifeSeries.push({ label: "life limit %", stroke: "#b91c1c", width: 1, dash: [6, 4], points: quiet, value: (u, v) => num(v, 1) });
        lifeData.push(life.times.map(() => limit));
      }
      const lifeOptions = {
        width: plotWidth(lifeNode), height: 260, tzDate: utcDate,
        scales: { x: { time: true } },
        series: lifeSeries,
        axes: [{ values: utcTicks, incrs: timeIncrs, space: 70, label: "time (UTC)" }, { label: "life used, %" }],
      };
      if (lifePlot) lifePlot.destroy();
      lifePlot = new uPlot(lifeOptions, lifeData, lifeNode);
      window.millgatePlots.fatigueLife = lifePlot;
      const resets = fatigueSeries ? fatigueSeries.resets.length : 0;
      describe(lifeNode, "Life used per fatigue component over time, " + timeSpan(life.times) + ": "
        + life.names.map((n, k) => n + " " + (rangeText(life.columns[k], 4, "%") || "no value")).join("; ")
        + (limit !== null ? "; life limit " + num(limit, 1) + " %" : "")
        + (resets ? "; " + resets + " reset" + (resets === 1 ? "" : "s") + " (the line starts again at 0)" : "") + ".");
      const points = bites.filter((b) => !missing(b.fatigue_bite_damage) && !missing(b.taf) && !b.degraded)
        .map((b) => [b.taf, b.fatigue_bite_damage]).sort((a, b) => a[0] - b[0]);
      const damageOptions = {
        width: plotWidth(damageNode), height: 260,
        scales: { x: { time: false } },
        series: [
          { label: "TAF", value: (u, v) => num(v, 3) },
          { label: "damage per bite (worst component)", stroke: "#7c3aed", width: 0, paths: () => null, points: { show: true, size: 6, fill: "#7c3aed" }, value: (u, v) => Number(v).toExponential(3) },
        ],
        axes: [{ label: "TAF of the bite" }, { label: "damage per bite" }],
      };
      if (damagePlot) damagePlot.destroy();
      damagePlot = new uPlot(damageOptions, [points.map((p) => p[0]), points.map((p) => p[1])], damageNode);
      window.millgatePlots.fatigueDamage = damagePlot;
      describe(damageNode, "Damage per bite over TAF of " + points.length + " bites.");
      fatigueNote.textContent = "Life used per component over time (the last stored bite of each time bucket, "
        + "a replaced component's line starting again at 0), with the life limit; the worst component's damage per bite "
        + "(the cycles closed since the bite before) over the bite's TAF.";
    }

    function cards(d) {
      fatigueTable(d);
      const card = (label, value, sub, state) =>
        el("div", { class: "card" }, el("div", { class: "label" }, label),
          el("div", { class: "value" }, value, state ? " " : null, state ? badge(state) : null),
          el("div", { class: "sub" }, sub || ""));
      document.getElementById("cards").replaceChildren(
        card("Last bite", d.last_bite_time ? utc(d.last_bite_time).slice(11) : "–", d.last_bite_time ? ago(d.last_bite_time) + " · bite " + d.bite_counter : "no bite yet"),
        card("TAF", num(d.taf, 3), "warning " + d.thresholds.taf_warning + " · alarm " + d.thresholds.taf_alarm, d.taf_state),
        card("Opened gap", d.gap_mrad !== null ? num(d.gap_mrad, 2) + " mrad" + couplingText(d) : "–",
          d.gap_mrad !== null ? "90%: " + num(d.gap_low_mrad, 2) + "–" + num(d.gap_high_mrad, 2) + " mrad · " + d.bites_pooled + " bites"
            : (d.has_model ? "no estimate yet" : "no driveline model configured"), d.wear_state),
        card("Growth", growthText(d), missing(d.gap_growth_mrad_per_day)
          ? (d.has_model ? "no trend yet" : "no driveline model configured")
          : "90%: " + signed(d.gap_growth_low_mrad_per_day, 3) + " to " + signed(d.gap_growth_high_mrad_per_day, 3) + " mrad/day"),
        gapAlarmCard(d, card),
        card("Static torque", d.static_torque_knm === null ? "–" : num(d.static_torque_knm, 0) + " kN·m",
          "peak " + (d.peak_torque_knm === null ? "–" : num(d.peak_torque_knm, 0) + " kN·m")));
    }

    // Where the gap is, in the card's own words (not only in the TAF plot's coupling
    // selector): " at coupling 2 “motor side”", or the likeliest one when the bites
    // cannot tell the couplings apart.
    function couplingText(d) {
      const number = d.gap_coupling !== null ? d.gap_coupling : d.likeliest_coupling;
      if (number === null || number === undefined) return "";
      const known = map && map.couplings ? map.couplings.find((c) => c.coupling === number) : null;
      const name = known ? " \u201c" + known.name + "\u201d" : "";
      return (d.gap_coupling !== null ? " at coupling " : " at coupling (likeliest) ") + number + name;
    }

    // The gap alarm's forecast: days with their interval and the date, or what the
    // forecast says instead.
    function gapAlarmCard(d, card) {
      const state = forecastState(d);
      if (state === "forecast" && !missing(d.days_to_gap_alarm)) {
        // Days, or hours when the alarm is less than two days away.
        const soon = d.days_to_gap_alarm < 2;
        const span = (v) => (missing(v) ? "–" : soon ? num(v * 24, 1) : num(v, 0));
        const unit = soon ? " h" : " days";
        const high = missing(d.days_to_gap_alarm_high) ? "beyond the horizon" : span(d.days_to_gap_alarm_high) + unit;
        return card("Gap alarm", "in " + span(d.days_to_gap_alarm) + unit,
          "90%: " + span(d.days_to_gap_alarm_low) + " to " + high + " · expected " + expectedText(d));
      }
      const why = {
        at_alarm: "the gap is at " + d.thresholds.gap_alarm_mrad + " mrad",
        not_growing: "the growth's 90% interval holds 0",
        beyond_horizon: "growing, the crossing lies beyond the forecast's horizon",
        too_few_bites: "too few bites since the last wear reset for a trend",
      };
      return card("Gap alarm", state ? FORECAST_WORDS[state] : "–",
        state ? why[state] : (d.has_model ? "no forecast yet" : "no driveline model configured"));
    }

    function row(b, fresh) {
      const gap = b.gap_mrad === null || b.gap_mrad === undefined ? "–"
        : num(b.gap_mrad, 2) + " (" + num(b.gap_low_mrad, 2) + "–" + num(b.gap_high_mrad, 2) + ")";
      return el("tr", { class: fresh ? "fresh" : "", "data-bite": b.bite_counter },
        el("td", {}, utc(b.time)), el("td", {}, b.bite_counter),
        el("td", {}, num(b.static_torque_knm, 0) + " kN·m"), el("td", {}, num(b.peak_torque_knm, 0) + " kN·m"),
        el("td", {}, num(b.taf, 3)),
        el("td", {}, b.period_shift_s === null || b.period_shift_s === undefined ? "–" : num(b.period_shift_s * 1000, 2) + " ms"),
        el("td", {}, gap), el("td", {}, b.degraded ? badge("warning", "degraded") : b.quality),
        captureCell(b));
    }
    // The bite's capture: plot it, or download it as the export writes it.
    function captureCell(b) {
      const id = captureOf.get(b.bite_counter);
      if (id === undefined) return el("td", { class: "muted" }, "–");
      const file = (format) => "/api/captures/" + id + "/file?format=" + format;
      return el("td", {},
        el("button", { type: "button", class: "plot-capture", "data-capture": id }, "plot"), " ",
        el("a", { href: file("csv"), download: "" }, "CSV"), " ",
        el("a", { href: file("parquet"), download: "" }, "Parquet"));
    }
    tbody.addEventListener("click", (event) => {
      const button = event.target.closest("button.plot-capture");
      if (button) showTrace(Number(button.dataset.capture));
    });

    // A bite's torque trace (its capture) beside the model's simulated response at
    // the bite's static torque (/api/captures/{id}/response), and the residual.
    async function showTrace(id) {
      traceShown = id;
      try {
        const capture = await getJson("/api/captures/" + id);
        let response = null;
        let why = "";
        if (info.has_model) {
          try {
            response = await getJson("/api/captures/" + id + "/response");
          } catch (error) { why = error.message; }
        } else {
          why = "no driveline model configured: no simulated response";
        }
        if (traceShown !== id) return; // another bite was chosen meanwhile
        const channel = capture.channels[0];
        const rate = capture.sample_rate_hz;
        const t = channel.samples.map((_, k) => k / rate);
        const data = [t, channel.samples];
        const series = [
          { label: "t, s", value: (u, v) => num(v, 4) },
          { label: channel.name + " (measured)", stroke: "#1f2933", width: 1.5, points: quiet, value: (u, v) => num(v, 1) + " " + channel.unit },
        ];
        if (response) {
          data.push(response.response.torque_knm);
          series.push({ label: "model at the bite's static torque", stroke: "#1d4ed8", width: 1.5, dash: [6, 4], points: quiet, value: (u, v) => num(v, 1) + " kN·m" });
        }
        const options = {
          width: plotWidth(traceNode), height: 300,
          scales: { x: { time: false } },
          series,
          axes: [{ label: "time from the capture's first sample, s" }, { label: "torque, " + channel.unit }],
        };
        if (tracePlot) tracePlot.destroy();
        tracePlot = new uPlot(options, data, traceNode);
        tracePlot.millgateCapture = id;
        window.millgatePlots.trace = tracePlot;
        describe(traceNode, "Torque trace of bite " + capture.bite_counter + " (capture " + id + "): "
          + channel.samples.length + " samples over " + num(channel.samples.length / rate, 3) + " s, measured "
          + rangeText(channel.samples, 1, channel.unit)
          + (response ? "; the model's response at the bite's static torque " + rangeText(response.response.torque_knm, 1, "kN·m")
            + ", residual " + num(response.response.residual_rms_knm, 2) + " kN·m RMS" : "") + ".");
        const bite = bites.find((b) => b.bite_counter === capture.bite_counter);
        const gap = bite && bite.gap_mrad !== null && bite.gap_mrad !== undefined
          ? "; estimated gap " + num(bite.gap_mrad, 2) + " mrad (" + num(bite.gap_low_mrad, 2) + "–" + num(bite.gap_high_mrad, 2) + ")" : "";
        const context = capture.context_status ? "; rolled in: " + contextText(capture) : "";
        traceNote.textContent = "Bite " + capture.bite_counter + " at " + utc(capture.bite_time) + ", capture " + id + ", "
          + channel.samples.length + " samples at " + rate + " Hz" + gap + context + ". "
          + (response ? "Model aligned to the record: static torque " + num(response.response.static_torque_knm, 1)
            + " kN·m, onset " + num(response.response.onset_s * 1000, 1) + " ms; residual (measured − model) "
            + num(response.response.residual_rms_knm, 2) + " kN·m RMS: what the model does not explain (a gap, a stiffness off)."
            : why);
      } catch (error) {
        traceNote.textContent = error.message;
      }
    }
    // The product filter of the bite table, and the table by product.
    const productSection = document.getElementById("products");
    const productBody = document.querySelector("#product-table tbody");
    const productLabel = document.getElementById("product-filter-label");
    const productSelect = document.getElementById("product-filter");
    productSelect.addEventListener("change", () => table());
    function table() {
      const chosen = productSelect.value === "" ? null : Number(productSelect.value);
      const shown = chosen === null ? bites : bites.filter((b) => b.product === chosen);
      fill(tbody, shown.slice(-25).reverse().map((b) => row(b, false)));
    }
    function drawProducts(products) {
      productSection.classList.toggle("hidden", products.length === 0);
      productLabel.classList.toggle("hidden", products.length === 0);
      fill(productBody, products.map((p) => el("tr", {},
        el("td", {}, String(p.product)), el("td", {}, String(p.bites)), el("td", {}, String(p.not_pooled)),
        el("td", {}, num(p.taf_mean, 3)), el("td", {}, num(p.taf_max, 3)),
        el("td", {}, p.static_torque_mean_knm === null ? "–" : num(p.static_torque_mean_knm, 1) + " kN·m"),
        el("td", {}, p.gap_mean_mrad === null ? "–" : num(p.gap_mean_mrad, 2) + " mrad"))));
      const chosen = productSelect.value;
      productSelect.replaceChildren(el("option", { value: "" }, "all"),
        ...products.map((p) => el("option", { value: String(p.product) }, String(p.product))));
      productSelect.value = products.some((p) => String(p.product) === chosen) ? chosen : "";
    }

    // The history's gap series (buckets), with the live bites since appended.
    let wearPoints = [];
    // The gap over time: the estimates with their 90% interval, the thresholds and,
    // once the wear trend has a growth (info.gap_cone), the fitted growth line, the
    // forecast's mean and 90% band (the time axis reaching its end) and the expected
    // date of the gap alarm marked and written.
    function drawGap() {
      const t = info.thresholds;
      const cone = info.gap_cone;
      // Rows by time (Unix s): gap, low, high, fitted line, forecast mean, low, high,
      // a bite not pooled (drawn at 0 mrad).
      const rows = new Map();
      const at = (time) => {
        const x = Date.parse(time) / 1000;
        if (!rows.has(x)) rows.set(x, [null, null, null, null, null, null, null, null]);
        return rows.get(x);
      };
      for (const p of wearPoints) {
        const r = at(p.end);
        r[0] = p.gap_mrad; r[1] = p.gap_low_mrad; r[2] = p.gap_high_mrad;
      }
      // Bites the context kept out of the wear trend (gated 1 state, 2 speed).
      const gated = bites.filter((b) => b.gated === 1 || b.gated === 2);
      for (const b of gated) at(b.time)[7] = 0;
      if (cone) {
        at(cone.fitted_line.from_time)[3] = cone.fitted_line.from_mrad;
        at(cone.fitted_line.to_time)[3] = cone.fitted_line.to_mrad;
        for (const c of cone.points) {
          const r = at(c.time);
          r[4] = c.mean_mrad; r[5] = c.low_mrad; r[6] = c.high_mrad;
        }
      }
      const xs = Array.from(rows.keys()).sort((a, b) => a - b);
      const column = (i) => xs.map((x) => rows.get(x)[i]);
      const data = [xs, column(0), column(1), column(2), xs.map(() => t.gap_warning_mrad), xs.map(() => t.gap_alarm_mrad),
        column(3), column(4), column(5), column(6), column(7)];
      const expected = expectedText(info) ? Date.parse(info.gap_alarm_date) / 1000 : null;
      const said = forecastText(info);
      const mrad = (u, v) => num(v, 2) + " mrad";
      const options = {
        width: plotWidth(gapNode), height: 300, tzDate: utcDate,
        scales: { x: { time: true } },
        series: [
          { label: "time (UTC)", value: timeLabel },
          { label: "gap", stroke: "#1d4ed8", width: 2, spanGaps: true, points: quiet, value: mrad },
          { label: "90% low", stroke: "#93c5fd", width: 1, spanGaps: true, points: quiet, value: (u, v) => num(v, 2) },
          { label: "90% high", stroke: "#93c5fd", width: 1, spanGaps: true, points: quiet, value: (u, v) => num(v, 2) },
          { label: "warning", stroke: "#b45309", width: 1.5, dash: [8, 5], points: quiet },
          { label: "alarm", stroke: "#b91c1c", width: 1.5, dash: [8, 5], points: quiet },
          { label: "fitted growth", stroke: "#0f766e", width: 2, dash: [4, 3], spanGaps: true, points: quiet, value: mrad },
          { label: "forecast", stroke: "#c2410c", width: 2, spanGaps: true, points: quiet, value: mrad },
          { label: "forecast 90% low", stroke: "#fdba74", width: 1, spanGaps: true, points: quiet, value: (u, v) => num(v, 2) },
          { label: "forecast 90% high", stroke: "#fdba74", width: 1, spanGaps: true, points: quiet, value: (u, v) => num(v, 2) },
          { label: "bite not pooled (state, speed)", stroke: "#6b7280", width: 0, paths: () => null,
            points: { show: true, size: 7, fill: "#ffffff", stroke: "#6b7280" }, value: (u, v) => (v === null ? "–" : "not pooled") },
        ],
        bands: [{ series: [3, 2], fill: "rgba(29, 78, 216, 0.15)" }, { series: [9, 8], fill: "rgba(194, 65, 12, 0.15)" }],
        axes: [{ values: utcTicks, incrs: timeIncrs, space: 70, label: "time (UTC)" }, { label: "opened gap, mrad" }],
        plugins: [expectedMark(expected, said)],
      };
      if (gapPlot) gapPlot.destroy();
      gapPlot = new uPlot(options, data, gapNode);
      gapPlot.millgateForecast = said;
      window.millgatePlots.gap = gapPlot;
      forecastNote.textContent = cone
        ? "Forecast (" + (said || "none") + "): the fitted growth since the last bites (dashed), the forecast's mean and 90% band (orange) up to the alarm line; growth "
          + growthText(info) + "."
        : (said ? "Forecast: " + said + " (no growth yet to draw)." : "");
      describeGap();
    }
    // A vertical line at the expected date `x` (Unix s) with `text` beside it.
    function expectedMark(x, text) {
      return {
        hooks: {
          draw: [(u) => {
            if (x === null) return;
            const ctx = u.ctx;
            const ratio = uPlot.pxRatio;
            const px = Math.round(u.valToPos(x, "x", true));
            const right = px > u.bbox.left + u.bbox.width / 2;
            ctx.save();
            ctx.strokeStyle = "#b91c1c";
            ctx.lineWidth = 1.5 * ratio;
            ctx.setLineDash([3 * ratio, 3 * ratio]);
            ctx.beginPath();
            ctx.moveTo(px, u.bbox.top);
            ctx.lineTo(px, u.bbox.top + u.bbox.height);
            ctx.stroke();
            ctx.fillStyle = "#b91c1c";
            ctx.font = Math.round(12 * ratio) + "px system-ui, sans-serif";
            ctx.textAlign = right ? "right" : "left";
            ctx.fillText(text, px + (right ? -4 : 4) * ratio, u.bbox.top + 14 * ratio);
            ctx.restore();
          }],
        },
      };
    }
    function describeGap() {
      const t = info.thresholds;
      const cone = info.gap_cone;
      const last = cone ? cone.points[cone.points.length - 1] : null;
      const gated = gapPlot.data[10].filter((v) => v !== null).length;
      describe(gapNode, gapSummary("Opened gap of " + name + " over time", gapPlot.data, ["gap"])
        + (gated ? " " + gated + " bites not pooled into the trend (the mill's state or speed), marked at 0 mrad." : "")
        + " Warning at " + t.gap_warning_mrad + " mrad, alarm at " + t.gap_alarm_mrad + " mrad."
        + (cone ? " Growth " + growthText(info) + "; forecast: " + (forecastText(info) || "none") + "; its 90% band "
          + num(cone.points[0].low_mrad, 2) + " to " + num(cone.points[0].high_mrad, 2) + " mrad at the last bite, "
          + num(last.low_mrad, 2) + " to " + num(last.high_mrad, 2) + " mrad on " + utc(last.time) + "." : ""));
    }

    // The gap maps (/api/drivelines/{name}/map) and the coupling whose curves are
    // drawn: the user's choice, else the one the estimate names (or its likeliest).
    let map = null;
    let chosenCoupling = null;
    const couplingSelect = document.getElementById("taf-coupling");
    couplingSelect.addEventListener("change", () => {
      chosenCoupling = Number(couplingSelect.value);
      drawTaf();
    });
    function mapCoupling() {
      if (!map || map.state !== "ready" || map.couplings.length === 0) return null;
      const wanted = chosenCoupling !== null ? chosenCoupling : (map.estimate ? map.estimate.coupling : null);
      return map.couplings.find((c) => c.coupling === wanted) || map.couplings[0];
    }
    function couplingPicker() {
      const ready = map && map.state === "ready" && map.couplings.length > 0;
      document.getElementById("taf-coupling-label").classList.toggle("hidden", !ready);
      if (!ready) return;
      const shown = mapCoupling();
      couplingSelect.replaceChildren(...map.couplings.map((c) => {
        const estimate = map.estimate && map.estimate.coupling === c.coupling
          ? (map.estimate.determined ? " (holds the gap)" : " (likeliest)") : "";
        const option = el("option", { value: c.coupling }, c.coupling + " " + c.name + estimate);
        option.selected = c.coupling === shown.coupling;
        return option;
      }));
    }
    // Curve colours: the linear driveline dark, larger gaps lighter.
    const curveColour = (i, n) => "hsl(215, 16%, " + Math.round(28 + 50 * i / Math.max(1, n - 1)) + "%)";

    function drawTaf() {
      const t = info.thresholds;
      const points = bites.filter((b) => b.taf !== null && !b.degraded)
        .map((b) => [b.static_torque_knm, b.taf]).sort((a, b) => a[0] - b[0]);
      const tables = [[points.map((p) => p[0]), points.map((p) => p[1])]];
      const series = [
        { label: "static torque, kN·m", value: (u, v) => num(v, 0) },
        { label: "TAF (bites)", stroke: "#0f766e", width: 0, paths: () => null, points: { show: true, size: 6, fill: "#0f766e" }, value: (u, v) => num(v, 3) },
      ];
      const bands = [];
      const curveTable = (curve) => [curve.points.map((p) => p[0]), curve.points.map((p) => p[1])];
      const coupling = mapCoupling();
      if (coupling) {
        coupling.curves.forEach((curve, i) => {
          tables.push(curveTable(curve));
          series.push({ label: "map, gap " + num(curve.gap_mrad, 0) + " mrad", stroke: curveColour(i, coupling.curves.length),
            width: 1, spanGaps: true, points: quiet, value: (u, v) => num(v, 3) });
        });
        const e = map.estimate;
        if (e && e.coupling === coupling.coupling) {
          const high = series.length;
          tables.push(curveTable(e.high), curveTable(e.low), curveTable(e.gap));
          series.push(
            { label: "90% high " + num(e.high.gap_mrad, 2), stroke: "#93c5fd", width: 1, spanGaps: true, points: quiet, value: (u, v) => num(v, 3) },
            { label: "90% low " + num(e.low.gap_mrad, 2), stroke: "#93c5fd", width: 1, spanGaps: true, points: quiet, value: (u, v) => num(v, 3) },
            { label: "estimate " + num(e.gap.gap_mrad, 2) + " mrad", stroke: "#1d4ed8", width: 2.5, spanGaps: true, points: quiet, value: (u, v) => num(v, 3) });
          bands.push({ series: [high, high + 1], fill: "rgba(29, 78, 216, 0.12)" });
        }
      }
      // The thresholds across everything drawn.
      const xs = tables.flatMap((table) => table[0]);
      const span = xs.length ? [Math.min(...xs), Math.max(...xs)] : [];
      tables.push([span, span.map(() => t.taf_warning), span.map(() => t.taf_alarm)]);
      series.push(
        { label: "warning", stroke: "#b45309", width: 1.5, dash: [8, 5], points: quiet },
        { label: "alarm", stroke: "#b91c1c", width: 1.5, dash: [8, 5], points: quiet });
      const options = {
        width: plotWidth(tafNode), height: 320,
        scales: { x: { time: false } },
        series, bands,
        axes: [{ label: "static torque (as measured), kN·m" }, { label: "TAF" }],
      };
      if (tafPlot) tafPlot.destroy();
      tafPlot = new uPlot(options, uPlot.join(tables), tafNode);
      window.millgatePlots.taf = tafPlot;
      tafPlot.millgateCoupling = coupling ? coupling.coupling : null;
      const estimate = coupling && map.estimate && map.estimate.coupling === coupling.coupling
        ? " Estimated opened gap " + num(map.estimate.gap.gap_mrad, 2) + " mrad (90%: " + num(map.estimate.low.gap_mrad, 2)
          + " to " + num(map.estimate.high.gap_mrad, 2) + ")." : "";
      describe(tafNode, "TAF over static torque of " + points.length + " measured bites"
        + (points.length ? ": TAF " + rangeText(points.map((p) => p[1]), 3) + " at " + rangeText(points.map((p) => p[0]), 0, "kN·m") : "")
        + ". Warning at TAF " + t.taf_warning + ", alarm at " + t.taf_alarm + "."
        + (coupling ? " Lines: the gap map of coupling " + coupling.coupling + ", gaps "
          + rangeText(coupling.curves.map((c) => c.gap_mrad), 0, "mrad") + "." : "") + estimate);
      const what = "Points: the measured bites" + (bites.length ? " (newest " + bites.length + ")" : " (none in the history yet)") + ". ";
      if (coupling) {
        const e = map.estimate;
        const where = !e ? "no estimate yet"
          : (e.coupling !== coupling.coupling ? "the estimate is on coupling " + e.coupling
            : (e.determined ? "the estimate names this coupling" : "the bites cannot tell the couplings apart; this is the likeliest"));
        tafNote.textContent = what + "Lines: the gap map of coupling " + coupling.coupling + " \u201c" + coupling.name +
          "\u201d (model " + map.model + "), the TAF a bite shows at each opened gap, simulated; " + where + ".";
      } else {
        tafNote.textContent = what + (map ? map.message : "");
      }
    }

    async function loadMap() {
      try {
        map = await getJson("/api/drivelines/" + encodeURIComponent(name) + "/map");
      } catch (error) {
        map = { state: "failed", message: error.message, couplings: [] };
      }
      couplingPicker();
      drawTaf();
      // A build in progress: look again until it is done (one timer).
      if (map.state === "building" && mapTimer === null) {
        mapTimer = setTimeout(() => { mapTimer = null; loadMap(); }, 5000);
      }
    }
    let mapTimer = null;

    let wearAt = 0;
    async function loadHistory() {
      try {
        const series = Date.now() - wearAt >= SERIES_PERIOD_MS;
        const fatigue = series && (info.fatigue_components || []).length > 0;
        const [wear, rows, captures, life, products] = await Promise.all([
          series ? getJson("/api/drivelines/" + encodeURIComponent(name) + "/wear?points=400") : null,
          getJson("/api/drivelines/" + encodeURIComponent(name) + "/bites?limit=500"),
          getJson("/api/drivelines/" + encodeURIComponent(name) + "/captures?limit=500"),
          fatigue ? getJson("/api/drivelines/" + encodeURIComponent(name) + "/fatigue/history?points=400") : null,
          series ? getJson("/api/drivelines/" + encodeURIComponent(name) + "/products") : null,
        ]);
        if (life) fatigueSeries = life;
        bites = rows;
        if (products) drawProducts(products);
        captureOf = new Map(captures.filter((c) => c.kind === "bite").map((c) => [c.bite_counter, c.id]));
        table();
        drawFatigue();
        // The newest captured bite's trace until one is chosen.
        if (traceShown === null) {
          const newest = bites.slice().reverse().find((b) => captureOf.has(b.bite_counter));
          if (newest) showTrace(captureOf.get(newest.bite_counter));
          else {
            traceNote.textContent = "No bite capture in the history yet.";
            describe(traceNode, "Bite trace: not drawn, " + traceNote.textContent);
          }
        }
        if (wear) {
          wearAt = Date.now();
          wearPoints = wear;
          drawGap();
          gapNote.textContent = wear.some((p) => p.gap_mrad !== null) ? ""
            : (info.has_model ? "No gap estimate in the history yet." : "No gap estimates: the driveline has no model configured.");
        }
        await loadMap();
      } catch (error) {
        gapNote.textContent = error.message;
        tafNote.textContent = error.message;
      }
    }

    async function start() {
      info = await getJson("/api/drivelines/" + encodeURIComponent(name));
      const overview = await getJson("/api/overview");
      allowCommands = overview.allow_commands;
      cards(info);
      if (overview.history) {
        await loadHistory();
      } else {
        gapNote.textContent = "No history configured: the plots need [history] in the configuration.";
        describe(gapNode, "Opened gap over time: not drawn, " + gapNote.textContent);
        await loadMap();
        traceNote.textContent = "No history configured: bite captures need [history].";
        describe(traceNode, "Bite trace: not drawn, " + traceNote.textContent);
        fill(tbody, [el("tr", {}, el("td", { colspan: 9, class: "muted" }, "no history configured: live figures only"))]);
      }
      let pending = null;
      listeners.push((now, before) => {
        const d = now.drivelines.find((x) => x.name === name);
        if (!d) return;
        info = d;
        cards(d);
        if (!newBites(now, before).some((x) => x.name === name)) return;
        // The new bite at once from the live figures...
        const liveBite = {
          time: d.last_bite_time, bite_counter: d.bite_counter, static_torque_knm: d.static_torque_knm,
          peak_torque_knm: d.peak_torque_knm, taf: d.taf, period_shift_s: d.period_shift_s,
          gap_mrad: d.gap_mrad, gap_low_mrad: d.gap_low_mrad, gap_high_mrad: d.gap_high_mrad,
          gap_coupling: d.gap_coupling, degraded: d.degraded, quality: "live",
        };
        tbody.prepend(row(liveBite, true));
        if (gapPlot && d.gap_mrad !== null && d.last_bite_time) {
          wearPoints = wearPoints.concat([{
            end: d.last_bite_time, gap_mrad: d.gap_mrad, gap_low_mrad: d.gap_low_mrad, gap_high_mrad: d.gap_high_mrad,
          }]);
          drawGap();
          gapNote.textContent = "";
        }
        // ...then the stored rows and the trend, once the history has them (without
        // a history, the estimate on the gap map).
        if (pending === null) {
          pending = setTimeout(async () => {
            pending = null;
            if (!overview.history) return loadMap();
            try {
              info = await getJson("/api/drivelines/" + encodeURIComponent(name));
            } catch (error) { console.error(error); }
            loadHistory();
          }, overview.history ? 1500 : 200);
        }
      });
      window.addEventListener("resize", () => {
        if (gapPlot) gapPlot.setSize({ width: plotWidth(gapNode), height: 300 });
        if (tafPlot) tafPlot.setSize({ width: plotWidth(tafNode), height: 320 });
        if (tracePlot) tracePlot.setSize({ width: plotWidth(traceNode), height: 300 });
        if (lifePlot) lifePlot.setSize({ width: plotWidth(lifeNode), height: 260 });
        if (damagePlot) damagePlot.setSize({ width: plotWidth(damageNode), height: 260 });
      });
    }
    start().catch((error) => { gapNote.textContent = error.message; });
    offerCapture(name, traceNote, 10, loadHistory);
  }

  // ---- tandem mill ----------------------------------------------------------------
  // A mill's captures (chatter episodes, manual captures of its stands) and, for the
  // one chosen, the stands' chatter-band RMS over time (the monitor's own band-pass)
  // and their spectra around the warning (/api/captures/{id}/bands).
  function tandemMillPage() {
    const mill = driveline; // the page's subject
    const tbody = document.querySelector("#episodes tbody");
    const note = document.getElementById("episodes-note");
    const bandNode = document.getElementById("band-plot");
    const bandNote = document.getElementById("band-note");
    const spectrumNode = document.getElementById("spectrum-plot");
    const spectrumNote = document.getElementById("spectrum-note");
    let bandPlot = null;
    let spectrumPlot = null;
    let shown = null;

    // The thresholds that judged a chatter capture's episode: the episode (of
    // `episodes`, /api/tandem_mills/{name}/episodes) whose warning lies within the
    // capture; its product group's name, or the mill's own.
    function thresholds(c, episodes) {
      if (c.kind !== "chatter") return "–";
      const from = Date.parse(c.started_at);
      const to = from + c.duration_s * 1000;
      const e = episodes.find((each) => {
        const at = Date.parse(each.started_at);
        return at >= from && at <= to;
      });
      return e ? (e.thresholds_group || "mill's") : "–";
    }

    function row(c, episodes) {
      const episode = c.meta && c.meta.episode;
      const at = (index) => (index === null || index === undefined ? "–" : num(index / c.sample_rate_hz, 2) + " s");
      const file = (format) => "/api/captures/" + c.id + "/file?format=" + format;
      return el("tr", { "data-capture": c.id },
        el("td", {}, utc(c.started_at)), el("td", {}, c.kind),
        el("td", {}, num(c.duration_s, 1) + " s"),
        el("td", {}, episode ? at(episode.warning_sample) : "–"),
        el("td", {}, episode ? (episode.cut ? "cut" : at(episode.cleared_sample)) : "–"),
        el("td", {}, thresholds(c, episodes)),
        el("td", { class: c.context_status && c.context_status !== "valid" ? "muted" : "" }, contextText(c)),
        el("td", {},
          el("button", { type: "button", class: "plot-capture", "data-capture": c.id }, "plot"), " ",
          el("a", { href: file("csv"), download: "" }, "CSV"), " ",
          el("a", { href: file("parquet"), download: "" }, "Parquet")));
    }
    tbody.addEventListener("click", (event) => {
      const button = event.target.closest("button.plot-capture");
      if (button) show(Number(button.dataset.capture));
    });

    // A vertical line at each of `marks` ([x, colour, label]) over the plot.
    const markLines = (marks) => ({
      hooks: {
        draw: [(u) => {
          const ctx = u.ctx;
          for (const [x, colour] of marks) {
            if (x === null || x === undefined) continue;
            const px = Math.round(u.valToPos(x, "x", true));
            ctx.save();
            ctx.strokeStyle = colour;
            ctx.setLineDash([5, 4]);
            ctx.lineWidth = 2;
            ctx.beginPath();
            ctx.moveTo(px, u.bbox.top);
            ctx.lineTo(px, u.bbox.top + u.bbox.height);
            ctx.stroke();
            ctx.restore();
          }
        }],
      },
    });

    async function show(id) {
      shown = id;
      try {
        const b = await getJson("/api/captures/" + id + "/bands");
        if (shown !== id) return;
        const unit = b.unit || "";
        // Band RMS over time: the buckets' largest values, one series per stand.
        const t = b.band_rms.length ? b.band_rms[0].t_s : [];
        const data = [t, ...b.band_rms.map((s) => s.max)];
        const series = [{ label: "t, s", value: (u, v) => num(v, 2) }, ...b.stands.map((name, i) => ({
          label: name, stroke: colours[i % colours.length], width: 1.5, points: quiet,
          value: (u, v) => num(v, 4) + " " + unit }))];
        const marks = [[b.warning_s, "#b45309"], [b.cleared_s, "#15803d"]];
        if (bandPlot) bandPlot.destroy();
        bandPlot = new uPlot({
          width: plotWidth(bandNode), height: 300, scales: { x: { time: false } }, series,
          axes: [{ label: "time from the capture's first sample, s" }, { label: "band RMS, " + unit }],
          plugins: [markLines(marks)],
        }, data, bandNode);
        bandPlot.millgateCapture = id;
        bandPlot.millgateBands = b;
        window.millgatePlots.band = bandPlot;
        const largest = b.band_rms.map((s, i) => b.stands[i] + " up to " + num(s.largest, 4) + " " + unit);
        const marked = (b.warning_s !== null ? "; warning at " + num(b.warning_s, 2) + " s" : "")
          + (b.cleared_s !== null ? ", cleared at " + num(b.cleared_s, 2) + " s" : "");
        describe(bandNode, "Chatter-band RMS (" + num(b.chatter_band_hz[0], 0) + "–" + num(b.chatter_band_hz[1], 0)
          + " Hz) of capture " + id + " over " + t.length + " points"
          + (t.length ? " from " + num(t[0], 2) + " to " + num(t[t.length - 1], 2) + " s" : "") + ": "
          + largest.join("; ") + marked + ".");
        bandNote.textContent = b.kind + " capture " + id + " of " + b.stands.length + " stands at " + b.sample_rate_hz
          + " Hz; the monitor's band-pass RMS over its gain window after each window" + marked + ".";

        // Spectra: PSD per stand (largest in each bucket), the chatter band marked.
        const spectra = b.spectra;
        const f = spectra.length ? spectra[0].frequency_hz : [];
        const sdata = [f, ...spectra.map((s) => s.max)];
        const sseries = [{ label: "f, Hz", value: (u, v) => num(v, 1) }, ...b.stands.map((name, i) => ({
          label: name, stroke: colours[i % colours.length], width: 1.5, points: quiet,
          value: (u, v) => (v === null ? "–" : v.toExponential(2)) }))];
        if (spectrumPlot) spectrumPlot.destroy();
        spectrumPlot = new uPlot({
          width: plotWidth(spectrumNode), height: 300, scales: { x: { time: false }, y: { distr: 3 } },
          series: sseries,
          axes: [{ label: "frequency, Hz" }, { label: "PSD, " + unit + "²/Hz" }],
          plugins: [markLines([[b.chatter_band_hz[0], "#b91c1c"], [b.chatter_band_hz[1], "#b91c1c"]])],
        }, sdata, spectrumNode);
        spectrumPlot.millgateCapture = id;
        window.millgatePlots.spectrum = spectrumPlot;
        const peaks = spectra.map((s, i) => b.stands[i] + " peak at " + num(s.peak_hz, 1) + " Hz");
        const span = num(b.spectrum_span_s[0], 2) + " to " + num(b.spectrum_span_s[1], 2) + " s";
        describe(spectrumNode, spectra.length
          ? "Spectra (Welch PSD) of capture " + id + " from " + span + ", " + f.length + " points up to "
            + num(f[f.length - 1], 0) + " Hz, chatter band " + num(b.chatter_band_hz[0], 0) + "–"
            + num(b.chatter_band_hz[1], 0) + " Hz marked: " + peaks.join("; ") + "."
          : "Spectra: not drawn, the span " + span + " is shorter than one window.");
        spectrumNote.textContent = "Welch PSD of the samples from " + span + " (segments of the monitor's window, "
          + (spectra.length ? num(spectra[0].frequency_step_hz, 2) + " Hz apart" : "none") + "); chatter band marked in red.";
      } catch (error) {
        bandNote.textContent = error.message;
      }
    }

    // The mill's state from the live updates, shown before any capture exists: its
    // chatter state, gain, worst stand, frequency and slow-down request.
    const stateNode = document.getElementById("mill-state");
    function state(o) {
      const m = o.tandem_mills.find((each) => each.name === mill);
      if (!m) return;
      const card = (label, value, sub) => el("div", { class: "card" }, el("div", { class: "label" }, label),
        el("div", { class: "value" }, value), el("div", { class: "sub" }, sub || ""));
      stateNode.replaceChildren(
        card("Chatter", badge(m.chatter_state), m.source_stale ? "source stale" : ""),
        card("Gain ratio", num(m.gain_ratio, 2), "worst stand " + (m.worst_stand_channel || "–")),
        card("Thresholds", m.thresholds_group === null ? "–" : (m.thresholds_group_name || "mill's"),
          [m.gain_thresholds_in_use ? m.gain_thresholds_in_use.map((t) => num(t, 3)).join(", ") : "",
            m.product_fallback ? m.product_fallback + " windows without a valid product" : ""]
            .filter((part) => part !== "").join("; ")),
        card("Chatter frequency", m.chatter_frequency_hz === null ? "–" : num(m.chatter_frequency_hz, 1) + " Hz", ""),
        card("Slow-down request", m.slow_down_request ? badge("warning", "requested") : "no", ""));
    }
    listeners.push((now) => state(now));

    async function load() {
      try {
        const base = "/api/tandem_mills/" + encodeURIComponent(mill);
        const [rows, episodeRows] = await Promise.all([
          getJson(base + "/captures?limit=100"), getJson(base + "/episodes?limit=100")]);
        note.textContent = rows.length ? rows.length + " captures, newest first: plot one, or download it." : "No captures of this mill in the history yet: the plots below show one once the mill's first chatter episode or a manual capture is stored.";
        // No empty panels: the plots only once there is a capture to draw.
        for (const id of ["band-section", "spectrum-section"]) {
          document.getElementById(id).classList.toggle("hidden", rows.length === 0);
        }
        fill(tbody, rows.slice().reverse().map((c) => row(c, episodeRows)));
        const episodes = rows.filter((c) => c.kind === "chatter");
        const first = episodes.length ? episodes[episodes.length - 1] : rows[rows.length - 1];
        if (first && shown === null) show(first.id);
      } catch (error) {
        note.textContent = error.message;
      }
    }
    window.addEventListener("resize", () => {
      if (bandPlot) bandPlot.setSize({ width: plotWidth(bandNode), height: 300 });
      if (spectrumPlot) spectrumPlot.setSize({ width: plotWidth(spectrumNode), height: 300 });
    });
    load();
    offerCapture(mill, note, 10, load);
  }

  // ---- alarms -------------------------------------------------------------------
  // The unit of an alarm event's value and threshold, by its kind.
  const ALARM_UNITS = {
    taf_warning: "(TAF)", taf_alarm: "(TAF)", gap_warning: "mrad", gap_alarm: "mrad",
    chatter_warning: "(gain ratio)", chatter_alarm: "(gain ratio)", slow_down_request: "(gain ratio)",
    unstable: "m/s (speed margin)", near_tongue: "m/s (speed margin)",
  };
  const withUnit = (value, kind) => (value === null ? "–" : num(value, 3) + (ALARM_UNITS[kind] ? " " + ALARM_UNITS[kind] : ""));

  function alarmsPage() {
    const note = document.getElementById("alarms-note");
    async function refresh() {
      try {
        const rows = await getJson("/api/alarms?limit=500");
        note.textContent = rows.length ? "The newest " + rows.length + " alarm events, newest first." : "No alarm events in the history.";
        fill(document.querySelector("#alarms tbody"), rows.reverse().map((a) =>
          el("tr", {},
            el("td", {}, utc(a.time)), el("td", {}, a.subject), el("td", {}, a.kind.replace("_", " ")),
            el("td", {}, badge(a.event === "raised" ? "alarm" : (a.event === "cleared" ? "ok" : "unknown"), a.event)),
            el("td", {}, a.origin + (a.peer ? " (" + a.peer + ")" : "")),
            el("td", {}, withUnit(a.value, a.kind)),
            el("td", {}, withUnit(a.threshold, a.kind)))));
      } catch (error) {
        note.textContent = error.message;
      }
    }
    const flags = (o) => JSON.stringify([o.drivelines.map((d) => [d.taf_warning, d.taf_alarm, d.gap_warning, d.gap_alarm]),
      o.tandem_mills.map((m) => [m.chatter_state])]);
    listeners.push((now, before) => {
      if (before && flags(now) !== flags(before)) setTimeout(refresh, 1000);
    });
    refresh();
  }

  if (page === "overview") overviewPage();
  else if (page === "driveline") drivelinePage();
  else if (page === "tandem_mill") tandemMillPage();
  else if (page === "alarms") alarmsPage();
  connect();
})();
