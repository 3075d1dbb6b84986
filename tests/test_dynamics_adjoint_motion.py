"""The dynamics adjoint with prescribed boundary motions (issue 27 item 3): dJ/dB against
central differences of whole runs (float64, within 1e-6 relative) on a cantilever strip whose
clamped end moves by a sinusoid (a scene's `[dynamics.motion]`) and on a sheet held at two
corner handles that follow their own paths in time (`solve.handle_paths.PathStepper`), the
tangent as the adjoint's transpose there, and the path's boundary where the path puts it."""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest
import torch

from inverse.material.trajectory_fit import observe
from taichi_ndf.minimise.newton import NewtonConfig
from taichi_ndf.problem.dynamics import BoundaryMotion, DynamicsConfig
from taichi_ndf.scene.reader import parse_scene
from taichi_ndf.solve.dynamics import TimeStepper
from taichi_ndf.solve.dynamics_adjoint import gradient, record, tangent
from taichi_ndf.solve.handle_paths import HandlePath, PathStepper

STRIP = {
    "name": "strip",
    "geometry": {"type": "plane", "bounds": [[0.0, 4.0], [0.0, 1.0]]},
    "material": {"type": "linear", "young_modulus": 1.2e6, "poisson_ratio": 0.3,
                 "thickness": 0.1, "areal_density": 1.0},
    "boundary": {"length": 1.0, "constraint": [
        {"type": "clamped_edge", "edge": "xi1_min", "displacement": [0.0, 0.1, 0.3]}]},
    "loads": {"gravity": [0.0, 0.0, -9.81]},
    "field": {"type": "spline", "spans": [6, 1]},
    "training": {"load_steps": [1.0]},
}
# A 1 m × 0.5 m sheet in the x-z plane held at its top corners (handles), hanging along −z.
SHEET = {
    "name": "sheet",
    "geometry": {"type": "plane", "bounds": [[0.0, 1.0], [0.0, 0.5]]},
    "material": {"type": "linear", "young_modulus": 1.2e6, "poisson_ratio": 0.3,
                 "thickness": 0.01, "areal_density": 1.0},
    "boundary": {"length": 0.2, "constraint": [
        {"type": "handle", "xi": [0.0, 0.0], "displacement": [0.0, 0.0, 0.0]},
        {"type": "handle", "xi": [1.0, 0.0], "displacement": [0.0, 0.0, 0.0]}]},
    "loads": {"gravity": [0.0, -9.81, 0.0]},
    "field": {"type": "spline", "spans": [3, 2]},
    "training": {"load_steps": [1.0]},
}
NEWTON = NewtonConfig()
PATH = HandlePath((0.0, 0.05, 0.1, 0.15, 0.2),
                  np.array([[[0.0, 0.0, 0.0], [0.0, 0.0, 0.0]],
                            [[0.01, 0.0, 0.02], [0.0, 0.01, -0.01]],
                            [[0.03, 0.01, 0.05], [-0.01, 0.02, -0.03]],
                            [[0.04, 0.01, 0.06], [-0.02, 0.02, -0.02]],
                            [[0.04, 0.0, 0.05], [-0.02, 0.01, 0.0]]]))


def strip(bending, integrator="newmark", alpha=0.0):
    s = parse_scene(copy.deepcopy(STRIP), base_dir=Path("."))
    model = s.model.with_material(s.model.material.with_stiffness(bending_stiffness=bending))
    config = DynamicsConfig(dt=0.05, duration=0.2, integrator=integrator, mass_damping=alpha,
                            motion=BoundaryMotion(amplitude=1.0, frequency=2.5))
    return TimeStepper(model, s.field, config, newton=NEWTON)


def sheet(bending, integrator="newmark", path=PATH):
    s = parse_scene(copy.deepcopy(SHEET), base_dir=Path("."))
    model = s.model.with_material(s.model.material.with_stiffness(bending_stiffness=bending))
    config = DynamicsConfig(dt=0.05, duration=0.2, integrator=integrator, mass_damping=0.5)
    return PathStepper(model, s.field, config, path, newton=NEWTON)


