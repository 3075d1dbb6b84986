"""Sizes a scene or a command line sets are checked against the memory they imply before any
work (`taichi_ndf.problem.run_size`): refused in one line with the estimate, exit code 2."""

from __future__ import annotations

import time
from pathlib import Path

import pytest
from test_cli import SMALL_NAPKIN, run_sim, write_scene

from taichi_ndf.problem.run_size import BYTES_PER_GAUSS_POINT, spline_gauss_points
from taichi_ndf.scene.reader import load_scene

SPLINE = SMALL_NAPKIN.replace("width = 16", 'type = "spline"\n{field}').replace(
    "[training]\niterations = 10\nsamples = 256\nlearning_rate = {lr}\nmonitor_every = 5\n"
    "monitor_samples = 512\ncheckpoint_every = 5", '[training]\nmethod = "newton"')
SPHERE = """[[obstacles]]
type = "sphere"
centre = [0.5, 0.5, -0.3]
radius = 0.2
[contact]
check_resolution = {resolution}
"""


def spline_scene(tmp_path: Path, field: str, extra: str = "") -> Path:
    return write_scene(tmp_path, SPLINE.format(field=field) + extra)


@pytest.mark.parametrize("field, extra", [
    ("spans = [10000, 10000]", ""),
    ("spans = [2000, 2000]", ""),
    ("spans = [8, 8]\nlevels = 20", ""),
    ("span_length = 1e-5", ""),
    ("spans = [8, 8]", SPHERE.format(resolution=1000000)),
], ids=["spans_10000", "spans_2000", "levels_20", "span_length_1e-5", "check_resolution_1e6"])
def test_absurd_sizes_are_refused_in_one_line_before_any_work(tmp_path, capsys, field, extra):
    scene = spline_scene(tmp_path, field, extra)
    started = time.perf_counter()
    assert run_sim(scene, "--out", tmp_path / "run") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "needs about" in err[0] and "this machine's" in err[0], err
    assert time.perf_counter() - started < 30  # refused before the runtime or a solve
    assert not (tmp_path / "run").exists() and not (tmp_path / "run.incomplete").exists()


def test_refine_30_and_a_huge_siren_are_refused(tmp_path, capsys):
    scene = spline_scene(tmp_path, "spans = [8, 8]")
    assert run_sim(scene, "--out", tmp_path / "a", "--refine", "30") == 2
    assert "30 levels" in capsys.readouterr().err
    wide = write_scene(tmp_path, SMALL_NAPKIN.format(lr=1e-3).replace("width = 16",
                                                                      "width = 100000"), "w.toml")
    assert run_sim(wide, "--out", tmp_path / "b") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "SIREN field 100000 wide" in err[0], err
    assert run_sim(write_scene(tmp_path, SMALL_NAPKIN.format(lr=1e-3), "s.toml"), "--out",
                   tmp_path / "c", "--samples", str(10**9)) == 2
    assert "on 1000000000 samples" in capsys.readouterr().err


def test_the_estimate_counts_the_finest_grid_and_the_check_points(tmp_path, monkeypatch,
                                                                   caplog):
    scene = spline_scene(tmp_path, "spans = [8, 4]\nlevels = 3", SPHERE.format(resolution=10))
    plan = load_scene(scene).field
    assert spline_gauss_points(plan) == (8 * 4) * (4 * 4) * 16
    need = (spline_gauss_points(plan) + 10 * 10) * BYTES_PER_GAUSS_POINT
    monkeypatch.setattr("taichi_ndf.problem.run_size.physical_memory", lambda: need - 1)
    with pytest.raises(ValueError, match="32 × 16 spans .* check grid of 10² points"):
        load_scene(scene)
    monkeypatch.setattr("taichi_ndf.problem.run_size.physical_memory", lambda: need)
    monkeypatch.setattr("taichi_ndf.problem.run_size.available_memory", lambda: need - 1)
    load_scene(scene)  # more than is available now: a warning, not a refusal
    assert "more than the" in caplog.text and "available now" in caplog.text
