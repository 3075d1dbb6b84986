"""The sheet's outline against the mask: which template vertices are on the border, which of
them the camera sees, and how deep inside the mask each may lie (the outline term of
`inverse.sft.least_squares`).

The silhouette term only pulls vertices that project outside the mask back in. A border that
retreats inside the mask (the sheet reconstructed too narrow there, e.g. a free edge bent to
the wrong side of the camera ray, which projects shorter) is not told. The outline term holds
each visible border vertex no deeper inside the mask than the template's own outline lay in
frame 0: that allowance absorbs a template whose outline does not follow mask 0 exactly (on
φ-SfT's R1 it lies from 10 px inside to 7 px outside it) instead of pulling the sheet out of
shape. A border vertex hidden behind the sheet (a roll, a fold over the sheet) projects inside
the mask legitimately: it is left out, judged on the previous frame's reconstruction.
"""

from __future__ import annotations

import numpy as np
import torch

from inverse.sft.camera import Camera
from inverse.sft.silhouette import bilinear_differentiable

# No allowance: the outline term ignores the vertex.
FREE = -np.inf


def border_edges(faces: np.ndarray) -> np.ndarray:
    """(E, 2): the edges (vertex pairs, sorted) that only one triangle of `faces` (F, 3) uses."""
    pairs = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), 1)
    edges, uses = np.unique(pairs, axis=0, return_counts=True)
    return edges[uses == 1]


def border_vertices(faces: np.ndarray, count: int) -> np.ndarray:
    """Bool (count,): vertices on an edge that only one triangle of `faces` (F, 3) uses."""
    border = np.zeros(count, dtype=bool)
    border[border_edges(faces).ravel()] = True
    return border


def visible_vertices(vertices: np.ndarray, faces: np.ndarray, which: np.ndarray, *,
                     tolerance: float) -> np.ndarray:
    """Bool (n,): which of the vertices [m] (n, 3) selected by `which` (bool (n,)) no triangle of
    the mesh hides from the camera (at the origin of camera coordinates): the ray from the
    camera to the vertex meets no triangle (F, 3) nearer than the vertex's own distance less
    `tolerance` [m] (Möller–Trumbore; the vertex's own triangles meet it at its distance).
    Unselected vertices are False."""
    points = vertices[which]  # (k, 3)
    a, b, c = (vertices[faces[:, i]] for i in range(3))  # (F, 3) each
    e1, e2 = b - a, c - a
    length = np.linalg.norm(points, axis=1)
    direction = points / length[:, None]  # (k, 3)
    p = np.cross(direction[:, None, :], e2[None])  # (k, F, 3)
    det = np.einsum("kfi,fi->kf", p, e1)
    parallel = np.abs(det) < 1e-15
    inv = 1.0 / np.where(parallel, 1.0, det)
    s = -a  # the ray starts at the origin
    u = np.einsum("kfi,fi->kf", p, s) * inv
    q = np.cross(s, e1)  # (F, 3)
    v = np.einsum("ki,fi->kf", direction, q) * inv
    t = np.einsum("fi,fi->f", q, e2)[None] * inv
    hit = ~parallel & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0) & (
        t < length[:, None] - tolerance)
    visible = np.zeros(len(vertices), dtype=bool)
    visible[np.flatnonzero(which)] = ~hit.any(axis=1)
    return visible


def outline_allowance(vertices: np.ndarray, faces: np.ndarray, camera: Camera,
                      distance: torch.Tensor, *, tolerance: float) -> np.ndarray:
    """(n,) [px]: for each border vertex the camera sees in frame 0 (template `vertices` [m],
    `distance` D₀ (h, w): frame 0's mask as its `silhouette_distance`, negative inside), the
    signed distance min(0, D₀(π(X_v))) it lies inside the mask; `FREE` for every other
    vertex."""
    allowance = np.full(len(vertices), FREE)
    border = border_vertices(faces, len(vertices))
    chosen = visible_vertices(vertices, faces, border, tolerance=tolerance)
    pixels = camera.project(torch.from_numpy(vertices[chosen]))
    depth = bilinear_differentiable(distance, pixels).numpy()
    allowance[chosen] = np.minimum(depth, 0.0)
    return allowance


def outline_offsets(allowance: np.ndarray, previous: np.ndarray, faces: np.ndarray, *,
                    tolerance: float) -> torch.Tensor:
    """The outline term's offsets of one frame (n,) [px] float64: the allowance of the border
    vertices that the previous frame's reconstruction `previous` [m] (n, 3) shows, `FREE` for
    the hidden ones."""
    offsets = allowance.copy()
    offsets[~visible_vertices(previous, faces, np.isfinite(allowance), tolerance=tolerance)] = FREE
    return torch.from_numpy(offsets)
