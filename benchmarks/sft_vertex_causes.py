"""Why a reconstruction's vertices are far from the capture's cloud: per frame, is the largest
distance a wrong image position or a wrong depth?

    python benchmarks/sft_vertex_causes.py --data PATH --result DIR [--limit 0.02]

For every frame of an ``ndf-sft`` output folder (``DIR/meshes/*.obj``) against the capture's
clouds (``ground_truth/*.npy``, camera coordinates [m]) and masks: the farthest vertex, where it
is on the sheet (corner / border / interior, from the mesh's faces), its distance to the cloud,
its **ray floor** (the distance from its viewing ray to the nearest cloud point: the least any
point seen at that pixel can score, whatever its depth), its depth minus the cloud's median
depth within 3 px of its pixel ("–": no cloud point there), and the mask's signed distance D
at its pixel [px] (> 0: outside the mask; `inverse.sft.silhouette.silhouette_distance` of the
mask's largest part); and the number of vertices beyond ``--limit`` [m] and of those whose ray
floor is beyond it (those no depth could bring within the limit). A vertex far from the cloud
with a small ray floor has its pixel right and its depth wrong.

Camera: the capture's camera.json (fx, fy, cx, cy). Prints a markdown table; figures:
benchmarks/RESULTS.md.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch
from scipy.spatial import cKDTree
from sft_vertex_floor import sheet_mask

from inverse.sft.outline import border_vertices
from inverse.sft.silhouette import bilinear_differentiable, silhouette_distance
from taichi_ndf.io import read_mesh


def project(points: np.ndarray, camera: dict) -> np.ndarray:
    """Pixels (N, 2) of points (N, 3) [m] (OpenCV pinhole, pixel centres at integers)."""
    return np.column_stack([camera["fx"] * points[:, 0] / points[:, 2] + camera["cx"],
                            camera["fy"] * points[:, 1] / points[:, 2] + camera["cy"]])


def ray_floor(points: np.ndarray, cloud: np.ndarray, chunk: int = 64) -> np.ndarray:
    """(N,) [m]: the distance from the camera ray through each point (N, 3) to the nearest
    cloud point (M, 3) (points behind the camera count as on the line; the cloud is in front)."""
    rays = points / np.linalg.norm(points, axis=1, keepdims=True)
    squared = (cloud**2).sum(1)[:, None]
    out = np.empty(len(points))
    for i in range(0, len(points), chunk):
        along = cloud @ rays[i:i + chunk].T
        out[i:i + chunk] = np.sqrt(np.maximum((squared - along**2).min(0), 0.0))
    return out


def vertex_kinds(faces: np.ndarray, count: int) -> np.ndarray:
    """(count,) str: "corner" (a border vertex of at most two triangles), "border", "interior"."""
    border = border_vertices(faces, count)
    uses = np.bincount(faces.ravel(), minlength=count)
    return np.where(border & (uses <= 2), "corner", np.where(border, "border", "interior"))


def frame_row(vertices: np.ndarray, faces: np.ndarray, cloud: np.ndarray, mask: np.ndarray,
              camera: dict, limit: float) -> dict:
    """The module docstring's figures of one frame."""
    distance = cKDTree(cloud).query(vertices)[0]
    floor = ray_floor(vertices, cloud)
    pixels = project(vertices, camera)
    signed = bilinear_differentiable(silhouette_distance(mask), torch.from_numpy(pixels)).numpy()
    v = int(np.argmax(distance))
    near = cKDTree(project(cloud, camera)).query_ball_point(pixels[v], 3.0)
    depth = vertices[v, 2] - np.median(cloud[near, 2]) if near else None
    kinds = vertex_kinds(faces, len(vertices))
    far = distance > limit
    return {"vertex": v, "kind": str(kinds[v]), "distance": float(distance[v]),
            "floor": float(floor[v]), "depth_error": depth, "signed_px": float(signed[v]),
            "far": int(far.sum()), "far_by_kind": {k: int((far & (kinds == k)).sum())
                                                  for k in ("corner", "border", "interior")},
            "far_floor": int((floor > limit).sum()), "largest_floor": float(floor.max())}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--data", type=Path, required=True, help="the capture folder")
    p.add_argument("--result", type=Path, required=True, help="an ndf-sft output folder")
    p.add_argument("--limit", type=float, default=0.02, help="distance [m] counted as far")
    args = p.parse_args()
    camera = json.loads((args.data / "camera.json").read_text())
    clouds = sorted((args.data / "ground_truth").glob("*.npy"))
    masks = sorted((args.data / "masks").glob("*.png"))
    meshes = sorted((args.result / "meshes").glob("*.obj"))
    if not meshes:
        raise SystemExit(f"no meshes in {args.result / 'meshes'}")
    mm = 1e3 * args.limit
    print(f"| frame | largest [mm] | vertex (kind) | its ray floor [mm] | its depth error [mm] | "
          f"D [px] | vertices > {mm:g} mm (corner / border / interior) | ray floor > {mm:g} mm "
          "| largest ray floor [mm] |")
    print("|---|---|---|---|---|---|---|---|---|")
    for i, path in enumerate(meshes[:len(clouds)]):
        mesh = read_mesh(path)
        r = frame_row(np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces),
                      np.load(clouds[i]).astype(np.float64), sheet_mask(masks[i]), camera,
                      args.limit)
        depth = "–" if r["depth_error"] is None else f"{1e3 * r['depth_error']:+.0f}"
        k = r["far_by_kind"]
        print(f"| {i} | {1e3 * r['distance']:.1f} | {r['vertex']} ({r['kind']}) | "
              f"{1e3 * r['floor']:.1f} | {depth} | {r['signed_px']:+.1f} | {r['far']} "
              f"({k['corner']} / {k['border']} / {k['interior']}) | {r['far_floor']} | "
              f"{1e3 * r['largest_floor']:.1f} |", flush=True)


if __name__ == "__main__":
    main()
