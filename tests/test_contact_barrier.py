"""The IPC barrier and the contact term: derivatives against central differences (also across
the floor and the activation distance), the term's gradient with respect to the displacement
jets, PSD Hessian blocks (exact for a plane), and the dense check points."""

from pathlib import Path

import pytest
import torch

from taichi_ndf import jets
from taichi_ndf.contact import ContactPoints, ContactTerm, GroundPlane, MeshObstacle, Sphere
from taichi_ndf.contact.barrier import FLOOR_RATIO, barrier
from taichi_ndf.geometry import Plane
from taichi_ndf.problem.sampling import sample_surface

F64 = torch.float64
TORUS = Path(__file__).resolve().parents[1] / "data" / "torus.obj"
ACTIVATION = 0.01


def test_barrier_derivatives_against_central_differences():
    gap = torch.cat((torch.linspace(-2e-5, 1.2 * ACTIVATION, 400, dtype=F64),
                     torch.tensor([0.5, 1.5, 2.0], dtype=F64) * ACTIVATION * FLOOR_RATIO))
    b, db, ddb = barrier(gap, ACTIVATION)
    h = 1e-9
    bp, dbp, _ = barrier(gap + h, ACTIVATION)
    bm, dbm, _ = barrier(gap - h, ACTIVATION)
    assert torch.allclose((bp - bm) / (2 * h), db, rtol=1e-6, atol=1e-9)
    assert torch.allclose((dbp - dbm) / (2 * h), ddb, rtol=1e-5, atol=1e-6)
    assert torch.all(b[gap >= ACTIVATION] == 0) and torch.all(db[gap >= ACTIVATION] == 0)
    inside = gap < ACTIVATION
    assert torch.all(b[inside] > 0) and torch.all(db[inside] < 0) and torch.all(ddb[inside] > 0)


def test_barrier_is_continuous_with_two_derivatives_at_the_floor_and_activation():
    for at in (ACTIVATION * FLOOR_RATIO, ACTIVATION):
        left = barrier(torch.tensor([at - 1e-12], dtype=F64), ACTIVATION)
        right = barrier(torch.tensor([at + 1e-12], dtype=F64), ACTIVATION)
        for lo, hi in zip(left, right, strict=True):
            assert float(lo) == pytest.approx(float(hi), rel=1e-6, abs=1e-9)


def surface_samples(n=48):
    surface = Plane(bounds=((-0.3, 0.3), (-0.3, 0.3)))
    return sample_surface(surface, n, None, torch.Generator().manual_seed(4), dtype=F64)


def displacement_near(term, samples, seed=5):
    """Displacement jets that put the sample points at gaps in (0.1, 0.9) ĝ along the
    obstacle normal, with small random other channels."""
    g = torch.Generator().manual_seed(seed)
    u = 1e-3 * torch.randn(len(samples), 6, 3, generator=g, dtype=F64)
    x = samples.r_jets[:, jets.VALUE]
    gap, normal = term.gaps(x)
    target = ACTIVATION * (0.1 + 0.8 * torch.rand(len(samples), generator=g, dtype=F64))
    u[:, jets.VALUE] = (target - gap[:, 0])[:, None] * normal[:, 0]
    return u


OBSTACLES = {
    "plane": GroundPlane(point=(0.0, 0.0, -0.05), normal=(0.2, 0.1, 1.0)),
    "sphere": Sphere(centre=(0.0, 0.0, -0.3), radius=0.25),
    "mesh": None,
}


@pytest.mark.parametrize("name", list(OBSTACLES))
def test_term_gradient_against_central_differences(name):
    obstacle = OBSTACLES[name] or MeshObstacle.from_file(TORUS, offset=(0.0, 0.0, -0.2))
    term = ContactTerm([obstacle], offset=0.002, activation=ACTIVATION, stiffness=300.0)
    samples = surface_samples()
    u = displacement_near(term, samples)
    value, grad = term.evaluate(samples, u, 1.0)
    assert value > 0
    assert torch.all(grad[:, 1:] == 0)
    step = 1e-8
    for k in range(3):
        up, down = u.clone(), u.clone()
        up[:, jets.VALUE, k] += step
        down[:, jets.VALUE, k] -= step
        # one sample at a time: the term is a sum over samples, so perturbing all of them
        # at once and comparing per-sample differences is exact
        per_up = term_values(term, samples, up)
        per_down = term_values(term, samples, down)
        fd = (per_up - per_down) / (2 * step)
        assert torch.allclose(fd, grad[:, jets.VALUE, k], rtol=1e-5, atol=1e-9 * fd.abs().max())


def term_values(term, samples, u):
    """Per-sample contributions of the term (value with all but one sample weighted 0)."""
    from taichi_ndf.contact.barrier import barrier as b_of

    x = samples.r_jets[:, jets.VALUE] + u[:, jets.VALUE]
    gap, _ = term.gaps(x)
    b, _, _ = b_of(gap, term.activation)
    return (term.weights(samples)[:, None] * b).sum(dim=1)


def test_hessian_blocks_are_psd_and_exact_for_a_plane():
    samples = surface_samples(32)
    plane = ContactTerm([OBSTACLES["plane"]], offset=0.002, activation=ACTIVATION,
                        stiffness=300.0)
    u = displacement_near(plane, samples)
    full = plane.hessian_blocks(samples, u)
    outside = full.clone()
    outside[:, jets.VALUE, :, jets.VALUE, :] = 0.0
    assert float(outside.abs().max()) == 0.0  # only the value channel carries the barrier
    blocks = full[:, jets.VALUE, :, jets.VALUE, :]
    step = 1e-8
    for k in range(3):
        up, down = u.clone(), u.clone()
        up[:, jets.VALUE, k] += step
        down[:, jets.VALUE, k] -= step
        fd = (plane.evaluate(samples, up)[1] - plane.evaluate(samples, down)[1]) / (2 * step)
        assert torch.allclose(fd[:, jets.VALUE], blocks[:, :, k], rtol=1e-5,
                              atol=1e-7 * float(blocks.abs().max()))
    sphere = ContactTerm([OBSTACLES["sphere"]], offset=0.002, activation=ACTIVATION,
                         stiffness=300.0)
    blocks = sphere.hessian_blocks(samples, displacement_near(sphere, samples))[
        :, jets.VALUE, :, jets.VALUE, :]
    assert float(torch.linalg.eigvalsh(blocks).min()) >= -1e-9 * float(blocks.abs().max())


def test_check_points_are_the_grid_points_that_came_close():
    surface = Plane(bounds=((-0.3, 0.3), (-0.3, 0.3)))
    sphere = Sphere(centre=(0.0, 0.0, -0.25), radius=0.25)
    term = ContactTerm([sphere], offset=0.001, activation=ACTIVATION, stiffness=1.0)
    points = ContactPoints(term, surface, 33)
    assert points.count == 0
    assert float(points.grid_weight.sum()) == pytest.approx(0.36)
    min_gap = points.refresh(lambda xi: torch.zeros(len(xi), 3, dtype=F64), 1.0)
    assert min_gap == pytest.approx(-0.001)
    # within ĝ of the top of the sphere: ‖ξ‖ up to about √(2 R (ĝ + h/2))
    assert 1 <= points.count < 33 * 33 // 10
    samples = points.augment(surface_samples(16))
    assert len(samples) == 16 + points.count
    assert torch.all(samples.barrier_weight[:16] == 0) and torch.all(samples.weight[16:] == 0)
