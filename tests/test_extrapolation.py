"""A refinement estimate built on a grid whose Newton solve did not converge says so (issue 35):
such a value is not the grid's discrete answer, so its changes say nothing of the order.
Measured: napkin in silk, 2 × 2 and 4 × 4 stopped at Π = 0 after one refused Newton step, the
8 × 8 … 32 × 32 levels converged (benchmarks/RESULTS.md, "Honest numbers (issue 35,
2026-12-06)")."""

from __future__ import annotations

import pytest

from taichi_ndf.minimise.extrapolation import SAFETY_OBSERVED, SAFETY_UNRELIABLE, richardson
from taichi_ndf.minimise.point_extrapolation import richardson_point
from taichi_ndf.minimise.state import LevelSummary, State
from taichi_ndf.problem.training import SolverConfig
from taichi_ndf.solve.spline_solver import SplineRun
from taichi_ndf.solve.tolerance import tolerance_met

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
    # the 32² value (benchmarks/RESULTS.md): each own bar holds it; the point's bar (± 0.035,
    # order 1.01 of |Δu|) would miss x and y (0.083, 0.080 away): components that turn are
    # not bounded by the point's bar
    corner_32 = [-0.902727, -0.912061, -1.4363]
    assert all(abs(b.value - ref) <= b.error for b, ref in zip(bars, corner_32, strict=True))


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


def test_a_component_falling_faster_than_its_point_is_bounded_by_the_points_bar():
    """u_h = (1e-3 h³, 2e-4 h³, 1e-3 h^4.5) on h = 1, 1/2, 1/4 (limit 0): the point falls at
    order ≈ 3.5, its near-zero z alone at 4.5, above the trusted 4.05: z's own bar is 3 × its
    range (3e-3, 1 500 × its distance); |u_z − u_z∞| ≤ |u − u∞|, so the point's bar bounds
    it: the finest value, ± the point's bar, which holds the limit. x and y keep their own."""
    values = [[1e-3 * h**3, 2e-4 * h**3, 1e-3 * h**4.5] for h in (1.0, 0.5, 0.25)]
    alone = [richardson([u[c] for u in values], order=4.0) for c in range(3)]
    assert alone[2].bound == "range" and alone[2].error > 1000 * values[2][2]
    bars = richardson_point(values, order=4.0)
    assert bars[:2] == alone[:2]
    z = bars[2]
    assert z.basis == "unreliable" and z.bound == "point" and z.value == values[2][2]
    assert values[2][2] <= z.error < alone[2].error / 100
    assert "within the point's bar" in z.describe() and z.to_dict()["error_bound"] == "point"


# The pinched hemisphere's four probes u [m] relative to its gauge (the three rotations about
# its pin) on 76 × 20, 152 × 40, 304 × 80 graded (wip-adapt9's levels, benchmarks/RESULTS.md
# "Adaptive refinement: the tolerance and free rigid motions"): the points fall at order
# 3.15–3.19, the z of out_0 and in_90 at 4.06–4.07 (3 × range: 2.7e-3 of |u|); and its Π [J].
HEMISPHERE = {
    "out_0": [[9.31156659429767e-05, 1.9013269718432073e-07, 4.5782028119402324e-05],
              [9.33637379744039e-05, 1.753487987627261e-07, 4.587114442662934e-05],
              [9.339171641608688e-05, 1.6989331199701436e-07, 4.587646113892576e-05]],
    "in_90": [[-1.9015644964270508e-07, -9.311630969409128e-05, -4.5781371151791315e-05],
              [-1.7536555314632063e-07, -9.336440681768118e-05, -4.58705025164561e-05],
              [-1.699140312081139e-07, -9.339239708565386e-05, -4.587583779028665e-05]],
    "out_180": [[-9.340806090741955e-05, 6.950936781672666e-08, 4.5256780040532006e-05],
                [-9.361178923145995e-05, 6.797247897328271e-08, 4.5403594078729345e-05],
                [-9.363123854253491e-05, 6.600290310266032e-08, 4.542408425169568e-05]],
    "in_270": [[-6.937527852619976e-08, 9.34095265140259e-05, -4.525590570802621e-05],
               [-6.785744664118343e-08, 9.36132279738996e-05, -4.5402768012339275e-05],
               [-6.589548382478086e-08, 9.363266274256573e-05, -4.54232905712971e-05]]}
HEMISPHERE_ENERGY = [-0.3730495631321597, -0.3739531589084145, -0.3740480136877291]


def test_the_pinched_hemisphere_meets_the_tolerance_on_its_measured_levels():
    """The stopping test at 1e-3 on the hemisphere's gauge-relative levels: before, 2.7e-3 (the
    z range bars); the z components now within their points' bars (4.3e-5 of |u|), the
    largest bar a non-monotone near-zero component's own range (1e-4)."""
    document = {"spans": [[76, 20], [152, 40], [304, 80]],
                "energy": richardson(HEMISPHERE_ENERGY, order=4.0).to_dict(), "probes": {}}
    for name, values in HEMISPHERE.items():
        document["probes"][name] = [e.to_dict() for e in richardson_point(values, order=4.0)]
    for name in ("out_0", "in_90"):
        assert document["probes"][name][2]["error_bound"] == "point"
    met, words = tolerance_met(document, 1e-3)
    assert met, words
    assert words == "largest estimated relative error 0.000101 (probe out_180:1)"


def test_a_point_whose_order_is_unreliable_keeps_its_components_bit_for_bit():
    """Where the point's order is unreliable (fly_bottom: order 0.37) or a level used did
    not converge, nothing is bounded by the point's bar: each component exactly as before."""
    bars = richardson_point(FLY_BOTTOM, order=4.0)
    assert bars[0] == richardson([u[0] for u in FLY_BOTTOM], order=4.0)
    for c in (1, 2):
        v = [u[c] for u in FLY_BOTTOM]
        assert bars[c].value == v[2] and bars[c].bound == "range"
        assert bars[c].error == SAFETY_UNRELIABLE * (max(v) - min(v))
    # a point at order 3 with z falling at 4.5, one level unconverged: own bars, no narrowing
    values = [[1e-3 * h**3, 2e-4 * h**3, 1e-3 * h**4.5] for h in (1.0, 0.5, 0.25)]
    flags = [True, False, True]
    bars = richardson_point(values, order=4.0, converged=flags)
    assert bars == [richardson([u[c] for u in values], order=4.0, converged=flags)
                    for c in range(3)]
    assert all(b.bound == "range" and "not converged" in b.reason for b in bars)
