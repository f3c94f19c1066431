"""Self-contained HTML 3D viewer of a part, its tool paths, rapids and remaining material.

:func:`write_viewer` writes ONE HTML file that opens offline in any WebGL browser: the
three.js library (a minified bundle vendored in ``output/assets``, MIT, rebuilt by
``tools/vendor_three.sh``) and the data are inlined. Arrays travel as base64 of little-endian
``float32``/``uint32`` in ``<script type="application/x-conformill">`` elements, which the page
decodes into typed arrays and hands to the GPU as is:

========  ============  ===========================================================
id        dtype         contents
========  ============  ===========================================================
``V``     float32       mesh vertices, ``(n, 3)``, mm, Z up
``F``     uint32        triangles, ``(m, 3)``
``P``     float32       feed points of all passes, concatenated, ``(N, 3)``
``PO``    uint32        pass offsets into ``P``, ``(passes + 1,)``
``R``     float32       rapid segments, ``(r, 2, 3)``
``H``     float32       remaining material per vertex, ``(n,)``, mm (NaN: no data)
========  ============  ===========================================================

All passes form one ``THREE.LineSegments`` (indexed, vertex colours by program position on a turbo
colour map), the rapids one dashed red ``LineSegments``, so the page stays interactive with a
300k-face mesh and a million path points. Nothing is decimated.

The page records its health in ``<pre id="cm-status">`` as JSON (``ok``, ``errors`` caught by
``window.onerror`` and a ``console.error`` hook, ``webgl``); opened with ``#selftest`` in the
URL it also renders each layer alone and reports how many canvas pixels each one covers
(``pixels``), which the browser test reads back with ``chromium --dump-dom``.

The output bytes depend only on the inputs (no dates, no random ids), and the file is
written atomically (:mod:`conformill.output.atomic`).
"""

from __future__ import annotations

import base64
import html
import math
import re
from importlib import resources
from typing import Mapping, Sequence

import numpy as np

from conformill.errors import OutputError
from conformill.output.atomic import write_text

__all__ = ["write_viewer", "render_viewer", "split_program", "THREE_ASSET"]

#: vendored three.js bundle (see tools/vendor_three.sh) and its licence, in output/assets
THREE_ASSET = "three.viewer.min.js"
THREE_LICENSE = "THREE_LICENSE.txt"


# ----------------------------------------------------------------------------- inputs

def _fail(what: str) -> OutputError:
    return OutputError(f"cannot build the 3D view: {what}")


def _points(a, what: str, min_rows: int = 0) -> np.ndarray:
    """``a`` as a finite ``(k, 3)`` float64 array, or a typed error naming ``what``."""
    try:
        arr = np.asarray(a, dtype=np.float64)
    except (TypeError, ValueError):
        raise _fail(f"{what} is not numeric") from None
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise _fail(f"{what} has shape {arr.shape}, expected (k, 3)")
    if arr.shape[0] < min_rows:
        raise _fail(f"{what} has {arr.shape[0]} points, expected at least {min_rows}")
    bad = np.flatnonzero(~np.isfinite(arr).all(axis=1))
    if bad.size:
        raise _fail(f"{what} has non-finite coordinates at row {int(bad[0])} ({bad.size} rows)")
    return arr


def _faces(F, n: int) -> np.ndarray:
    try:
        arr = np.asarray(F)
    except (TypeError, ValueError):
        raise _fail("F is not an integer array") from None
    if arr.ndim != 2 or arr.shape[1] != 3 or arr.shape[0] == 0:
        raise _fail(f"F has shape {arr.shape}, expected (m, 3) with m >= 1")
    if arr.dtype.kind not in "iu":
        if arr.dtype.kind != "f" or not np.array_equal(arr, np.round(arr)):
            raise _fail(f"F has dtype {arr.dtype}, expected integers")
        arr = arr.astype(np.int64)
    bad = np.flatnonzero(((arr < 0) | (arr >= n)).any(axis=1))
    if bad.size:
        raise _fail(f"F row {int(bad[0])} = {arr[bad[0]].tolist()} indexes outside the {n} vertices")
    return arr


