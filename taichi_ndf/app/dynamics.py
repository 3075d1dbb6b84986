"""A scene with a `[dynamics]` section run in physical time, with its outputs."""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from collections.abc import Callable

from taichi_ndf import progress
from taichi_ndf.app.outputs import (
    deformed_mesh,
    write_mesh_files,
    write_probe_points,
    write_reference_mesh,
    write_render,
    write_trajectory_mesh,
    write_trajectory_video,
)
from taichi_ndf.io import OutputDir
from taichi_ndf.io.run_files import up_direction
from taichi_ndf.problem.training import SolverConfig
from taichi_ndf.solve.dynamics import TimeStepper
from taichi_ndf.solve.spline_solver import newton_config

log = logging.getLogger(__name__)

FORMAT_VERSION = 1


def simulate_dynamics(scene, out: OutputDir, *, solver: SolverConfig | None = None,
                      resume: bool = False, machine: dict | None = None,
                      on_result: Callable[[dict], None] | None = None,
                      pictures: bool = True) -> dict:
    """Integrate `scene` (its `dynamics`, a `DynamicsConfig`) from rest in the reference state,
    loads on from t = 0, on the finest grid of its spline plan (`TimeStepper`), and write
    trajectory/step_NNN.obj at every output frame (frame k at result.json's
    `trajectory.times[k]` [s]), mesh.obj/.ply, reference.obj and probes.json of the final
    state, render.png and trajectory.mp4 with `pictures`, and result.json (`dynamics`: times,
    energies, Newton iterations, CPU cost). solver: its Newton settings (newton_max_iterations,
    newton_tolerance). on_result: called with the result before the outputs are written.
    ValueError for what the dynamic path does not do yet (resume, prescribed motions)."""
    config = solver or scene.solver
    if resume:
        raise ValueError("--resume: a dynamic run cannot be resumed yet; start it again")
    if scene.output.usd:
        raise ValueError("output.usd: a dynamic run does not write USD yet")
    dynamics = scene.dynamics
    stepper = TimeStepper(scene.model, scene.field, dynamics,
                          newton=newton_config(config, _dtype()))
    frames, final = [], []  # (time [s], deformed positions (V, 3)) per frame; the last mesh

    def on_frame(t: float, field) -> None:
        mesh = deformed_mesh(scene.model, field, scene.output.resolution)
        write_trajectory_mesh(out, len(frames), mesh)
        frames.append((t, mesh.deformed))
        final[:] = [mesh]

    started = time.perf_counter()
    trajectory = stepper.run(on_frame=on_frame)
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
    with progress.stage("outputs: mesh, render, video" if pictures else "outputs: mesh", 3):
        final = final[0]
        for name, values in final.scalars().items():
            if not all(math.isfinite(float(v)) for v in values):
                raise ValueError(f"non-finite {name} in the exported mesh")
        write_mesh_files(out, "mesh", final)
        write_reference_mesh(out, final)
        write_probe_points(out, scene.model, probes)
        progress.report(1)
        if pictures:
            up = up_direction(scene.model.loads.gravity)
            write_render(out, "render.png", final, up=up, views=scene.output.views)
            progress.report(2)
            write_trajectory_video(out, [x for _, x in frames], final.faces,
                                   [t for t, _ in frames], reference=final.reference, up=up,
                                   pseudo_time=True)  # labelled "t", the time [s]
        progress.report(3)
    out.write_json("result.json", result)
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
