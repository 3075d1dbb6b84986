"""The terms of a time step: inertia (`taichi_ndf.objective.inertia`) and stiffness-proportional
damping (`taichi_ndf.objective.damping`): their Hessian blocks against central differences of
their gradients, the consistent mass matrix it assembles on a spline field
(1ᵀM1 per component = ρ_A × area, on a flat and on a curved surface) and the kinetic energy of a
rigid translation."""

from __future__ import annotations

import copy
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from taichi_ndf import jets
from taichi_ndf.discretise import of_scene
from taichi_ndf.geometry import Plane
from taichi_ndf.objective.damping import StiffnessDampingTerm
from taichi_ndf.objective.inertia import InertiaTerm, kinetic_energy, point_masses
from taichi_ndf.problem.loads import Loads
from taichi_ndf.problem.sampling import sample_surface
from taichi_ndf.scene.reader import parse_scene
from taichi_ndf.shell.hessian import flat_blocks, sample_hessians

DENSITY = 0.3  # kg/m²

FREE_PLATE = {
    "name": "free plate",
    "geometry": {"type": "plane", "bounds": [[0.0, 0.6], [0.0, 0.25]]},
    "material": {"type": "linear", "membrane_stiffness": 100.0, "bending_stiffness": 1e-3,
                 "poisson_ratio": 0.0, "areal_density": DENSITY},
    "field": {"type": "spline", "spans": [6, 3]},
    "training": {"load_steps": [1.0]},
}
# a quarter of a cylinder, R = 0.2 m, length 0.5 m: area = (π/2) R × 0.5
ROOF = dict(FREE_PLATE, geometry={"type": "cylinder", "radius": 0.2, "length": 0.5,
                                  "angle_deg": 90.0})


def test_the_hessian_blocks_are_the_central_differences_of_the_gradient():
    torch.manual_seed(0)
    samples = sample_surface(Plane(((0.0, 2.0), (0.0, 1.0))), 16, Loads(),
                             torch.Generator().manual_seed(1))
    u = 0.01 * torch.randn(len(samples.xi), jets.CHANNELS, 3, dtype=torch.float64)
    target = 0.01 * torch.randn_like(u)
    term = InertiaTerm(DENSITY, 2.5e5, target)

    def potential(s, u_jets, grad):
        value, gradient = term.evaluate(s, u_jets, 1.0, grad=grad)
        return type("R", (), {"total": value, "grad_u_jets": gradient})

    steps = torch.full((jets.CHANNELS,), 1e-4, dtype=torch.float64)
    exact = term.hessian_blocks(samples, u, 1.0, steps=steps)
    differenced = sample_hessians(potential, samples, u, steps=steps)
    assert torch.allclose(exact, differenced, rtol=1e-9, atol=1e-9)
    assert exact.abs().sum() > 0
    # the value: ½ s Σ ρ_A w √a |u − û|² (a plane: √a = 1); only the value channel counts
    value, _ = term.evaluate(samples, u, 1.0, grad=False)
    gap = u[:, jets.VALUE] - target[:, jets.VALUE]
    expected = 0.5 * 2.5e5 * DENSITY * float((samples.weight * (gap ** 2).sum(dim=1)).sum())
    assert value == pytest.approx(expected, rel=1e-12)