def _rapid_segments(rapids) -> np.ndarray:
    """Rapids as ``(r, 2, 3)`` float64 segments: from an ``(r, 2, 3)`` array or a list of polylines."""
    if rapids is None:
        return np.zeros((0, 2, 3))
    if isinstance(rapids, np.ndarray) and rapids.ndim == 3:
        if rapids.shape[1:] != (2, 3):
            raise _fail(f"rapids has shape {rapids.shape}, expected (r, 2, 3) segments")
        return _points(rapids.reshape(-1, 3), "rapids").reshape(-1, 2, 3)
    if isinstance(rapids, np.ndarray) and rapids.ndim == 2:  # one polyline
        rapids = [rapids]
    parts = []
    for i, line in enumerate(rapids):
        pts = _points(line, f"rapids[{i}]", min_rows=2)
        parts.append(np.stack([pts[:-1], pts[1:]], axis=1))
    return np.concatenate(parts) if parts else np.zeros((0, 2, 3))


def split_program(points, motion, start=None) -> tuple[list[np.ndarray], np.ndarray]:
    """Split a program's moves into feed passes (polylines) and rapid segments.

    Move ``i`` goes from the previous position (``start`` for ``i = 0``) to ``points[i]``.
    A pass is a maximal run of consecutive feed moves, drawn from the position before its
    first move to the end of its last move.

    Parameters
    ----------
    points : (k, 3) float
        Tool-tip position at the end of each move, mm.
    motion : (k,) int
        0 for a rapid (G0) move, anything else for a feed move.
    start : (3,) float, optional
        Position before the first move; when omitted the first move has no length.

    Returns
    -------
    passes : list of (k_i + 1, 3) float64
        Feed polylines (views into one array), in program order.
    rapids : (r, 2, 3) float64
        Rapid moves of non-zero length as (from, to) segments.

    Raises
    ------
    OutputError
        Shapes disagree or coordinates are not finite.
    """
    pts = _points(points, "program points")
    mot = np.asarray(motion).reshape(-1)
    if mot.shape[0] != pts.shape[0]:
        raise _fail(f"program has {pts.shape[0]} points but {mot.shape[0]} motion codes")
    first = pts[:1] if start is None else _points(np.reshape(start, (1, 3)), "program start")
    if pts.shape[0] == 0:
        return [], np.zeros((0, 2, 3))
    ext = np.concatenate([first, pts])  # ext[i] is where move i starts, ext[i + 1] where it ends
    feed = (mot != 0).astype(np.int8)
    edge = np.diff(feed, prepend=np.int8(0), append=np.int8(0))
    run_start = np.flatnonzero(edge == 1)
    run_end = np.flatnonzero(edge == -1)  # exclusive move index
    passes = [ext[s : e + 1] for s, e in zip(run_start.tolist(), run_end.tolist())]
    r = np.flatnonzero(mot == 0)
    seg = np.stack([ext[r], ext[r + 1]], axis=1)
    moving = np.any(seg[:, 0] != seg[:, 1], axis=1)
    return passes, seg[moving]


# ----------------------------------------------------------------------------- encoding

def _b64(arr: np.ndarray, dtype: str) -> str:
    return base64.b64encode(np.ascontiguousarray(arr, dtype=dtype).tobytes()).decode("ascii")


def _blob(key: str, arr: np.ndarray, dtype: str, shape: tuple) -> str:
    dt = {"<f4": "float32", "<u4": "uint32"}[dtype]
    shp = ",".join(str(int(s)) for s in shape)
    return (f'<script type="application/x-conformill" id="cm-{key}" data-dtype="{dt}" '
            f'data-shape="{shp}">{_b64(arr, dtype)}</script>\n')


def _fmt(value) -> str:
    """A value for the info panel: floats to 4 significant digits, sequences joined."""
    if isinstance(value, (bool, np.bool_)):
        return "yes" if value else "no"
    if isinstance(value, (int, np.integer)):
        return f"{int(value):,}".replace(",", "\u202f")
    if isinstance(value, (float, np.floating)):
        x = float(value)
        if not math.isfinite(x):
            return str(x)
        if abs(x) >= 1e4:
            return f"{x:,.0f}".replace(",", "\u202f")
        return f"{x:.4g}"
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if isinstance(value, (list, tuple)):
        return ", ".join(_fmt(v) for v in value)
    return str(value)


def _asset(name: str) -> str:
    try:
        return resources.files("conformill.output").joinpath("assets", name).read_text(encoding="utf-8")
    except OSError as exc:
        raise OutputError(f"cannot build the 3D view: vendored file output/assets/{name} is missing ({exc})") from None


