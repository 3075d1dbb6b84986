"""A model solved by projected Newton over a spline field, coarse to fine (`method = "newton"`).

The spline path's driver (the Adam path's is `solve/solver.py`), on the one continuation loop
(`taichi_ndf.minimise.continuation`) with the stages `minimise.refinement.GridLevels`: level 0 from
the undeformed state through the load steps, each finer grid (exact dyadic refinement) at each load
step from the coarser solution prolonged. Reports per level Π, every probe and the seconds
taken, and per Newton iteration Π, the decrement, the step length and the time split; with
several levels the Richardson-extrapolated Π and probes and their error bars (`richardson`: an
observed order from three or more levels, trusted only between 0.5 and the expected 2·(p − 1)
— the energy-norm rate of degree-p splines for a fourth-order problem — else "order
unreliable" and 3 × the range of the last three values; with two levels that order assumed,
said so, and the error widened to the change between the levels).
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import torch

from taichi_ndf.boundary.gauge_motions import probe_gauge
from taichi_ndf.boundary.gauges import gauge_points
from taichi_ndf.contact.newton_contact import NewtonContact
from taichi_ndf.field import SplineField
from taichi_ndf.minimise.callbacks import call
from taichi_ndf.minimise.checkpoint import CheckpointError
from taichi_ndf.minimise.continuation import Hook, Stages, Step, resume_point, solve_over
from taichi_ndf.minimise.linear_solve import LinearSolverConfig
from taichi_ndf.minimise.linearisation import GridLinearisation
from taichi_ndf.minimise.newton import NewtonConfig
from taichi_ndf.minimise.newton_state import NewtonIterate
from taichi_ndf.minimise.refinement import GridLevels, LevelSolution, richardson, richardson_point
from taichi_ndf.minimise.state import (
    InsideLevel,
    LevelSummary,
    NewtonRecord,
    State,
    load_step_records,
)
from taichi_ndf.objective import Objective
from taichi_ndf.objective.seam import with_seam_points
from taichi_ndf.problem.model import ShellModel
from taichi_ndf.problem.spline_grid import SplinePlan, no_singular_feature
from taichi_ndf.problem.training import SolverConfig

__all__ = ["LevelSummary", "NewtonRecord", "SplineRun", "newton_config", "solve_spline"]

log = logging.getLogger(__name__)


@dataclass
class SplineRun:
    """A projected-Newton run so far: its `State` (method "newton": the field of the last
    finished level, the levels' summaries, every Newton iteration) and settings — what the
    callbacks (`taichi_ndf.minimise.callbacks`) see as `solver` on this path."""

    state: State
    config: SolverConfig
    wall_time: float = 0.0
    # (load factor, coefficients (n, 3)) of every load step solved on the last level
    steps: list[tuple[float, torch.Tensor]] = dataclasses.field(default_factory=list)
    # per load step of the last level: load factor, Π [J], probes (displacement [m] by name)
    load_steps: list[dict] = dataclasses.field(default_factory=list)
    contact: NewtonContact | None = None  # with obstacles: the check points, κ, rounds
    # the model has no known singular feature (`spline_grid.no_singular_feature`): Π's bar
    # past a converged sequence at the a-priori order (`richardson(..., smooth=True)`), and a
    # probe's too where every level measured its solve error (`GridLevels`' probe stop)
    smooth: bool = False
    # the probe components ("name:axis") a gauge motion moves (`ProbeGauge.components`): no
    # solve settles them, so no solve error of theirs is read
    gauge_moved: tuple[str, ...] = ()

    @property
    def field(self) -> SplineField:
        """The last finished grid with its final coefficients."""
        return self.state.field

    @property
    def levels(self) -> list[LevelSummary]:
        return self.state.levels

    @property
    def history(self) -> list[NewtonRecord]:
        return self.state.history

    @property
    def energy(self) -> float:
        return self.levels[-1].energy

    @property
    def probes(self) -> dict[str, list[float]]:
        return self.levels[-1].probes

    def refinement(self, degree: int) -> dict | None:
        """Π and every probe component per level with the Richardson value, its error bar and
        how it was found (`Extrapolation.to_dict`: order, order_basis "observed" / "assumed" /
        "unreliable", order_reason, warning, text); None with one level."""
        if len(self.levels) < 2:
            return None
        order = 2.0 * (degree - 1)
        converged = [lv.converged for lv in self.levels]  # an unconverged level: no order

        def extrapolate(values):  # Π
            return {"values": values, **richardson(values, order=order, converged=converged,
                                                   smooth=self.smooth).to_dict()}

        def point(name):  # a probe's order is the point's (`richardson_point`)
            values = [lv.probes[name] for lv in self.levels]
            errors = [lv.probe_errors and lv.probe_errors.get(name) for lv in self.levels]
            measured = self.smooth and all(e is not None for e in errors)
            if measured:  # not measured (NaN): a component a gauge motion moves
                moved = [f"{name}:{axis}" in self.gauge_moved for axis in range(3)]
                errors = [[math.nan if m else x for m, x in zip(moved, e, strict=True)]
                          for e in errors]
            return [{"values": [v[c] for v in values], **e.to_dict()} for c, e in enumerate(
                richardson_point(values, order=order, converged=converged,
                                 solve_errors=errors if measured else None))]

        probes = {name: point(name) for name in self.levels[-1].probes}
        return {"spans": [list(lv.spans) for lv in self.levels],
                "energy": extrapolate([lv.energy for lv in self.levels]), "probes": probes}


def newton_config(config: SolverConfig, dtype: torch.dtype) -> NewtonConfig:
    """Projected-Newton settings of a run: the FD step and the stopping tolerances suit the
    precision (float32: Π is summed over thousands of points, so its rounding floor is about
    1e-6 |Π|; the float64 defaults would never stop); a run's `newton_tolerance` looser than
    that floor replaces the decrement tolerance."""
    if dtype == torch.float64:
        newton = NewtonConfig(max_iterations=config.newton_max_iterations)
    else:
        newton = NewtonConfig(max_iterations=config.newton_max_iterations, fd_step=3e-3,
                              decrement_tolerance=1e-7, gradient_tolerance=1e-5,
                              floor_tolerance=1e-6)
    if config.newton_tolerance is None or config.newton_tolerance <= newton.decrement_tolerance:
        return newton
    return dataclasses.replace(newton, decrement_tolerance=config.newton_tolerance)


def solve_spline(model: ShellModel, plan: SplinePlan, config: SolverConfig, *,
                 objective: Objective | None = None, state: State | None = None,
                 callbacks: tuple[Any, ...] | list[Any] = (),
                 on_level: Callable[[SplineRun], None] | None = None,
                 linearise: Callable[[SplineField], GridLinearisation] | None = None
                 ) -> SplineRun:
    """Solve the model on the plan's grids (at most `config.max_levels` of them when > 0).

    state: a resumed run's (`State.restore`, method "newton": the last finished level's field,
    its levels and history, and where the run was inside a grid level, `State.inside`: it
    goes on there, bit for bit; without it, the remaining levels are solved at the last load
    factor from the last level). With obstacles (`model.contact`) each load step is solved
    by the contact's `ContactMinimiser` (which adds the contact terms to the objective); its
    state (check points, κ, the round in progress) is in `State.inside.contact` and a resume
    inside a level takes it back (`NewtonContact.restore`).
    callbacks (`taichi_ndf.minimise.callbacks`, each hook optional, called with the `SplineRun`):
    on_start, on_record(run, Π, ‖g‖, load factor) at every Newton iteration, on_iteration(run,
    None) after each Newton step a load step goes on from (`State.inside` then holds the
    iterate), on_load_step(run, load factor) and on_level(run) after each level (its field:
    that level's grid), on_interrupt(run) on Ctrl-C inside the levels (solve_over's
    `Stages.interrupted`; then re-raised), on_end.
    on_level(run): after each level too, after the callbacks.
    linearise(grid): the builder of each grid level's linearisation, the discretisation's
    (`SplineDiscretisation.linearise`: `SplineDiscretisation.solve` passes it); None: the
    same construction here (`GridLinearisation` on the model's boundary, the domain's √area
    as FD length, the run's `linear_solver`).
    """
    objective = objective or Objective.of_model(model)
    surface = model.surface

    levels = plan.levels if not config.max_levels else min(plan.levels, config.max_levels)
    load_steps = tuple(config.load_steps)
    state = state or State.newton(None)
    if state.field is None:
        state.field = SplineField(plan.config)
    inside = state.inside
    if inside is not None and (model.contact is None) != (inside.contact is None):
        raise CheckpointError(
            f"the checkpoint was written inside grid level {inside.level} of a run "
            f"{'without' if inside.contact is None else 'with'} obstacles; resume it with "
            "its own scene")
    if inside is not None and not inside.fits(load_steps):
        raise CheckpointError(
            f"the checkpoint was written inside grid level {inside.level} of a run with other "
            f"load steps than {list(load_steps)}; resume it with its own [training] load_steps")
    # inside a level: the last finished level's grid refined (the first level's: the grid)
    coarse_grid = None if inside is None or inside.coarser is None else state.field
    grid = state.field if coarse_grid is None else coarse_grid.refined()
    # resumed without `inside`: the last level re-solved at the last load step and refined
    first, first_step = resume_point(state, len(load_steps))
    state.levels = state.levels[:first]
    done = [] if inside is None else list(inside.done)  # this level's finished load steps
    coarser = None if inside is None else inside.coarser
    contact = None
    if model.contact is not None:
        contact = NewtonContact(model.contact, model, grid.coefficients.dtype)
        if inside is not None:
            contact.restore(inside.contact)
    gauges = gauge_points(model)  # once per solve
    smooth = no_singular_feature(model, gauges)
    gauge = probe_gauge(model, gauges) if smooth else None
    run = SplineRun(state, config, contact=contact, smooth=smooth,
                    gauge_moved=() if gauge is None else gauge.components())
    if first + 1 > levels:
        raise ValueError(f"the checkpoint holds {first + 1} levels, more than the {levels} "
                         "this run solves")
    probes = {p.name: p.xi for p in model.probes}
    newton = newton_config(config, grid.coefficients.dtype)
    started = time.perf_counter()

    def iterated(level: int, spans: tuple[int, int], record) -> None:
        values = dataclasses.asdict(record)
        values.update(iteration=len(state.history), level=level, spans=spans)
        call(callbacks, "on_record", run, record.energy, record.gradient_norm,
              record.load_factor)
        state.history.append(NewtonRecord(**values))
        state.iteration = len(state.history)

    def within(level: int, step: int | None = None, iterate: NewtonIterate | None = None
               ) -> InsideLevel:  # where the run is (with contact: its state)
        return InsideLevel(level, first_step, list(done), coarser, len(state.history), step,
                           iterate, None if contact is None else contact.to_dict())

    def iterate_kept(step: Step, iterate: NewtonIterate) -> None:
        state.inside = within(step.level, step.index, iterate)
        call(callbacks, "on_iteration", run, None)

    def stepped(step: Step, solution: LevelSolution) -> None:
        state.load_step = step.index
        done.append(solution)
        state.inside = within(step.level)

    def finished(level: int, solutions: list[LevelSolution]) -> None:
        nonlocal coarser
        field_ = grids.grid
        field_.coefficients.copy_(solutions[-1].coefficients)
        summary = LevelSummary.of(level, solutions, sum(s.seconds for s in solutions))
        state.levels.append(summary)
        state.field = field_
        state.load_step = len(config.load_steps)
        run.steps = [(s.load_factor, s.coefficients) for s in solutions]
        run.load_steps = load_step_records(solutions)
        run.wall_time = time.perf_counter() - started
        coarser = solutions
        done.clear()
        state.inside = within(level + 1) if level + 1 < levels else None
        log.info("level %d (%d × %d spans): Π %.10g J, %d Newton iterations, %.2f s%s", level,
                 *summary.spans, summary.energy, summary.iterations, summary.seconds,
                 "" if summary.converged else " (not converged)")

    def ended() -> None:
        run.wall_time = time.perf_counter() - started

    points = plan.quadrature_points
    grids = GridLevels(grid, model.boundary,
                       lambda f: with_seam_points(GridLinearisation.quadrature(
                           surface, f.config, model.loads, points=points,
                           dtype=f.coefficients.dtype), objective.extra),
                       objective, levels=levels, config=newton, probes=probes,
                       length=math.sqrt(surface.domain.rectangle_area), contact=contact,
                       linear=LinearSolverConfig(kind=config.linear_solver),
                       on_iteration=iterated, first_level=first,
                       first_coarse=state.levels[first - 1].energy if first else None,
                       linearise=linearise, coarse_grid=coarse_grid,
                       resume=None if inside is None or inside.iterate is None else (
                           inside.step, inside.iterate), on_iterate=iterate_kept,
                       probe_stop_at=load_steps[-1] if run.smooth else None,
                       gauge_moved=run.gauge_moved)
    callbacks = tuple(callbacks)
    if on_level is not None:  # after the callbacks
        callbacks = (*callbacks, Hook("on_level", lambda: on_level(run)))
    solve_over(Stages(grids.solve, grids.start, grids.enter_level, stepped, finished, ended,
                      interrupted=lambda: call(callbacks, "on_interrupt", run)),
               load_steps, levels=levels, first_level=first, first_step=first_step,
               callbacks=callbacks, subject=run, done=list(done), coarser=coarser)
    return run
