"""Graded knots of the spline field (issue 33): the map η = h(ξ) (monotone, C², ends fixed,
periodic and mirror consistent), the field's jets against central differences, its backward
against the dense Jacobian, the local basis, the quadrature on graded spans, exact
prolongation and a checkpoint round trip."""

import pytest
import torch

from taichi_ndf.field import SplineConfig, SplineField
from taichi_ndf.field.grading import GradedMap, Grading, strength_for
from taichi_ndf.minimise.checkpoint import load_checkpoint, save_checkpoint
from taichi_ndf.problem.quadrature import gauss_legendre, span_points

F64 = torch.float64
DOMAIN = ((0.5, 2.5), (-1.0, 0.5))
GRADING = (Grading((0.5, 1.7), 0.2, 2.0), Grading((0.0,), 0.1, 3.0))
CASES = [  # (periodic, even_ends)
    ((False, False), ((), ())),
    ((True, False), ((), ())),
    ((False, False), (("min",), ("min", "max"))),
]


def graded_field(periodic, even, spans=(6, 5), degree=3, seed=0):
    config = SplineConfig(spans=spans, degree=degree, domain=DOMAIN, periodic=periodic,
                          even_ends=even, grading=GRADING)
    field = SplineField(config, dtype=F64)
    g = torch.Generator().manual_seed(seed)
    field.coefficients.copy_(torch.randn(field.coefficients.shape, generator=g, dtype=F64))
    return field


def inside(n, seed=1):
    g = torch.Generator().manual_seed(seed)
    lo = torch.tensor([d[0] for d in DOMAIN], dtype=F64)
    hi = torch.tensor([d[1] for d in DOMAIN], dtype=F64)
    return lo + (hi - lo) * (0.02 + 0.96 * torch.rand(n, 2, generator=g, dtype=F64))


@pytest.mark.parametrize(("periodic", "even"), [(False, ()), (True, ()), (False, ("min",)),
                                                (False, ("min", "max"))])
def test_map_is_monotone_c2_with_fixed_ends(periodic, even):
    features = (0.0, 0.3)
    strength = strength_for(features, 0.1, 0.5, 0.0, 1.0, periodic=periodic, even=even)
    graded = GradedMap(Grading(features, 0.1, strength), 0.0, 1.0, periodic=periodic,
                       even=even)
    x = torch.linspace(0.0, 1.0, 2001, dtype=F64)
    h, dh, ddh = graded.jets(x)
    ends = graded.jets(torch.tensor([0.0, 1.0], dtype=F64))
    assert ends[0].tolist() == pytest.approx([0.0, 1.0], abs=1e-14)
    assert float(dh.min()) > 0.1
    # Graded: the slope (knots per unit ξ) at the feature 0.3 well above the far one (0.65).
    slope_at = graded.jets(torch.tensor([0.3, 0.65], dtype=F64))[1]
    assert float(slope_at[0]) > 1.5 * float(slope_at[1])
    e = 1e-6
    inner = x[(x > 2e-3) & (x < 1 - 2e-3)]
    hp, dhp, _ = graded.jets(inner + e)
    hm, dhm, _ = graded.jets(inner - e)
    _, dh_i, ddh_i = graded.jets(inner)
    assert float(((hp - hm) / (2 * e) - dh_i).abs().max()) < 1e-7
    assert float(((dhp - dhm) / (2 * e) - ddh_i).abs().max()) < 1e-4 * float(ddh.abs().max())
    torch.testing.assert_close(graded.inverse(h), x, rtol=0, atol=1e-13)
    if periodic:
        torch.testing.assert_close(graded.jets(x + 1.0)[0], h + 1.0, rtol=0, atol=1e-13)
        torch.testing.assert_close(graded.jets(x + 1.0)[2], ddh, rtol=0, atol=1e-9)
    for end in even:  # odd about a mirrored end: h″ = 0 there
        at = torch.tensor([0.0 if end == "min" else 1.0], dtype=F64)
        assert abs(float(graded.jets(at)[2])) < 1e-9 * float(ddh.abs().max())


@pytest.mark.parametrize(("periodic", "even"), CASES)
def test_jets_match_central_differences(periodic, even):
    field = graded_field(periodic, even)
    xi = inside(40)
    u = field.jets(xi)
    e = 1e-5

    def shifted(k, sign):
        step = torch.zeros(2, dtype=F64)
        step[k] = sign * e
        return field.evaluate(xi + step, derivatives=True)

    scale = float(u.abs().max())
    for k, (first, second) in enumerate(((1, (3, 4)), (2, (4, 5)))):
        (vp, dp), (vm, dm) = shifted(k, 1), shifted(k, -1)
        assert float(((vp - vm) / (2 * e) - u[:, first]).abs().max()) < 1e-6 * scale
        dd = (dp - dm) / (2 * e)  # (N, 2, c): ∂/∂ξk of (d1, d2)
        assert float((dd[:, 0] - u[:, second[0]]).abs().max()) < 1e-5 * scale
        assert float((dd[:, 1] - u[:, second[1]]).abs().max()) < 1e-5 * scale
    uniform = SplineField(SplineConfig(spans=(6, 5), domain=DOMAIN, periodic=periodic,
                                       even_ends=even), dtype=F64)
    uniform.coefficients.copy_(field.coefficients)
    assert float((uniform.jets(xi) - u).abs().max()) > 1e-2 * scale  # the grading acts


