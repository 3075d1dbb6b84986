"""A refinement estimate built on a grid whose Newton solve did not converge says so (issue 35):
such a value is not the grid's discrete answer, so its changes say nothing of the order.
Measured: napkin in silk, 2 × 2 and 4 × 4 stopped at Π = 0 after one refused Newton step, the
8 × 8 … 32 × 32 levels converged (benchmarks/RESULTS.md, "Honest numbers (issue 35,
2026-12-06)")."""

from __future__ import annotations

import pytest

from taichi_ndf.minimise.extrapolation import SAFETY_OBSERVED, SAFETY_UNRELIABLE, richardson
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
