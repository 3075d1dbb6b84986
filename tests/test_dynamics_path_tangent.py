"""Held points' paths as unknowns in the dynamics' tangent (issue 27 item 3): a sheet held at
two corner handles on paths with p unknowns (`HandlePath.basis`), started at rest
(`rest_start`: its dC₀/dq); the tangent's columns dC_k/dq, projected on J = Σ w_k · C_k
(k = 0 included), against central differences of whole runs with the path moved along each
basis column, each run from its own rest state (float64, within 1e-6 relative); θ's column
unchanged by the path's; without the boundary's terms of the step the columns miss."""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest
import torch

from taichi_ndf.minimise.newton import NewtonConfig
from taichi_ndf.problem.dynamics import DynamicsConfig
from taichi_ndf.scene.reader import parse_scene
from taichi_ndf.solve import dynamics_adjoint
from taichi_ndf.solve.dynamics_adjoint import record, rest_start, tangent
from taichi_ndf.solve.handle_paths import HandlePath, PathStepper
from tests.test_dynamics_adjoint_start import PATH, SHEET, objective, weights

# three unknowns: corner a's x along a ramp, corner b's z as a bump, both corners' y at t = 0.05
BASIS = np.zeros((5, 2, 3, 3))
BASIS[:, 0, 0, 0] = [0.0, 0.25, 0.5, 0.75, 1.0]
BASIS[:, 1, 2, 1] = [1.0, 0.8, 0.3, 0.1, 0.0]
BASIS[1, :, 1, 2] = 1.0
BENDING = 1e-2


def sheet(q=None, basis=BASIS):
    scene = parse_scene(copy.deepcopy(SHEET), base_dir=Path("."))
    model = scene.model.with_material(
        scene.model.material.with_stiffness(bending_stiffness=BENDING))
    config = DynamicsConfig(dt=0.05, duration=0.2, integrator="implicit_euler",
                            mass_damping=0.5)
    q = np.zeros(BASIS.shape[-1]) if q is None else q
    path = HandlePath(PATH.times, PATH.displacements + BASIS @ q, basis)
    return PathStepper(model, scene.field, config, path, newton=NewtonConfig())


def run(q=None):
    stepper = sheet(q)
    start = rest_start(stepper, torch.zeros_like(stepper.field.coefficients),
                       "bending_stiffness")
    return stepper, start, record(stepper, start.displacement, start.velocity)


@pytest.fixture(scope="module")
def check():
    stepper, start, states = run()
    w = weights(len(states), states[0].displacement.shape)
    delta = 1e-5
    central = []
    for j in range(BASIS.shape[-1]):
        e = np.zeros(3)
        e[j] = delta
        central.append((objective(run(e)[2], w) - objective(run(-e)[2], w)) / (2 * delta))
    return stepper, start, states, w, np.array(central)


def projected(forward, w):
    return np.array([sum(float((w[k] * forward[k][..., j]).sum()) for k in w)
                     for j in range(forward[0].shape[-1])])


def test_the_paths_columns_match_central_differences_of_whole_runs(check):
    stepper, start, states, w, central = check
    assert start.derivative[0].shape[-1] == 1 + BASIS.shape[-1]
    forward = projected(tangent(stepper, states, "bending_stiffness", start.derivative), w)
    assert np.all(np.abs(central) > 1e-3)
    assert forward[1:] == pytest.approx(central, rel=1e-6)
    # θ's column is the tangent of the path without unknowns
    bare = sheet(basis=None)
    bare_start = rest_start(bare, start.displacement, "bending_stiffness")
    alone = tangent(bare, states, "bending_stiffness", bare_start.derivative)
    assert projected([a[..., None] for a in alone], w)[0] == pytest.approx(forward[0],
                                                                            rel=1e-9)


def test_without_the_boundarys_step_terms_the_columns_miss(check, monkeypatch):
    stepper, start, states, w, central = check
    monkeypatch.setattr(dynamics_adjoint, "_pulled",
                        lambda st, linear, blocks: torch.zeros(
                            len(st.field.coefficients), 3, 6, dtype=torch.float64))
    forward = projected(tangent(stepper, states, "bending_stiffness", start.derivative), w)
    assert np.max(np.abs(forward[1:] / central - 1)) > 1e-3
