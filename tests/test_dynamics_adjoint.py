"""The discrete adjoint of the time steps (`taichi_ndf.solve.dynamics_adjoint`): dJ/dB of a
trajectory quantity against central differences of whole runs (float64, a cantilever strip
bent and moving at t = 0 under gravity, a few steps, both integrators) within 1e-6 relative
(issue 29), the same comparison failing when a term of the adjoint is dropped, the step map as
the stepper's update, the tangent as the adjoint's transpose, what the adjoint refuses, and
`record`'s time steps as the steps of the one continuation loop."""

from __future__ import annotations

import copy
import types
from pathlib import Path

import pytest
import torch

from taichi_ndf import jets
from taichi_ndf.minimise import continuation
from taichi_ndf.minimise.assembly import displacement_at
from taichi_ndf.minimise.newton import NewtonConfig
from taichi_ndf.problem.dynamics import DynamicsConfig
from taichi_ndf.problem.operator import DisplacementOperator
from taichi_ndf.scene.reader import parse_scene
from taichi_ndf.solve import dynamics_adjoint
from taichi_ndf.solve.dynamics import DynamicsError, TimeStepper, initial_velocity
from taichi_ndf.solve.dynamics_adjoint import StepMap, gradient, record, tangent

# Cantilever strip L = 4 m, b = 1 m, ν = 0.3, bending_stiffness B set to 100 N·m, ρ_A = 1 kg/m²,
# gravity.
STRIP = {
    "name": "strip",
    "geometry": {"type": "plane", "bounds": [[0.0, 4.0], [0.0, 1.0]]},
    "material": {"type": "linear", "young_modulus": 1.2e6, "poisson_ratio": 0.3,
                 "thickness": 0.1, "areal_density": 1.0},
    "boundary": {"length": 1.0, "constraint": [{"type": "clamped_edge", "edge": "xi1_min"}]},
    "loads": {"gravity": [0.0, 0.0, -9.81]},
    "field": {"type": "spline", "spans": [6, 1]},
    "training": {"load_steps": [1.0]},
}
NEWTON = NewtonConfig()


def stepper(integrator, bending, alpha=0.0):
    s = parse_scene(copy.deepcopy(STRIP), base_dir=Path("."))
    model = s.model.with_material(s.model.material.with_stiffness(bending_stiffness=bending))
    config = DynamicsConfig(dt=0.05, duration=0.2, integrator=integrator, mass_damping=alpha)
    return TimeStepper(model, s.field, config, newton=NEWTON)


def start(st):
    """A bent (x² shape, 0.2 m at the tip) and moving (0.5 m/s up at the tip) start."""
    def shape(scale):
        def rate(xi):
            out = torch.zeros(len(xi), 3, dtype=xi.dtype)
            out[:, 2] = scale * (xi[:, 0] / 4.0) ** 2
            return out
        return rate
    return initial_velocity(st, shape(0.2)), initial_velocity(st, shape(0.5))


