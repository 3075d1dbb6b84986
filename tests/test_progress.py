"""Progress reports (`taichi_ndf.progress`) and how the tools show them: the hook, the line per
stage off a terminal, and each long-running tool on a pseudo-terminal showing its bar within
5 s of the start of its solve."""

from __future__ import annotations

import contextlib
import fcntl
import io
import logging
import os
import pty
import re
import select
import signal
import struct
import subprocess
import sys
import termios
import time
from pathlib import Path

import pytest

from taichi_ndf import progress
from taichi_ndf.cli.progress import ProgressDisplay

ROOT = Path(__file__).resolve().parents[1]


def test_reports_go_to_listeners_inside_a_stage_only():
    seen = []
    progress.report(1, x=1.0)  # outside any stage: nothing, no error
    with progress.listening(seen.append):
        with progress.stage("outer", 3):
            progress.report(1, **{"Π": -1.5})
            with progress.stage("inner"):
                progress.report(7)
            progress.report(2, **{"Π": -1.25})
    progress.report(3)
    assert [(p.stage, p.step, p.done) for p in seen] == [
        ("outer", 0, False), ("outer", 1, False), ("inner", 0, False), ("inner", 7, False),
        ("inner", 7, True), ("outer", 2, False), ("outer", 2, True)]
    assert seen[-1].values == {"Π": -1.25} and seen[-1].total == 3
    assert seen[-1].elapsed >= 0


def test_a_finished_stage_is_logged_and_closed_when_its_work_raises(caplog):
    seen = []
    with caplog.at_level(logging.INFO, logger="taichi_ndf.progress"), \
            progress.listening(seen.append), pytest.raises(RuntimeError):
        with progress.stage("Newton level 0 (4 × 4 spans), load 1", 10):
            progress.report(2, **{"Π": -0.5, "λ²": 1e-3})
            raise RuntimeError("stop")
    assert seen[-1].done and seen[-1].step == 2
    assert "Newton level 0 (4 × 4 spans), load 1: 2 steps, Π -0.5, λ² 0.001, 0.0 s" in caplog.text
    progress.report(5)  # the stage is closed: nothing
    assert len(seen) == 3


def test_off_a_terminal_one_line_per_finished_stage():
    stream = io.StringIO()
    display = ProgressDisplay("ndf-x", stream=stream, terminal=False)
    with progress.listening(display):
        with progress.stage("fit", 5):
            for i in range(1, 4):
                progress.report(i, loss=0.5 / i)
    assert re.fullmatch(r"ndf-x: fit: 3 steps, loss 0\.166667, \d+\.\d s\n", stream.getvalue())
    with progress.listening(display), progress.stage("set-up"):
        pass
    assert re.search(r"\nndf-x: set-up: \d+\.\d s\n$", stream.getvalue())


def test_on_a_terminal_a_bar_per_stage():
    stream = io.StringIO()
    display = ProgressDisplay("ndf-x", stream=stream, terminal=True)
    with progress.listening(display), progress.stage("Adam, load 1", 10):
        progress.report(4, **{"Π": -1.0})
    text = stream.getvalue()
    assert "Adam, load 1" in text and "4/10" in text and "Π -1" in text


SCENE = """
name = "progress_napkin"
[geometry]
type = "plane"
bounds = [[0.0, 1.0], [0.0, 1.0]]
[material]
preset = "denim"
[loads]
gravity = [0.0, 0.0, -9.81]
[[boundary.constraint]]
type = "pinned_point"
xi = [0.0, 0.0]
rotation = "free"
[field]
{field}
[training]
{training}
[output]
resolution = [8, 8]
"""

SPLINE = ('type = "spline"\nspans = [8, 8]', 'newton_max_iterations = 300')
ADAM = ("width = 16", "iterations = 100000\nsamples = 256")

# Imports done before the marker: the 5 s measure the tool's own start and its solve.
WRAPPER = """
import sys, taichi, torch
import taichi_ndf.scene.reader, taichi_ndf.app.simulation
from {module} import main
print("SOLVE STARTS", flush=True)
sys.exit(main(sys.argv[1:]))
"""


def _first_progress(command: list[str], pattern: str, timeout: float) -> tuple[float, str]:
    """Run `command` on a pseudo-terminal; seconds from its "SOLVE STARTS" marker to the first
    output matching `pattern`, and the output so far. The process is killed then."""
    (seconds,), text = _progress_times(command, [pattern], timeout)
    return seconds, text


def _progress_times(command: list[str], patterns: list[str],
                    timeout: float) -> tuple[list[float], str]:
    """Run `command` on a pseudo-terminal; for each of `patterns`, the seconds from the
    command's "SOLVE STARTS" marker to the first output matching it, and the output so far.
    The command and every process it started are killed once all have matched."""
    master, slave = pty.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 120, 0, 0))
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen(command, stdin=slave, stdout=slave, stderr=slave, env=env,
                            cwd=ROOT, close_fds=True, start_new_session=True)
    os.close(slave)
    text, started, found = "", None, {}
    deadline = time.monotonic() + timeout
    try:
        while time.monotonic() < deadline and len(found) < len(patterns):
            ready, _, _ = select.select([master], [], [], 0.1)
            if not ready:
                if proc.poll() is not None:
                    break
                continue
            try:
                chunk = os.read(master, 65536).decode(errors="replace")
            except OSError:
                break
            text += chunk
            now = time.monotonic()
            if started is None and "SOLVE STARTS" in text:
                started, text = now, text.split("SOLVE STARTS", 1)[1]
            if started is not None:
                found.update({p: now - started for p in patterns
                              if p not in found and re.search(p, text)})
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)  # a sweep's workers too
        proc.wait()
        os.close(master)
    assert started is not None, f"the tool never started:\n{text}"
    missing = [p for p in patterns if p not in found]
    assert not missing, f"no progress matching {missing} in {timeout} s:\n{text}"
    return [found[p] for p in patterns], text


@pytest.mark.parametrize("path", ["spline", "adam"])
def test_ndf_sim_shows_progress_on_a_terminal_within_5_s(tmp_path, path):
    field, training = SPLINE if path == "spline" else ADAM
    scene = tmp_path / "scene.toml"
    scene.write_text(SCENE.format(field=field, training=training))
    command = [sys.executable, "-c", WRAPPER.format(module="taichi_ndf.cli.sim"), str(scene),
               "--out", str(tmp_path / "run")]
    # The Adam path first estimates its output scale by a coarse Newton solve (its own stage).
    stage = "Newton level 0" if path == "spline" else "Newton level 0|Adam, load 1"
    seconds, text = _first_progress(command, stage, timeout=60)
    assert seconds < 5, f"first progress after {seconds:.1f} s:\n{text}"
