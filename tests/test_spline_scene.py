"""Spline scenes end to end: the [field] type = "spline" / [training] method = "newton" keys,
`ndf-sim --field spline` and `--refine K`, the checkpoint per level (resume, export)."""

from __future__ import annotations

import dataclasses
import json
import re

import numpy as np
import pytest
import torch

from taichi_ndf.cli import export, sim
from taichi_ndf.problem.spline_grid import SplinePlan, grid_spans
from taichi_ndf.scene.reader import load_scene
from taichi_ndf.scene.schema import SceneError
from taichi_ndf.solve.spline_solver import newton_config

RUNTIME = ["--precision", "f64"]

# A strip clamped at one end, bent by gravity.
STRIP = """
name = "strip"
[geometry]
type = "plane"
bounds = [[0.0, 2.0], [0.0, 1.0]]
[material]
type = "linear"
young_modulus = 1.0e7
poisson_ratio = 0.3
thickness = 0.05
areal_density = 1.0
[loads]
gravity = [0.0, 0.0, -9.81]
[boundary]
length = 0.5
[[boundary.constraint]]
type = "clamped_edge"
edge = "xi1_min"
{field}
{training}
[[probes]]
name = "tip"
xi = [2.0, 0.5]
[output]
resolution = [8, 8]
"""

SPLINE = '[field]\ntype = "spline"\nspans = [4, 2]\nlevels = 2'
NEWTON = "[training]\nload_steps = [0.5, 1.0]"


def write(tmp_path, field=SPLINE, training=NEWTON, name="strip.toml"):
    path = tmp_path / name
    path.write_text(STRIP.format(field=field, training=training))
    return path


def test_a_spline_scene_reads_its_grid_and_defaults_to_newton(tmp_path):
    scene = load_scene(write(tmp_path))
    assert isinstance(scene.field, SplinePlan)
    assert scene.field.config.spans == (4, 2) and scene.field.levels == 2
    assert scene.field.config.degree == 3 and scene.field.quadrature_points == 4
    assert scene.solver.method == "newton" and scene.solver.load_steps == (0.5, 1.0)
    assert scene.quick_solver.max_levels == 1
    auto = load_scene(write(tmp_path, field='[field]\ntype = "spline"\ndegree = 4'))
    assert auto.field.config.spans == grid_spans(auto.model.surface, 0.05, 0.5) == (8, 4)
    assert auto.field.config.degree == 4 and auto.field.quadrature_points == 5
    sized = load_scene(write(tmp_path, field='[field]\ntype = "spline"\nspan_length = 0.3'))
    assert sized.field.config.spans == (7, 4)


@pytest.mark.parametrize("field, training, message", [
    ('[field]\ntype = "spline"\nomega0 = 3.0', "", "field.omega0: a SIREN key"),
    ("[field]\nlevels = 2", "", "field.levels: a spline key"),
    ('[field]\ntype = "spline"\ndegree = 5', "", "field.degree: must be 3"),
    ('[field]\ntype = "spline"\nspans = [2, 0]', "", "field.spans: expected two integers"),
    ('[field]\ntype = "spline"\nspans = [2, 2]\nspan_length = 0.1', "", "not both"),
    ('[field]\ntype = "spline"\nspan_length = -1', "", "field.span_length"),
    ('[field]\ntype = "bezier"', "", "field.type: must be one of"),
    ("", '[training]\nmethod = "newton"', "training.method: \"newton\" (projected Newton) "
     "needs [field] type = \"spline\""),
    (SPLINE, "[training]\niterations = 100", "training.iterations: not used by method = "
     "\"newton\""),
    (SPLINE, '[training]\nmethod = "adam"\npseudo_time = true', "training.pseudo_time"),
    (SPLINE, "[training]\nnewton_tolerance = 0", "training.newton_tolerance: expected a "
     "number in (0, 1)"),
])
def test_wrong_spline_and_newton_keys_are_named(tmp_path, field, training, message):
    with pytest.raises(SceneError, match=re.escape(message)):
        load_scene(write(tmp_path, field=field, training=training))


