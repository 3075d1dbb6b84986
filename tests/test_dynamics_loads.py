"""Loads and motions in time in the dynamic path: wind with the quadratic drag law on the
normal relative velocity (`problem.wind`, `objective.wind`), and a prescribed boundary motion
μ(t) (`problem.dynamics.BoundaryMotion`), with their scene keys."""

from __future__ import annotations

import copy
import math
from pathlib import Path

import pytest

from taichi_ndf.problem.dynamics import AdaptiveStep, BoundaryMotion, DynamicsConfig
from taichi_ndf.problem.wind import Wind
from taichi_ndf.scene.reader import parse_scene
from taichi_ndf.scene.schema import SceneError
from taichi_ndf.solve.dynamics import TimeStepper

# A free 0.2 m x 0.1 m plate, no gravity (ρ_A = 0.2 kg/m²).
PLATE = {
    "name": "plate",
    "geometry": {"type": "plane", "bounds": [[0.0, 0.2], [0.0, 0.1]]},
    "material": {"type": "linear", "young_modulus": 1.2e6, "poisson_ratio": 0.0,
                 "thickness": 0.01, "areal_density": 0.2},
    "field": {"type": "spline", "spans": [2, 1]},
    "training": {"load_steps": [1.0]},
    "probes": [{"name": "root", "xi": [0.0, 0.05]}, {"name": "tip", "xi": [0.2, 0.05]}],
}


def scene(document):
    return parse_scene(copy.deepcopy(document), base_dir=Path("."))


def test_wind_pushes_a_plate_by_the_drag_law_on_its_normal_velocity():
    """Wind (3, 0, 2) m/s on a plate in the x-y plane: only the normal part 2 m/s acts; the
    plate moves as implicit Euler with the drag linearised about each step's start does on
    one point: ρ_A (v' − v)/h = p(s) + p'(s)(v − v'), s = U − v, p = ½ ρ C_d s|s|."""
    s = scene(PLATE)
    wind = Wind(velocity=(3.0, 0.0, 2.0), air_density=1.2, drag_coefficient=1.5)
    h, steps = 0.02, 10
    stepper = TimeStepper(s.model, s.field, DynamicsConfig(dt=h, duration=h * steps,
                                                           wind=wind))
    trajectory = stepper.run()
    k, rho = 1.2 * 1.5, 0.2
    z, v = 0.0, 0.0
    for n in range(steps):
        s_ = 2.0 - v
        p, slope = 0.5 * k * s_ * abs(s_), k * abs(s_)
        v = (rho * v / h + p + slope * v) / (rho / h + slope)
        z += h * v
        for probe in ("root", "tip"):
            u = trajectory.probes[probe][n + 1]
            assert u[2] == pytest.approx(z, rel=1e-9)
            assert abs(u[0]) < 1e-12 and abs(u[1]) < 1e-12  # the tangential wind does nothing
    assert 0.5 < v < 2.0  # still accelerating towards the air's speed


def test_wind_gusts():
    wind = Wind(velocity=(0.0, 1.0, 2.0), gust_amplitude=0.5, gust_frequency=2.0)
    assert wind.at(0.125) == pytest.approx((0.0, 1.5, 3.0))  # sin(π/2) = 1
    assert wind.at(0.375) == pytest.approx((0.0, 0.5, 1.0))
    p, slope = wind.pressure(__import__("torch").tensor([-2.0, 3.0]))
    assert p.tolist() == pytest.approx([-0.5 * 1.2 * 1.2 * 4, 0.5 * 1.2 * 1.2 * 9])
    assert slope.tolist() == pytest.approx([1.2 * 1.2 * 2, 1.2 * 1.2 * 3])


