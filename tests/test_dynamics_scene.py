"""The `[dynamics]` section of a scene (`taichi_ndf.scene.dynamics`) and `ndf-sim` on it: the
keys into a `DynamicsConfig`, bad values and unsupported combinations refused in one line
(exit 2), and a run that writes physical time, the energies and the trajectory's frames."""

from __future__ import annotations

import copy
import json
import math
from pathlib import Path

import pytest

from taichi_ndf.cli import sim
from taichi_ndf.io.run_files import read_run
from taichi_ndf.problem.dynamics import DynamicsConfig
from taichi_ndf.scene.reader import parse_scene
from taichi_ndf.scene.schema import SceneError

RUNTIME = ["--arch", "cpu", "--precision", "f64", "--threads", "1"]

SCENE = """name = "drop"
[geometry]
type = "plane"
bounds = [[0.0, 1.0], [0.0, 0.2]]
[material]
type = "linear"
young_modulus = 1e6
poisson_ratio = 0.3
thickness = 1e-3
areal_density = 0.2
[loads]
gravity = [0.0, 0.0, -9.81]
[boundary]
length = 2.0
[[boundary.constraint]]
type = "clamped_edge"
edge = "xi1_min"
[field]
type = "spline"
spans = [4, 1]
[training]
method = "newton"
[dynamics]
integrator = "implicit_euler"
dt = 0.005
duration = 0.02
frame_rate = 100
mass_damping = 0.5
[output]
resolution = [8, 2]
[[probes]]
name = "tip"
xi = [1.0, 0.1]
"""

DOCUMENT = {
    "name": "strip",
    "geometry": {"type": "plane", "bounds": [[0.0, 1.0], [0.0, 0.2]]},
    "material": {"type": "linear", "young_modulus": 1e6, "poisson_ratio": 0.3,
                 "thickness": 1e-3, "areal_density": 0.2},
    "field": {"type": "spline", "spans": [4, 1]},
    "training": {"method": "newton"},
    "dynamics": {"dt": 0.01, "duration": 0.1},
}


def parse(document):
    return parse_scene(copy.deepcopy(document), base_dir=Path("."))


def test_the_keys_make_the_config():
    assert parse(DOCUMENT).dynamics == DynamicsConfig(dt=0.01, duration=0.1)
    document = copy.deepcopy(DOCUMENT)
    document["dynamics"].update(integrator="implicit_euler", frame_rate=25.0,
                                mass_damping=0.3, stiffness_damping=0.01, load_ramp=0.05,
                                halvings=2)
    assert parse(document).dynamics == DynamicsConfig(
        dt=0.01, duration=0.1, integrator="implicit_euler", frame_rate=25.0,
        mass_damping=0.3, stiffness_damping=0.01, load_ramp=0.05, halvings=2)
    del document["dynamics"]
    assert parse(document).dynamics is None


@pytest.mark.parametrize("change, message", [
    ({"dt": 0.0}, r"dynamics.dt: must be > 0"),
    ({"dt": None}, r"dynamics.dt: required key is missing"),
    ({"duration": 0.105}, r"dynamics: duration .* whole number of steps"),
    ({"integrator": "rk4"}, r"dynamics.integrator: must be one of"),
    ({"mass_damping": -0.1}, r"dynamics.mass_damping: must be >= 0"),
    ({"frame_rate": 1000.0}, r"dynamics: frame_rate .* more than one frame per step"),
    ({"stiffness_damping": -0.1}, r"dynamics.stiffness_damping: must be >= 0"),
    ({"load_ramp": -1.0}, r"dynamics.load_ramp: must be >= 0"),
    ({"step": 0.1}, r"dynamics: unknown key\(s\) 'step'"),
])
def test_bad_values_name_the_key(change, message):
    document = copy.deepcopy(DOCUMENT)
    document["dynamics"].update(change)
    document["dynamics"] = {k: v for k, v in document["dynamics"].items() if v is not None}
    with pytest.raises(SceneError, match=message):
        parse(document)


def test_a_siren_field_and_stiffness_damping_with_obstacles_are_refused():
    document = copy.deepcopy(DOCUMENT)
    document["field"] = {"width": 16, "hidden_layers": 1}
    document["training"] = {}
    with pytest.raises(SceneError, match="dynamics: needs a spline field"):
        parse(document)
    document = copy.deepcopy(DOCUMENT)
    document["loads"] = {"gravity": [0.0, 0.0, -9.81]}
    document["obstacles"] = [{"type": "sphere", "name": "ball", "centre": [0.5, 0.1, -0.2],
                              "radius": 0.1}]
    parse(document)  # obstacles with mass damping: solved with contact in every step
    document["dynamics"]["stiffness_damping"] = 1e-3
    with pytest.raises(SceneError, match=r"dynamics: stiffness_damping with contact"):
        parse(document)