def test_newton_tolerance_loosens_only_the_decrement_tolerance(tmp_path):
    scene = load_scene(write(tmp_path, training="[training]\nnewton_tolerance = 1e-4"))
    assert scene.solver.newton_tolerance == 1e-4
    loose = newton_config(scene.solver, torch.float64)
    default = newton_config(load_scene(write(tmp_path)).solver, torch.float64)
    assert loose.decrement_tolerance == 1e-4 and default.decrement_tolerance == 1e-12
    assert dataclasses.replace(loose, decrement_tolerance=1e-12) == default
    # float32: a tolerance tighter than its rounding floor leaves the floor
    assert newton_config(scene.solver, torch.float32).decrement_tolerance == 1e-4
    assert newton_config(dataclasses.replace(scene.solver, newton_tolerance=1e-9),
                         torch.float32).decrement_tolerance == 1e-7


def test_field_switch_keeps_load_steps_and_seed(tmp_path):
    siren = write(tmp_path, field="[field]\nwidth = 16",
                  training="[training]\niterations = 10\nload_steps = [0.5, 1.0]\nseed = 3")
    scene = load_scene(siren, field="spline")
    assert isinstance(scene.field, SplinePlan) and scene.solver.method == "newton"
    assert scene.solver.load_steps == (0.5, 1.0) and scene.solver.seed == 3
    assert scene.document["field"] == {"type": "spline"}
    assert load_scene(siren, field="siren").document == load_scene(siren).document


def test_field_switch_solves_a_pseudo_time_path_at_its_frames(tmp_path):
    path = write(tmp_path, field="[field]\nwidth = 16", training="[training]\n"
                 "iterations = 10\npseudo_time = true\npseudo_time_start = 0.2")
    path.write_text(path.read_text() + "frames = 5\n")
    assert load_scene(path).output.frames == 5
    scene = load_scene(path, field="spline")
    assert isinstance(scene.field, SplinePlan) and scene.solver.method == "newton"
    assert scene.solver.load_steps == pytest.approx((0.2, 0.4, 0.6, 0.8, 1.0))
    assert scene.output.frames is None and "frames" not in scene.document["output"]


def test_sim_solves_a_spline_scene_on_refined_grids_and_resumes_and_exports(tmp_path,
                                                                             capsys):
    out = tmp_path / "run"
    assert sim.main([str(write(tmp_path)), "--out", str(out), "--refine", "3", *RUNTIME]) == 0
    result = json.loads((out / "result.json").read_text())
    for name in ("mesh.obj", "mesh.ply", "render.png", "energy.png", "checkpoint.pt",
                 "probes.json", "trajectory.mp4"):
        assert (out / name).is_file(), name
    assert [lv["spans"] for lv in result["levels"]] == [[4, 2], [8, 4], [16, 8]]
    assert all(lv["converged"] for lv in result["levels"])
    refinement = result["refinement"]
    energies = refinement["energy"]["values"]
    assert energies == [lv["energy"] for lv in result["levels"]]
    assert energies[0] > energies[1] > energies[2]  # a finer grid, a lower minimum
    assert refinement["energy"]["extrapolated"] <= energies[2]
    tip = refinement["probes"]["tip"][2]  # the tip's deflection per level, converging
    v = tip["values"]
    assert v[2] < 0 and abs(v[2] - v[1]) < abs(v[1] - v[0])
    assert tip["estimated_error"] < 0.05 * abs(v[2])
    history = result["history"]
    assert {"energy", "decrement", "step_length", "time_hessian", "time_assembly",
            "time_solve", "level", "load_factor"} <= set(history[0])
    assert [h["iteration"] for h in history] == list(range(len(history)))
    assert result["iterations"] == len(history)
    assert result["probes"]["tip"] == result["levels"][-1]["probes"]["tip"]
    assert result["trajectory"]["load_factors"] == [0.5, 1.0]

    # --resume of a finished run re-solves its finest grid: one converged Newton step, and
    # the strip (no singular feature) the probe stop's one more (`GridLevels._probe_stop`).
    assert sim.main([str(write(tmp_path)), "--out", str(out), "--refine", "3", "--resume",
                     *RUNTIME]) == 0
    resumed = json.loads((out / "result.json").read_text())
    assert resumed["levels"][:2] == result["levels"][:2]
    assert resumed["energy"] == pytest.approx(result["energy"], rel=1e-10)
    assert resumed["history"][:-2] == history and len(resumed["history"]) == len(history) + 2

    # The checkpoint holds the finest spline field: ndf-export reproduces the run's mesh.
    mesh = tmp_path / "same.obj"
    assert export.main([str(out / "checkpoint.pt"), "--resolution", "8", "--out", str(mesh),
                        *RUNTIME]) == 0

    def vertices(path):
        return np.loadtxt([ln for ln in path.read_text().splitlines() if ln.startswith("v ")],
                          usecols=(1, 2, 3))
    np.testing.assert_allclose(vertices(mesh), vertices(out / "mesh.obj"), atol=1e-9)


