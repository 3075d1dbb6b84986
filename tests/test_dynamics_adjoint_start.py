"""A run's start that depends on the stiffness (`dynamics_adjoint.rest_start`: the static
equilibrium at t = 0, V₀ = 0) in the dynamics adjoint (issue 27 item 3): on a sheet held at two
corner handles whose path starts with one corner moved out of the sheet's plane (a twisted,
bent rest state), dJ/dB of J = Σ w_k · C_k (k = 0 included) by the adjoint with the start's
derivative dC₀/dB against central differences of whole runs, each started at its own rest
state (float64, within 1e-6 relative); without the start's derivative the adjoint misses; the
tangent is its transpose; the rest start is an equilibrium (its gradient at rounding)."""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest
import torch

from inverse.material.trajectory_fit import observe
from taichi_ndf.minimise.newton import NewtonConfig
from taichi_ndf.problem.dynamics import DynamicsConfig
from taichi_ndf.scene.reader import parse_scene
from taichi_ndf.solve.dynamics_adjoint import gradient, record, rest_start, tangent
from taichi_ndf.solve.handle_paths import HandlePath, PathStepper
from tests.test_dynamics_adjoint_motion import SHEET as MOTION_SHEET

# test_dynamics_adjoint_motion's 1 m × 0.5 m sheet held at its two corner handles, hanging
# along +y here
SHEET = {**MOTION_SHEET, "loads": {"gravity": [0.0, 9.81, 0.0]}}
# corner b starts 8 cm out of the plane (the rest state bends: it depends on B), then moves
PATH = HandlePath((0.0, 0.05, 0.1, 0.15, 0.2),
                  np.array([[[0.0, 0.0, 0.0], [0.0, 0.0, 0.08]],
                            [[0.01, 0.0, 0.02], [0.0, 0.01, 0.07]],
                            [[0.03, 0.01, 0.05], [-0.01, 0.02, 0.05]],
                            [[0.04, 0.01, 0.06], [-0.02, 0.02, 0.06]],
                            [[0.04, 0.0, 0.05], [-0.02, 0.01, 0.08]]]))


def sheet(bending, integrator="implicit_euler"):
    s = parse_scene(copy.deepcopy(SHEET), base_dir=Path("."))
    model = s.model.with_material(s.model.material.with_stiffness(bending_stiffness=bending))
    config = DynamicsConfig(dt=0.05, duration=0.2, integrator=integrator, mass_damping=0.5)
    return PathStepper(model, s.field, config, PATH, newton=NewtonConfig())


def run(bending):
    stepper = sheet(bending)
    zeros = torch.zeros_like(stepper.field.coefficients)
    start = rest_start(stepper, zeros, "bending_stiffness")
    return stepper, start, record(stepper, start.displacement, start.velocity)


def weights(n_states, shape):
    generator = torch.Generator().manual_seed(7)
    return {k: torch.randn(shape, generator=generator, dtype=torch.float64)
            for k in (0, n_states // 2, n_states - 1)}


def objective(states, w):
    return sum(float((w[k] * states[k].displacement).sum()) for k in w)


@pytest.fixture(scope="module")
def check():
    b, delta = 1e-2, 1e-6
    stepper, start, states = run(b)
    w = weights(len(states), states[0].displacement.shape)
    central = (objective(run(b + delta)[2], w) - objective(run(b - delta)[2], w)) / (2 * delta)
    return stepper, start, states, w, central


def test_the_adjoint_with_the_rest_start_matches_central_differences(check):
    stepper, start, states, w, central = check
    adjoint = gradient(stepper, states, "bending_stiffness", w, start.derivative)
    assert abs(central) > 1e-6
    assert adjoint == pytest.approx(central, rel=1e-6)
    forward = tangent(stepper, states, "bending_stiffness", start.derivative)
    assert sum(float((w[k] * forward[k]).sum()) for k in w) == pytest.approx(adjoint,
                                                                            rel=1e-10)


def test_without_the_starts_derivative_the_adjoint_misses(check):
    stepper, start, states, w, central = check
    # the rest state bends with B: B dC₀/dB is not small against C₀
    assert 1e-2 * float(start.derivative[0].abs().max()) > 1e-2 * float(
        start.displacement.abs().max())
    wrong = gradient(stepper, states, "bending_stiffness", w)
    assert abs(wrong / central - 1) > 1e-3


def test_the_rest_start_is_an_equilibrium_at_rest(check):
    stepper, start, states, _, _ = check
    linear = stepper._at(0.0)
    potential = stepper.objective.potential(1.0)
    g = linear.gradient(potential(stepper.samples, linear.displacement(start.displacement),
                                  True).grad_u_jets)
    at_reference = linear.gradient(potential(stepper.samples, linear.displacement(
        torch.zeros_like(g)), True).grad_u_jets)
    assert float(g.abs().max()) < 1e-10 * float(at_reference.abs().max())
    assert float(start.velocity.abs().max()) == 0.0
    # the corner stands where the path starts it
    corner = torch.tensor([[1.0, 0.0]], dtype=torch.float64)
    u = observe(stepper, corner, start.displacement, 0.0)
    assert u.numpy()[0] == pytest.approx(PATH.displacements[0, 1], abs=1e-12)


def test_newmark_with_a_start_that_depends_on_b_is_refused(check):
    stepper, start, states, w, _ = check
    newmark = sheet(1e-2, "newmark")
    with pytest.raises(ValueError, match="implicit Euler only"):
        tangent(newmark, states, "bending_stiffness", start.derivative)
