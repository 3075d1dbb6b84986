"""Line loads: validation, quadrature (resultant and moment exact), scaling, work, scenes."""

import math

import pytest
import torch

from taichi_ndf.geometry import Cylinder, Plane
from taichi_ndf.problem.line_loads import LineLoad, edge_path, quadrature
from taichi_ndf.problem.loads import Loads
from taichi_ndf.problem.sampling import sample_surface
from taichi_ndf.shell import ShellEnergy, preset

F64 = torch.float64


def test_resultant_and_moment_of_a_polyline_on_a_placed_plane_are_exact():
    # A placed, rotated plane: r is affine in ξ, so |dr/ds| is constant per segment and the
    # moment ∫ r × q dℓ is the integral of a linear function: exact with one node or more.
    c, s = math.cos(0.3), math.sin(0.3)
    plane = Plane(bounds=((0, 2), (0, 1)), origin=(1.0, -2.0, 0.5),
                  frame=((c, s, 0.0), (-s, c, 0.0), (0.0, 0.0, 1.0)))
    path = ((0.0, 0.0), (2.0, 1.0), (1.0, 1.0), (0.5, 0.25))
    q = (0.5, -1.0, 3.0)
    for nodes in (1, 3):
        xi, force = quadrature(plane, [LineLoad(path, q, nodes)], dtype=F64)
        assert xi.shape == (3 * nodes, 2)
        r = plane.positions(xi)
        length, moment = 0.0, torch.zeros(3, dtype=F64)
        for a, b in zip(path, path[1:], strict=False):
            ra, rb = plane.positions(torch.tensor([a, b], dtype=F64))
            seg = float((rb - ra).norm())
            length += seg
            moment += seg * torch.linalg.cross(0.5 * (ra + rb), torch.tensor(q, dtype=F64))
        assert torch.allclose(force.sum(0), length * torch.tensor(q, dtype=F64), rtol=1e-14)
        assert torch.allclose(torch.linalg.cross(r, force).sum(0), moment, rtol=1e-13,
                              atol=1e-13)


def test_resultant_and_moment_along_a_cylinder_rim():
    # The rim ξ² = L of a cylinder: a circle of radius R; a radial-free constant q gives the
    # resultant 2πR q and the moment ∫ r × q dℓ = 2πR (0, 0, L) × q (the circle's centroid).
    radius, length = 2.0, 3.0
    cylinder = Cylinder(radius=radius, length=length)
    q = torch.tensor([1.0, 2.0, -0.5], dtype=F64)
    load = LineLoad(edge_path("xi2_max", cylinder.domain.bounds), tuple(q.tolist()), nodes=24)
    xi, force = quadrature(cylinder, [load], dtype=F64)
    arc = 2 * math.pi * radius
    assert torch.allclose(force.sum(0), arc * q, rtol=1e-14)
    expected = arc * torch.linalg.cross(torch.tensor([0.0, 0.0, length], dtype=F64), q)
    assert torch.allclose(torch.linalg.cross(cylinder.positions(xi), force).sum(0), expected,
                          atol=1e-12)


def test_work_on_a_translation_and_the_load_factor():
    plane = Plane(bounds=((0, 2), (0, 1)))
    loads = Loads(line_loads=(LineLoad(edge_path("xi1_max", plane.domain.bounds),
                                       (0.0, 0.0, -4.0)),))
    samples = sample_surface(plane, 64, loads.scaled(0.5), torch.Generator().manual_seed(0),
                             dtype=F64, device="cpu")
    assert len(samples) == 64 + 8 and bool((samples.weight[64:] == 0).all())
    u = torch.zeros(len(samples), 6, 3, dtype=F64)
    u[:, 0] = torch.tensor([0.1, 0.2, 0.3], dtype=F64)
    work = ShellEnergy(preset("cloth"), Loads()).evaluate(samples, u, grad=False).external
    assert work == pytest.approx(-(0.5 * -4.0 * 1.0) * 0.3, rel=1e-13)   # −λ q·u L


def test_line_nodes_come_before_point_loads():
    plane = Plane()
    loads = Loads(point_loads=[((0.5, 0.5), (0, 0, 1.0))],
                  line_loads=(LineLoad(((0, 0), (1, 0)), (1.0, 0, 0), nodes=2),))
    samples = sample_surface(plane, 16, loads, torch.Generator().manual_seed(0), dtype=F64,
                             device="cpu")
    assert samples.point_force[-1].tolist() == [0.0, 0.0, 1.0]
    assert samples.point_force[-3:-1, 0].sum().item() == pytest.approx(1.0)


@pytest.mark.parametrize("make, match", [
    (lambda: LineLoad(((0, 0),), (0, 0, 1)), "at least 2"),
    (lambda: LineLoad(((0, 0), (0, 0)), (0, 0, 1)), "equal consecutive"),
    (lambda: LineLoad(((0, 0), (1, math.nan)), (0, 0, 1)), "path point"),
    (lambda: LineLoad(((0, 0), (1, 0)), (0, 1)), "force"),
    (lambda: LineLoad(((0, 0), (1, 0)), (0, 0, 1), nodes=0), "nodes"),
    (lambda: edge_path("left", ((0, 1), (0, 1))), "edge"),
])
def test_invalid_line_loads_raise(make, match):
    with pytest.raises(ValueError, match=match):
        make()


def test_path_outside_the_domain_is_refused():
    loads = Loads(line_loads=(LineLoad(((0, 0), (1.5, 0)), (0, 0, 1)),))
    with pytest.raises(ValueError, match="line load path point"):
        loads.check_domain(Plane().domain)


def test_the_material_conditioned_field_refuses_line_loads():
    from inverse.material.conditioned import ConditionedEquilibrium
    from inverse.material.unknowns import parse_unknowns
    from taichi_ndf.boundary import BoundaryConditions, ClampedEdge
    from taichi_ndf.problem.model import ShellModel
    from taichi_ndf.shell.materials import LinearIsotropic

    plane = Plane()
    loads = Loads(line_loads=(LineLoad(edge_path("xi1_max", plane.domain.bounds), (0, 0, -1.0)),))
    model = ShellModel(plane, LinearIsotropic(6.4, 7.68e-7, 0.25, 0.144), loads,
                       BoundaryConditions([ClampedEdge("xi1_min")], plane.domain))
    model, unknowns = parse_unknowns("bending", model)
    with pytest.raises(ValueError, match="does not support line loads"):
        ConditionedEquilibrium(model, unknowns, [(-1.0, 1.0)])
