import math

import pytest
import torch

from taichi_ndf import jets
from taichi_ndf.boundary import (
    BoundaryConditions,
    ClampedEdge,
    Handle,
    HingedEdge,
    InteriorLine,
    PinnedPoint,
    RimRotation,
)
from taichi_ndf.geometry import ParameterDomain, ReferenceSurface

PLATE = ParameterDomain(((0.0, 2.0), (-1.0, 1.0)))
RADIUS, HEIGHT = 0.5, 1.2


class Cylinder(ReferenceSurface):
    """r(θ, z) = (R cos θ, R sin θ, z), periodic in θ."""

    def __init__(self):
        self.domain = ParameterDomain(((0.0, 2 * math.pi), (0.0, HEIGHT)), periodic=(True, False))

    def jets(self, xi):
        c, s = torch.cos(xi[:, 0]), torch.sin(xi[:, 0])
        out = xi.new_zeros(xi.shape[0], 6, 3)
        out[:, jets.VALUE] = torch.stack((RADIUS * c, RADIUS * s, xi[:, 1]), 1)
        out[:, jets.D1, 0], out[:, jets.D1, 1] = -RADIUS * s, RADIUS * c
        out[:, jets.D2, 2] = 1.0
        out[:, jets.D11, 0], out[:, jets.D11, 1] = -RADIUS * c, -RADIUS * s
        return out


def random_jets(n, seed=0):
    gen = torch.Generator().manual_seed(seed)
    return torch.randn(n, 6, 3, dtype=torch.float64, generator=gen)


def smooth_raw(xi):
    """Jets (N, 6, 3) of a smooth raw field N(ξ), in closed form from torch ops (so they are
    differentiable in ξ)."""
    x, y = xi[:, 0], xi[:, 1]
    s, c = torch.sin(x + 2 * y), torch.cos(x + 2 * y)
    s3, c3 = torch.sin(3 * x), torch.cos(3 * x)
    zero, one = torch.zeros_like(x), torch.ones_like(x)
    channels = (
        (s + 1, x * y + 0.5, c3 * y + 2),
        (c, y, -3 * s3 * y),
        (2 * c, x, c3),
        (-s, zero, -9 * c3 * y),
        (-2 * s, one, -3 * s3),
        (-4 * s, zero, zero),
    )
    return torch.stack([torch.stack(ch, 1) for ch in channels], 1)


def autograd_jets(f, xi):
    """Jets (N, 6, 3) of a pointwise function f: ξ (N, 2) -> values (N, 3) by torch autograd."""
    xi = xi.clone().requires_grad_(True)
    values = f(xi)
    out = []
    for c in range(3):
        (g,) = torch.autograd.grad(values[:, c].sum(), xi, create_graph=True)
        (h1,) = torch.autograd.grad(g[:, 0].sum(), xi, retain_graph=True)
        (h2,) = torch.autograd.grad(g[:, 1].sum(), xi, retain_graph=True)
        out.append(torch.stack((values[:, c], g[:, 0], g[:, 1], h1[:, 0], h1[:, 1], h2[:, 1]), 1))
    return torch.stack(out, 2).detach()


def on_segment(start, end, n=9):
    s = torch.linspace(0, 1, n, dtype=torch.float64)[:, None]
    return (
        torch.tensor(start, dtype=torch.float64) * (1 - s)
        + torch.tensor(end, dtype=torch.float64) * s
    )


MIXED = [
    ClampedEdge("xi1_min"),
    HingedEdge("xi2_min", components="xy"),
    PinnedPoint((1.0, 0.0)),
    Handle((1.5, 0.5), (0.1, 0.2, 0.3)),
    InteriorLine((0.5, 0.2), (1.0, 0.7)),
    InteriorLine((1.8, -1.0), (1.8, 1.0), extend=True, hinged=True, components="z"),
]


