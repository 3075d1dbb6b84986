"""A smooth model's quantity whose changes fall faster than the a-priori order on both of the
last two ratios: Roache's GCI at the slower observed order with Fs = 1.25 on the finest value
(`richardson(..., smooth=True)`, bound "fast"; issue 33: "never more than 10 × too large").
The ratios are taken within the values' solve errors, every change above the rounding level,
and the four values used converged. Measured sequences: benchmarks/RESULTS.md (wip-adapt14:
cantilever_moment's −U solved to precision, with its recorded solve errors) and the stored
studies (benchmarks/refinement_coverage_out5.json, out6.json), each with its finer value."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from taichi_ndf.minimise.extrapolation import SAFETY_OBSERVED, richardson

# cantilever_moment's tip:0 on 8×1 / 16×2 / 32×4 / 64×8 at the probe stop, its recorded solve
# errors, and its tight 128×16 value (wip-adapt14; tests/test_probe_solve_error.py)
MOMENT = [-12.2390722858, -11.9999505405, -11.9945929367, -11.9945126512]
MOMENT_ERRORS = [2.2e-9, 4.5e-9, 4.3e-12, 9.0e-10]
MOMENT_FINER = -11.99451248
# the quarter plate at ν = 0.45 (out6): centre:2 on 4² … 32² with the probe stop's errors,
# and its 128² value
PLATE = [0.332637449578, 0.332930320896, 0.332945683454, 0.332946601238]
PLATE_ERRORS = [1.27e-9, 6.8e-12, 1.9e-14, 8.9e-16]
PLATE_FINER = 0.332946661596
# the quarter plate at h = 2 (out5): Π [J] on 4² … 32², and its 128² value
THICK = [-31.8863263816, -31.9040199101, -31.9049529171, -31.9050087072]
THICK_FINER = -31.9050123703


def _fast_error(values, errors):
    d = [b - a for a, b in zip(values, values[1:], strict=False)]
    e = errors
    ratios = [(abs(d[k]) - e[k] - e[k + 1]) / (abs(d[k + 1]) + e[k + 1] + e[k + 2])
              for k in (0, 1)]
    order = math.log2(min(ratios))
    return SAFETY_OBSERVED * (abs(d[2]) + e[2] + e[3]) / (2.0**order - 1.0) + e[3]


@pytest.mark.parametrize("values, errors, finer", [
    (MOMENT, MOMENT_ERRORS, MOMENT_FINER), (PLATE, PLATE_ERRORS, PLATE_FINER),
    (THICK, None, THICK_FINER)], ids=["cantilever_moment -U", "plate nu 0.45 w", "plate h 2 Pi"])
def test_changes_faster_than_the_a_priori_order_on_two_ratios_take_the_observed_gci(
        values, errors, finer):
    bar = richardson(values, order=4.0, smooth=True, solve_errors=errors)
    assert bar.bound == "fast" and bar.value == values[-1]
    assert bar.error == pytest.approx(_fast_error(values, errors or [0.0] * 4))
    assert abs(finer - bar.value) <= bar.error
    # the a-priori sum of the last three values alone: wider, still holding
    old = richardson(values[1:], order=4.0, smooth=True,
                     solve_errors=errors and errors[1:])
    assert old.bound in ("a priori", "range") and old.error > bar.error
    assert abs(finer - old.value) <= old.error


def test_one_fast_ratio_is_not_enough():
    """The earlier ratio at order 3 (below the a-priori 4): the last fast fall may be a
    coincidence (module docstring: the bowl in silk at order 5.0), so the a-priori bar stays."""
    values = [1.0, 1.0 + 8e-3, 1.0 + 9e-3, 1.0 + 9e-3 + 1e-5]
    bar = richardson(values, order=4.0, smooth=True)
    assert bar.bound != "fast"
    three = richardson(values[1:], order=4.0, smooth=True)
    assert (bar.error, bar.bound) == (three.error, three.bound)


def test_solve_errors_that_blur_a_ratio_below_the_a_priori_order_refuse_it():
    """cantilever_moment's −U with solve errors large enough that its last ratio could be
    below 2⁴ within them: no "fast" bound."""
    blurred = [0.0, 0.0, 2e-6, 2e-6]  # (5.36e-3 − 2e-6)/(8.03e-5 + 4e-6) ≈ 64 > 2⁴
    assert richardson(MOMENT, order=4.0, smooth=True, solve_errors=blurred).bound == "fast"
    blurred = [0.0, 0.0, 2e-4, 2e-4]  # (5.36e-3 − 2e-4)/(8.03e-5 + 4e-4) ≈ 11 < 2⁴
    assert richardson(MOMENT, order=4.0, smooth=True, solve_errors=blurred).bound != "fast"


def test_the_fast_bound_needs_a_smooth_model_and_four_converged_values():
    assert richardson(MOMENT, order=4.0).bound != "fast"  # a feature: no a-priori order
    assert richardson(MOMENT[1:], order=4.0, smooth=True,
                      solve_errors=MOMENT_ERRORS[1:]).bound != "fast"
    assert richardson(MOMENT, order=4.0, smooth=True, solve_errors=MOMENT_ERRORS,
                      converged=[False, True, True, True]).bound != "fast"
    assert richardson(MOMENT, order=4.0, smooth=True, solve_errors=MOMENT_ERRORS,
                      converged=[True] * 4).bound == "fast"


def test_the_coverage_benchmark_reads_a_window_as_result_json_does():
    """`benchmarks/refinement_coverage.py`'s `bar_row` reads a window from every grid up to its
    finest (as `SplineRun.refinement` reads a run's levels), so a window whose grids are
    preceded by a coarser one shows the fast bound (the quarter plate at h = 2, out5: Π on
    8² / 16² / 32² after 4², against 64²)."""
    import importlib.util
    import sys

    path = Path(__file__).resolve().parents[1] / "benchmarks" / "refinement_coverage.py"
    spec = importlib.util.spec_from_file_location("refinement_coverage", path)
    coverage = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = coverage  # its dataclasses look their module up
    spec.loader.exec_module(coverage)
    values = [*THICK, -31.9050121555]
    spans = [[4 * 2**i] * 2 for i in range(len(values))]
    row = coverage.bar_row(values, 1, spans, "energy", [True] * len(values), smooth_energy=True)
    assert row["three"]["error_bound"] == "fast" and row["three_covers"]
