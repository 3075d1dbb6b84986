"""Coarse-to-fine projected-Newton solves and refinement studies on a spline field.

`solve_levels` solves on K successively refined grids (exact dyadic refinement): level 0 by
load continuation from the undeformed state, each finer level at each load factor from the
coarser level's solution prolonged exactly (`SplineField.refined`), so a finer level starts
where the coarser one ended and takes few Newton steps. It reads Π and every probe per level
and load factor.

The probe stop (`probe_stop_at`: the load factor whose probes are read; `solve_spline` sets
it, the last one, on a model with no known singular feature, `spline_grid.no_singular_feature`):
that load step goes on past Newton's own stop while a probe moved over the last step by more
than `PROBE_FRACTION` of the rounding level of its displacement (`ROUNDING` × |u|: 1e-8 |u|),
until a step the line search shortens at Newton's rounding floor, at most `PROBE_STEPS` more
steps, and records each probe component's change over the last step taken, as the full step
would have made it (the change / α: U is affine in the coefficients), as its solve error
(`LevelSolution.probe_errors`). A bar at the a-priori order needs a probe's solve error below
its grid changes: Newton's default stop (`NewtonConfig.discretisation_fraction`, a test on Π)
leaves cantilever_moment's −U 3.6e-5 from the tight solve on 64 × 8, 45 % of its last grid
change, while its changes, solved tight, fall at order 8.9 (benchmarks/RESULTS.md,
wip-adapt12, wip-adapt13); a target relative to a probe's own last change would not be below
the next one. What is left after a Newton step in its quadratic range is far below the step
(measured against tight solves: benchmarks/RESULTS.md, wip-adapt14), and after a shortened
step at most the untaken part of the full one. A probe component a gauge motion moves
(`gauge_moved`) is not read: no solve settles it. A load step whose Newton did not converge
or ended at a non-finite Π is left as it ended (the divergence is reported), and one where
Newton takes no step (a zero gradient: an unloaded step) records no solve error.

`richardson` (`taichi_ndf.minimise.extrapolation`, imported from here too) extrapolates a
quantity from its values on the last grids and bounds the error of the result.
"""

from __future__ import annotations

import dataclasses
import logging
import math
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
)
from taichi_ndf.minimise.linear_solve import LinearSolverConfig
from taichi_ndf.minimise.linearisation import (  # noqa: F401 (held_unknowns: imported from here)
    GridLinearisation,
    held_unknowns,
)
from taichi_ndf.minimise.minimisers import Hooks, NewtonMinimiser, Phase, run_phases
from taichi_ndf.minimise.newton import NewtonConfig, NewtonIteration, minimise
from taichi_ndf.minimise.newton_state import NewtonIterate
from taichi_ndf.minimise.point_extrapolation import richardson_point  # noqa: F401 (imported from here)
from taichi_ndf.objective import Objective
from taichi_ndf.problem.sampling import SurfaceSamples

log = logging.getLogger(__name__)

# The probe stop (module docstring): a probe's change over a Newton step at most this
# fraction of the rounding level of its displacement, within this many steps past Newton's.
PROBE_FRACTION = 1e-2
PROBE_STEPS = 5