def test_composed_jets_are_the_derivatives_of_the_composed_field():
    bc = BoundaryConditions(MIXED, PLATE)
    gen = torch.Generator().manual_seed(0)
    xi = torch.rand(16, 2, dtype=torch.float64, generator=gen) * 2 - torch.tensor([0.0, 1.0])
    # Points near every constraint set and inside their bands.
    xi = torch.cat(
        (
            xi,
            torch.tensor(
                [
                    [0.05, 0.3],
                    [1.0, -0.95],
                    [1.05, 0.05],
                    [1.45, 0.55],
                    [0.7, 0.45],
                    [1.02, 0.72],
                    [1.78, 0.1],
                    [1.83, -0.4],
                ]
            ),
        )
    )

    torch.testing.assert_close(
        smooth_raw(xi), autograd_jets(lambda q: smooth_raw(q)[:, jets.VALUE], xi)
    )

    def u(q):
        return bc.compose(q, smooth_raw(q), t=0.7)[:, jets.VALUE]

    torch.testing.assert_close(
        bc.compose(xi, smooth_raw(xi), t=0.7), autograd_jets(u, xi), rtol=1e-10, atol=1e-10
    )


def test_adjoint_is_the_transpose_of_compose():
    bc = BoundaryConditions(MIXED, PLATE)
    gen = torch.Generator().manual_seed(1)
    xi = torch.rand(200, 2, dtype=torch.float64, generator=gen) * 2 - torch.tensor([0.0, 1.0])
    raw = random_jets(200, seed=2).requires_grad_(True)
    grad_u = random_jets(200, seed=3)
    (bc.compose(xi, raw, t=0.4) * grad_u).sum().backward()
    torch.testing.assert_close(
        bc.compose_adjoint(xi, grad_u, t=0.4), raw.grad, rtol=1e-13, atol=1e-13
    )


def test_edges_hold_values_and_clamps_hold_slopes():
    bc = BoundaryConditions(
        [
            ClampedEdge("xi1_min"),
            HingedEdge("xi1_max"),
            ClampedEdge("xi2_min", components="z"),
            HingedEdge("xi2_max", components="xy"),
        ],
        PLATE,
    )
    # Away from the corners, where two edge conditions combine.
    along = torch.linspace(-0.8, 0.8, 11, dtype=torch.float64)
    across = torch.linspace(0.3, 1.7, 11, dtype=torch.float64)
    raw = random_jets(11)
    left = bc.compose(torch.stack((torch.zeros(11), along), 1).double(), raw)
    assert left[:, :3].abs().max() < 1e-15  # value and both slopes: clamped
    right = bc.compose(torch.stack((torch.full((11,), 2.0), along), 1).double(), raw)
    assert right[:, [jets.VALUE, jets.D2, jets.D22]].abs().max() < 1e-15
    assert right[:, jets.D1].abs().min() > 0  # hinged: free to rotate
    bottom = bc.compose(torch.stack((across, torch.full((11,), -1.0)), 1).double(), raw)
    assert bottom[:, :3, 2].abs().max() < 1e-15  # z clamped
    assert bottom[:, jets.VALUE, :2].abs().min() > 0  # x, y free
    top = bc.compose(torch.stack((across, torch.ones(11)), 1).double(), raw)
    assert top[:, [jets.VALUE, jets.D1, jets.D11], :2].abs().max() < 1e-15
    assert top[:, jets.VALUE, 2].abs().min() > 0


def test_field_is_untouched_outside_the_bands():
    bc = BoundaryConditions(MIXED, PLATE, length=0.05)
    xi = torch.tensor([[0.3, -0.5], [1.2, 0.5], [0.6, -0.3]], dtype=torch.float64)
    phi = bc.vanishing_factor(xi)
    assert torch.equal(phi, jets.constant(torch.ones(3, 3, dtype=torch.float64)))


def test_an_edge_band_wider_than_the_domain_is_one_polynomial():
    """Clamped edge, band ℓ = 2: φ = 1 − (1 − (η/ℓ)²)³ over the whole domain (no cutoff)."""
    bc = BoundaryConditions([ClampedEdge("xi1_min", length=2.0)], PLATE)
    x = torch.linspace(0.0, 2.0, 9, dtype=torch.float64)
    xi = torch.stack((x, torch.zeros_like(x)), 1)
    phi = bc.vanishing_factor(xi)[:, :, 0]
    q = (x / 2.0 / 2.0) ** 2  # η = x / 2 on PLATE, ℓ = 2
    dq, d2q = 2 * (x / 4.0) / 4.0, 2 / 16.0
    assert torch.allclose(phi[:, jets.VALUE], 1 - (1 - q) ** 3, rtol=0, atol=1e-15)
    assert torch.allclose(phi[:, jets.D1], 3 * (1 - q) ** 2 * dq, rtol=0, atol=1e-15)
    assert torch.allclose(phi[:, jets.D11], -6 * (1 - q) * dq**2 + 3 * (1 - q) ** 2 * d2q,
                          rtol=0, atol=1e-15)
    assert float(phi[-1, jets.VALUE]) < 0.6  # still rising at the far edge


