"""A panel's outline: a closed polygon of the flat pattern, optionally with curved edges
(issue 30), and its edges.

`Outline`: points (x, y) [m] counter-clockwise, at least 3, no zero-length edge, no two edges
crossing or touching other than neighbours at their shared point; edge e_i runs from point i
to point i + 1 (the last from the last point to the first), straight, or a circular arc where
point i has a bulge β_i ≠ 0 (`taichi_ndf.problem.arcs.Arc`: θ = 4 atan β, β < 0 cut into the
panel). The panel's chart is the plane of the outline, ξ = (x, y) [m], over the outline's
bounding box (`bounds`, arcs included); the trimmed quadrature
(`taichi_ndf.discretise.trimmed`) integrates over the inside only, arcs as arcs.

Checks and the inside: the polygon of the points with each arc cut into chords
(`flattened`) is what the crossing test and the ear clipping of `area_in` see (chords of at
most `CHECK_ANGLE`: an arc's sagitta there is R (1 − cos(CHECK_ANGLE/2)), 0.1 % of R); the
area, the bounds, `contains` and `nearest_on_border` are those of the arcs themselves.

`PolygonEdge`: one edge as a path in ξ from `start` to `end` (a segment or an arc), the outline
on its left (counter-clockwise), so its outward normal is the right-hand normal of its
direction: what a seam (`taichi_ndf.objective.seam.SeamTerm`) takes as one of its sides.

`OutlinePlane`: the panel's flat rest surface, a `Plane` over the bounding box whose domain is
masked to the outline.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
import torch

from taichi_ndf.geometry import Plane
from taichi_ndf.geometry.domain import ParameterDomain
from taichi_ndf.problem.arcs import MAX_ANGLE, Arc, bulge_angle, snapped
from taichi_ndf.problem.polygon import clip_to_box, cross, ear_clip, polygon_area, segments_meet

Point = tuple[float, float]

# Largest angle [rad] of an arc's chord in the polygon that the checks and `area_in` see.
CHECK_ANGLE = math.pi / 32


@dataclass(frozen=True)
class PolygonEdge:
    """Edge `edge` (a name, e.g. "front.e2") of an outline from start to end in ξ [m], the
    outline on its left: the segment (bulge 0) or the arc of that bulge (`Arc`)."""

    edge: str
    start: Point
    end: Point
    bulge: float = 0.0

    def path(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """At fractions s (M,) of its arclength: ξ (M, 2), dξ/ds (M, 2) [m] (constant speed:
        the edge's length) and the unit outward normal (M, 2), float64."""
        s = np.asarray(s, float)
        arc = Arc.of_bulge(self.start, self.end, self.bulge)
        if arc is not None:
            return arc.path(s)
        a, b = np.asarray(self.start, float), np.asarray(self.end, float)
        d = b - a
        normal = np.array([d[1], -d[0]]) / np.hypot(*d)
        return (a + s[:, None] * d, np.broadcast_to(d, (len(s), 2)).copy(),
                np.broadcast_to(normal, (len(s), 2)).copy())


@dataclass(frozen=True)
class Outline:
    """A closed outline (module docstring); points [(x, y), …] [m]; bulges: one per edge
    e_i (0 straight; None: all straight). Raises ValueError naming the edge for fewer than 3
    points, a non-finite coordinate or bulge, a zero-length edge, two edges that cross or
    touch (a self-intersecting outline) and clockwise points."""

    points: tuple[Point, ...]
    bulges: tuple[float, ...] | None = None

    def __post_init__(self):
        try:
            points = tuple((float(x), float(y)) for x, y in self.points)
        except (TypeError, ValueError) as err:
            raise ValueError(f"outline: expected points [[x, y], ...], got {self.points!r}"
                             ) from err
        object.__setattr__(self, "points", points)
        n = len(points)
        if n < 3:
            raise ValueError(f"outline: a polygon needs at least 3 points, got {n}")
        if not all(math.isfinite(v) for p in points for v in p):
            raise ValueError("outline: the points must be finite numbers [m]")
        bulges = (0.0,) * n if self.bulges is None else tuple(self.bulges)
        if len(bulges) != n:
            raise ValueError(f"outline: {len(bulges)} bulges for {n} edges")
        for i, bulge in enumerate(bulges):
            if not (isinstance(bulge, (int, float)) and math.isfinite(bulge)
                    and abs(bulge_angle(bulge)) < MAX_ANGLE):
                raise ValueError(f"outline: edge e{i}: the bulge must be a finite number "
                                 f"(tan of a quarter of the arc's angle), got {bulge!r}")
        object.__setattr__(self, "bulges", tuple(float(b) for b in bulges))
        size = max(max(p[k] for p in points) - min(p[k] for p in points) for k in range(2))
        tol = 1e-12 * size * size
        for i in range(n):
            a, b = self.edge_points(i)
            if math.hypot(b[0] - a[0], b[1] - a[1]) <= 1e-12 * size:
                raise ValueError(f"outline: edge e{i} has zero length (points {i} and "
                                 f"{(i + 1) % n} coincide)")
        flat, owner = self.flattened(CHECK_ANGLE)
        m = len(flat)
        for i in range(m):
            for j in range(i + 1, m):
                neighbours = j == i + 1 or (i == 0 and j == m - 1)
                if owner[i][0] == owner[j][0]:  # chords of one arc: apart, or neighbours
                    continue
                a, b = flat[i], flat[(i + 1) % m]
                c, d = flat[j], flat[(j + 1) % m]
                i_edge, j_edge = owner[i][0], owner[j][0]
                if neighbours:  # meeting at their shared point only: not folding back
                    shared, other_i, other_j = (b, a, d) if j == i + 1 else (a, b, c)
                    if abs(cross(shared, other_i, other_j)) <= tol and (
                            (other_i[0] - shared[0]) * (other_j[0] - shared[0])
                            + (other_i[1] - shared[1]) * (other_j[1] - shared[1]) > 0):
                        raise ValueError(f"outline: edges e{i_edge} and e{j_edge} overlap (the "
                                         "outline folds back on itself)")
                elif segments_meet(a, b, c, d, tol):
                    raise ValueError(f"outline: edges e{i_edge} and e{j_edge} cross or touch "
                                     "(a self-intersecting outline)")
        if self.area <= 0:
            raise ValueError("outline: the points run clockwise; list them counter-clockwise "
                             "(the panel on the left of each edge)")

    @functools.cached_property
    def arcs(self) -> tuple[Arc | None, ...]:
        """Each edge's arc (None: straight); made once (the checks, `contains`, `bounds` and
        `nearest_on_border` all walk them)."""
        return tuple(Arc.of_bulge(*self.edge_points(i), b) for i, b in enumerate(self.bulges))

    def flattened(self, max_angle: float, cuts=((), ())
                  ) -> tuple[list[Point], list[tuple[int, Arc | None]]]:
        """The outline as a polygon: its points with each arc cut into chords of at most
        `max_angle` [rad] and at its crossings of the lines ξ¹ = cuts[0][k], ξ² = cuts[1][k]
        (`Arc.splits`; a crossing's coordinate set to the line's value exactly); per polygon
        edge, its outline edge's number and the piece of arc it is the chord of (None: a
        straight edge)."""
        flat, pieces = [], []
        n = len(self.points)
        for i, arc in enumerate(self.arcs):
            if arc is None:
                flat.append(self.points[i])
                pieces.append((i, None))
                continue
            ts = arc.splits(max_angle, cuts)
            ends = ([self.points[i]] + [snapped(p, cuts) for p in arc.at(np.array(ts[1:-1]))]
                    + [self.points[(i + 1) % n]])
            for k in range(len(ts) - 1):
                flat.append(ends[k])
                pieces.append((i, Arc(ends[k], ends[k + 1], arc.angle * (ts[k + 1] - ts[k]))))
        return flat, pieces

    @property
    def area(self) -> float:
        """The signed area [m²] (shoelace of the points, plus each arc's segment; > 0
        counter-clockwise)."""
        p = np.asarray(self.points)
        x, y = p[:, 0], p[:, 1]
        polygon = 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y))
        return polygon + sum(arc.segment_area for arc in self.arcs if arc is not None)

    @property
    def bounds(self) -> tuple[tuple[float, float], tuple[float, float]]:
        """The bounding box ((x_min, x_max), (y_min, y_max)) [m]: the panel's chart."""
        points = list(self.points)
        for arc in self.arcs:
            if arc is not None:
                points.extend(arc.extremes())
        return tuple((min(p[k] for p in points), max(p[k] for p in points)) for k in range(2))

    @property
    def edges(self) -> tuple[str, ...]:
        """The edge names e0, e1, …"""
        return tuple(f"e{i}" for i in range(len(self.points)))

    def edge_points(self, i: int) -> tuple[Point, Point]:
        """Edge e_i's start and end points."""
        return self.points[i], self.points[(i + 1) % len(self.points)]

    def index(self, edge: str) -> int:
        """The number i of edge "e<i>" (ValueError naming the edges for another name)."""
        if edge not in self.edges:
            raise ValueError(f"no edge {edge!r} (edges: {', '.join(self.edges)})")
        return int(edge[1:])

    def edge(self, edge: str, label: str | None = None) -> PolygonEdge:
        """Edge `edge` ("e<i>") as a `PolygonEdge` named `label` (default `edge`)."""
        i = self.index(edge)
        start, end = self.edge_points(i)
        return PolygonEdge(label or edge, start, end, self.bulges[i])

    def box_side(self, edge: str) -> str:
        """The side of the bounding box ("xi1_min", "xi1_max", "xi2_min", "xi2_max") that edge
        `edge` lies on; ValueError where it lies on none (a slanted or inner edge)."""
        (x0, x1), (y0, y1) = self.bounds
        a, b = self.edge_points(self.index(edge))
        if self.bulges[self.index(edge)]:
            raise ValueError(f"edge {edge!r} is curved: it lies on no side of the outline's "
                             "bounding box")
        tol = 1e-12 * max(x1 - x0, y1 - y0)
        for side, k, value in (("xi1_min", 0, x0), ("xi1_max", 0, x1),
                               ("xi2_min", 1, y0), ("xi2_max", 1, y1)):
            if abs(a[k] - value) <= tol and abs(b[k] - value) <= tol:
                return side
        raise ValueError(f"edge {edge!r} ({list(a)} to {list(b)}) is not on a side of the "
                         f"outline's bounding box")

    def on_side(self, side: str) -> tuple[str, ...]:
        """The edges that lie on bounding-box side `side`."""
        found = []
        for edge in self.edges:
            try:
                if self.box_side(edge) == side:
                    found.append(edge)
            except ValueError:
                pass
        return tuple(found)

    @functools.cached_property
    def triangles(self) -> tuple[tuple[Point, Point, Point], ...]:
        """The outline cut into triangles (`ear_clip` of `flattened` at `CHECK_ANGLE`: arcs as
        chords), as their corners."""
        flat = self.flattened(CHECK_ANGLE)[0]
        return tuple(tuple(flat[i] for i in tri) for tri in ear_clip(flat))

    def area_in(self, box) -> float:
        """The area [m²] of the outline's part inside the rectangle box = ((x0, x1), (y0, y1))
        (its ear-clipped triangles clipped to the box; arcs as the chords of `triangles`)."""
        area = 0.0
        for corners in self.triangles:
            if (max(c[0] for c in corners) <= box[0][0] or min(c[0] for c in corners) >= box[0][1]
                    or max(c[1] for c in corners) <= box[1][0]
                    or min(c[1] for c in corners) >= box[1][1]):
                continue
            piece = clip_to_box(corners, box)
            if len(piece) >= 3:
                area += polygon_area(piece)
        return area

    def nearest_on_border(self, xi: np.ndarray) -> np.ndarray:
        """The point of the outline's border (its edges) nearest to each ξ (N, 2) [m]."""
        xi = np.asarray(xi, float)
        best = np.full(len(xi), np.inf)
        out = xi.copy()
        for i, arc in enumerate(self.arcs):
            if arc is not None:
                foot, dist = arc.nearest(xi)
            else:
                a, b = (np.asarray(p, float) for p in self.edge_points(i))
                d = b - a
                t = np.clip((xi - a) @ d / float(d @ d), 0.0, 1.0)
                foot = a + t[:, None] * d
                dist = np.linalg.norm(xi - foot, axis=1)
            closer = dist < best
            best[closer], out[closer] = dist[closer], foot[closer]
        return out

    def contains(self, xi: np.ndarray) -> np.ndarray:
        """Whether each point ξ (N, 2) is inside or on the border (crossing number of the
        points' polygon, flipped inside each arc's circular segment; within 1e-12 of the
        outline's size of an edge counts as on it: the closed outline, so the outputs' faces
        reach the border and a seam's two sides meet there); bool (N,)."""
        xi = np.asarray(xi, float)
        inside = np.zeros(len(xi), bool)
        for i in range(len(self.points)):
            (ax, ay), (bx, by) = self.edge_points(i)
            up = (ay <= xi[:, 1]) != (by <= xi[:, 1])
            with np.errstate(divide="ignore", invalid="ignore"):
                x = ax + (xi[:, 1] - ay) * (bx - ax) / (by - ay)
            inside ^= up & (xi[:, 0] < x)
        for arc in self.arcs:
            if arc is not None:
                inside ^= arc.in_segment(xi)
        (x0, x1), (y0, y1) = self.bounds
        near = np.linalg.norm(self.nearest_on_border(xi) - xi, axis=1)
        return inside | (near <= 1e-12 * max(x1 - x0, y1 - y0))


