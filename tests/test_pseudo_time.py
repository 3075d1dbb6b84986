"""Pseudo-time fields: one field u(ξ, t) trained over all load factors t at once gives the
quasistatic path; prescribed motions follow g(t) exactly; scene keys are checked strictly."""

from __future__ import annotations

import dataclasses
import math
import tomllib
from pathlib import Path

import numpy as np
import pytest
import torch

from taichi_ndf.app.outputs import deformed_mesh
from taichi_ndf.field import NeuralField
from taichi_ndf.problem.loads import Loads
from taichi_ndf.problem.pseudo_time import (
    POINT_REPEATS,
    conditioning,
    frame_times,
    samples_over_time,
)
from taichi_ndf.problem.sampling import sample_surface, stratified_uniform
from taichi_ndf.scene.reader import load_scene, parse_scene
from taichi_ndf.scene.schema import SceneError
from taichi_ndf.solve.solver import Solver

ROOT = Path(__file__).resolve().parents[1]
SCENES = ROOT / "scenes"


def document(name: str) -> dict:
    return tomllib.loads((SCENES / f"{name}.toml").read_text())


def stretch_energy(t: float) -> float:
    """Exact Π of membrane_stretch.toml at load factor t: uniform stretch λ = 1 + 0.2 t."""
    return 0.5 * 100.0 * (0.5 * ((1 + 0.2 * t) ** 2 - 1)) ** 2


@pytest.fixture(scope="module")
def stretch_path():
    doc = document("membrane_stretch")
    doc["training"].update(pseudo_time=True, iterations=600)
    scene = parse_scene(doc, base_dir=SCENES)
    field = NeuralField(scene.field, seed=0)
    solver = Solver(scene.model, field, dataclasses.replace(scene.solver, progress=False))
    return scene, solver, solver.run()


def test_pseudo_time_field_follows_the_exact_path(stretch_path):
    # membrane_stretch.toml has the exact solution u = 0.2 t x e_x at every load factor t, the
    # ordinary solve reaches Π(1) within 1 % (test_simulation). Measured here after 600
    # iterations over t ∈ [0, 1] (f64): Π within 1.0 % at t = 1, 0.9 % at t = 0.5, 1.8 % at
    # t = 0.25 (Π(0.25) is 18x smaller); probe errors ≤ 3.6e-3 m.
    scene, solver, result = stretch_path
    assert result.energy == pytest.approx(stretch_energy(1.0), rel=0.02)
    fresh = solver._samples(32768, torch.Generator().manual_seed(12345))
    for t in (1.0, 0.5):
        energy = solver.energy_and_gradient(fresh, t, grad=False).total
        assert energy == pytest.approx(stretch_energy(t), rel=0.02), t
        probes = solver.probe_displacements(t)
        for probe in scene.model.probes:
            np.testing.assert_allclose(probes[probe.name], [0.2 * t * probe.xi[0], 0.0, 0.0],
                                       rtol=0, atol=0.004, err_msg=f"{probe.name} at t={t}")
    # The path is not the final state everywhere: half the load, about half the displacement.
    half = solver.probe_displacements(0.5)["centre"][0]
    assert half == pytest.approx(0.05, abs=0.004)


def test_prescribed_motion_follows_g_of_t_at_the_boundary(stretch_path):
    scene, solver, _ = stretch_path
    y = torch.linspace(0.0, 1.0, 11, dtype=torch.float64)
    moved = torch.stack((torch.ones_like(y), y), 1)
    held = torch.stack((torch.zeros_like(y), y), 1)
    for t in (0.0, 0.37, 1.0):
        for xi, expected in ((moved, [0.2 * t, 0.0, 0.0]), (held, [0.0, 0.0, 0.0])):
            cond = conditioning(t, len(xi), dtype=torch.float64)
            u = scene.model.displacement(solver.field, xi, t=t, conditioning=cond)
            np.testing.assert_allclose(u.numpy(), np.tile(expected, (len(xi), 1)), rtol=0,
                                       atol=1e-14)


