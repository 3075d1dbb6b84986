"""The run's progress file (`io.progress_log`, written by ndf-sim) and the viewer that follows a
run while it is written (`viewer.live`, `ndf-view` on a running run)."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys

import pytest
from test_cli import run_sim, small_napkin
from test_render_figure import fake_run

from taichi_ndf import progress
from taichi_ndf.cli import view
from taichi_ndf.io import incomplete_path
from taichi_ndf.io.progress_log import PROGRESS_FILE, ProgressLog, logged_progress, read_progress
from taichi_ndf.io.run_lock import _start_time, held_by_a_live_run, lock_path


def test_each_new_value_and_each_finished_stage_is_one_line(tmp_path):
    path = tmp_path / PROGRESS_FILE
    with logged_progress(path), progress.stage("Newton level 0, load 1", 10):
        progress.report(1, **{"Π": -1.0, "λ²": 0.5})
        progress.report(2)  # no values: not a line
        progress.report(3, **{"Π": -1.0, "λ²": 0.5})  # the same values again: not a line
        progress.report(4, **{"Π": -1.5, "λ²": 1e-9})
    lines = read_progress(path)
    assert [(r["step"], r["done"]) for r in lines] == [(1, False), (4, False), (4, True)]
    assert lines[1]["values"] == {"Π": -1.5, "λ²": 1e-9} and lines[0]["total"] == 10
    assert lines[0]["stage"] == "Newton level 0, load 1" and lines[2]["elapsed"] >= 0


def test_a_line_being_written_is_left_for_the_next_read(tmp_path):
    path = tmp_path / PROGRESS_FILE
    assert read_progress(path) == []
    log = ProgressLog(path)
    log(progress.Progress("s", 1, None, {"Π": 2.0}))
    log.close()
    with open(path, "a", encoding="utf-8") as file:
        file.write('{"stage": "s", "ste')
    assert [r["values"] for r in read_progress(path)] == [{"Π": 2.0}]
    path.write_text("not json\n")
    with pytest.raises(ValueError, match="not a progress file"):
        read_progress(path)


def test_ndf_sim_writes_the_newton_iterations_into_its_run(tmp_path):
    scene = small_napkin(tmp_path)
    out = tmp_path / "run"
    assert run_sim(scene, "--out", out, "--field", "spline", "--quick") == 0
    lines = read_progress(out / PROGRESS_FILE)
    newton = [r for r in lines if r["stage"].startswith("Newton level") and not r["done"]
              and "λ²" in r["values"]]
    result = json.loads((out / "result.json").read_text())
    # every Newton iteration of the run is one line, with the Π result.json records for it
    assert len(newton) == len(result["history"]) > 0
    assert [r["values"]["Π"] for r in newton] == pytest.approx(
        [h["energy"] for h in result["history"]], rel=1e-12)


@pytest.fixture
def live_holder(tmp_path):
    """A running process (sleep) recorded as the holder of tmp_path/run's claim, with the run's
    staging folder and its progress file of two Newton iterations."""
    final = tmp_path / "run"
    stage = incomplete_path(final)
    stage.mkdir()
    child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(120)"])
    try:
        holder = {"pid": child.pid, "host": socket.gethostname(),
                  "start": _start_time(child.pid), "started": "now", "command": "ndf-sim"}
        lock_path(final).write_text(json.dumps(holder) + "\n")
        log = ProgressLog(stage / PROGRESS_FILE)
        for step, (energy, decrement) in enumerate([(-1.0, 0.1), (-1.2, 1e-4)], 1):
            log(progress.Progress("Newton level 0 (8 × 8 spans), load 1", step, 50,
                                  {"Π": energy, "λ²": decrement}))
        yield final, log
        log.close()
    finally:
        child.kill()
        child.wait()


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_a_run_is_live_only_while_a_running_process_holds_it(tmp_path, live_holder):
    final, _ = live_holder
    from taichi_ndf.viewer.live import live_run

    assert held_by_a_live_run(final)
    assert live_run(final) == final and live_run(incomplete_path(final)) == final
    lock_path(final).write_text(json.dumps({"pid": 2**22 + 17, "host": socket.gethostname()}))
    assert not held_by_a_live_run(final) and live_run(final) is None  # a killed run's lock


def test_the_live_viewer_plots_new_iterations_and_sees_the_run_finish(tmp_path, live_holder):
    pytest.importorskip("viser", reason="viser (pip install 'taichi-ndf[viewer]') is missing")
    from taichi_ndf.viewer.live import LiveViewer

    final, log = live_holder
    viewer = LiveViewer(final, port=free_port())
    try:
        iterations, energies, log_decrements = viewer.plot.data
        assert list(iterations) == [1.0, 2.0] and list(energies) == [-1.0, -1.2]
        assert list(log_decrements) == pytest.approx([-1.0, -4.0])
        assert "step 2 of 50" in viewer.status.content and "running" in viewer.status.content
        log(progress.Progress("Newton level 0 (8 × 8 spans), load 1", 3, 50,
                              {"Π": -1.25, "λ²": 1e-9}))
        assert viewer.poll() is False
        assert list(viewer.plot.data[1]) == [-1.0, -1.2, -1.25]
        incomplete_path(final).rename(final)  # the run is moved into place ...
        (final / "result.json").write_text("{}")
        assert viewer.poll() is True  # ... and the viewer says it has finished
    finally:
        viewer.stop()


def test_a_staging_folder_nobody_writes_is_refused_in_one_line(tmp_path, capsys):
    pytest.importorskip("viser", reason="viser (pip install 'taichi-ndf[viewer]') is missing")
    stage = incomplete_path(tmp_path / "run")
    stage.mkdir()
    assert view.main([str(stage), "--port", str(free_port())]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not running" in err[0] and "--resume" in err[0]


def next_tool_line(process: subprocess.Popen, limit: int = 40) -> str:
    """The next line the tool prints itself ("ndf-view: ..."; viser's banner lines skipped);
    "" if the process ends first."""
    for _ in range(limit):
        line = process.stdout.readline()
        if not line or line.startswith("ndf-view:"):
            return line
    return ""


def test_ndf_view_follows_a_running_run_and_then_shows_the_finished_run(tmp_path, live_holder):
    pytest.importorskip("viser", reason="viser (pip install 'taichi-ndf[viewer]') is missing")
    final, _ = live_holder
    stage = incomplete_path(final)
    fake_run(stage)  # the files the run will have when it is moved into place
    viewer = subprocess.Popen(
        [sys.executable, "-m", "taichi_ndf.cli.view", str(final), "--port", str(free_port())],
        env={**os.environ, "OMP_NUM_THREADS": "1"}, stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL, text=True)
    try:
        assert "(running;" in next_tool_line(viewer)
        stage.rename(final)  # the run finishes
        assert "finished; reload the page" in next_tool_line(viewer)
        assert viewer.poll() is None  # and goes on serving the finished run
    finally:
        viewer.kill()
        viewer.wait()
