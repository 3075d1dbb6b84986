"""The fixed cost of a run (issue 28): ndf-sim prints its result before it writes the outputs
(seconds of CPU: a render, a plot, a video), the pictures can be left out, and the napkin
demo prints its corner sag from the result handed over before the outputs."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from taichi_ndf.cli import sim
from tests.scripts import load_script

ROOT = Path(__file__).resolve().parents[1]
RUNTIME = ["--precision", "f64"]  # the test session's runtime (tests/conftest.py)
SCENE = ROOT / "scenes" / "membrane_stretch.toml"  # 5 Newton steps on 8 × 8 spans


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory, taichi_runtime):
    """ndf-sim --no-pictures on a small spline run, with what existed in the staging folder
    and what was printed when the result was handed over."""
    out = tmp_path_factory.mktemp("startup") / "run"
    seen = {}

    def on_result(result: dict) -> None:
        staging = out.parent / f"{out.name}.incomplete"
        seen["files"] = sorted(p.name for p in staging.iterdir())
        seen["result"] = result

    code = sim.main([str(SCENE), "--field", "spline", "--quick", "--no-pictures",
                     "--out", str(out), *RUNTIME], on_result=on_result)
    return code, out, seen


def test_the_result_is_handed_over_before_any_output_is_written(quick_run):
    code, out, seen = quick_run
    assert code == 0
    outputs = {"mesh.obj", "mesh.ply", "reference.obj", "probes.json", "render.png",
               "energy.png", "result.json"}
    assert not outputs & set(seen["files"]), seen["files"]
    written = json.loads((out / "result.json").read_text())
    for key in ("energy", "iterations", "wall_time", "probes", "refinement", "levels"):
        assert json.loads(json.dumps(seen["result"][key])) == written[key], key


def test_no_pictures_writes_the_meshes_and_result_only(quick_run):
    _, out, _ = quick_run
    names = {p.name for p in out.iterdir()}
    assert {"mesh.obj", "mesh.ply", "reference.obj", "probes.json", "checkpoint.pt",
            "result.json"} <= names
    assert not {"render.png", "energy.png", "trajectory.mp4"} & names


def test_the_pictures_are_written_by_default(tmp_path, capsys, taichi_runtime):
    out = tmp_path / "run"
    assert sim.main([str(SCENE), "--field", "spline", "--quick", "--out", str(out),
                     *RUNTIME]) == 0
    printed = capsys.readouterr()
    assert "membrane_stretch: Π =" in printed.out
    assert (out / "render.png").is_file() and (out / "energy.png").is_file()


def test_the_napkin_demo_prints_its_sag_from_the_handed_over_result(monkeypatch, capsys):
    demo = load_script("demos/napkin.py", "demo_napkin")
    result = {"energy": -1.6, "probes": {"free_corner": [-0.9, -0.9, -1.43]},
              "refinement": None}

    def fake_main(argv, *, on_result=None):
        on_result(result)  # what ndf-sim hands over before its outputs
        return 0

    monkeypatch.setattr(demo.sim, "main", fake_main)
    assert demo.main(["--out", "nowhere"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == demo.corner_sag(result)
    assert lines[0].startswith("free corner 1.4300 m below the pin")


def test_the_soft_shadow_is_the_full_resolution_blur_within_its_tolerance():
    import cv2
    import numpy as np

    from taichi_ndf.render.figure import soft_shadow

    coverage = np.zeros((600, 900))  # a 3x supersampled 200 x 300 image: a sheet's shadow
    rows, cols = np.mgrid[:600, :900]
    coverage[(rows - 350) ** 2 / 150**2 + (cols - 420) ** 2 / 300**2 < 1] = 1.0
    coverage[100:200, 600:700] = 1.0  # and a square
    sigma = 0.01 * 600
    full = cv2.GaussianBlur(coverage, (0, 0), sigma)
    soft = soft_shadow(coverage, sigma, 3)
    assert soft.shape == coverage.shape and soft.dtype == np.float64
    assert np.abs(soft - full).max() < 0.02  # of a shadow 0.35 deep: < 2 of 255 grey levels
    assert np.abs(soft - full).mean() < 1e-3
