"""A B-spline field solved by projected Newton on fixed Gauss points per knot span, coarse to
fine over the plan's grids: `solve_spline` over the grid levels × load steps."""

from __future__ import annotations

import dataclasses
import logging
import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, ClassVar

import torch

from taichi_ndf import jets
from taichi_ndf.discretise.held_patches import held_patch_points
from taichi_ndf.discretise.protocol import (
    OnLoadStep,
    Probes,
    ResultPart,
    Solution,
    SolveRefused,
)
from taichi_ndf.discretise.start import fitted_start
from taichi_ndf.field import SplineField
from taichi_ndf.minimise.assembly import displacement_at
from taichi_ndf.minimise.linear_solve import LinearSolverConfig
from taichi_ndf.minimise.linearisation import GridLinearisation, SplineLinearisation
from taichi_ndf.minimise.state import State
from taichi_ndf.objective import Objective
from taichi_ndf.objective.seam import with_seam_points
from taichi_ndf.problem.field_types import SPLINE, FieldType
from taichi_ndf.problem.model import ShellModel
from taichi_ndf.problem.operator import DisplacementOperator
from taichi_ndf.problem.run_size import contact_check_points
from taichi_ndf.problem.sampling import SurfaceSamples, with_point_loads
from taichi_ndf.problem.spline_grid import SplinePlan
from taichi_ndf.problem.start_shape import StartShape
from taichi_ndf.problem.training import SolverConfig
from taichi_ndf.solve.spline_solver import SplineRun, solve_spline

log = logging.getLogger(__name__)


