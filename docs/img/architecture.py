#!/usr/bin/env python3
"""Draw docs/img/architecture.svg, the data path of the README's picture.

    python3 docs/img/architecture.py > docs/img/architecture.svg

Standard library only. The colours follow the reader's theme (`prefers-color-scheme`),
on an opaque background of their own, so the picture reads on GitHub's light and dark
pages alike.
"""

from xml.sax.saxutils import escape

WIDTH, HEIGHT = 1000, 660

STYLE = """
  .bg { fill: #ffffff; }
  text { font-family: -apple-system, 'Segoe UI', 'Helvetica Neue', Arial, sans-serif; fill: #1f2328; }
  .title { font-size: 17px; font-weight: 700; }
  .head { font-size: 15px; font-weight: 700; }
  .path { font-family: ui-monospace, 'SFMono-Regular', Menlo, Consolas, monospace; font-size: 11px; fill: #59636e; }
  .item { font-size: 12.5px; }
  .small { font-size: 11.5px; fill: #59636e; }
  .label { font-size: 12px; font-style: italic; fill: #59636e; }
  .peer { fill: #f6f8fa; stroke: #8c959f; stroke-width: 1; }
  .tile { fill: #ffffff; stroke-width: 1; }
  .arrow { stroke: #59636e; stroke-width: 1.6; fill: none; marker-end: url(#head); }
  .dashed { stroke-dasharray: 5 4; }
  .tip { fill: #59636e; }
  .field { fill: #ddf4ff; stroke: #0969da; }
  .analysis { fill: #fbefff; stroke: #8250df; }
  .state { fill: #dafbe1; stroke: #1a7f37; }
  .outputs { fill: #fff1e5; stroke: #bc4c00; }
  .history { fill: #fff8c5; stroke: #9a6700; }
  .stage { stroke-width: 1.6; }
  @media (prefers-color-scheme: dark) {
    .bg { fill: #0d1117; }
    text { fill: #e6edf3; }
    .path, .small, .label { fill: #9198a1; }
    .peer { fill: #151b23; stroke: #656c76; }
    .tile { fill: #0d1117; }
    .arrow { stroke: #9198a1; }
    .tip { fill: #9198a1; }
    .field { fill: #0c2d4a; stroke: #4493f8; }
    .analysis { fill: #2b1a47; stroke: #ab7df8; }
    .state { fill: #0f3320; stroke: #3fb950; }
    .outputs { fill: #3d1d05; stroke: #f0883e; }
    .history { fill: #332a06; stroke: #d29922; }
  }
"""

parts = []


def text(x, y, value, cls, anchor="start"):
    parts.append(
        f'<text x="{x}" y="{y}" class="{cls}" text-anchor="{anchor}">{escape(value)}</text>'
    )


def box(x, y, w, h, cls, rx=8):
    parts.append(f'<rect x="{x}" y="{y}" width="{w}" height="{h}" rx="{rx}" class="{cls}"/>')


def stage(x, y, w, h, cls, head, path, items):
    """A stage of the data path: a heading, its folder and its lines of text."""
    box(x, y, w, h, f"stage {cls}")
    text(x + 14, y + 24, head, "head")
    text(x + 14, y + 40, path, "path")
    line_y = y + 64
    for item in items:
        if item is None:
            line_y += 8
            continue
        indent = 12 if item.startswith("  ") else 0
        text(x + 14 + indent, line_y, item.strip(), "item")
        line_y += 18


def tile(x, y, w, h, cls, lines):
    box(x, y, w, h, f"tile {cls}", rx=5)
    first = y + h / 2 - (len(lines) - 1) * 8 + 4
    for i, line in enumerate(lines):
        text(x + w / 2, first + i * 16, line, "item" if i == 0 else "small", "middle")


def peer(x, y, w, h, lines):
    box(x, y, w, h, "peer", rx=5)
    first = y + h / 2 - (len(lines) - 1) * 7.5 + 4
    for i, line in enumerate(lines):
        text(x + w / 2, first + i * 15, line, "small", "middle")


def arrow(points, dashed=False):
    d = "M " + " L ".join(f"{x} {y}" for x, y in points)
    cls = "arrow dashed" if dashed else "arrow"
    parts.append(f'<path d="{d}" class="{cls}"/>')


# Row 1: field I/O -> Acquired -> analysis -> state.
text(16, 28, "millgate: the data path", "title")
peer(10, 78, 122, 46, ["DAQs, PLCs", "Modbus TCP"])
peer(10, 148, 122, 46, ["serial devices", "Modbus RTU"])
peer(10, 218, 122, 46, ["CAN sensor nodes", "SocketCAN"])
for y in (101, 171, 241):
    arrow([(132, y), (158, y)])

