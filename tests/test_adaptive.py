"""Adaptive refinement (issue 33): a tabulated knot density, the indicator's spans, the
equidistributed next grid, the projection warm start, the loop's stopping rule and its
refusals, and one small run end to end through ndf-sim (result.json's estimate)."""

import json
from pathlib import Path

import pytest
import torch

from taichi_ndf.field import SplineConfig, SplineField
from taichi_ndf.field.grading import GradedMap, Grading, _density_kernel
from taichi_ndf.solve.adaptive import AdaptiveConfig, density_order, project, tolerance_met
from taichi_ndf.solve.error_indicator import equidistributed, knot_density, span_edges, span_index

F64 = torch.float64
ROOT = Path(__file__).resolve().parents[1]


def test_a_tabulated_density_gives_the_map_of_the_same_density():
    """The features law sampled on 400 points and tabulated: the same map to 1e-4."""
    features = Grading((0.2,), 0.05, 4.0)
    at = torch.linspace(0.0, 1.0, 400, dtype=F64)
    rho = 1 + 4.0 * _density_kernel(at, [0.2], None, 0.05)
    table = Grading((), 1.0, 0.0, density=tuple(rho.tolist()), at=tuple(at.tolist()))
    x = torch.linspace(0.0, 1.0, 101, dtype=F64)
    expected = GradedMap(features, 0.0, 1.0).jets(x)[0]
    torch.testing.assert_close(GradedMap(table, 0.0, 1.0).jets(x)[0], expected, rtol=0,
                               atol=1e-4)


@pytest.mark.parametrize("even", [("min",), ("max",), ("min", "max")])
def test_a_tabulated_density_is_even_across_a_mirrored_end(even):
    """h is odd about a mirrored end (h″ = 0 there), also where the table is not flat."""
    table = Grading((), 1.0, 0.0, density=(5.0, 2.0, 1.0, 3.0), at=(0.0, 0.3, 0.6, 1.0))
    graded = GradedMap(table, 0.0, 1.0, even=even)
    ddh = graded.jets(torch.linspace(0, 1, 201, dtype=F64))[2]
    for end in even:
        at = torch.tensor([0.0 if end == "min" else 1.0], dtype=F64)
        assert abs(float(graded.jets(at)[2])) < 1e-6 * float(ddh.abs().max())
    plain = GradedMap(table, 0.0, 1.0)  # not mirrored: h″ ≠ 0 at the ends
    assert abs(float(plain.jets(torch.tensor([0.0], dtype=F64))[2])) > 1e-3


def test_a_tabulated_density_is_checked():
    with pytest.raises(ValueError, match="density must be positive"):
        Grading((), 1.0, 0.0, density=(1.0, -1.0), at=(0.1, 0.2))
    with pytest.raises(ValueError, match="density must be positive"):
        Grading((), 1.0, 0.0, density=(1.0, 2.0), at=(0.3, 0.2))
    with pytest.raises(ValueError, match="features"):
        Grading((), 1.0, 0.0)


def test_the_next_grid_is_finer_where_the_indicator_is_large():
    config = SplineConfig(spans=(8, 4))
    indicator = torch.ones(8, 4, dtype=F64)
    indicator[0, :] = 1e4  # the first span of direction 1
    nxt = equidistributed(config, indicator, growth=2, order=4.0)
    assert nxt.spans == (16, 8)
    e1, e2 = span_edges(nxt)
    widths = e1[1:] - e1[:-1]
    assert float(widths[0]) < 0.6 * float(widths[-1])  # graded towards ξ¹ = 0
    assert float(e1[0]) == 0.0 and float(e1[-1]) == 1.0
    w2 = e2[1:] - e2[:-1]
    torch.testing.assert_close(w2, torch.full_like(w2, 1 / 8), rtol=0, atol=1e-6)
    # a stronger indicator at the same span grades more
    indicator[0, :] = 1e8
    stronger = span_edges(equidistributed(config, indicator, growth=2, order=4.0))[0]
    assert float(stronger[1] - stronger[0]) < float(widths[0])


