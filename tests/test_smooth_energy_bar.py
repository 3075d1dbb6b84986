"""Π of a model with no known singular feature, converged to the rounding level: the changes
still to come are summed at the a-priori order 2(p − 1) with Roache's Fs = 3 for an assumed
order (`richardson(..., smooth=True)`, bound "a priori"), not at order 0.5 (issue 33:
"never more than 10 × too large"). Measured sequences: the coverage table of benchmarks/
RESULTS.md ("Adaptive refinement: gauges, honest bars, coverage") and the stored studies
(benchmarks/refinement_coverage_*.json), each with its finer solve; the shear cantilever's
Π solved for issue 33 on wip-adapt12 (5 dyadic grids from 4 × 1, Newton defaults and to
λ²/2 ≤ 1e-15 |Π|: the same values to 10 digits)."""

from __future__ import annotations

from pathlib import Path

import pytest

from taichi_ndf.minimise.extrapolation import SAFETY_UNRELIABLE, richardson
from taichi_ndf.minimise.state import LevelSummary, State
from taichi_ndf.problem.spline_grid import no_singular_feature
from taichi_ndf.problem.training import SolverConfig
from taichi_ndf.scene.reader import load_scene
from taichi_ndf.solve.spline_solver import SplineRun

ROOT = Path(__file__).resolve().parents[1]

# (Π on three grids [J], Π on the finer grid, the order-0.5 floor's bar / distance before)
SMOOTH = {
    "square_plate_quarter 8² / 16² / 32², 64²": (
        [-231.4931519, -231.4984642, -231.4987818], -231.4988014, 39.1),
    "cantilever_moment 16×2 / 32×4 / 64×8, 128×16 (d₂ below the rounding level)": (
        [-164.5228386, -164.5308415, -164.5309962], -164.5310101, 28.6),
    "scordelis_lo_roof 14×20 / 28×40 / 56×80, 112×160": (
        [-4825.360291, -4825.996841, -4826.009192], -4826.009627, 68.5),
    "square_plate_quarter h = 0.5, 4² / 8² / 16², 64²": (
        [-641.5846841, -641.6473263, -641.650636], -641.6508454, 38.2),
}


@pytest.mark.parametrize("values, reference, before", SMOOTH.values(), ids=SMOOTH)
def test_a_smooth_models_energy_past_the_floor_is_summed_at_the_a_priori_order(
        values, reference, before):
    bar = richardson(values, order=4.0, smooth=True)
    distance = abs(reference - bar.value)
    assert bar.basis == "unreliable" and bar.bound == "a priori" and bar.value == values[-1]
    floor = max(abs(values[2] - values[1]), 1e-6 * max(abs(v) for v in values))
    assert bar.error == pytest.approx(SAFETY_UNRELIABLE * floor / 15.0)
    assert distance <= bar.error <= 10 * distance
    assert "a-priori order" in bar.describe()
    # the same values as a probe, or Π of a model with a feature: the order-0.5 floor
    old = richardson(values, order=4.0)
    assert old.bound == "floor" and old.error / distance == pytest.approx(before, rel=0.02)


def test_changes_slower_than_the_a_priori_order_keep_the_order_half_floor():
    """The shear cantilever's Π on 8×2 / 16×4 / 32×8 (point loads: a feature) falls at order
    1.88 near the rounding level, then at 0.41 to 64×16: even called smooth, an observed order
    below the a-priori one keeps the order-0.5 sum, which holds the 64×16 value (the sum at
    order 4 would be 0.42 × the distance)."""
    values, reference = [-17.571911352, -17.571951885, -17.5719629064], -17.5719712113
    bar = richardson(values, order=4.0, smooth=True)
    assert bar.bound == "floor"
    assert bar == richardson(values, order=4.0)
    assert abs(reference - bar.value) <= bar.error


def test_the_spline_run_reads_its_energy_at_the_a_priori_order_only_where_smooth():
    """`SplineRun.refinement` (result.json, the console, energy.png): Π's bar by the run's
    `smooth`; a probe's not without its solve errors (they go with √λ², not λ²/2:
    tests/test_probe_solve_error.py)."""
    values = SMOOTH["square_plate_quarter 8² / 16² / 32², 64²"][0]
    levels = [LevelSummary(i, (8 * 2**i, 8 * 2**i), v, {"centre": [0.0, 0.0, -v / 1e3]}, 5,
                           1.0, True) for i, v in enumerate(values)]
    for smooth, bound in ((True, "a priori"), (False, "floor")):
        run = SplineRun(State(field=None, method="newton", levels=levels), SolverConfig(),
                        smooth=smooth)
        document = run.refinement(degree=3)
        assert document["energy"]["error_bound"] == bound
        assert document["probes"]["centre"][2]["error_bound"] == "floor"


@pytest.mark.parametrize("scene, smooth", [
    ("validation/scenes/square_plate_quarter.toml", True),
    ("validation/scenes/scordelis_lo_roof.toml", True),
    ("validation/scenes/cantilever_moment.toml", True),
    ("validation/scenes/cantilever_shear.toml", False),  # point loads
    ("validation/scenes/pinched_hemisphere.toml", False),  # point loads (its pin a gauge)
    ("scenes/napkin.toml", False),  # a pin that carries the weight
    ("scenes/napkin_interior_line.toml", False),  # an interior line
    ("scenes/tablecloth_box.toml", False),  # an obstacle
])
def test_which_models_have_no_known_singular_feature(scene, smooth):
    model = load_scene(ROOT / scene, field="spline").model
    assert no_singular_feature(model) is smooth


@pytest.mark.parametrize("scene, smooth", [
    ("validation/scenes/square_plate_quarter.toml", True),
    ("validation/scenes/pinched_cylinder_octant.toml", False),  # a point load
])
def test_solve_spline_marks_its_run_smooth_by_the_models_features(scene, smooth):
    """The run that result.json's refinement is read from carries the model's test."""
    import dataclasses

    from taichi_ndf.solve.spline_solver import solve_spline

    loaded = load_scene(ROOT / scene, field="spline")
    plan = dataclasses.replace(loaded.field, levels=1, config=dataclasses.replace(
        loaded.field.config, spans=(4, 4)))
    solver = dataclasses.replace(loaded.solver, max_levels=0, progress=False,
                                 load_steps=(1.0,))
    assert solve_spline(loaded.model, plan, solver).smooth is smooth