def test_a_prescribed_motion_moves_the_clamped_edge_and_the_plate_follows():
    """The clamped root moves by μ(t) (0, 0, 0.02) m, μ rising from 0 to 1 over 0.2 s then
    held: the root follows μ(t) exactly at every step, the plate (first bending mode 0.1 s,
    damped) follows it at the root's mean speed 0.1 m/s and settles at the displaced rest."""
    document = dict(PLATE, boundary={"length": 2.0, "constraint": [
        {"type": "clamped_edge", "edge": "xi1_min", "displacement": [0.0, 0.0, 0.02]}]})
    s = scene(document)
    motion = BoundaryMotion(keyframes=((0.0, 0.0), (0.2, 1.0)))
    h = 0.005
    config = DynamicsConfig(dt=h, duration=0.3, motion=motion, mass_damping=40.0)
    trajectory = TimeStepper(s.model, s.field, config).run()
    times = trajectory.times
    root = [u[2] for u in trajectory.probes["root"]]
    tip = [u[2] for u in trajectory.probes["tip"]]
    for t, z in zip(times, root, strict=True):
        assert z == pytest.approx(0.02 * min(1.0, t / 0.2), abs=1e-12)
    assert (tip[40] - tip[20]) / 0.1 == pytest.approx(0.1, rel=0.05)  # t = 0.1 ... 0.2 s
    assert tip[-1] == pytest.approx(0.02, rel=0.02)
    assert trajectory.records[-1].kinetic < 1e-3 * max(r.kinetic for r in trajectory.records)


def test_a_boundary_motion_is_needed_for_prescribed_displacements():
    document = dict(PLATE, boundary={"constraint": [
        {"type": "clamped_edge", "edge": "xi1_min", "displacement": [0.0, 0.0, 0.1]}]})
    s = scene(document)
    with pytest.raises(ValueError, match=r"\[dynamics.motion\]"):
        TimeStepper(s.model, s.field, DynamicsConfig(dt=0.1, duration=0.1))
    with pytest.raises(ValueError, match="no displacement to move"):
        s = scene(PLATE)
        TimeStepper(s.model, s.field, DynamicsConfig(
            dt=0.1, duration=0.1, motion=BoundaryMotion(amplitude=1.0, frequency=1.0)))


def test_motion_factors():
    ramp = BoundaryMotion(keyframes=((0.0, 0.0), (1.0, 2.0), (3.0, -1.0)))
    assert [ramp.factor(t) for t in (0.0, 0.5, 1.0, 2.0, 3.0, 9.0)] == \
        pytest.approx([0.0, 1.0, 2.0, 0.5, -1.0, -1.0])
    wave = BoundaryMotion(amplitude=0.5, frequency=2.0)
    assert wave.factor(0.125) == pytest.approx(0.5) and wave.factor(0.0) == 0.0
    assert DynamicsConfig(dt=0.1, duration=0.1).boundary_factor(0.05) == 1.0
    assert math.isclose(DynamicsConfig(dt=0.1, duration=0.1, motion=wave).boundary_factor(
        0.375), -0.5)


@pytest.mark.parametrize("section, message", [
    ({"wind": {"velocity": [1.0, 0.0]}}, "dynamics.wind.velocity: expected a list of 3"),
    ({"wind": {"velocity": [1.0, 0.0, 0.0], "gust_amplitude": -1.0}},
     "dynamics.wind.gust_amplitude"),
    ({"wind": {"velocity": [1.0, 0.0, 0.0], "drag_coefficient": 0.0}},
     "dynamics.wind.drag_coefficient"),
    ({"wind": {"velocity": [1.0, 0.0, 0.0], "speed": 3.0}}, "unknown key"),
    ({"motion": {"times": [0.0, 1.0], "factors": [0.0]}}, "one factor per time"),
    ({"motion": {"times": [0.0, 1.0], "factors": [0.5, 1.0]}}, "must start at"),
    ({"motion": {"times": [0.0, 1.0, 1.0], "factors": [0.0, 1.0, 2.0]}}, "must increase"),
    ({"motion": {"times": [0.0, 1.0], "factors": [0.0, 1.0], "frequency": 1.0}}, "not both"),
    ({"motion": {"amplitude": 1.0, "frequency": 0.0}}, "dynamics.motion.frequency"),
])
def test_bad_wind_and_motion_keys_are_refused_in_one_line(section, message):
    document = dict(PLATE, dynamics={"dt": 0.1, "duration": 0.1, **section})
    with pytest.raises(SceneError, match=message) as err:
        scene(document)
    assert "\n" not in str(err.value)


