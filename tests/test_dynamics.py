"""Implicit time stepping on a spline field (`taichi_ndf.solve.dynamics`): a free plate falls
as ½ g t² (Newmark: exactly; implicit Euler: its known lag), the first bending mode of a
cantilever strip (ν = 0: the Euler–Bernoulli beam) keeps its energy under Newmark and vibrates
at the scheme's period T (1 + (ωh)²/12), implicit Euler loses the energy fraction
(1 + (ωh)²)⁻¹ per step, a ramped load moves a free plate as each scheme on one point,
mass-proportional damping takes exp(−α t) of the energy and
stiffness-proportional damping exp(−β_R ω² t); a step whose
Newton does not converge is halved and, past the halvings, the run fails; the settings and
what the path refuses."""

from __future__ import annotations

import copy
import logging
import math
from pathlib import Path

import pytest
import torch

from taichi_ndf.minimise.newton import NewtonConfig
from taichi_ndf.problem.dynamics import DynamicsConfig
from taichi_ndf.scene.reader import parse_scene
from taichi_ndf.solve.dynamics import DynamicsError, TimeStepper, initial_velocity

# Cantilever strip L = 10 m, b = 1 m, E = 1.2e6 Pa, h = 0.1 m, ν = 0: B = E h³/12 = 100 N·m,
# ρ_A = 1 kg/m². With ν = 0 the y-independent beam modes are exact plate modes:
# ω₁ = (β₁L)² √(B/(ρ_A L⁴)), β₁L = 1.875104069 (Blevins, Formulas for natural frequency and
# mode shape, table 8-1).
STRIP = {
    "name": "strip",
    "geometry": {"type": "plane", "bounds": [[0.0, 10.0], [0.0, 1.0]]},
    "material": {"type": "linear", "young_modulus": 1.2e6, "poisson_ratio": 0.0,
                 "thickness": 0.1, "areal_density": 1.0},
    "boundary": {"length": 2.0, "constraint": [{"type": "clamped_edge", "edge": "xi1_min"}]},
    "field": {"type": "spline", "spans": [16, 2]},
    "training": {"load_steps": [1.0]},
    "probes": [{"name": "tip", "xi": [10.0, 0.5]}],
}
BETA_L, SIGMA = 1.875104069, 0.734095514
OMEGA = BETA_L**2 * math.sqrt(100.0 / 1e4)  # rad/s
PERIOD = 2 * math.pi / OMEGA
FREE = dict(STRIP, boundary={}, loads={"gravity": [0.0, 0.0, -9.81]},
            field={"type": "spline", "spans": [2, 1]})


def scene(document):
    return parse_scene(copy.deepcopy(document), base_dir=Path("."))


def first_mode(amplitude):
    """The first mode's velocity ω A φ₁(x)/φ₁(L) along z (N, 3) [m/s] at ξ (N, 2)."""
    def rate(xi):
        x = xi[:, 0] * BETA_L / 10.0
        phi = torch.cosh(x) - torch.cos(x) - SIGMA * (torch.sinh(x) - torch.sin(x))
        out = torch.zeros(len(xi), 3, dtype=xi.dtype)
        out[:, 2] = amplitude * OMEGA * phi / 2.0  # φ₁(L) = 2.0
        return out
    return rate


def vibrate(integrator, steps_per_period, periods=1.0, damping=0.0, stiffness_damping=0.0,
            amplitude=0.01):
    s = scene(STRIP)
    dt = PERIOD / steps_per_period
    config = DynamicsConfig(dt=dt, duration=dt * round(periods * steps_per_period),
                            integrator=integrator, mass_damping=damping,
                            stiffness_damping=stiffness_damping)
    stepper = TimeStepper(s.model, s.field, config)
    return stepper.run(velocity=initial_velocity(stepper, first_mode(amplitude)))


def period(trajectory):
    """The period [s] from the tip's zero crossings (linear interpolation)."""
    w, t = [u[2] for u in trajectory.probes["tip"]], trajectory.times
    crossings = [t[i] - w[i] * (t[i + 1] - t[i]) / (w[i + 1] - w[i])
                 for i in range(1, len(w) - 1) if w[i] * w[i + 1] < 0]
    return 2 * (crossings[-1] - crossings[0]) / (len(crossings) - 1)


@pytest.mark.parametrize("integrator", ["newmark", "implicit_euler"])
def test_a_free_plate_falls_as_the_scheme_says(integrator):
    s = scene(FREE)
    h = 0.01
    config = DynamicsConfig(dt=h, duration=5 * h, integrator=integrator)
    trajectory = TimeStepper(s.model, s.field, config).run()
    for n, u in enumerate(trajectory.probes["tip"]):
        # Newmark integrates a constant acceleration exactly; implicit Euler gives
        # x_n = −g h² n (n + 1)/2
        expected = -0.5 * 9.81 * (n * h) ** 2 if integrator == "newmark" else \
            -9.81 * h**2 * n * (n + 1) / 2
        assert u[2] == pytest.approx(expected, rel=1e-8, abs=1e-12)
        assert abs(u[0]) < 1e-12 and abs(u[1]) < 1e-12


