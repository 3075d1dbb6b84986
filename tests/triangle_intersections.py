"""An independent test of a triangle mesh for self-intersections (numpy only), for the
self-contact checks: two triangles that share no vertex intersect when an edge of one
crosses the other (the non-coplanar case; Möller 1997's segment–triangle form). Candidate
pairs: centroids closer than the two circumradii (scipy's cKDTree)."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree


def _segments_cross(p: np.ndarray, q: np.ndarray, a: np.ndarray, b: np.ndarray,
                    c: np.ndarray) -> np.ndarray:
    """Whether segments p–q (K, 3) cross triangles abc (K, 3 each): Möller–Trumbore with the
    ray parameter in [0, 1]; parallel segments count as not crossing."""
    d = q - p
    e1, e2 = b - a, c - a
    h = np.cross(d, e2)
    det = (e1 * h).sum(axis=1)
    scale = np.abs(e1).max(axis=1) * np.abs(e2).max(axis=1) * np.abs(d).max(axis=1)
    ok = np.abs(det) > 1e-14 * np.maximum(scale, 1e-300)
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    s = p - a
    u = (s * h).sum(axis=1) * inv
    qv = np.cross(s, e1)
    v = (d * qv).sum(axis=1) * inv
    t = (e2 * qv).sum(axis=1) * inv
    return ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t >= 0) & (t <= 1)


def intersecting_pairs(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Pairs (K, 2) of faces (F, 3) of the mesh (vertices (V, 3)) that share no vertex and
    intersect."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    corners = v[f]  # (F, 3, 3)
    centroid = corners.mean(axis=1)
    radius = np.linalg.norm(corners - centroid[:, None], axis=2).max(axis=1)
    pairs = cKDTree(centroid).query_pairs(2 * radius.max(), output_type="ndarray")
    if not len(pairs):
        return pairs.reshape(0, 2)
    i, j = pairs[:, 0], pairs[:, 1]
    near = np.linalg.norm(centroid[i] - centroid[j], axis=1) <= radius[i] + radius[j]
    shared = (f[i][:, :, None] == f[j][:, None, :]).any(axis=(1, 2))
    pairs = pairs[near & ~shared]
    i, j = pairs[:, 0], pairs[:, 1]
    hit = np.zeros(len(pairs), dtype=bool)
    for first, second in ((i, j), (j, i)):
        a, b, c = (corners[second][:, k] for k in range(3))
        for k in range(3):
            p, q = corners[first][:, k], corners[first][:, (k + 1) % 3]
            hit |= _segments_cross(p, q, a, b, c)
    return pairs[hit]
