"""Last-layer Newton phase of the material-conditioned field (`ConditionedEquilibrium`):
its Sobol (ξ, z) samples, and the equilibrium it reaches on the cantilever strip against the
independent heavy elastica (scipy BVP)."""

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
import torch
from test_inverse_material_elastica import cantilever

from inverse.material import Observation, apply, parse_unknowns, template_xi
from inverse.material.bilevel import BilevelConfig, bilevel_estimate
from inverse.material.conditioned import ConditionedConfig, ConditionedEquilibrium
from taichi_ndf.boundary import BoundaryConditions
from taichi_ndf.field import NeuralField
from taichi_ndf.problem.loads import PointLoad
from taichi_ndf.scene.reader import load_scene
from taichi_ndf.solve.solver import Solver

SCENES = Path(__file__).parents[1] / "scenes" / "inverse"
LENGTH, WIDTH, RHO, G = 0.2, 0.04, 0.2, 9.81
B_TRUE = RHO * G * 0.2**3


def test_quasi_samples_cover_the_domain_and_the_box_and_carry_the_point_force():
    scene = load_scene(SCENES / "cantilever_strip.toml")
    loads = dataclasses.replace(scene.model.loads,
                                point_loads=(PointLoad((0.2, 0.02), (0.0, 0.0, -0.02)),))
    model, unknowns = parse_unknowns("bending,point_load:0", scene.model.with_loads(loads))
    unknowns = [u for u in unknowns if u.kind != "point_load" or u.axis == 2]
    ranges = [(math.log(0.01), math.log(0.03)), (-0.03, -0.01)]
    copies = 16
    eq = ConditionedEquilibrium(model, unknowns, ranges, ConditionedConfig(
        boundary_length=2.0))
    assert eq.model.boundary.length == 2.0
    samples, z = eq.quasi_samples(1000, torch.Generator().manual_seed(0), torch.float64, "cpu",
                                  copies)
    assert len(samples) == len(z) == 1000 + copies
    area = samples.weight > 0
    assert float(samples.weight.sum()) == pytest.approx(LENGTH * WIDTH, rel=1e-12)
    for j, (lo, hi) in enumerate(ranges):
        assert bool(((z[:, j] >= lo) & (z[:, j] <= hi)).all())
        # Low discrepancy: every tenth of the range holds 100 ± 10 of the 1000 area samples.
        counts = torch.histc(z[area, j], bins=10, min=lo, max=hi)
        assert bool(((counts - 100).abs() <= 10).all())
    point = ~area
    assert torch.allclose(samples.xi[point], torch.tensor([0.2, 0.02], dtype=torch.float64))
    assert torch.allclose(samples.point_force[point, 2], z[point, 1] / copies)
    assert not samples.point_force[area].any()


def test_newton_phase_puts_the_conditioned_strip_in_equilibrium():
    """Adam (features) then one Newton phase: the Newton phase lowers the mean Π, and x*(B)
    at the true B (inside the box) matches the heavy elastica."""
    model, unknowns = parse_unknowns("bending", load_scene(SCENES / "cantilever_strip.toml")
                                     .model)
    config = ConditionedConfig(width=128, hidden_layers=2, iterations=200, samples=256,
                               lbfgs_iterations=0, newton_iterations=10, newton_samples=4096,
                               boundary_length=2.0, output_scale=0.03)
    eq = ConditionedEquilibrium(model, unknowns, [(math.log(B_TRUE / 3), math.log(3 * B_TRUE))],
                                config).train()
    assert eq.newton_result.energy < eq.newton_result.energy_before
    positions, _ = cantilever(LENGTH, B_TRUE, model.material.membrane_stiffness,
                              (0.0, -RHO * G))
    s = np.linspace(0, LENGTH, 21)
    xz = positions(s)
    xi = torch.tensor(np.stack([s, np.full_like(s, 0.02)], axis=1))
    fitted = eq.positions(xi, [math.log(B_TRUE)])
    expected = torch.tensor(np.stack([xz[:, 0], np.full_like(s, 0.02), xz[:, 1]], axis=1))
    assert float((fitted - expected).norm(dim=1).max()) < 0.002 * LENGTH


@pytest.mark.slow
def test_flap_scale_from_a_newton_converged_observation():
    """The orthotropic flap (docs/inverse_material.md): observation solved by last-layer
    Newton with this project's solver (stiffness scale 0.1), conditioned field by Adam +
    Newton, start 10× too stiff, box ±1.3 decades. About 1.5 minutes on the 2-core CPU."""
    scene = load_scene(SCENES / "orthotropic_flap.toml")
    model, unknowns = parse_unknowns("scale", scene.model)
    b = model.boundary
    truth = dataclasses.replace(apply(model, unknowns, [0.1]), boundary=BoundaryConditions(
        b.constraints, b.domain, surface=b.surface, length=2.0))
    field = NeuralField(dataclasses.replace(scene.field, width=128, hidden_layers=2), seed=1)
    Solver(truth, field, dataclasses.replace(
        scene.solver, iterations=0, progress=False, checkpoint_every=0, monitor_samples=2048,
        newton_iterations=40, newton_samples=8192, load_steps=(0.5, 1.0))).run()
    xi = template_xi(truth, scene.output.resolution)
    points = truth.surface.jets(xi)[:, 0] + truth.displacement(field, xi)
    observation = Observation(model, points, xi)
    config = BilevelConfig(field=ConditionedConfig(
        width=256, hidden_layers=2, iterations=300, samples=512, lbfgs_iterations=0,
        newton_iterations=30, newton_samples=8192, boundary_length=2.0,
        output_scale=scene.field.output_scale))
    result = bilevel_estimate([observation], unknowns, config)
    assert abs(result.estimate.value("stiffness_scale_factor") / 0.1 - 1) < 0.02
    noisy = bilevel_estimate([observation.with_noise(0.02, seed=1)], unknowns, config,
                             equilibria=result.equilibria).estimate
    assert noisy.is_determined("stiffness_scale_factor")
    assert abs(noisy.value("stiffness_scale_factor") / 0.1 - 1) < 0.1