def test_no_span_of_the_next_grid_is_wider_than_the_one_it_lies_in():
    """Where the indicator is tiny the next grid's spans are at most this grid's."""
    table = Grading((), 1.0, 0.0, density=(6.0, 1.0), at=(0.0, 1.0))
    config = SplineConfig(spans=(6, 2), grading=(table, None))
    indicator = torch.full((6, 2), 1e-12, dtype=F64)
    indicator[-1] = 1e6  # all the error in the last (widest) span
    old = span_edges(config)[0]
    new = span_edges(equidistributed(config, indicator, growth=2, order=4.0))[0]
    for a, b in zip(new[:-1], new[1:], strict=True):
        mid = (a + b) / 2
        i = int(torch.searchsorted(old, mid)) - 1
        assert float(b - a) <= float(old[i + 1] - old[i]) * 1.05


def test_a_zero_indicator_keeps_the_direction_uniform():
    config = SplineConfig(spans=(4, 4))
    nxt = equidistributed(config, torch.zeros(4, 4, dtype=F64), growth=2, order=4.0)
    assert nxt.grading == (None, None) and nxt.spans == (8, 8)
    assert knot_density(torch.zeros(3, dtype=F64), torch.linspace(0, 1, 4), 4.0) is None


def test_span_index_on_a_graded_grid():
    table = Grading((), 1.0, 0.0, density=(8.0, 1.0), at=(0.0, 1.0))
    config = SplineConfig(spans=(5, 3), grading=(table, None))
    e1, e2 = span_edges(config)
    centres = torch.stack(torch.meshgrid((e1[1:] + e1[:-1]) / 2, (e2[1:] + e2[:-1]) / 2,
                                         indexing="ij"), -1).reshape(-1, 2)
    i1, i2 = span_index(config, centres)
    assert i1.tolist() == [i for i in range(5) for _ in range(3)]
    assert i2.tolist() == [j for _ in range(5) for j in range(3)]


def test_projection_onto_a_refinement_is_exact():
    """Projecting onto the dyadic refinement reproduces the field (its exact prolongation)."""
    config = SplineConfig(spans=(3, 4), grading=(Grading((0.3,), 0.2, 2.0), None))
    field = SplineField(config, dtype=F64)
    g = torch.Generator().manual_seed(0)
    field.coefficients.copy_(torch.randn(field.coefficients.shape, generator=g, dtype=F64))
    from taichi_ndf.problem.quadrature import span_points

    xi, w = span_points(config.refined())
    fine = SplineField(config.refined(), dtype=F64)
    fine.coefficients.copy_(project(field, config.refined(), xi, w))
    points = torch.rand(500, 2, generator=g, dtype=F64)
    scale = float(field.evaluate(points).abs().max())
    torch.testing.assert_close(fine.evaluate(points), field.evaluate(points), rtol=0,
                               atol=1e-8 * scale)


def test_stopping_rule_and_order():
    def doc(energy, error, probe_error, spans=3):
        probe = {"extrapolated": 1.0, "estimated_error": probe_error}
        zero = {"extrapolated": 0.0, "estimated_error": 0.0}
        return {"spans": [[1, 1]] * spans,
                "energy": {"extrapolated": energy, "estimated_error": error},
                "probes": {"tip": [probe, zero, zero]}}
    assert tolerance_met(doc(-2.0, 1e-3, 5e-4), 1e-3)[0]
    met, worst = tolerance_met(doc(-2.0, 1e-3, 2e-3), 1e-3)
    assert not met and "probe tip:0" in worst
    assert not tolerance_met(doc(-2.0, 3e-3, 0.0), 1e-3)[0]
    assert not tolerance_met(doc(-2.0, 0.0, 0.0, spans=2), 1e-3)[0]  # no observed order
    # a level of the last three whose Newton solve did not converge: never met, however small
    # the bars (0: Newton stopped at the same Π on every grid); one outside the window is fine
    met, why = tolerance_met(doc(-2.0, 0.0, 0.0, spans=4), 1e-3, [True, True, False, True])
    assert not met and why.startswith("grid level 2 of 4 not converged")
    assert tolerance_met(doc(-2.0, 0.0, 0.0, spans=4), 1e-3, [False, True, True, True])[0]
    # the equidistribution's order: the trusted observed one, else the expected
    assert density_order([1.0, 0.5, 0.25], 4.0) == pytest.approx(1.0)
    assert density_order([1.0, 0.5], 4.0) == 4.0
    assert density_order([1.0, 0.5, 0.6], 4.0) == 4.0  # changes not falling


