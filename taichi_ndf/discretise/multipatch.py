"""Several spline patches (a garment's panels) solved in one projected Newton, behind the
`Discretisation` protocol: `MultiPatchDiscretisation`.

Each patch is a `ShellModel` of its own (surface, boundary conditions, line loads) with a
spline grid (`SplineConfig`); seams join an edge of one patch to an edge of another
(`SeamTerm` with `surface_b`, its points looked up in each patch's rows: `SeamTerm.between`).
Every load step minimises Π = Σ_patches Π_shell + Σ_seams Π_seam over the joint coefficients
by projected Newton on the joined linearisation (`minimise.multipatch.MultiPatchLinearisation`:
block-diagonal K, the seams' pair couplings across patches); the load factor ramps gravity and
sews the seams, as on one patch. One grid per patch (no coarse-to-fine levels), a material per
patch (one `ShellEnergyTerm` over the joined points where all are the same, else a
`PanelEnergy` of one per patch, built on each contact round's points) and one gravity for all
patches, float64.
With obstacles each load step is the contact rounds over all patches at once
(`discretise.panel_contact`), flat-cut panels included (their held edges clamped and their
seams sewn from the start in every round).
The load steps are the steps of the one continuation loop (`minimise.continuation.solve_over`:
a step's Newton is its `Stages.solve`, the step record its `after_step`, the rollback on Ctrl-C
its `interrupted`). The application's callbacks (`minimise.callbacks`) see a `PanelsRun` as
`solver`: on_start,
on_record at every Newton iteration (the divergence guard), on_load_step, on_resume_point
after each load step and on Ctrl-C (a `CheckpointWriter` writes the run's `State`: the panels'
coefficients, `PanelFields`, and the finished load steps) and on_end; `start` resumes from
such a checkpoint, and the resumed run goes on from the last finished load step bit for bit
(not with obstacles: the contact rounds' state is not in the checkpoint).
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import torch

from taichi_ndf import jets
from taichi_ndf.discretise.held_edges import HeldEdges, held_moves
from taichi_ndf.discretise.panel_contact import inside, outside_step, panel_contact, seams_at
from taichi_ndf.discretise.panel_energy import PanelEnergy, SewnFromStart
from taichi_ndf.discretise.protocol import (
    OnLoadStep,
    Probes,
    ResultPart,
    Solution,
    SolveRefused,
)
from taichi_ndf.discretise.start import fitted_start
from taichi_ndf.discretise.trimmed import patch_grid
from taichi_ndf.field import SplineField
from taichi_ndf.field.panels import PanelFields
from taichi_ndf.minimise.assembly import displacement_at
from taichi_ndf.minimise.callbacks import call
from taichi_ndf.minimise.checkpoint import CheckpointError
from taichi_ndf.minimise.continuation import Hook, Stages, solve_over
from taichi_ndf.minimise.linearisation import GridLinearisation
from taichi_ndf.minimise.minimisers import Hooks, NewtonMinimiser, Phase, run_phases
from taichi_ndf.minimise.multipatch import MultiPatchLinearisation
from taichi_ndf.minimise.state import State
from taichi_ndf.objective import Objective, ShellEnergyTerm
from taichi_ndf.objective.seam import SeamTerm
from taichi_ndf.problem.loads import Loads
from taichi_ndf.problem.model import ShellModel
from taichi_ndf.problem.multipatch import MultiPatchPlan, Patch, PatchSeam
from taichi_ndf.problem.operator import DisplacementOperator
from taichi_ndf.problem.training import SolverConfig
from taichi_ndf.solve.spline_solver import newton_config

__all__ = ["MultiPatchDiscretisation", "MultiPatchPlan", "Patch", "PatchSeam"]

log = logging.getLogger(__name__)

DTYPE = torch.float64
# The most unknowns (3 × coefficients over all patches) of one joint K (`check_size`).
MAX_UNKNOWNS = 2_000_000


@dataclass
class PanelsRun:
    """The `solver` the callbacks are called with: the joint field, its state (method
    "newton", field the panels' `PanelFields`: `minimise.state.State`), the config."""

    field: PanelFields
    state: State
    config: SolverConfig


class MultiPatchDiscretisation:
    """A `MultiPatchPlan` solved by projected Newton over all patches at once (module
    docstring). objective, estimate: not supported (None)."""

    field_type: ClassVar[Any] = None
    name: ClassVar[str] = "multipatch"
    dtype: ClassVar[torch.dtype] = DTYPE

    def __init__(self, spec: MultiPatchPlan, model: ShellModel | None = None, *,
                 objective: Objective | None = None, estimate: str | None = None):
        if objective is not None:
            raise ValueError("a multi-patch discretisation minimises Π of its patches only")
        self.spec = spec
        self.model = model or spec.patches[0].model
        self.fields: list[SplineField] | None = None
        self.state: State | None = None
        self.converged: list[bool] = []
        self._linear: MultiPatchLinearisation | None = None

    def uses_newton(self, config: SolverConfig) -> bool:
        return True

    def check_size(self, config: SolverConfig, *, itemsize: int = 4) -> None:
        """ValueError where the patches' unknowns together exceed `MAX_UNKNOWNS` (the joint
        K is one sparse matrix of 3 Σ n_i rows)."""
        total = sum(3 * math.prod(p.config.spans[i] + p.config.degree for i in range(2))
                    for p in self.spec.patches)
        if total > MAX_UNKNOWNS:
            raise ValueError(f"the panels have {total} unknowns together, more than "
                             f"{MAX_UNKNOWNS}; use fewer spans")

    def refined(self, levels: int) -> MultiPatchDiscretisation:
        if levels != 1:
            raise ValueError("--refine: a multi-patch field is solved on one grid per patch")
        return self

    def with_displacement_unit(self, factor: float) -> MultiPatchDiscretisation:
        return self

    def for_case(self, scene_solver: SolverConfig, quick_solver: SolverConfig, *,
                 quick: bool, solver: SolverConfig | None, iterations: int | None,
                 seed: int | None, levels: int) -> tuple[MultiPatchDiscretisation, SolverConfig]:
        raise ValueError("a multi-patch field is not a validation case")

    def start(self, config: SolverConfig, *, seed: int, resume_from: Path | None = None
              ) -> None:
        """Zero coefficients on every patch (its rest shape), or a flat-cut patch's start
        shape (its placement) fitted by its coefficients (`fitted_start`); or a checkpoint's
        state (`State.save` of a garment's run): its panels' coefficients and finished load
        steps (CheckpointError where it holds other panels or grids, or load steps other than
        the first of `config.load_steps`, or the garment has obstacles)."""
        if config.method != "newton":
            raise ValueError("a multi-patch field is solved with [training] method = \"newton\"")
        fields = [SplineField(p.config, dtype=DTYPE) if p.start is None
                  else fitted_start(p.model, p.config, p.start, dtype=DTYPE)
                  for p in self.spec.patches]
        self._start = torch.cat([f.coefficients.detach() for f in fields])
        self.state = State.newton(PanelFields.of([p.name for p in self.spec.patches], fields))
        if resume_from is not None:
            if self.model.contact is not None:
                raise CheckpointError("--resume: a garment run with obstacles cannot be "
                                      "resumed yet (the contact rounds' state is not in its "
                                      "checkpoint); start it again")
            ours = self.state.field.config
            self.state.restore(resume_from)
            stored = self.state.field
            if not isinstance(stored, PanelFields) or stored.config != ours:
                what = (f"panels {list(stored.config.names)}" if isinstance(stored, PanelFields)
                        else f"a {type(stored).__name__}")
                raise CheckpointError(f"{resume_from} holds {what}, not this garment's panels "
                                      f"{list(ours.names)} on their grids")
            done = [s["load_factor"] for s in self.state.steps]
            if done != list(config.load_steps[:len(done)]):
                raise CheckpointError(f"{resume_from} finished the load steps {done}, not the "
                                      f"first of {list(config.load_steps)}; resume it with its "
                                      "own [training] load_steps")
            fields = list(stored.fields)
        self.fields = fields
        self._targets = [None if p.held_target is None
                         else fitted_start(p.model, p.config, p.held_target, dtype=DTYPE)
                         for p in self.spec.patches]

    def _grids(self) -> tuple[list[GridLinearisation], list[SeamTerm]]:
        """Each patch's grid assembled on its Gauss points and the seam points on it, and the
        seam terms (before `between`)."""
        patches = self.spec.patches
        seams = [SeamTerm(s.spec, patches[s.a].model.surface, self.spec.seam_material(s),
                          surface_b=patches[s.b].model.surface) for s in self.spec.seams]
        grids = []
        for i, (patch, field) in enumerate(zip(patches, self.fields, strict=True)):
            grid, points = patch_grid(patch, field, dtype=DTYPE)  # trimmed to an outline
            for seam, term in zip(self.spec.seams, seams, strict=True):
                if seam.a == i:
                    points = points.joined(term.points(0))
                if seam.b == i:
                    points = points.joined(term.points(1))
            grid.assemble(points)
            grids.append(grid)
        return grids, seams

    def solve(self, config: SolverConfig, *, callbacks: Sequence[Any] = (),
              on_load_step: OnLoadStep | None = None,
              report: Callable[[str], None] | None = None) -> Solution:
        """Each load step's Newton over the joint coefficients, from the last step's."""
        started = time.perf_counter()
        grids, seams = self._grids()
        linear = self._joined(grids, 1.0)
        terms = tuple(term.between(linear.rows(s.a), linear.rows(s.b))
                      for s, term in zip(self.spec.seams, seams, strict=True))
        loads, materials = Loads(gravity=self.spec.gravity), self.spec.materials
        one = ShellEnergyTerm(materials[0], loads) if len(set(materials)) == 1 else None
        def shell_at(linear):  # the shell term over each panel's rows of linear's samples
            return one if one is not None else PanelEnergy(
                materials, loads, [linear.rows(i) for i in range(len(materials))])
        shell = shell_at(linear)
        c = torch.cat([f.coefficients.detach() for f in self.fields])
        sewn = self._start if any(p.start is not None for p in self.spec.patches) else None
        if sewn is not None:  # sewn from the placement
            start = linear.displacement(sewn)
            objective = Objective(shell, tuple(SewnFromStart(t, start) for t in terms))
        else:
            objective = Objective(shell, terms)
        newton = newton_config(config, DTYPE)
        contact = None
        if self.model.contact is not None:
            contact, self._points = panel_contact(self.spec, self.model, grids, self._joined,
                                                  self._start, seams)
        state = self.state  # fresh, or a checkpoint's: its finished load steps
        run = PanelsRun(self.field, state, config)
        history, steps = state.history, state.steps
        self.converged = [s["converged"] for s in steps]
        energy = steps[-1]["energy"] if steps else math.nan
        if state.load_step == len(config.load_steps):  # a finished run's: nothing to solve
            linear = self._joined(grids, config.load_steps[-1])

        def iterated(record) -> None:
            call(callbacks, "on_record", run, record.energy, record.gradient_norm,
                 record.load_factor)
            history.append(record)
            state.iteration = len(history)

        state.iteration = len(history)
        moves = held_moves(self.spec.patches, self._targets, linear, self._start)
        previous = steps[-1]["load_factor"] if steps else 0.0  # the contact rounds start there

        def moved(t: float) -> torch.Tensor:  # c, its held rows moved on from previous to t
            if moves is None:
                return c
            held, first, target = moves
            out = c.clone()
            step = min(max(t, 0.0), 1.0) - min(max(previous, 0.0), 1.0)
            out.reshape(-1)[held] += step * (target - first)
            return out

        def next_value(_index, _result) -> float | None:  # the scene's next load step, cut
            goal = next((s for s in config.load_steps if s > previous), None)  # where the
            if goal is None or moves is None or contact is None:  # held rows' move would
                return goal  # start the rounds inside an obstacle (`outside_step`)
            before = max((s for s in config.load_steps if s < goal), default=0.0)
            return outside_step(previous, goal, goal - before, lambda t: inside(
                self.spec, contact[0], contact[1], moved(t), t,
                "where its held edges are moved to"))

        def solve(step, _start):  # one load step's Newton (or contact rounds) from c
            nonlocal c, linear, previous
            t = step.value
            linear = self._joined(grids, t)
            c = moved(t)  # the held rows moved towards their targets (no step)
            phase = Phase(NewtonMinimiser(newton, load_factor=t),
                          objective=lambda linear=linear: (linear, objective.potential(t)),
                          parameters=lambda c=c: c, hooks=Hooks(on_iteration=iterated),
                          stage=(f"Newton, {len(self.fields)} panels, load factor {t:g}",
                                 newton.max_iterations))
            if contact is not None:  # the contact rounds over the joint chart
                phase.minimiser = contact[0].minimiser(newton, load_factor=t,
                                                       start_load_factor=previous,
                                                       terms_at=seams_at(self.spec, seams, sewn),
                                                       base_at=lambda r: Objective(shell_at(r)))
                phase.objective = lambda: contact[1:] + (None,)  # Π: per round, base_at
            solution, = run_phases([phase])
            previous = t
            return solution

        def stepped(step, solution) -> None:  # the step's record, the fields set to it
            nonlocal c, energy
            c, energy = solution.parameters, solution.energy
            self.converged.append(solution.converged)
            if not solution.converged and step.value < config.load_steps[-1]:
                log.warning("projected Newton did not converge at load factor %g of the panels "
                            "(%d iterations, Π %.6g J); the next load step starts from there",
                            step.value, len(solution.history), energy)
            steps.append({"load_factor": step.value, "energy": energy,
                          "iterations": len(solution.history),
                          "converged": solution.converged})
            self._set(c, linear)
            state.load_step += 1

        def resume_point(t: float) -> None:  # after the callbacks' on_load_step
            call(callbacks, "on_resume_point", run)
            if config.progress and report is not None:
                last = steps[-1]
                report(f"load factor {t:g}: Π = {energy:.8g} J, {last['iterations']} "
                       f"Newton iterations, converged {last['converged']}")
            if on_load_step is not None:
                on_load_step(t, self.field)

        def interrupted() -> None:  # the fields hold the last finished load step's solution
            del history[sum(s["iterations"] for s in steps):]
            state.iteration = len(history)
            call(callbacks, "on_resume_point", run)

        solve_over(Stages(solve, after_step=stepped, interrupted=interrupted), (),
                   first_step=state.load_step, subject=run, next_value=next_value,
                   callbacks=(*callbacks, Hook("on_load_step", resume_point)))
        if contact is not None:  # the grids back on their Gauss and seam points (seam_gaps)
            for grid, points in zip(grids, self._points, strict=True):
                grid.assemble(points)
            linear = self._joined(grids, config.load_steps[-1])
        self._linear = linear
        self._terms = terms
        wall = time.perf_counter() - started
        probes = self.probes(self.field, config.load_steps[-1])
        return Solution(
            field=self.field, energy=energy, iterations=len(history), wall_time=wall,
            history=history, probes=probes, field_document=self.spec.to_dict(),
            document={"load_steps": list(steps),
                      "seam_gaps": self.seam_gaps()},
            newton_steps=len(history), contact=None if contact is None else contact[0].points,
            contact_counts={} if contact is None else {"newton_rounds": contact[0].rounds},
            settings={"method": "newton", "load_steps": list(config.load_steps),
                      "field": self.spec.to_dict()})

    def _set(self, c: torch.Tensor, linear: MultiPatchLinearisation) -> None:
        for i, f in enumerate(self.fields):
            f.coefficients.data.copy_(
                c[linear.coefficient_offsets[i]:linear.coefficient_offsets[i + 1]])

    def seam_gaps(self) -> dict[str, float]:
        """Each seam's largest gap |x_A − x_B| [m] at its Gauss points, after `solve`."""
        linear = self._linear
        c = torch.cat([f.coefficients.detach() for f in self.fields])
        u = linear.displacement(c)
        return {t.spec.name: float(t.gaps(linear.samples, u).max()) for t in self._terms}

    def check_solution(self, solution: Solution) -> None:
        """No Newton step on any load step: refused; the last step not converged: logged."""
        if not any(h.step_length > 0 for h in solution.history):
            raise SolveRefused("projected Newton took no step on any load step of the panels, "
                               f"so the result would be the start, Π = {solution.energy:.6g} J")
        if not self.converged[-1]:
            log.warning("projected Newton did not converge at the last load step of the "
                        "panels (see result.json history)")

    @property
    def field(self) -> PanelFields:
        """The panels' fields under their names: the run state's (after `start`), shared with
        the solve (`self.fields`)."""
        return self.state.field

    def probes(self, field: PanelFields, load_factor: float) -> Probes:
        """Each patch's probes, named "panel.probe"."""
        out: Probes = {}
        for patch, f in zip(self.spec.patches, field.fields, strict=True):
            probes = patch.model.probes
            if not probes:
                continue
            xi = torch.tensor([p.xi for p in probes], dtype=DTYPE).reshape(-1, 2)
            u = displacement_at(DisplacementOperator(f, patch.model.boundary), xi,
                                f.coefficients, load_factor)[:, jets.VALUE]
            out.update({f"{patch.name}.{p.name}": [float(v) for v in u[k]]
                        for k, p in enumerate(probes)})
        return out

    def energy_at(self, load_factor: float) -> float:
        raise ValueError("a multi-patch field has no pseudo-time path")

    def evaluation_points(self):
        """The joined points of all patches (after `solve`)."""
        return self._linear.samples

    def displacement(self, xi: torch.Tensor, load_factor: float) -> torch.Tensor:
        raise ValueError("a multi-patch field's ξ is per patch: use displacement_of(patch, xi)")

    def displacement_of(self, patch: int, xi: torch.Tensor, load_factor: float = 1.0
                        ) -> torch.Tensor:
        """Displacement jets (N, 6, 3) [m] of patch `patch` at its ξ (N, 2)."""
        f, model = self.fields[patch], self.spec.patches[patch].model
        return displacement_at(DisplacementOperator(f, model.boundary), xi.to(DTYPE),
                               f.coefficients, load_factor)

    def linearisation(self, samples, load_factor: float) -> MultiPatchLinearisation:
        """The joined linearisation of the patches at their own points (`samples` must be
        `evaluation_points()`)."""
        if samples is not self._linear.samples:
            raise ValueError("a multi-patch linearisation is built on its own points "
                             "(evaluation_points())")
        return self._joined(self._linear.grids, load_factor)

    def _joined(self, grids, load_factor: float) -> MultiPatchLinearisation:
        """The patches' joined linearisation with the held edges' unknowns held too."""
        return HeldEdges(grids, load_factor, self.spec.patches)

    def result_parts(self, field: PanelFields) -> tuple[ResultPart, ...]:
        """One part per panel, named by it, in the plan's order, with the seams between
        outline edges (`MultiPatchPlan.outline_seams`)."""
        seams = self.spec.outline_seams()
        return tuple(ResultPart(p.name, p.model, f, seams)
                     for p, f in zip(self.spec.patches, field.fields, strict=True))