def test_interior_point_segment_and_line_hold():
    bc = BoundaryConditions(MIXED, PLATE)
    raw = random_jets(9, seed=4)
    point = bc.compose(torch.tensor([[1.0, 0.0]] * 9, dtype=torch.float64), raw)
    assert point[:, :3].abs().max() < 1e-15
    segment = bc.compose(on_segment((0.5, 0.2), (1.0, 0.7)), raw)
    assert segment[:, :3].abs().max() < 1e-14
    line = bc.compose(on_segment((1.8, -1.0), (1.8, 1.0)), raw)
    assert line[:, [jets.VALUE, jets.D2, jets.D22], 2].abs().max() < 1e-15
    assert line[:, jets.D1, 2].abs().min() > 0  # hinged line: slope across it free


@pytest.mark.parametrize("t", [0.0, 0.3, 1.0])
def test_handle_moves_with_pseudo_time(t):
    bc = BoundaryConditions(MIXED, PLATE)
    raw = random_jets(11, seed=5)
    at = bc.compose(torch.tensor([[1.5, 0.5]], dtype=torch.float64), raw[:1], t=t)[0]
    torch.testing.assert_close(
        at[jets.VALUE], t * torch.tensor([0.1, 0.2, 0.3], dtype=torch.float64), rtol=0, atol=1e-15
    )
    assert at[1:3].abs().max() < 1e-14  # the handle translates without turning
    edge = bc.compose(
        torch.stack((torch.zeros(11), torch.linspace(-1, 1, 11)), 1).double(), raw, t=t
    )
    assert edge[:, :3].abs().max() < 1e-15


def rotation(axis, angle):
    k = torch.tensor(axis, dtype=torch.float64)
    k = k / k.norm()
    cross = torch.tensor(
        [[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]], dtype=torch.float64
    )
    return (
        torch.eye(3, dtype=torch.float64)
        + math.sin(angle) * cross
        + (1 - math.cos(angle)) * cross @ cross
    )


@pytest.mark.parametrize("t", [0.5, 1.0])
def test_rim_rotation_is_an_exact_rigid_motion(t):
    surface = Cylinder()
    axis, point, angle = (1.0, 0.0, 1.0), (0.0, 0.0, 0.6), 2.0
    bc = BoundaryConditions(
        [ClampedEdge("xi2_min"), RimRotation("xi2_max", axis_point=point, axis=axis, angle=angle)],
        surface.domain,
        surface=surface,
    )
    theta = torch.linspace(0, 2 * math.pi, 13, dtype=torch.float64)
    rim = torch.stack((theta, torch.full_like(theta, HEIGHT)), 1)
    r = surface.jets(rim)
    x = r + bc.compose(rim, random_jets(13, seed=6), t=t)
    rot, p = rotation(axis, t * angle), torch.tensor(point, dtype=torch.float64)
    torch.testing.assert_close(
        x[:, jets.VALUE], (r[:, jets.VALUE] - p) @ rot.T + p, rtol=0, atol=1e-14
    )
    # The tangent plane turns with the cuff: x_,α = R r_,α.
    torch.testing.assert_close(
        x[:, jets.D1 : jets.D2 + 1], r[:, jets.D1 : jets.D2 + 1] @ rot.T, rtol=0, atol=1e-14
    )
    base = torch.stack((theta, torch.zeros_like(theta)), 1)
    assert bc.compose(base, random_jets(13, seed=7), t=t)[:, :3].abs().max() < 1e-15


def test_fields_are_continuous_across_the_periodic_seam():
    surface = Cylinder()
    bc = BoundaryConditions(
        [
            PinnedPoint((0.1, 0.5)),
            InteriorLine((6.0, 0.2), (6.2, 0.9)),
            RimRotation("xi2_max", axis_point=(0, 0, 0), axis=(0, 0, 1), angle=0.5),
            HingedEdge("xi2_min", components="xy"),
            InteriorLine((0.0, 0.7), (1.0, 0.7), extend=True),
        ],
        surface.domain,
        surface=surface,
        length=0.2,
    )
    z = torch.linspace(0, HEIGHT, 7, dtype=torch.float64)
    raw = random_jets(7, seed=8)
    seam0 = bc.compose(torch.stack((torch.zeros_like(z), z), 1), raw)
    seam1 = bc.compose(torch.stack((torch.full_like(z, 2 * math.pi), z), 1), raw)
    torch.testing.assert_close(seam0, seam1, rtol=0, atol=1e-13)


