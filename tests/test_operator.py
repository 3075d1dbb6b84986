"""The displacement operator: jets and backward are the composition and its adjoint chained
with the field, checked against central differences; Jacobians for a dense block and a local
basis (with a free pin kept apart); the refusals; no boundary conditions = the raw field."""

import pytest
import torch

from taichi_ndf.boundary import BoundaryConditions, ClampedEdge, PinnedPoint, SymmetryPlane
from taichi_ndf.field import FieldConfig, NeuralField
from taichi_ndf.geometry import Plane
from taichi_ndf.problem.operator import DisplacementOperator

F64 = torch.float64
SURFACE = Plane(bounds=((0.0, 1.0), (0.0, 1.0)))


def boundaries():
    """Clamped edge with a held pin, and a free pin (u = N(ξ) − N(ξ₀)) on two components."""
    return {
        "clamped": BoundaryConditions([ClampedEdge("xi1_min"), PinnedPoint((1.0, 1.0))],
                                      SURFACE.domain, surface=SURFACE),
        "free_pin": BoundaryConditions([PinnedPoint((0.2, 0.3), components="xz",
                                                    rotation="free")],
                                       SURFACE.domain, surface=SURFACE),
        "symmetry": BoundaryConditions(
            [SymmetryPlane("xi1_min", "x"), SymmetryPlane("xi2_max", "y", antisymmetric=True),
             ClampedEdge("xi1_max", displacement=(0.0, 0.1, 0.0))],
            SURFACE.domain, surface=SURFACE),
    }


def small_field(seed=2):
    return NeuralField(FieldConfig(width=8, hidden_layers=2, omega0=3.0, output_scale=0.1,
                                   domain=SURFACE.domain.bounds), seed=seed, dtype=F64)


def xi_points(n=9, seed=4):
    return torch.rand(n, 2, dtype=F64, generator=torch.Generator().manual_seed(seed))


@pytest.mark.parametrize("name", ["clamped", "free_pin", "symmetry"])
def test_backward_is_the_gradient_of_a_loss_of_the_jets(name):
    field = small_field()
    operator = DisplacementOperator(field, boundaries()[name])
    xi = xi_points()
    weights = torch.randn(len(xi), 6, 3, dtype=F64, generator=torch.Generator().manual_seed(5))

    def loss() -> float:
        return float((operator.jets(xi, t=0.7) * weights).sum())

    loss()
    operator.backward(weights)
    analytic = field.get_flat_gradient().clone()
    flat = field.get_flat().clone()
    step = 1e-6
    for index in torch.randperm(len(flat), generator=torch.Generator().manual_seed(6))[:12]:
        shifted = flat.clone()
        shifted[index] += step
        field.set_flat(shifted)
        up = loss()
        shifted[index] -= 2 * step
        field.set_flat(shifted)
        down = loss()
        assert (up - down) / (2 * step) == pytest.approx(float(analytic[index]), rel=1e-6,
                                                          abs=1e-9)
    field.set_flat(flat)


def test_displacement_is_the_value_channel_of_the_jets():
    field = small_field()
    operator = DisplacementOperator(field, boundaries()["free_pin"])
    xi = xi_points()
    torch.testing.assert_close(operator.displacement(xi, t=0.5),
                               operator.jets(xi, t=0.5)[:, 0], rtol=1e-12, atol=1e-14)


def test_without_boundary_conditions_the_displacement_is_the_raw_field():
    field = small_field()
    operator = DisplacementOperator(field, None)
    xi = xi_points()
    assert torch.equal(operator.jets(xi), field.jets(xi))
    grad = torch.ones(len(xi), 6, 3, dtype=F64)
    assert torch.equal(operator.raw_gradient(xi, grad), grad)


@pytest.mark.parametrize("name", ["clamped", "free_pin", "symmetry"])
def test_output_layer_jacobian_predicts_a_change_of_the_output_layer(name):
    field = small_field()
    operator = DisplacementOperator(field, boundaries()[name])
    xi = xi_points()
    u, jacobian = operator.output_layer_jacobian(xi, t=0.4)
    change = 1e-3 * torch.randn(3, 9, dtype=F64, generator=torch.Generator().manual_seed(7))
    weight, bias = field.output_layer()
    weight.add_(change[:, :-1])
    bias.add_(change[:, -1])
    predicted = u + torch.einsum("knca,ka->nck", jacobian, change)
    torch.testing.assert_close(operator.jets(xi, t=0.4), predicted, rtol=1e-10, atol=1e-14)


@pytest.mark.parametrize("name", ["clamped", "free_pin", "symmetry"])
def test_local_jacobian_of_a_shared_basis_adds_up_to_the_dense_one(name):
    """A dense basis is a local basis whose rows are the same for every point: own + pin
    must then give `jacobian`; without a free pin there is no pin part."""
    boundary = boundaries()[name]
    operator = DisplacementOperator(None, boundary)
    xi = xi_points()
    m = len(operator.evaluation_points(xi))
    basis = torch.randn(m, 6, 4, dtype=F64, generator=torch.Generator().manual_seed(8))
    dense = operator.jacobian(xi, basis)
    local = operator.local_jacobian(xi, basis)
    if boundary.free_pin is None:
        assert local.pin is None
        torch.testing.assert_close(local.own, dense, rtol=0, atol=0)
    else:
        assert local.pin.shape == (3, 6, 4)
        assert not local.pin[1].any()  # y is not a free-pin component
        torch.testing.assert_close(local.own + local.pin[:, None], dense, rtol=1e-14,
                                   atol=1e-15)


def test_refusals_name_what_a_free_pin_does_not_support():
    operator = DisplacementOperator(small_field(), boundaries()["free_pin"])
    with pytest.raises(ValueError, match="conditioned field"):
        operator.jets(xi_points(), conditioning=torch.zeros(9, 1, dtype=F64))
    with pytest.raises(ValueError, match="pseudo_time does not support a free pin"):
        operator.refuse_free_pin("pseudo_time")
    DisplacementOperator(small_field(), boundaries()["clamped"]).refuse_free_pin("anything")
    with pytest.raises(RuntimeError, match="preceding jets"):
        DisplacementOperator(small_field(), None).backward(torch.zeros(1, 6, 3, dtype=F64))