@pytest.mark.parametrize("value", [0.0, -1e-3, 0.5, float("nan"), True])
def test_a_bad_tolerance_is_refused(value):
    with pytest.raises(ValueError, match="--tolerance"):
        AdaptiveConfig(value)
    with pytest.raises(ValueError, match="--max-unknowns"):
        AdaptiveConfig(1e-3, 0)


def run_sim(*args):
    from taichi_ndf.cli import sim

    return sim.main([str(a) for a in args] + ["--arch", "cpu", "--precision", "f64"])


@pytest.mark.parametrize(("extra", "message"), [
    (["--tolerance", "0"], "--tolerance must be a relative error"),
    (["--tolerance", "1e-3", "--max-unknowns", "-4"], "--max-unknowns must be"),
    (["--tolerance", "1e-3", "--refine", "3"], "drop --refine"),
    (["--tolerance", "1e-3", "--field", "siren"], "needs a spline field"),
])
def test_bad_requests_exit_2_in_one_line(tmp_path, capsys, extra, message):
    field = [] if "--field" in extra else ["--field", "spline"]
    status = run_sim("scenes/napkin.toml", "--out", tmp_path / "run", *field, *extra)
    err = capsys.readouterr().err.strip()
    assert status == 2 and message in err and len(err.splitlines()) == 1
    assert not (tmp_path / "run").exists()


def test_without_an_indicator_the_grids_are_dyadic(tmp_path):
    """--indicator none: 3² → 6² → 12² uniform; the tolerance met, or the budget."""
    out = tmp_path / "run"
    assert run_sim("scenes/napkin.toml", "--out", out, "--field", "spline", "--set",
                   "field.spans=[3,3]", "--tolerance", "1e-3", "--max-unknowns", "700",
                   "--indicator", "none", "--no-pictures") == 0
    result = json.loads((out / "result.json").read_text())
    assert result["refinement"]["spans"] == [[3, 3], [6, 6], [12, 12]]
    assert result["refinement"]["adaptive"]["indicator"] == "none"
    assert result["resolved"]["field"]["finest_grading"] == [None, None]


def test_by_default_every_grid_is_graded_towards_the_pin_by_its_own_spans(tmp_path):
    """--tolerance alone on the napkin (a pin at a corner): 3² → 6² → 12², each grid graded
    towards the pin with the core one span of that grid (not of the first: the graded core
    shrinks with the span), half its spans graded; the finest grid is the features grading
    of 12² spans."""
    from taichi_ndf.problem.spline_grid import graded_config
    from taichi_ndf.scene.reader import load_scene

    out = tmp_path / "run"
    assert run_sim("scenes/napkin.toml", "--out", out, "--field", "spline", "--set",
                   "field.spans=[3,3]", "--tolerance", "1e-3", "--max-unknowns", "700",
                   "--no-pictures") == 0
    result = json.loads((out / "result.json").read_text())
    refinement = result["refinement"]
    assert refinement["spans"] == [[3, 3], [6, 6], [12, 12]]
    adaptive = refinement["adaptive"]
    assert adaptive["indicator"] == "features" and adaptive["grids"] == "features"
    assert [lv["grid"] for lv in adaptive["levels"]] == ["first", "features", "features"]
    scene = load_scene(ROOT / "scenes" / "napkin.toml", field="spline",
                       overrides={"field.spans": [12, 12]})
    model = scene.model
    expected = json.loads(json.dumps(graded_config(
        scene.field.config, model.boundary, model.loads, model.surface.domain
    ).to_dict()["grading"]))
    finest = result["resolved"]["field"]["finest_grading"]
    assert finest == expected
    (lo, hi) = scene.field.config.domain[0]
    assert finest[0]["core"] == pytest.approx((hi - lo) / 12)
    energy = refinement["energy"]
    assert energy["estimated_error"] >= abs(energy["values"][-1] - energy["values"][-2])