def weights(n_states, shape):
    generator = torch.Generator().manual_seed(5)
    return {k: torch.randn(shape, generator=generator, dtype=torch.float64)
            for k in (n_states // 2, n_states - 1)}


def objective(states, w):
    return sum(float((w[k] * states[k].displacement).sum()) for k in w)


def central_check(make, b, delta):
    st = make(b)
    states = record(st)
    w = weights(len(states), states[0].displacement.shape)
    adjoint = gradient(st, states, "bending_stiffness", w)
    values = [objective(record(make(b + s * delta)), w) for s in (1, -1)]
    return adjoint, (values[0] - values[1]) / (2 * delta), st, states, w


@pytest.mark.parametrize("integrator,alpha", [("newmark", 0.0), ("implicit_euler", 0.5)])
def test_the_adjoint_with_a_sinusoidal_end_matches_central_differences(integrator, alpha):
    adjoint, central, st, states, _ = central_check(
        lambda b: strip(b, integrator, alpha), 100.0, 1e-2)
    # the end moved: the clamped edge's displacement is μ(t) (0, 0.1, 0.3) m at each state
    end = observe(st, torch.tensor([[0.0, 0.5]], dtype=torch.float64),
                  states[1].displacement, states[1].time)
    assert end[0].tolist() == pytest.approx([0.0, 0.1 * np.sin(2 * np.pi * 2.5 * 0.05),
                                             0.3 * np.sin(2 * np.pi * 2.5 * 0.05)], abs=1e-12)
    assert abs(central) > 1e-6
    assert adjoint == pytest.approx(central, rel=1e-6)


def test_the_adjoint_with_handles_on_paths_matches_central_differences():
    adjoint, central, st, states, w = central_check(sheet, 1e-2, 1e-6)
    assert abs(central) > 1e-6
    assert adjoint == pytest.approx(central, rel=1e-6)
    forward = tangent(st, states, "bending_stiffness")
    assert sum(float((w[k] * forward[k]).sum()) for k in w) == pytest.approx(adjoint,
                                                                            rel=1e-10)


def test_without_the_boundarys_motion_the_adjoint_misses(monkeypatch):
    """The same check with the boundary frozen at its start in the adjoint's K and ∂f/∂θ
    (as the code before this change took them) is off by more than 1e-3."""
    adjoint, central, st, states, w = central_check(sheet, 1e-2, 1e-6)
    frozen = st._offsets[0.0]
    original = PathStepper._at

    def at_start(self, t):
        linear = original(self, t)
        self._grid.assembly.offset = frozen
        return linear

    monkeypatch.setattr(PathStepper, "_at", at_start)
    wrong = gradient(st, states, "bending_stiffness", w)
    assert abs(wrong / central - 1) > 1e-3


def test_the_handles_stand_where_their_path_puts_them():
    st = sheet(1e-2, "implicit_euler")
    states = record(st)
    corners = torch.tensor([[0.0, 0.0], [1.0, 0.0]], dtype=torch.float64)
    for state in states:
        u = observe(st, corners, state.displacement, state.time)
        assert u.numpy() == pytest.approx(PATH.at(state.time), abs=1e-12)
    # the free part stays held at the corners (J C = 0 there)
    assert float(observe(st, corners, states[-1].displacement).abs().max()) < 1e-12


def test_a_path_is_checked():
    with pytest.raises(ValueError, match="must start at 0"):
        HandlePath((0.1, 0.2), np.zeros((2, 2, 3)))
    with pytest.raises(ValueError, match=r"\(T, H, 3\)"):
        HandlePath((0.0, 0.2), np.zeros((3, 2, 3)))
    with pytest.raises(ValueError, match="3 handles' displacements for 2 handles"):
        sheet(1e-2, path=HandlePath((0.0, 0.2), np.zeros((2, 3, 3))))
    s = parse_scene(copy.deepcopy(STRIP), base_dir=Path("."))
    with pytest.raises(ValueError, match="no handle to move"):
        PathStepper(s.model, s.field, DynamicsConfig(dt=0.05, duration=0.2), PATH)
    moved = copy.deepcopy(SHEET)
    moved["boundary"]["constraint"][0]["displacement"] = [0.0, 0.0, 0.01]
    s = parse_scene(moved, base_dir=Path("."))
    with pytest.raises(ValueError, match="must be at the reference"):
        PathStepper(s.model, s.field, DynamicsConfig(dt=0.05, duration=0.2), PATH)
    with pytest.raises(ValueError, match="either"):
        PathStepper(s.model, s.field, DynamicsConfig(
            dt=0.05, duration=0.2, motion=BoundaryMotion(amplitude=1.0, frequency=1.0)), PATH)
