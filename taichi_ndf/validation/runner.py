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
from taichi_ndf.callbacks import DivergenceGuard
from taichi_ndf.field import NeuralField
from taichi_ndf.model import ShellModel
from taichi_ndf.objective import EndMomentTerm, Objective
from taichi_ndf.scene import Scene, load_scene
from taichi_ndf.solver import Solver, SolverConfig
from taichi_ndf.validation.catalogue import LINEARISATION, SCENES_DIR, Case, Readings

log = logging.getLogger(__name__)


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


def load_case_scene(case: Case, scenes_dir: Path = SCENES_DIR) -> tuple[Scene, ShellModel, object]:
    """The case's scene, its model with the case's load scale, and the field configuration."""
    scene = load_scene(Path(scenes_dir) / case.scene)
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
        field_config = dataclasses.replace(
            field_config, output_scale=field_config.output_scale * LINEARISATION)
    return scene, model.with_loads(loads), field_config


def run_case(case: Case, *, quick: bool = False, solver: SolverConfig | None = None,
             iterations: int | None = None, scenes_dir: Path = SCENES_DIR,
             seed: int | None = None) -> CaseResult:
    """Train the case's field and read its quantities.

    quick: use the scene's [training.quick] settings; solver: explicit settings instead.
    iterations: Adam iterations per load step (overrides the settings).
    seed: field initialisation and sampling seed (default: the scene's).
    """
    scene, model, field_config = load_case_scene(case, scenes_dir)
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
    field_ = NeuralField(field_config, seed=config.seed)
    if case.end_moment is not None:
        width = model.surface.domain.lengths[1]
        objective = Objective.of_model(model).with_terms(
            EndMomentTerm(case.end_moment(model), width))
        run = Solver(model, field_, config, objective=objective)
    else:
        run = Solver(model, field_, config)
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


def _level_key(level: float, load_steps: tuple[float, ...]) -> float | None:
    for step in load_steps:
        if abs(step - level) < 1e-9:
            return step
    return None
