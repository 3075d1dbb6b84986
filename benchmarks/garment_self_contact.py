"""Self-contact on a garment's panels (issue 30, "Self-contact"): scenes/tube_top_body.toml
(four flat-cut knit panels sewn into a tube, gathered onto a capsule torso) solved without
and with `[self_contact]` (distance ĝ, default 2 mm; offset, κ and exclusion by default from
the coarsest panel grid) on n × m spans per panel (default 4 × 6 and 8 × 12), side by side in
one process. Per run: Π at the last load step, Newton iterations, convergence at every load
step, contact rounds, the seams' largest gap, the self-contact settings, the smallest
distance between self-contact points not excluded as neighbours, the intersecting triangle
pairs of the joined output meshes (`taichi_ndf.io.mesh_check.self_intersections`, 48 × 48
per panel, the seams' vertices welded within 1e-5 m), CPU (user + sys) and wall time of
the solve, the load average.

    PYTHONPATH=$PWD OMP_NUM_THREADS=1 python benchmarks/garment_self_contact.py [ĝ] [n m ...]
    PYTHONPATH=$PWD OMP_NUM_THREADS=1 python benchmarks/garment_self_contact.py --stack
"""

from __future__ import annotations

import copy
import os
import resource
import sys
import time
import tomllib
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from provenance import commit  # noqa: E402

import taichi_ndf  # noqa: E402
from taichi_ndf.app.panels import combined, part_meshes  # noqa: E402
from taichi_ndf.discretise import of_scene  # noqa: E402
from taichi_ndf.io.mesh_check import self_intersections, welded  # noqa: E402
from taichi_ndf.scene.reader import parse_scene  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "scenes" / "tube_top_body.toml"


def _cpu() -> float:
    use = resource.getrusage(resource.RUSAGE_SELF)
    return use.ru_utime + use.ru_stime


def _crossings(panels, resolution=(48, 48), weld: float = 1e-5) -> int:
    """Intersecting triangle pairs of the panels' output meshes joined into one, the vertices
    of the seams' two sides (closer than `weld` [m]) merged into one first: else the two
    panels' triangles that meet at a seam count as crossing."""
    vertices, faces, _ = combined(part_meshes(panels.result_parts(panels.field), resolution))
    vertices, faces, _ = welded(vertices, faces, weld)
    return len(self_intersections(vertices, faces))


def run(spans, distance: float | None) -> dict:
    document = tomllib.loads(SCENE.read_text())
    document["field"]["spans"] = list(spans)
    if distance is not None:
        document["self_contact"] = {"distance": distance}
    scene = parse_scene(copy.deepcopy(document), base_dir=SCENE.parent, path=SCENE)
    panels = of_scene(scene)
    panels.start(scene.solver, seed=0)
    cpu, wall = _cpu(), time.perf_counter()
    solution = panels.solve(scene.solver)
    cpu, wall = _cpu() - cpu, time.perf_counter() - wall
    out = {"spans": spans, "distance": distance, "energy": solution.energy,
           "iterations": solution.iterations, "converged": all(panels.converged),
           "rounds": solution.contact_counts.get("newton_rounds"),
           "seam_gap": max(solution.document["seam_gaps"].values()),
           "crossings": _crossings(panels), "cpu": cpu, "wall": wall, "closest": None,
           "config": scene.model.contact.self_contact}
    if out["config"] is not None:
        out["closest"] = _closest(panels, out["config"])
    return out


def _closest(panels, config) -> float:
    """The smallest distance [m] between two Gauss points of the panels that started at
    least the exclusion radius apart (the pairs the barrier acts on)."""
    import torch
    from scipy.spatial import cKDTree

    linear = panels._linear
    c = torch.cat([f.coefficients.detach() for f in panels.fields])
    x = (linear.samples.r_jets[:, 0] + linear.displacement(c)[:, 0]).numpy()
    x0 = (linear.samples.r_jets[:, 0] + linear.displacement(panels._start)[:, 0]).numpy()
    gauss = linear.samples.weight.numpy() > 0
    x, x0 = x[gauss], x0[gauss]
    pairs = cKDTree(x).query_pairs(config.exclusion, output_type="ndarray")
    apart = np.linalg.norm(x0[pairs[:, 0]] - x0[pairs[:, 1]], axis=1) >= config.exclusion
    pairs = pairs[apart]
    if not len(pairs):
        return float("inf")
    return float(np.linalg.norm(x[pairs[:, 0]] - x[pairs[:, 1]], axis=1).min())


def stack() -> None:
    """tests/test_garment_self_contact.py's two stacked panels (a cantilever drooping onto a
    held panel 5 cm below), without and with `[self_contact]` (ĝ = 5 mm): the middles' height
    difference, crossings of the joined meshes (24 × 24 per panel), iterations, CPU, wall."""
    sys.path.insert(0, str(ROOT / "tests"))
    from test_garment_self_contact import _middle_z, _solve, _stack

    print("| self-contact | upper − lower middle [mm] | o + ĝ/2 [mm] | Newton it. | converged "
          "| crossings | CPU [s] | wall [s] |")
    print("|---|---|---|---|---|---|---|---|")
    for settings in (None, {"distance": 0.005}):
        cpu, wall = _cpu(), time.perf_counter()
        scene, panels, solution = _solve(_stack(settings))
        cpu, wall = _cpu() - cpu, time.perf_counter() - wall
        lower, upper = _middle_z(scene, panels)
        config = scene.model.contact.self_contact if scene.model.contact else None
        rest = "–" if config is None else f"{1e3 * (config.offset + config.activation / 2):.2f}"
        print(f"| {'on' if settings else 'off'} | {1e3 * (upper - lower):.2f} | {rest} | "
              f"{solution.iterations} | {all(panels.converged)} | "
              f"{_crossings(panels, (24, 24))} | {cpu:.1f} | {wall:.1f} |", flush=True)


def main(argv: list[str]) -> None:
    if argv[:1] == ["--stack"]:
        taichi_ndf.init(arch="cpu", precision="f64", seed=0)
        print(f"commit {commit()}, load average {os.getloadavg()}")
        stack()
        print(f"load average after {os.getloadavg()}")
        return
    distance = float(argv[0]) if argv else 0.002
    numbers = [int(v) for v in argv[1:]]
    grids = list(zip(numbers[::2], numbers[1::2], strict=True)) or [(4, 6), (8, 12)]
    taichi_ndf.init(arch="cpu", precision="f64", seed=0)
    print(f"commit {commit()}, load average {os.getloadavg()}")
    print("| spans | self-contact | Π [J] | Newton it. | converged | rounds | seam gap [m] "
          "| o, ĝ, ρ [mm] | closest non-neighbours [mm] | crossings | CPU [s] | wall [s] |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for spans in grids:
        for d in (None, distance):
            r = run(spans, d)
            c = r["config"]
            settings = "–" if c is None else (f"{1e3 * c.offset:.2f}, {1e3 * c.activation:.2f}, "
                                              f"{1e3 * c.exclusion:.2f}")
            closest = "–" if r["closest"] is None else f"{1e3 * r['closest']:.2f}"
            print(f"| {spans[0]}×{spans[1]} | {'on' if d else 'off'} | {r['energy']:.8g} | "
                  f"{r['iterations']} | {r['converged']} | {r['rounds']} | "
                  f"{r['seam_gap']:.2g} | {settings} | {closest} | {r['crossings']} | "
                  f"{r['cpu']:.1f} | {r['wall']:.1f} |", flush=True)
    print(f"load average after {os.getloadavg()}")


if __name__ == "__main__":
    main(sys.argv[1:])
