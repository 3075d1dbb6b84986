"""Forward simulation against known answers: an exact solution, independence of the output
resolution and of the template mesh's triangulation."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
import torch

from taichi_ndf.app.outputs import deformed_mesh
from taichi_ndf.field import NeuralField
from taichi_ndf.scene.reader import load_scene, parse_scene
from taichi_ndf.solve.solver import Solver

ROOT = Path(__file__).resolve().parents[1]


def solve(scene, config):
    field = NeuralField(scene.field, seed=config.seed)
    solver = Solver(scene.model, field, dataclasses.replace(config, progress=False))
    return solver, field, solver.run()


def test_uniform_stretch_matches_the_exact_solution():
    # Membrane (ν = 0) with hinged x edges, the right one moved by δ = 0.2 m: u = δ x e_x,
    # ε₁₁ = ½(λ² − 1) with λ = 1 + δ, Π = ½ D ε₁₁² · area.
    scene = load_scene(ROOT / "scenes" / "membrane_stretch.toml")
    delta, stiffness, area = 0.2, scene.model.material.membrane_stiffness, 1.0
    exact_energy = 0.5 * stiffness * (0.5 * ((1 + delta) ** 2 - 1)) ** 2 * area
    assert exact_energy == pytest.approx(2.42)
    solver, _, result = solve(scene, scene.solver)

    # Π on fresh, denser samples than the training ones (no quadrature bias from training).
    fresh = solver._samples(32768, torch.Generator().manual_seed(12345))
    energy = solver.energy_and_gradient(fresh, 1.0, grad=False).total
    assert energy == pytest.approx(exact_energy, rel=0.01)
    assert result.energy == pytest.approx(exact_energy, rel=0.01)
    for probe in scene.model.probes:
        exact = np.array([delta * probe.xi[0], 0.0, 0.0])
        np.testing.assert_allclose(result.probes[probe.name], exact, rtol=0, atol=0.01 * delta,
                                   err_msg=probe.name)


def test_output_is_independent_of_its_resolution():
    scene = load_scene(ROOT / "scenes" / "napkin.toml")
    scene = dataclasses.replace(scene, field=dataclasses.replace(scene.field, width=16))
    _, field, _ = solve(scene, scene.quick_solver.with_iterations(10))
    coarse = deformed_mesh(scene.model, field, (32, 32))
    fine = deformed_mesh(scene.model, field, (256, 256))
    # grid_mesh numbers vertex (i, j) as j (n + 1) + i: coarse (i, j) is fine (8 i, 8 j).
    i, j = np.meshgrid(np.arange(33), np.arange(33))
    shared = (8 * j * 257 + 8 * i).ravel()
    np.testing.assert_array_equal(fine.xi[shared], coarse.xi)
    np.testing.assert_allclose(fine.deformed[shared], coarse.deformed, rtol=1e-12, atol=1e-12)
    for name, values in coarse.scalars().items():
        np.testing.assert_allclose(fine.scalars()[name][shared], values, rtol=1e-9, atol=1e-12,
                                   err_msg=name)
    assert np.ptp(coarse.deformed[:, 2]) > 1e-3  # the field did move the napkin


def _template_scenes(width: int | None):
    """The napkin template scene on napkin.obj and on its other triangulation napkin_alt.obj."""
    path = ROOT / "scenes" / "napkin_template.toml"
    base = load_scene(path)
    alt_doc = {**base.document, "geometry": {**base.document["geometry"],
                                              "path": "../data/napkin_alt.obj"}}
    scenes = [base, parse_scene(alt_doc, base_dir=path.parent, path=path)]
    if width is not None:
        scenes = [dataclasses.replace(s, field=dataclasses.replace(s.field, width=width))
                  for s in scenes]
    return scenes


def _assert_same_probes(config_of, width):
    results = [solve(s, config_of(s))[2] for s in _template_scenes(width)]
    for name, u in results[0].probes.items():
        u, v = np.array(u), np.array(results[1].probes[name])
        assert np.linalg.norm(u - v) <= 0.02 * max(np.linalg.norm(u), 1e-9), (name, u, v)
    return results


def test_triangulation_independence_quick():
    # Both templates are exact fits of the same flat square, so even a short run must agree.
    results = _assert_same_probes(lambda s: s.quick_solver.with_iterations(20), width=16)
    # the short run did move the corner (5.7 mm in 20 Adam steps with the measured weave)
    assert np.linalg.norm(results[0].probes["free_corner"]) > 1e-3


@pytest.mark.slow
def test_triangulation_independence_converged():
    _assert_same_probes(lambda s: s.solver, width=None)
