"""Coarse-to-fine projected-Newton solves and refinement studies on a spline field.

`solve_levels` solves on K successively refined grids (exact dyadic refinement): level 0 by
load continuation from the undeformed state, each finer level at each load factor from the
coarser level's solution prolonged exactly (`SplineField.refined`), so a finer level starts
where the coarser one ended and takes few Newton steps. It reads Π and every probe per level
and load factor.

`richardson` extrapolates a quantity from its values on the last grids (one rule for every
caller: `extrapolate_changes` works on the changes between successive grids, signed for a
scalar, a norm for a field of positions). With three values v₀, v₁, v₂ on grids h, h/2, h/4
the observed order is p = log₂((v₁ − v₀)/(v₂ − v₁)) and v∞ = v₂ + (v₂ − v₁)/(2ᵖ − 1); the
error bar is |v∞ − v₂| (the interval v∞ ± error reaches back to v₂); a warning is logged
where p is more than a factor `ORDER_FAR` from the expected order. When the differences do not
fall monotonically (no asymptotic range yet) the extrapolation is not trusted: v∞ = v₂ and the
error is the larger of the last two changes (chosen after the coverage study, where the last
change alone missed napkin_clamped_edges' oscillating 5/10/20-span values;
benchmarks/RESULTS.md). With two values the order cannot be observed: it is assumed (the expected
order, 2(p − 1) for degree-p splines), the value is extrapolated with it and the error is
widened to the whole change |v₂ − v₁| between the two grids — a bar that does not rest on the
assumption (measured: the napkin's two-grid bar at the assumed order 4 was 15× smaller than
the change; benchmarks/RESULTS.md, "Refinement error bars").
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
from taichi_ndf.minimise.linearisation import SplineLinearisation
from taichi_ndf.minimise.newton import NewtonConfig, NewtonIteration, minimise
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


ORDER_FAR = 2.0  # an observed order outside [expected / ORDER_FAR, expected × ORDER_FAR] warns


@dataclass(frozen=True)
class Extrapolation:
    """A refinement-extrapolated value and its error bar (the interval value ± error should
    hold the converged value), the order it used, and how it was found: basis "observed"
    (three or more grids), "assumed" (two grids: `order` is the expected one) or "not
    converging" (differences not falling: value = the finest value, order None). grids: how
    many values; warning: a one-line caution (observed order far from the expected) or None."""

    value: float
    error: float
    order: float | None
    basis: str = "observed"
    grids: int = 3
    expected: float | None = None
    warning: str | None = None

    @property
    def assumed(self) -> bool:
        return self.basis == "assumed"

    def describe(self, unit: str = "") -> str:
        """'v ± e unit (how)', the way every output shows the value."""
        unit = f" {unit}" if unit else ""
        return f"{self.value:.6g} ± {self.error:.2g}{unit} ({self.how()})"

    def how(self) -> str:
        """How the value was found, in words (shown beside it everywhere)."""
        if self.basis == "assumed":
            return (f"order {self.order:g} assumed from {self.grids} grids, error = the change "
                    "between them")
        if self.basis == "not converging":
            return (f"{self.grids} grids, differences not falling: finest value, error = the "
                    "larger of the last two changes")
        expected = "" if self.expected is None else f", expected {self.expected:g}"
        return f"observed order {self.order:.2f} from {self.grids} grids{expected}"

    def to_dict(self) -> dict:
        return {"extrapolated": self.value, "estimated_error": self.error, "order": self.order,
                "order_basis": self.basis, "grids": self.grids,
                "expected_order": self.expected, "warning": self.warning,
                "text": self.describe()}


def extrapolate_changes(changes: list[float], order: float | None = None
                        ) -> tuple[float | None, float, str, str | None]:
    """The order, the error bar of the finest value's extrapolation, the basis and a warning
    from the changes between successive grids refined by 2 each (signed differences of a
    scalar, or norms of a field's differences; module docstring). order: the expected order,
    assumed with one change and compared with the observed one with two or more. The
    correction v∞ − v_finest is changes[-1] / (2^order − 1) where the basis is not "not
    converging"."""
    if not changes:
        raise ValueError("richardson needs at least two values, got 1")
    last = changes[-1]
    if len(changes) == 1:
        if order is None:
            raise ValueError("two values need an assumed order")
        return order, abs(last), "assumed", None
    largest = max(abs(c) for c in changes[-2:])
    if last == 0.0:
        return None, largest, "not converging", None
    ratio = changes[-2] / last
    if not (math.isfinite(ratio) and ratio > 1):
        return None, largest, "not converging", None
    observed = math.log2(ratio)
    warning = None
    if order is not None and not order / ORDER_FAR <= observed <= order * ORDER_FAR:
        warning = (f"observed refinement order {observed:.2f} is far from the expected "
                   f"{order:g}: the grids are not in the asymptotic range (a singularity or "
                   "an unresolved layer?); the error bar rests on the observed order")
    return observed, abs(last) / (2.0**observed - 1.0), "observed", warning


def richardson(values: list[float], order: float | None = None) -> Extrapolation:
    """Richardson extrapolation of values on grids refined by 2 each (module docstring).
    order: the expected convergence order, assumed with two values (required then) and
    compared with the observed order of the last three with three or more."""
    if len(values) < 2:
        raise ValueError(f"richardson needs at least two values, got {len(values)}")
    last = values[-3:]
    changes = np.diff(last).tolist()
    used, error, basis, warning = extrapolate_changes(changes, order)
    finest = values[-1]
    value = finest if basis == "not converging" else (
        finest + changes[-1] / (2.0**used - 1.0))
    if warning is not None:
        log.warning("%s", warning)
    return Extrapolation(value, error, used, basis, len(values), order, warning)


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
    level's own dyadic hierarchy on large grids). on_iteration(level, spans, record): every
    Newton iteration (`minimise`'s); on_load_step(load factor): after each load step of each
    level. Returns [level][load step] solutions.
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
        iterated = None if on_iteration is None else (
            lambda record, level=level, spans=grid.config.spans: on_iteration(level, spans,
                                                                              record))
        for k, t in enumerate(load_steps):
            started = time.perf_counter()
            if level:
                coefficients = torch.sparse.mm(prolongation,
                                               results[-1][k].coefficients.to(dtype))
            with progress.stage(f"Newton level {level} ({nx} × {ny} spans), load {t:.4g}",
                                (newton or NewtonConfig()).max_iterations):
                if contact is None:
                    assembly.at_load(operator, t)
                    linearisation = SplineLinearisation(assembly, fixed=fixed, solver=solver,
                                                        length=length)
                    solution = minimise(linearisation, objective.potential(t), coefficients,
                                        newton, load_factor=t, on_iteration=iterated)
                else:  # from the previous load step's state (finer level: this one's, prolonged)
                    solution = contact.solve(
                        operator, samples, objective, coefficients, newton,
                        load_factor=t, start_load_factor=t if level else (
                            load_steps[k - 1] if k else 0.0), length=length, fixed=fixed,
                        linear_solver=solver, on_iteration=iterated)
            coefficients = solution.parameters
            u = displacement_at(operator, probe_xi, coefficients, t)[:, jets.VALUE]
            readings = {name: u[i].double().cpu().numpy() for i, name in enumerate(probes)}
            seconds = time.perf_counter() - started + (setup if k == 0 else 0.0)
            per_load.append(LevelSolution(grid.config.spans, t, solution.energy, readings,
                                          coefficients, solution.converged, seconds,
                                          solution.history))
            log.info("level %d (%d × %d spans), load %.4g: Π %.10g J in %d Newton steps, "
                     "%.2f s", level, *grid.config.spans, t, solution.energy,
                     len(solution.history), seconds)
            if on_load_step is not None:
                on_load_step(t)
        results.append(per_load)
        if on_level is not None:
            on_level(level, grid, per_load)
    return results