def test_rim_of_the_shipped_path_scene_turns_by_t_times_the_angle():
    scene = load_scene(SCENES / "sleeve_twist_path.toml")
    field = NeuralField(dataclasses.replace(scene.field, width=16), seed=1)  # any field
    theta = torch.linspace(0.0, 2 * math.pi, 9, dtype=torch.float64)[:-1]
    rim = torch.stack((theta, torch.full_like(theta, 0.4)), 1)
    for t in (0.0, 0.5, 1.0):
        cond = conditioning(t, len(rim), dtype=torch.float64)
        u = scene.model.displacement(field, rim, t=t, conditioning=cond).numpy()
        angle = t * math.pi / 2
        c, s = math.cos(angle), math.sin(angle)
        x, y = 0.1 * np.cos(theta.numpy()), 0.1 * np.sin(theta.numpy())
        expected = np.stack((c * x - s * y - x, s * x + c * y - y, 0 * x), 1)
        np.testing.assert_allclose(u, expected, rtol=0, atol=1e-14, err_msg=f"t={t}")


def test_the_path_starts_at_rest():
    """t = 0: no load, no prescribed motion, so the equilibrium is the reference; the operator
    multiplies a pseudo-time field's output by t, so the first frame is at rest exactly for
    any weights (on main the trained sleeve_twist_path's first frame moved 16.5 mm)."""
    scene = load_scene(SCENES / "sleeve_twist_path.toml")
    assert scene.field.pseudo_time
    field = NeuralField(dataclasses.replace(scene.field, width=16), seed=1)  # any field
    first = deformed_mesh(scene.model, field, (24, 12), load_factor=0.0, pseudo_time=True)
    assert float(np.abs(first.deformed - first.reference).max()) == 0.0
    later = deformed_mesh(scene.model, field, (24, 12), load_factor=0.5, pseudo_time=True)
    assert float(np.abs(later.deformed - later.reference).max()) > 1e-3


def test_samples_over_time_are_stratified_and_average_point_loads():
    scene = load_scene(SCENES / "membrane_stretch.toml")
    loads = Loads(point_loads=[((0.5, 0.5), (0.0, 0.0, -2.0)), ((0.2, 0.9), (1.0, 0.0, 0.0))])
    gen = torch.Generator().manual_seed(0)
    samples = sample_surface(scene.model.surface, 64, loads, gen)
    spread, t = samples_over_time(samples, 0.2, 0.6, gen)
    assert len(spread) == len(t) == 64 + 2 * POINT_REPEATS
    strata = torch.sort(t[:64]).values
    edges = 0.2 + 0.4 * torch.arange(65, dtype=torch.float64) / 64
    assert bool(((strata >= edges[:-1]) & (strata <= edges[1:])).all())  # one t per stratum
    torch.testing.assert_close(spread.xi[:64], samples.xi[:64])
    assert float(spread.weight[64:].abs().max()) == 0.0
    for k in range(2):
        rows = slice(64 + k * POINT_REPEATS, 64 + (k + 1) * POINT_REPEATS)
        torch.testing.assert_close(spread.point_force[rows].sum(0), samples.point_force[64 + k])
        assert float(t[rows].min()) >= 0.2 and float(t[rows].max()) <= 0.6
    assert stratified_uniform(5, 0.0, 1.0, gen, dtype=torch.float64).shape == (5,)
    assert frame_times(0.25, 4) == [0.25, 0.5, 0.75, 1.0]
    with pytest.raises(ValueError, match="2 frames"):
        frame_times(0.0, 1)


def test_load_steps_widen_the_range_of_t():
    doc = document("membrane_stretch")
    doc["training"].update(pseudo_time=True, pseudo_time_start=0.1, load_steps=[0.4, 1.0])
    scene = parse_scene(doc, base_dir=SCENES)
    solver = Solver(scene.model, NeuralField(dataclasses.replace(scene.field, width=8)),
                    dataclasses.replace(scene.solver, progress=False))
    gen = torch.Generator().manual_seed(0)
    _, first = solver.training_samples(256, 0.4, gen)
    _, last = solver.training_samples(256, 1.0, gen)
    assert 0.1 <= float(first.min()) and float(first.max()) <= 0.4
    assert float(last.max()) > 0.9