def test_the_damping_blocks_are_the_central_differences_of_the_gradient():
    torch.manual_seed(2)
    samples = sample_surface(Plane(((0.0, 2.0), (0.0, 1.0))), 16, Loads(),
                             torch.Generator().manual_seed(1))
    n = len(samples.xi)
    root = torch.randn(n, 18, 18, dtype=torch.float64)
    blocks = (root @ root.transpose(1, 2)).reshape(n, jets.CHANNELS, 3, jets.CHANNELS, 3)
    u = 0.01 * torch.randn(n, jets.CHANNELS, 3, dtype=torch.float64)
    target = 0.01 * torch.randn_like(u)
    term = StiffnessDampingTerm(blocks, 0.7, target)

    def potential(s, u_jets, grad):
        value, gradient = term.evaluate(s, u_jets, 1.0, grad=grad)
        return type("R", (), {"total": value, "grad_u_jets": gradient})

    steps = torch.full((jets.CHANNELS,), 1e-4, dtype=torch.float64)
    exact = term.hessian_blocks(samples, u, 1.0, steps=steps)
    assert torch.allclose(exact, 0.7 * blocks, rtol=1e-14, atol=0)
    assert torch.allclose(exact, sample_hessians(potential, samples, u, steps=steps),
                          rtol=1e-8, atol=1e-8)
    gap = (u - target).reshape(n, 18)
    value, _ = term.evaluate(samples, u, 1.0, grad=False)
    expected = 0.5 * 0.7 * float(torch.einsum("ni,nij,nj->", gap, root @ root.transpose(1, 2),
                                              gap))
    assert value == pytest.approx(expected, rel=1e-12)


def _mass_matrix(document):
    """The assembled consistent mass matrix M (scipy, unknowns coefficient × 3 + component) of
    the scene's spline field, the linearisation and its samples."""
    scene = parse_scene(copy.deepcopy(document), base_dir=Path("."))
    d = of_scene(scene)
    linear = d.linearisation(d.evaluation_points(), 1.0)
    u = linear.displacement(torch.zeros_like(d.field.coefficients))
    term = InertiaTerm(DENSITY, 1.0, torch.zeros_like(u))
    blocks = term.hessian_blocks(linear.samples, u, 1.0)
    return linear.hessian(flat_blocks(blocks)), linear, d.field.coefficients.shape[0]


@pytest.mark.parametrize("document, area", [
    (FREE_PLATE, 0.6 * 0.25),
    (ROOF, 0.5 * math.pi * 0.2 * 0.5),
])
def test_the_mass_matrix_holds_the_mass_of_the_sheet(document, area):
    matrix, linear, n = _mass_matrix(document)
    for component in range(3):  # a unit translation along one axis: 1ᵀ M 1
        ones = np.zeros(3 * n)
        ones[component::3] = 1.0
        assert ones @ (matrix @ ones) == pytest.approx(DENSITY * area, rel=1e-9)
    # consistent, not lumped: off-diagonal coefficient pairs couple
    dense = matrix.toarray()
    assert np.count_nonzero(dense - np.diag(np.diag(dense))) > 0
    assert np.allclose(dense, dense.T, rtol=0, atol=1e-15)
    assert float(point_masses(linear.samples, DENSITY, torch.float64).sum()) == pytest.approx(
        DENSITY * area, rel=1e-9)


def test_a_rigid_translation_has_the_kinetic_energy_of_the_sheet():
    matrix, linear, n = _mass_matrix(FREE_PLATE)
    velocity = torch.tensor([0.3, -1.2, 2.0], dtype=torch.float64)
    coefficients = velocity.expand(n, 3).clone()  # partition of unity: v everywhere
    v_jets = linear.displacement(coefficients) - linear.displacement(torch.zeros_like(
        coefficients))
    assert torch.allclose(v_jets[:, jets.VALUE], velocity.expand(len(v_jets), 3), atol=1e-12)
    expected = 0.5 * DENSITY * 0.6 * 0.25 * float(velocity @ velocity)
    assert kinetic_energy(linear.samples, DENSITY, v_jets) == pytest.approx(expected, rel=1e-9)
    flat = coefficients.reshape(-1).numpy()
    assert 0.5 * flat @ (matrix @ flat) == pytest.approx(expected, rel=1e-9)


@pytest.mark.parametrize("args, message", [
    ((0.0, 1.0), "areal_density must be finite and > 0"),
    ((0.1, -1.0), "scale must be finite and > 0"),
    ((0.1, math.inf), "scale must be finite and > 0"),
])
def test_bad_settings_are_refused(args, message):
    with pytest.raises(ValueError, match=message):
        InertiaTerm(*args, torch.zeros(4, jets.CHANNELS, 3))
