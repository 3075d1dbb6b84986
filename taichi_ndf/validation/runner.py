"""Running a validation case: train its field and read its quantities
(`taichi_ndf.validation.catalogue` says what a case is)."""

from __future__ import annotations

import dataclasses
import logging
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from taichi_ndf import jets, runtime
from taichi_ndf.boundary.rigid_motions import warn_rigid_motions
from taichi_ndf.discretise import Discretisation, discretisation
from taichi_ndf.minimise.callbacks import DivergenceGuard
from taichi_ndf.objective import EndMomentTerm, Objective
from taichi_ndf.problem.model import ShellModel
from taichi_ndf.scene.reader import Scene, load_scene
from taichi_ndf.solve.solver import SolverConfig
from taichi_ndf.validation.catalogue import LINEARISATION, SCENES_DIR, Case, Readings

log = logging.getLogger(__name__)

# Grids of the spline path: the grid rule's, then two dyadic refinements (benchmarks/RESULTS.md).
SPLINE_LEVELS = 3


@dataclass
class Row:
    """One line of the results table."""

    case: str
    quantity: str
    description: str
    level: float
    computed: float | None  # None: the level was not part of the run (e.g. --quick)
    reference: float
    relative_error: float | None
    tolerance: float
    passed: bool | None
    iterations: int  # Adam iterations, all load steps
    wall_time: float  # [s] of the whole case
    samples: int  # per Adam iteration
    newton_steps: int = 0  # last-layer Newton steps, all phases
    newton_samples: int = 0  # fixed samples of the Newton phases (0: no Newton)
    source: str = ""  # where the reference comes from


@dataclass
class CaseResult:
    case: Case
    rows: list[Row]
    # value of each quantity (keyed "name @ level") against the iteration count
    convergence: dict[str, tuple[list[int], list[float]]] = field(default_factory=dict)
    solver: dict = field(default_factory=dict)


def load_case_scene(case: Case, scenes_dir: Path = SCENES_DIR, field: str | None = None
                    ) -> tuple[Scene, ShellModel, object]:
    """The case's scene, its model with the case's load scale, and the field configuration.
    field: "spline" or "siren" to solve the case with that field (`load_scene`)."""
    scene = load_scene(Path(scenes_dir) / case.scene, field=field)
    model = scene.model
    field_config = scene.field
    loads = model.loads.scaled(case.load_scale)
    if case.membrane_scale != 1.0:
        material = model.material
        model = model.with_material(material.with_stiffness(
            membrane_stiffness=material.membrane_stiffness * case.membrane_scale))
    if case.linear:
        loads = loads.scaled(1 / LINEARISATION)
        model = model.with_material(model.material.scaled(LINEARISATION**-2))
    if case.linear:  # a SIREN's output scale follows the displacements' unit
        field_config = discretisation(field_config, model).with_displacement_unit(
            LINEARISATION).spec
    return scene, model.with_loads(loads), field_config


@dataclass
class CaseSolve:
    """What one solve of a case gives its table, whichever the field: the probe readings
    (displacement [m] by name, linearised units undone) per load factor of the final field,
    the convergence series per load factor (its axis: Adam iterations or grid levels, and the
    readings along it), the counts for the rows, the wall time [s] and the settings."""

    final: dict[float, Readings]
    series: dict[float, tuple[list[int], list[Readings]]]
    iterations: int  # Adam iterations, all load steps (0 on the Newton path)
    newton_steps: int  # last-layer Newton steps, or projected-Newton iterations
    samples: int  # per Adam iteration (0 on the Newton path)
    newton_samples: int
    wall_time: float
    solver: dict