def test_ndf_sim_writes_time_energies_and_frames(tmp_path, capsys):
    scene = tmp_path / "drop.toml"
    scene.write_text(SCENE)
    out = tmp_path / "run"
    assert sim.main([str(scene), "--out", str(out), "--no-pictures", *RUNTIME]) == 0
    result = json.loads((out / "result.json").read_text())
    dynamics = result["dynamics"]
    assert result["time"] == pytest.approx(0.02)
    assert dynamics["times"] == pytest.approx([0.0, 0.005, 0.01, 0.015, 0.02])
    assert dynamics["integrator"] == "implicit_euler" and dynamics["mass_damping"] == 0.5
    assert result["trajectory"]["times"] == pytest.approx([0.0, 0.01, 0.02])
    assert sorted(p.name for p in (out / "trajectory").iterdir()) == [
        "step_000.obj", "step_001.obj", "step_002.obj"]
    assert (out / "mesh.obj").is_file() and not (out / "render.png").exists()
    # from rest under gravity: the energy only falls (implicit Euler and damping dissipate)
    total = dynamics["total"]
    assert total[0] == 0.0 and all(b < a for a, b in zip(total[:-1], total[1:], strict=True))
    # early on the strip falls nearly freely: the tip near −½ g t², never below
    tip = result["probes"]["tip"][2]
    assert -0.5 * 9.81 * 0.02**2 * 1.5 < tip < 0.0
    assert all(math.isfinite(c) and c > 0 for c in (dynamics["cpu_per_step"],
                                                     dynamics["cpu_per_simulated_second"]))
    assert "drop: Π =" in capsys.readouterr().out
    run = read_run(out)  # what ndf-render, ndf-view and ndf-export read: a frame per time
    assert [f.load_factor for f in run.frames] == pytest.approx([0.0, 0.01, 0.02])


def test_ndf_sim_refuses_in_one_line(tmp_path, capsys):
    scene = tmp_path / "drop.toml"
    scene.write_text(SCENE)
    for extra, message in ((["--field", "siren"], "dynamics: needs a spline field"),
                           (["--refine", "2"], "--refine: a dynamic run"),
                           (["--tolerance", "1e-3"], "--tolerance: a dynamic run"),
                           (["--set", "dynamics.dt=-1"], "dynamics.dt: must be > 0")):
        assert sim.main([str(scene), "--out", str(tmp_path / "x"), *extra, *RUNTIME]) == 2
        err = capsys.readouterr().err.strip()
        assert message in err and "\n" not in err


def test_ndf_sim_writes_usd_time_codes_at_the_output_rate(tmp_path):
    """[output] usd = true on a dynamic run: result.usdc's frames at time codes t × 100
    (frame_rate 100 /s as time codes and frames per second), ndf:time the frames' t [s]."""
    pytest.importorskip("pxr")
    from pxr import Usd

    scene = tmp_path / "drop.toml"
    scene.write_text(SCENE.replace("resolution = [8, 2]", "resolution = [8, 2]\nusd = true"))
    out = tmp_path / "run"
    assert sim.main([str(scene), "--out", str(out), "--no-pictures", *RUNTIME]) == 0
    stage = Usd.Stage.Open(str(out / "result.usdc"))
    assert stage.GetTimeCodesPerSecond() == pytest.approx(100.0)
    assert stage.GetFramesPerSecond() == pytest.approx(100.0)
    assert (stage.GetStartTimeCode(), stage.GetEndTimeCode()) == pytest.approx((0.0, 2.0))
    deformed = stage.GetPrimAtPath("/World/deformed")
    times = deformed.GetAttribute("ndf:time")
    assert times.GetTimeSamples() == pytest.approx([0.0, 1.0, 2.0])
    assert [times.Get(c) for c in (0.0, 1.0, 2.0)] == pytest.approx([0.0, 0.01, 0.02])
    points = deformed.GetAttribute("points")
    last = [line.split()[1:4] for line in (out / "trajectory" / "step_002.obj").read_text()
            .splitlines() if line.startswith("v ")]
    assert list(points.Get(2.0)[-1]) == pytest.approx([float(v) for v in last[-1]], rel=1e-6)
