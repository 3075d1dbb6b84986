"""Triangle–triangle intersection, point–triangle distance and the winding number, from their
definitions, on arrays of triangles (numpy only).

Written to check a run's output meshes independently of the solver: nothing here comes from
or is shared with the contact path (`taichi_ndf/contact/`). Two closed triangles intersect
when (not coplanar) an edge of one meets the other — the segment–triangle form of Möller's
1997 test: the segment of the planes' intersection that both triangles cover has its ends on
edges — or (coplanar) when an edge of one crosses an edge of the other in their plane or a
corner of one lies in the other. Closed triangles: a touch (a corner on the other triangle)
counts as an intersection. Lengths in the units of the vertices (metres for a run's meshes).
"""

from __future__ import annotations

import numpy as np

# Relative tolerance of the coplanar and parallel decisions, against the pair's size.
_RELATIVE = 1e-10


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.einsum("...i,...i->...", a, b)


def segments_meet_triangles(p: np.ndarray, q: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Whether the closed segments p–q (K, 3) meet the closed triangles t (K, 3, 3): the
    point p + s (q − p), s ∈ [0, 1], in the triangle (barycentric coordinates ≥ 0). A segment
    parallel to the triangle's plane (within the relative tolerance) meets it nowhere here;
    the coplanar case is `coplanar_overlap`'s. (K,) bool."""
    a, b, c = t[:, 0], t[:, 1], t[:, 2]
    d = q - p
    e1, e2 = b - a, c - a
    normal = np.cross(e1, e2)
    det = -_dot(d, normal)                      # the system [e1 e2 −d] (u, v, s) = p − a
    size = np.linalg.norm(normal, axis=1) * np.linalg.norm(d, axis=1)
    ok = np.abs(det) > _RELATIVE * np.maximum(size, 1e-300)
    safe = np.where(ok, det, 1.0)
    w = p - a
    s = _dot(w, normal) / safe
    u = -_dot(d, np.cross(w, e2)) / safe
    v = -_dot(d, np.cross(e1, w)) / safe
    return ok & (s >= 0) & (s <= 1) & (u >= 0) & (v >= 0) & (u + v <= 1)


def _plane_distances(t: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Signed distances (K, 3) of points (K, 3, 3) to the planes of triangles t (K, 3, 3)."""
    normal = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    length = np.linalg.norm(normal, axis=1)
    unit = normal / np.where(length > 0, length, 1.0)[:, None]
    return _dot(points - t[:, :1], unit[:, None, :])


def _size(t1: np.ndarray, t2: np.ndarray) -> np.ndarray:
    both = np.concatenate((t1, t2), axis=1)
    return (both.max(axis=1) - both.min(axis=1)).max(axis=1)


def coplanar(t1: np.ndarray, t2: np.ndarray) -> np.ndarray:
    """Whether each pair of triangles (K, 3, 3) lies in one plane (every corner of each within
    the relative tolerance × the pair's size of the other's plane). (K,) bool."""
    eps = _RELATIVE * _size(t1, t2)[:, None]
    return ((np.abs(_plane_distances(t1, t2)) <= eps).all(axis=1)
            & (np.abs(_plane_distances(t2, t1)) <= eps).all(axis=1))


def _cross2(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def _segments_meet_2d(p, q, r, s) -> np.ndarray:
    """Whether closed 2-D segments p–q and r–s (K, 2) meet (collinear overlaps included)."""
    d1 = _cross2(q - p, r - p)
    d2 = _cross2(q - p, s - p)
    d3 = _cross2(s - r, p - r)
    d4 = _cross2(s - r, q - r)
    proper = (d1 * d2 <= 0) & (d3 * d4 <= 0)
    collinear = (d1 == 0) & (d2 == 0)
    # Collinear: they meet when their boxes overlap.
    lo1, hi1 = np.minimum(p, q), np.maximum(p, q)
    lo2, hi2 = np.minimum(r, s), np.maximum(r, s)
    boxes = ((lo1 <= hi2) & (lo2 <= hi1)).all(axis=1)
    return np.where(collinear, boxes, proper)


def _inside_2d(points: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Whether 2-D points (K, 2) lie in the closed 2-D triangles t (K, 3, 2)."""
    signs = np.stack([_cross2(t[:, (k + 1) % 3] - t[:, k], points - t[:, k]) for k in range(3)],
                     axis=1)
    return (signs >= 0).all(axis=1) | (signs <= 0).all(axis=1)


def coplanar_overlap(t1: np.ndarray, t2: np.ndarray) -> np.ndarray:
    """Whether coplanar triangle pairs (K, 3, 3) overlap, in the plane of the two coordinate
    axes that the first's normal is most across. (K,) bool."""
    normal = np.abs(np.cross(t1[:, 1] - t1[:, 0], t1[:, 2] - t1[:, 0]))
    drop = normal.argmax(axis=1)
    keep = np.array([[1, 2], [0, 2], [0, 1]])[drop]            # (K, 2)
    a = np.take_along_axis(t1, keep[:, None, :], axis=2)       # (K, 3, 2)
    b = np.take_along_axis(t2, keep[:, None, :], axis=2)
    hit = np.zeros(len(t1), dtype=bool)
    for i in range(3):
        for j in range(3):
            hit |= _segments_meet_2d(a[:, i], a[:, (i + 1) % 3], b[:, j], b[:, (j + 1) % 3])
    return hit | _inside_2d(a[:, 0], b) | _inside_2d(b[:, 0], a)


def triangles_intersect(t1: np.ndarray, t2: np.ndarray) -> np.ndarray:
    """Whether the closed triangles t1[k] and t2[k] (K, 3, 3) intersect. (K,) bool."""
    t1 = np.asarray(t1, dtype=np.float64)
    t2 = np.asarray(t2, dtype=np.float64)
    flat = coplanar(t1, t2)
    hit = np.zeros(len(t1), dtype=bool)
    if flat.any():
        hit[flat] = coplanar_overlap(t1[flat], t2[flat])
    rest = ~flat
    if rest.any():
        hit[rest] = edges_meet(t1[rest], t2[rest]) | edges_meet(t2[rest], t1[rest])
    return hit


def edges_meet(t1: np.ndarray, t2: np.ndarray, edges=(0, 1, 2)) -> np.ndarray:
    """Whether any of the listed edges of t1 (edge k from corner k to corner k + 1) meets the
    triangle t2 (K, 3, 3 each). (K,) bool."""
    hit = np.zeros(len(t1), dtype=bool)
    for k in edges:
        hit |= segments_meet_triangles(t1[:, k], t1[:, (k + 1) % 3], t2)
    return hit


def point_triangle_distance(p: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Euclidean distance (K,) from points p (K, 3) to the closed triangles t (K, 3, 3): the
    closest point by the triangle's Voronoi regions (corners, edges, face), as in Ericson's
    Real-Time Collision Detection §5.1.5."""
    a, b, c = t[:, 0], t[:, 1], t[:, 2]
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = _dot(ab, ap), _dot(ac, ap)
    bp = p - b
    d3, d4 = _dot(ab, bp), _dot(ac, bp)
    cp = p - c
    d5, d6 = _dot(ab, cp), _dot(ac, cp)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = va + vb + vc
        v = np.where(denom != 0, vb / denom, 0.0)
        w = np.where(denom != 0, vc / denom, 0.0)
        closest = a + v[:, None] * ab + w[:, None] * ac                        # face
        t_ab = np.clip(d1 / np.where(d1 - d3 != 0, d1 - d3, 1.0), 0, 1)
        t_ac = np.clip(d2 / np.where(d2 - d6 != 0, d2 - d6, 1.0), 0, 1)
        t_bc = np.clip((d4 - d3) / np.where((d4 - d3) + (d5 - d6) != 0,
                                            (d4 - d3) + (d5 - d6), 1.0), 0, 1)
    on_ab = (vc <= 0) & (d1 >= 0) & (d3 <= 0)
    on_ac = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
    on_bc = (va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0)
    closest = np.where(on_bc[:, None], b + t_bc[:, None] * (c - b), closest)
    closest = np.where(on_ac[:, None], a + t_ac[:, None] * ac, closest)
    closest = np.where(on_ab[:, None], a + t_ab[:, None] * ab, closest)
    closest = np.where(((d6 >= 0) & (d5 <= d6))[:, None], c, closest)
    closest = np.where(((d3 >= 0) & (d4 <= d3))[:, None], b, closest)
    closest = np.where(((d1 <= 0) & (d2 <= 0))[:, None], a, closest)
    return np.linalg.norm(p - closest, axis=1)


def winding_numbers(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray,
                    chunk: int = 250_000) -> np.ndarray:
    """The winding number (N,) of a closed, consistently oriented triangle mesh (vertices
    (V, 3), faces (F, 3)) about each point (N, 3): Σ of the faces' solid angles / 4π (Van
    Oosterom and Strackee 1983), ±1 inside (the sign is the orientation's), 0 outside."""
    points = np.asarray(points, dtype=np.float64)
    corners = np.asarray(vertices, dtype=np.float64)[np.asarray(faces)]   # (F, 3, 3)
    out = np.zeros(len(points))
    step = max(1, chunk // max(len(corners), 1))
    for start in range(0, len(points), step):
        r = corners[None] - points[start:start + step, None, None, :]     # (n, F, 3, 3)
        a, b, c = r[:, :, 0], r[:, :, 1], r[:, :, 2]
        la, lb, lc = (np.linalg.norm(x, axis=2) for x in (a, b, c))
        numerator = _dot(a, np.cross(b, c))
        denominator = la * lb * lc + _dot(a, b) * lc + _dot(a, c) * lb + _dot(b, c) * la
        out[start:start + step] = 2 * np.arctan2(numerator, denominator).sum(axis=1)
    return out / (4 * np.pi)