def test_rigid_diaphragm_leaves_the_axial_component_free():
    surface = Cylinder()
    bc = BoundaryConditions([HingedEdge("xi2_min", components="xy")], surface.domain)
    theta = torch.linspace(0, 6, 7, dtype=torch.float64)
    u = bc.compose(torch.stack((theta, torch.zeros_like(theta)), 1), random_jets(7, seed=9))
    assert u[:, jets.VALUE, :2].abs().max() < 1e-15
    assert u[:, jets.VALUE, 2].abs().min() > 0


def test_components_of_disjoint_constraints_may_share_a_place():
    bc = BoundaryConditions(
        [
            HingedEdge("xi2_min", components="xy"),
            Handle((1.0, -1.0), (0.0, 0.0, 0.2), components="z"),
        ],
        PLATE,
    )
    u = bc.compose(torch.tensor([[1.0, -1.0]], dtype=torch.float64), random_jets(1), t=0.5)[0]
    torch.testing.assert_close(
        u[jets.VALUE], torch.tensor([0.0, 0.0, 0.1], dtype=torch.float64), rtol=0, atol=1e-15
    )


@pytest.mark.parametrize(
    ("constraints", "domain", "message"),
    [
        ([PinnedPoint((3.0, 0.0))], PLATE, "outside the parameter domain"),
        ([Handle((1.0, 1.5), (0, 0, 1))], PLATE, "outside the parameter domain"),
        ([InteriorLine((0.5, 0.0), (2.5, 0.0))], PLATE, "leaves the parameter domain"),
        ([InteriorLine((3.0, 0.0), (3.0, 1.0), extend=True)], PLATE, "misses the domain"),
        ([ClampedEdge("xi1_min")], Cylinder().domain, "periodic"),
        ([ClampedEdge("xi1_min"), Handle((0.0, 0.3), (0, 0, 0.1))], PLATE, "contradictory"),
        ([PinnedPoint((1.0, 0.0)), Handle((1.0, 0.0), (0.1, 0, 0))], PLATE, "contradictory"),
        (
            [InteriorLine((0.5, 0.0), (1.5, 0.0)), Handle((1.0, 0.0), (0.1, 0, 0))],
            PLATE,
            "contradictory",
        ),
        (
            [ClampedEdge("xi1_min"), ClampedEdge("xi2_max", displacement=(0.1, 0, 0))],
            PLATE,
            "contradictory",
        ),
        ([RimRotation("xi1_max", (0, 0, 0), (0, 0, 1), 1.0)], PLATE, "needs the reference surface"),
        ([InteriorLine((0.0, 0.1), (1.0, 0.5), extend=True)], Cylinder().domain, "parallel"),
        (
            [InteriorLine((1.0, 0.1), (1.0, 0.5), extend=True, hinged=True)],
            Cylinder().domain,
            "hinged line across",
        ),
        ([InteriorLine((0.5, 0.1), (6.0, 0.5))], Cylinder().domain, "whole period"),
    ],
)
def test_invalid_constraints_are_refused(constraints, domain, message):
    with pytest.raises(ValueError, match=message):
        BoundaryConditions(constraints, domain)


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (lambda: ClampedEdge("left"), "edge must be one of"),
        (lambda: HingedEdge("xi1_min", components="xw"), "components"),
        (lambda: PinnedPoint((0.0, 0.0), components=""), "components"),
        (lambda: PinnedPoint((0.0, math.nan)), "xi must be 2 finite numbers"),
        (lambda: Handle((0.0, 0.0), (1.0, 2.0)), "displacement must be 3"),
        (lambda: InteriorLine((0.0, 0.0), (0.0, 0.0)), "coincide"),
        (lambda: InteriorLine((0.0, 0.0), (1.0, 0.0), hinged=True), "needs extend=True"),
        (lambda: RimRotation("xi2_max", (0, 0, 0), (0, 0, 0), 1.0), "axis must be a non-zero"),
        (lambda: RimRotation("xi2_max", (0, 0, 0), (0, 0, 1), math.inf), "angle"),
        (lambda: ClampedEdge("xi1_min", length=-1.0), "length"),
        (lambda: PinnedPoint((0.5, 0.5), length=0.7), "length"),
        (lambda: BoundaryConditions([PinnedPoint((0.5, 0.5))], PLATE, length=0.7), "below 0.5"),
        (lambda: BoundaryConditions([], PLATE, length=0.0), "length"),
    ],
)
def test_invalid_parameters_are_refused(make, message):
    with pytest.raises(ValueError, match=message):
        make()


