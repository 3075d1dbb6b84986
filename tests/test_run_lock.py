"""The claim of an output directory (`taichi_ndf.io.run_lock`): a second run on one --out is
refused while the first runs, and the lock of a killed run is taken over."""

from __future__ import annotations

import json
import logging
import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest
from test_cli import small_napkin

from taichi_ndf.io import OutputDir, staged_run
from taichi_ndf.io.run_lock import OutputLockedError, RunLock, lock_path

ROOT = Path(__file__).resolve().parents[1]


def dead_pid() -> int:
    """The pid of a process that has ended (and was reaped)."""
    process = subprocess.Popen([sys.executable, "-c", "pass"])
    process.wait()
    return process.pid


def test_a_second_process_on_the_same_out_is_refused_and_the_first_run_keeps_its_files(
        tmp_path):
    scene = small_napkin(tmp_path)
    out = tmp_path / "run"
    with staged_run(out, products=("result.json", "mesh.obj")) as first:
        first.write_text("mesh.obj", "v 0 0 0\n")
        second = subprocess.run(
            [sys.executable, "-m", "taichi_ndf.cli.sim", str(scene), "--out", str(out),
             "--iters", "1", "--precision", "f64"],
            cwd=ROOT, capture_output=True, text=True, timeout=600)
        assert second.returncode == 2, second.stderr
        lines = second.stderr.strip().splitlines()
        assert len(lines) == 1 and "in use by another run" in lines[0], second.stderr
        assert f"pid {os.getpid()}" in lines[0]
        # the first run's attempt is untouched, and it keeps writing
        assert (first.path / "mesh.obj").read_text() == "v 0 0 0\n"
        first.write_json("result.json", {"energy": 1.0})
    assert sorted(p.name for p in out.iterdir()) == ["mesh.obj", "result.json"]
    assert not lock_path(out).exists() and not (tmp_path / "run.incomplete").exists()


def test_output_dir_is_held_until_released_and_refused_meanwhile(tmp_path):
    run = OutputDir(tmp_path / "a")
    with pytest.raises(OutputLockedError, match="in use by another run"):
        OutputDir(tmp_path / "a", overwrite=True)
    holder = json.loads(lock_path(tmp_path / "a").read_text())
    assert holder["pid"] == os.getpid() and holder["host"] == socket.gethostname()
    run.release()
    assert not lock_path(tmp_path / "a").exists()
    with OutputDir(tmp_path / "a", overwrite=True) as again:
        assert again.lock.held
    assert not again.lock.held and not lock_path(tmp_path / "a").exists()


def test_the_stale_lock_of_a_killed_run_is_taken_over_with_a_log_line(tmp_path, caplog):
    out = tmp_path / "run"
    (tmp_path / "run.incomplete").mkdir()
    (tmp_path / "run.incomplete" / "checkpoint.pt").write_bytes(b"killed run's")
    lock_path(out).write_text(json.dumps({"pid": dead_pid(), "host": socket.gethostname(),
                                          "start": "1", "started": "earlier"}))
    with caplog.at_level(logging.WARNING, logger="taichi_ndf.io.run_lock"):
        with staged_run(out) as run:
            run.write_text("result.json", "{}")
    assert "taking over the lock" in caplog.text and "no longer running" in caplog.text
    assert (out / "result.json").is_file() and not lock_path(out).exists()


def test_a_recorded_live_holder_is_refused_even_without_its_flock(tmp_path):
    """Where flock does not exclude (no fcntl, a filesystem without it), the recorded holder
    on this host that still runs the same process is refused; a reused pid is not that."""
    holder = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        start = Path(f"/proc/{holder.pid}/stat").read_text().rsplit(")", 1)[1].split()[19]
        record = {"pid": holder.pid, "host": socket.gethostname(), "start": start}
        lock_path(tmp_path / "a").write_text(json.dumps(record))
        with pytest.raises(OutputLockedError, match=f"pid {holder.pid}"):
            RunLock(tmp_path / "a")
        assert json.loads(lock_path(tmp_path / "a").read_text()) == record  # left as it was
        lock_path(tmp_path / "a").write_text(json.dumps({**record, "start": "0"}))  # reused
        RunLock(tmp_path / "a").release()
    finally:
        holder.kill()
        holder.wait()


def test_a_run_replaces_the_per_panel_meshes_of_an_earlier_garment_run(tmp_path):
    # a garment run's mesh_<panel>.obj are the run's files (a pattern among its products):
    # a later run into the same directory removes them instead of keeping them beside its own
    out = tmp_path / "run"
    products = ("result.json", "mesh.obj", "mesh_*.obj")
    with staged_run(out, products=products) as garment:
        garment.write_text("mesh_front.obj", "v 0 0 0\n")
        garment.write_text("mesh.obj", "v 0 0 0\n")
    (out / "notes.txt").write_text("mine")
    with staged_run(out, overwrite=True, products=products) as napkin:
        napkin.write_text("mesh.obj", "v 1 1 1\n")
    assert sorted(p.name for p in out.iterdir()) == ["mesh.obj", "notes.txt"]