stage(160, 50, 224, 250, "field", "field I/O", "gateway/src/field", [
    "Modbus TCP readers",
    "Modbus RTU readers (serial line)",
    "CAN readers (DBC signals,",
    "  kernel receive times)",
    None,
    "source health: ok, stale, lost",
    "blocks, gaps, drops counted",
])

arrow([(384, 160), (452, 160)])
text(418, 150, "Acquired", "label", "middle")
text(418, 180, "samples,", "small", "middle")
text(418, 195, "gaps,", "small", "middle")
text(418, 210, "process", "small", "middle")
text(418, 225, "values", "small", "middle")

stage(454, 50, 236, 250, "analysis", "analysis", "gateway/src/analysis", [
    "drivelines: each bite's TAF,",
    "  periods, eq. (1) fit, wear",
    "  index, opened gap (mrad)",
    "tandem mills: chatter, band",
    "  gain, slow-down request",
    "rod mills: span stability",
    "  (Mathieu, Floquet)",
])
tile(468, 246, 208, 40, "analysis", ["gap maps", "built on threads, cached"])

arrow([(690, 140), (758, 140)])
text(725, 128, "results,", "small", "middle")
text(725, 158, "events", "small", "middle")
arrow([(758, 230), (690, 230)], dashed=True)
text(725, 220, "commands", "small", "middle")

stage(760, 50, 230, 250, "state", "state", "gateway/src/state", [
    "board: live results,",
    "  source health",
    "catalogue: every published",
    "  figure once (key, unit,",
    "  quality bit, stale rule)",
    "history queue (bounded)",
    "commands: acknowledge,",
    "  reset wear, capture",
])

# Row 2: the history and the outputs.
arrow([(800, 300), (800, 326), (280, 326), (280, 370)])
text(540, 320, "events and captures, on the history queue", "label", "middle")
arrow([(850, 300), (850, 370)])
text(842, 344, "reads", "label", "end")
arrow([(910, 370), (910, 300)], dashed=True)
text(918, 344, "commands", "small")

stage(160, 370, 240, 170, "history", "history", "gateway/src/history", [
    "one SQLite file: bites, wear,",
    "  alarms, outages, runs",
    "captures: each bite's samples",
    "writer thread: WAL, group commit",
    "restore at start, retention",
])

stage(454, 370, 536, 170, "outputs", "outputs", "gateway/src/outputs", [])
tiles = [
    (["PLC writer", "FC 16 writes"], ["PLC"]),
    (["HMI server", "Modbus TCP"], ["HMI, SCADA"]),
    (["/metrics", "Prometheus"], ["Prometheus"]),
    (["web page", "JSON API"], ["browser"]),
    (["Sparkplug B", "MQTT"], ["MQTT broker,", "hosts"]),
    (["OPC UA", "feature opcua"], ["OPC UA", "clients"]),
]
tile_w, gap = 82, 6
x = 461
for lines, peer_lines in tiles:
    tile(x, 440, tile_w, 84, "outputs", lines)
    arrow([(x + tile_w / 2, 524), (x + tile_w / 2, 578)])
    peer(x, 580, tile_w, 44, peer_lines)
    x += tile_w + gap

arrow([(400, 455), (452, 455)])
text(426, 445, "bites,", "small", "middle")
text(426, 475, "queries", "small", "middle")
arrow([(280, 540), (280, 578)])
peer(160, 580, 240, 44, ["millgate history, report,", "capture export (CLI)"])

text(16, 648, "service (gateway/src/service) builds and wires every task; readers stop first, "
     "analysis drains, the PLC gets a last write.", "small")

svg = [
    f'<svg xmlns="http://www.w3.org/2000/svg" width="{WIDTH}" height="{HEIGHT}" '
    f'viewBox="0 0 {WIDTH} {HEIGHT}" role="img" aria-labelledby="title">',
    '<title id="title">millgate: field I/O (Modbus TCP/RTU, SocketCAN) to Acquired samples, '
    "the analysis (drivelines, tandem mills, rod mills), the state (board, catalogue, "
    "history queue), the outputs (PLC writer, HMI server, /metrics, web page, Sparkplug, "
    "OPC UA) and the history (SQLite, captures)</title>",
    f"<style>{STYLE}</style>",
    "<defs>",
    '<marker id="head" viewBox="0 0 10 10" refX="9" refY="5" markerWidth="7" '
    'markerHeight="7" orient="auto-start-reverse">',
    '<path d="M 0 0 L 10 5 L 0 10 z" class="tip"/>',
    "</marker>",
    "</defs>",
    f'<rect x="0" y="0" width="{WIDTH}" height="{HEIGHT}" rx="10" class="bg"/>',
    *parts,
    "</svg>",
]
print("\n".join(svg))
