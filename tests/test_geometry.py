"""Parameter domains and analytic reference surfaces: exact jets, positions, normals, areas."""

import math

import pytest
import torch

from taichi_ndf.geometry import (
    Annulus,
    Cone,
    Cylinder,
    CylindricalRoof,
    Hemisphere,
    ParameterDomain,
    Plane,
)
from taichi_ndf.problem.sampling import sample_surface

TILTED = ((0.0, 0.0, 1.0), (1.0, 0.0, 0.0), (0.0, 1.0, 0.0))  # local x, y, z -> world z, x, y

SURFACES = {
    "plane": Plane(bounds=((0.0, 2.0), (-1.0, 0.5)), origin=(1.0, 2.0, 3.0), frame=TILTED),
    "cylinder": Cylinder(radius=2.0, length=3.0),
    "cone": Cone(bottom_radius=1.0, top_radius=0.3, height=2.0, origin=(0.5, 0.0, -1.0)),
    "roof": CylindricalRoof(radius=25.0, length=50.0, half_angle=math.radians(40)),
    "hemisphere_hole": Hemisphere(radius=2.0, hole_half_angle=math.radians(18)),
    "hemisphere_disk": Hemisphere(radius=2.0),
    "cap_disk": Hemisphere(radius=1.5, rim_angle=2.5, frame=TILTED),
    "annulus": Annulus(inner_radius=0.5, outer_radius=2.0, origin=(0.3, 0.0, 1.0), frame=TILTED),
    "slit_annulus": Annulus(inner_radius=6.0, outer_radius=10.0, slit=True),
    "sector": Annulus(inner_radius=0.5, outer_radius=2.0, angle=1.5, start_angle=-0.5),
}

# Exact surface areas [m²].
AREAS = {
    "plane": 3.0,
    "cylinder": 2 * math.pi * 2.0 * 3.0,
    "cone": math.pi * 1.3 * math.hypot(0.7, 2.0),
    "roof": 2 * math.radians(40) * 25.0 * 50.0,
    "hemisphere_hole": 2 * math.pi * 4.0 * math.cos(math.radians(18)),
    "hemisphere_disk": 2 * math.pi * 4.0,
    "cap_disk": 2 * math.pi * 1.5**2 * (1 - math.cos(2.5)),
    "annulus": math.pi * (2.0**2 - 0.5**2),
    "slit_annulus": math.pi * (10.0**2 - 6.0**2),
    "sector": 0.5 * 1.5 * (2.0**2 - 0.5**2),
}


def _samples(surface, n=256, seed=0):
    return surface.domain.sample(n, torch.Generator().manual_seed(seed))


@pytest.mark.parametrize("name", SURFACES)
def test_jets_are_the_derivatives_of_the_position(name):
    surface = SURFACES[name]
    xi = _samples(surface).requires_grad_(True)
    j = surface.jets(xi)
    for c in range(3):
        first = torch.autograd.grad(j[:, 0, c].sum(), xi, create_graph=True)[0]
        assert torch.allclose(first, j[:, 1:3, c], atol=1e-12, rtol=0)
        d1 = torch.autograd.grad(j[:, 1, c].sum(), xi, retain_graph=True)[0]
        d2 = torch.autograd.grad(j[:, 2, c].sum(), xi, retain_graph=True)[0]
        assert torch.allclose(d1, j[:, 3:5, c], atol=1e-12, rtol=0)
        assert torch.allclose(d2, j[:, 4:6, c], atol=1e-12, rtol=0)


@pytest.mark.parametrize("name", ["annulus", "slit_annulus", "sector"])
def test_annulus_jets_against_central_differences(name):
    surface, h = SURFACES[name], 1e-5
    xi = _samples(surface, 64)
    j = surface.jets(xi)

    def shifted(k, step):
        delta = torch.zeros(2, dtype=torch.float64)
        delta[k] = step
        return surface.jets(xi + delta)

    for k in range(2):   # first derivatives from r, second ones from the first derivatives
        plus, minus = shifted(k, h), shifted(k, -h)
        fd = (plus - minus) / (2 * h)
        assert torch.allclose(fd[:, 0], j[:, 1 + k], atol=1e-9, rtol=0)
        assert torch.allclose(fd[:, 1], j[:, 3 + k], atol=1e-9, rtol=0)
        assert torch.allclose(fd[:, 2], j[:, 4 + k], atol=1e-9, rtol=0)


