"""A panel's exported mesh reaches its outline, curved edges included (issue 30:
`taichi_ndf.problem.outline_mesh`, `app.outputs.export_grid`)."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from taichi_ndf.app.outputs import export_grid
from taichi_ndf.io import grid_mesh
from taichi_ndf.problem.outline import CHECK_ANGLE, Outline, OutlinePlane

SQUARE = Outline(((0, 0), (1, 0), (1, 1), (0, 1)))
L_SHAPES = (Outline(((0, 0), (1, 0), (1, 0.5), (0.5, 0.5), (0.5, 1), (0, 1))),
            Outline(((0, 0), (0.5, 0), (0.5, 0.5), (1, 0.5), (1, 1), (0, 1))))
NOTCH = Outline(((0, 0), (1, 0), (1, 1), (0.7, 1), (0.3, 1), (0, 1)), (0, 0, 0, -1, 0, 0))
CURVED = Outline(((0.3, 0.2), (0.9, 0.1), (1.1, 0.8), (0.2, 0.9)), (0.3, -0.2, 0.4, 0.1))


def _export(outline: Outline, resolution, chart=None):
    plane = OutlinePlane(outline=outline, chart=chart)
    return export_grid(SimpleNamespace(surface=plane), resolution)


def _areas(xi: np.ndarray, faces: np.ndarray) -> np.ndarray:
    a, b, c = (xi[faces[:, k]] for k in range(3))
    return 0.5 * ((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1])
                  - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0]))


def _boundary_edges(faces: np.ndarray) -> tuple[np.ndarray, int]:
    """Edges used by one face, and the most faces any edge is used by."""
    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]),
                    axis=1)
    unique, count = np.unique(edges, axis=0, return_counts=True)
    return unique[count == 1], int(count.max())


def _chord_area(outline: Outline) -> float:
    """The most area [m²] the border polygon's chords of arcs (at most CHECK_ANGLE each) may
    miss or add: per arc, its length times ⅔ its chords' sagitta."""
    return sum(arc.length * 2 / 3 * arc.radius * (1 - math.cos(CHECK_ANGLE / 2))
               for arc in outline.arcs if arc is not None)


@pytest.mark.parametrize("outline", [NOTCH, CURVED, L_SHAPES[0]], ids=["notch", "curved", "L"])
@pytest.mark.parametrize("resolution", [(16, 16), (23, 31)])
def test_export_covers_the_outline(outline, resolution):
    """The faces' areas add up to the outline's to the chords' error, none is flipped or
    empty, every vertex is inside or on the outline, every edge is shared by at most two faces
    (the mesh conforms) and each edge on one face only lies on the border (its ends on it, its
    middle within a chord's sagitta). Before: the staircase missed up to a cell along arcs."""
    xi, faces, uv = _export(outline, resolution)
    areas = _areas(xi, faces)
    assert areas.min() > 0
    assert abs(areas.sum() - outline.area) <= _chord_area(outline) + 1e-12
    assert outline.contains(xi).all()
    border, most = _boundary_edges(faces)
    assert most <= 2
    ends = xi[border.ravel()]
    assert np.abs(outline.nearest_on_border(ends) - ends).max() < 1e-12
    middle = 0.5 * (xi[border[:, 0]] + xi[border[:, 1]])
    sagitta = max([a.radius * (1 - math.cos(CHECK_ANGLE / 2)) for a in outline.arcs if a],
                  default=0.0)
    assert np.linalg.norm(outline.nearest_on_border(middle) - middle, axis=1).max() \
        <= sagitta + 1e-12
    (x0, x1), (y0, y1) = outline.bounds
    assert np.allclose(uv, (xi - [x0, y0]) / [x1 - x0, y1 - y0])


def test_notch_border_vertices_on_the_arc():
    """The notch's (a half disc cut into the top edge) border vertices lie on its arc, at least
    one per grid line it crosses."""
    xi, faces, _ = _export(NOTCH, (16, 16))
    border, _ = _boundary_edges(faces)
    ends = np.unique(border.ravel())
    arc = NOTCH.arcs[3]
    radius = np.linalg.norm(xi[ends] - arc.centre, axis=1)
    on_arc = np.abs(radius - arc.radius) < 1e-12
    assert on_arc.sum() >= 2 * 6 + 1  # 0.4 m wide and deep 0.2 m: 6 + 6 grid-line crossings
    assert (xi[ends[on_arc], 1] <= 1 + 1e-12).all()