@dataclass(frozen=True)
class OutlinePlane(Plane):
    """A polygon panel's flat rest surface: the `Plane` over the outline's bounding box (or a
    larger `chart` rectangle holding it), its domain masked to the outline (so outputs mesh the
    outline only, `domain.area` is its area and probes outside it are refused). bounds: set
    from `chart` or the outline (any given are replaced)."""

    outline: Outline | None = None
    chart: tuple[tuple[float, float], tuple[float, float]] | None = None

    def __post_init__(self):
        if not isinstance(self.outline, Outline):
            raise ValueError(f"an outline plane needs an Outline, got {self.outline!r}")
        box = self.outline.bounds
        bounds = box if self.chart is None else ParameterDomain(self.chart).bounds
        if not all(lo <= b_lo and b_hi <= hi for (lo, hi), (b_lo, b_hi) in zip(bounds, box,
                                                                            strict=True)):
            raise ValueError(f"the chart {bounds} does not hold the outline's bounding box "
                             f"{box}")
        object.__setattr__(self, "bounds", tuple(bounds))
        super().__post_init__()

    @property
    def domain(self) -> ParameterDomain:
        outline = self.outline
        return ParameterDomain(self.bounds, inside=lambda xi: torch.from_numpy(
            outline.contains(xi.detach().cpu().numpy())).to(xi.device),
            mask_area=outline.area)
