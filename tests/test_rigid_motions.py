"""The check of the rigid motions the supports leave free (taichi_ndf.boundary.rigid_motions),
and tablecloth_box, whose free turn about z slid the spline solve into corner flaps."""

import logging
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh

from taichi_ndf.boundary.rigid_motions import (
    free_motions,
    rigid_motion_findings,
    warn_rigid_motions,
)
from taichi_ndf.scene.reader import load_scene

ROOT = Path(__file__).resolve().parents[1]
SCENES = ROOT / "scenes"
VALIDATION = ROOT / "validation" / "scenes"


def model_of(tmp_path, text: str):
    path = tmp_path / "scene.toml"
    path.write_text(text)
    return load_scene(path).model


def tablecloth_centre_only(tmp_path):
    """tablecloth_box as it was shipped: held at its centre only (xy)."""
    text = (SCENES / "tablecloth_box.toml").read_text()
    start = text.index("[[boundary.constraint]]  # the mirror line")
    end = text.index("[[obstacles]]")
    return model_of(tmp_path, text[:start] + text[end:])


def test_the_shipped_tablecloth_leaves_no_rigid_motion_without_stiffness():
    assert rigid_motion_findings(load_scene(SCENES / "tablecloth_box.toml").model) == []


def test_a_tablecloth_held_at_its_centre_only_turns_freely_about_z(tmp_path):
    """Centre held in-plane, a frictionless table: the table resists the vertical translation
    and the tilts, gravity does no work on a turn about the vertical, and the centre's held
    slope is a point's: one motion with no stiffness, named."""
    model = tablecloth_centre_only(tmp_path)
    basis, _, _ = free_motions(model.boundary, model.surface)
    assert basis.shape[1] == 4  # z translation, three rotations about the centre
    (finding,) = rigid_motion_findings(model)
    assert finding.kind == "no_stiffness"
    assert finding.motion == "the rotation about z through (0, 0, 0.005) m"
    assert rigid_motion_findings(model, newton=False) == []


def test_the_pinched_hemisphere_held_at_one_point_swings_about_x():
    """Four radial loads ±2 at radius 10 on the equator: M = Σ F xᵀ = diag(40, −40, 0), so the
    dead loads' potential along a rotation about k falls by ½ θ² (kᵀ M k − tr M): −40 J/rad²
    about x (the loads at φ = 0, π pull outwards along x); the held point's slope is all that
    holds it."""
    (finding,) = rigid_motion_findings(load_scene(VALIDATION / "pinched_hemisphere.toml").model)
    assert finding.kind == "second_order"
    assert finding.loads == ("the point loads",)
    assert finding.value == pytest.approx(-40.0, rel=1e-9)
    assert finding.motion.startswith("the rotation about x through (0, 2.185, 9.511)")
    assert "only a point's held slope holds" in finding.line()


FREE_SHEET = """
name = "free_sheet"
[geometry]
type = "plane"
bounds = [[0.0, 1.0], [0.0, 0.5]]
[material]
preset = "cloth"
[loads]
gravity = [0.0, 0.0, -9.81]
"""


def test_a_sheet_with_no_support_under_gravity_has_no_equilibrium(tmp_path):
    model = model_of(tmp_path, FREE_SHEET)
    (finding,) = [f for f in rigid_motion_findings(model) if f.kind == "work"]
    weight = model.material.areal_density * 9.81 * 0.5
    assert finding.motion == "the translation along z"
    assert finding.loads == ("gravity",)
    assert finding.value == pytest.approx(weight, rel=1e-9)
    assert "no equilibrium" in finding.line()


def test_clamped_and_hinged_supports_are_the_scenes_statement(tmp_path):
    """A clamped edge removes all six motions; the flag's hinged pole leaves the turn about
    the pole free, which its wind and gravity choose (as stated: no finding)."""
    clamped = FREE_SHEET + '[[boundary.constraint]]\ntype = "clamped_edge"\nedge = "xi1_min"\n'
    model = model_of(tmp_path, clamped)
    assert free_motions(model.boundary, model.surface)[0].shape[1] == 0
    assert rigid_motion_findings(model) == []
    flag = load_scene(SCENES / "flag.toml").model
    assert free_motions(flag.boundary, flag.surface)[0].shape[1] == 1
    assert rigid_motion_findings(flag) == []


def test_the_warning_is_one_line_per_motion(tmp_path, caplog):
    model = tablecloth_centre_only(tmp_path)
    with caplog.at_level(logging.WARNING, logger="taichi_ndf.boundary.rigid_motions"):
        lines = warn_rigid_motions(model)
    assert len(lines) == 1 and "\n" not in lines[0]
    assert [r.getMessage() for r in caplog.records] == lines


# The physical check of tablecloth_box: a point of the cloth hangs below the table top at most
# its reference distance to the flat part of the top (the box's half extents less the 3 cm
# rounding: what lies beyond it has to run over the rounded edge) plus the 5 mm it starts
# above the top; the cloth stretches under its own weight by far less than the 1 % allowed.
# A cloth that slid or turned on the table breaks it (the f32 solve on main: 0.163 m too deep;
# the scene held on its mirror line: 9.8 mm to spare in f32 and f64).
TABLE_HALF = (0.37, 0.27)


def sag_excess(run: Path) -> float:
    """The largest depth [m] of a vertex below the table top beyond what its reference
    distance to the flat part of the top allows (≤ 0: physical)."""
    ref = trimesh.load(run / "reference.obj", process=False).vertices
    cur = trimesh.load(run / "mesh.obj", process=False).vertices
    outside = np.maximum(np.abs(ref[:, :2]) - np.asarray(TABLE_HALF), 0.0)
    allowed = 1.01 * np.linalg.norm(outside, axis=1) + 0.005
    return float((-cur[:, 2] - allowed).max())


def run_tablecloth(out: Path, precision: str) -> dict:
    import json

    env = dict(os.environ, PYTHONPATH=str(ROOT))
    done = subprocess.run(
        [sys.executable, "-m", "taichi_ndf.cli.sim", str(SCENES / "tablecloth_box.toml"),
         "--field", "spline", "--precision", precision, "--out", str(out)],
        env=env, capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stderr[-2000:]
    return json.loads((out / "result.json").read_text())


@pytest.mark.slow
def test_tablecloth_on_the_spline_path_is_one_physical_answer_in_f32_and_f64(tmp_path):
    """Measured (13 × 10 spans): f32 −0.02311157 J, f64 −0.02311157 J (1.4e-7 relative), both
    converged, the top turned 0.000°, 9.8 mm to spare on the sag check; on main the f32 solve
    slid to −0.045159 J with the cloth turned 44.8° (0.163 m too deep), f64 stayed at
    −0.02310496 J on the saddle. On the polyester preset (scene since fde2b08; measured
    2026-12-06 on 286b6f6): f32 −0.0092764403 J, f64 −0.0092764435 J (3.5e-7 relative), 56 / 61
    iterations, 8.8 mm to spare in both."""
    results = {p: run_tablecloth(tmp_path / p, p) for p in ("f32", "f64")}
    energies = [results[p]["energy"] for p in ("f32", "f64")]
    assert math.isclose(*energies, rel_tol=1e-4), energies
    for p in ("f32", "f64"):
        assert sag_excess(tmp_path / p) <= 0.0, p
        assert all(level["converged"] for level in results[p]["levels"]), p