def test_annulus_domains_rims_and_normal():
    full, slit, sector = SURFACES["annulus"], SURFACES["slit_annulus"], SURFACES["sector"]
    assert full.domain.periodic == (False, True)
    assert slit.domain.periodic == (False, False)
    assert sector.domain.periodic == (False, False)
    assert sector.domain.bounds == ((0.5, 2.0), (-0.5, 1.0))
    j = slit.jets(_samples(slit))
    radius = j[:, 0, :2].norm(dim=1)
    assert torch.allclose(radius, _samples(slit)[:, 0])
    normal = torch.linalg.cross(j[:, 1], j[:, 2], dim=1)
    assert torch.allclose(normal / radius[:, None],
                          torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64).expand(len(j), 3))


def test_points_lie_on_the_analytic_surfaces():
    def radius_of(name, center=(0.0, 0.0, 0.0), axis=None):
        s = SURFACES[name]
        p = s.positions(_samples(s)) - torch.tensor(center, dtype=torch.float64)
        if axis is not None:
            p = p - (p @ torch.tensor(axis, dtype=torch.float64))[:, None] * torch.tensor(axis)
        return p.norm(dim=1)

    assert torch.allclose(radius_of("cylinder", axis=(0.0, 0.0, 1.0)), torch.tensor(2.0).double())
    assert torch.allclose(radius_of("roof", axis=(0.0, 1.0, 0.0)), torch.tensor(25.0).double())
    for name, radius in (("hemisphere_hole", 2.0), ("hemisphere_disk", 2.0), ("cap_disk", 1.5)):
        assert torch.allclose(radius_of(name), torch.tensor(radius).double())
    cone = SURFACES["cone"]
    p = cone.positions(_samples(cone)) - torch.tensor(cone.origin)
    assert torch.allclose(p[:, :2].norm(dim=1), 1.0 - 0.35 * p[:, 2])
    plane = SURFACES["plane"]
    xi = _samples(plane)
    expected = torch.stack((1.0 + xi[:, 1], 2.0 + 0 * xi[:, 0], 3.0 + xi[:, 0]), dim=1)
    assert torch.allclose(plane.positions(xi), expected)


@pytest.mark.parametrize("name", ["cylinder", "cone", "roof", "hemisphere_hole",
                                  "hemisphere_disk"])
def test_normals_point_outwards(name):
    surface = SURFACES[name]
    j = surface.jets(_samples(surface))
    normal = torch.linalg.cross(j[:, 1], j[:, 2], dim=1)
    p = j[:, 0] - torch.tensor(surface.origin, dtype=torch.float64)
    if not name.startswith("hemisphere"):  # remove the axial component
        axis = {"roof": 1}.get(name, 2)
        p[:, axis] = 0.0
    assert ((normal * p).sum(dim=1) > 0).all()


@pytest.mark.parametrize("name", SURFACES)
def test_area_weighted_samples_integrate_the_surface_area(name):
    surface = SURFACES[name]
    samples = sample_surface(surface, 16384, generator=torch.Generator().manual_seed(1))
    j = samples.r_jets
    sqrt_a = torch.linalg.cross(j[:, 1], j[:, 2], dim=1).norm(dim=1)
    estimate = float((samples.weight * sqrt_a).sum())
    assert estimate == pytest.approx(AREAS[name], rel=2e-3)


def test_hemisphere_charts():
    assert SURFACES["hemisphere_hole"].chart == "polar"
    disk = SURFACES["hemisphere_disk"]
    assert disk.chart == "disk"
    assert disk.domain.area == pytest.approx(math.pi * math.pi**2)
    pole = disk.jets(torch.zeros(1, 2, dtype=torch.float64))[0]
    expected = torch.tensor([[0, 0, 2.0], [1, 0, 0], [0, 1, 0], [0, 0, -0.5], [0, 0, 0],
                             [0, 0, -0.5]], dtype=torch.float64)
    assert torch.allclose(pole, expected, atol=1e-15)
    hole = SURFACES["hemisphere_hole"].domain
    assert hole.periodic == (True, False)
    assert hole.bounds[1] == pytest.approx((0.0, math.radians(72)))


