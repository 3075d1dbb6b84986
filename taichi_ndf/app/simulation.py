"""Run a scene end to end: build the field, solve, write every output into a run directory."""

from __future__ import annotations

import dataclasses
import logging
import os
from collections.abc import Callable
from pathlib import Path

import numpy as np

from taichi_ndf.app.dynamics import simulate_dynamics
from taichi_ndf.app.outputs import (
    CONTACT_GRID,
    DeformedMesh,
    ExportError,
    contact_outputs,
    deformed_mesh,
    surface_points,
    trajectory_mesh_name,
    write_field_outputs,
    write_trajectory_mesh,
)
from taichi_ndf.app.panels import write_panel_outputs
from taichi_ndf.boundary.rigid_motions import warn_rigid_motions
from taichi_ndf.discretise import SolveRefused, of_scene
from taichi_ndf.discretise.adaptive import adaptive as adaptive_discretisation
from taichi_ndf.export.usd import require_usd, write_run_usd
from taichi_ndf.extras import MissingExtra
from taichi_ndf.io import OutputDir, read_mesh
from taichi_ndf.io.run_files import read_run
from taichi_ndf.minimise.callbacks import CheckpointWriter, DivergenceGuard
from taichi_ndf.minimise.checkpoint import CheckpointError, read_checkpoint
from taichi_ndf.problem.pseudo_time import frame_times
from taichi_ndf.scene.reader import Scene, parse_scene
from taichi_ndf.scene.schema import SceneError
from taichi_ndf.solve.adaptive import AdaptiveConfig
from taichi_ndf.solve.solver import DivergenceError, SolverConfig

log = logging.getLogger(__name__)

FORMAT_VERSION = 1
# What a run writes into its directory (see `simulate`): replaced as a whole by the next run.
RUN_FILES = ("mesh.obj", "mesh.ply", "reference.obj", "probes.json", "render.png", "energy.png",
             "checkpoint.pt", "result.json", "result.usdc", "trajectory", "trajectory.mp4",
             "obstacles", "progress.jsonl", "mesh_*.obj", "mesh_*.ply")  # mesh_<panel>: a garment
# Scene sections a resumed run may change: how long and how it trains, what it writes.
RESUMABLE_CHANGES = ("name", "description", "training", "output")


class SimulationError(RuntimeError):
    """A run could not produce a trustworthy result; the message says why."""