def weights(n_states, shape):
    generator = torch.Generator().manual_seed(3)
    return {k: torch.randn(shape, generator=generator, dtype=torch.float64)
            for k in (n_states // 2, n_states - 1)}


def objective(states, w):
    return sum(float((w[k] * states[k].displacement).sum()) for k in w)


def check(integrator, alpha):
    b, delta = 100.0, 1e-2
    st = stepper(integrator, b, alpha)
    c0, v0 = start(st)
    states = record(st, c0, v0)
    w = weights(len(states), c0.shape)
    adjoint = gradient(st, states, "bending_stiffness", w)
    values = []
    for sign in (1, -1):
        other = stepper(integrator, b + sign * delta, alpha)
        values.append(objective(record(other, c0, v0), w))
    central = (values[0] - values[1]) / (2 * delta)
    return adjoint, central


@pytest.mark.parametrize("integrator,alpha", [("newmark", 0.0), ("implicit_euler", 0.5),
                                              ("newmark", 0.5)])
def test_the_adjoint_matches_central_differences_of_whole_runs(integrator, alpha):
    adjoint, central = check(integrator, alpha)
    assert abs(central) > 1e-6
    assert adjoint == pytest.approx(central, rel=1e-6)


def test_dropping_a_term_of_the_adjoint_breaks_the_match(monkeypatch):
    adjoint, central = check("newmark", 0.0)
    assert adjoint == pytest.approx(central, rel=1e-6)
    # without the initial acceleration's dependence on B (Newmark, bent start)
    monkeypatch.setattr(dynamics_adjoint, "_initial_acceleration_derivative",
                        lambda st, p, c: torch.zeros_like(c))
    dropped, _ = check("newmark", 0.0)
    assert abs(dropped / central - 1) > 1e-3
    monkeypatch.undo()
    # without the inertia's coupling of a step's end to its start
    monkeypatch.setattr(dynamics_adjoint, "_mass_times", lambda st, c: torch.zeros_like(c))
    dropped, _ = check("newmark", 0.0)
    assert abs(dropped / central - 1) > 1e-3


@pytest.mark.parametrize("integrator,alpha", [("newmark", 0.3), ("implicit_euler", 0.3)])
def test_the_step_map_is_the_steppers_update(integrator, alpha):
    st = stepper(integrator, 100.0, alpha)
    c0, v0 = start(st)
    states = record(st, c0, v0)
    step = StepMap.of(st.config, st.config.dt)
    for before, after in zip(states[:-1], states[1:], strict=True):
        velocity, acceleration = step.apply(after.displacement, before)
        assert torch.allclose(velocity, after.velocity, rtol=1e-12, atol=1e-12)
        assert torch.allclose(acceleration, after.acceleration, rtol=1e-12, atol=1e-10)


@pytest.mark.parametrize("integrator", ["newmark", "implicit_euler"])
def test_the_tangent_is_the_adjoints_transpose(integrator):
    st = stepper(integrator, 100.0, 0.5)
    c0, v0 = start(st)
    states = record(st, c0, v0)
    w = weights(len(states), c0.shape)
    forward = tangent(st, states, "bending_stiffness")
    assert sum(float((w[k] * forward[k]).sum()) for k in w) == pytest.approx(
        gradient(st, states, "bending_stiffness", w), rel=1e-10)


def test_what_the_adjoint_refuses():
    st = stepper("newmark", 100.0)
    states = [None]
    with pytest.raises(ValueError, match="unknown stiffness parameter 'thickness'"):
        gradient(st, states, "thickness", {})
    s = parse_scene(copy.deepcopy(STRIP), base_dir=Path("."))
    damped = TimeStepper(s.model, s.field, DynamicsConfig(dt=0.05, duration=0.1,
                                                          stiffness_damping=0.01))
    with pytest.raises(ValueError, match="stiffness-proportional damping"):
        tangent(damped, states, "bending_stiffness")


@pytest.mark.parametrize("integrator", ["newmark", "implicit_euler"])
def test_a_probes_position_at_the_end_against_central_differences(integrator):
    """J = the tip's z displacement at T (the issue's acceptance quantity)."""
    tip = torch.tensor([[4.0, 0.5]], dtype=torch.float64)

    def probe(st, coefficients):
        operator = DisplacementOperator(st.field, st.model.boundary)
        return displacement_at(operator, tip, coefficients, 1.0)[0, jets.VALUE, 2]

    b, delta = 100.0, 1e-2
    st = stepper(integrator, b)
    c0, v0 = start(st)
    states = record(st, c0, v0)
    end = states[-1].displacement.clone().requires_grad_(True)
    (weight,) = torch.autograd.grad(probe(st, end), end)
    adjoint = gradient(st, states, "bending_stiffness", {len(states) - 1: weight})
    values = [float(probe(other, record(other, c0, v0)[-1].displacement))
              for other in (stepper(integrator, b + delta), stepper(integrator, b - delta))]
    central = (values[0] - values[1]) / (2 * delta)
    assert abs(central) > 1e-6
    assert adjoint == pytest.approx(central, rel=1e-6)


def test_records_time_steps_are_the_continuation_loops_steps(monkeypatch):
    """One call of `solve_over` with the steps' end times [s] as its values, each state after
    t = 0 the result of its step; a step whose Newton does not converge stops the loop and is
    named by its number (from 1)."""
    calls = []

    def spy(stages, steps, **options):
        calls.append(list(steps))
        return continuation.solve_over(stages, steps, **options)

    monkeypatch.setattr(dynamics_adjoint, "solve_over", spy)
    st = stepper("newmark", 100.0)
    c0, v0 = start(st)
    states = record(st, c0, v0)
    assert calls == [[k * 0.05 for k in range(1, 5)]]
    assert [state.time for state in states] == [0.0, *calls[0]]
    assert torch.equal(states[0].displacement, c0)

    steps, real = [], st.step

    def third_fails(state, h):
        end, solution = real(state, h)
        steps.append(state.time)
        return end, types.SimpleNamespace(converged=solution.converged and len(steps) != 3)

    monkeypatch.setattr(st, "step", third_fails)
    with pytest.raises(DynamicsError, match="step 3 did not converge"):
        record(st, c0, v0)
    assert steps == [0.0, *calls[0][:2]]
