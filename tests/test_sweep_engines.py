"""`ndf-sweep` runs: a 2 × 3 study of quick ndf-sim runs on the local pool, the same on a local
Ray head (skipped where Ray is not installed), a study interrupted (Ctrl-C) and killed
(SIGKILL) mid-way and resumed to the same table, and a failing run kept as a row."""

from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest
from test_cli import SMALL_NAPKIN

from taichi_ndf.cli import sweep
from taichi_ndf.io import atomic_path
from taichi_ndf.sweep.table import TIMES, ResultsTable, read_csv

ROOT = Path(__file__).resolve().parents[1]

# tests/test_cli.py's small napkin (a 16-wide SIREN, a 16 x 16 output grid), 3 Adam
# iterations, seed 7 (set for every run by the study's [options]): ~9 s of CPU per run, most of
# it start-up (imports, Taichi's cached kernels) and the outputs.
STUDY = """
job = "scene"
base = "scene.toml"
[options]
precision = "f64"
"training.iterations" = 3
"training.seed" = 7
[axes]
"material.stiffness_scale" = [1.0, 2.0]
loads.gravity = [[0.0, 0.0, -9.81], [0.0, 0.0, -4.9], [0.0, -2.0, -9.81]]
"""


def write_study(folder: Path) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "scene.toml").write_text(SMALL_NAPKIN.format(lr=1e-3))
    (folder / "study.toml").write_text(STUDY)
    return folder / "study.toml"


def environment() -> dict:
    return {**os.environ, "PYTHONPATH": os.pathsep.join(
        [str(ROOT), *filter(None, [os.environ.get("PYTHONPATH")])])}


def sweep_command(study: Path, out: Path, *engine: str) -> list[str]:
    return [sys.executable, "-m", "taichi_ndf.cli.sweep", str(study), "--out", str(out),
            *engine]


def comparable(rows: list[dict]) -> list[dict]:
    """The rows without the columns that differ between identical runs (times, memory)."""
    return [{k: v for k, v in r.items() if k not in TIMES} for r in rows]


@pytest.fixture(scope="module")
def pool_study(tmp_path_factory):
    """The study run on the local pool with 2 workers: (study file, its results rows)."""
    folder = tmp_path_factory.mktemp("pool")
    study = write_study(folder)
    assert sweep.main([str(study), "--out", str(folder / "out"), "--workers", "2"]) == 0
    return study, read_csv(folder / "out" / "results.csv")


def test_local_pool_sweep(pool_study):
    study, rows = pool_study
    out = study.parent / "out"
    assert [r["status"] for r in rows] == ["ok"] * 6
    assert rows[1]["point"] == "stiffness_scale-1.0_gravity-0.0,0.0,-4.9"
    assert rows[1]["loads.gravity"] == "[0.0, 0.0, -4.9]"
    energies = [float(r["energy_J"]) for r in rows]
    assert len(set(energies)) == 6 and all(e < 0 for e in energies)
    for r in rows:
        assert (out / "runs" / r["point"] / "result.json").is_file()
        assert r["seed"] == "7" and r["iterations"] == "3" and float(r["cpu_s"]) > 0
        assert float(r["peak_memory_MiB"]) > 50 and r["commit"] and r["machine"]
    assert (out / "summary.png").stat().st_size > 1000
    # Running it again does nothing: every run is finished.
    again = subprocess.run(sweep_command(study, out), capture_output=True, text=True,
                           env=environment(), timeout=600)
    assert again.returncode == 0 and "6 finished before (skipped), 0 to run" in again.stdout


def test_ray_gives_the_same_table(pool_study, tmp_path):
    pytest.importorskip("ray", reason="Ray is not installed (pip install 'taichi-ndf[ray]')")
    study, rows = pool_study
    # A head of its own, in its own session (stopped with its process group), listening on
    # 127.0.0.1 only: Ray replaces a loopback --node-ip-address by the machine's address
    # unless RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER=0 (read when ray is imported). A short session
    # folder: Ray's socket paths must fit in 107 bytes.
    session = tempfile.mkdtemp(prefix="ndf-ray-", dir="/tmp")
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    env = {**environment(), "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER": "0",
           "RAY_AUTH_MODE": "disabled"}  # no token: the head is reachable from here only
    ray_cli = Path(sys.executable).with_name("ray")
    head = subprocess.Popen([str(ray_cli), "start", "--head", "--block",
                             "--node-ip-address=127.0.0.1", f"--port={port}",
                             "--include-dashboard=false", "--disable-usage-stats",
                             "--num-cpus=2", f"--temp-dir={session}"],
                            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)
    try:
        done = subprocess.run(sweep_command(study, tmp_path / "out", "--ray",
                                            f"127.0.0.1:{port}"),
                              capture_output=True, text=True, env=env, timeout=1500)
    finally:
        os.killpg(head.pid, signal.SIGKILL)  # `ray start --block` ignores SIGTERM
        head.wait(timeout=60)
        shutil.rmtree(session, ignore_errors=True)
    assert done.returncode == 0, done.stderr[-2000:]
    assert comparable(read_csv(tmp_path / "out" / "results.csv")) == comparable(rows)


