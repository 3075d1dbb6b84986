"""What the adjoint of the time steps (`taichi_ndf.solve.dynamics_adjoint`) covers, issue 29's
Build item "adjoints through contact, wind, motions": contact and wind are refused in one
line (ValueError) by `gradient`, `tangent` and `record` alike, not answered with a gradient of
another problem (the adjoint's step Hessian and `record`'s polish have no barrier or drag);
boundary motions are followed since issue 27 item 3 (tests/test_dynamics_adjoint_motion.py
checks them against central differences); and a boundary motion with obstacles is refused by
the scene reader."""

from __future__ import annotations

import copy
from pathlib import Path

import pytest

from taichi_ndf.problem.dynamics import DynamicsConfig
from taichi_ndf.problem.wind import Wind
from taichi_ndf.scene.reader import parse_scene
from taichi_ndf.scene.schema import SceneError
from taichi_ndf.solve.dynamics import TimeStepper
from taichi_ndf.solve.dynamics_adjoint import gradient, record, tangent

PLATE = {
    "name": "plate",
    "geometry": {"type": "plane", "bounds": [[0.0, 0.2], [0.0, 0.1]]},
    "material": {"type": "linear", "young_modulus": 1.2e6, "poisson_ratio": 0.0,
                 "thickness": 0.01, "areal_density": 0.2},
    "loads": {"gravity": [0.0, 0.0, -9.81]},
    "field": {"type": "spline", "spans": [2, 1]},
    "training": {"load_steps": [1.0]},
}
OBSTACLE = {"obstacles": [{"type": "plane", "name": "ground", "point": [0.0, 0.0, -0.01]}],
            "contact": {"check_resolution": 8}}
MOVING = {"boundary": {"length": 2.0, "constraint": [
    {"type": "clamped_edge", "edge": "xi1_min", "displacement": [0.0, 0.0, 0.02]}]}}


def scene(document):
    return parse_scene(copy.deepcopy(document), base_dir=Path("."))


def refused(stepper, match):
    for call in (lambda: record(stepper), lambda: gradient(stepper, [None], "bending_stiffness",
                                                            {}),
                 lambda: tangent(stepper, [None], "bending_stiffness")):
        with pytest.raises(ValueError, match=match) as info:
            call()
        assert "\n" not in str(info.value)


def test_the_adjoint_refuses_contact():
    s = scene({**PLATE, **OBSTACLE})
    refused(TimeStepper(s.model, s.field, DynamicsConfig(dt=0.02, duration=0.04)), "contact")


def test_the_adjoint_refuses_wind():
    s = scene(PLATE)
    config = DynamicsConfig(dt=0.02, duration=0.04, wind=Wind(velocity=(0.0, 0.0, 2.0)))
    refused(TimeStepper(s.model, s.field, config), "wind")


def test_a_boundary_motion_with_obstacles_is_refused_by_the_scene():
    document = {**PLATE, **OBSTACLE, **MOVING,
                "dynamics": {"dt": 0.02, "duration": 0.04,
                             "motion": {"times": [0.0, 0.04], "factors": [0.0, 1.0]}}}
    with pytest.raises(SceneError, match="boundary motion with contact") as info:
        scene(document)
    assert "\n" not in str(info.value)
