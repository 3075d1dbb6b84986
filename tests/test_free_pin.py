"""A pinned point with rotation="free": u = N(ξ) − N(ξ₀), through training, Newton, probes and
the scene schema."""

from pathlib import Path

import pytest
import torch

from taichi_ndf import jets
from taichi_ndf.boundary import BoundaryConditions, ClampedEdge, PinnedPoint
from taichi_ndf.field import FieldConfig, NeuralField
from taichi_ndf.geometry import Plane
from taichi_ndf.minimise.last_layer import output_jacobian, solve_last_layer
from taichi_ndf.problem.loads import Loads
from taichi_ndf.problem.model import Probe, ShellModel
from taichi_ndf.scene.reader import parse_scene
from taichi_ndf.scene.schema import SceneError
from taichi_ndf.shell.materials import preset
from taichi_ndf.solve.solver import Solver, SolverConfig

PIN = (0.0, 0.0)
SURFACE = Plane(bounds=((0.0, 1.0), (0.0, 1.0)))


def free_pin(components="xyz"):
    return BoundaryConditions([PinnedPoint(PIN, components=components, rotation="free")],
                              SURFACE.domain, surface=SURFACE)


def random_jets(n, seed=0):
    return torch.randn(n, 6, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(seed))


def random_xi(n, seed=1):
    return torch.rand(n, 2, dtype=torch.float64, generator=torch.Generator().manual_seed(seed))


@pytest.fixture
def hanging():
    """A small napkin (1 × 1 m cloth pinned freely at a corner, gravity), a 16-wide f64 field
    with a pin probe, and a solver on 256 samples."""
    material = preset("cloth")
    loads = Loads(gravity=(0.0, 0.0, -9.81))
    model = ShellModel(SURFACE, material, loads, free_pin(),
                       probes=(Probe("pin", PIN), Probe("corner", (1.0, 1.0))))
    field = NeuralField(FieldConfig(width=16, hidden_layers=2, omega0=3.0, output_scale=0.05,
                                    domain=SURFACE.domain.bounds), seed=3, dtype=torch.float64)
    config = SolverConfig(iterations=5, samples=256, monitor_every=5, monitor_samples=256,
                          newton_samples=256, checkpoint_every=0, progress=False)
    return model, field, Solver(model, field, config)


def test_free_pin_subtracts_the_pin_value_and_keeps_the_derivatives():
    bc = free_pin(components="xz")
    xi = random_xi(50)
    raw = random_jets(51)
    u = bc.compose(xi, raw)
    expected = raw[:50].clone()
    expected[:, jets.VALUE, 0] -= raw[50, jets.VALUE, 0]
    expected[:, jets.VALUE, 2] -= raw[50, jets.VALUE, 2]
    assert torch.equal(u, expected)
    assert torch.equal(bc.vanishing_factor(xi), jets.constant(torch.ones(50, 3).double()))
    assert torch.equal(bc.evaluation_points(xi), torch.cat((xi, torch.tensor([PIN]).double())))


def test_free_pin_adjoint_is_the_transpose_of_compose():
    bc = free_pin(components="xy")
    xi = random_xi(40)
    raw = random_jets(41).requires_grad_(True)
    grad_u = random_jets(40, seed=4)
    (bc.compose(xi, raw) * grad_u).sum().backward()
    torch.testing.assert_close(bc.compose_adjoint(xi, grad_u), raw.grad, rtol=1e-13, atol=1e-13)


def test_training_gradient_matches_finite_differences(hanging):
    """dΠ/dweights through the pin's own value N(ξ₀), against central differences in f64."""
    _, field, solver = hanging
    samples = solver.monitor_samples()
    solver.energy_and_gradient(samples, 1.0)
    gradient = field.get_flat_gradient().clone()
    flat = field.get_flat().clone()
    # A raw output bias moves N(ξ) and N(ξ₀) alike: u does not depend on it.
    assert float(field.gradients[-1].abs().max()) <= 1e-12 * float(gradient.abs().max())
    direction = torch.randn(flat.shape, generator=torch.Generator().manual_seed(5),
                            dtype=torch.float64)
    step = 1e-6
    energies = []
    for sign in (1.0, -1.0):
        field.set_flat(flat + sign * step * direction)
        energies.append(solver.energy_and_gradient(samples, 1.0, grad=False).total)
    field.set_flat(flat)
    finite = (energies[0] - energies[1]) / (2 * step)
    assert float(gradient @ direction) == pytest.approx(finite, rel=1e-6)