def test_pseudo_time_must_be_finite():
    bc = BoundaryConditions([Handle((1.0, 0.0), (0.1, 0, 0))], PLATE)
    with pytest.raises(ValueError, match="pseudo-time"):
        bc.compose(torch.zeros(1, 2, dtype=torch.float64), random_jets(1), t=math.nan)


def test_per_sample_pseudo_time_equals_one_time_per_sample():
    # Handles, a moved clamped edge and a rotating rim: compose with one t per sample gives,
    # row by row, the composition at that sample's t (per-sample rotation matrices included).
    surface = Cylinder()
    cases = [
        (BoundaryConditions(MIXED, PLATE), PLATE, None),
        (BoundaryConditions([ClampedEdge("xi1_min", displacement=(0.1, -0.2, 0.05)),
                             HingedEdge("xi1_max")], PLATE), PLATE, None),
        (BoundaryConditions([ClampedEdge("xi2_min"),
                             RimRotation("xi2_max", axis_point=(0.0, 0.0, 0.6),
                                         axis=(1.0, 0.0, 1.0), angle=2.0)],
                            surface.domain, surface=surface), surface.domain, surface),
    ]
    gen = torch.Generator().manual_seed(3)
    for bc, domain, _ in cases:
        xi = domain.sample(40, gen).double()
        raw = random_jets(len(xi), seed=9)
        t = torch.rand(len(xi), generator=gen, dtype=torch.float64)
        together = bc.compose(xi, raw, t=t)
        one_by_one = torch.cat([bc.compose(xi[i:i + 1], raw[i:i + 1], t=float(t[i]))
                                for i in range(len(xi))])
        torch.testing.assert_close(together, one_by_one, rtol=1e-13, atol=1e-14)
        torch.testing.assert_close(bc.prescribed_displacement(xi, t),
                                   torch.cat([bc.prescribed_displacement(xi[i:i + 1], float(t[i]))
                                              for i in range(len(xi))]), rtol=1e-13, atol=1e-14)
        torch.testing.assert_close(bc.compose_adjoint(xi, raw, t=t), bc.compose_adjoint(xi, raw))


def test_per_sample_rim_rotation_is_an_exact_rigid_motion():
    surface = Cylinder()
    axis, point, angle = (1.0, 0.0, 1.0), (0.0, 0.0, 0.6), 2.0
    bc = BoundaryConditions(
        [ClampedEdge("xi2_min"), RimRotation("xi2_max", axis_point=point, axis=axis, angle=angle)],
        surface.domain, surface=surface)
    theta = torch.linspace(0, 2 * math.pi, 13, dtype=torch.float64)
    rim = torch.stack((theta, torch.full_like(theta, HEIGHT)), 1)
    t = torch.linspace(0.0, 1.0, 13, dtype=torch.float64)
    r = surface.jets(rim)
    x = r + bc.compose(rim, random_jets(13, seed=6), t=t)
    p = torch.tensor(point, dtype=torch.float64)
    for i in range(13):
        rot = rotation(axis, float(t[i]) * angle)
        torch.testing.assert_close(x[i, jets.VALUE], (r[i, jets.VALUE] - p) @ rot.T + p,
                                   rtol=0, atol=1e-14)
        torch.testing.assert_close(x[i, jets.D1:jets.D2 + 1], r[i, jets.D1:jets.D2 + 1] @ rot.T,
                                   rtol=0, atol=1e-14)


def test_per_sample_pseudo_time_is_checked():
    bc = BoundaryConditions([Handle((1.0, 0.0), (0.1, 0, 0))], PLATE)
    xi = torch.zeros(2, 2, dtype=torch.float64)
    with pytest.raises(ValueError, match="shape"):
        bc.compose(xi, random_jets(2), t=torch.ones(3, dtype=torch.float64))
    with pytest.raises(ValueError, match="finite"):
        bc.compose(xi, random_jets(2), t=torch.tensor([0.5, math.inf], dtype=torch.float64))
