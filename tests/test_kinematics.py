"""Exact Kirchhoff–Love strains: rigid motions, rolled strip beyond a full turn, stretch,
inflation, and agreement with a plain torch reference of physics.md §2."""

import math

import pytest
import torch

from taichi_ndf.geometry import Annulus, Cone, Cylinder, CylindricalRoof, Hemisphere, Plane
from taichi_ndf.shell import function_jets, strains

SURFACES = [
    Plane(bounds=((0.0, 2.0), (-1.0, 0.5)), origin=(1.0, 2.0, 3.0)),
    Cylinder(radius=2.0, length=3.0),
    Cone(bottom_radius=1.0, top_radius=0.3, height=2.0),
    CylindricalRoof(),
    Hemisphere(radius=2.0, hole_half_angle=0.3),
    Hemisphere(radius=2.0),
    Annulus(inner_radius=0.5, outer_radius=2.0),
    Annulus(inner_radius=6.0, outer_radius=10.0, slit=True, origin=(1.0, 0.0, -2.0)),
]


def _rotation():
    generator = torch.tensor([[0.0, -0.7, 1.1], [0.7, 0.0, -2.3], [-1.1, 2.3, 0.0]])
    return torch.linalg.matrix_exp(generator.double())  # a large rotation (~2.6 rad)


@pytest.mark.parametrize("surface", SURFACES, ids=lambda s: type(s).__name__)
def test_rigid_motion_gives_zero_strain(surface):
    xi = surface.domain.sample(200, torch.Generator().manual_seed(0))
    r = surface.jets(xi)
    u = r @ _rotation().T - r  # rotation about the origin, applied to every channel
    u[:, 0] += torch.tensor([0.1, -3.0, 7.5], dtype=torch.float64)
    eps, kappa, sqrt_a = strains(r, u)
    assert eps.abs().max() <= 1e-10
    assert kappa.abs().max() <= 1e-10
    assert (sqrt_a > 0).all()


@pytest.mark.parametrize("rho", [10.0, 1.0, 0.3, 0.1, 0.05])
def test_rolled_strip_curvature_is_one_over_radius(rho):
    length = 1.0  # rho = 0.05 rolls the strip more than three full turns
    plane = Plane(bounds=((0.0, length), (0.0, 0.2)))
    xi = plane.domain.sample(300, torch.Generator().manual_seed(1))

    def rolled(x):
        t = x[:, 0] / rho
        return torch.stack((rho * torch.sin(t), x[:, 1], rho * (1 - torch.cos(t))), dim=1)

    r = plane.jets(xi)
    eps, kappa, _ = strains(r, function_jets(rolled, xi) - r)
    assert torch.allclose(kappa[:, 0, 0].abs(), torch.full_like(kappa[:, 0, 0], 1 / rho),
                          rtol=1e-9, atol=0)
    assert kappa[:, 0, 1].abs().max() < 1e-9 / rho and kappa[:, 1, 1].abs().max() < 1e-9 / rho
    assert eps.abs().max() < 1e-12  # rolling is inextensional


def test_rolling_in_the_second_direction_is_symmetric():
    """κ₂₂ uses the same formula as κ₁₁ (the original code had an index typo there)."""
    plane = Plane(bounds=((0.0, 0.2), (0.0, 1.0)))
    xi = plane.domain.sample(100, torch.Generator().manual_seed(2))
    rho = 0.2

    def rolled(x):
        t = x[:, 1] / rho
        return torch.stack((x[:, 0], rho * torch.sin(t), rho * (1 - torch.cos(t))), dim=1)

    r = plane.jets(xi)
    eps, kappa, _ = strains(r, function_jets(rolled, xi) - r)
    assert torch.allclose(kappa[:, 1, 1].abs(), torch.full_like(xi[:, 0], 1 / rho), rtol=1e-9)
    assert kappa[:, 0, 0].abs().max() < 1e-9 and eps.abs().max() < 1e-12
    assert torch.equal(kappa[:, 0, 1], kappa[:, 1, 0])