@pytest.mark.parametrize("make, match", [
    (lambda: Cylinder(radius=0.0), "radius"),
    (lambda: Cylinder(length=-1.0), "length"),
    (lambda: Cone(top_radius=0.0), "top_radius"),
    (lambda: Cone(height=float("nan")), "height"),
    (lambda: CylindricalRoof(half_angle=math.pi), "half_angle"),
    (lambda: Hemisphere(radius=-2.0), "radius"),
    (lambda: Hemisphere(rim_angle=math.pi), "rim_angle"),
    (lambda: Hemisphere(hole_half_angle=2.0), "hole_half_angle"),
    (lambda: Hemisphere(hole_half_angle=-0.1), "hole_half_angle"),
    (lambda: Plane(bounds=((0.0, 0.0), (0.0, 1.0))), "bounds"),
    (lambda: Annulus(inner_radius=0.0), "inner_radius"),
    (lambda: Annulus(inner_radius=1.0, outer_radius=1.0), "outer_radius"),
    (lambda: Annulus(angle=7.0), "angle"),
    (lambda: Annulus(angle=1.0, slit=True), "slit"),
    (lambda: Annulus(start_angle=math.inf), "start_angle"),
    (lambda: Plane(origin=(0.0, 1.0)), "origin"),
    (lambda: Plane(frame=((1, 0, 0), (1, 0, 0), (0, 0, 1))), "orthonormal"),
    (lambda: Plane(frame=((1, 0, 0), (0, 1, 0), (0, 0, -1))), "right-handed"),
])
def test_invalid_surfaces_raise(make, match):
    with pytest.raises(ValueError, match=match):
        make()


def test_domain_area_contains_and_periodic():
    d = ParameterDomain(((0, 2), (-1, 1)), periodic=(True, False))
    assert d.area == 4.0 and d.periodic == (True, False)
    xi = torch.tensor([[0.0, 0.0], [2.0, 1.0], [2.1, 0.0], [1.0, -1.5]], dtype=torch.float64)
    assert d.contains(xi).tolist() == [True, True, False, False]


def test_domain_samples_are_stratified():
    d = ParameterDomain(((0, 2), (0, 1)))
    xi = d.sample(200, torch.Generator().manual_seed(3))  # 20 x 10 cells of 0.1 x 0.1
    assert xi.shape == (200, 2)
    cells = (xi[:, 0] / 0.1).floor() * 10 + (xi[:, 1] / 0.1).floor()
    assert sorted(cells.long().tolist()) == list(range(200))
    again = d.sample(200, torch.Generator().manual_seed(3))
    assert torch.equal(xi, again)
    odd = d.sample(203, torch.Generator().manual_seed(3))
    assert odd.shape == (203, 2) and d.contains(odd).all()


def test_masked_domain():
    disk = ParameterDomain(((-1, 1), (-1, 1)), inside=lambda xi: (xi**2).sum(dim=1) <= 1)
    assert disk.area == pytest.approx(math.pi, rel=1e-3)
    xi = disk.sample(4000, torch.Generator().manual_seed(0))
    assert (xi.norm(dim=1) <= 1).all()
    assert xi.shape[0] / 4000 * 4 == pytest.approx(math.pi, rel=0.02)
    exact = ParameterDomain(((-1, 1), (-1, 1)), inside=disk.inside, mask_area=math.pi)
    assert exact.area == math.pi


@pytest.mark.parametrize("kwargs, match", [
    (dict(bounds=((0, 1),)), "bounds"),
    (dict(bounds=((0, 1), (1, 0))), r"bounds\[1\]"),
    (dict(bounds=((0, math.inf), (0, 1))), r"bounds\[0\]"),
    (dict(bounds=((0, 1), (0, 1)), mask_area=0.5), "mask_area"),
    (dict(bounds=((0, 1), (0, 1)), inside=lambda xi: xi[:, 0] > 0, mask_area=2.0), "mask_area"),
])
def test_invalid_domains_raise(kwargs, match):
    with pytest.raises(ValueError, match=match):
        ParameterDomain(**kwargs)


def test_bad_mask_and_sample_count_raise():
    bad = ParameterDomain(((0, 1), (0, 1)), inside=lambda xi: xi[:, 0])
    with pytest.raises(ValueError, match="bool tensor"):
        bad.sample(10)
    empty = ParameterDomain(((0, 1), (0, 1)), inside=lambda xi: xi[:, 0] > 2)
    with pytest.raises(ValueError, match="empty"):
        _ = empty.area
    with pytest.raises(ValueError, match="positive integer"):
        ParameterDomain(((0, 1), (0, 1))).sample(0)
