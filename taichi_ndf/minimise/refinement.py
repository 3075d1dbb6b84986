"""Coarse-to-fine projected-Newton solves and refinement studies on a spline field.

`solve_levels` solves on K successively refined grids (exact dyadic refinement): level 0 by
load continuation from the undeformed state, each finer level at each load factor from the
coarser level's solution prolonged exactly (`SplineField.refined`), so a finer level starts
where the coarser one ended and takes few Newton steps. It reads Π and every probe per level
and load factor.

`richardson` extrapolates a quantity from its values on the last grids and bounds the error
of the result (one rule for every caller: `extrapolate_changes` works on the changes between
successive grids, signed for a scalar, a norm for a field of positions). It follows Roache's
grid convergence index (GCI; P. J. Roache, "Perspective: a method for uniform reporting of
grid refinement studies", J. Fluids Eng. 116 (1994) 405–413, and "Discussion: factors of
safety for Richardson extrapolation", J. Fluids Eng. 133 (2011) 115501): the extrapolation is
trusted only where the observed order is reasonable, with a safety factor Fs = 1.25; where it
is not, the bar falls back to a conservative one with Fs = 3. With three values v₀, v₁, v₂ on
grids h, h/2, h/4 (changes d₁ = v₁ − v₀, d₂ = v₂ − v₁):

- observed order p = log₂(d₁/d₂); the order is **reliable** where the changes fall
  monotonically (d₁/d₂ > 1), neither change is at the rounding level (|d| > `ROUNDING` ×
  max|v|) and `ORDER_MIN` ≤ p ≤ the expected order 2(p_deg − 1) (+ `ORDER_SLACK`, where one
  is given). Then
  v∞ = v₂ + d₂/(2ᵖ − 1) and the error is 1.25 |v∞ − v₂| (the interval reaches a quarter of
  the correction past v₂ on one side and 1.25 corrections past v∞ on the other); a warning
  is logged where p is below the expected order / `ORDER_FAR`.
- otherwise the order is **unreliable** (said so in the value's text and `order_basis`):
  v∞ = v₂ and the error is 3 Δ_M, Δ_M = max|vᵢ − vⱼ| the range of the three values (Eça and
  Hoekstra's data range, L. Eça and M. Hoekstra, J. Comput. Phys. 262 (2014) 104–130, with
  their Fs = 3 for data that do not converge monotonically). Not Roache's "p_th with Fs = 3"
  fallback, 3 |d₂|/(2^p_th − 1): where p is above the expected order the last change is
  small by coincidence (measured, benchmarks/RESULTS.md: cantilever_shear's tip at t = 0.1
  changes by 6.5e-6 then 6.4e-9, observed order 10, and the 64 × 16 value lies 4.8e-7 away,
  75× the last change), so no multiple of the last change bounds the error; the range does.
  For a field (norms of its differences) Δ_M is bounded by d₁ + d₂.

With two values the order cannot be observed: it is assumed (the expected order, required),
the value is extrapolated with it and the error is widened to the whole change |v₂ − v₁|
between the two grids (Roache's two-grid GCI, 3 |d|/(2^p − 1), is 0.2 |d| at p = 4: narrower;
measured: the napkin's two-grid bar at the assumed order 4 was 15× smaller than the change;
benchmarks/RESULTS.md, "Refinement error bars"). The text says "order assumed".
"""

from __future__ import annotations

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


ORDER_FAR = 2.0  # a reliable observed order below expected / ORDER_FAR warns
ORDER_MIN = 0.5  # an observed order below this is unreliable (2ᵖ − 1 → 0: the correction blows up)
# An observed order up to expected + ORDER_SLACK is reliable (Xing and Stern's and Eça and
# Hoekstra's p < 2.05 for a second-order method), so an exact power law of the expected order
# is not refused for its rounding.
ORDER_SLACK = 0.05
# A change at most this fraction of max|v| is not resolved: float32's Π rounding floor is
# about 1e-6 |Π| (spline_solver.newton_config), and in float64 at the default Newton tolerance
# cantilever_shear's tip stops converging near 1e-7 relative (benchmarks/RESULTS.md).
ROUNDING = 1e-6
SAFETY_OBSERVED = 1.25  # Roache's Fs for three grids with a reliable observed order
SAFETY_UNRELIABLE = 3.0  # Roache's Fs where the order cannot be trusted (times the range)
ORDER_BASES = ("observed", "assumed", "unreliable")


