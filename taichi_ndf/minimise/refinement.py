"""Coarse-to-fine projected-Newton solves and refinement studies on a spline field.

`solve_levels` solves on K successively refined grids (exact dyadic refinement): level 0 by
load continuation from the undeformed state, each finer level at each load factor from the
coarser level's solution prolonged exactly (`SplineField.refined`), so a finer level starts
where the coarser one ended and takes few Newton steps. It reads Π and every probe per level
and load factor.

`richardson` extrapolates a quantity from its values on the last grids: with three values
v₀, v₁, v₂ on grids h, h/2, h/4 the observed order is p = log₂((v₁ − v₀)/(v₂ − v₁)) and
v∞ = v₂ + (v₂ − v₁)/(2ᵖ − 1); the estimated discretisation error of v₂ is |v∞ − v₂|. When the
differences do not fall monotonically (no asymptotic range yet) the extrapolation is not
trusted: v∞ = v₂ and the error estimate is |v₂ − v₁|. With two values the order must be given.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import torch

from taichi_ndf import jets, progress
from taichi_ndf.boundary import BoundaryConditions
from taichi_ndf.minimise.assembly import (
    Assembly,
    displacement_at,
    gauge_unknowns,
    local_basis_at,
)
from taichi_ndf.minimise.linear_solve import LinearSolver, LinearSolverConfig
from taichi_ndf.minimise.projected_newton import (
    NewtonIteration,
    ProjectedNewtonConfig,
    minimise,
)
from taichi_ndf.objective import Objective
from taichi_ndf.operator import DisplacementOperator
from taichi_ndf.sampling import SurfaceSamples
from taichi_ndf.shell.hessian import COMPONENTS

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


@dataclass(frozen=True)
class Extrapolation:
    """A refinement-extrapolated value, the estimated error of the finest value, and the
    observed order (None: not trusted or assumed)."""

    value: float
    error: float
    order: float | None


def richardson(values: list[float], order: float | None = None) -> Extrapolation:
    """Richardson extrapolation of values on grids refined by 2 each (module docstring).
    order: the assumed convergence order, needed for two values; with three or more the
    observed order of the last three is used."""
    if len(values) < 2:
        raise ValueError(f"richardson needs at least two values, got {len(values)}")
    v1, v2 = values[-2], values[-1]
    if len(values) >= 3:
        v0 = values[-3]
        ratio = (v1 - v0) / (v2 - v1) if v2 != v1 else math.inf
        if not (math.isfinite(ratio) and ratio > 1):
            return Extrapolation(v2, abs(v2 - v1), None)
        order = math.log2(ratio)
    elif order is None:
        raise ValueError("two values need an assumed order")
    limit = v2 + (v2 - v1) / (2**order - 1)
    return Extrapolation(limit, abs(limit - v2), order)


def held_unknowns(grid, boundary, basis) -> np.ndarray | None:
    """Unknowns held at zero: the gauge of a free pin (`gauge_unknowns`) and the coefficients
    a mirrored spline never reads (`SplineField.aliased_coefficients`), which no point
    couples."""
    held = [gauge_unknowns(boundary, basis)]
    aliased = grid.aliased_coefficients.numpy()
    if aliased.size:
        held.append((aliased[:, None] * COMPONENTS + np.arange(COMPONENTS)).reshape(-1))
    held = [h for h in held if h is not None]
    return np.concatenate(held) if held else None


def solve_levels(field_, boundary: BoundaryConditions,
                 samples_for: Callable[[object], SurfaceSamples],
                 objective: Objective, *, levels: int,
                 load_steps: tuple[float, ...] = (1.0,),
                 config: ProjectedNewtonConfig | None = None,
                 coarse_config: ProjectedNewtonConfig | None = None,
                 probes: dict[str, tuple[float, float]] | None = None,
                 length: float = 1.0,
                 on_level: Callable[[int, object, list[LevelSolution]], None] | None = None,
                 contact=None, linear: LinearSolverConfig | None = None
                 ) -> list[list[LevelSolution]]:
    """Solve on `levels` grids, the field's and its dyadic refinements (module docstring).

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
    level's own dyadic hierarchy on large grids). Returns [level][load step] solutions.
    """
    if levels < 1:
        raise ValueError(f"levels must be >= 1, got {levels}")
    probes = probes or {}
    dtype = field_.coefficients.dtype
    probe_xi = torch.tensor(list(probes.values()), dtype=dtype).reshape(-1, 2)
    results: list[list[LevelSolution]] = []
    grid, prolongation = field_, None
    for level in range(levels):
        if level:
            prolongation = grid.prolongation()  # coarse -> this level
            grid = grid.refined()
        started = time.perf_counter()
        nx, ny = grid.config.spans
        with progress.stage(f"Newton level {level} ({nx} × {ny} spans): quadrature, basis"):
            samples = samples_for(grid)
            operator = DisplacementOperator(grid, boundary)
            basis = local_basis_at(operator, samples.xi)
            assembly = None if contact else Assembly(samples, basis, grid.coefficients.shape[0])
            fixed = held_unknowns(grid, boundary, basis)
            solver = LinearSolver.for_grid(grid.config, linear)
        setup = time.perf_counter() - started
        per_load: list[LevelSolution] = []
        coefficients = grid.coefficients.detach().clone()
        newton = config if coarse_config is None or level == levels - 1 else coarse_config
        for k, t in enumerate(load_steps):
            started = time.perf_counter()
            if level:
                coefficients = torch.sparse.mm(prolongation,
                                               results[-1][k].coefficients.to(dtype))
            with progress.stage(f"Newton level {level} ({nx} × {ny} spans), load {t:.4g}",
                                (newton or ProjectedNewtonConfig()).max_iterations):
                if contact is None:
                    assembly.at_load(operator, t)
                    solution = minimise(assembly, objective.potential(t), coefficients, newton,
                                        load_factor=t, length=length, fixed=fixed,
                                        linear_solver=solver)
                else:  # from the previous load step's state (finer level: this one's, prolonged)
                    solution = contact.solve(
                        operator, samples, objective, coefficients, newton,
                        load_factor=t, start_load_factor=t if level else (
                            load_steps[k - 1] if k else 0.0), length=length, fixed=fixed,
                        linear_solver=solver)
            coefficients = solution.coefficients
            u = displacement_at(operator, probe_xi, coefficients, t)[:, jets.VALUE]
            readings = {name: u[i].double().cpu().numpy() for i, name in enumerate(probes)}
            seconds = time.perf_counter() - started + (setup if k == 0 else 0.0)
            per_load.append(LevelSolution(grid.config.spans, t, solution.energy, readings,
                                          coefficients, solution.converged, seconds,
                                          solution.history))
            log.info("level %d (%d × %d spans), load %.4g: Π %.10g J in %d Newton steps, "
                     "%.2f s", level, *grid.config.spans, t, solution.energy,
                     len(solution.history), seconds)
        results.append(per_load)
        if on_level is not None:
            on_level(level, grid, per_load)
    return results
