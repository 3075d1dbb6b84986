"""Knot lines on the band ends (`field.knot_lines`, `spline_grid.band_end_config`, `[field]
band_end_knots`; issue 33): an edge's vanishing factor that ends inside the domain leaves u/φ
with a third-derivative jump there, and the grid rule moves a knot line of the coarsest grid
onto it, so it is a knot line on every level. Measured (benchmarks/RESULTS.md, wip-adapt16):
the full square plate's Π on 8² / 16² / 32² changes at order 3.79 with the rule, 0.71
without."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from taichi_ndf.discretise.trimmed import span_knots
from taichi_ndf.field import SplineConfig
from taichi_ndf.field.knot_lines import KnotLineMap, KnotLines, knot_lines_for
from taichi_ndf.problem.spline_grid import band_ends
from taichi_ndf.scene.reader import load_scene
from taichi_ndf.solve.spline_solver import solve_spline

ROOT = Path(__file__).resolve().parents[1]
PLATE = ROOT / "validation/scenes/square_plate.toml"


def test_the_map_sends_the_breaks_onto_knots_and_is_c2():
    lines = knot_lines_for([55.0, 45.0], 8, 0.0, 100.0)
    assert lines == KnotLines((45.0, 55.0), (37.5, 50.0))  # 50 is nearest to both: one moves
    h = KnotLineMap(lines, 0.0, 100.0)
    at = torch.tensor([45.0, 55.0], dtype=torch.float64)
    assert torch.allclose(h.jets(at)[0], torch.tensor([37.5, 50.0], dtype=torch.float64),
                          atol=1e-12, rtol=0)
    eps = 1e-9
    for b in (45.0, 55.0):  # h, h′, h″ continuous across a breakpoint
        left, right = (h.jets(torch.tensor([b + s], dtype=torch.float64)) for s in (-eps, eps))
        for k, tol in enumerate((1e-8, 1e-8, 1e-8)):
            assert abs(float(left[k] - right[k])) < tol
    ends = h.jets(torch.tensor([0.0, 100.0], dtype=torch.float64))
    assert ends[0].tolist() == [0.0, 100.0] and float(ends[2].abs().max()) == 0.0
    x = torch.linspace(0.0, 100.0, 1001, dtype=torch.float64)
    assert float(h.jets(x)[1].min()) > 0
    assert torch.allclose(h.inverse(h.jets(x)[0]), x, atol=1e-10, rtol=0)


def test_too_few_knots_and_bad_lines_are_refused():
    assert knot_lines_for([45.0, 55.0], 2, 0.0, 100.0) is None  # one interior knot for two
    with pytest.raises(ValueError, match="strictly increasing"):
        KnotLines((55.0, 45.0), (50.0, 62.5))
    with pytest.raises(ValueError, match="strictly inside"):
        KnotLineMap(KnotLines((45.0,), (100.0,)), 0.0, 100.0)
    with pytest.raises(ValueError, match="periodic"):
        SplineConfig(spans=(8, 8), domain=((0.0, 100.0), (0.0, 100.0)),
                     periodic=(True, False), grading=(KnotLines((45.0,), (50.0,)), None))


def test_the_plates_band_ends_are_knot_lines_on_every_level():
    scene = load_scene(PLATE, field="spline", overrides={"field.band_end_knots": True})
    assert band_ends(scene.model.boundary) == ((45.0, 55.0), (45.0, 55.0))
    config = scene.field.config
    assert SplineConfig.from_dict(config.to_dict()) == config  # a checkpoint keeps them
    for _ in range(3):
        for knots in span_knots(config):
            for end in (45.0, 55.0):
                assert np.abs(knots - end).min() < 1e-9
        config = config.refined()
    off = load_scene(PLATE, field="spline")  # the default: uniform knots
    assert off.field.config.grading == (None, None)
    assert all(np.abs(k - 45.0).min() > 1 for k in span_knots(off.field.config))


@pytest.mark.slow
def test_the_plates_energy_converges_at_the_full_order():
    """Π on 8², 16², 32²: the order of its changes ≥ 3.5 (measured 3.79; 0.71 without)."""
    scene = load_scene(PLATE, field="spline", overrides={"field.band_end_knots": True})
    plan = dataclasses.replace(scene.field, levels=3)
    solver = dataclasses.replace(scene.solver, max_levels=0)
    energy: list[float] = []
    solve_spline(scene.model, plan, solver,
                 on_level=lambda run: energy.append(run.load_steps[-1]["energy"]))
    order = math.log2(abs((energy[1] - energy[0]) / (energy[2] - energy[1])))
    assert order >= 3.5, (energy, order)
