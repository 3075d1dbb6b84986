"""J stored once per distinct component (`minimise.jacobian`): the assembly's U, g and K equal
those of the dense J (3, N, 6, k) of `DisplacementOperator.local_jacobian`, on a cylinder whose
diaphragms hold x and y only (J_z is the basis jets, J_x = J_y: two arrays) and on a plate
with a free pin holding x and z."""

import math

import pytest
import torch

from taichi_ndf.boundary import BoundaryConditions, HingedEdge, PinnedPoint
from taichi_ndf.field.spline import SplineConfig, SplineField
from taichi_ndf.geometry import Cylinder, Plane
from taichi_ndf.minimise.assembly import Assembly, local_basis_at
from taichi_ndf.minimise.jacobian import component_jacobian
from taichi_ndf.problem.loads import Loads, PointLoad
from taichi_ndf.problem.operator import DisplacementOperator
from taichi_ndf.problem.quadrature import span_quadrature

F64 = torch.float64


def _cylinder():
    """A cylinder on 8 × 3 cubic spans (periodic in θ) with both end rings held in x and y
    (the pinched cylinder's diaphragms, band 0.45) and a point load (an extra sample)."""
    surface = Cylinder(radius=1.0, length=2.0)
    config = SplineConfig(spans=(8, 3), domain=surface.domain.bounds, periodic=(True, False))
    boundary = BoundaryConditions([HingedEdge("xi2_min", components="xy"),
                                   HingedEdge("xi2_max", components="xy")],
                                  surface.domain, surface=surface, length=0.45)
    loads = Loads(point_loads=(PointLoad((0.0, 1.0), (-1.0, 0.0, 0.0)),))
    return surface, config, boundary, loads


def _free_pin_plate():
    """A plate on 3 × 2 cubic spans with a free pin holding x and z (u = N(ξ) − N(ξ₀) there:
    every point also depends on the pin's coefficients) and a point load."""
    surface = Plane(bounds=((0.0, 2.0), (0.0, 1.0)))
    config = SplineConfig(spans=(3, 2), domain=surface.domain.bounds)
    boundary = BoundaryConditions([PinnedPoint((0.0, 0.0), components="xz", rotation="free")],
                                  surface.domain, surface=surface)
    loads = Loads(point_loads=(PointLoad((0.5, 0.25), (0.0, 0.0, -1.0)),))
    return surface, config, boundary, loads


CASES = {"cylinder_xy_diaphragms": _cylinder, "free_pin_xz": _free_pin_plate}


def _dense_reference(assembly, operator, coefficients, grad_u, blocks):
    """U, g and K·v from the dense J of `operator.local_jacobian` at all points at once (the
    form before J was stored per component): direct einsums, K as a dense matrix."""
    basis = assembly.basis
    xi = assembly.samples.xi
    full = basis.jets if basis.pin_jets is None else torch.cat((basis.jets, basis.pin_jets[None]))
    local = operator.local_jacobian(xi, full)
    count, k = basis.index.shape
    n = assembly.n_coefficients
    dense = torch.zeros(3, count, 6, n, dtype=F64)  # over all coefficients
    dense.scatter_add_(3, basis.index[None, :, None, :].expand(3, count, 6, k), local.own)
    if local.pin is not None:
        dense[:, :, :, basis.pin_index] += local.pin[:, None]
    u = assembly.offset + operator.to_world(torch.einsum("cqja,ac->qjc", dense, coefficients))
    gradient = torch.einsum("cqja,qjc->ac", dense, operator.to_frame(grad_u))
    h = operator.blocks_to_frame(blocks).reshape(count, 6, 3, 6, 3)
    # K[a c, b d] = Σ_q J[c, q, i, a] H[q, i, c, j, d] J[d, q, j, b]
    matrix = torch.einsum("cqia,qicjd,dqjb->acbd", dense, h, dense).reshape(3 * n, 3 * n)
    return u, gradient, matrix


@pytest.mark.parametrize("case", sorted(CASES))
def test_assembly_equals_the_dense_jacobian(case):
    """U, g and K (applied to a vector) of the assembly equal the dense J's to 1e-14
    relative; the cylinder's J is two arrays, J_z the basis jets themselves; the free pin's
    own part is the basis jets for all three components (its pin part apart)."""
    surface, config, boundary, loads = CASES[case]()
    field = SplineField(config, dtype=F64)
    samples = span_quadrature(surface, config, loads, dtype=F64)
    operator = DisplacementOperator(field, boundary)
    assembly = Assembly(samples, local_basis_at(operator, samples.xi),
                        field.coefficients.shape[0]).at_load(operator, 0.6)
    jacobian = assembly.jacobian
    if case.startswith("cylinder"):  # x and y alike, z free: the basis itself, not a copy
        slots = jacobian.slots
        assert len(jacobian.arrays) == 2 and slots[0] == slots[1] != slots[2]
        assert jacobian.component(2) is assembly.basis.jets
    else:  # a free pin's own part is the raw field's: the basis for all three
        assert len(jacobian.arrays) == 1 and jacobian.slots == (0, 0, 0)
        assert jacobian.component(0) is assembly.basis.jets
        assert assembly.pin_jacobian is not None
    gen = torch.Generator().manual_seed(0)
    count, n = len(assembly.samples), assembly.n_coefficients
    coefficients = 1e-2 * torch.randn(n, 3, generator=gen, dtype=F64)
    grad_u = torch.randn(count, 6, 3, generator=gen, dtype=F64)
    blocks = torch.randn(count, 18, 18, generator=gen, dtype=F64)
    blocks = blocks + blocks.transpose(1, 2)
    vector = torch.randn(3 * n, generator=gen, dtype=F64)
    u, gradient, matrix = _dense_reference(assembly, operator, coefficients, grad_u, blocks)

    def close(ours, reference):
        scale = float(reference.abs().max())
        assert scale > 0
        assert float((ours - reference).abs().max()) <= 1e-14 * scale

    close(assembly.displacement(coefficients), u)
    close(assembly.gradient(grad_u), gradient)
    product = torch.from_numpy(assembly.hessian(blocks) @ vector.numpy())
    close(product, matrix @ vector)


@pytest.mark.parametrize("chunk", [5, 37, 100000])
def test_the_chunked_build_equals_the_dense_jacobian_bit_for_bit(chunk):
    """J built in chunks of points (small chunks: the groups of equal components are split
    as they come, the first chunks lying where φ_x = φ_y = 1 ... or not) equals the dense J
    of all points at once, entry for entry, whatever the chunk; and the stored arrays are
    the same two."""
    surface, config, boundary, loads = _cylinder()
    field = SplineField(config, dtype=F64)
    # points ordered from the middle of the cylinder outwards: the first chunks see φ = 1
    xi = span_quadrature(surface, config, loads, dtype=F64).xi
    xi = xi[torch.argsort((xi[:, 1] - 1.0).abs(), stable=True)]
    operator = DisplacementOperator(field, boundary)
    basis = local_basis_at(operator, xi)
    jacobian, pin = component_jacobian(operator, xi, basis.jets, chunk=chunk)
    assert pin is None
    assert torch.equal(jacobian.dense(), operator.local_jacobian(xi, basis.jets).own)
    assert len(jacobian.arrays) == 2 and jacobian.component(2) is basis.jets
    far = torch.tensor([[0.5, 1.0]], dtype=F64)  # mid-length: outside both bands
    assert math.isclose(float(operator.boundary.vanishing_factor(far)[0, 0, 0]), 1.0)
