"""Force estimation by the equilibrium-residual method (Π is linear in the loads) on the
heavy-elastica reference of `test_inverse_material_elastica` (scipy BVP): the gravity
direction of a strip whose weight pulls 20° off the vertical, clean and with noise."""

import math

import numpy as np
import torch
from test_inverse_material_elastica import cantilever

from inverse.material import Observation, ResidualConfig, parse_unknowns, residual_estimate
from taichi_ndf.boundary import BoundaryConditions, ClampedEdge
from taichi_ndf.geometry import Plane
from taichi_ndf.problem.loads import Loads
from taichi_ndf.problem.model import ShellModel
from taichi_ndf.shell.materials import LinearIsotropic

GRAVITY = (9.81 * math.sin(math.radians(20.0)), 0.0, -9.81 * math.cos(math.radians(20.0)))


def _tilted_strip():
    """Observation (41 x 9 points) of a strip whose weight pulls 20° off the vertical, with the
    material known and gravity unknown."""
    length, width, rho, g, c, membrane = 0.1, 0.03, 0.2, 9.81, 0.05, 100.0
    bending = rho * g * c**3
    positions, _ = cantilever(length, bending, membrane, (rho * GRAVITY[0], rho * GRAVITY[2]))
    s, y = np.meshgrid(np.linspace(0, length, 41), np.linspace(0, width, 9))
    xz = positions(s.ravel())
    points = torch.tensor(np.stack([xz[:, 0], y.ravel(), xz[:, 1]], axis=1))
    xi = torch.tensor(np.stack([s.ravel(), y.ravel()], axis=1))
    surface = Plane(bounds=((0.0, length), (0.0, width)))
    material = LinearIsotropic(membrane, bending, 0.0, rho)  # known material: a force scale
    model = ShellModel(surface, material, Loads(gravity=(0.0, 0.0, -1.0)),
                       BoundaryConditions([ClampedEdge("xi1_min")], surface.domain))
    model, unknowns = parse_unknowns("gravity", model)
    return Observation(model, points, xi), unknowns


def test_gravity_direction_within_one_degree():
    observation, unknowns = _tilted_strip()
    estimate = residual_estimate([observation], unknowns,
                                 ResidualConfig(fit_degree=8, virtual_degree=2, samples=16384))
    g_est = np.array([estimate.value(f"gravity_{a}") for a in "xyz"])
    g = np.linalg.norm(GRAVITY)
    angle = math.degrees(math.acos(g_est @ np.array(GRAVITY) / np.linalg.norm(g_est) / g))
    assert estimate.is_determined("gravity_x") and estimate.is_determined("gravity_z")
    assert angle < 1.0
    assert abs(np.linalg.norm(g_est) / g - 1) < 0.03


def test_noisy_gravity_is_reported_undetermined_not_wrong():
    """With 0.5 % noise the residual method cannot find gravity (the fit's second derivatives
    amplify noise; measured 60°-88° off): the identifiability analysis must say so."""
    observation, unknowns = _tilted_strip()
    estimate = residual_estimate([observation.with_noise(0.005, seed=1)], unknowns,
                                 ResidualConfig(fit_degree=8, virtual_degree=2, samples=16384))
    assert not any(estimate.identifiability.determined)
    assert np.all(np.isinf(estimate.standard_errors))