def test_without_a_singular_feature_the_default_is_dyadic_to_the_bit():
    """The square plate (edge supports, pressure: no pin, point load or interior line): the
    default grid rule ("features") solves the same grids as "none" and gives the same Π and
    probes on every level, bit for bit."""
    from taichi_ndf.scene.reader import load_scene
    from taichi_ndf.solve.adaptive import solve_adaptive

    scene = load_scene(ROOT / "validation" / "scenes" / "square_plate.toml", field="spline",
                       overrides={"field.spans": [2, 2]})
    runs = [solve_adaptive(scene.model, scene.field, scene.solver,
                           AdaptiveConfig(1e-3, max_unknowns=400, indicator=rule))
            for rule in ("features", "none")]
    assert runs[0].adaptive["grids"] == runs[1].adaptive["grids"] == "dyadic"
    assert [lv.spans for lv in runs[0].levels] == [lv.spans for lv in runs[1].levels]
    assert len(runs[0].levels) >= 3
    for a, b in zip(runs[0].levels, runs[1].levels, strict=True):
        assert a.energy == b.energy and a.probes == b.probes
    assert torch.equal(runs[0].field.coefficients, runs[1].field.coefficients)


def test_a_small_adaptive_run_end_to_end(tmp_path):
    """napkin 3² → 6² → 12² (equidistributed, graded) within a budget of 700 unknowns: the
    budget stops it, the estimate over three grids is in result.json and holds the three
    values' spread."""
    out = tmp_path / "run"
    status = run_sim("scenes/napkin.toml", "--out", out, "--field", "spline", "--set",
                     "field.spans=[3,3]", "--tolerance", "1e-3", "--max-unknowns", "700",
                     "--indicator", "density", "--no-pictures")
    assert status == 0
    result = json.loads((out / "result.json").read_text())
    refinement = result["refinement"]
    adaptive = refinement["adaptive"]
    assert [lv["grid"] for lv in adaptive["levels"]] == ["first", "dyadic", "equidistributed"]
    assert refinement["spans"] == [[3, 3], [6, 6], [12, 12]]
    assert adaptive["outcome"] == "budget" and adaptive["met"] is False
    grading = result["resolved"]["field"]["finest_grading"]
    assert any(g is not None and g["density"] for g in grading)
    energy = refinement["energy"]
    values = energy["values"]
    assert energy["extrapolated"] == pytest.approx(result["energy"], abs=energy["estimated_error"])
    assert energy["estimated_error"] >= abs(values[-1] - values[-2])


def test_an_unconverged_window_never_meets_the_tolerance(tmp_path):
    """Newton cut to one iteration per load step and grid on an almost linear plate (square
    plate at pressure 1e-3, 4² → 8² → 16²): the three grids' values agree within the 10 %
    asked (bars 5 % of Π and 8 % of the centre's u), but no grid converged, so that bar is no
    discretisation error: not met, the loop refines on to the budget, and result.json says
    why and which levels."""
    out = tmp_path / "run"
    assert run_sim("validation/scenes/square_plate.toml", "--out", out, "--field", "spline",
                   "--set", "field.spans=[4,4]", "--set", "training.newton_max_iterations=1",
                   "--set", "loads.pressure=0.001", "--tolerance", "0.1", "--max-unknowns",
                   "1100", "--no-pictures") == 0
    refinement = json.loads((out / "result.json").read_text())["refinement"]
    adaptive = refinement["adaptive"]
    assert refinement["spans"] == [[4, 4], [8, 8], [16, 16]]
    energy = refinement["energy"]
    assert energy["estimated_error"] <= 0.1 * abs(energy["extrapolated"])  # the bar is small
    assert energy["order_basis"] == "unreliable"
    assert adaptive["met"] is False and adaptive["outcome"] == "budget"
    assert adaptive["unconverged_levels"] == [0, 1, 2]
    assert "grid levels 0, 1, 2 of 3 not converged" in adaptive["worst"]
    assert "over the budget" in adaptive["stopped"] and "not converged" in adaptive["stopped"]
    assert len(adaptive["stopped"].splitlines()) == 1


