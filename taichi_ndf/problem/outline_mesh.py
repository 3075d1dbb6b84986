"""A panel's output mesh that reaches its outline: the export grid's cells cut by the border
(issue 30).

The border is cut into a polygon of points on it (`border_points`): every edge at each grid
line it crosses, each arc further into pieces of at most `CHECK_ANGLE` (its vertices on the
arc, its chords inside one cell), and at any extra fractions of an edge's arclength asked for
(a seam's two sides sampled at the same parameters, so the seam's vertices coincide after
sewing). A point within 1e-12 (relative) of a grid line is put on it, so a crossing is one
point shared by the two cells it joins.

Each cell of the grid (`cut_cells`): one the border does not enter keeps its two grid
triangles if its centre is inside (nothing if outside); one it enters is the region of the
cell left of the border's pieces in it: the pieces joined, from where each leaves the cell to
where the next enters, by the cell's sides counter-clockwise (passing its corners), then each
closed loop ear-clipped (`ear_clip`). A cell whose one loop is its four corners (a border along
grid lines) keeps its grid triangles, so a rectangle or an outline on grid lines gives the
grid's faces exactly. Neighbouring cells share every vertex on their common side (the grid
corners and the border's crossings), so the mesh conforms; its vertices are grid corners
inside the outline or on it, and border points (exactly on the border, arcs included).
"""

from __future__ import annotations

import math

import numpy as np

from taichi_ndf.problem.arcs import snapped
from taichi_ndf.problem.outline import CHECK_ANGLE, Outline
from taichi_ndf.problem.polygon import cross, ear_clip

Point = tuple[float, float]


def edge_fractions(outline: Outline, i: int, cuts, extra=()) -> list[float]:
    """Fractions 0 = t₀ < … < t_n = 1 of edge e_i's arclength: its crossings of the lines
    ξ¹ = cuts[0][k], ξ² = cuts[1][k], an arc's pieces of at most `CHECK_ANGLE`, and `extra`."""
    arc = outline.arcs[i]
    if arc is not None:
        ts = set(arc.splits(CHECK_ANGLE, cuts))
    else:
        a, b = outline.edge_points(i)
        ts = {0.0, 1.0}
        for axis in range(2):
            if a[axis] == b[axis]:
                continue
            for value in cuts[axis]:
                t = (float(value) - a[axis]) / (b[axis] - a[axis])
                if 1e-12 < t < 1.0 - 1e-12:
                    ts.add(t)
    ts.update(float(t) for t in extra if 1e-12 < t < 1.0 - 1e-12)
    ordered = sorted(ts)
    kept = [ordered[0]]
    for t in ordered[1:]:
        if t - kept[-1] > 1e-12:
            kept.append(t)
    kept[-1] = 1.0
    return kept


def border_points(outline: Outline, cuts, fractions: dict[int, np.ndarray] | None = None
                  ) -> list[Point]:
    """The border as a closed polygon of points on it, counter-clockwise (module docstring);
    fractions: extra fractions of arclength per edge number."""
    fractions = fractions or {}
    points: list[Point] = []
    for i, arc in enumerate(outline.arcs):
        ts = edge_fractions(outline, i, cuts, fractions.get(i, ()))
        a, b = (np.asarray(p, float) for p in outline.edge_points(i))
        inner = np.asarray(ts[1:-1])
        at = arc.at(inner) if arc is not None else a + inner[:, None] * (b - a)
        points.append(snapped(outline.points[i], cuts))
        points.extend(snapped(p, cuts) for p in at)
    return points