def simulate(scene: Scene, out: OutputDir, *, solver: SolverConfig | None = None,
             resume: bool = False, machine: dict | None = None, seed: int | None = None,
             report: Callable[[str], None] | None = None,
             on_result: Callable[[dict], None] | None = None, pictures: bool = True,
             adaptive: AdaptiveConfig | None = None) -> dict:
    """Solve `scene` and write mesh.obj/.ply, reference.obj, probes.json, render.png,
    energy.png, checkpoint.pt, result.json (result.usdc with `[output] usd`; and trajectory/ +
    trajectory.mp4 with several load steps, or with a pseudo-time field at `output.frames`
    pseudo-times) into `out`.
    report: where a spline run's one-line summary of each finished grid level goes when the
    solver configuration asks for progress (the command line passes `print`); None: nowhere.
    on_result: called once the solve is done, before any output is written (they cost
    seconds: benchmarks/RESULTS.md, "Start-up"), with the result so far: "energy",
    "iterations", "wall_time", "probes" and the discretisation's own keys ("refinement", ...).
    pictures: False leaves out render.png, energy.png and trajectory.mp4 (the meshes, probes,
    checkpoint and result.json are written all the same).
    adaptive: refine a spline field adaptively to this request (`--tolerance`,
    `taichi_ndf.discretise.adaptive`) instead of the plan's levels.
    Returns the result dictionary also written to result.json."""
    config = solver or scene.solver
    if scene.dynamics is not None:  # in physical time: another path with its own outputs
        return simulate_dynamics(scene, out, solver=config, resume=resume, machine=machine,
                                 on_result=on_result, pictures=pictures)
    if scene.output.usd:  # before the solve, not after it
        try:
            require_usd()
        except MissingExtra as err:
            raise SimulationError(f"[output] usd = true: {err}") from err
    if config.pseudo_time != scene.solver.pseudo_time:
        raise ValueError("the solver configuration and the scene disagree on pseudo_time (the "
                         "scene's field has a pseudo-time input only with it)")
    seed = config.seed if seed is None else seed
    discretisation = of_scene(scene)
    if adaptive is not None:
        discretisation = adaptive_discretisation(discretisation, adaptive)
    warn_rigid_motions(scene.model, newton=discretisation.uses_newton(config))
    checkpoint = out.file("checkpoint.pt")
    if resume:
        _check_same_scene(checkpoint, scene)
    try:
        discretisation.start(config, seed=seed, resume_from=checkpoint if resume else None)
    except CheckpointError as err:
        raise SimulationError(f"--resume: {err}") from err
    # the surfaces the result is made of: one (mesh.obj), or named panels (mesh_<panel>.obj)
    panels = _named(discretisation.result_parts(discretisation.field))
    step_frames = len(config.load_steps) > 1 and not config.pseudo_time and not panels
    frames: dict[int, DeformedMesh] = {}  # load step index -> its deformed mesh

    def on_load_step(load_factor: float, field) -> None:
        if step_frames:  # written at once: a resumed run reads the finished steps back
            index = config.load_steps.index(load_factor)
            part, = discretisation.result_parts(field)
            frames[index] = deformed_mesh(part.model, part.field, scene.output.resolution,
                                          load_factor=load_factor)
            write_trajectory_mesh(out, index, frames[index])

    callbacks = [DivergenceGuard(checkpoint), CheckpointWriter(checkpoint, {"scene": scene.document,
                                               "scene_dir": str(scene.path.parent.resolve())})]
    try:
        solution = discretisation.solve(config, callbacks=callbacks, on_load_step=on_load_step,
                                        report=report)
        discretisation.check_solution(solution)
    except (DivergenceError, SolveRefused) as err:
        raise SimulationError(str(err)) from err
    if on_result is not None:
        on_result({"energy": solution.energy, "iterations": solution.iterations,
                   "wall_time": solution.wall_time, "probes": solution.probes,
                   **solution.document})
    parts = discretisation.result_parts(solution.field)

    trajectory = None
    if step_frames:
        trajectory = _load_step_trajectory(out, config.load_steps, frames, solution.history,
                                           solution.document.get("load_steps", ()))
    if config.pseudo_time:  # the whole path from the one field, at any number of frames
        times = frame_times(config.pseudo_time_start, scene.output.frames)
        energy, states = [], []
        for index, t in enumerate(times):
            mesh = deformed_mesh(parts[0].model, parts[0].field, scene.output.resolution,
                                 load_factor=t, pseudo_time=True)
            write_trajectory_mesh(out, index, mesh)
            states.append(mesh.deformed)
            energy.append(discretisation.energy_at(t))
        trajectory = {"source": "pseudo_time", "load_factors": list(times), "energy": energy,
                      "states": states}
    contact, obstacle_meshes = None, ()
    if solution.contact is not None:  # every part's surface (a garment: every panel's)
        surface = np.concatenate([surface_points(p.model, p.field, CONTACT_GRID)
                                  for p in parts])
        contact, obstacle_meshes = contact_outputs(scene.model.contact, out, surface,
                                                   solution.contact, **solution.contact_counts)
    if _named(parts):
        write_panel_outputs(out, parts, scene.output.resolution,
                            probes=solution.probes, views=scene.output.views,
                            pictures=pictures, obstacles=obstacle_meshes)
    else:
        part, = parts
        _write_field_outputs(scene, out, part, solution.probes, solution.history,
                             pseudo_time=config.pseudo_time, refinement=solution.refinement,
                             obstacles=obstacle_meshes, trajectory=trajectory,
                             pictures=pictures)
    summary = _summary(scene, config, seed, solution.energy, solution.iterations,
                       solution.wall_time, solution.probes, trajectory, solution.field_document,
                       machine, solution.history, contact)
    summary.update(solution.document)  # e.g. Adam's backoffs, a spline's levels
    return _finish(scene, out, summary)


def _named(parts) -> bool:
    """Whether a result's parts (`Discretisation.result_parts`) are named panels."""
    return any(p.name for p in parts)


def _write_field_outputs(scene: Scene, out: OutputDir, part, probes: dict, history, *,
                         pseudo_time: bool = False, refinement: dict | None = None,
                         obstacles: tuple = (), trajectory: dict | None = None,
                         pictures: bool = True) -> None:
    """The outputs of the result's one part (`ResultPart`: the model with the final field)
    and trajectory.mp4 of a `trajectory` (its "states", taken out of it here) with the
    obstacles at each state's load factor (`write_field_outputs`)."""
    states = trajectory.pop("states", None) if trajectory else None
    contact = scene.model.contact
    factors = trajectory["load_factors"] if states else None
    try:
        write_field_outputs(
            out, part.model, part.field, probes, resolution=scene.output.resolution,
            views=scene.output.views, history=history, pseudo_time=pseudo_time,
            refinement=refinement, obstacles=obstacles, states=states, state_parameters=factors,
            state_obstacles=None if contact is None or not states else [
                tuple(o.triangles(t) for o in contact.obstacles) for t in factors],
            pictures=pictures)
    except ExportError as err:
        raise SimulationError(str(err)) from err