class _Seen:
    """The callbacks an adaptive solve calls, with the number of finished grid levels."""

    def __init__(self):
        self.calls = []

    def on_start(self, run):
        self.calls.append(("start", len(run.levels)))

    def on_load_step(self, run, load_factor):
        self.calls.append(("load_step", len(run.levels)))

    def on_level(self, run):
        self.calls.append(("level", len(run.levels)))

    def on_end(self, run):
        self.calls.append(("end", len(run.levels)))


def test_the_adaptive_grids_are_a_pass_of_the_continuation_loop():
    """napkin 3² → 6² → 12² (budget 700): the adaptive grid (level 2) is solved by
    `solve_over` after `solve_spline`'s two levels, so the callbacks see its load steps, its
    on_level and on_end after the last level (before: on_end after level 1, then the adaptive
    grid's on_level only)."""
    from taichi_ndf.discretise import of_scene
    from taichi_ndf.discretise.adaptive import adaptive
    from taichi_ndf.scene.reader import load_scene

    scene = load_scene(ROOT / "scenes" / "napkin.toml", field="spline",
                       overrides={"field.spans": [3, 3]})
    run = adaptive(of_scene(scene), AdaptiveConfig(1e-3, max_unknowns=700, indicator="none"))
    run.start(scene.solver, seed=0)
    seen = _Seen()
    solution = run.solve(scene.solver, callbacks=[seen])
    assert solution.settings["spans"] == [[3, 3], [6, 6], [12, 12]]
    steps = len(scene.solver.load_steps)
    assert seen.calls == [("start", 0), *[("load_step", 0)] * steps, ("level", 1),
                          *[("load_step", 1)] * steps, ("level", 2), ("end", 2),
                          ("start", 2), *[("load_step", 2)] * steps, ("level", 3), ("end", 3)]


def test_graded_levels_are_a_pass_of_the_continuation_loop_from_level_1():
    """The default on the napkin (graded towards its pin, 3² → 6² → 12²): `solve_spline`
    solves the first grid only; levels 1 and 2 (regraded, not nested) are the adaptive pass,
    each load step projected from the level before; on_load_step once per load step and
    level."""
    from taichi_ndf.discretise import of_scene
    from taichi_ndf.discretise.adaptive import adaptive
    from taichi_ndf.scene.reader import load_scene

    scene = load_scene(ROOT / "scenes" / "napkin.toml", field="spline",
                       overrides={"field.spans": [3, 3]})
    run = adaptive(of_scene(scene), AdaptiveConfig(1e-3, max_unknowns=700))
    run.start(scene.solver, seed=0)
    seen, stepped = _Seen(), []
    solution = run.solve(scene.solver, callbacks=[seen],
                         on_load_step=lambda t, field: stepped.append(field.config.spans))
    assert solution.settings["spans"] == [[3, 3], [6, 6], [12, 12]]
    steps = len(scene.solver.load_steps)
    assert seen.calls == [("start", 0), *[("load_step", 0)] * steps, ("level", 1), ("end", 1),
                          ("start", 1), *[("load_step", 1)] * steps, ("level", 2),
                          *[("load_step", 2)] * steps, ("level", 3), ("end", 3)]
    assert stepped == [(3, 3)] * steps + [(6, 6)] * steps + [(12, 12)] * steps
