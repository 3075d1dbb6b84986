"""Shape fit of the material estimator: a smooth displacement is recovered with its jets."""

import torch

from inverse.material import Observation, fit_shape
from taichi_ndf import jets
from taichi_ndf.boundary import BoundaryConditions, ClampedEdge
from taichi_ndf.geometry import Plane
from taichi_ndf.problem.loads import Loads
from taichi_ndf.problem.model import ShellModel
from taichi_ndf.shell.materials import preset


def _model():
    surface = Plane(bounds=((0.0, 0.2), (0.0, 0.1)))
    bc = BoundaryConditions([ClampedEdge("xi1_min")], surface.domain)
    return ShellModel(surface, preset("cloth"), Loads(gravity=(0, 0, -9.81)), bc)


def _bent(xi):
    """Cubic displacement u = (0, 0, −s² (1 + s)) with s = 5 ξ¹ and its exact jets."""
    s = 5 * xi[:, 0]
    out = xi.new_zeros(len(xi), 6, 3)
    out[:, jets.VALUE, 2] = -(s**2) * (1 + s)
    out[:, jets.D1, 2] = -5 * (2 * s + 3 * s**2)
    out[:, jets.D11, 2] = -25 * (2 + 6 * s)
    return out


def test_fit_with_correspondence_reproduces_a_polynomial_shape_and_its_curvature():
    model = _model()
    g1, g2 = torch.meshgrid(torch.linspace(0, 0.2, 21, dtype=torch.float64),
                            torch.linspace(0, 0.1, 6, dtype=torch.float64), indexing="ij")
    xi = torch.stack([g1.ravel(), g2.ravel()], dim=1)
    points = model.surface.jets(xi)[:, jets.VALUE] + _bent(xi)[:, jets.VALUE]
    shape = fit_shape(Observation(model, points, xi), degree=6, smoothing=1e-12)
    probe = torch.tensor([[0.05, 0.03], [0.13, 0.07]], dtype=torch.float64)
    assert shape.rms < 1e-8
    assert torch.allclose(shape.displacement_jets(probe), _bent(probe), atol=1e-5)


def test_fit_of_a_point_cloud_without_correspondence():
    model = _model()
    gen = torch.Generator().manual_seed(3)
    xi = torch.rand(400, 2, generator=gen, dtype=torch.float64) * torch.tensor([0.2, 0.1])
    points = model.surface.jets(xi)[:, jets.VALUE] + _bent(xi)[:, jets.VALUE]
    shape = fit_shape(Observation(model, points, None), degree=5, smoothing=1e-12)
    assert shape.rms < 1e-4 * 0.2


def test_misfit_is_the_rms_point_distance_not_per_coordinate():
    """Three points each 3 mm off along one axis with correspondence (9 residual entries) and
    the same as a point cloud (3 signed distances) both give an rms point distance of 3 mm."""
    import numpy as np
    import pytest

    from inverse.material.observations import rms_point_distance

    points = torch.zeros(3, 3, dtype=torch.float64)
    with_xi = Observation(_model(), points, torch.full((3, 2), 0.05, dtype=torch.float64))
    offsets = np.array([[0.003, 0.0, 0.0], [0.0, 0.003, 0.0], [0.0, 0.0, -0.003]])
    assert rms_point_distance(offsets.ravel(), [with_xi]) == pytest.approx(0.003)
    cloud = Observation(_model(), points, None)
    assert rms_point_distance(np.array([0.003, -0.003, 0.003]), [cloud]) == pytest.approx(0.003)
