"""A spline field refined adaptively to a requested relative error (`ndf-sim --tolerance`):
the plan's first grid, its dyadic refinement, then equidistributed grids until the guarded
three-grid estimate of Π and of every probe is within the tolerance or the budget of unknowns
is spent (`taichi_ndf.solve.adaptive`)."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from taichi_ndf.discretise.protocol import OnLoadStep, Probes, Solution
from taichi_ndf.discretise.spline import SplineDiscretisation
from taichi_ndf.problem.model import ShellModel
from taichi_ndf.problem.spline_grid import SplinePlan
from taichi_ndf.problem.training import SolverConfig
from taichi_ndf.solve.adaptive import (
    CONTACT_REFUSED,
    AdaptiveConfig,
    AdaptiveRun,
    solve_adaptive,
    unknowns,
)


def adaptive(discretisation, config: AdaptiveConfig) -> AdaptiveDiscretisation:
    """The adaptive form of a scene's discretisation; ValueError (one line) where there is
    none: a SIREN field, obstacles."""
    if not isinstance(discretisation, SplineDiscretisation):
        raise ValueError("--tolerance needs a spline field (--field spline): a SIREN has no "
                         "grids to refine")
    if discretisation.model.contact is not None:
        raise ValueError(CONTACT_REFUSED)
    if discretisation.start_shape is not None:
        raise ValueError("--tolerance: an adaptive run starts from the rest shape; drop the "
                         "scene's [start] or --tolerance")
    return AdaptiveDiscretisation(discretisation.spec, discretisation.model, config,
                                  objective=discretisation.objective)


class AdaptiveDiscretisation(SplineDiscretisation):
    """`SplineDiscretisation` solved by `solve_adaptive`; the plan's `levels` are replaced by
    the adaptive sequence (its first grid is the plan's `config`)."""

    def __init__(self, spec: SplinePlan, model: ShellModel, adaptive_config: AdaptiveConfig,
                 *, objective=None):
        super().__init__(spec, model, objective=objective)
        self.adaptive = adaptive_config

    def check_size(self, config: SolverConfig, *, itemsize: int = 4) -> None:
        """The largest grid the budget allows, counted as the plan's grid refined while its
        unknowns stay within the budget (the adaptive grids have as many)."""
        plan = dataclasses.replace(self.spec, levels=1)
        while unknowns(plan.config.refined()) <= self.adaptive.max_unknowns:
            plan = dataclasses.replace(plan, config=plan.config.refined())
        SplineDiscretisation(plan, self.model).check_size(config, itemsize=itemsize)

    def start(self, config: SolverConfig, *, seed: int, resume_from: Path | None = None
              ) -> None:
        if resume_from is not None:
            raise ValueError("--tolerance: an adaptive run cannot be resumed (start it again)")
        super().start(config, seed=seed)

    def solve(self, config: SolverConfig, *, callbacks: Sequence[Any] = (),
              on_load_step: OnLoadStep | None = None,
              report: Callable[[str], None] | None = None) -> Solution:
        """`solve_adaptive`, a line to `report` per level and the estimate at the end."""
        per_level: list[dict[float, Probes]] = []

        def on_level(run) -> None:
            last = run.levels[-1]
            if config.progress and report is not None:
                report(f"level {last.level} ({last.spans[0]} × {last.spans[1]} spans, "
                       f"{unknowns(run.field.config)} unknowns): Π = {last.energy:.8g} J, "
                       f"{last.iterations} Newton iterations, {last.seconds:.1f} s")
            per_level.append({t: self._probes_of(run.field, c, t) for t, c in run.steps})

        run: AdaptiveRun = solve_adaptive(
            self.model, self.spec, config, self.adaptive, objective=self.objective,
            callbacks=callbacks, on_level=on_level, on_load_step=on_load_step)
        self.run = run
        refinement = run.refinement(self.spec.config.degree)
        if report is not None and refinement is not None:
            outcome = refinement["adaptive"]
            report(f"adaptive refinement: {outcome['outcome']} (tolerance "
                   f"{outcome['tolerance']:g}; {outcome.get('worst', 'no estimate')})")
            if "gauge" in outcome:
                report(f"adaptive refinement: {outcome['gauge']['line']}")
        last = run.state.levels[-1].level
        convergence = {t: ([i for i, level in enumerate(per_level) if t in level],
                           [level[t] for level in per_level if t in level])
                       for t in per_level[-1]}
        spans = [list(lv.spans) for lv in run.levels]
        return Solution(
            field=run.field, energy=run.energy, iterations=len(run.history),
            wall_time=run.wall_time, history=run.history, probes=run.probes,
            field_document={**self.spec.to_dict(), "levels": last + 1,
                            "finest_spans": list(run.field.config.spans),
                            "finest_grading": run.field.config.to_dict()["grading"]},
            document={"levels": [dataclasses.asdict(lv) for lv in run.levels],
                      "load_steps": run.load_steps, "refinement": refinement},
            refinement=refinement, convergence=convergence, newton_steps=len(run.history),
            settings={"method": "newton", "convergence_axis": "grid level",
                      "load_steps": list(config.load_steps), "spans": spans,
                      "newton_iterations": len(run.history), "field": self.spec.to_dict(),
                      "tolerance": self.adaptive.tolerance,
                      "max_unknowns": self.adaptive.max_unknowns})
