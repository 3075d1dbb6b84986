"""Gauss–Legendre quadrature on the knot spans of a spline field."""

import pytest
import torch

from taichi_ndf.field import SplineConfig
from taichi_ndf.geometry import Hemisphere, Plane
from taichi_ndf.problem.loads import Loads
from taichi_ndf.problem.quadrature import gauss_legendre, span_points, span_quadrature

F64 = torch.float64
BOUNDS = ((-1.0, 2.0), (0.5, 1.5))


@pytest.mark.parametrize("points", [1, 2, 4, 5])
def test_rule_is_exact_to_degree_two_q_minus_one(points):
    nodes, weights = gauss_legendre(points)
    assert nodes.min() > 0 and nodes.max() < 1
    for k in range(2 * points):
        assert float((weights * nodes**k).sum()) == pytest.approx(1 / (k + 1), rel=1e-14)
    k = 2 * points
    assert float((weights * nodes**k).sum()) != pytest.approx(1 / (k + 1), rel=1e-6)


def integral(exponents, bounds):
    (a, b), (c, d) = bounds
    k, m = exponents
    return (b ** (k + 1) - a ** (k + 1)) / (k + 1) * (d ** (m + 1) - c ** (m + 1)) / (m + 1)


@pytest.mark.parametrize(("degree", "points"), [(3, None), (4, None), (3, (2, 3))])
def test_polynomials_are_integrated_exactly_over_the_domain(degree, points):
    config = SplineConfig(spans=(3, 2), degree=degree, domain=BOUNDS)
    samples = span_quadrature(Plane(bounds=BOUNDS), config, points=points, dtype=F64)
    q1, q2 = (degree + 1,) * 2 if points is None else points
    assert len(samples) == 3 * 2 * q1 * q2
    assert float(samples.weight.sum()) == pytest.approx(3.0 * 1.0, rel=1e-14)
    x, y = samples.xi[:, 0], samples.xi[:, 1]
    for k in range(2 * q1):
        for m in range(2 * q2):
            exact = integral((k, m), BOUNDS)
            value = float((samples.weight * x**k * y**m).sum())
            assert value == pytest.approx(exact, rel=1e-12, abs=1e-12), (k, m)
    # One degree more in ξ¹ is no longer exact (the rule has its documented order).
    k = 2 * q1
    assert float((samples.weight * x**k).sum()) != pytest.approx(integral((k, 0), BOUNDS),
                                                                 rel=1e-9)


def test_points_lie_span_by_span_inside_their_spans():
    config = SplineConfig(spans=(3, 2), domain=BOUNDS)
    xi, weight = span_points(config, points=(2, 3))
    spans = torch.floor((xi - torch.tensor([-1.0, 0.5], dtype=F64))
                        / torch.tensor(config.spacing, dtype=F64)).long()
    per_span = spans.view(3 * 2, 2 * 3, 2)
    assert (per_span == per_span[:, :1]).all()  # the q1·q2 points of a span are consecutive
    assert per_span[:, 0].tolist() == [[0, 0], [0, 1], [1, 0], [1, 1], [2, 0], [2, 1]]
    torch.testing.assert_close(weight.view(6, 6).sum(1), torch.full((6,), 0.5, dtype=F64))


def test_point_loads_are_added_where_they_act():
    config = SplineConfig(spans=(2, 2), domain=BOUNDS)
    loads = Loads(point_loads=[((0.25, 1.0), (0.0, 0.0, -3.0))])
    samples = span_quadrature(Plane(bounds=BOUNDS), config, loads, dtype=F64)
    assert len(samples) == 4 * 16 + 1
    assert samples.xi[-1].tolist() == [0.25, 1.0] and float(samples.weight[-1]) == 0.0
    assert samples.point_force[-1].tolist() == [0.0, 0.0, -3.0]
    assert (samples.point_force[:-1] == 0).all()
    with pytest.raises(ValueError, match="outside"):
        span_quadrature(Plane(bounds=BOUNDS), config,
                        Loads(point_loads=[((5.0, 1.0), (0, 0, 1))]), dtype=F64)


def test_masked_domain_drops_the_outside_points_and_converges_to_its_area():
    disk = Hemisphere(radius=1.0)  # parameter domain: a disk (exact area) in its square
    area = disk.domain.area
    errors = []
    for spans in (4, 16, 64):
        config = SplineConfig(spans=(spans, spans), domain=disk.domain.bounds)
        samples = span_quadrature(disk, config, dtype=F64)
        xi, weight = span_points(config)
        inside = disk.domain.contains(xi)
        assert 0 < inside.sum() < len(xi)
        torch.testing.assert_close(samples.xi, xi[inside], rtol=0, atol=0)
        torch.testing.assert_close(samples.weight, weight[inside], rtol=0, atol=0)
        errors.append(abs(float(samples.weight.sum()) - area) / area)
    # Measured: 1.5e-2, 1.5e-3, 1.6e-4 (relative): the error falls with the span size.
    assert errors[0] > errors[1] > errors[2] and errors[2] < 3e-4


def test_errors_name_the_problem():
    config = SplineConfig(spans=(2, 2), domain=BOUNDS)
    with pytest.raises(ValueError, match="domain"):
        span_quadrature(Plane(), config, dtype=F64)
    with pytest.raises(ValueError, match="positive integer"):
        span_points(config, points=(0, 2))
    with pytest.raises(ValueError, match="pair"):
        span_points(config, points=(2, 2, 2))
    samples = span_quadrature(Plane(bounds=BOUNDS), config, dtype=torch.float32)
    assert samples.xi.dtype == torch.float32 and samples.r_jets.dtype == torch.float32
