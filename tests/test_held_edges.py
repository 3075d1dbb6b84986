"""A flat-cut panel's held edge (`Patch.held`, `taichi_ndf.discretise.held_edges`) is a clamp:
it holds the edge's position and its derivative across the edge where the start put them,
and leaves the edge's curvature free."""

from __future__ import annotations

import pytest
import torch

from taichi_ndf import jets
from taichi_ndf.boundary import BoundaryConditions
from taichi_ndf.discretise.held_edges import patch_map
from taichi_ndf.discretise.multipatch import MultiPatchDiscretisation
from taichi_ndf.field.spline import SplineConfig, SplineField
from taichi_ndf.geometry import Plane
from taichi_ndf.problem.loads import Loads
from taichi_ndf.problem.model import ShellModel
from taichi_ndf.problem.multipatch import MultiPatchPlan, Patch
from taichi_ndf.problem.start_shape import StartShape
from taichi_ndf.problem.training import SolverConfig
from taichi_ndf.shell.materials import LinearIsotropic

DT = torch.float64
LENGTH, WIDTH = 0.3, 0.1
GRAVITY = (0.0, 0.0, -9.81)
# B = 3.3 N·m, ν = 0: a strip's tip deflection under its weight q = ρ_A g is q L⁴ / (8 B),
# 0.30 mm (w/L = 1e-3: linear)
MATERIAL = LinearIsotropic(membrane_stiffness=1e5, bending_stiffness=3.3, poisson_ratio=0.0,
                           areal_density=0.1)


def _patch(spans, held=("xi1_min",), degree=3) -> Patch:
    surface = Plane(bounds=((0.0, LENGTH), (0.0, WIDTH)))
    model = ShellModel(surface, MATERIAL, Loads(gravity=GRAVITY),
                       BoundaryConditions([], domain=surface.domain), ())
    return Patch("strip", model, SplineConfig(spans=spans, domain=surface.domain.bounds,
                                              degree=degree),
                 start=StartShape("rigid"), held=held)


def _edge_jets(patch, coefficients: torch.Tensor, xi: torch.Tensor) -> torch.Tensor:
    field = SplineField(patch.config, dtype=DT)
    field.coefficients.data.copy_(coefficients.reshape(field.coefficients.shape))
    return field.jets(xi)


@pytest.mark.parametrize(("degree", "held"), [(3, ("xi1_min",)), (3, ("xi1_max", "xi2_min")),
                                              (4, ("xi1_min", "xi1_max", "xi2_max"))])
def test_a_held_step_keeps_each_held_edge_and_its_slope_and_moves_its_curvature(degree, held):
    """Any step T z of the held map: zero value and zero derivative across every held edge
    (the field's own jets at 9 points of each), the second derivative across it not zero."""
    patch = _patch((6, 5), held, degree)
    t, fixed = patch_map(patch)
    z = torch.randn(t.shape[1], generator=torch.Generator().manual_seed(1), dtype=DT)
    z[torch.from_numpy(fixed)] = 0.0
    step = torch.from_numpy(t @ z.numpy())
    s = torch.linspace(0.0, 1.0, 9, dtype=DT)
    for edge in held:
        axis, side = int(edge[2]) - 1, edge.endswith("max")
        xi = torch.stack((s * LENGTH, s * WIDTH), dim=1)
        xi[:, axis] = (LENGTH, WIDTH)[axis] if side else 0.0
        u = _edge_jets(patch, step, xi)
        across, second = (jets.D1, jets.D11) if axis == 0 else (jets.D2, jets.D22)
        assert float(u[:, jets.VALUE].abs().max()) < 1e-12
        assert float(u[:, across].abs().max()) < 1e-10
        assert float(u[:, second].abs().max()) > 1e-3


def test_a_flat_cut_strip_held_at_one_end_hangs_as_a_clamped_cantilever():
    """The strip held at ξ¹ = 0 (its start its rest shape) under its weight, 4 × 2 cubic
    spans: the tip deflection q L⁴/(8 B) to 1e-4 (measured −8e-7: the cubic spline is exact
    at the knots of a beam). Holding the edge's 3 rows of coefficients instead (its
    curvature held at 0) gave −29 % here (−55 %, −14 %, −7.2 % on 2, 8 and 16 spans)."""
    patch = _patch((4, 2))
    panels = MultiPatchDiscretisation(MultiPatchPlan((patch,), gravity=GRAVITY))
    config = SolverConfig(method="newton", load_steps=(1.0,), progress=False)
    panels.start(config, seed=0)
    solution = panels.solve(config)
    panels.check_solution(solution)
    assert all(panels.converged)
    q = MATERIAL.areal_density * 9.81
    tip = -panels.displacement_of(0, torch.tensor([[LENGTH, 0.5 * WIDTH]], dtype=DT))[0, 0, 2]
    assert float(tip) == pytest.approx(q * LENGTH ** 4 / (8 * MATERIAL.bending_stiffness),
                                       rel=1e-4)
    root = panels.displacement_of(0, torch.tensor([[0.0, 0.05], [0.0, 0.0]], dtype=DT))
    assert float(root[:, jets.VALUE].abs().max()) < 1e-12
    assert float(root[:, jets.D1].abs().max()) < 1e-10
    assert float(root[:, jets.D11, 2].abs().min()) > 0.0
