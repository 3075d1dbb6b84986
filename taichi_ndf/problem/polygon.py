"""Plane polygons (points (x, y) [m] in order): signed areas, ear clipping, clipping to a
rectangle and a segment-crossing test; what a panel's outline (`taichi_ndf.problem.outline`),
its trimmed quadrature and its output mesh are cut with."""

from __future__ import annotations

import math


def cross(o, a, b) -> float:
    """(a − o) × (b − o): twice the signed area of the triangle o, a, b (> 0 counter-clockwise)."""
    return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])


def polygon_area(piece) -> float:
    """The area of a convex polygon (points in counter-clockwise order) [m²]."""
    return 0.5 * sum(cross(piece[0], piece[k], piece[k + 1]) for k in range(1, len(piece) - 1))


def ear_clip(points, degenerate_last: bool = False) -> list[tuple[int, int, int]]:
    """Triangles (index triples, counter-clockwise) of a simple counter-clockwise polygon
    (n − 2 of them; a collinear vertex is clipped as a zero-area ear). degenerate_last: an ear
    of (nearly: 1e-12 of the polygon's extent squared) zero area is clipped only where no
    other is left, so a point on a side stays a corner of a triangle with area (the output
    mesh's cells: `outline_mesh`)."""
    points = [tuple(p) for p in points]
    left = list(range(len(points)))
    extent = max(max(p[k] for p in points) - min(p[k] for p in points) for k in range(2))
    passes = (1e-12 * extent * extent, 0.0) if degenerate_last else (0.0,)
    triangles = []
    while len(left) > 3:
        for least in passes:
            k = _ear(points, left, least)
            if k is not None:
                break
        else:
            raise ValueError("ear clipping found no ear: the polygon is not simple and "
                             "counter-clockwise")
        triangles.append((left[k - 1], left[k], left[(k + 1) % len(left)]))
        del left[k]
    triangles.append(tuple(left))
    return triangles


def _ear(points, left: list[int], least: float) -> int | None:
    """The first k whose corner left[k] is an ear of the polygon `left` (its triangle's
    doubled area at least `least` and no other point in it), or None."""
    for k in range(len(left)):
        i, j, m = left[k - 1], left[k], left[(k + 1) % len(left)]
        a, b, c = points[i], points[j], points[m]
        if cross(a, b, c) < least:
            continue
        if any(cross(a, b, points[q]) >= 0 and cross(b, c, points[q]) >= 0
               and cross(c, a, points[q]) >= 0 and points[q] not in (a, b, c)
               for q in left if q not in (i, j, m)):
            continue
        return k
    return None


def clip_to_box(polygon: list, box) -> list:
    """Sutherland–Hodgman: the part of `polygon` (points, in order) inside the rectangle
    box = ((x0, x1), (y0, y1)), as points in order (fewer than 3: nothing inside)."""
    for k, bound, keep in ((0, box[0][0], 1), (0, box[0][1], -1),
                           (1, box[1][0], 1), (1, box[1][1], -1)):
        if not polygon:
            break
        out = []
        for index, p in enumerate(polygon):
            q = polygon[index - 1]
            p_in, q_in = keep * (p[k] - bound) >= 0, keep * (q[k] - bound) >= 0
            if p_in != q_in:
                t = (bound - q[k]) / (p[k] - q[k])
                cut = [q[0] + t * (p[0] - q[0]), q[1] + t * (p[1] - q[1])]
                cut[k] = bound
                out.append(tuple(cut))
            if p_in:
                out.append(p)
        polygon = out
    return polygon


def _on_segment(p, a, b, tol: float) -> bool:
    """Whether p (collinear with a, b to `tol`) lies within the segment's box."""
    return (min(a[0], b[0]) - tol <= p[0] <= max(a[0], b[0]) + tol
            and min(a[1], b[1]) - tol <= p[1] <= max(a[1], b[1]) + tol)


def segments_meet(a, b, c, d, tol: float) -> bool:
    """Whether the closed segments ab and cd share a point (`tol` [m²] on the cross products,
    [m] on the boxes)."""
    d1, d2 = cross(c, d, a), cross(c, d, b)
    d3, d4 = cross(a, b, c), cross(a, b, d)
    if ((d1 > tol and d2 < -tol) or (d1 < -tol and d2 > tol)) and \
            ((d3 > tol and d4 < -tol) or (d3 < -tol and d4 > tol)):
        return True
    scale = math.sqrt(tol)
    return any(abs(cr) <= tol and _on_segment(p, s, e, scale)
               for cr, p, s, e in ((d1, a, c, d), (d2, b, c, d), (d3, c, a, b), (d4, d, a, b)))
