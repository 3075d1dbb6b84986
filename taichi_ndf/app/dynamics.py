"""A scene with a `[dynamics]` section run in physical time, with its outputs."""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Callable

from taichi_ndf.app.outputs import (
    CONTACT_GRID,
    ExportError,
    contact_outputs,
    deformed_mesh,
    surface_points,
    trajectory_mesh_name,
    write_field_outputs,
    write_trajectory_mesh,
)
from taichi_ndf.export.usd import require_usd, write_run_usd
from taichi_ndf.extras import MissingExtra
from taichi_ndf.io import OutputDir, read_mesh
from taichi_ndf.io.run_files import read_run
from taichi_ndf.problem.training import SolverConfig
from taichi_ndf.solve.dynamics import TimeStepper
from taichi_ndf.solve.dynamics_trajectory import read_checkpoint, write_checkpoint
from taichi_ndf.solve.spline_solver import newton_config

log = logging.getLogger(__name__)

FORMAT_VERSION = 1
CHECKPOINT = "checkpoint.pt"  # the state at the last output frame (`write_checkpoint`)
# Scene sections a resumed dynamic run may change (the steps depend on everything else).
RESUMABLE_CHANGES = ("name", "description", "output")


def simulate_dynamics(scene, out: OutputDir, *, solver: SolverConfig | None = None,
                      resume: bool = False, machine: dict | None = None,
                      on_result: Callable[[dict], None] | None = None,
                      pictures: bool = True) -> dict:
    """Integrate `scene` (its `dynamics`, a `DynamicsConfig`) from rest in the reference state,
    loads on from t = 0, on the finest grid of its spline plan (`TimeStepper`), and write
    trajectory/step_NNN.obj at every output frame (frame k at result.json's
    `trajectory.times[k]` [s]), mesh.obj/.ply, reference.obj and probes.json of the final
    state, render.png and trajectory.mp4 with `pictures` (the obstacles drawn, labelled with
    the time t [s]; through the static path's writer, `write_field_outputs`), with obstacles
    obstacles/*.obj and result.json's `contact` of the final state, and result.json
    (`time` [s]; `dynamics`: times, energies, Newton iterations, CPU cost). solver: its
    Newton settings (newton_max_iterations, newton_tolerance). on_result: called with the
    result before the outputs are written.
    checkpoint.pt: the state at every output frame; `resume` continues from it (the frames
    before it read back from trajectory/), and the run ends as the uninterrupted one would.
    With `[output] usd`, result.usdc with the frames at time codes t × (frames per second)
    (`export.usd`). ValueError for a checkpoint of another scene, and for USD without its
    extra."""
    config = solver or scene.solver
    if scene.output.usd:  # before the steps, not after them
        try:
            require_usd()
        except MissingExtra as err:
            raise ValueError(f"[output] usd = true: {err}") from err
    dynamics = scene.dynamics
    stepper = TimeStepper(scene.model, scene.field, dynamics,
                          newton=newton_config(config, _dtype()))
    frames = []  # (time [s], deformed positions (V, 3)) per frame
    extra = {"scene": scene.document}
    start = None
    if resume:
        start, stored = read_checkpoint(out.file(CHECKPOINT), dynamics)
        changed = sorted(k for k in set(stored["scene"]) | set(scene.document)
                         if k not in RESUMABLE_CHANGES
                         and stored["scene"].get(k) != scene.document.get(k))
        if changed:
            raise ValueError(f"--resume: the scene changed since {out.file(CHECKPOINT)} was "
                             f"written ([{'], ['.join(changed)}] differ)")
        for index, (t, _) in enumerate(start.trajectory.frames):
            frames.append((t, read_mesh(out.file(trajectory_mesh_name(index))).vertices))
        log.info("resuming %s at t = %.6g s (step %d)", scene.name, start.state.time,
                 start.step)

    def on_frame(t: float, field) -> None:
        mesh = deformed_mesh(scene.model, field, scene.output.resolution,
                             load_factor=dynamics.boundary_factor(t))
        write_trajectory_mesh(out, len(frames), mesh)
        frames.append((t, mesh.deformed))

    started = time.perf_counter()
    trajectory = stepper.run(on_frame=on_frame, resume=start, on_checkpoint=lambda c:
                             write_checkpoint(out.file(CHECKPOINT), c, extra))
    wall = time.perf_counter() - started
    document = trajectory.to_dict()
    probes = {name: values[-1] for name, values in trajectory.probes.items()}
    iterations = sum(document["newton_iterations"])
    result = {"format_version": FORMAT_VERSION, "scene": scene.name, "seed": config.seed,
              "energy": document["potential"][-1], "iterations": iterations,
              "wall_time": wall, "time": trajectory.times[-1], "probes": probes,
              "dynamics": document,
              # load_factors: the same times, under the key the run readers take for a
              # frame's parameter (`io.run_files.read_run`: ndf-render, ndf-view, ndf-export)
              "trajectory": {"source": "dynamics", "times": [t for t, _ in frames],
                             "load_factors": [t for t, _ in frames],
                             "energy": [_at(document, t) for t, _ in frames]},
              "resolved": {"field": {**scene.field.to_dict(),
                                     "finest_spans": list(trajectory.spans)},
                           "solver": dataclasses.asdict(config),
                           "output": dataclasses.asdict(scene.output),
                           "scene_file": scene.document},
              "machine": machine or {}}
    if on_result is not None:
        on_result(result)
    end = trajectory.times[-1]
    obstacles, contact = (), scene.model.contact
    if contact is not None:
        result["contact"], obstacles = contact_outputs(
            contact, out, surface_points(scene.model, trajectory.field, CONTACT_GRID),
            stepper.contact.points, load_factor=dynamics.load_factor(end))
    times = [t for t, _ in frames]
    try:
        write_field_outputs(
            out, scene.model, trajectory.field, probes, resolution=scene.output.resolution,
            views=scene.output.views, obstacles=obstacles,
            load_factor=dynamics.boundary_factor(end), states=[x for _, x in frames],
            state_parameters=times, physical_time=True, label=f"t = {end:.2f} s",
            state_obstacles=None if contact is None else [
                tuple(o.triangles(dynamics.load_factor(t)) for o in contact.obstacles)
                for t in times],
            pictures=pictures)
    except ExportError as err:
        raise ValueError(str(err)) from err
    out.write_json("result.json", result)
    if scene.output.usd:  # time codes at the output rate (`export.usd`)
        write_run_usd(read_run(out.path), out.file("result.usdc"))
    log.info("wrote outputs of %s to %s", scene.name, out.path)
    return result


def _at(document: dict, t: float) -> float:
    """T + Π [J] at the recorded time nearest t."""
    times = document["times"]
    index = min(range(len(times)), key=lambda i: abs(times[i] - t))
    return document["total"][index]


def _dtype():
    import taichi_ndf

    return taichi_ndf.current().dtype
