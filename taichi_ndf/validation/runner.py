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

from taichi_ndf import jets
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


def run_case(case: Case, *, quick: bool = False, solver: SolverConfig | None = None,
             iterations: int | None = None, scenes_dir: Path = SCENES_DIR,
             seed: int | None = None, field: str | None = None,
             levels: int = SPLINE_LEVELS) -> CaseResult:
    """Train the case's field and read its quantities.

    quick: use the scene's [training.quick] settings; solver: explicit settings instead.
    iterations: Adam iterations per load step (overrides the settings).
    seed: field initialisation and sampling seed (default: the scene's).
    field: "spline" to solve the case with a spline field by projected Newton on `levels`
    grids (`run_spline_case`), "siren" with the SIREN; None: the field the case's scene
    names (its `[field] type`), as `ndf-sim` does.
    """
    if field is None:
        field = "spline" if _own_spline(case, scenes_dir) else "siren"
    if field == "spline":
        if iterations is not None:
            raise ValueError("--iterations sets Adam; the spline path solves by projected "
                             "Newton")
        return run_spline_case(case, quick=quick, scenes_dir=scenes_dir, levels=levels)
    scene, model, field_config = load_case_scene(case, scenes_dir, field)
    names = [p.name for p in model.probes]
    for q in case.quantities:
        missing = [p for p in q.probes if p not in names]
        if missing:
            raise ValueError(f"case {case.name}: quantity {q.name} reads probe(s) "
                             f"{', '.join(missing)} that the scene {case.scene} does not "
                             f"define (its probes: {', '.join(names) or 'none'})")
    config = solver or (scene.quick_solver if quick else scene.solver)
    if iterations is not None:
        config = config.with_iterations(iterations)
    if seed is not None:
        config = dataclasses.replace(config, seed=seed)
    config = dataclasses.replace(config, progress=False)
    warn_rigid_motions(model, newton=config.newton_iterations > 0)
    # "auto" output scale with Adam: the linear estimate of the case's (scaled) model.
    field_config = field_for_run(field_config, scene.output_scale_estimate, model, config)
    field_ = NeuralField(field_config, seed=config.seed)
    run = Solver(model, field_, config, objective=_objective(case, model))
    dtype = field_.parameters[0].dtype
    xi = torch.tensor([p.xi for p in model.probes], dtype=dtype)
    positions = model.surface.jets(xi)[:, jets.VALUE]
    reference_positions = {n: positions[k].double().numpy() for k, n in enumerate(names)}
    unit = LINEARISATION if case.linear else 1.0
    at_level: dict[float, Readings] = {}

    def readings(probes: dict[str, list[float]]) -> Readings:
        return {n: np.asarray(v, dtype=np.float64) / unit for n, v in probes.items()}

    def on_load_step(load_factor: float) -> None:
        at_level[load_factor] = readings(run.probe_displacements(load_factor))

    start = time.perf_counter()
    result = run.run(callbacks=[DivergenceGuard()], on_load_step=on_load_step)
    wall = time.perf_counter() - start
    rows, convergence = [], {}
    for q in case.quantities:
        key = _level_key(q.level, config.load_steps)
        computed = None if key is None else q.read(at_level[key], reference_positions)
        error = None if computed is None else abs(computed - q.reference) / abs(q.reference)
        rows.append(Row(case=case.name, quantity=q.name, description=q.description,
                        level=q.level, computed=computed, reference=q.reference,
                        relative_error=error, tolerance=q.tolerance,
                        passed=None if error is None else error <= q.tolerance,
                        iterations=result.iterations, wall_time=wall, samples=config.samples,
                        newton_steps=result.newton_steps,
                        newton_samples=config.newton_samples if config.newton_iterations else 0,
                        source=q.source))
        if key is not None:
            records = [h for h in result.history if h.load_factor == key]
            convergence[f"{q.name} @ {q.level:g}"] = (
                [h.iteration for h in records],
                [q.read(readings(h.probes), reference_positions) for h in records])
    log.info("%s: %d iterations in %.1f s", case.name, result.iterations, wall)
    return CaseResult(case=case, rows=rows, convergence=convergence,
                      solver={"iterations_per_step": config.iterations,
                              "samples": config.samples,
                              "load_steps": list(config.load_steps),
                              "lbfgs_iterations": config.lbfgs_iterations,
                              "newton_iterations": config.newton_iterations,
                              "newton_every": config.newton_every,
                              "newton_samples": config.newton_samples,
                              "learning_rate": config.adam.lr,
                              "field": field_config.to_dict(),
                              "load_scale": case.load_scale})


