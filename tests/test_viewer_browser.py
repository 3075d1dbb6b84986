"""`ndf-view` in a real browser: the viewer serves a run on a free loopback port, headless
Chromium (driven over its DevTools protocol) opens it at the first of three trajectory frames,
and its screenshot must show the mesh (not a blank page) filling at least half the canvas, the
probe (red) on that frame, and the convergence plot (uPlot, Π and the Newton decrement) whole
in the window; after "fit to view" (framed for the browser's own canvas) the mesh fills more.

Needs the [viewer] extra and Chromium (Debian: apt-get install chromium; .ci/run installs it).
Bounded: the viewer must start within 60 s and the mesh appear within 150 s (software WebGL on
a busy 2-core machine took ~55 s).
"""

from __future__ import annotations

import base64
import json
import os
import shutil
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import cv2
import numpy as np
import pytest
from test_render_figure import fake_run

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.browser
pytest.importorskip("viser", reason="viser (pip install 'taichi-ndf[viewer]') is missing")
websockets_client = pytest.importorskip("websockets.sync.client",
                                        reason="websockets (a viser dependency) is missing")
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
WIDTH, HEIGHT = 1280, 800


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_for(predicate, timeout: float, what: str):
    """The first value of `predicate()` that is not None, polled every 0.5 s."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        value = predicate()
        if value is not None:
            return value
        time.sleep(0.5)
    raise AssertionError(f"timed out after {timeout:.0f} s waiting for {what}")


class DevTools:
    """A headless Chromium page driven over the Chrome DevTools Protocol."""

    def __init__(self, url: str, profile: Path):
        port = free_port()
        self.process = subprocess.Popen(
            [CHROMIUM, "--headless", "--no-sandbox", "--use-angle=swiftshader",
             "--enable-unsafe-swiftshader", "--no-first-run", f"--user-data-dir={profile}",
             f"--remote-debugging-port={port}", "--remote-debugging-address=127.0.0.1",
             f"--window-size={WIDTH},{HEIGHT}", url],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        page = wait_for(lambda: self._page(port), 30, "Chromium's DevTools endpoint")
        self.socket = websockets_client.connect(page, max_size=None, open_timeout=10)
        self.next_id = 0

    @staticmethod
    def _page(port: int) -> str | None:
        try:
            with urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list", timeout=2) as r:
                pages = [p for p in json.load(r) if p.get("type") == "page"]
        except OSError:
            return None
        return pages[0]["webSocketDebuggerUrl"] if pages else None

    def call(self, method: str, **params) -> dict:
        self.next_id += 1
        self.socket.send(json.dumps({"id": self.next_id, "method": method, "params": params}))
        while True:
            message = json.loads(self.socket.recv(timeout=30))
            if message.get("id") == self.next_id:
                if "error" in message:
                    raise RuntimeError(f"{method}: {message['error']}")
                return message["result"]

    def evaluate(self, expression: str):
        """The value of a JavaScript expression in the page."""
        result = self.call("Runtime.evaluate", expression=expression, returnByValue=True)
        return result["result"].get("value")

    def screenshot(self) -> np.ndarray | None:
        """The page as BGR, or None when no frame came within 30 s (a software-rendered WebGL
        page on a busy CPU can take that long)."""
        try:
            data = base64.b64decode(self.call("Page.captureScreenshot", format="png")["data"])
        except TimeoutError:
            return None
        return cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)

    def close(self):
        self.socket.close()
        self.process.terminate()
        self.process.wait(timeout=10)


def middle(image: np.ndarray) -> np.ndarray:
    """The middle of the page, away from the control panel (right) and the notifications and
    axes (left)."""
    h, w = image.shape[:2]
    return image[int(0.1 * h):int(0.9 * h), int(0.2 * w):int(0.7 * w)]


def mesh_mask(image: np.ndarray) -> np.ndarray:
    """Saturated pixels with viridis hues (purple through green to yellow) or the plain
    surface's steel blue."""
    hsv = cv2.cvtColor(image, cv2.COLOR_BGR2HSV)
    hue, saturation = hsv[..., 0].astype(int), hsv[..., 1]
    viridis_hue = (hue >= 25) & (hue <= 150)  # OpenCV hue in [0, 180): yellow 30 .. violet 140
    return viridis_hue & (saturation > 60)


def mesh_pixels(image: np.ndarray) -> int:
    return int(np.count_nonzero(mesh_mask(middle(image))))


def probe_pixels(image: np.ndarray) -> int:
    """Saturated red pixels (the probes' spheres) in the middle of the page."""
    hsv = cv2.cvtColor(middle(image), cv2.COLOR_BGR2HSV)
    hue, saturation = hsv[..., 0].astype(int), hsv[..., 1]
    return int(np.count_nonzero(((hue <= 8) | (hue >= 172)) & (saturation > 120)))