def default_sigint() -> None:
    """In the child: SIGINT as a terminal delivers it (a test run in the background of a
    non-interactive shell inherits SIGINT ignored, and so would its children)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def records(out: Path) -> list[Path]:
    """The finished runs' records, OUT/rows/NAME.json — not a record being written (its
    temporary, .NAME.*.partial.json, also matches pathlib's *.json)."""
    return [p for p in (out / "rows").glob("*.json") if not p.name.startswith(".")]


def wait_for_rows(out: Path, count: int, process: subprocess.Popen) -> None:
    deadline = time.monotonic() + 600
    while len(records(out)) < count:
        assert process.poll() is None, "the study ended before it was stopped"
        assert time.monotonic() < deadline
        time.sleep(0.2)


def test_stopped_and_killed_study_resumes_to_the_same_table(pool_study, tmp_path):
    study, rows = pool_study
    out = tmp_path / "out"
    # Ctrl-C (SIGINT to the process group, as a terminal sends it) after the first run.
    process = subprocess.Popen(sweep_command(study, out, "--workers", "2"), env=environment(),
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                               start_new_session=True, preexec_fn=default_sigint)
    wait_for_rows(out, 1, process)
    os.killpg(process.pid, signal.SIGINT)
    _, err = process.communicate(timeout=300)
    assert process.returncode == 130
    assert "interrupted;" in err and f"resume with: ndf-sweep {study} --out {out}" in err
    stopped = len(read_csv(out / "results.csv"))
    assert 1 <= stopped < 6
    # SIGKILL of the study and its runs (a machine that went down) after one more run.
    process = subprocess.Popen(sweep_command(study, out, "--workers", "2"), env=environment(),
                               stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
                               start_new_session=True)
    wait_for_rows(out, stopped + 1, process)
    os.killpg(process.pid, signal.SIGKILL)
    process.wait(timeout=60)
    killed = len(records(out))
    assert killed < 6, "the study finished before it was killed"
    resumed = subprocess.run(sweep_command(study, out, "--workers", "2"), capture_output=True,
                             text=True, env=environment(), timeout=900)
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    assert f"{killed} finished before (skipped), {6 - killed} to run" in resumed.stdout
    assert not list((out / "runs").glob("*.incomplete"))
    assert comparable(read_csv(out / "results.csv")) == comparable(rows)


def test_ctrl_c_between_a_runs_record_and_the_table_keeps_its_row(tmp_path, monkeypatch,
                                                                     capsys):
    """Ctrl-C that lands after a run's record (rows/NAME.json) is written but before the table
    kept the row: the interrupted study's results.csv still holds it (it was lost, 1 in ~3
    runs of the test above, when the signal came in that window)."""
    real_add = ResultsTable.add

    def add_then_interrupted(self, index, row):
        with atomic_path(self.rows_dir / f"{self.names[index]}.json") as path:
            path.write_text(json.dumps(row))
        raise KeyboardInterrupt

    monkeypatch.setattr(ResultsTable, "add", add_then_interrupted)
    study = tmp_path / "study.toml"
    study.write_text('job = "calibration"\n[[points]]\ncase = "strip"\nnoise = 0.01\nseed = 0\n'
                     '[[points]]\ncase = "strip"\nnoise = 0.02\nseed = 0\n')
    out = tmp_path / "out"
    assert sweep.main([str(study), "--out", str(out), "--workers", "1"]) == 130
    rows = read_csv(out / "results.csv")
    assert [r["point"] for r in rows] == ["case-strip_noise-0.01_seed-0"]
    assert rows[0]["status"] == "failed"
    assert "interrupted; 1 of 2 runs finished" in capsys.readouterr().err
    monkeypatch.setattr(ResultsTable, "add", real_add)
    assert sweep.main([str(study), "--out", str(out), "--workers", "1"]) == 0
    assert "1 finished before (skipped), 1 to run" in capsys.readouterr().out
    assert len(read_csv(out / "results.csv")) == 2


def test_a_failing_run_is_a_row_and_the_study_goes_on(tmp_path, capsys):
    # The calibration tool refuses seed 0 with noise (one line, exit 2) after its imports.
    study = tmp_path / "study.toml"
    study.write_text('job = "calibration"\n[[points]]\ncase = "strip"\nnoise = 0.01\nseed = 0\n'
                     '[[points]]\ncase = "strip"\nnoise = 0.02\nseed = 0\n')
    assert sweep.main([str(study), "--out", str(tmp_path / "out"), "--workers", "2"]) == 0
    rows = read_csv(tmp_path / "out" / "results.csv")
    assert [r["status"] for r in rows] == ["failed", "failed"]
    assert rows[0]["reason"].startswith("calibration_draw: error: --seed 0 is the noise-free")
    assert "2 failed" in capsys.readouterr().out