def run_spline_case(case: Case, *, quick: bool = False, scenes_dir: Path = SCENES_DIR,
                    levels: int = SPLINE_LEVELS) -> CaseResult:
    """The case with one default spline configuration (`ndf-sim --field spline`: cubic, the
    grid rule, Gauss points p + 1, projected-Newton defaults) on `levels` grids (quick: one).
    Quantities are read on the finest grid; the convergence plot shows them per grid level."""
    from taichi_ndf.minimise.assembly import displacement_at
    from taichi_ndf.operator import DisplacementOperator
    from taichi_ndf.spline_solver import solve_spline

    # A scene with its own spline field keeps its keys (spans, degree, quadrature points).
    own = _own_spline(case, scenes_dir)
    scene, model, plan = load_case_scene(case, scenes_dir, None if own else "spline")
    plan = dataclasses.replace(plan, levels=1 if quick else levels)
    check_run_size(dataclasses.replace(scene, field=plan), scene.solver)
    config = dataclasses.replace(scene.solver, progress=False)
    warn_rigid_motions(model)
    objective = _objective(case, model)
    names = [p.name for p in model.probes]
    unit = LINEARISATION if case.linear else 1.0
    positions = {}
    per_level: list[dict[float, Readings]] = []

    def on_level(run) -> None:
        operator = DisplacementOperator(run.field, model.boundary)
        dtype = run.field.coefficients.dtype
        xi = torch.tensor([p.xi for p in model.probes], dtype=dtype).reshape(-1, 2)
        if not positions:
            r = model.surface.jets(xi)[:, jets.VALUE]
            positions.update({n: r[k].double().numpy() for k, n in enumerate(names)})
        per_level.append({t: {n: u[k].double().numpy() / unit for k, n in enumerate(names)}
                          for t, c in run.steps
                          for u in [displacement_at(operator, xi, c, t)[:, jets.VALUE]]})

    start = time.perf_counter()
    run = solve_spline(model, plan, config, objective=objective, on_level=on_level)
    wall = time.perf_counter() - start
    rows, convergence = [], {}
    for q in case.quantities:
        key = _level_key(q.level, config.load_steps)
        computed = None if key is None else q.read(per_level[-1][key], positions)
        error = None if computed is None else abs(computed - q.reference) / abs(q.reference)
        rows.append(Row(case=case.name, quantity=q.name, description=q.description,
                        level=q.level, computed=computed, reference=q.reference,
                        relative_error=error, tolerance=q.tolerance,
                        passed=None if error is None else error <= q.tolerance,
                        iterations=0, wall_time=wall, samples=0,
                        newton_steps=len(run.history), source=q.source))
        if key is not None and all(key in level for level in per_level):
            convergence[f"{q.name} @ {q.level:g}"] = (
                list(range(len(per_level))),
                [q.read(level[key], positions) for level in per_level])
    log.info("%s (spline): %d Newton iterations in %.1f s", case.name, len(run.history), wall)
    return CaseResult(case=case, rows=rows, convergence=convergence,
                      solver={"method": "newton", "convergence_axis": "grid level",
                              "load_steps": list(config.load_steps),
                              "spans": [list(lv.spans) for lv in run.levels],
                              "newton_iterations": len(run.history),
                              "field": plan.to_dict(), "load_scale": case.load_scale})


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
