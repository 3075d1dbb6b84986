"""`ndf-view` in a real browser: the viewer serves a run on a free loopback port, headless
Chromium (driven over its DevTools protocol) opens it, and its screenshot must show the mesh in
the colours of the colour map, not a blank page.

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


def mesh_pixels(image: np.ndarray) -> int:
    """Saturated pixels with viridis hues (purple through green to yellow) in the middle of the
    canvas, away from the control panel (right) and the notifications and axes (left)."""
    h, w = image.shape[:2]
    middle = image[int(0.1 * h):int(0.9 * h), int(0.25 * w):int(0.72 * w)]
    hsv = cv2.cvtColor(middle, cv2.COLOR_BGR2HSV)
    hue, saturation = hsv[..., 0].astype(int), hsv[..., 1]
    viridis_hue = (hue >= 25) & (hue <= 150)  # OpenCV hue in [0, 180): yellow 30 .. violet 140
    return int(np.count_nonzero(viridis_hue & (saturation > 60)))


@pytest.mark.skipif(CHROMIUM is None, reason="no Chromium: apt-get install chromium (Debian), "
                    "which .ci/run does when it can")
def test_viewer_shows_the_mesh_in_headless_chromium(tmp_path):
    run = fake_run(tmp_path / "run", frames=3, obstacle=True)
    port = free_port()
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    viewer = subprocess.Popen([sys.executable, "-m", "taichi_ndf.cli.view", str(run), "--port",
                               str(port)], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                              text=True, env=env)
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
        cv2.imwrite(str(tmp_path / "viewer.png"), image)
        assert image.shape[1] == WIDTH and float(image.std()) > 10.0  # not a blank page
        assert mesh_pixels(image) > 5000, f"no mesh in {tmp_path / 'viewer.png'}"
    finally:
        if browser is not None:
            browser.close()
        viewer.terminate()
        viewer.wait(timeout=10)
