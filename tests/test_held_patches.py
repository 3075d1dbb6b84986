"""The quadrature outside held corner patches (`discretise.held_patches`): exact area and
moments of the domain minus the quarter discs, no point on a patch, and the dynamics' points
are those."""

import math

import numpy as np
import pytest
import torch

from taichi_ndf.boundary import BoundaryConditions, Handle
from taichi_ndf.discretise.held_patches import corner_patches, held_patch_points
from taichi_ndf.field.spline import SplineConfig
from taichi_ndf.geometry import Plane
from taichi_ndf.problem.dynamics import DynamicsConfig
from taichi_ndf.problem.loads import Loads
from taichi_ndf.problem.model import ShellModel
from taichi_ndf.problem.spline_grid import SplinePlan
from taichi_ndf.shell.materials import LinearIsotropic
from taichi_ndf.solve.handle_paths import HandlePath, PathStepper

W = 0.55


def _grips(radius: float, surface=None):
    surface = surface or Plane(bounds=((0.0, W), (0.0, W)))
    return BoundaryConditions([Handle((0.0, 0.0), (0.0, 0.0, 0.0), radius=radius / W),
                               Handle((W, 0.0), (0.0, 0.0, 0.0), radius=radius / W)],
                              surface.domain, surface=surface)


@pytest.mark.parametrize("spans,radius", [((16, 16), 0.02), ((32, 32), 0.02), ((40, 24), 0.03)])
def test_the_points_integrate_the_domain_outside_the_corner_patches(spans, radius):
    config = SplineConfig(spans=spans, degree=3, domain=((0.0, W), (0.0, W)))
    xi, weight = held_patch_points(_grips(radius), config)
    quarter = math.pi * radius**2 / 4
    assert float(weight.sum()) == pytest.approx(W * W - 2 * quarter, rel=1e-14)
    # ∫ x² y dA: the rectangle's W⁵/6 less the quarter discs' about (0, 0) and (W, 0)
    moment = W**5 / 6 - radius**5 / 15 - (W**2 * radius**3 / 3 - W * radius**4 / 4
                                          + radius**5 / 15)
    assert float((weight * xi[:, 0] ** 2 * xi[:, 1]).sum()) == pytest.approx(moment, rel=1e-12)
    centre = torch.tensor([[0.0, 0.0], [W, 0.0]], dtype=xi.dtype)
    assert float(torch.cdist(xi, centre).min()) > radius
    assert float(weight.min()) > 0


def test_only_corner_circles_are_trimmed():
    config = SplineConfig(spans=(8, 8), degree=3, domain=((0.0, W), (0.0, W)))
    assert corner_patches(_grips(0.02), config) == {(0, 0): pytest.approx(0.02),
                                                    (1, 0): pytest.approx(0.02)}
    surface = Plane(bounds=((0.0, W), (0.0, W)))
    point = BoundaryConditions([Handle((0.0, 0.0), (0.0, 0.0, 0.0))], surface.domain,
                               surface=surface)
    assert held_patch_points(point, config) is None  # no patch: the spans' own points
    middle = BoundaryConditions([Handle((W / 2, 0.0), (0.0, 0.0, 0.0), radius=0.05)],
                                surface.domain, surface=surface)
    assert held_patch_points(middle, config) is None  # not at a corner
    wide = Plane(bounds=((0.0, 2 * W), (0.0, W)))
    ellipse = BoundaryConditions([Handle((0.0, 0.0), (0.0, 0.0, 0.0), radius=0.05)],
                                 wide.domain, surface=wide)
    wide_config = SplineConfig(spans=(8, 8), degree=3, domain=((0.0, 2 * W), (0.0, W)))
    assert held_patch_points(ellipse, wide_config) is None  # an ellipse in ξ


def test_a_stepper_with_grips_integrates_outside_them():
    surface = Plane(bounds=((0.0, W), (0.0, W)))
    model = ShellModel(surface, LinearIsotropic(300.0, 1.5e-5, 0.25, 0.197),
                       Loads(gravity=(0.0, 9.81, 0.0)), _grips(0.03, surface))
    plan = SplinePlan(SplineConfig(spans=(12, 12), degree=3, domain=((0.0, W), (0.0, W))))
    stepper = PathStepper(model, plan, DynamicsConfig(dt=0.05, duration=0.1),
                          HandlePath((0.0, 1.0), np.zeros((2, 2, 3))))
    xi, weight = stepper.samples.xi, stepper.samples.weight
    assert float(weight.sum()) == pytest.approx(W * W - math.pi * 0.03**2 / 2, rel=1e-13)
    centre = torch.tensor([[0.0, 0.0], [W, 0.0]], dtype=xi.dtype)
    assert float(torch.cdist(xi, centre).min()) > 0.03


def test_the_stiffness_force_with_grips_is_the_gradients_slope_in_b():
    """∂f/∂B (`dynamics_adjoint.force_derivative`, the rest start's and the tangent's right-hand
    side) is dΠ's slope in B at fixed coefficients: the stepper's points are the assembly's
    order, which a trimmed quadrature's are not as made (they were paired with displacements
    in another order: 71 % off on the swing's graded 32² grip)."""
    from taichi_ndf.solve.dynamics_adjoint import force_derivative

    surface = Plane(bounds=((0.0, W), (0.0, W)))
    material = LinearIsotropic(300.0, 1.5e-5, 0.25, 0.197)
    plan = SplinePlan(SplineConfig(spans=(12, 12), degree=3, domain=((0.0, W), (0.0, W))))
    torch.manual_seed(0)

    def stepper(bending):
        model = ShellModel(surface, material.with_stiffness(bending_stiffness=bending),
                           Loads(gravity=(0.0, 9.81, 0.0)), _grips(0.03, surface))
        return PathStepper(model, plan, DynamicsConfig(dt=0.05, duration=0.1),
                           HandlePath((0.0, 1.0), np.zeros((2, 2, 3))))

    first, second = stepper(1.5e-5), stepper(3.0e-5)
    c = 1e-3 * torch.randn(first.field.coefficients.shape, dtype=torch.float64)

    def gradient(s):
        linear = s._at(0.0)
        result = s.objective.potential(1.0)(linear.samples, linear.displacement(c), True)
        return linear.gradient(result.grad_u_jets)

    slope = (gradient(second) - gradient(first)) / 1.5e-5
    found = force_derivative(first, "bending_stiffness", c, 0.0)
    assert torch.allclose(found, slope, rtol=1e-7, atol=1e-9 * float(slope.abs().max()))