@pytest.mark.parametrize("outline", [SQUARE, *L_SHAPES], ids=["square", "L", "L2"])
def test_outline_on_grid_lines_gives_the_grid_faces(outline):
    """An outline along grid lines exports the grid's own faces, in the grid's order: those
    whose corners are all inside (the rule before)."""
    xi, faces, uv = _export(outline, (8, 8))
    grid = grid_mesh(outline.bounds, (8, 8))
    inside = outline.contains(grid.xi)
    centre = grid.xi[grid.faces].mean(axis=1)
    old = grid.faces[inside[grid.faces].all(axis=1) & outline.contains(centre)]
    used = np.unique(old)
    remap = -np.ones(len(grid.xi), dtype=np.int64)
    remap[used] = np.arange(len(used))
    assert np.array_equal(faces, remap[old])
    assert np.array_equal(xi, grid.xi[used])
    assert np.array_equal(uv, grid.uv[used])


def test_chart_larger_than_the_outline():
    """A chart that holds the outline with room to spare meshes the outline only."""
    xi, faces, _ = _export(CURVED, (24, 24), chart=((0.0, 1.5), (-0.2, 1.2)))
    assert abs(_areas(xi, faces).sum() - CURVED.area) <= _chord_area(CURVED) + 1e-12
    assert CURVED.contains(xi).all()


def test_unmasked_chart_unchanged():
    """A plain rectangle (no outline) exports the grid as it is."""
    from taichi_ndf.geometry import Plane

    plane = Plane(bounds=((0.0, 2.0), (0.0, 1.0)))
    xi, faces, uv = export_grid(SimpleNamespace(surface=plane), (5, 3))
    grid = grid_mesh(((0.0, 2.0), (0.0, 1.0)), (5, 3))
    assert np.array_equal(xi, grid.xi) and np.array_equal(faces, grid.faces)
    assert np.array_equal(uv, grid.uv)


def _fractions_on(outline: Outline, i: int, xi: np.ndarray) -> np.ndarray:
    """The fractions of edge e_i's arclength of the points of ξ (N, 2) that lie on it."""
    arc = outline.arcs[i]
    a, b = (np.asarray(p, float) for p in outline.edge_points(i))
    if arc is None:
        d = b - a
        t = (xi - a) @ d / float(d @ d)
        off = np.abs((xi[:, 0] - a[0]) * d[1] - (xi[:, 1] - a[1]) * d[0]) / np.hypot(*d)
        return np.sort(t[(off < 1e-12) & (t > -1e-12) & (t < 1 + 1e-12)])
    rel = xi - arc.centre
    on = np.abs(np.hypot(rel[:, 0], rel[:, 1]) - arc.radius) < 1e-12
    turn = np.mod(np.arctan2(rel[:, 1], rel[:, 0]) - arc.start_angle, 2 * math.pi)
    if arc.angle < 0:
        turn = np.where(turn > 1e-12, turn - 2 * math.pi, 0.0)
    t = turn / arc.angle
    return np.sort(t[on & (t > -1e-12) & (t < 1 + 1e-12)])


@pytest.mark.parametrize("reverse", [False, True])
def test_seam_sides_sampled_alike(reverse):
    """A seam's two sides, on panels with different grids (a straight side to a straight one,
    an arc cut in to an arc bulging out; lengths not checked here), get border vertices at the
    same fractions of their arclength (s ↔ 1 − s where reversed): the seam's vertices coincide
    after sewing. Before: each side had only its own grid's crossings."""
    from taichi_ndf.problem.outline_mesh import conforming_mesh, seam_fractions

    body = Outline(((0, 0), (0.4, 0), (0.4, 0.5), (0, 0.5)), (0, -0.3, 0, 0))
    sleeve = Outline(((0, 0), (0.5, 0.05), (0.45, 0.6), (0.05, 0.5)), (0, 0.2, 0, 0))
    grids = [grid_mesh(o.bounds, r) for o, r in ((body, (13, 17)), (sleeve, (19, 11)))]
    cuts = [(g.xi[:g.cells[0] + 1, 0], g.xi[::g.cells[0] + 1, 1]) for g in grids]
    seams = ((0, 1, 1, 1, reverse), (0, 3, 1, 3, reverse))
    border = seam_fractions([body, sleeve], cuts, seams)
    meshes = [conforming_mesh(o, g, b) for o, g, b in zip((body, sleeve), grids, border,
                                                           strict=True)]
    for edge in (1, 3):
        t_a = _fractions_on(body, edge, meshes[0][0])
        t_b = _fractions_on(sleeve, edge, meshes[1][0])
        if reverse:
            t_b = np.sort(1.0 - t_b)
        assert len(t_a) == len(t_b) > 13
        assert np.abs(t_a - t_b).max() < 1e-9
    for (xi, faces, _), outline in zip(meshes, (body, sleeve), strict=True):
        assert _areas(xi, faces).min() > 0
        assert abs(_areas(xi, faces).sum() - outline.area) <= _chord_area(outline) + 1e-12
