"""Contact in time (`taichi_ndf.solve.dynamics` with `[[obstacles]]`): a free plate dropped
1 cm onto a ground plane never enters it (the dense check grid's smallest gap > 0 after every
step, and the Gauss points' heights checked here from the coefficients) and comes to lie on
it (the barrier holds its weight: without contact it would have fallen ½ g t² ≈ 0.2 m),
at rest under implicit Euler (Newmark, not dissipative, keeps bouncing on the stiff barrier
at this step: docs/dynamics.md); the lagged friction of a step decelerates a plate sliding
on the barrier at μ g; stiffness damping with contact is refused."""

from __future__ import annotations

import copy
from pathlib import Path

import pytest
import torch

from taichi_ndf import jets
from taichi_ndf.problem.dynamics import DynamicsConfig
from taichi_ndf.scene.reader import parse_scene
from taichi_ndf.solve.dynamics import TimeStepper

GROUND = -0.01  # the plane's height [m]; the plate starts at z = 0
PLATE = {
    "name": "drop_on_ground",
    "geometry": {"type": "plane", "bounds": [[-0.1, 0.1], [-0.1, 0.1]]},
    "material": {"type": "linear", "young_modulus": 1e6, "poisson_ratio": 0.3,
                 "thickness": 1e-3, "areal_density": 0.2},
    "loads": {"gravity": [0.0, 0.0, -9.81]},
    "field": {"type": "spline", "spans": [2, 2]},
    "training": {"load_steps": [1.0]},
    "obstacles": [{"type": "plane", "name": "ground", "point": [0.0, 0.0, GROUND]}],
    "contact": {"check_resolution": 16},
    "probes": [{"name": "centre", "xi": [0.0, 0.0]}],
}


def scene(document):
    return parse_scene(copy.deepcopy(document), base_dir=Path("."))


def drop(integrator, duration):
    s = scene(PLATE)
    config = DynamicsConfig(dt=0.02, duration=duration, integrator=integrator,
                            mass_damping=20.0, frame_rate=50.0)
    stepper = TimeStepper(s.model, s.field, config)
    return s, stepper, stepper.run()


@pytest.mark.parametrize("integrator", ["implicit_euler", "newmark"])
def test_a_dropped_plate_never_enters_the_ground(integrator):
    s, stepper, trajectory = drop(integrator, 0.2)
    gaps = [r.gap for r in trajectory.records]
    assert all(g is not None and g > 0 for g in gaps), gaps
    for _, c in trajectory.frames:  # every Gauss point above the ground, from the coefficients
        z = stepper.samples.r_jets[:, jets.VALUE, 2] + stepper.linear.displacement(c)[
            :, jets.VALUE, 2]
        assert float(z.min()) > GROUND
    # it reached the ground (free fall over 0.2 s: 0.196 m) and the barrier held it there
    centre = [u[2] for u in trajectory.probes["centre"]]
    activation = s.model.contact.activation
    assert GROUND < min(centre) < GROUND + 2 * activation
    assert min(gaps) < activation
    # the gap at t = 0: the plane's distance less half the thickness and the margin
    contact = s.model.contact
    assert trajectory.to_dict()["gaps"][0] == pytest.approx(
        -GROUND - 0.5 * contact.thickness - contact.margin, rel=1e-9)


def test_implicit_euler_brings_it_to_rest_on_the_barrier():
    s, _, trajectory = drop("implicit_euler", 0.2)
    gaps = [r.gap for r in trajectory.records]
    centre = [u[2] for u in trajectory.probes["centre"]]
    activation = s.model.contact.activation
    assert 0 < gaps[-1] < activation  # its lowest point within ĝ: on the barrier
    assert max(centre[-3:]) - min(centre[-3:]) < 0.01 * activation
    assert trajectory.records[-1].kinetic < 1e-9  # [J]; the weight × 1 cm is 7.8e-4 J


def test_stiffness_damping_with_contact_is_refused():
    s = scene(PLATE)
    with pytest.raises(ValueError, match="stiffness damping with contact"):
        TimeStepper(s.model, s.field, DynamicsConfig(dt=0.01, duration=0.01,
                                                     stiffness_damping=1e-3))


def test_the_step_is_feasible_from_its_start_when_the_prediction_is_inside():
    """A plate launched downwards at 1 m/s from 1 cm above the ground: the step's prediction
    x̂ = C + h V is 1 cm inside, yet every step ends outside."""
    s = scene(PLATE)
    config = DynamicsConfig(dt=0.02, duration=0.06, integrator="implicit_euler",
                            mass_damping=5.0)
    stepper = TimeStepper(s.model, s.field, config)
    velocity = torch.zeros_like(stepper.field.coefficients)
    velocity[:, 2] = -1.0  # a uniform translation: the spline's partition of unity
    trajectory = stepper.run(velocity=velocity)
    assert all(r.gap > 0 for r in trajectory.records)


def test_the_shipped_drop_scene_is_a_contact_run_in_time():
    from taichi_ndf.scene.reader import load_scene

    s = load_scene(Path(__file__).resolve().parents[1] / "scenes" / "napkin_drop_sphere.toml")
    assert s.dynamics.integrator == "implicit_euler" and s.dynamics.mass_damping > 0
    assert [o.name for o in s.model.contact.obstacles] == ["sphere"]
    stepper = TimeStepper(s.model, s.field, s.dynamics)
    assert stepper.contact is not None
    assert stepper.gap(torch.zeros_like(stepper.field.coefficients), 0.0) > 0


@pytest.mark.parametrize("mu", [0.0, 0.5])
def test_friction_in_time_decelerates_a_sliding_plate_at_mu_g(mu):
    """A plate resting on the barrier (gap 0.6 mm < ĝ) launched along x at 0.2 m/s: without
    friction it slides on at 0.2 m/s; with μ = 0.5 the lagged friction decelerates it at μ g
    (implicit Euler: v₁ = v₀ − μ g h, x₁ = h v₁) and it stops within two steps."""
    document = copy.deepcopy(PLATE)
    document["obstacles"] = [{"type": "plane", "name": "ground", "point": [0.0, 0.0, -0.0012],
                              "friction": mu}]
    s = scene(document)
    h, v0 = 0.02, 0.2
    stepper = TimeStepper(s.model, s.field, DynamicsConfig(dt=h, duration=5 * h,
                                                           integrator="implicit_euler"))
    velocity = torch.zeros_like(stepper.field.coefficients)
    velocity[:, 0] = v0
    trajectory = stepper.run(velocity=velocity)
    x = [u[0] for u in trajectory.probes["centre"]]
    assert all(r.gap > 0 for r in trajectory.records)
    if mu == 0:
        assert x[-1] == pytest.approx(5 * h * v0, rel=1e-3)
    else:
        assert x[1] == pytest.approx(h * (v0 - mu * 9.81 * h), rel=0.05)
        assert abs(x[-1] - x[2]) < 1e-3 * x[1]  # stuck