@pytest.mark.parametrize("stretch", [0.5, 1.0, 1.3, 3.0])
def test_uniform_stretch(stretch):
    frame = ((0.0, 0.6, 0.8), (0.0, -0.8, 0.6), (1.0, 0.0, 0.0))  # plane in an arbitrary pose
    plane = Plane(bounds=((0.0, 1.0), (0.0, 1.0)), frame=frame)
    xi = plane.domain.sample(64, torch.Generator().manual_seed(3))
    r = plane.jets(xi)
    u = torch.zeros_like(r)
    u[:, 0] = (stretch - 1) * xi[:, :1] * r[:, 1]  # (λ − 1) ξ¹ e_x
    u[:, 1] = (stretch - 1) * r[:, 1]
    eps, kappa, _ = strains(r, u)
    assert torch.allclose(eps[:, 0, 0], torch.full_like(xi[:, 0], 0.5 * (stretch**2 - 1)),
                          rtol=1e-13)
    assert eps[:, 0, 1].abs().max() < 1e-14 and eps[:, 1, 1].abs().max() < 1e-14
    assert kappa.abs().max() < 1e-14


def test_inflated_cylinder_hoop_strain():
    radius, factor = 2.0, 1.01
    cylinder = Cylinder(radius=radius, length=3.0)
    xi = cylinder.domain.sample(100, torch.Generator().manual_seed(4))
    r = cylinder.jets(xi)
    u = (factor - 1) * r
    u[:, :, 2] = 0.0  # radial expansion only
    eps, kappa, _ = strains(r, u)
    hoop = eps[:, 0, 0] / radius**2  # physical strain: ε₁₁ a^{11}
    assert torch.allclose(hoop, torch.full_like(hoop, 0.5 * (factor**2 - 1)), rtol=1e-12)
    assert eps[:, 1, 1].abs().max() < 1e-15 and eps[:, 0, 1].abs().max() < 1e-15
    # b₁₁ = −R, b̄₁₁ = −λR: κ₁₁ = (λ − 1) R
    assert torch.allclose(kappa[:, 0, 0], torch.full_like(hoop, (factor - 1) * radius),
                          rtol=1e-12)


def _torch_reference(r, u):
    """Straightforward torch transcription of physics.md §2."""
    x = r + u

    def forms(p):
        a1, a2 = p[:, 1], p[:, 2]
        n = torch.linalg.cross(a1, a2, dim=1)
        a3 = n / n.norm(dim=1, keepdim=True)
        metric = torch.stack([torch.stack([(a1 * a1).sum(1), (a1 * a2).sum(1)], 1),
                              torch.stack([(a2 * a1).sum(1), (a2 * a2).sum(1)], 1)], 1)
        b = lambda c: (p[:, c] * a3).sum(1)  # noqa: E731
        curvature = torch.stack([torch.stack([b(3), b(4)], 1), torch.stack([b(4), b(5)], 1)], 1)
        return metric, curvature, n.norm(dim=1)

    a, b, sqrt_a = forms(r)
    a_bar, b_bar, _ = forms(x)
    return 0.5 * (a_bar - a), b - b_bar, sqrt_a


@pytest.mark.parametrize("surface", SURFACES[2:], ids=lambda s: type(s).__name__)
def test_strains_match_torch_reference_for_a_large_deformation(surface):
    generator = torch.Generator().manual_seed(5)
    xi = surface.domain.sample(128, generator)
    r = surface.jets(xi)
    u = 0.3 * torch.randn(r.shape, generator=generator, dtype=torch.float64)
    eps, kappa, sqrt_a = strains(r, u)
    eps_ref, kappa_ref, sqrt_a_ref = _torch_reference(r, u)
    assert torch.allclose(eps, eps_ref, rtol=1e-12, atol=1e-13)
    assert torch.allclose(kappa, kappa_ref, rtol=1e-12, atol=1e-13)
    assert torch.allclose(sqrt_a, sqrt_a_ref, rtol=1e-13)


def test_shape_mismatch_raises():
    with pytest.raises(ValueError, match="u_jets"):
        strains(torch.zeros(3, 6, 3, dtype=torch.float64), torch.zeros(4, 6, 3))


def test_moderate_rotation_regime_is_not_used():
    """At 4 rad of rotation the moderate-rotation approximation flips sign; ours does not."""
    plane = Plane(bounds=((0.0, 1.0), (0.0, 0.1)))
    xi = torch.tensor([[1.0, 0.05]], dtype=torch.float64)
    rho = 1.0 / 4.0  # angle at ξ¹ = 1 is 4 rad

    def rolled(x):
        t = x[:, 0] / rho
        return torch.stack((rho * torch.sin(t), x[:, 1], rho * (1 - torch.cos(t))), dim=1)

    r = plane.jets(xi)
    _, kappa, _ = strains(r, function_jets(rolled, xi) - r)
    assert kappa[0, 0, 0].item() == pytest.approx(-1 / rho, rel=1e-12)
    assert math.isfinite(kappa.abs().max().item())