@dataclass(frozen=True)
class Extrapolation:
    """A refinement-extrapolated value and its error bar (the interval value ± error should
    hold the converged value), the order it used, and how it was found: basis "observed"
    (three or more grids, a reliable observed order), "assumed" (two grids: `order` is the
    expected one) or "unreliable" (three or more grids whose order cannot be trusted: value
    = the finest value, error = 3 × the range of the last three values; `order` the observed
    one or None, `reason` why; module docstring). grids: how many values; warning: a
    one-line caution or None."""

    value: float
    error: float
    order: float | None
    basis: str = "observed"
    grids: int = 3
    expected: float | None = None
    warning: str | None = None
    reason: str | None = None

    @property
    def assumed(self) -> bool:
        return self.basis == "assumed"

    @property
    def unreliable(self) -> bool:
        return self.basis == "unreliable"

    def describe(self, unit: str = "") -> str:
        """'v ± e unit (how)', the way every output shows the value."""
        unit = f" {unit}" if unit else ""
        return f"{self.value:.6g} ± {self.error:.2g}{unit} ({self.how()})"

    def how(self) -> str:
        """How the value was found, in words (shown beside it everywhere)."""
        if self.basis == "assumed":
            return (f"order {self.order:g} assumed from {self.grids} grids, error = the change "
                    "between them")
        if self.basis == "unreliable":
            return (f"order unreliable from {self.grids} grids ({self.reason}): finest value, "
                    "error = 3 × the range of the last three")
        expected = "" if self.expected is None else f", expected {self.expected:g}"
        return f"observed order {self.order:.2f} from {self.grids} grids{expected}"

    def to_dict(self) -> dict:
        return {"extrapolated": self.value, "estimated_error": self.error, "order": self.order,
                "order_basis": self.basis, "order_reason": self.reason, "grids": self.grids,
                "expected_order": self.expected, "warning": self.warning,
                "text": self.describe()}


@dataclass(frozen=True)
class OrderEstimate:
    """What the changes between successive grids say (`extrapolate_changes`): the order
    (observed, assumed, or the observed one that is not trusted; None where none can be
    computed), the correction v∞ − v_finest (0 where unreliable), the error bar, the basis,
    why an order is unreliable, and a warning."""

    order: float | None
    correction: float
    error: float
    basis: str
    reason: str | None = None
    warning: str | None = None


def _unreliable_reason(d1: float, d2: float, scale: float,
                       expected: float | None) -> tuple[float | None, str | None]:
    """The observed order of changes d₁, d₂ (None where the changes do not fall) and why it
    is not to be trusted (None: it is)."""
    ratio = d1 / d2 if d2 != 0.0 else math.inf
    observed = math.log2(ratio) if math.isfinite(ratio) and ratio > 1.0 else None
    if min(abs(d1), abs(d2)) <= ROUNDING * scale:
        return observed, f"a change at the rounding level, ≤ {ROUNDING:g} of the value"
    if observed is None:
        return None, "changes not falling monotonically"
    if observed < ORDER_MIN:
        return observed, f"observed order {observed:.2f} below {ORDER_MIN:g}"
    if expected is not None and observed > expected + ORDER_SLACK:
        return observed, f"observed order {observed:.2f} above the expected {expected:g}"
    return observed, None


def extrapolate_changes(changes: list[float], order: float | None = None,
                        scale: float = 0.0) -> OrderEstimate:
    """The order, correction and error bar of the finest value from the changes between
    successive grids refined by 2 each (signed differences of a scalar, or norms of a field's
    differences; the last two are used; module docstring). order: the expected order, assumed
    with one change and the upper limit of a reliable observed one with two or more. scale:
    the size of the values (max |v|) that the rounding level is relative to (0: no rounding
    check)."""
    if not changes:
        raise ValueError("richardson needs at least two values, got 1")
    last = changes[-1]
    if len(changes) == 1:
        if order is None:
            raise ValueError("two values need an assumed order")
        return OrderEstimate(order, last / (2.0**order - 1.0), abs(last), "assumed")
    d1, d2 = changes[-2:]
    observed, reason = _unreliable_reason(d1, d2, scale, order)
    if reason is not None:
        spread = max(abs(d1), abs(d2), abs(d1 + d2))  # the range of the three values
        warning = (f"refinement order unreliable ({reason}): the finest value with 3 × the "
                   "range of the last three grids as its error bar; refine further for an "
                   "extrapolation")
        return OrderEstimate(observed, 0.0, SAFETY_UNRELIABLE * spread, "unreliable",
                             reason, warning)
    correction = d2 / (2.0**observed - 1.0)
    warning = None
    if order is not None and observed < order / ORDER_FAR:
        warning = (f"observed refinement order {observed:.2f} is far below the expected "
                   f"{order:g}: the grids are not in the asymptotic range (a singularity or "
                   "an unresolved layer?); the error bar rests on the observed order")
    return OrderEstimate(observed, correction, SAFETY_OBSERVED * abs(correction), "observed",
                         None, warning)


def richardson(values: list[float], order: float | None = None) -> Extrapolation:
    """Richardson extrapolation of values on grids refined by 2 each, with a GCI-style error
    bar (module docstring). order: the expected convergence order, assumed with two values
    (required then) and the upper limit of a reliable observed order of the last three with
    three or more."""
    if len(values) < 2:
        raise ValueError(f"richardson needs at least two values, got {len(values)}")
    last = values[-3:]
    changes = np.diff(last).tolist()
    estimate = extrapolate_changes(changes, order, scale=max(abs(v) for v in last))
    if estimate.warning is not None:
        log.warning("%s", estimate.warning)
    return Extrapolation(values[-1] + estimate.correction, estimate.error, estimate.order,
                         estimate.basis, len(values), order, estimate.warning, estimate.reason)


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