def mesh_extent(image: np.ndarray, canvas: dict) -> float:
    """The larger of the mesh's width and height (2nd to 98th percentile of its pixels) as a
    fraction of the canvas's."""
    x0, y0 = int(canvas["left"]), int(canvas["top"])
    inside = mesh_mask(image[y0:y0 + int(canvas["height"]), x0:x0 + int(canvas["width"])])
    rows, columns = np.nonzero(inside)
    spread = [np.ptp(np.percentile(v, [2, 98])) for v in (columns, rows)]
    return max(spread[0] / canvas["width"], spread[1] / canvas["height"])


LARGEST_CANVAS = """(() => {
  const c = [...document.querySelectorAll('canvas')].map(e => e.getBoundingClientRect())
    .sort((a, b) => b.width * b.height - a.width * a.height)[0];
  return {left: c.left, top: c.top, width: c.width, height: c.height};
})()"""
PLOT = """(() => {
  const p = document.querySelector('.uplot');
  if (!p) return null;
  const r = p.getBoundingClientRect();
  return {text: p.innerText, top: r.top, bottom: r.bottom, height: r.height,
          window: window.innerHeight, canvases: p.querySelectorAll('canvas').length};
})()"""

CLICK_FIT = """(() => {
  const b = [...document.querySelectorAll('button')].find(e => e.innerText.trim() == 'fit to view');
  if (!b) return false;
  b.click();
  return true;
})()"""


def newton_history(run: Path) -> None:
    """Give the fake run a projected-Newton history: a decrement per iteration (one of them
    zero, drawn as a gap on the log axis)."""
    result = json.loads((run / "result.json").read_text())
    for k, row in enumerate(result["history"]):
        row["decrement"] = 0.0 if k == 4 else 10.0 ** -(2 * k)
    (run / "result.json").write_text(json.dumps(result))


@pytest.mark.skipif(CHROMIUM is None, reason="no Chromium: apt-get install chromium (Debian), "
                    "which .ci/run does when it can")
def test_viewer_shows_the_mesh_in_headless_chromium(tmp_path):
    run = fake_run(tmp_path / "run", frames=3, obstacle=True)
    newton_history(run)
    port = free_port()
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    viewer = subprocess.Popen([sys.executable, "-m", "taichi_ndf.cli.view", str(run), "--port",
                               str(port), "--frame", "0"], stdout=subprocess.PIPE,
                              stderr=subprocess.STDOUT, text=True, env=env)
    browser = None
    try:
        line = wait_for(lambda: viewer.stdout.readline() or None, 60, "the viewer's URL")
        while "ndf-view:" not in line:
            line = viewer.stdout.readline()
            assert line, "the viewer exited before printing its URL"
        url = f"http://127.0.0.1:{port}"
        assert url in line
        browser = DevTools(url, tmp_path / "profile")
        image = wait_for(lambda: (lambda im: im if im is not None and mesh_pixels(im) > 5000
                                  else None)(browser.screenshot()), 150, "the mesh in the browser")
        time.sleep(2.0)  # let the fade-in finish for the saved picture
        later = browser.screenshot()
        image = image if later is None else later
        saved = tmp_path / "viewer.png"
        cv2.imwrite(str(saved), image)
        assert image.shape[1] == WIDTH and float(image.std()) > 10.0  # not a blank page
        assert mesh_pixels(image) > 5000, f"no mesh in {saved}"
        canvas = browser.evaluate(LARGEST_CANVAS)
        assert canvas["width"] < 0.85 * WIDTH, canvas  # beside the docked panel, not under it
        extent = mesh_extent(image, canvas)
        assert extent > 0.5, f"the mesh spans {extent:.0%} of the canvas in {saved}"
        assert probe_pixels(image) > 50, f"no probe on frame 0 in {saved}"
        plot = browser.evaluate(PLOT)
        assert plot is not None, "no uPlot chart in the page"
        assert "Π [J]" in plot["text"] and "log₁₀ λ² [J]" in plot["text"], plot
        assert plot["canvases"] >= 1 and plot["height"] > 100, plot
        assert 0 <= plot["top"] and plot["bottom"] <= plot["window"], plot  # whole, not cut off
        assert browser.evaluate(CLICK_FIT), "no 'fit to view' button"
        time.sleep(3.0)  # the camera moves on the server's next message
        fitted = browser.screenshot()
        assert fitted is not None
        cv2.imwrite(str(tmp_path / "fitted.png"), fitted)
        # fitted to the canvas's own aspect (measured here: 74 % on its larger side, 66 % before)
        assert mesh_extent(fitted, canvas) > 0.7, tmp_path / "fitted.png"
    finally:
        if browser is not None:
            browser.close()
        viewer.terminate()
        viewer.wait(timeout=10)
