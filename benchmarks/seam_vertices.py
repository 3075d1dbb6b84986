"""Whether a garment's exported seams meet (issue 30): per seam between two outline edges, the
border vertices of the output mesh on each side, the largest distance from one side's deformed
vertices to the other side's deformed edge (the field evaluated densely along it), how many of
a side's vertices have one of the other side's within the seam rule's 0.1 mm (what
benchmarks/intersections.py and `io.mesh_check.welded` merge), and the widest strip in ξ
between each side's edge and its panel's mesh (what no output face covers).

    PYTHONPATH=$PWD OMP_NUM_THREADS=1 python benchmarks/seam_vertices.py RUN [--resolution R]

RUN: a finished garment run of `ndf-sim` (its checkpoint.pt); the meshes are made again by
`app.panels.part_meshes` (what ndf-sim and ndf-export write) at RUN's output resolution (or
R × R), so the same checkpoint measures the export of whichever tree is imported.
Prints one markdown table; CPU = user + sys of this process.
"""

from __future__ import annotations

import argparse
import os
import resource
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from provenance import commit  # noqa: E402

SEAM_TOLERANCE = 1e-4  # [m] the seam rule of benchmarks/intersections.py
DENSE = 4001           # points along a side's edge for its deformed curve


def _cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def _on_edge(side, xi: np.ndarray) -> np.ndarray:
    """Which ξ (N, 2) lie on the seam side's edge (a `PolygonEdge`: within 1e-9 m)."""
    from taichi_ndf.problem.arcs import Arc

    arc = Arc.of_bulge(side.start, side.end, side.bulge)
    if arc is not None:
        return arc.nearest(xi)[1] < 1e-9
    a, b = np.asarray(side.start, float), np.asarray(side.end, float)
    d = b - a
    t = np.clip((xi - a) @ d / float(d @ d), 0.0, 1.0)
    return np.linalg.norm(xi - (a + t[:, None] * d), axis=1) < 1e-9


def _curve(part, side) -> np.ndarray:
    """The deformed edge (DENSE, 3) [m]: the field evaluated at DENSE fractions along it."""
    import torch

    from taichi_ndf import jets

    xi = torch.from_numpy(side.path(np.linspace(0.0, 1.0, DENSE))[0])
    model = part.model
    return (model.surface.jets(xi)[:, jets.VALUE]
            + model.displacement(part.field, xi)).double().detach().numpy()


def _to_polyline(points: np.ndarray, line: np.ndarray) -> np.ndarray:
    """Each point's (N, D) distance [m] to the polyline (M, D)."""
    return _to_segments(points, line[:-1], line[1:])


def _to_segments(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Each point's (N, D) distance [m] to the nearest of the segments a → b (M, D)."""
    d = b - a
    t = np.clip(np.einsum("nmk,mk->nm", points[:, None] - a[None], d) / (d * d).sum(1), 0, 1)
    foot = a[None] + t[..., None] * d[None]
    return np.linalg.norm(points[:, None] - foot, axis=2).min(axis=1)


def _strip(side, mesh) -> float:
    """The widest strip [m] in ξ between the side's edge and its panel's mesh: the largest
    distance from a point of the edge (DENSE along it) to the mesh's border edges."""
    f = mesh.faces
    edges = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    unique, count = np.unique(edges, axis=0, return_counts=True)
    border = unique[count == 1]
    along = side.path(np.linspace(0.0, 1.0, DENSE))[0]
    return float(_to_segments(along, mesh.xi[border[:, 0]], mesh.xi[border[:, 1]]).max())


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("run", type=Path)
    parser.add_argument("--resolution", type=int, default=None)
    args = parser.parse_args()
    if not (args.run / "checkpoint.pt").exists():
        print(f"seam_vertices.py: error: {args.run}: no checkpoint.pt", file=sys.stderr)
        return 2
    import taichi_ndf

    taichi_ndf.init(arch="cpu", precision="f64")
    from scipy.spatial import cKDTree

    from taichi_ndf.app.panels import part_meshes
    from taichi_ndf.app.simulation import checkpoint_scene
    from taichi_ndf.discretise import of_scene
    from taichi_ndf.minimise.checkpoint import load_checkpoint
    from taichi_ndf.problem.outline import PolygonEdge

    start = _cpu()
    checkpoint = load_checkpoint(args.run / "checkpoint.pt")
    scene = checkpoint_scene(args.run / "checkpoint.pt", checkpoint.extra)
    discretisation = of_scene(scene)
    parts = discretisation.result_parts(checkpoint.field)
    res = scene.output.resolution if args.resolution is None else (args.resolution,) * 2
    meshes = part_meshes(parts, res)
    print(f"commit {commit()}, {taichi_ndf.__file__}, load average {os.getloadavg()[0]:.1f} "
          f"(start), output cells {res[0]} × {res[1]} per panel")
    print("| seam | side A: vertices on it | side B | largest distance A's vertices → B's "
          "curve, B's → A's [µm] | A's vertices with a B vertex within 0.1 mm | widest strip "
          "in ξ between the edge and its mesh, A, B [mm] |")
    print("|---|---|---|---|---|---|")
    for seam in discretisation.spec.seams:
        spec = seam.spec
        if not (isinstance(spec.a, PolygonEdge) and isinstance(spec.b, PolygonEdge)):
            continue
        a, b = parts[seam.a], parts[seam.b]
        on_a = meshes[seam.a].deformed[_on_edge(spec.a, meshes[seam.a].xi)]
        on_b = meshes[seam.b].deformed[_on_edge(spec.b, meshes[seam.b].xi)]
        strip = (f"{_strip(spec.a, meshes[seam.a]) * 1e3:.3f}, "
                 f"{_strip(spec.b, meshes[seam.b]) * 1e3:.3f}")
        if not (len(on_a) and len(on_b)):  # a side without a vertex on its edge
            print(f"| {spec.name} ({spec.a.edge} – {spec.b.edge}) | {len(on_a)} | {len(on_b)} "
                  f"| — | 0 | {strip} |")
            continue
        to_b = _to_polyline(on_a, _curve(b, spec.b)).max()
        to_a = _to_polyline(on_b, _curve(a, spec.a)).max()
        near = cKDTree(on_b).query(on_a)[0] <= SEAM_TOLERANCE
        print(f"| {spec.name} ({spec.a.edge} – {spec.b.edge}) | {len(on_a)} | {len(on_b)} | "
              f"{to_b * 1e6:.1f}, {to_a * 1e6:.1f} | {int(near.sum())} of {len(on_a)} | {strip} |")
    print(f"load average {os.getloadavg()[0]:.1f} (end), CPU {_cpu() - start:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