def test_wind_and_motion_keys_are_read():
    document = dict(PLATE, boundary={"constraint": [
        {"type": "clamped_edge", "edge": "xi1_min", "displacement": [0.0, 0.0, 0.1]}]},
        dynamics={"dt": 0.1, "duration": 0.2, "wind": {
            "velocity": [0.0, 5.0, 0.0], "gust_amplitude": 0.3, "gust_frequency": 0.5},
            "motion": {"times": [0.0, 0.1], "factors": [0.0, 1.0]}})
    config = scene(document).dynamics
    assert config.wind == Wind(velocity=(0.0, 5.0, 0.0), gust_amplitude=0.3,
                               gust_frequency=0.5)
    assert config.motion.keyframes == ((0.0, 0.0), (0.1, 1.0))
    assert config.to_dict()["wind"]["velocity"] == [0.0, 5.0, 0.0]


def test_adaptive_steps_grow_on_easy_solves_and_land_on_the_frames():
    """A free plate falling under gravity (every Newton solve easy): after every 3 easy steps
    h grows by 1.25 up to max_dt, shortened to land on each output frame; the fall is implicit
    Euler's with those steps, v' = v − g h, z' = z + h v', to 1e-9."""
    document = dict(PLATE, loads={"gravity": [0.0, 0.0, -9.81]})
    s = scene(document)
    rule = AdaptiveStep(max_dt=0.02, easy_iterations=4, grow_after=3)
    config = DynamicsConfig(dt=0.005, duration=0.2, frame_rate=20, adaptive=rule)
    trajectory = TimeStepper(s.model, s.field, config).run()
    sizes = [r.size for r in trajectory.records]
    assert sizes[:4] == pytest.approx([0.005, 0.005, 0.005, 0.00625])
    assert max(sizes) == pytest.approx(0.005 * 1.25**6) and len(sizes) < 0.6 * config.steps
    assert [t for t, _ in trajectory.frames] == [0.0, 0.05, 0.1, 0.15, 0.2]
    assert trajectory.times[-1] == 0.2
    z, v = 0.0, 0.0
    for n, h in enumerate(sizes):
        v -= 9.81 * h
        z += h * v
        assert trajectory.probes["tip"][n + 1][2] == pytest.approx(z, rel=1e-9)
    assert trajectory.to_dict()["step_sizes"] == sizes


def test_the_adaptive_rule():
    rule = AdaptiveStep(max_dt=0.1, easy_iterations=3, grow_after=2)
    assert rule.after(0.01, 0, 3, 1) == (0.01, 1)
    assert rule.after(0.01, 1, 2, 1) == (pytest.approx(0.0125), 0)
    assert rule.after(0.01, 1, 4, 1) == (0.01, 0)  # a hard solve resets the count
    assert rule.after(0.01, 1, 9, 3) == (0.005, 0)  # halved: on at half the size
    assert rule.after(0.09, 1, 1, 1) == (0.1, 0)  # capped at max_dt
    with pytest.raises(ValueError, match="max_dt must be >= dt"):
        DynamicsConfig(dt=0.1, duration=0.1, adaptive=AdaptiveStep(max_dt=0.05))
    with pytest.raises(SceneError, match="dynamics.max_dt: needs adaptive = true"):
        scene(dict(PLATE, dynamics={"dt": 0.1, "duration": 0.1, "max_dt": 0.2}))
    read = scene(dict(PLATE, dynamics={"dt": 0.1, "duration": 0.2, "adaptive": True}))
    assert read.dynamics.adaptive == AdaptiveStep(max_dt=0.8)