@pytest.mark.parametrize("integrator", ["newmark", "implicit_euler"])
def test_a_ramped_load_moves_a_free_plate_as_the_scheme_on_one_point(integrator):
    s = scene(FREE)
    h, ramp = 0.01, 0.04
    config = DynamicsConfig(dt=h, duration=6 * h, integrator=integrator, load_ramp=ramp)
    trajectory = TimeStepper(s.model, s.field, config).run()
    # a rigid translation: every point follows the scheme on ẍ = −g λ(t), λ = min(1, t/ramp)
    x, v, a = 0.0, 0.0, 0.0
    for n, u in enumerate(trajectory.probes["tip"][1:], start=1):
        a_new = -9.81 * min(1.0, n * h / ramp)
        if integrator == "newmark":
            x, v = x + h * v + 0.25 * h * h * (a + a_new), v + 0.5 * h * (a + a_new)
        else:
            v = v + h * a_new
            x = x + h * v
        a = a_new
        assert u[2] == pytest.approx(x, rel=1e-8, abs=1e-14)
    assert trajectory.probes["tip"][0][2] == 0.0
    # the exact motion is −g t³/(6 ramp) up to the ramp's end: Newmark within h² of it
    if integrator == "newmark":
        exact = -9.81 * (4 * h) ** 3 / (6 * ramp)
        assert trajectory.probes["tip"][4][2] == pytest.approx(exact, rel=0.05)


def test_newmark_keeps_the_energy_and_has_its_period():
    trajectory = vibrate("newmark", 20, periods=2.0)
    total = [trajectory.initial.total] + [r.total for r in trajectory.records]
    assert trajectory.initial.kinetic > 0 and trajectory.initial.potential == 0.0
    assert max(abs(e / total[0] - 1) for e in total) < 1e-6
    # the trapezoidal rule's period elongation: T_h = T (1 + (ωh)²/12 + O(h⁴))
    expected = PERIOD * (1 + (2 * math.pi / 20) ** 2 / 12)
    assert period(trajectory) == pytest.approx(expected, rel=2e-4)
    assert all(r.substeps == 1 and r.newton_iterations >= 1 for r in trajectory.records)


def test_implicit_euler_loses_energy_at_its_rate():
    trajectory = vibrate("implicit_euler", 20, periods=0.5)
    # backward Euler on ẍ = −ω² x: each step multiplies the energy by 1/(1 + (ωh)²)
    ratio = 1 / (1 + (2 * math.pi / 20) ** 2)
    for r in trajectory.records:
        assert r.total / trajectory.initial.total == pytest.approx(ratio**r.step, rel=1e-3)


def _newmark_mode(alpha, h, steps):
    """The energy ratio after `steps` Newmark steps (β = ¼, γ = ½) of the one mode
    x'' + α x' + ω² x = 0 from x = 0, x' = 1 (the scheme on the modal equation)."""
    x, v = 0.0, 1.0
    a = -alpha * v
    for _ in range(steps):
        predicted, v_tilde = x + h * v + 0.25 * h * h * a, v + 0.5 * h * a
        scale = 4 / h**2 + 2 * alpha / h
        x_new = (scale * predicted - alpha * v_tilde) / (scale + OMEGA**2)
        a = (x_new - predicted) * 4 / h**2
        x, v = x_new, v_tilde + 0.5 * h * a
    return v * v + OMEGA**2 * x * x


def test_mass_proportional_damping_takes_exp_minus_alpha_t_of_the_energy():
    alpha = 0.02  # 1/s: ζ = α/(2ω) = 2.8 %
    trajectory = vibrate("newmark", 40, periods=1.0, damping=alpha)
    end = trajectory.records[-1]
    ratio = end.total / trajectory.initial.total
    # the scheme on the modal equation, to the spline's modal error
    assert ratio == pytest.approx(_newmark_mode(alpha, PERIOD / 40, 40), rel=1e-5)
    # the exact damped oscillator from x = 0, x' = 1 over one undamped period: 0.69959
    # (exp(−α T) = 0.69949); Newmark's O((ωh)²) error at h = T/40 is 0.3 %
    zeta = alpha / (2 * OMEGA)
    damped = OMEGA * math.sqrt(1 - zeta**2)
    t = end.time
    x = math.exp(-zeta * OMEGA * t) * math.sin(damped * t) / damped
    v = math.exp(-zeta * OMEGA * t) * (math.cos(damped * t) - zeta * OMEGA / damped
                                       * math.sin(damped * t))
    assert ratio == pytest.approx(v * v + OMEGA**2 * x * x, rel=5e-3)
    assert ratio == pytest.approx(math.exp(-alpha * t), rel=5e-3)


