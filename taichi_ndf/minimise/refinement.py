"""Coarse-to-fine projected-Newton solves and refinement studies on a spline field.

`solve_levels` solves on K successively refined grids (exact dyadic refinement): level 0 by
load continuation from the undeformed state, each finer level at each load factor from the
coarser level's solution prolonged exactly (`SplineField.refined`), so a finer level starts
where the coarser one ended and takes few Newton steps. It reads Π and every probe per level
and load factor.

`richardson` (`taichi_ndf.minimise.extrapolation`, imported from here too) extrapolates a
quantity from its values on the last grids and bounds the error of the result.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial

import numpy as np
import torch

from taichi_ndf import jets, progress
from taichi_ndf.boundary import BoundaryConditions
from taichi_ndf.minimise.assembly import displacement_at
from taichi_ndf.minimise.continuation import Stages, Step, solve_over
from taichi_ndf.minimise.extrapolation import (  # noqa: F401 (imported from here)
    ORDER_BASES,
    ORDER_FAR,
    ORDER_MIN,
    ORDER_SLACK,
    ROUNDING,
    SAFETY_OBSERVED,
    SAFETY_UNRELIABLE,
    Extrapolation,
    OrderEstimate,
    extrapolate_changes,
    richardson,
    richardson_point,
)
from taichi_ndf.minimise.linear_solve import LinearSolverConfig
from taichi_ndf.minimise.linearisation import (  # noqa: F401 (held_unknowns: imported from here)
    GridLinearisation,
    held_unknowns,
)
from taichi_ndf.minimise.minimisers import Hooks, NewtonMinimiser, Phase, run_phases
from taichi_ndf.minimise.newton import NewtonConfig, NewtonIteration
from taichi_ndf.minimise.newton_state import NewtonIterate
from taichi_ndf.objective import Objective
from taichi_ndf.problem.sampling import SurfaceSamples

log = logging.getLogger(__name__)


@dataclass
class LevelSolution:
    """The solution on one grid at one load factor.

    spans: knot spans of the grid; energy: Π [J]; probes: displacement (3,) [m] by name;
    coefficients (n, 3); seconds: wall time of this level and load step (setup + Newton);
    history: its Newton iterations."""

    spans: tuple[int, int]
    load_factor: float
    energy: float
    probes: dict[str, np.ndarray]
    coefficients: torch.Tensor
    converged: bool
    seconds: float
    history: list[NewtonIteration] = field(default_factory=list)


class GridLevels:
    """The stages of a coarse-to-fine projected-Newton solve (`taichi_ndf.minimise.continuation`):
    each level's grid (the field's, then its dyadic refinements), quadrature, assembly and
    linear solver; a load step's start (the previous step's solution, the level's field at
    the first; on a finer level the coarser solution at the same load factor, prolonged
    exactly); its Newton solve and readings (`LevelSolution`). `grid`: the current level's
    field (its coefficients: the level's starting point). Settings as `solve_levels`';
    first_level: the level the run starts on (`field_`'s); first_coarse: a resumed run's
    coarser Π there (its Newton stops as the whole run's did: `start`); linearise(grid): the
    builder of a level's linearisation (`GridLinearisation`; a discretisation's,
    `SplineDiscretisation.linearise`), None: on `boundary` with `length` and `linear`.
    Resumed inside the first level: coarse_grid, the grid below it (its prolongation);
    resume, (step index, `NewtonIterate`): that step's Newton goes on from the iterate.
    on_iterate(step, iterate): after each Newton step that a load step goes on from."""

    def __init__(self, field_, boundary: BoundaryConditions,
                 samples_for: Callable[[object], SurfaceSamples], objective: Objective, *,
                 levels: int, config: NewtonConfig | None = None,
                 coarse_config: NewtonConfig | None = None,
                 probes: dict[str, tuple[float, float]] | None = None, length: float = 1.0,
                 contact=None, linear: LinearSolverConfig | None = None,
                 on_iteration: Callable[[int, tuple[int, int], NewtonIteration], None]
                 | None = None, first_level: int = 0, first_coarse: float | None = None,
                 linearise: Callable[[object], GridLinearisation] | None = None,
                 coarse_grid=None, resume: tuple[int, NewtonIterate] | None = None,
                 on_iterate: Callable[[Step, NewtonIterate], None] | None = None):
        self.grid, self.boundary, self.samples_for = field_, boundary, samples_for
        self.resume = {} if resume is None else {(first_level, resume[0]): resume[1]}
        self.on_iterate = on_iterate
        self.first_coarse = first_coarse
        self.objective, self.levels, self.first_level = objective, levels, first_level
        self.config, self.coarse_config, self.length = config, coarse_config, length
        self.contact, self.linear, self.on_iteration = contact, linear, on_iteration
        self.linearise = linearise or (lambda grid: GridLinearisation(
            grid, boundary, length=length, linear=linear or LinearSolverConfig()))
        self.probes = probes or {}
        self.dtype = field_.coefficients.dtype
        self.probe_xi = torch.tensor(list(self.probes.values()),
                                     dtype=self.dtype).reshape(-1, 2)
        self._prolongation = None if coarse_grid is None else coarse_grid.prolongation()

    def enter_level(self, level: int) -> None:
        """The level's grid (refined from the previous one past the first level), its
        quadrature points, basis, assembly, held unknowns and linear solver."""
        if level > self.first_level:
            self._prolongation = self.grid.prolongation()  # coarse -> this level
            self.grid = self.grid.refined()
        grid = self.grid
        started = time.perf_counter()
        nx, ny = grid.config.spans
        with progress.stage(f"Newton level {level - self.first_level} ({nx} × {ny} spans): "
                            "quadrature, basis"):
            self.samples = self.samples_for(grid)
            self.builder = self.linearise(grid)
            if self.contact is None:  # with contact: one assembly per round (NewtonContact)
                self.builder.assemble(self.samples)
        self._setup = time.perf_counter() - started  # counted in the level's first step
        last = level == self.levels - 1
        self.newton = self.config if self.coarse_config is None or last else self.coarse_config
        self.iterated = None if self.on_iteration is None else (
            lambda record, level=level, spans=grid.config.spans: self.on_iteration(
                level, spans, record))

    def start(self, step: Step, previous: LevelSolution | None,
              coarser: LevelSolution | None
              ) -> tuple[torch.Tensor, float, float, float | None]:
        """The step's starting coefficients (n, 3), the load factor they were solved at (0:
        the level's own field at the run's first level), the time the step started and the
        coarser grid's Π [J] at this load factor (None on the first level: Newton's
        discretisation stopping test, `NewtonConfig.discretisation_fraction`)."""
        started = time.perf_counter()
        if coarser is not None:
            coefficients = torch.sparse.mm(self._prolongation,
                                           coarser.coefficients.to(self.dtype))
            return coefficients, step.load_factor, started, coarser.energy
        if previous is not None:
            return previous.coefficients, previous.load_factor, started, None
        return self.grid.coefficients.detach().clone(), 0.0, started, self.first_coarse

    def solve(self, step: Step, start: tuple[torch.Tensor, float, float, float | None]
              ) -> LevelSolution:
        """Projected Newton at the step's load factor from `start` (`NewtonMinimiser`, or
        `ContactMinimiser`'s rounds with obstacles); the solution, Π, the probes' readings."""
        coefficients, start_load_factor, started, coarse_energy = start
        grid, t, newton = self.grid, step.load_factor, self.newton
        nx, ny = grid.config.spans
        resume = self.resume.pop((step.level, step.index), None)  # the first only
        shown = step.level - self.first_level  # labels count this run's levels (as before)
        stage = (f"Newton level {shown} ({nx} × {ny} spans), load {t:.4g}",
                 (newton or NewtonConfig()).max_iterations)
        iterate = None if self.on_iterate is None else partial(self.on_iterate, step)
        if self.contact is None:
            phase = Phase(NewtonMinimiser(newton, load_factor=t, coarse_energy=coarse_energy,
                                          resume=resume),
                          lambda: (self.builder.linearisation(t), self.objective.potential(t)))
        else:  # from the previous load step's state (finer level: this one's, prolonged)
            phase = Phase(self.contact.minimiser(newton, load_factor=t, resume=resume,
                                                 start_load_factor=start_load_factor),
                          lambda: (self.builder, self.samples, self.objective))
        phase.parameters = lambda: coefficients
        phase.hooks, phase.stage = Hooks(on_iteration=self.iterated, on_iterate=iterate), stage
        solution = run_phases([phase])[0]
        coefficients = solution.parameters
        readings = {}
        if self.probes:  # (a free pin's composition needs a point)
            u = displacement_at(self.builder.operator, self.probe_xi, coefficients,
                                t)[:, jets.VALUE]
            readings = {name: u[i].double().cpu().numpy() for i, name in enumerate(self.probes)}
        seconds = time.perf_counter() - started + self._setup
        self._setup = 0.0
        log.info("level %d (%d × %d spans), load %.4g: Π %.10g J in %d Newton steps, "
                 "%.2f s", shown, *grid.config.spans, t, solution.energy,
                 len(solution.history), seconds)
        return LevelSolution(grid.config.spans, t, solution.energy, readings, coefficients,
                             solution.converged, seconds, solution.history)


def solve_levels(field_, boundary: BoundaryConditions,
                 samples_for: Callable[[object], SurfaceSamples],
                 objective: Objective, *, levels: int,
                 load_steps: tuple[float, ...] = (1.0,),
                 config: NewtonConfig | None = None,
                 coarse_config: NewtonConfig | None = None,
                 probes: dict[str, tuple[float, float]] | None = None,
                 length: float = 1.0,
                 on_level: Callable[[int, object, list[LevelSolution]], None] | None = None,
                 contact=None, linear: LinearSolverConfig | None = None,
                 on_iteration: Callable[[int, tuple[int, int], NewtonIteration], None]
                 | None = None,
                 on_load_step: Callable[[float], None] | None = None
                 ) -> list[list[LevelSolution]]:
    """Solve on `levels` grids, the field's and its dyadic refinements (module docstring),
    by the continuation loop (`taichi_ndf.minimise.continuation.solve_over`) over `GridLevels`.

    field_: a `SplineField` (its coefficients are the level-0 starting point; not changed).
    samples_for(field): the quadrature points of a field's grid (point forces unscaled).
    objective: Π (`Objective.potential(t)` applies the load factor to every load).
    config: Newton settings of the finest level; coarse_config: of the coarser levels (e.g. a
    looser tolerance: they only give the next level its start), `config` if None.
    probes: name -> ξ. length: a
    parameter-domain length for the Hessian's FD steps. on_level(level, grid, solutions): called
    after each level with its field (coefficients: its starting point) and its solutions per
    load step. contact: a `taichi_ndf.contact.newton_contact.NewtonContact` that solves each
    load step with its check points, its terms and a penetration-free line search. linear:
    the linear solver's settings (`LinearSolver.for_grid` per level: multigrid over the
    level's own dyadic hierarchy on large grids). on_iteration(level, spans, record): every
    Newton iteration (`minimise`'s); on_load_step(load factor): after each load step of each
    level. Returns [level][load step] solutions.
    """
    if levels < 1:
        raise ValueError(f"levels must be >= 1, got {levels}")
    grids = GridLevels(field_, boundary, samples_for, objective, levels=levels, config=config,
                       coarse_config=coarse_config, probes=probes, length=length,
                       contact=contact, linear=linear, on_iteration=on_iteration)
    after_step = None if on_load_step is None else (
        lambda step, solution: on_load_step(step.load_factor))
    after_level = None if on_level is None else (
        lambda level, solutions: on_level(level, grids.grid, solutions))
    return solve_over(Stages(grids.solve, grids.start, grids.enter_level, after_step,
                             after_level), load_steps, levels=levels)
