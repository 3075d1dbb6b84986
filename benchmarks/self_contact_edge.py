"""Self-contact at the free edge, and self-contact without a table (issue 30).

The 0.3 m napkin of benchmarks/self_contact_fold.py's first version (scenes/napkin_fold.toml
with bounds 0.3 m × 0.15 m, 16 × 8 spans, folded at ξ¹ = 0.15, output 121 × 61), started
folded and solved under gravity at load factor 1 by the spline contact rounds, three ways in
one process:
- "gauss only": on the table, self-contact points = the Gauss points (`edges = false`, as
  before the edge points);
- "edges": on the table, with the chart's edge points (`SelfContactConfig.edges`, the default);
- "edges, no table": the same without the table ([self_contact] alone,
  `ContactConfig.self_only`): the clamped napkin folded in the air.
Checked on the output mesh: the nearest-vertex distance between the two layers (ξ¹ below the
crease of the start against ξ¹ beyond it; `self_contact_fold.layer_distances`), where the
closest upper vertex is (ξ), the smallest distance of the upper layer's free-edge vertices
(ξ¹ = 0.3) to the lower layer, against the offset; and taichi_ndf/io/mesh_check.py. CPU =
user + sys of the process over each solve (`resource.getrusage`), wall beside it.

    PYTHONPATH=$PWD OMP_NUM_THREADS=1 python benchmarks/self_contact_edge.py
"""

from __future__ import annotations

import dataclasses
import os
import sys
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(ROOT / "benchmarks"))
from provenance import commit  # noqa: E402
from self_contact_fold import CREASE_RADIUS, folded_solve, layers  # noqa: E402

import taichi_ndf  # noqa: E402
from taichi_ndf.contact.config import ContactConfig  # noqa: E402
from taichi_ndf.io.mesh_check import self_intersections  # noqa: E402
from taichi_ndf.scene.reader import load_scene  # noqa: E402

SCENE = ROOT / "scenes" / "napkin_fold.toml"
LENGTH = 0.3  # [m]
SMALL = {"geometry.bounds": [[0.0, LENGTH], [0.0, 0.15]], "field.spans": [16, 8],
         "start.at": 0.5 * LENGTH, "output.resolution": [121, 61],
         "probes[0].xi": [LENGTH, 0.075], "probes[1].xi": [0.5 * LENGTH, 0.075]}


def run(name: str, *, edges: bool, table: bool) -> dict:
    scene = load_scene(SCENE, overrides=SMALL)
    model = scene.model
    config = dataclasses.replace(model.contact.self_contact, edges=edges)
    contact = dataclasses.replace(model.contact, self_contact=config) if table else \
        ContactConfig.self_only(model, config)
    model = dataclasses.replace(model, contact=contact)
    result, mesh, cpu, wall = folded_solve(scene, model)
    a = 0.5 * LENGTH - 0.5 * np.pi * CREASE_RADIUS
    lower_mask = mesh.xi[:, 0] < a
    upper_rows = np.nonzero(mesh.xi[:, 0] > a + np.pi * CREASE_RADIUS)[0]
    lower, upper = layers(mesh, LENGTH, CREASE_RADIUS)
    distance = cKDTree(mesh.deformed[lower_mask]).query(upper)[0]
    closest = upper_rows[int(np.argmin(distance))]
    free_edge = np.isclose(mesh.xi[upper_rows, 0], LENGTH)
    summary = result.state.levels[-1]
    return {"name": name, "min": float(distance.min()),
            "where": tuple(float(v) for v in mesh.xi[closest]),
            "edge_min": float(distance[free_edge].min()),
            "intersections": len(self_intersections(mesh.deformed, mesh.faces)),
            "energy": summary.energy, "iterations": len(result.state.history),
            "rounds": result.contact.rounds, "converged": summary.converged,
            "cpu": cpu,
            "wall": wall, "offset": config.offset, "reach": config.offset + config.activation,
            "lowest_upper_z": float(upper[:, 2].min())}


def main() -> None:
    taichi_ndf.init(arch="cpu", precision="f64")
    print(f"commit {commit()}, load average {os.getloadavg()[0]:.1f} (start)")
    rows = [run("gauss only", edges=False, table=True), run("edges", edges=True, table=True),
            run("edges, no table", edges=True, table=False)]
    print(f"offset {1e3 * rows[0]['offset']:.2f} mm, offset + ĝ {1e3 * rows[0]['reach']:.2f} mm")
    print("| self-contact points | layer distance min [mm] | at ξ [m] | free edge's min [mm] | "
          "upper layer lowest z [mm] | intersecting face pairs | Π [J] | Newton iterations | "
          "contact rounds | converged | CPU [s] | wall [s] |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['name']} | {1e3 * r['min']:.2f} | ({r['where'][0]:.4f}, "
              f"{r['where'][1]:.4f}) | {1e3 * r['edge_min']:.2f} | "
              f"{1e3 * r['lowest_upper_z']:.2f} | {r['intersections']} | {r['energy']:.6g} | "
              f"{r['iterations']} | {r['rounds']} | {r['converged']} | {r['cpu']:.1f} | "
              f"{r['wall']:.1f} |")
    print(f"load average {os.getloadavg()[0]:.1f} (end)")


if __name__ == "__main__":
    main()