def test_stiffness_proportional_damping_is_the_modal_damping_beta_omega_squared():
    beta_r = 0.16  # s: ζ = β_R ω/2 = 2.8 %, the modal damping coefficient β_R ω² [1/s]
    # A tip amplitude of L/10 000: K₀ depends on the state, and at L/1000 the run differs
    # from the linear modal recursion by 4.7e-4 (1e-2 m) against 4.7e-6 here (quadratic in A)
    trajectory = vibrate("newmark", 40, periods=1.0, stiffness_damping=beta_r, amplitude=1e-3)
    end = trajectory.records[-1]
    ratio = end.total / trajectory.initial.total
    assert ratio == pytest.approx(_newmark_mode(beta_r * OMEGA**2, PERIOD / 40, 40), rel=2e-5)
    assert ratio == pytest.approx(math.exp(-beta_r * OMEGA**2 * end.time), rel=5e-3)
    # implicit Euler: its own loss, 1/(1 + (ωh)²) per step, and the damping's on top
    undamped = vibrate("implicit_euler", 20, periods=0.25)
    damped = vibrate("implicit_euler", 20, periods=0.25, stiffness_damping=beta_r)
    assert damped.records[-1].total < undamped.records[-1].total * 0.99


def test_a_halved_step_is_the_same_as_four_steps_of_a_quarter(caplog):
    # Two Newton iterations (a step and the test that stops) suffice at h = T/80 but not at
    # T/20 or T/40 (3 there: the longer step's nonlinearity needs a second Newton step)
    s = scene(STRIP)
    h = PERIOD / 20
    stepper = TimeStepper(s.model, s.field, DynamicsConfig(dt=h, duration=2 * h, halvings=3,
                                                          integrator="newmark"),
                          newton=NewtonConfig(max_iterations=2))
    with caplog.at_level(logging.WARNING, logger="taichi_ndf.solve.dynamics"):
        halved = stepper.run(velocity=initial_velocity(stepper, first_mode(0.01)))
    assert [r.substeps for r in halved.records] == [4, 4]
    assert sum("halved" in r.message for r in caplog.records) == 6
    assert [r.time for r in halved.records] == pytest.approx([h, 2 * h], rel=1e-15)
    direct = TimeStepper(s.model, s.field, DynamicsConfig(dt=h / 4, duration=2 * h,
                                                          integrator="newmark"))
    straight = direct.run(velocity=initial_velocity(direct, first_mode(0.01)))
    assert all(r.substeps == 1 for r in straight.records)
    assert halved.probes["tip"][-1] == pytest.approx(straight.probes["tip"][-1], rel=1e-9,
                                                     abs=1e-15)
    assert halved.records[-1].total == pytest.approx(straight.records[-1].total, rel=1e-9)


def test_a_step_that_does_not_converge_is_halved_then_refused(caplog):
    s = scene(STRIP)
    config = DynamicsConfig(dt=PERIOD / 20, duration=PERIOD / 20, halvings=2,
                            integrator="newmark")
    stepper = TimeStepper(s.model, s.field, config, newton=NewtonConfig(max_iterations=1))
    with caplog.at_level(logging.WARNING, logger="taichi_ndf.solve.dynamics"), \
            pytest.raises(DynamicsError, match="did not converge .* also after 2 halvings"):
        stepper.run(velocity=initial_velocity(stepper, first_mode(0.01)))
    assert sum("halved" in r.message for r in caplog.records) == 2


@pytest.mark.parametrize("settings, message", [
    ({"dt": 0.0, "duration": 1.0}, "dt must be finite and > 0"),
    ({"dt": 0.1, "duration": 0.05}, "duration .* must be at least dt"),
    ({"dt": 0.3, "duration": 1.0}, "whole number of steps"),
    ({"dt": 0.1, "duration": 1.0, "integrator": "verlet"}, "integrator must be one of"),
    ({"dt": 0.1, "duration": 1.0, "frame_rate": 20.0}, "more than one frame per step"),
    ({"dt": 0.1, "duration": 1.0, "mass_damping": -1.0}, "mass_damping must be"),
    ({"dt": 0.1, "duration": 1.0, "stiffness_damping": math.nan}, "stiffness_damping must be"),
    ({"dt": 0.1, "duration": 1.0, "halvings": -1}, "halvings must be"),
    ({"dt": 0.1, "duration": 1.0, "load_ramp": -1.0}, "load_ramp must be"),
])
def test_bad_settings_are_refused(settings, message):
    with pytest.raises(ValueError, match=message):
        DynamicsConfig(**settings)


def test_frames_and_steps():
    config = DynamicsConfig(dt=0.01, duration=1.0, frame_rate=30.0)
    assert config.steps == 100 and config.frame_every == 3 and config.frames == 1 + 33 + 1
    assert DynamicsConfig(dt=0.01, duration=1.0, frame_rate=50.0).frames == 51
    assert DynamicsConfig(dt=0.01, duration=1.0).frames == 2


def test_prescribed_displacements_need_a_motion_in_time():
    document = dict(STRIP, boundary={"constraint": [
        {"type": "clamped_edge", "edge": "xi1_min", "displacement": [0.0, 0.0, 0.1]}]})
    s = scene(document)
    with pytest.raises(ValueError, match="give their motion in time"):
        TimeStepper(s.model, s.field, DynamicsConfig(dt=0.1, duration=0.1))
