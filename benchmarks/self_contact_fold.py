"""A napkin folded in half on a table, with and without self-contact (issue 30).

scenes/napkin_fold.toml (0.6 m × 0.15 m cotton/polyester, edge ξ¹ = 0 clamped on a table,
32 × 8 cubic spans, float64) started folded: the half ξ¹ > 0.3 turned over the other,
2 ρ = 2 cm above it around a crease of radius ρ = 1 cm (an isometric fold, fitted by the
spline in least squares: the scene's [start], `fitted_start`), then solved under gravity at
load factor 1 by the spline path's contact solve, once with the scene's [self_contact] and
once without it.
Checked on the output mesh (241 × 61 vertices) by taichi_ndf/io/mesh_check.py, an
independent segment–triangle test of every pair of faces that share no vertex, and by the
smallest distance between the vertices of the two flat layers (ξ¹ below the crease against
ξ¹ beyond it: nearest-vertex distances, everywhere and 2 cm of ξ¹ away from the crease).
Prints the table (layer distances, intersecting face pairs, Π, Newton iterations and contact
rounds, CPU and wall time, load average, commit).

    PYTHONPATH=$PWD OMP_NUM_THREADS=1 python benchmarks/self_contact_fold.py [OUT_DIR]

(OUT_DIR: the two output meshes as OBJ files.)

    PYTHONPATH=$PWD OMP_NUM_THREADS=1 python benchmarks/self_contact_fold.py --run RUN_DIR

checks the mesh.obj of an `ndf-sim scenes/napkin_fold.toml --out RUN_DIR` run (which starts
folded by the scene's [start]) the same way: layer distances and intersecting face pairs.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import resource
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import torch
from scipy.spatial import cKDTree

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(ROOT / "benchmarks"))
from provenance import commit  # noqa: E402

import taichi_ndf  # noqa: E402
from taichi_ndf.app.outputs import deformed_mesh, export_grid  # noqa: E402
from taichi_ndf.discretise.start import fitted_start  # noqa: E402
from taichi_ndf.io import read_mesh, write_obj  # noqa: E402
from taichi_ndf.io.mesh_check import self_intersections  # noqa: E402
from taichi_ndf.minimise.state import State  # noqa: E402
from taichi_ndf.scene.reader import load_scene  # noqa: E402
from taichi_ndf.solve.spline_solver import solve_spline  # noqa: E402

SCENE = ROOT / "scenes" / "napkin_fold.toml"
CREASE_RADIUS = 0.01  # ρ [m]
CREASE_MARGIN = 0.02  # [m] of ξ¹ left out around the crease for the flat layers' distances


def layers(mesh, length: float, radius: float, margin: float = 0.0
           ) -> tuple[np.ndarray, np.ndarray]:
    """Vertices of the lower and the upper flat layer (ξ¹ below the crease, and beyond it),
    `margin` [m] of ξ¹ away from the crease of the start."""
    a = 0.5 * length - 0.5 * math.pi * radius
    lower = mesh.xi[:, 0] < a - margin
    upper = mesh.xi[:, 0] > a + math.pi * radius + margin
    return mesh.deformed[lower], mesh.deformed[upper]


def layer_distances(mesh, length: float, radius: float, margin: float = 0.0) -> np.ndarray:
    """Each upper-layer vertex's distance [m] to the nearest lower-layer vertex (`layers`)."""
    lower, upper = layers(mesh, length, radius, margin)
    return cKDTree(lower).query(upper)[0]


def profile(mesh, stations=(0.0, 0.1, 0.2, 0.25, 0.3, 0.35, 0.4, 0.5, 0.6)) -> str:
    """x, z [mm] of the mesh's middle line ξ² = mid at the given ξ¹ [m] (nearest vertices)."""
    mid = mesh.xi[:, 1].min() + 0.5 * np.ptp(mesh.xi[:, 1])
    line = np.abs(mesh.xi[:, 1] - mid) <= 0.5 * np.diff(np.unique(mesh.xi[:, 1])).max()
    xi, x = mesh.xi[line], mesh.deformed[line]
    rows = [x[int(np.argmin(np.abs(xi[:, 0] - s)))] for s in stations]
    return ", ".join(f"ξ¹ {s:.2f}: ({1e3 * p[0]:.1f}, {1e3 * p[2]:.1f})"
                     for s, p in zip(stations, rows, strict=True))


def folded_solve(scene, model):
    """`model` (the scene's, its contact changed) solved from the scene's folded start:
    (the spline solve's result, its deformed mesh at the output resolution, CPU s (user +
    sys), wall s)."""
    start = fitted_start(model, scene.field.config, scene.start)
    before = resource.getrusage(resource.RUSAGE_SELF)
    wall = time.perf_counter()
    result = solve_spline(model, scene.field, scene.solver, state=State.newton(start))
    wall = time.perf_counter() - wall
    after = resource.getrusage(resource.RUSAGE_SELF)
    mesh = deformed_mesh(model, result.state.field, scene.output.resolution)
    cpu = after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime
    return result, mesh, cpu, wall