# ----------------------------------------------------------------------------- page

def render_viewer(V, F, passes: Sequence, rapids=None, heat=None, title: str = "",
                  info: Mapping | None = None) -> str:
    """The viewer page as HTML text (see :func:`write_viewer`, which takes the same arguments)."""
    V = _points(V, "V", min_rows=3)
    n = V.shape[0]
    F = _faces(F, n)
    pass_list = [_points(p, f"passes[{i}]", min_rows=1) for i, p in enumerate(passes)]
    P = np.concatenate(pass_list) if pass_list else np.zeros((0, 3))
    PO = np.concatenate([[0], np.cumsum([p.shape[0] for p in pass_list], dtype=np.int64)])
    if P.shape[0] >= 2**32:
        raise _fail(f"{P.shape[0]} path points exceed the 2**32 index range")
    R = _rapid_segments(rapids)
    H = None
    if heat is not None:
        try:
            H = np.asarray(heat, dtype=np.float64).reshape(-1)
        except (TypeError, ValueError):
            raise _fail("heat is not numeric") from None
        if H.shape[0] != n:
            raise _fail(f"heat has {H.shape[0]} values for {n} vertices")
        if not np.isfinite(H).any():
            raise _fail("heat has no finite value")

    # summary figures, vectorized over all passes at once
    seg_len = np.linalg.norm(np.diff(P, axis=0), axis=1) if P.shape[0] > 1 else np.zeros(0)
    if seg_len.size:
        seg_len[PO[1:-1] - 1] = 0.0  # the jumps between consecutive passes are not cut
    feed_len = float(seg_len.sum())
    rapid_len = float(np.linalg.norm(R[:, 1] - R[:, 0], axis=1).sum()) if R.size else 0.0

    rows = [(str(k), _fmt(v)) for k, v in (info or {}).items()]
    rows += [
        ("mesh", f"{_fmt(n)} vertices, {_fmt(F.shape[0])} faces"),
        ("passes", f"{_fmt(len(pass_list))} ({_fmt(P.shape[0])} points)"),
        ("feed length", f"{_fmt(feed_len)} mm"),
        ("rapids", f"{_fmt(R.shape[0])} moves, {_fmt(rapid_len)} mm"),
    ]
    lo = hi = 0.0
    if H is not None:
        lo, hi = float(np.nanmin(H)), float(np.nanmax(H))
        rows.append(("remaining", f"{_fmt(lo)} to {_fmt(hi)} mm"))
    esc = html.escape
    info_html = "".join(f"<tr><th>{esc(k)}</th><td>{esc(v)}</td></tr>" for k, v in rows)
    name = title or "conformill view"

    blobs = _blob("V", V, "<f4", V.shape) + _blob("F", F, "<u4", F.shape)
    blobs += _blob("P", P, "<f4", P.shape) + _blob("PO", PO, "<u4", PO.shape)
    blobs += _blob("R", R, "<f4", R.shape)
    if H is not None:
        blobs += _blob("H", np.where(np.isfinite(H), H, np.nan), "<f4", H.shape)

    three = _asset(THREE_ASSET)
    if "</script" in three.lower() or "<!--" in three:
        raise _fail(f"vendored {THREE_ASSET} contains '</script' or '<!--' and cannot be inlined")
    heat_range = f"{lo!r},{hi!r}" if H is not None else "null"
    fill = {"TITLE": esc(name), "INFO": info_html, "HEATRANGE": heat_range}
    page = re.sub(r"@([A-Z]+)@", lambda m: fill[m.group(1)], _PAGE_HEAD + _PAGE_BODY + "\x00" + _PAGE_JS)
    body, js = page.split("\x00")
    return body + blobs + "<script>\n" + three + "\n</script>\n<script>\n" + js + "</script>\n</body>\n</html>\n"