def test_trained_pin_does_not_move(hanging):
    _, _, solver = hanging
    result = solver.run()
    assert result.probes["pin"] == [0.0, 0.0, 0.0]
    assert result.probes["corner"][2] < 0.0  # the free corner falls
    assert all(record.probes["pin"] == [0.0, 0.0, 0.0] for record in result.history)


def test_newton_jacobian_is_exact_and_a_step_lowers_the_energy(hanging):
    model, field, solver = hanging
    samples = solver.newton_samples()
    u, jacobian = output_jacobian(solver.operator, samples.xi, 1.0)
    change = 1e-3 * torch.randn(3, field.config.width + 1, dtype=torch.float64,
                                generator=torch.Generator().manual_seed(6))
    field.parameters[-2].add_(change[:, :-1])
    field.parameters[-1].add_(change[:, -1])
    moved = model.displacement_jets(field, samples.xi)
    predicted = u + torch.einsum("knca,ka->nck", jacobian, change)
    torch.testing.assert_close(moved, predicted, rtol=1e-10, atol=1e-14)

    result = solve_last_layer(solver.operator, solver.objective.potential(1.0), samples, 1.0)
    assert result.energy < result.energy_before


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (lambda: PinnedPoint(PIN, rotation="loose"), "rotation must be one of"),
        (lambda: PinnedPoint(PIN, rotation="free", length=0.2), "length does not apply"),
        (lambda: BoundaryConditions([PinnedPoint(PIN, rotation="free"),
                                     PinnedPoint((1.0, 0.0), rotation="free")],
                                    SURFACE.domain), "must be the only constraint"),
        (lambda: BoundaryConditions([PinnedPoint(PIN, rotation="free"),
                                     ClampedEdge("xi1_max")], SURFACE.domain),
         "must be the only constraint"),
        (lambda: BoundaryConditions([PinnedPoint((2.0, 0.0), rotation="free")],
                                    SURFACE.domain), "outside the parameter domain"),
        (lambda: free_pin().compose(random_xi(4), random_jets(4)), "evaluation_points"),
    ],
)
def test_invalid_free_pins_are_refused(make, message):
    with pytest.raises(ValueError, match=message):
        make()


def test_free_pin_refuses_conditioned_fields(hanging):
    model, field, _ = hanging
    with pytest.raises(ValueError, match="conditioned field"):
        model.displacement(field, random_xi(3), conditioning=torch.zeros(3, 1))
    with pytest.raises(ValueError, match="pseudo_time does not support a free pin"):
        Solver(model, field, SolverConfig(pseudo_time=True, progress=False))


def scene_with_pin(**pin):
    document = {"name": "hanging", "material": {"preset": "cloth"},
                "geometry": {"type": "plane", "bounds": [[0.0, 1.0], [0.0, 1.0]]},
                "boundary": {"constraint": [{"type": "pinned_point", "xi": [0.0, 0.0], **pin}]}}
    return parse_scene(document, base_dir=Path("."))


def test_scene_schema_reads_and_checks_the_rotation():
    for rotation in ("free", "held"):
        pin = scene_with_pin(rotation=rotation).model.boundary.constraints[0]
        assert pin.rotation == rotation
    assert scene_with_pin().model.boundary.free_pin is None  # the default holds the slope
    with pytest.raises(SceneError, match="rotation"):
        scene_with_pin(rotation="spinning")
    with pytest.raises(SceneError, match="length does not apply"):
        scene_with_pin(rotation="free", length=0.2)


def test_inverse_methods_without_free_pin_support_refuse_it_clearly():
    from inverse.material import Observation, parse_unknowns, residual_estimate
    from inverse.material.conditioned import ConditionedEquilibrium
    from taichi_ndf.shell.materials import LinearIsotropic

    surface = Plane(bounds=((0.0, 1.0), (0.0, 1.0)))
    model = ShellModel(surface, LinearIsotropic(6.4, 7.68e-7, 0.25, 0.144),
                       Loads(gravity=(0.0, 0.0, -9.81)),
                       BoundaryConditions([PinnedPoint((0.0, 0.0), rotation="free")],
                                          surface.domain))
    model, unknowns = parse_unknowns("bending", model)
    xi = torch.rand(20, 2, dtype=torch.float64)
    points = torch.cat((xi, torch.zeros(20, 1, dtype=torch.float64)), dim=1)
    with pytest.raises(ValueError, match="residual method does not support a free pin"):
        residual_estimate([Observation(model, points, xi)], unknowns)
    with pytest.raises(ValueError, match="conditioned field does not support a free pin"):
        ConditionedEquilibrium(model, unknowns, [(-1.0, 1.0)])