def run(self_contact: bool, out: Path | None = None) -> dict:
    scene = load_scene(SCENE)
    model = scene.model
    if not self_contact:
        model = dataclasses.replace(model, contact=dataclasses.replace(model.contact,
                                                                       self_contact=None))
    result, mesh, cpu, wall = folded_solve(scene, model)
    (lo, hi), _ = model.surface.domain.bounds
    if out is not None:
        write_obj(out / f"napkin_fold_{'on' if self_contact else 'off'}.obj", mesh.deformed,
                  mesh.faces)
    everywhere = layer_distances(mesh, hi - lo, CREASE_RADIUS)
    flat = layer_distances(mesh, hi - lo, CREASE_RADIUS, CREASE_MARGIN)
    lower, upper = layers(mesh, hi - lo, CREASE_RADIUS, CREASE_MARGIN)
    summary = result.state.levels[-1]
    config = scene.model.contact.self_contact
    touching = everywhere < config.offset + config.activation
    return {"self_contact": self_contact, "min_layer_distance": float(everywhere.min()),
            "touching": float(touching.mean()),
            "touching_median": float(np.median(everywhere[touching])) if touching.any()
            else math.nan, "profile": profile(mesh),
            "min_flat_distance": float(flat.min()), "median_flat_distance": float(np.median(flat)),
            "upper_lowest_z": float(upper[:, 2].min()),
            "lower_highest_z": float(lower[:, 2].max()),
            "intersections": len(self_intersections(mesh.deformed, mesh.faces)),
            "energy": summary.energy, "iterations": len(result.state.history),
            "rounds": result.contact.rounds, "converged": summary.converged,
            "cpu": cpu,
            "wall": wall, "config": model.contact.self_contact, "mesh": mesh}


def table(rows: list[dict]) -> str:
    lines = ["| self-contact | layer distance: min [mm] | upper layer within o + ĝ of the "
             "lower: share, median distance [mm] | flat parts: min, median [mm] | "
             "upper layer lowest z, lower highest z [mm] | "
             "intersecting face pairs | Π [J] | Newton iterations | contact rounds | "
             "converged | CPU [s] | wall [s] |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {'on' if r['self_contact'] else 'off'} | "
                     f"{1e3 * r['min_layer_distance']:.2f} | {100 * r['touching']:.0f} %, "
                     f"{1e3 * r['touching_median']:.2f} | {1e3 * r['min_flat_distance']:.2f}, "
                     f"{1e3 * r['median_flat_distance']:.2f} | {1e3 * r['upper_lowest_z']:.2f}, "
                     f"{1e3 * r['lower_highest_z']:.2f} | "
                     f"{r['intersections']} | {r['energy']:.6g} | {r['iterations']} | "
                     f"{r['rounds']} | {r['converged']} | {r['cpu']:.1f} | {r['wall']:.1f} |")
    return "\n".join(lines)


def check_run(run_dir: Path) -> None:
    """The layer distances and intersecting face pairs of an ndf-sim run's mesh.obj (its ξ:
    the scene's export grid, `export_grid`), and its result.json's Π and Newton iterations."""
    scene = load_scene(SCENE)
    xi, faces, _ = export_grid(scene.model, scene.output.resolution)
    mesh = SimpleNamespace(xi=xi, deformed=read_mesh(run_dir / "mesh.obj").vertices,
                           faces=faces)
    (lo, hi), _ = scene.model.surface.domain.bounds
    result = json.loads((run_dir / "result.json").read_text())
    everywhere = layer_distances(mesh, hi - lo, CREASE_RADIUS)
    flat = layer_distances(mesh, hi - lo, CREASE_RADIUS, CREASE_MARGIN)
    print(f"ndf-sim run {run_dir}: layer distance min {1e3 * everywhere.min():.2f} mm, flat "
          f"parts min {1e3 * flat.min():.2f} mm, median {1e3 * np.median(flat):.2f} mm, "
          f"intersecting face pairs {len(self_intersections(mesh.deformed, mesh.faces))}, "
          f"Π {result['energy']:.6g} J, {result['iterations']} Newton iterations")


def main() -> None:
    taichi_ndf.init(arch="cpu", precision="f64")
    torch.set_num_threads(1)
    print(f"commit {commit()}, load average {os.getloadavg()[0]:.1f} (start)")
    if len(sys.argv) == 3 and sys.argv[1] == "--run":
        check_run(Path(sys.argv[2]))
        return
    out = Path(sys.argv[1]) if len(sys.argv) > 1 else None
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
    rows = [run(True, out), run(False, out)]
    config = rows[0]["config"]
    print(f"self-contact: ĝ {config.activation * 1e3:.2g} mm, offset {config.offset * 1e3:.3g}"
          f" mm, κ {config.stiffness:.4g} N/m⁵, exclusion {config.exclusion * 1e3:.3g} mm")
    print(table(rows))
    for r in rows:
        print(f"middle line, self-contact {'on' if r['self_contact'] else 'off'} (x, z) [mm]: "
              f"{r['profile']}")
    print(f"load average {os.getloadavg()[0]:.1f} (end)")


if __name__ == "__main__":
    main()