def write_viewer(path, V, F, passes: Sequence, rapids=None, heat=None, title: str = "",
                 info: Mapping | None = None) -> None:
    """Write a self-contained HTML 3D view of a part and its tool paths.

    The page shows the shaded part, the feed passes coloured by position in the program
    (turbo colour map, start blue, end red: passes and the revolutions of one spiral
    differ), the rapids dashed red and, when given, the remaining
    material as vertex colours (viridis, with a legend in mm). Mouse: left drag orbits,
    right drag pans, wheel zooms (towards the cursor); check boxes toggle each layer,
    buttons reset the view (fit, top, iso). A panel lists ``title``, ``info`` and summary
    figures (mesh size, pass count, feed and rapid lengths, remaining-material range).

    Parameters
    ----------
    path : str or Path
        Output ``.html`` file; written atomically.
    V : (n, 3) float
        Mesh vertices, mm, Z up.
    F : (m, 3) int
        Triangles (indices into ``V``).
    passes : sequence of (k_i, 3) float
        Feed polylines (tool-tip positions), in program order.
    rapids : (r, 2, 3) float or sequence of (k_i, 3) float, optional
        Rapid moves, as segments or as polylines.
    heat : (n,) float, optional
        Remaining material per vertex, mm; NaN for "no data" (drawn grey).
    title : str
        Page title and panel heading.
    info : mapping, optional
        Extra key/value lines for the panel (tool, scallop, ...), shown in their order.

    Raises
    ------
    OutputError
        An input has the wrong shape or non-finite values (the message names it), or the
        file cannot be written. No partial file is left behind.

    Notes
    -----
    Geometry is stored as float32 (about 1e-5 mm resolution at 100 mm). File size is about
    ``4/3 * (12 n + 12 m + 12 N + 24 r + 4 n)`` bytes of base64 plus 0.57 MB for three.js.
    """
    write_text(path, render_viewer(V, F, passes, rapids=rapids, heat=heat, title=title, info=info))


# ----------------------------------------------------------------------------- page text
# Kept as plain strings (no template engine); @NAME@ markers are replaced above.

_PAGE_HEAD = """<!DOCTYPE html>
<html lang="en">
<head>
<meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<meta name="generator" content="conformill">
<title>@TITLE@</title>
<style>
html, body { margin: 0; height: 100%; overflow: hidden; background: #eef0f3;
  font: 13px/1.35 system-ui, -apple-system, "Segoe UI", Roboto, sans-serif; color: #1d2329; }
#cm-canvas { position: absolute; inset: 0; width: 100%; height: 100%; display: block; outline: none; }
#cm-panel { position: absolute; top: 10px; left: 10px; max-width: 330px; padding: 10px 12px;
  background: rgba(255,255,255,0.88); border: 1px solid #c9ced6; border-radius: 6px;
  box-shadow: 0 1px 4px rgba(0,0,0,0.12); }
#cm-panel h1 { font-size: 15px; margin: 0 0 6px 0; }
#cm-panel table { border-collapse: collapse; margin-bottom: 6px; }
#cm-panel th { text-align: left; font-weight: 600; padding: 1px 10px 1px 0; vertical-align: top; white-space: nowrap; }
#cm-panel td { padding: 1px 0; }
#cm-panel label { display: inline-block; margin-right: 10px; white-space: nowrap; }
#cm-panel button { font: inherit; margin: 6px 4px 0 0; padding: 2px 9px; }
.cm-legend { margin-top: 7px; }
.cm-bar { height: 10px; border-radius: 2px; border: 1px solid #9aa1ab; }
.cm-ticks { display: flex; justify-content: space-between; font-size: 11px; color: #48515c; }
.cm-dash { display: inline-block; width: 26px; height: 0; border-top: 2px dashed #d62728; vertical-align: middle; margin-right: 6px; }
.cm-swatch { display: inline-block; width: 12px; height: 10px; background: #333; border: 1px solid #9aa1ab; vertical-align: middle; margin-right: 6px; }
#cm-help { font-size: 11px; color: #5b6470; margin-top: 6px; }
#cm-error { position: absolute; bottom: 10px; left: 10px; right: 10px; color: #8a1111; background: #fde8e8;
  border: 1px solid #e6a1a1; padding: 6px 10px; border-radius: 4px; display: none; white-space: pre-wrap; }
</style>
<script>
/* error hook: installed before anything else runs; the page's status lists what it caught */
window.__cm = { errors: [], warnings: [] };
window.addEventListener("error", function (e) {
  window.__cm.errors.push(String(e.message || e) + (e.lineno ? " (line " + e.lineno + ")" : ""));
  if (window.__cmReport) window.__cmReport();
});
window.addEventListener("unhandledrejection", function (e) { window.__cm.errors.push("unhandled rejection: " + String(e.reason)); });
(function () {
  var err = console.error, warn = console.warn;
  console.error = function () { window.__cm.errors.push(Array.prototype.map.call(arguments, String).join(" ")); err.apply(console, arguments); };
  console.warn = function () { window.__cm.warnings.push(Array.prototype.map.call(arguments, String).join(" ")); warn.apply(console, arguments); };
})();
</script>
</head>
"""

