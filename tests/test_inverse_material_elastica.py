"""The planar heavy elastica (`taichi_ndf.validation.elastica`, scipy BVP, none of the
project's solver code) as the independent reference of the material estimators."""

import numpy as np
import pytest

from taichi_ndf.validation.elastica import cantilever  # noqa: F401 (imported by other tests)


def test_reference_elastica_reproduces_the_cantilever_test_angle():
    """Peirce / ASTM D1388: at overhang L = 2c (c = (B / (ρ_A g))^{1/3}) the chord from the
    clamp to the tip of an inextensible strip makes 41.5° with the horizontal."""
    length, rho_g = 0.1, 0.2 * 9.81
    c = length / 2
    positions, _ = cantilever(length, rho_g * c**3, 1e7, (0.0, -rho_g))
    x, z = positions([length])[0]
    assert abs(np.degrees(np.arctan2(-z, x)) - 41.5) < 0.1


LENGTH, WIDTH, RHO, G, BENDING_LENGTH, MEMBRANE = 0.1, 0.03, 0.2, 9.81, 0.05, 100.0


def heavy_elastica_observation(start_material):
    """A strip clamped at ξ¹ = 0 under its own weight, shape from the reference ODE (not from
    this project's solver), 41 × 9 points; the model carries `start_material`.
    Returns (model, observation, true bending stiffness [N·m])."""
    import torch

    from taichi_ndf.boundary import BoundaryConditions, ClampedEdge
    from taichi_ndf.geometry import Plane
    from taichi_ndf.problem.loads import Loads
    from taichi_ndf.problem.model import ShellModel

    bending = RHO * G * BENDING_LENGTH**3
    positions, _ = cantilever(LENGTH, bending, MEMBRANE, (0.0, -RHO * G))
    s, y = np.meshgrid(np.linspace(0, LENGTH, 41), np.linspace(0, WIDTH, 9))
    xz = positions(s.ravel())
    points = torch.tensor(np.stack([xz[:, 0], y.ravel(), xz[:, 1]], axis=1))
    xi = torch.tensor(np.stack([s.ravel(), y.ravel()], axis=1))
    surface = Plane(bounds=((0.0, LENGTH), (0.0, WIDTH)))
    model = ShellModel(surface, start_material, Loads(gravity=(0.0, 0.0, -G)),
                       BoundaryConditions([ClampedEdge("xi1_min")], surface.domain))
    return model, points, xi, bending


def test_residual_estimate_recovers_the_bending_length_of_a_heavy_elastica():
    """The scene's B is 10× too stiff and is not used: bending length within 3 %."""
    from inverse.material import (
        Observation,
        ResidualConfig,
        bending_length,
        parse_unknowns,
        residual_estimate,
    )
    from taichi_ndf.shell.materials import LinearIsotropic

    bending = RHO * G * BENDING_LENGTH**3
    start = LinearIsotropic(MEMBRANE, 10 * bending, 0.0, RHO)  # ν = 0: cylindrical bending
    model, points, xi, _ = heavy_elastica_observation(start)
    model, unknowns = parse_unknowns("bending", model)
    estimate = residual_estimate([Observation(model, points, xi)], unknowns,
                                 ResidualConfig(fit_degree=8, virtual_degree=2, samples=16384))
    assert estimate.is_determined("bending_stiffness")
    c_est, _ = bending_length(estimate, model)
    assert abs(c_est / BENDING_LENGTH - 1) < 0.03


def test_residual_estimate_recovers_young_modulus_at_known_thickness():
    """E at the strip's known thickness h = √(12 B / D) and ν = 0, from a start 10× too
    stiff (D and B both 10×): E h³ / 12 is the bending stiffness, so the bending length
    (E h³ / (12 ρ_A g))^{1/3} must be within 3 %; the estimate is reported in Pa."""
    import math

    from inverse.material import Observation, ResidualConfig, parse_unknowns, residual_estimate
    from taichi_ndf.shell.materials import LinearIsotropic

    bending = RHO * G * BENDING_LENGTH**3
    thickness = math.sqrt(12 * bending / MEMBRANE)
    young = MEMBRANE / thickness
    start = LinearIsotropic.from_young(10 * young, 0.0, thickness, RHO)
    model, points, xi, _ = heavy_elastica_observation(start)
    model, unknowns = parse_unknowns("E", model)
    assert [u.name for u in unknowns] == ["young_modulus"] and unknowns[0].unit == "Pa"
    assert unknowns[0].value(model) == pytest.approx(10 * young)
    estimate = residual_estimate([Observation(model, points, xi)], unknowns,
                                 ResidualConfig(fit_degree=8, virtual_degree=2, samples=16384))
    assert estimate.is_determined("young_modulus")
    c_est = (estimate.value("young_modulus") * thickness**3 / 12 / (RHO * G)) ** (1 / 3)
    assert abs(c_est / BENDING_LENGTH - 1) < 0.03


def test_young_modulus_is_refused_for_other_materials_and_with_scale():
    from inverse.material import parse_unknowns
    from taichi_ndf.shell.materials import LinearIsotropic, OrthotropicStVK

    model, _, _, _ = heavy_elastica_observation(
        OrthotropicStVK.isotropic(100.0, 0.3, 0.01, areal_density=RHO))
    with pytest.raises(ValueError, match="young_modulus needs the linear isotropic"):
        parse_unknowns("young_modulus", model)
    model, _, _, _ = heavy_elastica_observation(LinearIsotropic(100.0, 1e-3, 0.3, RHO))
    with pytest.raises(ValueError, match="same unknown"):
        parse_unknowns("scale,E", model)