def test_point_loads_and_lbfgs_in_a_pseudo_time_solve():
    doc = document("napkin")
    doc["training"] = {"pseudo_time": True, "iterations": 3, "samples": 64,
                       "monitor_samples": 256, "lbfgs_iterations": 2, "checkpoint_every": 0}
    doc.setdefault("loads", {})["point"] = [{"xi": [0.5, 0.5], "force": [0.0, 0.0, -0.1]}]
    doc["boundary"]["constraint"][0]["rotation"] = "held"  # a free pin refuses pseudo_time
    scene = parse_scene(doc, base_dir=SCENES)
    field = NeuralField(dataclasses.replace(scene.field, width=8), seed=0)
    solver = Solver(scene.model, field, dataclasses.replace(scene.solver, progress=False))
    result = solver.run()
    assert math.isfinite(result.energy) and result.history[-1].load_factor == 1.0


def scene_error(doc: dict, message: str) -> None:
    with pytest.raises(SceneError, match=message):
        parse_scene(doc, base_dir=SCENES)


def test_scene_keys_are_checked():
    doc = document("membrane_stretch")
    scene = parse_scene(doc, base_dir=SCENES)
    assert not scene.solver.pseudo_time and scene.output.frames is None
    assert scene.field.conditioning == ()
    path = load_scene(SCENES / "sleeve_twist_path.toml")
    assert path.solver.pseudo_time and path.quick_solver.pseudo_time
    assert path.field.conditioning == ((0.0, 1.0),) and path.output.frames == 24

    bad = document("membrane_stretch")
    bad["training"]["pseudo_time"] = "yes"
    scene_error(bad, r"training\.pseudo_time: expected true or false")
    bad = document("membrane_stretch")
    bad["training"]["pseudo_time_start"] = 0.2
    scene_error(bad, r"training\.pseudo_time_start: needs pseudo_time = true")
    bad = document("membrane_stretch")
    bad["training"].update(pseudo_time=True, pseudo_time_start=0.5, load_steps=[0.5, 1.0])
    scene_error(bad, r"training\.pseudo_time_start: must be below the first load step")
    bad = document("membrane_stretch")
    bad["training"].update(pseudo_time=True, pseudo_time_start=-0.1)
    scene_error(bad, r"training\.pseudo_time_start: must be >= 0")
    bad = document("membrane_stretch")
    bad["training"].update(pseudo_time=True, newton_iterations=3)
    scene_error(bad, r"training\.pseudo_time: not available with newton_iterations")
    bad = document("membrane_stretch")
    bad["training"].update(pseudo_time=True)
    bad["training"]["quick"]["pseudo_time"] = False
    scene_error(bad, r"training\.quick: unknown key\(s\) 'pseudo_time'")
    bad = document("membrane_stretch")
    bad["output"]["frames"] = 10
    scene_error(bad, r"output\.frames: needs \[training\] pseudo_time = true")
    bad = document("sleeve_twist_path")
    bad["output"]["frames"] = 1
    scene_error(bad, r"output\.frames: must be >= 2")
    bad = document("sleeve_twist_path")
    bad["output"]["frames"] = 2.5
    scene_error(bad, r"output\.frames: expected an integer")


def test_solver_refuses_a_field_without_the_time_input():
    doc = document("membrane_stretch")
    doc["training"]["pseudo_time"] = True
    scene = parse_scene(doc, base_dir=SCENES)
    plain = dataclasses.replace(scene.field, conditioning=(), pseudo_time=False)
    with pytest.raises(ValueError, match="conditioning"):
        Solver(scene.model, NeuralField(plain), scene.solver)