_PAGE_BODY = """<body>
<canvas id="cm-canvas" tabindex="0"></canvas>
<div id="cm-panel">
<h1>@TITLE@</h1>
<table>@INFO@</table>
<div>
<label><input type="checkbox" id="cm-show-part" checked> part</label>
<label><input type="checkbox" id="cm-show-paths" checked> paths</label>
<label><input type="checkbox" id="cm-show-rapids" checked> rapids</label>
<label><input type="checkbox" id="cm-show-heat"> remaining material</label>
</div>
<div>
<button type="button" id="cm-fit">fit</button><button type="button" id="cm-top">top</button><button type="button" id="cm-iso">iso</button>
</div>
<div class="cm-legend" id="cm-legend-paths"><div>feed paths (program order, start to end)</div><div class="cm-bar" id="cm-bar-paths"></div>
<div class="cm-ticks"><span id="cm-pass-first">start</span><span id="cm-pass-last"></span></div></div>
<div class="cm-legend" id="cm-legend-rapids"><span class="cm-dash"></span>rapids</div>
<div class="cm-legend" id="cm-legend-heat" style="display:none"><div>remaining material (mm)</div><div class="cm-bar" id="cm-bar-heat"></div>
<div class="cm-ticks"><span id="cm-heat-lo"></span><span id="cm-heat-mid"></span><span id="cm-heat-hi"></span></div>
<div id="cm-gouge" style="display:none"><div>gouge (below the surface)</div><div class="cm-bar" id="cm-bar-gouge"></div>
<div class="cm-ticks"><span id="cm-gouge-lo"></span><span>0</span></div></div>
<div><span class="cm-swatch"></span>no data / uncut</div></div>
<div id="cm-help">left drag: orbit &middot; right drag: pan &middot; wheel: zoom</div>
</div>
<div id="cm-error"></div>
<pre id="cm-status" hidden>{"ok":false,"stage":"loading"}</pre>
"""