@pytest.mark.parametrize(("periodic", "even"), CASES)
def test_backward_and_local_basis_are_the_jacobian(periodic, even):
    field = graded_field(periodic, even, spans=(4, 4))
    xi = inside(7)
    n = field.coefficients.numel()
    dense = torch.zeros(xi.shape[0] * 6 * 3, n, dtype=F64)
    base = field.coefficients.clone()
    for j in range(n):  # jets are linear in C: column j = jets of the unit coefficient
        field.coefficients.zero_()
        field.coefficients.view(-1)[j] = 1.0
        dense[:, j] = field.jets(xi).reshape(-1)
    field.coefficients.copy_(base)
    g = torch.Generator().manual_seed(5)
    grad_jets = torch.randn(xi.shape[0], 6, 3, generator=g, dtype=F64)
    field.jets(xi)
    field.backward(grad_jets)
    torch.testing.assert_close(field.gradients[0].reshape(-1), dense.T @ grad_jets.reshape(-1),
                               rtol=1e-12, atol=1e-12)
    index, basis = field.local_basis(xi)
    rebuilt = torch.einsum("nck,nkd->ncd", basis, field.coefficients[index])
    torch.testing.assert_close(rebuilt, field.jets(xi), rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize(("periodic", "even"), CASES)
def test_quadrature_is_exact_for_polynomials_in_eta(periodic, even):
    """∫ q(h(ξ)) h′(ξ) dξ = ∫ q(η) dη: exact for q of degree ≤ 2q − 1 per span, per direction."""
    config = graded_field(periodic, even).config
    xi, weight = span_points(config)
    maps = config.graded_maps()
    h1, dh1, _ = maps[0].jets(xi[:, 0])
    h2, dh2, _ = maps[1].jets(xi[:, 1])
    (a, b), (c, d) = DOMAIN
    for k in range(2 * (config.degree + 1)):
        for m in (0, 3, 7):
            value = float((weight * h1**k * dh1 * h2**m * dh2).sum())
            exact = ((b ** (k + 1) - a ** (k + 1)) / (k + 1)
                     * (d ** (m + 1) - c ** (m + 1)) / (m + 1))
            assert value == pytest.approx(exact, rel=1e-12, abs=1e-12)
    # The spans are graded in ξ: the Gauss points crowd at the feature ξ² = 0 (GRADING[1]).
    uniform, _ = span_points(SplineConfig(spans=(6, 5), domain=DOMAIN, periodic=periodic,
                                          even_ends=even))
    near = int((xi[:, 1].abs() < 0.1).sum())
    assert near > 1.3 * int((uniform[:, 1].abs() < 0.1).sum())
    nodes, _ = gauss_legendre(config.degree + 1)
    assert xi.shape[0] == 6 * 5 * nodes.numel() ** 2


@pytest.mark.parametrize(("periodic", "even"), CASES)
def test_prolongation_is_exact_and_keeps_the_grading(periodic, even):
    field = graded_field(periodic, even)
    fine = field.refined()
    assert fine.config.grading == field.config.grading
    xi = inside(200)
    coarse = field.jets(xi)
    scale = coarse.abs().amax(dim=(0, 2), keepdim=True).clamp(min=1.0)
    assert float(((fine.jets(xi) - coarse).abs() / scale).max()) < 1e-12


def test_checkpoint_round_trip(tmp_path):
    field = graded_field((True, False), ((), ()))
    path = save_checkpoint(tmp_path / "ckpt.pt", field)
    loaded = load_checkpoint(path)
    assert loaded.field.config == field.config and loaded.field.config.graded
    xi = inside(30)
    assert torch.equal(loaded.field.jets(xi), field.jets(xi))


def test_a_grading_is_checked():
    with pytest.raises(ValueError, match="outside the domain"):
        SplineConfig(spans=(2, 2), grading=(Grading((1.5,), 0.1, 1.0), None))
    with pytest.raises(ValueError, match="core must be a positive"):
        Grading((0.5,), 0.0, 1.0)
    with pytest.raises(ValueError, match="features"):
        Grading((), 0.1, 1.0)