def _side_parameter(p: Point, box) -> float:
    """Where p on the side of box = ((x0, x1), (y0, y1)) lies, counter-clockwise from (x0, y0):
    0–1 along the bottom, 1–2 the right, 2–3 the top, 3–4 the left."""
    (x0, x1), (y0, y1) = box
    tol = 1e-9 * max(x1 - x0, y1 - y0)
    if abs(p[1] - y0) <= tol:
        return (p[0] - x0) / (x1 - x0)
    if abs(p[0] - x1) <= tol:
        return 1.0 + (p[1] - y0) / (y1 - y0)
    if abs(p[1] - y1) <= tol:
        return 2.0 + (x1 - p[0]) / (x1 - x0)
    if abs(p[0] - x0) <= tol:
        return 3.0 + (y1 - p[1]) / (y1 - y0)
    raise ValueError(f"point {p} is on no side of the cell {box}")


def cell_loops(chains: list[list[Point]], box) -> list[list[Point]]:
    """The closed loops (points, counter-clockwise) of the cell box's part left of the border
    `chains` (each the border's points in order through the cell, from where it enters to
    where it leaves: module docstring)."""
    (x0, x1), (y0, y1) = box
    corners = [((x0, y0), 0.0), ((x1, y0), 1.0), ((x1, y1), 2.0), ((x0, y1), 3.0)]
    if len(chains) == 1 and chains[0][0] == chains[0][-1]:  # the whole border in one cell
        return [chains[0][:-1]]
    entry = [_side_parameter(c[0], box) for c in chains]
    exit_ = [_side_parameter(c[-1], box) for c in chains]
    left, loops = set(range(len(chains))), []
    while left:
        first = current = min(left)
        loop: list[Point] = []
        while True:
            left.discard(current)
            loop.extend(chains[current])
            gap = [(entry[k] - exit_[current]) % 4.0 for k in range(len(chains))]
            nxt = min(range(len(chains)), key=lambda k: gap[k])
            loop.extend(p for p, tau in sorted(corners, key=lambda c: (c[1] - exit_[current])
                                               % 4.0)
                        if 0.0 < (tau - exit_[current]) % 4.0 < gap[nxt])
            if nxt == first:
                break
            current = nxt
        loops.append([p for k, p in enumerate(loop) if p != loop[k - 1]])
    return loops


def cut_cells(outline: Outline, xs: np.ndarray, ys: np.ndarray,
              fractions: dict[int, np.ndarray] | None = None
              ) -> tuple[np.ndarray, list[Point], list[tuple[Point, Point, Point]]]:
    """The grid with lines ξ¹ = xs (n1 + 1,), ξ² = ys (n2 + 1,) cut by the outline: whether each
    cell (n2, n1) keeps its two grid triangles, and the border points and triangles (corners,
    counter-clockwise) of the cells the border enters (module docstring); fractions: extra
    fractions of arclength per edge (`border_points`)."""
    cuts = (list(map(float, xs)), list(map(float, ys)))
    n1, n2 = len(xs) - 1, len(ys) - 1
    polygon = border_points(outline, cuts, fractions)
    m = len(polygon)
    size = max(xs[-1] - xs[0], ys[-1] - ys[0])
    cell_of = []
    for k in range(m):
        a, b = np.asarray(polygon[k]), np.asarray(polygon[(k + 1) % m])
        d = b - a
        probe = 0.5 * (a + b) + 1e-9 * size * np.array([-d[1], d[0]]) / np.hypot(*d)
        i = min(n1 - 1, max(0, int(np.searchsorted(xs, probe[0], side="right")) - 1))
        j = min(n2 - 1, max(0, int(np.searchsorted(ys, probe[1], side="right")) - 1))
        cell_of.append((i, j))
    chains: dict[tuple[int, int], list[list[Point]]] = {}
    start = next((k for k in range(m) if cell_of[k] != cell_of[k - 1]), 0)
    for step in range(m):
        k = (start + step) % m
        if step == 0 or cell_of[k] != cell_of[k - 1]:
            chains.setdefault(cell_of[k], []).append([polygon[k]])
        chains[cell_of[k]][-1].append(polygon[(k + 1) % m])
    centres = np.stack(np.meshgrid(0.5 * (xs[:-1] + xs[1:]), 0.5 * (ys[:-1] + ys[1:])), -1)
    whole = outline.contains(centres.reshape(-1, 2)).reshape(n2, n1)
    triangles = []
    for (i, j), cell_chains in chains.items():
        box = ((float(xs[i]), float(xs[i + 1])), (float(ys[j]), float(ys[j + 1])))
        loops = cell_loops(cell_chains, box)
        full = (len(loops) == 1 and len(loops[0]) == 4
                and {p for p in loops[0]} == {(x, y) for x in box[0] for y in box[1]})
        whole[j, i] = full
        if full:
            continue
        area = (box[0][1] - box[0][0]) * (box[1][1] - box[1][0])
        for loop in loops:
            for tri in ear_clip(loop, degenerate_last=True):
                corners = tuple(loop[q] for q in tri)
                if cross(*corners) > 1e-12 * area:
                    triangles.append(corners)
    return whole, polygon, triangles


