"""A refinement estimate built on a grid whose Newton solve did not converge says so (issue 35):
such a value is not the grid's discrete answer, so its changes say nothing of the order.
Measured: napkin in silk, 2 × 2 and 4 × 4 stopped at Π = 0 after one refused Newton step, the
8 × 8 … 32 × 32 levels converged (benchmarks/RESULTS.md, "Honest numbers (issue 35,
2026-12-06)")."""

from __future__ import annotations

import pytest

from taichi_ndf.minimise.extrapolation import (
    SAFETY_OBSERVED,
    SAFETY_UNRELIABLE,
    richardson,
    richardson_point,
)
from taichi_ndf.minimise.state import LevelSummary, State
from taichi_ndf.problem.training import SolverConfig
from taichi_ndf.solve.spline_solver import SplineRun

# v_h = 1 + h²: an exact order-2 sequence on h = 1, 1/2, 1/4 (changes −0.75, −0.1875)
POWER_LAW = [2.0, 1.25, 1.0625]


def test_an_order_observed_on_converged_levels_is_trusted():
    bar = richardson(POWER_LAW, order=4.0, converged=[True, True, True])
    assert bar.basis == "observed" and bar.order == pytest.approx(2.0)
    assert bar.value == pytest.approx(1.0) and bar.error == pytest.approx(
        SAFETY_OBSERVED * 0.0625)


def test_an_unconverged_level_makes_the_order_unreliable_whatever_the_changes():
    bar = richardson(POWER_LAW, order=4.0, converged=[False, True, True])
    assert bar.basis == "unreliable"
    assert bar.reason == "grid level 0 of 3 not converged"
    assert "not converged" in bar.describe() and bar.warning is not None
    assert bar.value == POWER_LAW[-1]
    assert bar.error == pytest.approx(SAFETY_UNRELIABLE * (POWER_LAW[0] - POWER_LAW[-1]))


def test_only_the_levels_used_count():
    """Four levels, the first unconverged: the last three are all converged."""
    bar = richardson([7.0, *POWER_LAW], order=4.0, converged=[False, True, True, True])
    assert bar.basis == "observed" and bar.grids == 4


def test_two_unconverged_grids_keep_the_change_and_warn():
    bar = richardson(POWER_LAW[1:], order=4.0, converged=[True, False])
    assert bar.basis == "assumed" and bar.error == pytest.approx(0.1875)
    assert bar.reason == "grid level 1 of 2 not converged" and "not converged" in bar.warning


def test_flags_and_values_must_match():
    with pytest.raises(ValueError, match="2 convergence flags for 3 values"):
        richardson(POWER_LAW, order=4.0, converged=[True, True])


def test_the_spline_run_passes_each_levels_convergence():
    """`SplineRun.refinement` (result.json, the console, energy.png) reads the flags of the
    levels: the first of three stopped unconverged."""
    levels = [LevelSummary(i, (2**i, 2**i), v, {"corner": [0.0, 0.0, v]}, 5, 1.0, i > 0)
              for i, v in enumerate(POWER_LAW)]
    run = SplineRun(State(field=None, method="newton", levels=levels), SolverConfig())
    document = run.refinement(degree=3)
    assert document["energy"]["order_basis"] == "unreliable"
    assert document["energy"]["order_reason"] == "grid level 0 of 3 not converged"
    assert document["probes"]["corner"][2]["order_basis"] == "unreliable"


# The flag's fly_bottom u [m] on 15 × 10, 30 × 20, 60 × 40 (`--refine`'s default grids) and
# 120 × 80 (benchmarks/RESULTS.md, "The flag's `--refine` default bar").
FLY_BOTTOM = [[-1.3827656233145138, -0.6294148886317771, 0.9082769030865477],
              [-1.425668581722233, -0.6906006114736567, 0.8001595744224824],
              [-1.5262452125614634, -0.7047660823853151, 0.7908669335849227]]
FLY_BOTTOM_120 = [-1.5226829823712211, -0.7130130768309426, 0.774102203532385]


def test_a_probe_component_takes_the_points_order():
    """fly_bottom's z alone falls at order 3.54 (a ± 1.1 mm bar that misses the 120 × 80
    value by 16 mm; y at 2.11); the point moves 0.131 m then 0.102 m (order 0.37): y and z
    unreliable for the point's reason (x does not fall: its own), and every component's bar
    holds the 120 × 80 value."""
    alone = richardson([u[2] for u in FLY_BOTTOM], order=4.0)
    assert alone.basis == "observed" and abs(alone.value - FLY_BOTTOM_120[2]) > alone.error
    bars = richardson_point(FLY_BOTTOM, order=4.0)
    assert all(b.basis == "unreliable" for b in bars)
    assert bars[0].reason == "changes not falling monotonically"  # x: its own reason
    assert all("the point's observed order 0.37" in b.reason for b in bars[1:])
    assert all(abs(b.value - ref) <= b.error for b, ref in zip(bars, FLY_BOTTOM_120,
                                                                strict=True))


