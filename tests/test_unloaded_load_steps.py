"""A scene whose load steps move nothing (no load acts: every Newton step starts at its
equilibrium, so no iteration is recorded) runs to its outputs with Π = 0 at every load step,
instead of failing while it writes the trajectory (issue 28's finding: `ndf-sim
validation/scenes/cantilever_moment.toml --field spline` raised StopIteration — its end moment
is added by `ndf-validate` only)."""

from __future__ import annotations

import json

from taichi_ndf.cli import sim
from tests.test_spline_scene import STRIP


def test_load_steps_without_a_load_write_their_trajectory(tmp_path):
    scene = tmp_path / "unloaded.toml"
    scene.write_text(STRIP.format(field='[field]\ntype = "spline"\nspans = [4, 2]',
                                  training="[training]\nload_steps = [0.5, 1.0]")
                     .replace("gravity = [0.0, 0.0, -9.81]", "gravity = [0.0, 0.0, 0.0]"))
    out = tmp_path / "out"
    code = sim.main([str(scene), "--precision", "f64", "--no-pictures", "--out", str(out)])
    assert code == 0
    result = json.loads((out / "result.json").read_text())
    assert result["energy"] == 0.0 and result["iterations"] == 0
    assert result["trajectory"]["load_factors"] == [0.5, 1.0]
    assert result["trajectory"]["energy"] == [0.0, 0.0]