_PAGE_JS = r"""(function () {
"use strict";
var t0 = performance.now();
var HEAT_RANGE = [@HEATRANGE@];
var BG = 0xeef0f3;
var PASS_STOPS = ["#4559cb", "#3e9bfe", "#19d5cd", "#46f884", "#a4fc3c", "#e1dd37", "#fea431", "#f05b12", "#c32503"];
var GOUGE_STOPS = ["#fcbba1", "#fb6a4a", "#cb181d", "#67000d"];
var HEAT_STOPS = ["#440154", "#482475", "#414487", "#355f8d", "#2a788e", "#21918c", "#22a884", "#44bf70", "#7ad151", "#bddf26", "#fde725"];
var status = { ok: false, stage: "start", errors: window.__cm.errors, warnings: window.__cm.warnings, webgl: false };
var statusEl = document.getElementById("cm-status");
function report() {
  status.ok = status.stage === "ready" && status.errors.length === 0;
  statusEl.textContent = JSON.stringify(status);
  if (status.errors.length) {
    var box = document.getElementById("cm-error");
    box.style.display = "block";
    box.textContent = status.errors.join("\n");
  }
}
window.__cmReport = report;

function hexRgb(h) { var v = parseInt(h.slice(1), 16); return [(v >> 16 & 255) / 255, (v >> 8 & 255) / 255, (v & 255) / 255]; }
function lin(c) { return c <= 0.04045 ? c / 12.92 : Math.pow((c + 0.055) / 1.055, 2.4); }
/* a colour map as a 256-entry table of linear-light RGB (vertex colours are linear in three.js) */
function lut(stops) {
  var rgb = stops.map(hexRgb), out = new Float32Array(256 * 3);
  for (var i = 0; i < 256; i++) {
    var x = i / 255 * (rgb.length - 1), k = Math.min(Math.floor(x), rgb.length - 2), f = x - k;
    for (var c = 0; c < 3; c++) out[3 * i + c] = lin(rgb[k][c] * (1 - f) + rgb[k + 1][c] * f);
  }
  return out;
}
function gradientCss(stops) { return "linear-gradient(to right, " + stops.join(", ") + ")"; }
function fmt(x) { return Math.abs(x) >= 100 ? x.toFixed(1) : Number(x.toPrecision(3)).toString(); }

function blob(id) {
  var el = document.getElementById("cm-" + id);
  if (!el) return null;
  var s = el.textContent.trim(), u8;
  if (typeof Uint8Array.fromBase64 === "function") {
    u8 = Uint8Array.fromBase64(s);
  } else {
    var bin = atob(s), n = bin.length;
    u8 = new Uint8Array(n);
    for (var i = 0; i < n; i++) u8[i] = bin.charCodeAt(i);
  }
  var T = el.getAttribute("data-dtype") === "uint32" ? Uint32Array : Float32Array;
  return new T(u8.buffer, u8.byteOffset, u8.byteLength / 4);
}

function disable(layer) {
  var box = document.getElementById("cm-show-" + layer);
  box.checked = false; box.disabled = true;
}

function main() {
  var canvas = document.getElementById("cm-canvas");
  var V = blob("V"), F = blob("F"), P = blob("P"), PO = blob("PO"), R = blob("R"), H = blob("H");
  status.ms = { decode: Math.round(performance.now() - t0) };
  status.counts = { vertices: V.length / 3, faces: F.length / 3, passes: PO.length - 1, pathPoints: P.length / 3, rapids: R.length / 6 };
  status.stage = "webgl";
  var renderer;
  try {
    renderer = new THREE.WebGLRenderer({ canvas: canvas, antialias: true, preserveDrawingBuffer: true });
  } catch (e) {
    throw new Error("WebGL is not available in this browser: " + (e && e.message ? e.message : e));
  }
  status.webgl = true;
  renderer.setPixelRatio(window.devicePixelRatio || 1);
  var scene = new THREE.Scene();
  scene.background = new THREE.Color(BG);
  var camera = new THREE.PerspectiveCamera(35, 1, 0.1, 1000);
  camera.up.set(0, 0, 1);
  scene.add(camera);
  scene.add(new THREE.HemisphereLight(0xffffff, 0x3c434d, 0.7));
  var key = new THREE.DirectionalLight(0xffffff, 3.0);
  key.position.set(-0.8, 1.0, 0.45);   /* camera space: from the upper left, grazing, to bring out relief */
  key.target.position.set(0, 0, -1);
  camera.add(key); camera.add(key.target);

  /* part */
  var partGeo = new THREE.BufferGeometry();
  partGeo.setAttribute("position", new THREE.BufferAttribute(V, 3));
  partGeo.setIndex(new THREE.BufferAttribute(F, 1));
  partGeo.computeVertexNormals();
  partGeo.computeBoundingSphere();
  var partMat = new THREE.MeshStandardMaterial({ color: 0xb9c0c9, metalness: 0.05, roughness: 0.55, side: THREE.DoubleSide,
    polygonOffset: true, polygonOffsetFactor: 1, polygonOffsetUnits: 1 });
  var part = new THREE.Mesh(partGeo, partMat);
  scene.add(part);

  /* remaining material: vertex colours on the same geometry, switched on with the check box */
  var heatMat = null;
  if (H) {
    /* values >= 0 on viridis over [max(lo, 0), hi]; negative ones (gouges) on a red ramp
       over [lo, 0]; NaN (no data, uncut) dark grey */
    var hl = lut(HEAT_STOPS), gl_ = lut(GOUGE_STOPS), col = new Float32Array(V.length);
    var gouged = HEAT_RANGE[0] < 0, lo = gouged ? 0 : HEAT_RANGE[0], span = HEAT_RANGE[1] - lo;
    for (var i = 0; i < H.length; i++) {
      var h = H[i], tab = hl, j;
      if (h !== h) { col[3 * i] = col[3 * i + 1] = col[3 * i + 2] = 0.03; continue; }
      if (h < 0) { tab = gl_; j = Math.round(Math.min(h / HEAT_RANGE[0], 1) * 255); }
      else j = span > 0 ? Math.round(Math.min(Math.max((h - lo) / span, 0), 1) * 255) : 0;
      col[3 * i] = tab[3 * j]; col[3 * i + 1] = tab[3 * j + 1]; col[3 * i + 2] = tab[3 * j + 2];
    }
    partGeo.setAttribute("color", new THREE.BufferAttribute(col, 3));
    heatMat = partMat.clone();
    heatMat.color.set(0xffffff);
    heatMat.vertexColors = true;
    document.getElementById("cm-bar-heat").style.background = gradientCss(HEAT_STOPS);
    document.getElementById("cm-heat-lo").textContent = fmt(lo);
    document.getElementById("cm-heat-mid").textContent = fmt((lo + HEAT_RANGE[1]) / 2);
    if (gouged) {
      document.getElementById("cm-gouge").style.display = "";
      document.getElementById("cm-bar-gouge").style.background = gradientCss(GOUGE_STOPS.slice().reverse());
      document.getElementById("cm-gouge-lo").textContent = fmt(HEAT_RANGE[0]);
    }
    document.getElementById("cm-heat-hi").textContent = fmt(HEAT_RANGE[1]);
  }

  /* feed passes: ONE indexed LineSegments, vertex colour = position in the program on the
     turbo map (so one spiral pass still shows its revolutions, and passes differ) */
  var nPass = PO.length - 1, nPts = P.length / 3, paths = null;
  if (nPts > 0) {
    var pl = lut(PASS_STOPS), pc = new Float32Array(P.length), idx = new Uint32Array(2 * Math.max(nPts - nPass, 0)), m = 0;
    for (var p = 0; p < nPass; p++) {
      var a = PO[p], b = PO[p + 1];
      for (var k = a; k < b; k++) {
        var q = nPts > 1 ? Math.round(255 * k / (nPts - 1)) : 0;
        pc[3 * k] = pl[3 * q]; pc[3 * k + 1] = pl[3 * q + 1]; pc[3 * k + 2] = pl[3 * q + 2];
        if (k + 1 < b) { idx[m++] = k; idx[m++] = k + 1; }
      }
    }
    var pathGeo = new THREE.BufferGeometry();
    pathGeo.setAttribute("position", new THREE.BufferAttribute(P, 3));
    pathGeo.setAttribute("color", new THREE.BufferAttribute(pc, 3));
    pathGeo.setIndex(new THREE.BufferAttribute(idx.subarray(0, m), 1));
    pathGeo.computeBoundingSphere();
    paths = new THREE.LineSegments(pathGeo, new THREE.LineBasicMaterial({ vertexColors: true }));
    scene.add(paths);
  }
  document.getElementById("cm-bar-paths").style.background = gradientCss(PASS_STOPS);
  document.getElementById("cm-pass-last").textContent = "end (" + nPass + (nPass === 1 ? " pass)" : " passes)");
  if (!paths) { disable("paths"); document.getElementById("cm-legend-paths").style.display = "none"; }

  /* rapids: one dashed LineSegments */
  var rapids = null;
  var bbox = new THREE.Box3().setFromBufferAttribute(partGeo.getAttribute("position"));
  if (paths) bbox.union(new THREE.Box3().setFromBufferAttribute(paths.geometry.getAttribute("position")));
  if (R.length > 0) {
    var rg = new THREE.BufferGeometry();
    rg.setAttribute("position", new THREE.BufferAttribute(R, 3));
    bbox.union(new THREE.Box3().setFromBufferAttribute(rg.getAttribute("position")));
    var d = bbox.getSize(new THREE.Vector3()).length();
    rapids = new THREE.LineSegments(rg, new THREE.LineDashedMaterial({ color: 0xd62728, dashSize: d / 120, gapSize: d / 200 }));
    rapids.computeLineDistances();
    scene.add(rapids);
  } else {
    disable("rapids");
    document.getElementById("cm-legend-rapids").style.display = "none";
  }
  if (!H) disable("heat");

  var sphere = bbox.getBoundingSphere(new THREE.Sphere());
  var radius = Math.max(sphere.radius, 1e-3);
  camera.near = radius / 500; camera.far = radius * 60; camera.updateProjectionMatrix();

  var controls = new THREE.OrbitControls(camera, canvas);
  controls.zoomToCursor = true;
  controls.maxDistance = radius * 20;

  function render() { renderer.render(scene, camera); }
  function resize() {
    var w = Math.max(canvas.clientWidth, 1), h = Math.max(canvas.clientHeight, 1);
    renderer.setSize(w, h, false);
    camera.aspect = w / h; camera.updateProjectionMatrix();
    render();
  }
  function look(dir) {
    var fov = camera.fov * Math.PI / 180, aspect = Math.max(camera.aspect, 1e-3);
    var dist = radius / Math.sin(Math.min(fov, 2 * Math.atan(Math.tan(fov / 2) * aspect)) / 2) * 1.05;
    var v = new THREE.Vector3(dir[0], dir[1], dir[2]).normalize();
    controls.target.copy(sphere.center);
    camera.position.copy(sphere.center).addScaledVector(v, dist);
    controls.update();
    render();
  }
  var ISO = [0.55, -1.0, 0.9], TOP = [0, -1e-4, 1];
  function sync() {
    var heatOn = !!H && document.getElementById("cm-show-heat").checked;
    part.visible = document.getElementById("cm-show-part").checked || heatOn;
    part.material = heatOn ? heatMat : partMat;
    if (paths) paths.visible = document.getElementById("cm-show-paths").checked;
    if (rapids) rapids.visible = document.getElementById("cm-show-rapids").checked;
    document.getElementById("cm-legend-heat").style.display = heatOn ? "" : "none";
    render();
  }
  ["part", "paths", "rapids", "heat"].forEach(function (n) { document.getElementById("cm-show-" + n).addEventListener("change", sync); });
  document.getElementById("cm-fit").addEventListener("click", function () { look(camera.position.clone().sub(controls.target).toArray()); });
  document.getElementById("cm-top").addEventListener("click", function () { look(TOP); });
  document.getElementById("cm-iso").addEventListener("click", function () { look(ISO); });
  controls.addEventListener("change", render);
  window.addEventListener("resize", resize);

  /* URL hash flags (e.g. file.html#heat,top): initial state, handy for screenshots */
  var flags = location.hash.slice(1).split(/[,&]/);
  if (H && flags.indexOf("heat") >= 0) document.getElementById("cm-show-heat").checked = true;
  ["part", "paths", "rapids"].forEach(function (n) { if (flags.indexOf("no" + n) >= 0) document.getElementById("cm-show-" + n).checked = false; });
  status.ms.build = Math.round(performance.now() - t0);
  resize();
  look(flags.indexOf("top") >= 0 ? TOP : ISO);
  sync();

  /* #selftest: render each layer alone and count the canvas pixels that differ from the
     background (and the strongly coloured ones), for the browser test */
  status.ms.firstFrame = Math.round(performance.now() - t0);
  if (flags.indexOf("selftest") >= 0) {
    var gl = renderer.getContext(), W = gl.drawingBufferWidth, Hh = gl.drawingBufferHeight, buf = new Uint8Array(W * Hh * 4);
    var br = BG >> 16 & 255, bgg = BG >> 8 & 255, bb = BG & 255;
    var count = function () {
      render();
      gl.readPixels(0, 0, W, Hh, gl.RGBA, gl.UNSIGNED_BYTE, buf);
      var drawn = 0, vivid = 0;
      for (var i = 0; i < buf.length; i += 4) {
        var r = buf[i], g = buf[i + 1], b = buf[i + 2];
        if (Math.abs(r - br) > 6 || Math.abs(g - bgg) > 6 || Math.abs(b - bb) > 6) drawn++;
        if (Math.max(r, g, b) - Math.min(r, g, b) > 60) vivid++;
      }
      return { drawn: drawn, vivid: vivid };
    };
    var ids = ["part", "paths", "rapids", "heat"], saved = {};
    ids.forEach(function (n) { saved[n] = document.getElementById("cm-show-" + n).checked; });
    var only = function (n) {
      ids.forEach(function (o) { document.getElementById("cm-show-" + o).checked = (o === n); });
      part.visible = n === "part" || n === "heat"; part.material = n === "heat" && heatMat ? heatMat : partMat;
      if (paths) paths.visible = n === "paths";
      if (rapids) rapids.visible = n === "rapids";
      return count();
    };
    status.pixels = { all: count(), part: only("part"), paths: paths ? only("paths") : null,
      rapids: rapids ? only("rapids") : null, heat: heatMat ? only("heat") : null, canvas: [W, Hh] };
    ids.forEach(function (n) { document.getElementById("cm-show-" + n).checked = saved[n]; });
    sync();
  }
  status.stage = "ready";
  status.ms.ready = Math.round(performance.now() - t0);
}

try {
  main();
} catch (e) {
  status.errors.push(String(e && e.message ? e.message : e));
}
report();
})();
"""