def test_a_point_converging_at_one_order_keeps_each_components_extrapolation():
    """u_h = u∞ + c h² per component (different c): the point's order is 2, each component
    is extrapolated to its u∞ as `richardson` does alone."""
    u_inf, c = [0.3, -0.2, 1.0], [1.0, -3.0, 0.5]
    values = [[a + k / 4**i for a, k in zip(u_inf, c, strict=True)] for i in range(3)]
    bars = richardson_point(values, order=4.0)
    for axis, bar in enumerate(bars):
        alone = richardson([v[axis] for v in values], order=4.0)
        assert bar.basis == "observed" and bar.order == pytest.approx(2.0)
        assert bar.value == pytest.approx(u_inf[axis]) == pytest.approx(alone.value)
        assert bar.error == pytest.approx(alone.error)
    unconverged = richardson_point(values, order=4.0, converged=[True, False, True])
    assert all(b.reason == "grid level 1 of 3 not converged" for b in unconverged)


def test_components_that_do_not_fall_stay_unreliable_when_the_point_falls():
    """The napkin's free corner on 2², 4², 8² (scenes/napkin.toml): |Δu| falls (order 1.01)
    but no component falls monotonically: their own unreliable bars are kept (they hold the
    32² value; bars at the point's order 1.01 missed x and y, benchmarks/RESULTS.md)."""
    corner = [[-0.8474192, -0.8488420, -1.4148213], [-0.8049260, -0.8102842, -1.4069167],
              [-0.8202152, -0.8317524, -1.4181840]]
    bars = richardson_point(corner, order=4.0)
    for axis, bar in enumerate(bars):
        alone = richardson([u[axis] for u in corner], order=4.0)
        assert bar == alone and bar.basis == "unreliable"


# Measured sequences (benchmarks/refinement_coverage_*.json, issue 35; their finer values):
# cantilever_shear's tip deflection on 4×1 / 8×2 / 16×4 (observed order 5.29, the last change
# 4.8e-6 of the value) and on 64×16; at its first load step (the last change 6e-9, at the
# rounding level); bowl in silk's centre on 2² / 4² / 8² (order 5.0, the last change 2.3e-3
# of the value) and on 32² (28 × that change away).
CANTILEVER = ([6.698596586, 6.699848783, 6.699880784], 6.699891985)
CANTILEVER_FIRST_LOAD = ([1.309746478, 1.30975294, 1.309752946], 1.309753429)
BOWL_SILK = ([-0.2270182726, -0.2450067314, -0.2455683642], -0.2610352035)


@pytest.mark.parametrize("values, reference", [CANTILEVER, CANTILEVER_FIRST_LOAD])
def test_a_sequence_converged_to_the_rounding_level_gets_a_bar_of_its_size(values, reference):
    """Changes that fall faster than the expected order to within a decade of the rounding
    level: the bar is the changes still to come (the last one, at least the rounding level,
    summed at order 0.5), not 3 × the range (344 × and 40 × the distance to the finer value):
    it holds that value and is at most 10 × the distance."""
    bar = richardson(values, order=4.0)
    distance = abs(reference - bar.value)
    assert bar.basis == "unreliable" and bar.bound == "floor"
    assert bar.value == values[-1]
    assert distance <= bar.error <= 10 * distance
    assert "summed at order 0.5" in bar.describe()


def test_a_fast_fall_far_above_the_rounding_level_keeps_the_range():
    """Bowl in silk's coarse grids fall at order 5.0 by coincidence: 3 × the range, which
    holds the 32² value (the last change alone misses it by 28 ×)."""
    values, reference = BOWL_SILK
    bar = richardson(values, order=4.0)
    assert bar.bound == "range"
    assert bar.error == pytest.approx(SAFETY_UNRELIABLE * abs(values[2] - values[0]))
    assert abs(reference - bar.value) <= bar.error


def test_a_point_converged_to_the_rounding_level_bounds_each_component():
    """The point's changes (norms) fall to the floor: a component whose own order looks
    reliable takes the point's floor bar, which bounds the vector's changes still to come."""
    x = [0.1, 0.1 + 1e-5, 0.1 + 1.25e-5]  # its own changes fall at order 2: reliable alone
    tip = [[a, 0.0, v] for a, v in zip(x, CANTILEVER[0], strict=True)]
    assert richardson(x, order=4.0).basis == "observed"
    bars = richardson_point(tip, order=4.0)
    assert bars[0].bound == "floor" and bars[2].bound == "floor"
    assert bars[0].error >= bars[2].error >= abs(CANTILEVER[1] - CANTILEVER[0][2])
    assert bars[0].error <= 10 * abs(CANTILEVER[1] - CANTILEVER[0][2])