@dataclass
class LevelSolution:
    """The solution on one grid at one load factor.

    spans: knot spans of the grid; energy: Π [J]; probes: displacement (3,) [m] by name;
    coefficients (n, 3); seconds: wall time of this level and load step (setup + Newton);
    history: its Newton iterations; probe_errors: each probe's solve error per component (3,)
    [m] by name, from the probe stop (module docstring; None: not measured)."""

    spans: tuple[int, int]
    load_factor: float
    energy: float
    probes: dict[str, np.ndarray]
    coefficients: torch.Tensor
    converged: bool
    seconds: float
    history: list[NewtonIteration] = field(default_factory=list)
    probe_errors: dict[str, np.ndarray] | None = None

    def probe_lists(self) -> dict[str, list[float]]:
        """`probes` as plain values (result.json, checkpoints)."""
        return {k: v.tolist() for k, v in self.probes.items()}

    def probe_error_lists(self) -> dict[str, list[float]] | None:
        """`probe_errors` as plain values (result.json, checkpoints; None: not measured)."""
        errors = self.probe_errors
        return None if errors is None else {k: v.tolist() for k, v in errors.items()}


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
    on_iterate(step, iterate): after each Newton step that a load step goes on from.
    probe_stop_at: the load factor of the probe stop (module docstring; None: Newton's own
    stop everywhere); gauge_moved: the probe components ("name:axis") a gauge motion moves,
    which it does not read (`ProbeGauge.components`)."""

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
                 on_iterate: Callable[[Step, NewtonIterate], None] | None = None,
                 probe_stop_at: float | None = None, gauge_moved: tuple[str, ...] = ()):
        self.probe_stop_at = probe_stop_at
        self.read = {name: np.array([f"{name}:{axis}" not in gauge_moved for axis in range(3)])
                     for name in probes or {}}  # the components the probe stop reads
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
        `ContactMinimiser`'s rounds with obstacles), then the probe stop where it is on; the
        solution, Π, the probes' readings."""
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
        errors = None
        if self.probes and self.contact is None and self.probe_stop_at is not None and abs(
                t - self.probe_stop_at) <= 1e-12 and solution.converged and math.isfinite(
                solution.energy):  # (a diverged step is reported as it ended)
            solution, errors = self._probe_stop(solution, t)
        coefficients = solution.parameters
        readings = self._readings(coefficients, t)
        seconds = time.perf_counter() - started + self._setup
        self._setup = 0.0
        log.info("level %d (%d × %d spans), load %.4g: Π %.10g J in %d Newton steps, "
                 "%.2f s", shown, *grid.config.spans, t, solution.energy,
                 len(solution.history), seconds)
        return LevelSolution(grid.config.spans, t, solution.energy, readings, coefficients,
                             solution.converged, seconds, solution.history, errors)

    def _readings(self, coefficients: torch.Tensor, t: float) -> dict[str, np.ndarray]:
        """Each probe's displacement (3,) [m] at the coefficients, by name."""
        if not self.probes:  # (a free pin's composition needs a point)
            return {}
        u = displacement_at(self.builder.operator, self.probe_xi, coefficients,
                            t)[:, jets.VALUE]
        return {name: u[i].double().cpu().numpy() for i, name in enumerate(self.probes)}

    def _probe_stop(self, solution, t: float):
        """Newton steps past its own stop until each probe's full-step change is at most
        `PROBE_FRACTION` × `ROUNDING` × |u| (its components a gauge motion moves left out),
        or a step shortened at Newton's rounding floor (its `floor_tolerance`), at most
        `PROBE_STEPS` (module docstring); the solution (its history with the extra steps)
        and each probe's full-step change (3,) [m] over the last step taken as its solve
        error (None: no step taken)."""
        newton = self.newton or NewtonConfig()
        more = dataclasses.replace(newton, decrement_tolerance=0.0, gradient_tolerance=0.0,
                                   relative_decrease=0.0, discretisation_fraction=0.0)
        linear, potential = self.builder.linearisation(t), self.objective.potential(t)
        c, energy, history = solution.parameters, solution.energy, list(solution.history)
        before, errors = self._readings(c, t), None
        for _ in range(PROBE_STEPS):
            step = minimise(linear, potential, c, dataclasses.replace(
                more, max_iterations=len(history) + 1), load_factor=t,
                on_iteration=self.iterated, report=False, resume=NewtonIterate(
                    c, len(history), 0.0, False, None, None, history))
            if len(step.history) <= len(history):  # no step taken (e.g. a zero gradient)
                break
            history, alpha = step.history, step.history[-1].step_length
            if alpha == 0.0:  # no step lowered Π: the last step's change stands
                break
            c, energy = step.parameters, step.energy
            after = self._readings(c, t)
            errors = {name: np.abs(after[name] - before[name]) / alpha for name in before}
            before = after
            last = history[-1]
            floor = 0.5 * abs(last.decrement) <= newton.floor_tolerance * abs(last.energy)
            if (alpha < 1.0 and floor) or all(
                    np.linalg.norm(errors[name] * read) <= PROBE_FRACTION * ROUNDING
                    * np.linalg.norm(after[name] * read) for name, read in self.read.items()):
                break
        log.info("probe stop at load %.4g: %d Newton steps past Newton's stop, solve errors %s",
                 t, len(history) - len(solution.history), errors and {
                     name: float(np.linalg.norm(e)) for name, e in errors.items()})
        return dataclasses.replace(solution, parameters=c, energy=energy,
                                   history=history), errors


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
