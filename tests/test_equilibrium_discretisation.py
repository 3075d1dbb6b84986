"""The material fits' spline equilibrium built through the forward solve's `Discretisation`
(`discretise.discretisation(..., dtype=)`): a discretisation makes its fields, points and
linearisations in the dtype asked for whatever the runtime's, and `SplineEquilibrium` takes
its grid's Gauss points from `evaluation_points` (a seam's own points among them, the point
loads' rows still theirs)."""

import dataclasses
from pathlib import Path

import numpy as np
import pytest
import torch

from inverse.material.spline_equilibrium import SplineEquilibrium, SplineModelConfig
from inverse.material.unknowns import parse_unknowns
from taichi_ndf.discretise import discretisation
from taichi_ndf.field import FieldConfig
from taichi_ndf.objective.seam import SeamTerm, seam_points
from taichi_ndf.problem.loads import PointLoad
from taichi_ndf.problem.spline_grid import SplinePlan
from taichi_ndf.problem.training import SolverConfig
from taichi_ndf.scene.reader import load_scene

SCENES = Path(__file__).parents[1] / "scenes"


def test_discretisations_make_their_fields_in_the_dtype_asked_for():
    """The session's runtime is float64 (conftest); asked for float32, the spline's field,
    Gauss points and linearisation and the SIREN's network are float32, and a garment's
    panels (float64 only) refuse it in one line."""
    model = load_scene(SCENES / "inverse" / "cantilever_strip.toml").model
    spline = discretisation(SplinePlan(SplineModelConfig(spans=(2, 1)).grid(model)), model,
                            dtype=torch.float32)
    spline.start(SolverConfig(method="newton"), seed=0)
    points = spline.evaluation_points()
    assert spline.field.coefficients.dtype == torch.float32
    assert points.xi.dtype == torch.float32
    assert spline.linearisation(points, 1.0).assembly.samples.xi.dtype == torch.float32
    assert spline.refined(2).dtype == torch.float32
    siren = discretisation(FieldConfig(width=8, hidden_layers=1, output_scale=0.01), model,
                           dtype=torch.float32)
    siren.start(SolverConfig(iterations=1, samples=16), seed=0)
    assert siren.field.parameters[0].dtype == torch.float32
    garment = load_scene(SCENES / "skirt_panels.toml")
    with pytest.raises(ValueError, match="multi-patch field is torch.float64"):
        discretisation(garment.field, garment.model, dtype=torch.float32)


def test_spline_equilibrium_takes_the_discretisation_points_with_a_seam():
    """The seamed tube with a point load: the equilibrium's samples are the discretisation's
    evaluation points (the span quadrature, then the seam's own points), its point-load rows
    are the point load's sample, θ's force lands there, and the seam finds its points
    exactly (before, the seam's points were missing and it took the nearest Gauss points)."""
    scene = load_scene(SCENES / "tube_seam.toml")
    xi = (1.0, 0.1)
    loads = dataclasses.replace(scene.model.loads,
                                point_loads=(PointLoad(xi, (0.0, 0.0, -0.01)),))
    model, unknowns = parse_unknowns("bending,point_load:0", scene.model.with_loads(loads))
    seams = [t for t in model.terms if isinstance(t, SeamTerm)]
    assert seams and seam_points(model.terms) > 0
    config = SplineModelConfig(spans=(4, 2), boundary_length=None)
    grid = config.grid(model)
    eq = SplineEquilibrium(model, unknowns, config, grid)
    points = discretisation(SplinePlan(grid), model, dtype=torch.float64).evaluation_points()
    assert len(eq.samples) == len(points)
    assert torch.equal(eq.samples.xi[eq._model_order], points.xi)
    assert eq.samples.xi[eq.point_rows].tolist() == [list(xi)]
    force = (0.0, 0.0, -0.02)
    potential = eq._potential(np.array([model.material.bending_stiffness, *force]), 1.0)
    assert eq.samples.point_force[eq.point_rows].tolist() == [list(force)]
    for seam in seams:  # before: ValueError, its points not among the samples
        pairs = seam.rows(eq.samples)
        assert torch.equal(eq.samples.xi[pairs.T.reshape(-1)], seam.xi.to(torch.float64))
    u = eq.grid.linearisation(1.0).displacement(eq.state())
    assert torch.isfinite(potential(eq.samples, u, True).grad_u_jets).all()
