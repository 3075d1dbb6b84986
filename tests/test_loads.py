"""External loads: validation, scaling, and the work they do in the energy."""

import math

import pytest
import torch

from taichi_ndf.geometry import Cylinder, Plane
from taichi_ndf.problem.loads import Loads, PointLoad
from taichi_ndf.problem.sampling import sample_surface
from taichi_ndf.shell import ShellEnergy, preset


def test_defaults_and_conversion():
    loads = Loads(gravity=[0, 0, -9.81], point_loads=[((0.5, 0.5), (0, 0, -1))])
    assert loads.gravity == (0.0, 0.0, -9.81) and loads.pressure == 0.0
    assert loads.point_loads == (PointLoad((0.5, 0.5), (0.0, 0.0, -1.0)),)
    assert Loads(gravity=(0, 0, -10), body_force=(1, 0, 0)).distributed_force(0.2) == (
        1.0, 0.0, -2.0)


def test_scaled():
    loads = Loads(gravity=(0, 0, -9.81), body_force=(1, 2, 3), pressure=4.0,
                  point_loads=[((0.5, 0.5), (0, 0, -1))])
    half = loads.scaled(0.5)
    assert half.gravity == (0.0, 0.0, -4.905) and half.body_force == (0.5, 1.0, 1.5)
    assert half.pressure == 2.0 and half.point_loads[0].force == (0.0, 0.0, -0.5)
    assert half.point_loads[0].xi == (0.5, 0.5)


@pytest.mark.parametrize("make, match", [
    (lambda: Loads(gravity=(0, 0)), "gravity"),
    (lambda: Loads(gravity=(0, 0, math.nan)), "gravity"),
    (lambda: Loads(body_force=(0, math.inf, 0)), "body_force"),
    (lambda: Loads(body_force="up"), "body_force"),
    (lambda: Loads(pressure=math.nan), "pressure"),
    (lambda: Loads(point_loads=[((0.5,), (0, 0, 1))]), "xi"),
    (lambda: Loads(point_loads=[((0.5, 0.5), (0, 1))]), "force"),
    (lambda: Loads().scaled(math.inf), "load factor"),
])
def test_invalid_loads_raise(make, match):
    with pytest.raises(ValueError, match=match):
        make()


def test_point_loads_must_lie_in_the_domain():
    domain = Plane(bounds=((0, 2), (0, 1))).domain
    Loads(point_loads=[((2.0, 1.0), (0, 0, 1))]).check_domain(domain)  # corner is inside
    with pytest.raises(ValueError, match="outside the parameter domain"):
        Loads(point_loads=[((2.5, 0.5), (0, 0, 1))]).check_domain(domain)


def _external(surface, loads, displacement, n=4096):
    samples = sample_surface(surface, n, loads, torch.Generator().manual_seed(0))
    u = torch.zeros(len(samples), 6, 3, dtype=torch.float64)
    u[:, 0] = displacement(samples)
    return ShellEnergy(preset("cloth"), loads).evaluate(samples, u, grad=False).external


def test_work_of_gravity_body_force_and_point_load_on_a_translation():
    plane = Plane(bounds=((0, 2), (0, 1)))
    loads = Loads(gravity=(0, 0, -9.81), body_force=(0.5, 0, 0),
                  point_loads=[((1.0, 0.5), (0, 3.0, 0))])
    shift = torch.tensor([0.1, 0.2, 0.3], dtype=torch.float64)
    work = _external(plane, loads, lambda s: shift.expand(len(s), 3))
    force = 2.0 * torch.tensor([0.5, 0.0, -9.81 * 0.144], dtype=torch.float64)
    force[1] += 3.0
    assert work == pytest.approx(-float(force @ shift), rel=1e-12)


def test_pressure_is_a_dead_load_along_the_reference_normal():
    radius, length, p, delta = 2.0, 3.0, 5.0, 1e-3
    cylinder = Cylinder(radius=radius, length=length)
    loads = Loads(pressure=p)

    def radial(samples):
        return delta * torch.nn.functional.normalize(
            torch.linalg.cross(samples.r_jets[:, 1], samples.r_jets[:, 2], dim=1), dim=1)

    area = 2 * math.pi * radius * length
    assert _external(cylinder, loads, radial) == pytest.approx(-p * delta * area, rel=1e-12)
    # A rigid translation of a closed cylinder: the pressure resultant vanishes.
    shift = torch.tensor([1.0, 0.5, 0.2], dtype=torch.float64)
    net = _external(cylinder, loads, lambda s: shift.expand(len(s), 3))
    assert abs(net) < 1e-3 * p * area * float(shift.norm())
