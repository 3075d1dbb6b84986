"""Plane geometry of constraint sets in the unit square η ∈ [0, 1]² (segments, clipping,
distances) and rotation matrices about an axis (Rodrigues) for prescribed rim rotations."""

from __future__ import annotations

import math

import numpy as np
import torch

Segment = tuple[tuple[float, float], tuple[float, float]]
# Points tested along a segment to decide that it lies inside a masked domain.
SEGMENT_PROBES = 65


def rotations(axis: tuple[float, float, float], angles: torch.Tensor) -> torch.Tensor:
    """Rotation matrices (N, 3, 3) by `angles` (N,) [rad] about `axis` (Rodrigues)."""
    k = np.asarray(axis, dtype=np.float64)
    k = k / np.linalg.norm(k)
    cross = torch.tensor([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]],
                         dtype=angles.dtype, device=angles.device)
    eye = torch.eye(3, dtype=angles.dtype, device=angles.device)
    return (eye + torch.sin(angles)[:, None, None] * cross
            + (1.0 - torch.cos(angles))[:, None, None] * (cross @ cross))


def points_along(start, end) -> list[tuple[float, float]]:
    """SEGMENT_PROBES points from start to end."""
    s = np.linspace(0.0, 1.0, SEGMENT_PROBES)
    return [(start[0] + u * (end[0] - start[0]), start[1] + u * (end[1] - start[1])) for u in s]


def clip_to_unit_square(a, b) -> Segment | None:
    """The part of the infinite line through a and b inside [0, 1]² (Liang–Barsky)."""
    d = (b[0] - a[0], b[1] - a[1])
    lo, hi = -math.inf, math.inf
    for k in range(2):
        if d[k] == 0.0:
            if not 0.0 <= a[k] <= 1.0:
                return None
            continue
        t0, t1 = (0.0 - a[k]) / d[k], (1.0 - a[k]) / d[k]
        lo, hi = max(lo, min(t0, t1)), min(hi, max(t0, t1))
    if lo > hi:
        return None
    return ((a[0] + lo * d[0], a[1] + lo * d[1]), (a[0] + hi * d[0], a[1] + hi * d[1]))


def point_segment_distance(p, a, b) -> float:
    """Distance from point p to the segment a–b."""
    d = (b[0] - a[0], b[1] - a[1])
    dd = d[0] ** 2 + d[1] ** 2
    u = 0.0 if dd == 0.0 else min(1.0, max(0.0, ((p[0] - a[0]) * d[0] + (p[1] - a[1]) * d[1]) / dd))
    return math.hypot(p[0] - a[0] - u * d[0], p[1] - a[1] - u * d[1])


def segment_distance(first: Segment, second: Segment) -> float:
    """Distance between two segments (0 when they cross)."""
    (p, q), (r, s) = first, second

    def orient(a, b, c):
        return (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])

    o1, o2, o3, o4 = orient(p, q, r), orient(p, q, s), orient(r, s, p), orient(r, s, q)
    if o1 * o2 < 0 and o3 * o4 < 0:
        return 0.0
    return min(
        point_segment_distance(p, r, s),
        point_segment_distance(q, r, s),
        point_segment_distance(r, p, q),
        point_segment_distance(s, p, q),
    )
