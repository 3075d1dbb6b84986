"""Point-load unknowns in the bilevel method: the conditioned field's point-load samples, and
(slow) recovery of a tip load's 3-vector from observations of this project's forward solver.
"""

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from inverse.material import Observation, apply, parse_unknowns
from inverse.material.bilevel import BilevelConfig, bilevel_estimate
from inverse.material.conditioned import (
    ConditionedConfig,
    ConditionedEquilibrium,
    to_coordinates,
    to_values,
)
from taichi_ndf.problem.loads import PointLoad
from taichi_ndf.scene.reader import load_scene

SCENE = Path(__file__).parents[1] / "scenes" / "inverse" / "cantilever_strip.toml"
B_TRUE = 0.2 * 9.81 * 0.2**3
TIP = (0.2, 0.02)


def _model(force):
    """The cantilever strip (bending stiffness of the truth) with a point load at the tip."""
    scene = load_scene(SCENE)
    model = apply(scene.model, parse_unknowns("bending", scene.model)[1], [B_TRUE])
    loads = dataclasses.replace(model.loads, point_loads=(PointLoad(TIP, tuple(force)),))
    return scene, model.with_loads(loads)


def test_point_load_samples_carry_a_share_of_their_own_force():
    """Each of the `point_load_copies` samples at the load draws its own z and carries
    1/copies of the force of that z; the force's known components stay the scene's."""
    _, model = _model((0.0, 0.0, -0.02))
    model, unknowns = parse_unknowns("point_load:0", model)
    unknowns = [u for u in unknowns if u.axis != 1]  # estimate x and z; y stays 0
    copies = 8
    eq = ConditionedEquilibrium(model, unknowns, [(-0.01, 0.01), (-0.03, -0.01)],
                                ConditionedConfig(point_load_copies=copies))
    samples, z = eq.samples(64, torch.Generator().manual_seed(0), torch.float64, "cpu")
    assert len(samples) == len(z) == 64 + copies
    point = samples.weight == 0
    assert int(point.sum()) == copies
    assert torch.allclose(samples.xi[point], torch.tensor(TIP, dtype=torch.float64))
    expected = torch.stack([z[point, 0], torch.zeros(copies, dtype=torch.float64),
                            z[point, 1]], dim=1) / copies
    assert torch.allclose(samples.point_force[point], expected)
    assert not samples.point_force[~point].any()
    assert bool((z[:, 0] >= -0.01).all() and (z[:, 0] <= 0.01).all())
    assert bool((z[:, 1] >= -0.03).all() and (z[:, 1] <= -0.01).all())


def test_coordinates_are_logarithmic_for_stiffness_and_linear_for_forces():
    _, model = _model((0.0, 0.0, -0.02))
    model, unknowns = parse_unknowns("bending,point_load:0", model)
    values = [0.0157, 0.004, -0.003, -0.01]
    z = to_coordinates(unknowns, values)
    assert math.isclose(z[0], math.log(0.0157)) and z[1:] == values[1:]
    assert np.allclose(to_values(unknowns, z), values)


def test_bilevel_needs_a_non_zero_start_force():
    _, model = _model((0.0, 0.0, 0.0))
    model, unknowns = parse_unknowns("point_load:0", model)
    points = model.surface.jets(torch.rand(10, 2, dtype=torch.float64) * 0.04)[:, 0]
    with pytest.raises(ValueError, match="non-zero"):
        bilevel_estimate([Observation(model, points)], unknowns,
                         BilevelConfig(centre_on_residual=False))


def test_point_load_unknown_acts_at_its_own_sample_beside_line_load_nodes():
    """Line-load nodes are zero-weight samples too; the point-load unknown's unit force must
    act at the point load's own sample (the last), not at the first zero-weight row."""
    from inverse.material.unknowns import term_gradients
    from taichi_ndf.problem.line_loads import LineLoad
    from taichi_ndf.problem.sampling import with_point_loads

    _, model = _model((0.0, 0.0, -0.02))
    line = LineLoad(path=((0.2, 0.0), (0.2, 0.04)), force=(0.0, 0.0, -0.1), nodes=4)
    model = model.with_loads(dataclasses.replace(model.loads, line_loads=(line,)))
    model, unknowns = parse_unknowns("point_load:0", model)
    xi = torch.tensor([[0.05, 0.02], [0.1, 0.01]], dtype=torch.float64)
    samples = with_point_loads(model.surface, xi, torch.full((2,), 1e-3, dtype=torch.float64),
                               model.loads)
    u = torch.zeros(len(samples), 6, 3, dtype=torch.float64)
    columns, _ = term_gradients(model, unknowns, samples, u)
    z = next(i for i, unknown in enumerate(unknowns) if unknown.axis == 2)
    rows = torch.nonzero(columns[z].abs().amax(dim=(1, 2))).ravel().tolist()
    assert rows == [len(samples) - 1]
    # dT/du of a unit force F_z at its sample: the work −F·u, so −1 in the value channel's z
    assert float(columns[z][-1, 0, 2]) == pytest.approx(-1.0)
