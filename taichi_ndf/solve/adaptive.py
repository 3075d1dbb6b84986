"""Adaptive refinement of a spline solve to a requested relative error (`--tolerance`,
issue 33): refine → solve (warm start) → estimate, until the estimated error of Π and of every
probe is at most the tolerance or the next grid would exceed a budget of unknowns.

A tensor-product spline cannot refine one element, so the grids are r/h-adaptive: each grid
has GROWTH (2) times the spans per direction of the one before, its knots placed by
`AdaptiveConfig.indicator`:
- "features" (the default): every grid graded towards the model's known singular features
  (pins but gauges, `boundary.gauges`; point loads, interior lines, segment and line-load
  ends: `spline_grid.singular_features`) by the features grading of its OWN spans
  (`spline_grid.graded_config`: core one span of that grid, half the spans graded), so the
  graded core shrinks with the span as on a single graded grid; where the model has no such
  feature, the dyadic refinement of the plan's grid ("none"), the same solves to the bit;
- "none": the dyadic refinement (the plan's grading kept; the projection is then exact);
- an error indicator (`taichi_ndf.solve.error_indicator`: the change of the strain energy
  density between the last two solves, per knot span), equidistributed (measured worse than
  uniform on 4 of 5 validation cases, benchmarks/RESULTS.md).

    level 0: the plan's first grid (with "features" graded by its spans), by load
                 continuation (`solve_spline`);
    level 1: its dyadic refinement (the same grading), each load step from level 0; where
                 the grids are graded by "features", regraded and solved as level k ≥ 2;
    level k ≥ 2: spans × 2, knots by the rule above (an indicator: of levels k−2 → k−1 at the
                 last load factor); each load step started from level k−1's solution at that
                 load factor projected onto the new grid (weighted least squares of the field
                 at the new grid's Gauss points; exact where the grids are nested);
    after each level from 2 on: the guarded three-grid rule (`minimise.refinement.richardson`,
                 the expected order 2(p − 1)) on Π and every probe component over the last
                 three levels; stop where every bar ≤ tolerance × |Π| (Π) and ≤ tolerance ×
                 |u| of the probe (a probe's components; read relative to the model's
                 gauge motions, free rigid motions nothing fixes: `solve.tolerance`), or
                 where the next grid's unknowns would exceed `max_unknowns`. An estimate
                 over a window with a level whose Newton solve did not converge never meets
                 the tolerance (its bar is no discretisation error, however small:
                 `tolerance_met`); the loop refines on.

The spans double per level in η, so h halves as the rule assumes; the knots move between
levels, so the observed order is that of the adaptive sequence (the rule sees the sequence's
own convergence: where it is erratic the order is "unreliable" and the bar widens to 3 × the
range of the last three values). The estimate is of the last load step. Levels 0 and 1 are
`solve_spline`'s; the adaptive levels from 2 on are one more pass of the continuation loop
(`minimise.continuation.solve_over`, its `next_level`: the stopping rule and the next grid),
so the callbacks see on_start, on_load_step, on_level and on_end there too. Refused: obstacles
(contact check points and κ are per grid and load path), a resumed run.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
import torch

from taichi_ndf.boundary.gauge_motions import probe_gauge
from taichi_ndf.boundary.gauges import gauge_points
from taichi_ndf.field import SplineConfig, SplineField
from taichi_ndf.minimise.callbacks import call
from taichi_ndf.minimise.continuation import Hook, Stages, Step, solve_over
from taichi_ndf.minimise.linear_solve import LinearSolverConfig
from taichi_ndf.minimise.linearisation import GridLinearisation
from taichi_ndf.minimise.refinement import GridLevels, LevelSolution, extrapolate_changes
from taichi_ndf.minimise.state import LevelSummary, NewtonRecord, load_step_records
from taichi_ndf.objective import Objective
from taichi_ndf.objective.seam import with_seam_points
from taichi_ndf.problem.model import ShellModel
from taichi_ndf.problem.spline_grid import SplinePlan, graded_config, singular_features
from taichi_ndf.problem.training import SolverConfig
from taichi_ndf.solve.error_indicator import INDICATORS, equidistributed, span_indicator
from taichi_ndf.solve.spline_solver import SplineRun, newton_config, solve_spline
from taichi_ndf.solve.tolerance import gauge_relative, tolerance_met

log = logging.getLogger(__name__)

GRID_RULES = ("features", "none", *INDICATORS)  # AdaptiveConfig.indicator
GROWTH = 2  # spans per direction, next grid / this one (h halves, as the three-grid rule needs)
CONTACT_REFUSED = ("--tolerance: obstacles are not supported on the adaptive path (the contact "
                   "check points and stiffness are per grid and load path)")


@dataclass(frozen=True)
class AdaptiveConfig:
    """tolerance: the relative error wanted of Π and of every probe, in (0, 0.5);
    max_unknowns: the budget, the most unknowns (3 per read coefficient) of a grid;
    indicator: how the next grid's knots are placed (module docstring): "features" (the
    default: every grid graded towards the model's known singular features by its own spans,
    dyadic where it has none), "none" (the dyadic refinement of this grid, its grading kept)
    or an error indicator of `error_indicator.INDICATORS`, equidistributed (measured,
    benchmarks/RESULTS.md: worse than uniform grids on the square plate, the roof and both
    cantilevers, better only on the napkin); order: the convergence
    order q of the equidistribution (`error_indicator.knot_density`), None: `density_order`."""

    tolerance: float
    max_unknowns: int = 200_000
    indicator: str = "features"
    order: float | None = None

    def __post_init__(self):
        t = self.tolerance
        if isinstance(t, bool) or not isinstance(t, (int, float)) or not (
                math.isfinite(t) and 0 < t < 0.5):
            raise ValueError(f"--tolerance must be a relative error in (0, 0.5), got {t!r}")
        m = self.max_unknowns
        if isinstance(m, bool) or not isinstance(m, int) or m < 1:
            raise ValueError(f"--max-unknowns must be a positive integer, got {m!r}")
        if self.indicator not in GRID_RULES:
            raise ValueError(f"--indicator must be one of {', '.join(GRID_RULES)}, got "
                             f"{self.indicator!r}")


def features_grid(config: SplineConfig, model: ShellModel, gauges=None) -> SplineConfig:
    """`config`'s spans graded towards the model's known singular features by the features
    grading of those spans (`spline_grid.graded_config`: core one span of this grid, whatever
    grading `config` had); a direction without features uniform. gauges: the model's gauge
    points (`gauge_points`, computed here where None)."""
    gauges = gauge_points(model) if gauges is None else gauges
    return graded_config(config, model.boundary, model.loads, model.surface.domain,
                         gauges=gauges)


def unknowns(config: SplineConfig) -> int:
    """3 × the coefficients that are read (a mirrored end's aliases are held)."""
    return 3 * int(config.alias_map().unique().numel())


def project(field: SplineField, config: SplineConfig, xi: torch.Tensor,
            weight: torch.Tensor) -> torch.Tensor:
    """Coefficients (n, 3) of the field on grid `config` nearest to `field` in the weighted
    least-squares sense at the points ξ (N, 2) with weights w (N,) (the new grid's Gauss
    points: every basis function is seen); a coefficient no point reads stays 0."""
    target = SplineField(config, dtype=field.coefficients.dtype)
    index, basis = target.local_basis(xi)
    values = field.evaluate(xi).double().cpu().numpy()
    n, k = index.shape
    rows = np.repeat(np.arange(n), k)
    b = sp.csr_matrix((basis[:, 0].double().cpu().numpy().ravel(),
                       (rows, index.cpu().numpy().ravel())),
                      shape=(n, target.coefficients.shape[0]))
    w = sp.diags(weight.double().cpu().numpy())
    normal = (b.T @ w @ b).tocsc()
    ridge = 1e-14 * float(normal.diagonal().max())
    normal = normal + ridge * sp.identity(normal.shape[0], format="csc")
    solve = spla.factorized(normal)
    rhs = b.T @ (w @ values)
    c = np.stack([solve(rhs[:, j]) for j in range(values.shape[1])], axis=1)
    return torch.from_numpy(c).to(field.coefficients.dtype)


@dataclass
class AdaptiveRun(SplineRun):
    """A `SplineRun` whose levels 2, 3, … are the adaptive grids (module docstring);
    `adaptive`: the request, the outcome and each level's grid."""

    adaptive: dict = dataclasses.field(default_factory=dict)

    def refinement(self, degree: int) -> dict | None:
        """As `SplineRun.refinement` over the adaptive sequence, with the request and its
        outcome under "adaptive"."""
        document = super().refinement(degree)
        if document is not None:
            document["adaptive"] = self.adaptive
        return document


def density_order(energies: list[float], expected: float) -> float:
    """The order q the next grid is equidistributed with (`error_indicator.knot_density`):
    the observed order of Π over the last three grids where the guarded rule trusts it
    (`extrapolate_changes`: basis "observed"), else the expected 2(p − 1). Near a
    singularity the error falls at the singular part's rate, below 2(p − 1), and that is
    the local order of the spans the indicator marks."""
    if len(energies) >= 3:
        last = energies[-3:]
        estimate = extrapolate_changes(np.diff(last).tolist(), expected,
                                       scale=max(abs(v) for v in last))
        if estimate.basis == "observed":
            return float(estimate.order)
    return expected


def solve_on(model: ShellModel, start: SplineField, config: SplineConfig, plan: SplinePlan,
             solver: SolverConfig, objective: Objective, *, level: int = 0, step: int = -1,
             coarse_energy: float | None = None, on_iteration=None, smooth: bool = False,
             gauge_moved: tuple[str, ...] = ()
             ) -> tuple[SplineField, LevelSolution]:
    """One grid `config` solved at the load step `step` (index into the load steps; −1: the
    last) from `start`'s solution there projected onto it (`project`, at its Gauss points):
    the field (its coefficients: the start) and the solution. coarse_energy: the previous
    grid's Π at that load factor (Newton's discretisation stopping test). smooth: the model
    has no known singular feature (`SplineRun.smooth`): the probe stop at the last load
    factor (`GridLevels`), not reading `gauge_moved` (`SplineRun.gauge_moved`)."""
    dtype = start.coefficients.dtype
    field = SplineField(config, dtype=dtype)
    points = GridLinearisation.quadrature(model.surface, config, None,
                                          points=plan.quadrature_points, dtype=torch.float64)
    field.coefficients.copy_(project(start, config, points.xi, points.weight))
    grids = GridLevels(
        field, model.boundary,
        lambda f: with_seam_points(GridLinearisation.quadrature(
            model.surface, f.config, model.loads, points=plan.quadrature_points, dtype=dtype),
            model.terms),
        objective, levels=level + 1, config=newton_config(solver, dtype),
        probes={p.name: p.xi for p in model.probes},
        length=math.sqrt(model.surface.domain.rectangle_area),
        linear=LinearSolverConfig(kind=solver.linear_solver), on_iteration=on_iteration,
        first_level=level, first_coarse=coarse_energy,
        probe_stop_at=solver.load_steps[-1] if smooth else None, gauge_moved=gauge_moved)
    grids.enter_level(level)
    index = step % len(solver.load_steps)
    at = Step(level, index, solver.load_steps[index])
    return field, grids.solve(at, grids.start(at, None, None))


def solve_adaptive(model: ShellModel, plan: SplinePlan, config: SolverConfig,
                   adaptive: AdaptiveConfig, *, objective: Objective | None = None,
                   callbacks=(), on_level: Callable[[SplineRun], None] | None = None,
                   on_load_step: Callable[[float, SplineField], None] | None = None
                   ) -> AdaptiveRun:
    """The adaptive loop (module docstring) from `plan.config` (the plan's levels ignored).
    callbacks and on_level as `solve_spline`'s (on_level after every level, adaptive ones
    too); on_load_step(load factor, field): after each load step of each level (those of
    `solve_spline`'s levels after the level's on_level)."""
    if model.contact is not None:
        raise ValueError(CONTACT_REFUSED)
    objective = objective or Objective.of_model(model)
    gauges = gauge_points(model)  # once per solve: every graded grid and the probes' gauge
    graded = adaptive.indicator == "features" and any(singular_features(
        model.boundary, model.loads, model.surface.domain, gauges))
    if graded:
        plan = dataclasses.replace(plan, config=features_grid(plan.config, model, gauges))
    elif adaptive.indicator == "features":
        log.info("--tolerance: no pin, point load or interior line to grade towards; the "
                 "grids are dyadic refinements")
    first_levels = 1 if graded else 2  # solved by `solve_spline` (load continuation)
    degree, order = plan.config.degree, 2.0 * (plan.config.degree - 1)
    if unknowns(plan.config.refined()) > adaptive.max_unknowns:
        raise ValueError(f"--max-unknowns {adaptive.max_unknowns}: the first two grids need "
                         f"{unknowns(plan.config.refined())} unknowns")
    snapshots: list[SplineField] = []
    record: dict = {"tolerance": adaptive.tolerance, "max_unknowns": adaptive.max_unknowns,
                    "growth": GROWTH, "indicator": adaptive.indicator,
                    "grids": "features" if graded else (
                        "dyadic" if adaptive.indicator in ("none", "features")
                        else "equidistributed"), "levels": []}
    gauge = probe_gauge(model, gauges)
    if gauge is not None:
        record["gauge"] = {"motions": list(gauge.motions), "components": list(
            gauge.components()), "line": gauge.line()}
        log.warning("--tolerance: %s", gauge.line())

    def level_done(run: SplineRun) -> None:
        field = SplineField(run.field.config, dtype=run.field.coefficients.dtype)
        field.coefficients.copy_(run.field.coefficients)
        snapshots.append(field)
        last = run.levels[-1]
        record["levels"].append({"spans": list(last.spans), "unknowns": unknowns(
            run.field.config), "energy": last.energy, "iterations": last.iterations,
            "seconds": last.seconds, "converged": last.converged,
            "grid": "first" if len(snapshots) == 1 else (
                "dyadic" if len(snapshots) == 2 and not graded else record["grids"])})
        if on_level is not None:
            on_level(run)
        if on_load_step is not None and len(snapshots) <= first_levels:
            for t, coefficients in run.steps:
                at = SplineField(run.field.config, dtype=run.field.coefficients.dtype)
                at.coefficients.copy_(coefficients)
                on_load_step(t, at)

    dyadic = solve_spline(model, dataclasses.replace(plan, levels=first_levels),
                          dataclasses.replace(config, max_levels=0), objective=objective,
                          callbacks=callbacks, on_level=level_done)
    run = AdaptiveRun(dyadic.state, config, dyadic.wall_time, dyadic.steps, dyadic.load_steps,
                      smooth=dyadic.smooth, gauge_moved=dyadic.gauge_moved, adaptive=record)
    t = config.load_steps[-1]
    dtype = run.field.coefficients.dtype
    length = math.sqrt(model.surface.domain.rectangle_area)
    started = time.perf_counter() - run.wall_time

    def samples_for(field):
        return with_seam_points(GridLinearisation.quadrature(
            model.surface, field.config, model.loads, points=plan.quadrature_points,
            dtype=dtype), model.terms)

    def iterated(level: int, spans, newton_record) -> None:
        values = dataclasses.asdict(newton_record)
        values.update(iteration=len(run.state.history), level=level, spans=spans)
        call(callbacks, "on_record", run, newton_record.energy, newton_record.gradient_norm,
             newton_record.load_factor)
        run.state.history.append(NewtonRecord(**values))
        run.state.iteration = len(run.state.history)

    outcome, stopped = "budget", ""
    grid: dict = {}  # the level being solved: its grid ("config"), the one before ("fine")

    def next_level(level: int) -> bool:  # the next grid, unless the tolerance or budget stops
        nonlocal outcome, stopped
        if len(run.levels) >= 3:
            converged = [lv.converged for lv in run.levels]
            document = run.refinement(degree)
            if gauge is not None:
                document = gauge_relative(document, gauge, order, converged)
                record["gauge"]["probes"] = document["probes"]  # the relative estimates
            met, worst = tolerance_met(document, adaptive.tolerance, converged)
            log.info("adaptive level %d: %s (tolerance %g)", len(run.levels) - 1, worst,
                     adaptive.tolerance)
            record["worst"] = worst
            if met:
                outcome = "tolerance met"
                stopped = f"--tolerance {adaptive.tolerance:g} met: {worst}"
                return False
        fine = snapshots[-1]
        if graded:
            next_config = features_grid(fine.config.refined(), model, gauges)
        elif adaptive.indicator in ("none", "features"):
            next_config = fine.config.refined()
        else:
            indicator = span_indicator(objective, samples_for(fine), fine, snapshots[-2],
                                       model.boundary, t, kind=adaptive.indicator,
                                       length=length)
            q = adaptive.order or density_order([lv.energy for lv in run.levels], order)
            record["levels"][-1]["next_grid_order"] = q
            next_config = equidistributed(fine.config, indicator, growth=GROWTH, order=q)
        if unknowns(next_config) > adaptive.max_unknowns:
            stopped = (f"--tolerance {adaptive.tolerance:g} not reached: the next grid "
                       f"({next_config.spans[0]} × {next_config.spans[1]} spans, "
                       f"{unknowns(next_config)} unknowns) is over the budget of "
                       f"{adaptive.max_unknowns} unknowns; {record.get('worst', 'no estimate')}")
            log.warning("%s", stopped)
            return False
        grid.update(config=next_config, fine=fine, started=time.perf_counter())
        return True

    def solve(step: Step, _start) -> tuple[SplineField, LevelSolution]:
        """A load step on the new grid from the level before's solution there, projected."""
        start = SplineField(grid["fine"].config, dtype=dtype)
        start.coefficients.copy_(run.steps[step.index][1])
        return solve_on(model, start, grid["config"], plan, config, objective,
                        level=step.level, step=step.index,
                        coarse_energy=run.load_steps[step.index]["energy"],
                        on_iteration=iterated, smooth=run.smooth,
                        gauge_moved=run.gauge_moved)

    def stepped(step: Step, result: tuple[SplineField, LevelSolution]) -> None:
        if on_load_step is not None:
            field, solution = result
            field.coefficients.copy_(solution.coefficients)
            on_load_step(step.value, field)

    def finished(level: int, results: list[tuple[SplineField, LevelSolution]]) -> None:
        field, solutions = results[-1][0], [solution for _, solution in results]
        field.coefficients.copy_(solutions[-1].coefficients)
        run.state.field = field
        run.state.levels.append(LevelSummary.of(level, solutions,
                                                time.perf_counter() - grid["started"]))
        run.steps = [(s.load_factor, s.coefficients) for s in solutions]
        run.load_steps = load_step_records(solutions)
        run.wall_time = time.perf_counter() - started

    solve_over(Stages(solve, after_step=stepped, after_level=finished), config.load_steps,
               first_level=len(run.levels), next_level=next_level, subject=run,
               callbacks=(*callbacks, Hook("on_level", lambda: level_done(run))))
    record["outcome"] = outcome
    record["met"] = outcome == "tolerance met"
    record["stopped"] = stopped  # why, in one line (the budget line names an unconverged level)
    record["unconverged_levels"] = [i for i, lv in enumerate(run.levels) if not lv.converged]
    run.wall_time = time.perf_counter() - started
    log.info("adaptive refinement: %s after %d grids", outcome, len(run.levels))
    return run