def conforming_mesh(outline: Outline, grid, fractions: dict[int, np.ndarray] | None = None
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The export grid (`io.grid_mesh`, open) cut to the outline: vertices ξ (V, 2) [m] (the
    grid's used ones in their order, then the border's), faces (F, 3), counter-clockwise (the
    whole cells' grid faces in the grid's order, then the cut cells': `cut_cells`) and UVs
    (V, 2) (the grid's; a border point's its ξ scaled to the grid's box)."""
    xs, ys = grid.lines
    whole, _, triangles = cut_cells(outline, xs, ys, fractions)
    keep = np.concatenate([whole.ravel(), whole.ravel()])
    index = {(float(x), float(y)): k for k, (x, y) in enumerate(grid.xi)}
    points = [tuple(p) for p in grid.xi]
    extra = []
    for tri in triangles:
        row = []
        for p in tri:
            if p not in index:
                index[p] = len(points)
                points.append(p)
            row.append(index[p])
        extra.append(row)
    faces = np.concatenate([grid.faces[keep], np.asarray(extra, np.int64).reshape(-1, 3)])
    xi = np.asarray(points, float)
    lo = np.array([xs[0], ys[0]])
    uv = np.concatenate([grid.uv, (xi[len(grid.xi):] - lo) / (np.array([xs[-1], ys[-1]]) - lo)])
    used = np.unique(faces)
    remap = -np.ones(len(points), dtype=np.int64)
    remap[used] = np.arange(len(used))
    return xi[used], remap[faces], uv[used]


def seam_fractions(outlines, cuts, seams) -> list[dict[int, list[float]]]:
    """Per panel, the extra fractions of arclength per edge number (`border_points`) that
    sample each seam's two sides at the same parameters: a side's own (`edge_fractions` at its
    panel's grid lines) given to the other side too (s there, or 1 − s for a reversed seam),
    so after sewing the seam's vertices coincide to its gap (and an output check welds them).
    outlines: per panel its `Outline` (None: a panel without one); cuts: per panel its grid
    lines (xs, ys); seams: (panel a, edge a, panel b, edge b, reversed) each."""
    extra: list[dict[int, list[float]]] = [{} for _ in outlines]
    for a, edge_a, b, edge_b, reverse in seams:
        if outlines[a] is None or outlines[b] is None:
            continue
        own_a = edge_fractions(outlines[a], edge_a, cuts[a])
        own_b = edge_fractions(outlines[b], edge_b, cuts[b])
        extra[a].setdefault(edge_a, []).extend(1.0 - t if reverse else t for t in own_b)
        extra[b].setdefault(edge_b, []).extend(1.0 - t if reverse else t for t in own_a)
    return extra


def chord_error(outline: Outline) -> float:
    """The largest sagitta [m] of the border polygon's chords of an arc (pieces of at most
    `CHECK_ANGLE`): how far the mesh's border may lie inside an outward arc."""
    radii = [arc.radius for arc in outline.arcs if arc is not None]
    return max(radii, default=0.0) * (1.0 - math.cos(CHECK_ANGLE / 2))
