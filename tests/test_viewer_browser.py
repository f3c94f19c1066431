"""The viewer page in a real browser: headless Chromium, software WebGL (SwiftShader).

How it is run (found to work with Debian's chromium 156, no GPU, no network, as root):

    chromium --headless --no-sandbox --disable-gpu
             --enable-unsafe-swiftshader --use-angle=swiftshader
             --disable-background-networking --disable-component-update --disable-sync
             --disable-quic --no-first-run --user-data-dir=<fresh tmp dir>
             --window-size=1200,800  (--dump-dom | --screenshot=OUT.png)  file:///...html#flags

- ``--disable-gpu`` alone leaves no WebGL; ``--enable-unsafe-swiftshader --use-angle=swiftshader``
  brings it back on the CPU (ANGLE over SwiftShader).
- ``--no-sandbox``: the tests may run as root (CI). The background-networking/component/sync/
  quic flags stop Chromium from calling home on a machine with no network.
- ``--dump-dom`` prints the DOM after the load event. The page draws synchronously while it
  loads; opened with ``#selftest`` it renders each layer alone, reads its canvas back and
  writes JSON into ``<pre id="cm-status">`` (errors caught by window.onerror / console.error,
  pixel counts per layer). A second run takes the screenshot, kept as a test artefact in
  ``$CONFORMILL_ARTIFACTS`` (or the test's tmp folder).
"""

from __future__ import annotations

import html
import json
import os
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from conformill.mesh import synthetic
from conformill.output.viewer import write_viewer

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
pytestmark = pytest.mark.skipif(CHROMIUM is None, reason="chromium is not installed")

FLAGS = [
    "--headless", "--no-sandbox", "--disable-gpu",
    "--enable-unsafe-swiftshader", "--use-angle=swiftshader",
    "--disable-background-networking", "--disable-component-update", "--disable-sync",
    "--disable-quic", "--no-first-run", "--hide-scrollbars", "--window-size=1200,800",
]
BG = np.array([0xEE, 0xF0, 0xF3]) / 255.0  # the page background (BG in the viewer's JS)


def chromium(tmp_path, *args) -> subprocess.CompletedProcess:
    profile = tmp_path / f"profile{len(list(tmp_path.glob('profile*')))}"
    cmd = [CHROMIUM, *FLAGS, f"--user-data-dir={profile}", *args]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=180, check=False)


def artefact_dir(tmp_path) -> Path:
    d = os.environ.get("CONFORMILL_ARTIFACTS")
    if d:
        Path(d).mkdir(parents=True, exist_ok=True)
        return Path(d)
    return tmp_path


def demo_page(path):
    """Free-form patch with zigzag feed passes on the surface, rapids between rows, a heat map."""
    mesh = synthetic.freeform_patch(spacing=2.5)
    V, F = mesh.V, mesh.F
    from scipy.interpolate import LinearNDInterpolator

    zf = LinearNDInterpolator(V[:, :2], V[:, 2])
    x = np.linspace(-45, 45, 120)
    passes, rapids = [], []
    for j, y in enumerate(np.linspace(-30, 0, 12)):  # rows below the notch, all inside the outline
        xs = x if j % 2 == 0 else x[::-1]
        passes.append(np.column_stack([xs, np.full_like(xs, y), zf(xs, np.full_like(xs, y)) + 0.05]))
    for a, b in zip(passes[:-1:3], passes[1::3]):
        rapids.append(np.array([a[-1], a[-1] + [0, 0, 15], b[0] + [0, 0, 15], b[0]]))
    heat = 0.05 * (1 + np.sin(V[:, 0] / 6.0))
    write_viewer(path, V, F, passes, rapids=rapids, heat=heat, title="freeform patch",
                 info={"tool": "ball R3 mm", "scallop": 0.01})
    return mesh, passes


def status_of(tmp_path, page: Path, flags: str = "selftest") -> dict:
    res = chromium(tmp_path, "--dump-dom", page.as_uri() + "#" + flags)
    m = re.search(r'<pre id="cm-status"[^>]*>(.*?)</pre>', res.stdout, re.S)
    assert m, f"no status in the dumped DOM (rc {res.returncode}):\n{res.stderr[-2000:]}"
    return json.loads(html.unescape(m.group(1)))


def test_page_renders_without_errors(tmp_path):
    page = tmp_path / "demo.html"
    _, passes = demo_page(page)
    st = status_of(tmp_path, page)
    assert st["errors"] == [], st["errors"]
    assert st["ok"] is True and st["stage"] == "ready" and st["webgl"] is True
    assert st["counts"]["passes"] == len(passes)
    assert st["counts"]["pathPoints"] == sum(len(p) for p in passes)
    px = st["pixels"]
    w, h = px["canvas"]
    n = w * h
    # the part covers a good share of the view and is drawn in greys (no heat colours)
    assert 0.05 * n < px["part"]["drawn"] < 0.9 * n
    assert px["part"]["vivid"] < 0.001 * n
    # paths and rapids draw coloured pixels; the heat map colours the part
    assert px["paths"]["vivid"] > 2000
    assert px["rapids"]["vivid"] > 200
    assert px["heat"]["drawn"] == px["part"]["drawn"]
    assert px["heat"]["vivid"] > 0.5 * px["heat"]["drawn"]
    assert px["all"]["drawn"] >= px["part"]["drawn"]


def test_screenshot_shows_shaded_part_and_paths(tmp_path):
    import matplotlib.image as mpimg

    page = tmp_path / "demo.html"
    demo_page(page)
    shot = artefact_dir(tmp_path) / "viewer_demo.png"
    res = chromium(tmp_path, f"--screenshot={shot}", page.as_uri())
    assert shot.is_file(), res.stderr[-2000:]
    img = mpimg.imread(shot)[..., :3]
    assert img.shape[:2] == (800, 1200)
    view = img[:, 380:]  # right of the info panel
    diff = np.abs(view - BG).max(axis=2)
    drawn = diff > 0.03
    assert drawn.mean() > 0.05  # the part is there
    # shaded: the grey part pixels span a range of brightness, not one flat tone
    grey = drawn & (view.max(axis=2) - view.min(axis=2) < 0.08)
    lum = view.mean(axis=2)[grey]
    assert grey.sum() > 5000 and np.percentile(lum, 95) - np.percentile(lum, 5) > 0.08
    # the paths: strongly coloured pixels on it
    vivid = view.max(axis=2) - view.min(axis=2) > 0.25
    assert vivid.sum() > 2000


def test_error_is_reported(tmp_path):
    """The status hook catches a script error (a corrupted data element) and says so."""
    page = tmp_path / "demo.html"
    demo_page(page)
    text = page.read_text("utf-8")
    broken = re.sub(r'(id="cm-F"[^>]*>)[A-Za-z0-9+/=]+', r"\1!!!", text)
    bad = tmp_path / "broken.html"
    bad.write_text(broken, "utf-8")
    st = status_of(tmp_path, bad)
    assert st["ok"] is False and st["errors"]