def test_two_grids_say_order_assumed_and_bar_the_whole_change(tmp_path, capsys):
    """Issue 35: a two-grid Richardson value must say that its order was assumed (console and
    result.json) and its bar must be the change between the grids, not the assumed-order
    correction (15× smaller on the napkin, where it missed the 32 × 32 value)."""
    out = tmp_path / "two"
    assert sim.main([str(write(tmp_path)), "--out", str(out), "--refine", "2", *RUNTIME]) == 0
    printed = capsys.readouterr().out
    energy = json.loads((out / "result.json").read_text())["refinement"]["energy"]
    assert energy["order_basis"] == "assumed" and energy["grids"] == 2
    change = abs(energy["values"][1] - energy["values"][0])
    assert energy["estimated_error"] == pytest.approx(change, rel=1e-12)
    assert "order 4 assumed from 2 grids" in energy["text"]
    assert "order 4 assumed from 2 grids" in printed and "Π →" in printed
    # and every probe: the flag's --refine 2 probe bar was 15× smaller than its change
    tip = json.loads((out / "result.json").read_text())["refinement"]["probes"]["tip"][2]
    assert tip["order_basis"] == "assumed"
    assert tip["estimated_error"] == pytest.approx(abs(tip["values"][1] - tip["values"][0]),
                                                   rel=1e-12)
    assert tip["estimated_error"] > 0


def test_refine_without_a_count_solves_three_grids_with_the_observed_order(tmp_path):
    out = tmp_path / "three"
    assert sim.main([str(write(tmp_path)), "--out", str(out), "--refine", *RUNTIME]) == 0
    refinement = json.loads((out / "result.json").read_text())["refinement"]
    assert len(refinement["spans"]) == 3
    energy = refinement["energy"]
    assert energy["order_basis"] in ("observed", "unreliable")
    if energy["order_basis"] == "unreliable":  # said so in result.json's text
        assert "order unreliable" in energy["text"] and energy["order_reason"]


@pytest.mark.parametrize("args, message", [
    (["--iters", "5"], "--iterations and --samples set Adam"),
    (["--refine", "0"], "--refine must be >= 1"),
])
def test_sim_refuses_adam_options_for_newton(tmp_path, capsys, args, message):
    assert sim.main([str(write(tmp_path)), "--out", str(tmp_path / "x"), *args, *RUNTIME]) == 2
    assert message in capsys.readouterr().err


def test_refine_needs_a_spline_field(tmp_path, capsys):
    siren = write(tmp_path, field="[field]\nwidth = 16", training="[training]\niterations = 2")
    assert sim.main([str(siren), "--out", str(tmp_path / "x"), "--refine", "2", *RUNTIME]) == 2
    assert "--refine needs a spline field" in capsys.readouterr().err


def test_validate_runs_a_case_with_the_spline_path(tmp_path, capsys):
    from taichi_ndf.cli import validate

    out = tmp_path / "val"
    assert validate.main(["square_plate", "--field", "spline", "--quick", "--out", str(out),
                          *RUNTIME]) == 0
    printed = capsys.readouterr().out
    assert "square_plate w_centre @ 1" in printed
    result = json.loads((out / "results.json").read_text())
    case = result["cases"]["square_plate"]
    # issue 35: the spline path wrote "source": "" for every row
    assert all(row["source"].startswith("Navier series") for row in result["rows"]), result["rows"]
    assert case["solver"]["method"] == "newton" and case["solver"]["spans"] == [[8, 8]]
    assert (out / "square_plate_convergence.png").is_file()