def run_case(case: Case, *, quick: bool = False, solver: SolverConfig | None = None,
             iterations: int | None = None, scenes_dir: Path = SCENES_DIR,
             seed: int | None = None, field: str | None = None,
             levels: int = SPLINE_LEVELS) -> CaseResult:
    """Solve the case and read its quantities (one table for both fields).

    quick: use the scene's [training.quick] settings (the spline path: one grid); solver:
    explicit settings instead (SIREN). iterations: Adam iterations per load step (overrides
    the settings). seed: field initialisation and sampling seed (default: the scene's).
    field: "spline" to solve the case with a spline field by projected Newton on `levels`
    grids, "siren" with the SIREN by Adam; None: the field the case's scene names (its
    `[field] type`, with its own keys), as `ndf-sim` does. The field's discretisation
    (`taichi_ndf.discretise`, `Discretisation.for_case`) chooses its settings and solves it.
    """
    # None: the scene's own field (with its keys, e.g. a spline's spans), as `ndf-sim` does
    scene, model, field_config = load_case_scene(case, scenes_dir, field)
    names = [p.name for p in model.probes]
    for q in case.quantities:
        missing = [p for p in q.probes if p not in names]
        if missing:
            raise ValueError(f"case {case.name}: quantity {q.name} reads probe(s) "
                             f"{', '.join(missing)} that the scene {case.scene} does not "
                             f"define (its probes: {', '.join(names) or 'none'})")
    objective = _objective(case, model)
    unit = LINEARISATION if case.linear else 1.0
    case_discretisation, config = discretisation(
        field_config, model, objective=objective, estimate=scene.output_scale_estimate
    ).for_case(scene.solver, scene.quick_solver, quick=quick, solver=solver,
               iterations=iterations, seed=seed, levels=levels)
    solved, load_steps = _solve(case_discretisation, model, config, unit)
    solved.solver["load_scale"] = case.load_scale
    positions = _reference_positions(model, runtime.current().dtype)  # the fields' dtype
    rows, convergence = [], {}
    for q in case.quantities:
        key = _level_key(q.level, load_steps)
        computed = None if key is None else q.read(solved.final[key], positions)
        error = None if computed is None else abs(computed - q.reference) / abs(q.reference)
        rows.append(Row(case=case.name, quantity=q.name, description=q.description,
                        level=q.level, computed=computed, reference=q.reference,
                        relative_error=error, tolerance=q.tolerance,
                        passed=None if error is None else error <= q.tolerance,
                        iterations=solved.iterations, wall_time=solved.wall_time,
                        samples=solved.samples, newton_steps=solved.newton_steps,
                        newton_samples=solved.newton_samples, source=q.source))
        if key is not None and key in solved.series:
            axis, readings = solved.series[key]
            convergence[f"{q.name} @ {q.level:g}"] = (
                list(axis), [q.read(r, positions) for r in readings])
    log.info("%s (%s): %d iterations, %d Newton steps in %.1f s", case.name,
             case_discretisation.name,
             solved.iterations, solved.newton_steps, solved.wall_time)
    return CaseResult(case=case, rows=rows, convergence=convergence, solver=solved.solver)


def _solve(case: Discretisation, model: ShellModel, config: SolverConfig, unit: float
           ) -> tuple[CaseSolve, tuple[float, ...]]:
    """The case solved on its discretisation with the divergence guard as the callback:
    readings (linearised units undone) after each load step of the final field (a spline:
    of the finest grid), and the convergence series per load factor (Adam: the monitor
    records; a spline: the grid levels)."""
    config = dataclasses.replace(config, progress=False)
    case.check_size(config)
    warn_rigid_motions(model, newton=case.uses_newton(config))
    case.start(config, seed=config.seed)
    final: dict[float, Readings] = {}

    def readings(probes: dict[str, list[float]]) -> Readings:
        return {n: np.asarray(v, dtype=np.float64) / unit for n, v in probes.items()}

    def on_load_step(load_factor: float, field) -> None:
        final[load_factor] = readings(case.probes(field, load_factor))

    start = time.perf_counter()
    solution = case.solve(config, callbacks=[DivergenceGuard()], on_load_step=on_load_step)
    wall = time.perf_counter() - start
    series = {t: (axis, [readings(p) for p in probes])
              for t, (axis, probes) in solution.convergence.items()}
    return CaseSolve(
        final, series, solution.adam_iterations, solution.newton_steps, solution.samples,
        solution.newton_samples, wall, solution.settings), config.load_steps


def _reference_positions(model: ShellModel, dtype) -> dict[str, np.ndarray]:
    """Each probe's undeformed position (3,) [m] by name."""
    xi = torch.tensor([p.xi for p in model.probes], dtype=dtype).reshape(-1, 2)
    r = model.surface.jets(xi)[:, jets.VALUE]
    return {p.name: r[k].double().numpy() for k, p in enumerate(model.probes)}


def _objective(case: Case, model: ShellModel) -> Objective:
    """Π of the case: the model's, plus the end moment's work for the roll-up."""
    objective = Objective.of_model(model)
    if case.end_moment is None:
        return objective
    width = model.surface.domain.lengths[1]
    return objective.with_terms(EndMomentTerm(case.end_moment(model), width))


def _level_key(level: float, load_steps: tuple[float, ...]) -> float | None:
    for step in load_steps:
        if abs(step - level) < 1e-9:
            return step
    return None
