"""Start shapes distinct from the rest shape (issue 30; docs/scenes.md "Start"): the
`[start]` table, its fit by the spline's coefficients, its one-line errors."""

from __future__ import annotations

import copy
import math
import re
import tomllib
from pathlib import Path

import pytest
import torch

from taichi_ndf import jets
from taichi_ndf.discretise import of_scene
from taichi_ndf.discretise.start import fitted_start
from taichi_ndf.field.spline import SplineConfig
from taichi_ndf.minimise.assembly import displacement_at
from taichi_ndf.minimise.linearisation import GridLinearisation
from taichi_ndf.problem.operator import DisplacementOperator
from taichi_ndf.problem.start_shape import StartShape
from taichi_ndf.problem.training import SolverConfig
from taichi_ndf.scene.reader import parse_scene
from taichi_ndf.scene.schema import SceneError

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "scenes" / "napkin_fold.toml"


def _parse(**start):
    document = tomllib.loads(SCENE.read_text())
    if start:
        document["start"] = start
    return parse_scene(copy.deepcopy(document), base_dir=ROOT / "scenes")


def test_the_napkin_scene_starts_folded_and_a_scene_without_start_at_rest():
    assert _parse().start == StartShape("fold", axis=0, at=0.3, radius=0.01)
    document = tomllib.loads(SCENE.read_text())
    del document["start"]
    assert parse_scene(document, base_dir=ROOT / "scenes").start is None


def test_fold_and_wrap_are_isometric_and_rigid_moves_rigidly():
    xi = torch.stack(torch.meshgrid(torch.linspace(0, 0.6, 601, dtype=torch.float64),
                                    torch.tensor([0.0], dtype=torch.float64),
                                    indexing="ij"), -1).reshape(-1, 2)
    r = torch.cat((xi, torch.zeros(len(xi), 1, dtype=xi.dtype)), 1)
    e1 = torch.tensor([[1.0, 0, 0]], dtype=xi.dtype).expand_as(r)
    e2 = torch.tensor([[0, 1.0, 0]], dtype=xi.dtype).expand_as(r)
    for shape in (StartShape("fold", at=0.3, radius=0.01),
                  StartShape("wrap", at=0.0, radius=0.6 / math.pi)):
        x = shape.positions(xi, r, e1, e2)
        arc = (x[1:] - x[:-1]).norm(dim=1).sum()
        assert float(arc) == pytest.approx(0.6, rel=1e-4)
    folded = StartShape("fold", at=0.3, radius=0.01).positions(xi, r, e1, e2)
    assert folded[-1].tolist() == pytest.approx([0.0, 0.0, 0.02], abs=1e-12)
    wrapped = StartShape("wrap", at=0.0, radius=0.6 / math.pi).positions(xi, r, e1, e2)
    assert wrapped[-1].tolist() == pytest.approx([0.0, 0.0, -1.2 / math.pi], abs=1e-12)
    moved = StartShape(rotation_axis=(0, 0, 1), angle=90, translation=(1, 0, 0)).positions(
        xi, r, e1, e2)
    assert moved[-1].tolist() == pytest.approx([1.0, 0.6, 0.0], abs=1e-12)


def test_the_fit_reproduces_the_start_at_the_gauss_points():
    """A half-cylinder wrap of the 0.6 m × 0.15 m napkin on 16 × 2 cubic spans, clamped at
    ξ¹ = 0 (where the wrap is tangent): the fitted displacement within 1e-4 m of the wrap's at
    every Gauss point, and the discretisation starts from it."""
    scene = _parse(type="wrap", at=0.0, radius=0.6 / math.pi)
    model = scene.model
    config = SplineConfig(spans=(16, 2), domain=model.surface.domain.bounds)
    shape = scene.start
    field = fitted_start(model, config, shape)
    samples = GridLinearisation.quadrature(model.surface, config, model.loads,
                                           dtype=torch.float64)
    r = samples.r_jets
    target = shape.positions(samples.xi, r[:, jets.VALUE], r[:, 1], r[:, 2]) - r[:, jets.VALUE]
    got = displacement_at(DisplacementOperator(field, model.boundary), samples.xi,
                          field.coefficients, 1.0)[:, jets.VALUE]
    assert float((got - target).norm(dim=1).max()) < 1e-4
    assert float(target.norm(dim=1).max()) > 0.1
    discretisation = of_scene(scene)
    discretisation.start(SolverConfig(method="newton"), seed=0)
    assert discretisation.state.field.coefficients.abs().max() > 0.1


@pytest.mark.parametrize(("start", "message"), [
    ({"type": "twist"}, "start.type"),
    ({"type": "fold", "at": 0.7, "radius": 0.01}, "start.at: 0.7 is outside"),
    ({"type": "fold", "at": 0.3}, "start.radius"),
    ({"type": "wrap", "at": 0.3, "radius": -1.0}, "start.radius"),
    ({"type": "rigid", "rotation_axis": [0, 0, 0]}, "start: rotation_axis must not be zero"),
    ({"type": "rigid", "colour": 1}, "start: unknown key(s) 'colour'"),
])
def test_bad_start_tables_are_refused_in_one_line(start, message):
    with pytest.raises(SceneError, match=re.escape(message)) as err:
        _parse(**start)
    assert "\n" not in str(err.value)