def _summary(scene: Scene, config: SolverConfig, seed: int, energy: float, iterations: int,
             wall_time: float, probes: dict, trajectory, field: dict, machine: dict | None,
             history, contact: dict | None = None) -> dict:
    return {
        "format_version": FORMAT_VERSION,
        "scene": scene.name,
        "seed": seed,
        "energy": energy,
        "iterations": iterations,
        "wall_time": wall_time,
        "probes": probes,
        "trajectory": trajectory,
        "contact": contact,
        "resolved": {
            "field": field,
            "solver": _plain(dataclasses.asdict(config)),
            "output": dataclasses.asdict(scene.output),
            "scene_file": scene.document,
        },
        "machine": machine or {},
        "history": [dataclasses.asdict(h) for h in history],
    }


def _finish(scene: Scene, out: OutputDir, summary: dict) -> dict:
    out.write_json("result.json", summary)
    if scene.output.usd:
        write_run_usd(read_run(out.path), out.file("result.usdc"))
    log.info("wrote outputs of %s to %s", scene.name, out.path)
    return summary


def _check_same_scene(checkpoint: Path, scene: Scene) -> None:
    """Refuse to resume from a checkpoint of another scene (naming the sections that differ);
    only [training] and [output] may change."""
    stored = read_checkpoint(checkpoint)["extra"].get("scene")
    if not isinstance(stored, dict):
        raise SimulationError(f"--resume: {checkpoint} holds no scene; it was not written by "
                              "ndf-sim")
    changed = sorted(k for k in set(stored) | set(scene.document)
                     if k not in RESUMABLE_CHANGES and stored.get(k) != scene.document.get(k))
    if changed:
        raise SimulationError(f"--resume: the scene changed since {checkpoint} was written "
                              f"([{'], ['.join(changed)}] differ; only [training] and [output] "
                              "may change); start a new run in a new directory")


def checkpoint_scene(path: str | os.PathLike, extra: dict) -> Scene:
    """The scene a checkpoint written by `simulate` was trained on (its ``extra``).

    Paths inside the scene (a template mesh) are resolved against the scene's folder as stored
    (absolute since it is stored so; older checkpoints hold it relative to the working folder
    of the run), then against the checkpoint's own folder, so a run folder that carries its
    mesh along can be exported from anywhere."""
    path = Path(path)
    if not isinstance(extra.get("scene"), dict):
        raise SceneError(f"{path} holds no scene; it was not written by ndf-sim")
    stored = extra.get("scene_dir")
    candidates = [Path(stored)] if isinstance(stored, str) else []
    if candidates and not candidates[0].is_absolute():
        candidates.append(path.parent / stored)
    candidates.append(path.parent)
    geometry = extra["scene"].get("geometry")
    mesh = geometry.get("path") if isinstance(geometry, dict) else None
    base = next((b for b in candidates if not isinstance(mesh, str) or (b / mesh).is_file()),
                candidates[0])
    try:
        return parse_scene(extra["scene"], base_dir=base)
    except SceneError as err:
        raise SceneError(f"{path}: the scene it holds: {err}") from None


def _load_step_trajectory(out: OutputDir, load_steps: tuple[float, ...],
                          frames: dict[int, DeformedMesh], history, solved_steps=()) -> dict:
    """Every finished load step's state ("states", for trajectory.mp4) and its summary for
    result.json. Steps that finished before a resume are read back from their OBJ files; the
    energy of each step is the last monitor record at its load factor (the checkpoint keeps
    the history), else — a step whose start already met Newton's test, so no iteration was
    recorded — the solve's own record of it (`solved_steps`: the document's "load_steps",
    each {"load_factor", "energy", ...})."""
    recorded = {step["load_factor"]: step["energy"] for step in solved_steps
                if isinstance(step, dict) and "energy" in step}
    states, factors, energy = [], [], []
    for index, load_factor in enumerate(load_steps):
        if index in frames:
            states.append(frames[index].deformed)
        else:
            path = out.file(trajectory_mesh_name(index))
            if not path.exists():
                log.warning("trajectory frame of load step %d (load factor %g) is missing "
                            "(%s); the trajectory leaves it out", index, load_factor, path)
                continue
            states.append(read_mesh(path).vertices)
        factors.append(load_factor)
        energy.append(next((h.energy for h in reversed(history)
                            if h.load_factor == load_factor), recorded.get(load_factor)))
    return {"source": "load_steps", "load_factors": factors, "energy": energy,
            "states": states}


def _plain(value):
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    return value
