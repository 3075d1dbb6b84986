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
from taichi_ndf.callbacks import DivergenceGuard
from taichi_ndf.field import FieldConfig, NeuralField
from taichi_ndf.model import ShellModel
from taichi_ndf.objective import EndMomentTerm, Objective
from taichi_ndf.output_scale import field_for_run
from taichi_ndf.run_size import check_run_size
from taichi_ndf.scene import Scene, load_scene
from taichi_ndf.solver import Solver, SolverConfig
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
    if case.linear and isinstance(field_config, FieldConfig):
        field_config = dataclasses.replace(
            field_config, output_scale=field_config.output_scale * LINEARISATION)
    return scene, model.with_loads(loads), field_config


def _own_spline(case: Case, scenes_dir: Path) -> bool:
    """Whether the case's scene itself asks for a spline field ([field] type = "spline")."""
    from taichi_ndf.spline_grid import SplinePlan

    return isinstance(load_scene(Path(scenes_dir) / case.scene).field, SplinePlan)


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
    grids (`_solve_spline`), "siren" with the SIREN by Adam (`_solve_siren`); None: the field
    the case's scene names (its `[field] type`), as `ndf-sim` does.
    """
    own = _own_spline(case, scenes_dir)
    field = field or ("spline" if own else "siren")
    if field == "spline" and iterations is not None:
        raise ValueError("--iterations sets Adam; the spline path solves by projected Newton")
    # A scene with its own spline field keeps its keys (spans, degree, quadrature points).
    scene, model, field_config = load_case_scene(
        case, scenes_dir, None if field == "spline" and own else field)
    names = [p.name for p in model.probes]
    for q in case.quantities:
        missing = [p for p in q.probes if p not in names]
        if missing:
            raise ValueError(f"case {case.name}: quantity {q.name} reads probe(s) "
                             f"{', '.join(missing)} that the scene {case.scene} does not "
                             f"define (its probes: {', '.join(names) or 'none'})")
    objective = _objective(case, model)
    unit = LINEARISATION if case.linear else 1.0
    if field == "spline":
        solved, load_steps = _solve_spline(scene, model, field_config, objective, unit,
                                           levels=1 if quick else levels)
    else:
        config = solver or (scene.quick_solver if quick else scene.solver)
        if iterations is not None:
            config = config.with_iterations(iterations)
        if seed is not None:
            config = dataclasses.replace(config, seed=seed)
        solved, load_steps = _solve_siren(scene, model, field_config, objective, unit, config)
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
    log.info("%s (%s): %d iterations, %d Newton steps in %.1f s", case.name, field,
             solved.iterations, solved.newton_steps, solved.wall_time)
    return CaseResult(case=case, rows=rows, convergence=convergence, solver=solved.solver)


def _solve_siren(scene: Scene, model: ShellModel, field_config, objective: Objective,
                 unit: float, config: SolverConfig) -> tuple[CaseSolve, tuple[float, ...]]:
    """The case's SIREN trained by Adam (`Solver`, the divergence guard as its callback):
    readings after each load step, the monitor history as the convergence series."""
    config = dataclasses.replace(config, progress=False)
    warn_rigid_motions(model, newton=config.newton_iterations > 0)
    # "auto" output scale with Adam: the linear estimate of the case's (scaled) model.
    field_config = field_for_run(field_config, scene.output_scale_estimate, model, config)
    run = Solver(model, NeuralField(field_config, seed=config.seed), config,
                 objective=objective)
    final: dict[float, Readings] = {}

    def readings(probes: dict[str, list[float]]) -> Readings:
        return {n: np.asarray(v, dtype=np.float64) / unit for n, v in probes.items()}

    def on_load_step(load_factor: float) -> None:
        final[load_factor] = readings(run.probe_displacements(load_factor))

    start = time.perf_counter()
    result = run.run(callbacks=[DivergenceGuard()], on_load_step=on_load_step)
    wall = time.perf_counter() - start
    series = {t: ([h.iteration for h in records], [readings(h.probes) for h in records])
              for t in config.load_steps
              for records in [[h for h in result.history if h.load_factor == t]]}
    return CaseSolve(
        final, series, result.iterations, result.newton_steps, config.samples,
        config.newton_samples if config.newton_iterations else 0, wall,
        {"iterations_per_step": config.iterations, "samples": config.samples,
         "load_steps": list(config.load_steps), "lbfgs_iterations": config.lbfgs_iterations,
         "newton_iterations": config.newton_iterations, "newton_every": config.newton_every,
         "newton_samples": config.newton_samples, "learning_rate": config.adam.lr,
         "field": field_config.to_dict()}), config.load_steps


def _solve_spline(scene: Scene, model: ShellModel, plan, objective: Objective, unit: float,
                  *, levels: int) -> tuple[CaseSolve, tuple[float, ...]]:
    """The case with one default spline configuration (`ndf-sim --field spline`: cubic, the
    grid rule, Gauss points p + 1, projected-Newton defaults) on `levels` grids, solved by
    `solve_spline` with the divergence guard as its callback: readings on the finest grid,
    the convergence series per grid level."""
    from taichi_ndf.minimise.assembly import displacement_at
    from taichi_ndf.operator import DisplacementOperator
    from taichi_ndf.spline_solver import solve_spline

    plan = dataclasses.replace(plan, levels=levels)
    check_run_size(dataclasses.replace(scene, field=plan), scene.solver)
    config = dataclasses.replace(scene.solver, progress=False)
    warn_rigid_motions(model)
    names = [p.name for p in model.probes]
    per_level: list[dict[float, Readings]] = []

    def on_level(run) -> None:
        operator = DisplacementOperator(run.field, model.boundary)
        dtype = run.field.coefficients.dtype
        xi = torch.tensor([p.xi for p in model.probes], dtype=dtype).reshape(-1, 2)
        per_level.append({t: {n: u[k].double().numpy() / unit for k, n in enumerate(names)}
                          for t, c in run.steps
                          for u in [displacement_at(operator, xi, c, t)[:, jets.VALUE]]})

    start = time.perf_counter()
    run = solve_spline(model, plan, config, objective=objective,
                       callbacks=[DivergenceGuard()], on_level=on_level)
    wall = time.perf_counter() - start
    series = {t: (list(range(len(per_level))), [level[t] for level in per_level])
              for t in per_level[-1] if all(t in level for level in per_level)}
    return CaseSolve(
        per_level[-1], series, 0, len(run.history), 0, 0, wall,
        {"method": "newton", "convergence_axis": "grid level",
         "load_steps": list(config.load_steps), "spans": [list(lv.spans) for lv in run.levels],
         "newton_iterations": len(run.history), "field": plan.to_dict()}), config.load_steps


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
