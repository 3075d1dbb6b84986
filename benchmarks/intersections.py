"""Runs' output meshes checked by the independent triangle test (issue 30): self-intersections,
crossings of and vertices inside each obstacle's surface, the clearance to it, and with
self-contact the smallest distance between the sheet's layers against the barrier's offset.

    PYTHONPATH=$PWD OMP_NUM_THREADS=1 python benchmarks/intersections.py [--fine K] NAME=RUN ...

Each RUN is a finished `ndf-sim` output directory. Checked per run: mesh.obj (a garment's
panels welded at their seams: vertices within 1 µm merged, and vertices on a panel's own
edge within --seam-tolerance, by default SEAM_TOLERANCE = 0.1 mm, the seam gap issue 30
accepts: a seam closed to its tolerance is joined there, one open wider is not, and its laps
count; interior vertices are never merged above 1 µm), each panel's mesh_<panel>.obj (welded
by the same rule: a seam between two edges of one panel, a sleeve's underarm),
every trajectory frame (trajectory/step_*.obj), and with `--fine K` the run's checkpoint
evaluated again at K × the output resolution (the same `part_meshes` that ndf-export
calls): a crossing at one resolution and not the other is the output mesh's linear
interpolation cutting a corner, not the surface. The obstacles are the run's own
obstacles/*.obj (each `Obstacle.triangles`), whose faces lie inside a curved obstacle by up
to their sagitta. The check shares no code with the contact path (taichi_ndf/io/mesh_check.py).
Prints one markdown table; CPU = user + sys of this process for each check.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))

from provenance import commit  # noqa: E402

from taichi_ndf.io import read_mesh  # noqa: E402
from taichi_ndf.io.mesh_check import check_mesh, welded  # noqa: E402

WELD = 1e-6       # [m] seams' and periodic edges' vertices merged below this distance
SEAM_TOLERANCE = 1e-4  # [m] vertices on panels' edges merged below this (a sewn seam's gap)
REACH = 0.05      # [m] clearances looked for within this; layer distances within 2 (o + ĝ)


def _cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def _self_contact(run: Path):
    """The run's self-contact configuration (offset, activation ĝ, exclusion [m]) or None,
    its scene and its checkpoint (as ndf-export reads them; a dynamic run's checkpoint is
    not read: its scene from scenes/<name>.toml, and None)."""
    from taichi_ndf.app.simulation import checkpoint_scene
    from taichi_ndf.minimise.checkpoint import CheckpointError, load_checkpoint
    from taichi_ndf.scene.reader import load_scene

    try:
        checkpoint = load_checkpoint(run / "checkpoint.pt")
        scene = checkpoint_scene(run / "checkpoint.pt", checkpoint.extra)
    except (CheckpointError, FileNotFoundError):  # a dynamic run's: its scene file by name
        checkpoint = None
        name = json.loads((run / "result.json").read_text())["scene"]
        scene = load_scene(ROOT / "scenes" / f"{name}.toml")
    contact = getattr(scene.model, "contact", None)
    return getattr(contact, "self_contact", None), scene, checkpoint


def _check(vertices, faces, obstacles, rest, config, seam_tolerance: float = 0.0
           ) -> tuple[dict, float]:
    before = _cpu()
    v, f, kept = welded(vertices, faces, WELD, seam_tolerance=seam_tolerance)
    merged = len(vertices) - len(kept)
    if rest is not None:
        rest = np.asarray(rest)[kept]
    report = check_mesh(v, f, obstacles,
                        rest_vertices=rest if config is not None else None,
                        exclusion=config.exclusion if config is not None else 0.0,
                        reach=REACH, layer_reach=None if config is None else
                        2 * (config.offset + config.activation))
    return {"report": report, "merged": merged}, _cpu() - before


def _mm(x: float | None) -> str:
    if x is None:
        return "—"
    return "beyond reach" if np.isinf(x) and x > 0 else f"{x * 1e3:.3f}"


def _obstacle_cells(report) -> str:
    if not report.obstacles:
        return "—"
    return "; ".join(f"{o.name}: {o.crossings} / {'n/a' if o.inside is None else o.inside} / "
                     f"{_mm(o.clearance)}" for o in report.obstacles)


def _row(name, mesh, cells, found, cpu) -> str:
    r = found["report"]
    return (f"| {name} | {mesh} | {cells} ({r.vertices} v, {r.faces} f) | {found['merged']} | "
            f"{r.self_intersections} | {_obstacle_cells(r)} | {_mm(r.layer_distance)} | "
            f"{cpu:.1f} |")


def _frames_row(name, frames, obstacles, rest, config) -> str:
    reports, cpu = [], 0.0
    for path in frames:
        mesh = read_mesh(path)
        found, seconds = _check(mesh.vertices, mesh.faces, obstacles, rest, config)
        reports.append(found["report"])
        cpu += seconds
    selfs = [r.self_intersections for r in reports]
    worst = int(np.argmax(selfs))
    obstacle_cells = []
    for k, o in enumerate(reports[0].obstacles):
        crossed = [r.obstacles[k].crossings for r in reports]
        held = [r.obstacles[k].inside for r in reports]
        clear = [r.obstacles[k].clearance for r in reports]
        obstacle_cells.append(
            f"{o.name}: {max(crossed)} (in {sum(c > 0 for c in crossed)} frames) / "
            f"{'n/a' if held[0] is None else max(held)} / {_mm(min(clear))} "
            f"(frame {int(np.argmin(clear))})")
    layers = [r.layer_distance for r in reports if r.layer_distance is not None]
    layer = (f"{_mm(min(layers))} (frame {int(np.argmin(layers))})" if layers else "—")
    return (f"| {name} | {len(frames)} frames, most pairs in frame {worst} | as mesh.obj | — | "
            f"{max(selfs)} (in {sum(s > 0 for s in selfs)} frames) | "
            f"{'; '.join(obstacle_cells) or '—'} | {layer} | {cpu:.1f} |")


def check_run(name: str, run: Path, fine: int, seam_tolerance: float = SEAM_TOLERANCE
              ) -> list[str]:
    result = json.loads((run / "result.json").read_text())
    cells = tuple(result["resolved"]["output"]["resolution"])
    obstacles = []
    for path in sorted((run / "obstacles").glob("*.obj")) if (run / "obstacles").is_dir() else []:
        mesh = read_mesh(path)
        obstacles.append((path.stem, mesh.vertices, mesh.faces))
    config, scene, checkpoint = _self_contact(run)
    rows = []
    if config is not None:
        rows.append(f"| {name} | self-contact: offset o {config.offset * 1e3:.3f} mm, o + ĝ "
                    f"{(config.offset + config.activation) * 1e3:.3f} mm, exclusion "
                    f"{config.exclusion * 1e3:.2f} mm | | | | | | |")
    final = read_mesh(run / "mesh.obj")
    rest = read_mesh(run / "reference.obj").vertices if (run / "reference.obj").exists() \
        else None
    if rest is not None and rest.shape != final.vertices.shape:
        rest = None
    found, cpu = _check(final.vertices, final.faces, obstacles, rest, config, seam_tolerance)
    rows.append(_row(name, "mesh.obj", f"{cells[0]} × {cells[1]}", found, cpu))
    for path in sorted(run.glob("mesh_*.obj")):
        mesh = read_mesh(path)
        found, cpu = _check(mesh.vertices, mesh.faces, obstacles, None, None, seam_tolerance)
        rows.append(_row(name, path.name, f"{cells[0]} × {cells[1]}", found, cpu))
    frames = sorted((run / "trajectory").glob("step_*.obj")) \
        if (run / "trajectory").is_dir() else []
    if frames:
        frame_rest = rest if rest is not None and len(rest) == len(
            read_mesh(frames[0]).vertices) else None
        rows.append(_frames_row(name, frames, obstacles, frame_rest, config))
    if fine > 1 and checkpoint is not None:  # (a dynamic run's checkpoint is not a field's)
        from taichi_ndf.app.panels import part_meshes
        from taichi_ndf.discretise import of_scene

        res = (fine * cells[0], fine * cells[1])
        parts = of_scene(scene).result_parts(checkpoint.field)
        meshes = part_meshes(parts, res)
        offsets = np.cumsum([0] + [len(m.deformed) for m in meshes])
        vertices = np.concatenate([m.deformed for m in meshes])
        reference = np.concatenate([m.reference for m in meshes])
        faces = np.concatenate([m.faces + o for m, o in zip(meshes, offsets, strict=False)])
        found, cpu = _check(vertices, faces, obstacles,
                            reference if len(meshes) == 1 else None, config, seam_tolerance)
        rows.append(_row(name, f"checkpoint at {fine} × the output cells", f"{res[0]} × {res[1]}",
                         found, cpu))
    return rows


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", nargs="+", metavar="NAME=RUN")
    parser.add_argument("--fine", type=int, default=2,
                        help="also the checkpoint at this many times the output cells (1: not)")
    parser.add_argument("--seam-tolerance", type=float, default=SEAM_TOLERANCE, metavar="M",
                        help="vertices on a panel's own edge (mesh boundary) closer than this "
                             "[m] are merged: a seam sewn to within it counts as joined, a "
                             "wider one's laps count as crossings; interior vertices are "
                             f"merged below {WELD:g} m only (default %(default)g, the seam "
                             "gap issue 30 accepts; 0: 1 µm everywhere)")
    args = parser.parse_args()
    if not args.seam_tolerance >= 0:
        print(f"intersections.py: error: --seam-tolerance {args.seam_tolerance}: must be a "
              "length ≥ 0 [m]", file=sys.stderr)
        return 2
    runs = []
    for item in args.runs:
        name, _, path = item.partition("=")
        if not path or not (Path(path) / "result.json").exists():
            print(f"intersections.py: error: {item}: not NAME=RUN with RUN/result.json",
                  file=sys.stderr)
            return 2
        runs.append((name, Path(path)))
    import taichi_ndf

    taichi_ndf.init(arch="cpu", precision="f64")
    print(f"commit {commit()}, load average {os.getloadavg()[0]:.1f} (start), seam tolerance "
          f"{args.seam_tolerance:g} m")
    print("| run | mesh | output cells (vertices, faces) | vertices welded | self-intersecting "
          "face pairs | obstacle: crossing pairs / vertices inside / clearance [mm] | layer "
          "distance [mm] | check CPU [s] |")
    print("|---|---|---|---|---|---|---|---|")
    for name, run in runs:
        for row in check_run(name, run, args.fine, args.seam_tolerance):
            print(row, flush=True)
    print(f"load average {os.getloadavg()[0]:.1f} (end)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