class SplineDiscretisation:
    """A `SplinePlan` on a model: its parameters are the coefficients (n, 3) of each grid,
    its energy is evaluated on the Gauss points of every knot span (`span_quadrature`,
    through `GridLinearisation.quadrature`).
    objective: what is minimised (None: Π of the model); estimate: unused (a spline's
    coefficients carry any scale); start_shape: where a fresh solve starts (None: the rest
    shape, zero coefficients; else `fitted_start` on the plan's first grid); dtype: the
    fields' (None: the runtime's; a start shape's fit makes its own)."""

    field_type: ClassVar[FieldType] = SPLINE
    name: ClassVar[str] = SPLINE.name

    def __init__(self, spec: SplinePlan, model: ShellModel, *,
                 objective: Objective | None = None, estimate: str | None = None,
                 start_shape: StartShape | None = None, dtype: torch.dtype | None = None):
        self.spec = spec
        self.model = model
        self.objective = objective
        self.start_shape = start_shape
        self.dtype = dtype
        self.state: State | None = None
        self.run: SplineRun | None = None

    def uses_newton(self, config: SolverConfig) -> bool:
        return True

    def check_size(self, config: SolverConfig, *, itemsize: int = 4) -> None:
        """The finest grid's Gauss points (f32 runs keep the Hessian work in f64: counted
        the same)."""
        SPLINE.check_size(self.spec, config, itemsize, **contact_check_points(self.model.contact))

    def refined(self, levels: int) -> SplineDiscretisation:
        if levels < 1:
            raise ValueError(f"--refine must be >= 1, got {levels}")
        return SplineDiscretisation(dataclasses.replace(self.spec, levels=levels), self.model,
                                    objective=self.objective, start_shape=self.start_shape,
                                    dtype=self.dtype)

    def with_displacement_unit(self, factor: float) -> SplineDiscretisation:
        return self

    def for_case(self, scene_solver: SolverConfig, quick_solver: SolverConfig, *,
                 quick: bool, solver: SolverConfig | None, iterations: int | None,
                 seed: int | None, levels: int) -> tuple[SplineDiscretisation, SolverConfig]:
        """The scene's own settings on `levels` grids (quick: one); the solver, the seed
        and Adam's iterations have no meaning here (iterations: ValueError)."""
        if iterations is not None:
            raise ValueError("--iterations sets Adam; the spline path solves by projected "
                             "Newton")
        return self.refined(1 if quick else levels), scene_solver

    def start(self, config: SolverConfig, *, seed: int, resume_from: Path | None = None
              ) -> None:
        """A resumed run goes on from the checkpoint's last finished level; a fresh one from
        the start shape's fit on the first grid (`fitted_start`), if any."""
        if config.method != "newton":
            raise ValueError("a spline field is solved with [training] method = \"newton\"")
        self.state = None
        if resume_from is not None:
            self.state = State.newton(None)
            self.state.restore(resume_from)
        elif self.start_shape is not None:
            self.state = State.newton(fitted_start(self.model, self.spec.config,
                                                   self.start_shape))
        else:  # as `solve_spline` starts without a state, in this discretisation's dtype
            self.state = State.newton(SplineField(self.spec.config, dtype=self.dtype))

    def solve(self, config: SolverConfig, *, callbacks: Sequence[Any] = (),
              on_load_step: OnLoadStep | None = None,
              report: Callable[[str], None] | None = None) -> Solution:
        """`solve_spline`, whose grid levels take their linearisation from `linearise` (with
        the run's linear solver); after each grid level a line to `report` (with
        `config.progress`) and on_load_step with a field per load step of that level."""
        per_level: list[dict[float, Probes]] = []

        def on_level(run: SplineRun) -> None:
            if config.progress and report is not None:
                last = run.levels[-1]
                report(f"level {last.level} ({last.spans[0]} × {last.spans[1]} spans): "
                       f"Π = {last.energy:.8g} J, {last.iterations} Newton iterations, "
                       f"{last.seconds:.1f} s")
            per_level.append({t: self._probes_of(run.field, c, t) for t, c in run.steps})
            if on_load_step is not None:
                for t, coefficients in run.steps:
                    field = SplineField(run.field.config)
                    field.coefficients.copy_(coefficients)
                    on_load_step(t, field)

        linear = LinearSolverConfig(kind=config.linear_solver)
        run = solve_spline(self.model, self.spec, config, objective=self.objective,
                           state=self.state, callbacks=callbacks, on_level=on_level,
                           linearise=lambda grid: self.linearise(grid, linear))
        self.run = run
        convergence = {t: (list(range(len(per_level))), [level[t] for level in per_level])
                       for t in per_level[-1] if all(t in level for level in per_level)}
        contact = None if run.contact is None else run.contact.points
        refinement = run.refinement(self.spec.config.degree)
        return Solution(
            field=run.field, energy=run.energy, iterations=len(run.history),
            wall_time=run.wall_time, history=run.history, probes=run.probes,
            field_document={**self.spec.to_dict(),
                            "finest_spans": list(run.field.config.spans)},
            document={"levels": [dataclasses.asdict(lv) for lv in run.levels],
                      "load_steps": run.load_steps,  # Π and probes per load step, finest
                      "refinement": refinement},
            refinement=refinement, contact=contact,
            contact_counts={} if run.contact is None else {"newton_rounds": run.contact.rounds},
            convergence=convergence, newton_steps=len(run.history),
            settings={"method": "newton", "convergence_axis": "grid level",
                      "load_steps": list(config.load_steps),
                      "spans": [list(lv.spans) for lv in run.levels],
                      "newton_iterations": len(run.history), "field": self.spec.to_dict()})

    def check_solution(self, solution: Solution) -> None:
        """Not converged on the finest grid: logged; no step taken on any grid: refused."""
        run = self.run
        if run.levels[-1].converged:
            return
        if not any(record.step_length > 0 for record in run.history):
            finest = run.levels[-1]
            decrement = f"λ² = {run.history[-1].decrement:.3g} J, " if run.history else ""
            # Seen on a free-pinned napkin on 1 × 1 spans: the first Newton step follows the
            # rotation about the pin, which the flat state does not resist (λ² = 3.8e9 J),
            # and no step length of the line search lowers Π.
            raise SolveRefused(
                f"projected Newton took no step on any grid (finest {finest.spans[0]} × "
                f"{finest.spans[1]} spans; {decrement}no step length lowered Π), so the result "
                f"would be the start, Π = {finest.energy:.6g} J; try a finer grid (omit [field] "
                "spans for the grid rule) or more load steps")
        log.warning("projected Newton did not converge on the finest grid (see result.json "
                    "history)")

    def probes(self, field: SplineField, load_factor: float) -> Probes:
        return self._probes_of(field, field.coefficients, load_factor)

    def _probes_of(self, field: SplineField, coefficients: torch.Tensor,
                   load_factor: float) -> Probes:
        """The probes of `field`'s grid with `coefficients` (n, 3) at a load factor."""
        probes = self.model.probes
        if not probes:  # nothing to evaluate (a free pin's raw jets need at least one point)
            return {}
        operator = DisplacementOperator(field, self.model.boundary)
        xi = torch.tensor([p.xi for p in probes], dtype=coefficients.dtype).reshape(-1, 2)
        u = displacement_at(operator, xi, coefficients, load_factor)[:, jets.VALUE]
        return {p.name: [float(v) for v in u[k]] for k, p in enumerate(probes)}

    def energy_at(self, load_factor: float) -> float:
        raise ValueError("a spline field has no pseudo-time path: its Π per load step is in "
                         "the solution's document (\"load_steps\")")

    @property
    def field(self) -> SplineField:
        """The current grid with its coefficients: the solution's after `solve`, else the
        checkpoint's or the plan's first grid (zero coefficients) that `start` made."""
        if self.run is not None:
            return self.run.field
        if self.state is not None:
            return self.state.field
        return SplineField(self.spec.config, dtype=self.dtype)

    def evaluation_points(self) -> SurfaceSamples:
        """The grid's Gauss points per knot span, or where handles hold patches at the domain's
        corners the domain outside them (`held_patches`: the rims integrated exactly)."""
        field = self.field
        dtype = field.coefficients.dtype
        trimmed = held_patch_points(self.model.boundary, field.config)
        if trimmed is None:
            samples = GridLinearisation.quadrature(
                self.model.surface, field.config, self.model.loads,
                points=self.spec.quadrature_points, dtype=dtype)
        else:
            samples = with_point_loads(self.model.surface, trimmed[0].to(dtype),
                                       trimmed[1].to(dtype), self.model.loads)
        return with_seam_points(samples, self.model.terms)

    def displacement(self, xi: torch.Tensor, load_factor: float) -> torch.Tensor:
        field = self.field
        operator = DisplacementOperator(field, self.model.boundary)
        return displacement_at(operator, xi, field.coefficients, load_factor)

    def linearisation(self, samples: SurfaceSamples, load_factor: float
                      ) -> SplineLinearisation:
        """Built as a grid level of `solve_spline` builds it (`minimise.refinement.GridLevels`:
        the one builder, `GridLinearisation`), with the default linear solver of its grid;
        length: the domain's √area [m]."""
        return self.linearise(self.field).linearisation(load_factor, samples)

    def linearise(self, field: SplineField,
                  linear: LinearSolverConfig | None = None) -> GridLinearisation:
        """The linearisation builder of a grid of this discretisation (`field`'s), the one
        that its solve's grid levels (`solve_spline`, `GridLevels`) and `linearisation` use:
        the model's boundary, the domain's √area [m] as the FD length, linear: the linear
        solver's settings (None: the default's)."""
        return GridLinearisation(field, self.model.boundary,
                                 length=math.sqrt(self.model.surface.domain.rectangle_area),
                                 linear=linear or LinearSolverConfig())

    def result_parts(self, field: SplineField) -> tuple[ResultPart, ...]:
        """One surface: the model with `field` (a grid of this discretisation)."""
        return (ResultPart("", self.model, field),)
