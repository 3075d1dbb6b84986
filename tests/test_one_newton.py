"""The one Newton (`minimise.newton.minimise`) over a dense and a sparse linearisation of the
same problem takes the same steps."""

import math

import pytest
import torch
from test_projected_newton import _large_deflection_strip

from taichi_ndf.field.spline import SplineConfig, SplineField
from taichi_ndf.minimise.assembly import Assembly, local_basis_at
from taichi_ndf.minimise.linearisation import DenseLinearisation, SplineLinearisation
from taichi_ndf.minimise.newton import NewtonConfig, minimise
from taichi_ndf.objective import Objective, ShellEnergyTerm
from taichi_ndf.problem.operator import DisplacementOperator
from taichi_ndf.problem.quadrature import span_quadrature

DT = torch.float64
LOAD_FACTOR = 0.3


def _strip():
    """The large-deflection strip (`_large_deflection_strip`) on 4 × 1 cubic spans (21
    coefficients) at load factor 0.3, which rotates its tip by about 30°: nonlinear, 25 Newton
    steps from the flat strip."""
    model = _large_deflection_strip()
    surface = model.surface
    field = SplineField(SplineConfig(spans=(4, 1), domain=surface.domain.bounds), dtype=DT)
    samples = span_quadrature(surface, field.config, model.loads, dtype=DT)
    operator = DisplacementOperator(field, model.boundary)
    assembly = Assembly(samples, local_basis_at(operator, samples.xi),
                        field.coefficients.shape[0]).at_load(operator, LOAD_FACTOR)
    potential = Objective(ShellEnergyTerm(model.material, model.loads)).potential(LOAD_FACTOR)
    return assembly, potential, math.sqrt(surface.domain.rectangle_area)


def _dense_of(sparse: SplineLinearisation) -> DenseLinearisation:
    """The sparse linearisation written out densely: J (3, N, 6, n) over parameters C ᵀ (3, n),
    with the spline's FD steps (the same blocks)."""
    assembly = sparse.assembly
    local = assembly.jacobian.dense()  # (3, N, 6, k) on the coefficients basis.index (N, k)
    comps, count, channels, _ = local.shape
    jacobian = local.new_zeros(comps, count, channels, assembly.n_coefficients)
    index = assembly.basis.index[None, :, None, :].expand(comps, count, channels, -1)
    jacobian.scatter_add_(3, index, local)
    dense = DenseLinearisation(assembly.samples, assembly.offset, jacobian)
    dense.fd_steps = lambda u, parameters, relative: sparse.fd_steps(u, None, relative)
    return dense


@pytest.mark.parametrize("correction", [False, True])
def test_dense_and_sparse_linearisations_take_the_same_newton_steps(correction):
    """The same iterations, step lengths (halved, full and doubled ones without the
    second-order correction; corrected full steps with it) and projections; Π
    along the way equal to 1e-7 relative (the dense solve's least damping, 1e-14 of the
    Jacobi-scaled K, and the two factorisations' rounding, carried through 25 nonlinear steps:
    measured ≤ 1.6e-9 with the compiler's fast math, ≤ 6.7e-9 with IEEE arithmetic, the default
    since 2026-12-03, whose decrements then differ by up to 3.2e-5 relative in the last steps;
    on 2026-12-07 on another machine of the project's kind (an AMD EPYC: the dense
    factorisation's rounding follows the CPU's BLAS kernels) 1.7e-8, its decrements 1.0e-4
    apart — hence 1e-7 and 1e-3 here), the minimum to 1e-13 (measured there 4.4e-16)."""
    assembly, potential, length = _strip()
    sparse = SplineLinearisation(assembly, length=length)
    dense = _dense_of(sparse)
    start = torch.zeros(assembly.n_coefficients, 3, dtype=DT)
    assert torch.allclose(dense.displacement(start.t() + 0.01), sparse.displacement(start + 0.01),
                          rtol=1e-13, atol=1e-15)
    config = NewtonConfig(decrement_tolerance=1e-14, second_order_correction=correction)
    by_sparse = minimise(sparse, potential, start, config, load_factor=LOAD_FACTOR)
    by_dense = minimise(dense, potential, start.t(), config, load_factor=LOAD_FACTOR)
    assert by_sparse.converged and by_dense.converged
    assert len(by_sparse.history) == len(by_dense.history) >= 5
    lengths = {h.step_length for h in by_sparse.history}
    assert by_sparse.history[0].projected_blocks > 0
    assert any(h.corrected for h in by_sparse.history) if correction else {0.5, 1.0, 2.0} <= lengths
    for s, d in zip(by_sparse.history, by_dense.history, strict=True):
        assert (s.step_length, s.projected_blocks, s.corrected) == (
            d.step_length, d.projected_blocks, d.corrected)
        assert d.energy == pytest.approx(s.energy, rel=1e-7, abs=1e-300)
        assert d.decrement == pytest.approx(s.decrement, rel=1e-3, abs=1e-12 * abs(s.energy))
    scale = float(by_sparse.parameters.abs().max())
    assert torch.allclose(by_dense.parameters.t(), by_sparse.parameters, rtol=0, atol=1e-9 * scale)
    assert by_dense.energy == pytest.approx(by_sparse.energy, rel=1e-13)


@pytest.mark.parametrize("dense", [False, True])
def test_newton_resumed_from_any_iterate_ends_bit_for_bit_where_it_would_have(dense):
    """`minimise(..., resume=)` from the iterate of each step (`on_iterate`: the parameters,
    the damping, the exact-K flag, ‖g₀‖, the last Π, the iterations) reaches the same
    parameters, Π and iterations exactly, on both linearisations; without the damping and
    the flag (a plain restart from the parameters) it does not."""
    assembly, potential, length = _strip()
    linear = SplineLinearisation(assembly, length=length)
    linear = _dense_of(linear) if dense else linear
    start = torch.zeros(assembly.n_coefficients, 3, dtype=DT)
    start = start.t() if dense else start
    iterates = []
    whole = minimise(linear, potential, start, load_factor=LOAD_FACTOR,
                     on_iterate=iterates.append)
    assert len(iterates) >= 10 and len(iterates) == whole.steps
    for iterate in iterates[1::4]:
        resumed = minimise(linear, potential, start, load_factor=LOAD_FACTOR, resume=iterate)
        assert torch.equal(resumed.parameters, whole.parameters)
        assert resumed.energy == whole.energy and resumed.converged == whole.converged
        assert [h.energy for h in resumed.history] == [h.energy for h in whole.history]
        assert [h.iteration for h in resumed.history] == list(range(len(whole.history)))
    damped = next(i for i in iterates if i.damping > 0 or not i.exact_failed)
    restarted = minimise(linear, potential, damped.parameters, load_factor=LOAD_FACTOR)
    assert not torch.equal(restarted.parameters, whole.parameters)


def test_newton_config_validates_its_fields():
    for bad in ({"line_searches": 0}, {"retry_damping": 0.0}, {"relative_decrease": 1.0},
                {"halvings": 0}, {"max_iterations": 0}, {"hessian": "flip"},
                {"decrement_tolerance": math.nan}):
        with pytest.raises(ValueError, match=next(iter(bad))):
            NewtonConfig(**bad)
