"""Obstacles: signed distances at known points, gradients against central differences, the
closed mesh against the exact torus, and the errors that name a bad obstacle."""

import math
import time
from pathlib import Path

import numpy as np
import pytest
import torch

from taichi_ndf.contact import (
    Capsule,
    Cylinder,
    GroundPlane,
    MeshObstacle,
    RoundedBox,
    Sphere,
)

F64 = torch.float64
TORUS = Path(__file__).resolve().parents[1] / "data" / "torus.obj"

ANALYTIC = [
    GroundPlane(point=(0.0, 0.0, -0.1), normal=(0.0, 1.0, 1.0)),
    Sphere(centre=(0.1, 0.0, 0.0), radius=0.3),
    RoundedBox(centre=(0.0, 0.1, 0.0), half_extents=(0.3, 0.2, 0.25), rounding=0.05),
    Capsule(start=(-0.2, 0.0, 0.0), end=(0.3, 0.1, 0.0), radius=0.1),
    Cylinder(start=(-0.2, 0.0, 0.0), end=(0.3, 0.1, 0.0), radius=0.15),
]


def points(n=200, seed=0, scale=0.8):
    g = torch.Generator().manual_seed(seed)
    return scale * (torch.rand(n, 3, generator=g, dtype=F64) - 0.5)


@pytest.mark.parametrize("obstacle", ANALYTIC + [None], ids=lambda o: getattr(o, "name", "mesh"))
def test_gradient_is_the_central_difference_and_a_unit_vector(obstacle):
    if obstacle is None:
        obstacle = MeshObstacle.from_file(TORUS)
    x = points()
    d, n = obstacle.signed_distance(x, 0.5)
    step = 1e-6
    for k in range(3):
        e = torch.zeros(3, dtype=F64)
        e[k] = step
        fd = (obstacle.signed_distance(x + e, 0.5)[0] - obstacle.signed_distance(x - e, 0.5)[0])
        fd = fd / (2 * step)
        # edges of the rounded box / cylinder and the mesh's Voronoi boundaries: C¹ only,
        # so a few points straddle a kink; nearly all agree to rounding
        close = (fd - n[:, k]).abs() < 1e-6
        assert close.float().mean() > 0.97
    assert torch.allclose(n.norm(dim=1), torch.ones_like(d), atol=1e-9)


def test_known_distances():
    x = torch.tensor([[0.1, 0.0, 0.5], [0.1, 0.0, 0.0]], dtype=F64)
    d, _ = Sphere(centre=(0.1, 0.0, 0.0), radius=0.3).signed_distance(x)
    assert d.tolist() == pytest.approx([0.2, -0.3])
    box = RoundedBox(half_extents=(0.3, 0.2, 0.25), rounding=0.05)
    # beyond a rounded corner: the distance to the corner sphere of radius 0.05
    corner = torch.tensor([[0.25, 0.15, 0.2]], dtype=F64) + 0.1 / math.sqrt(3)
    d, _ = box.signed_distance(torch.cat((corner, torch.tensor(
        [[0.0, 0.0, 0.4], [0.0, 0.0, 0.0]], dtype=F64))))
    assert d.tolist() == pytest.approx([0.05, 0.15, -0.2])
    cyl = Cylinder(start=(0.0, 0.0, 0.0), end=(1.0, 0.0, 0.0), radius=0.1)
    d, _ = cyl.signed_distance(torch.tensor([[1.3, 0.4, 0.0], [0.5, 0.0, 0.3]], dtype=F64))
    assert d.tolist() == pytest.approx([math.hypot(0.3, 0.3), 0.2])  # beyond the rim
    cap = Capsule(start=(0.0, 0.0, 0.0), end=(1.0, 0.0, 0.0), radius=0.1)
    d, _ = cap.signed_distance(torch.tensor([[1.3, 0.4, 0.0]], dtype=F64))
    assert d.tolist() == pytest.approx([0.4])


def test_motion_translates_the_obstacle_with_the_load_factor():
    sphere = Sphere(centre=(0.0, 0.0, 0.0), radius=0.1, motion=(0.0, 0.0, 0.2))
    x = torch.tensor([[0.0, 0.0, 0.3]], dtype=F64)
    assert float(sphere.signed_distance(x, 0.0)[0]) == pytest.approx(0.2)
    assert float(sphere.signed_distance(x, 0.5)[0]) == pytest.approx(0.1)
    vertices, _ = sphere.triangles(0.5)
    assert vertices[:, 2].max() == pytest.approx(0.2, abs=1e-9)


def test_mesh_torus_matches_the_exact_torus_within_its_facets(capsys):
    torus = MeshObstacle.from_file(TORUS)
    x = points(2000, seed=1) * torch.tensor([1.1, 1.1, 0.4], dtype=F64)
    torus.signed_distance(x[:4])  # compile
    start = time.perf_counter()
    d, _ = torus.signed_distance(x)
    elapsed = time.perf_counter() - start
    rho = x[:, :2].norm(dim=1)
    exact = ((rho - 0.25) ** 2 + x[:, 2] ** 2).sqrt() - 0.08
    assert float((d - exact).abs().max()) < 3.2e-3  # chord sag of the 32 x 16 facets
    assert bool(torch.all(((d < 0) == (exact < 0)) | (exact.abs() < 3.2e-3)))
    with capsys.disabled():
        print(f"\nmesh obstacle: {elapsed / (len(x) * len(torus.faces)) * 1e9:.0f} ns per "
              f"point-triangle pair ({len(x)} points, {len(torus.faces)} triangles)")


def test_mesh_obstacles_sign_does_not_depend_on_triangle_orientation():
    torus = MeshObstacle.from_file(TORUS)
    flipped = MeshObstacle(vertices=torus.vertices, faces=torus.faces[:, ::-1].copy())
    x = points(300, seed=2)
    assert torch.allclose(torus.signed_distance(x)[0], flipped.signed_distance(x)[0])


@pytest.mark.parametrize("build, message", [
    (lambda: Sphere(radius=0.0), "radius must be > 0"),
    (lambda: Capsule(start=(0, 0, 0), end=(0, 0, 0), radius=0.1), "zero length"),
    (lambda: Cylinder(radius=-1.0), "radius must be > 0"),
    (lambda: RoundedBox(half_extents=(0.1, 0.2, 0.3), rounding=0.1), "rounding must be"),
    (lambda: GroundPlane(normal=(0, 0, 0)), "normal must be non-zero"),
    (lambda: Sphere(centre=(0, float("nan"), 0)), "centre"),
])
def test_bad_obstacles_are_refused_with_the_problem_named(build, message):
    with pytest.raises(ValueError, match=message):
        build()


def test_open_mesh_is_refused():
    torus = MeshObstacle.from_file(TORUS)
    with pytest.raises(ValueError, match="not closed"):
        MeshObstacle(name="holey", vertices=torus.vertices, faces=np.asarray(torus.faces)[1:])
