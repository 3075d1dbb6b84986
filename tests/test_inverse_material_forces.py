"""Force estimation by the equilibrium-residual method (Π is linear in the loads) on the
heavy-elastica reference of `test_inverse_material_elastica` (scipy BVP): the gravity
direction of a strip whose weight pulls 20° off the vertical."""

import math

import numpy as np
import torch
from test_inverse_material_elastica import cantilever

from inverse.material import Observation, ResidualConfig, parse_unknowns, residual_estimate
from taichi_ndf.boundary import BoundaryConditions, ClampedEdge
from taichi_ndf.geometry import Plane
from taichi_ndf.loads import Loads
from taichi_ndf.model import ShellModel
from taichi_ndf.shell.materials import LinearIsotropic


def test_gravity_direction_within_one_degree():
    length, width, rho, g, c, membrane = 0.1, 0.03, 0.2, 9.81, 0.05, 100.0
    bending = rho * g * c**3
    tilt = math.radians(20.0)
    gravity = (g * math.sin(tilt), 0.0, -g * math.cos(tilt))
    positions, _ = cantilever(length, bending, membrane, (rho * gravity[0], rho * gravity[2]))
    s, y = np.meshgrid(np.linspace(0, length, 41), np.linspace(0, width, 9))
    xz = positions(s.ravel())
    points = torch.tensor(np.stack([xz[:, 0], y.ravel(), xz[:, 1]], axis=1))
    xi = torch.tensor(np.stack([s.ravel(), y.ravel()], axis=1))
    surface = Plane(bounds=((0.0, length), (0.0, width)))
    material = LinearIsotropic(membrane, bending, 0.0, rho)  # known material: a force scale
    model = ShellModel(surface, material, Loads(gravity=(0.0, 0.0, -1.0)),
                       BoundaryConditions([ClampedEdge("xi1_min")], surface.domain))
    model, unknowns = parse_unknowns("gravity", model)
    estimate = residual_estimate([Observation(model, points, xi)], unknowns,
                                 ResidualConfig(fit_degree=8, virtual_degree=2, samples=16384))
    g_est = np.array([estimate.value(f"gravity_{a}") for a in "xyz"])
    angle = math.degrees(math.acos(g_est @ np.array(gravity) / np.linalg.norm(g_est) / g))
    assert estimate.is_determined("gravity_x") and estimate.is_determined("gravity_z")
    assert angle < 1.0
    assert abs(np.linalg.norm(g_est) / g - 1) < 0.03
