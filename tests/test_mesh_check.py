"""The independent output-mesh check (taichi_ndf/io/tri_tri.py, io/mesh_check.py) on hand-made
cases whose answer is known, and against brute force over every pair of triangles."""

import numpy as np
import pytest

from taichi_ndf.io.mesh_check import (
    check_mesh,
    crossings,
    distances_to_mesh,
    inside,
    is_closed,
    layer_distance,
    self_intersections,
    welded,
)
from taichi_ndf.io.tri_tri import point_triangle_distance, triangles_intersect, winding_numbers

BASE = np.array([[[0.0, 0, 0], [1, 0, 0], [0, 1, 0]]])


def _one(*corners) -> np.ndarray:
    return np.array([corners], dtype=float)


def test_two_crossing_triangles_intersect_and_moved_apart_do_not():
    crossing = _one([0.2, 0.2, -1], [0.3, 0.2, 1], [0.2, 0.9, 1])
    assert triangles_intersect(BASE, crossing).tolist() == [True]
    assert triangles_intersect(crossing, BASE).tolist() == [True]
    assert triangles_intersect(BASE, crossing + [2, 0, 0]).tolist() == [False]
    # Piercing through the middle of the other without any corner near it.
    spear = _one([0.25, 0.25, -1], [0.25, 0.25, 1], [5, 5, 0.5])
    assert triangles_intersect(BASE, spear).tolist() == [True]
    # Near the hypotenuse x + y = 1: just inside crosses, just outside does not.
    for at, crosses in ((0.49, True), (0.51, False)):
        spear = _one([at, at, -1], [at, at, 1], [at + 5, at - 5, 0.5])
        assert triangles_intersect(BASE, spear).tolist() == [crosses]
        assert triangles_intersect(spear, BASE).tolist() == [crosses]


def test_a_corner_touching_the_other_counts_and_a_hair_above_does_not():
    touch = _one([0.2, 0.2, 0], [0.3, 0.2, 1], [0.2, 0.9, 1])
    assert triangles_intersect(BASE, touch).tolist() == [True]
    assert triangles_intersect(BASE, touch + [0, 0, 1e-6]).tolist() == [False]


def test_coplanar_triangles_overlap_or_not():
    overlap = _one([0.5, 0.5, 0], [-0.5, 0.2, 0], [0.1, -0.5, 0])
    inside_it = _one([0.1, 0.1, 0], [0.2, 0.1, 0], [0.1, 0.2, 0])  # no edges cross
    assert triangles_intersect(BASE, overlap).tolist() == [True]
    assert triangles_intersect(BASE, inside_it).tolist() == [True]
    assert triangles_intersect(inside_it, BASE).tolist() == [True]
    assert triangles_intersect(BASE, overlap + [3, 0, 0]).tolist() == [False]
    # Beside the hypotenuse, in the plane, apart.
    assert triangles_intersect(BASE, _one([0.6, 0.6, 0], [1, 0.6, 0], [0.6, 1, 0])).tolist() \
        == [False]


def test_parallel_triangles_apart_do_not_intersect_and_their_distance_is_the_gap():
    above = BASE + [0, 0, 0.01]
    assert triangles_intersect(BASE, above).tolist() == [False]
    d = point_triangle_distance(above[0], np.repeat(BASE, 3, axis=0))
    assert np.allclose(d, 0.01)


def test_point_triangle_distance_against_dense_sampling():
    rng = np.random.default_rng(1)
    t = rng.normal(size=(1, 3, 3))
    s, r = np.meshgrid(np.linspace(0, 1, 401), np.linspace(0, 1, 401))
    keep = s + r <= 1
    samples = t[0, 0] + s[keep, None] * (t[0, 1] - t[0, 0]) + r[keep, None] * (t[0, 2] - t[0, 0])
    points = rng.normal(scale=2.0, size=(200, 3))
    exact = point_triangle_distance(points, np.repeat(t, len(points), axis=0))
    sampled = np.linalg.norm(points[:, None] - samples[None], axis=2).min(axis=1)
    step = np.linalg.norm(t[0, 1:] - t[0, 0], axis=1).max() / 400
    assert (exact <= sampled + 1e-12).all()
    assert (sampled - exact <= step).all()
    # The three kinds of closest point: a corner, an edge, the face.
    d = point_triangle_distance(np.array([[-1.0, -1, 0], [0.5, -2, 0], [0.2, 0.2, 3]]),
                                np.repeat(BASE, 3, axis=0))
    assert np.allclose(d, [np.sqrt(2), 2, 3])


def _sheet(n: int, size: float = 1.0):
    """A flat n × n grid of vertices in the plane z = 0, two triangles per cell."""
    x, y = np.meshgrid(np.linspace(0, size, n), np.linspace(0, size, n), indexing="ij")
    vertices = np.stack((x.ravel(), y.ravel(), np.zeros(n * n)), axis=1)
    faces = []
    for i in range(n - 1):
        for j in range(n - 1):
            a, b = i * n + j, (i + 1) * n + j
            faces += [[a, b, b + 1], [a, b + 1, a + 1]]
    return vertices, np.array(faces)


def _box(half: float = 1.0):
    corners = half * np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)],
                              dtype=float)
    faces = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                      [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    return corners, faces


def test_a_flat_sheet_has_no_self_intersection_and_two_crossing_sheets_do():
    v, f = _sheet(12)
    assert len(self_intersections(v, f)) == 0
    # A second sheet standing across the first, in the same mesh: they cross along x = 0.5.
    upright = v[:, [2, 1, 0]] + [0.5 + 1e-3, 0, -0.5]
    both = np.concatenate((v, upright))
    faces = np.concatenate((f, f + len(v)))
    pairs = self_intersections(both, faces)
    assert len(pairs) > 0
    assert ((pairs[:, 0] < len(f)) & (pairs[:, 1] >= len(f))).all()
    # Along the line of crossing every cell of the upright sheet is cut: 11 cells of it.
    assert len(np.unique(pairs[:, 1])) >= 11


def test_self_intersections_equal_brute_force_over_every_pair():
    """A crumpled sheet folded over itself: the candidate search drops no intersecting pair
    (every pair of non-adjacent triangles tested exactly, the same answer)."""
    v, f = _sheet(9)
    rng = np.random.default_rng(0)
    x = v[:, 0]
    v = np.stack((np.where(x > 0.5, 1 - x, x), v[:, 1],
                  0.2 * np.sin(9 * x) * np.cos(6 * v[:, 1]) + 0.03 * rng.normal(size=len(v))
                  + 0.01 * (x > 0.5)), axis=1)
    found = {tuple(p) for p in self_intersections(v, f).tolist()}
    i, j = np.triu_indices(len(f), k=1)
    shared = (f[i][:, :, None] == f[j][:, None, :]).sum(axis=(1, 2))
    apart = shared == 0
    brute = triangles_intersect(v[f[i[apart]]], v[f[j[apart]]])
    expected = {(int(a), int(b)) for a, b in zip(i[apart][brute], j[apart][brute], strict=True)}
    assert len(expected) > 10
    assert {p for p in found if not (set(f[p[0]]) & set(f[p[1]]))} == expected


def test_a_fan_folded_through_at_a_shared_vertex_is_found():
    """Two triangles sharing one vertex, the second's far edge through the first."""
    v = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0.3, 0.3, -0.5], [0.3, 0.3, 0.5]])
    assert len(self_intersections(v, np.array([[0, 1, 2], [0, 3, 4]]))) == 1
    v2 = v.copy()
    v2[3:, 0] = -0.3          # the same fan with the second triangle turned away (x < 0)
    assert len(self_intersections(v2, np.array([[0, 1, 2], [0, 3, 4]]))) == 0


def test_a_sheet_inside_a_box_is_inside_without_crossing_and_one_through_it_crosses():
    box_v, box_f = _box(1.0)
    assert is_closed(box_f)
    sheet_v, sheet_f = _sheet(6, size=1.0)
    within = sheet_v - [0.5, 0.5, 0.0]
    assert inside(within, box_v, box_f).all()
    assert len(crossings(within, sheet_f, box_v, box_f)) == 0
    through = sheet_v * 3 - [1.5, 1.5, 0.0]       # 3 m across, out through the sides
    crossed = crossings(through, sheet_f, box_v, box_f)
    assert len(crossed) > 0
    held = inside(through, box_v, box_f)
    assert 0 < held.sum() < len(through)
    assert np.allclose(np.abs(winding_numbers(np.array([[0.0, 0, 0], [3, 0, 0]]), box_v,
                                              box_f)), [1, 0], atol=1e-12)
    report = check_mesh(through, sheet_f, obstacles=[("box", box_v, box_f)])
    assert report.obstacles[0].crossings == len(crossed)
    assert report.obstacles[0].inside == held.sum()
    assert report.obstacles[0].clearance < 0 and not report.clean
    with pytest.raises(ValueError, match="not closed"):
        inside(within, box_v, box_f[:-1])


def test_the_clearance_to_an_obstacle_and_an_open_one_has_no_inside():
    sheet_v, sheet_f = _sheet(6, size=1.0)
    floor_v = np.array([[-5.0, -5, 0], [5, -5, 0], [5, 5, 0], [-5, 5, 0]])
    floor_f = np.array([[0, 1, 2], [0, 2, 3]])
    lifted = sheet_v + [0, 0, 0.003]
    assert np.allclose(distances_to_mesh(lifted, floor_v, floor_f, reach=0.01), 0.003)
    assert np.isinf(distances_to_mesh(lifted + [0, 0, 1], floor_v, floor_f, reach=0.01)).all()
    report = check_mesh(lifted, sheet_f, obstacles=[("floor", floor_v, floor_f)])
    assert report.clean and report.obstacles[0].inside is None
    assert report.obstacles[0].clearance == pytest.approx(0.003)
    sagging = lifted.copy()
    sagging[sagging[:, 0] == 0.4, 2] = -0.01
    report = check_mesh(sagging, sheet_f, obstacles=[("floor", floor_v, floor_f)])
    assert report.obstacles[0].crossings > 0 and not report.clean


def test_the_layer_distance_of_a_folded_sheet_is_the_gap_between_its_layers():
    """A strip folded in half around a crease: the layers 6 mm apart, the crease's own
    neighbours left out by the rest distance."""
    n = 61
    s = np.linspace(0, 0.6, n)
    t = np.linspace(0, 0.1, 6)
    gap, radius = 0.006, 0.003
    centre = 0.3 - np.pi * radius / 2            # the crease: a half circle of radius 3 mm
    points = []
    for a in s:
        if a <= centre:
            points.append((a, 0.0))
        elif a >= centre + np.pi * radius:
            points.append((centre - (a - centre - np.pi * radius), 2 * radius))
        else:
            phi = (a - centre) / radius
            points.append((centre + radius * np.sin(phi), radius * (1 - np.cos(phi))))
    xz = np.array(points)
    vertices = np.array([[x, y, z] for x, z in xz for y in t])
    rest = np.array([[a, y, 0.0] for a in s for y in t])
    faces = []
    m = len(t)
    for i in range(n - 1):
        for j in range(m - 1):
            a, b = i * m + j, (i + 1) * m + j
            faces += [[a, b, b + 1], [a, b + 1, a + 1]]
    faces = np.array(faces)
    assert len(self_intersections(vertices, faces)) == 0
    distance, vertex, _ = layer_distance(vertices, faces, rest, exclusion=0.05, reach=0.05)
    assert distance == pytest.approx(gap, rel=1e-9)
    assert abs(rest[vertex, 0] - 0.3) > 0.05 - 1e-12
    # Without the exclusion the crease's neighbours are the nearest (mesh spacing).
    assert layer_distance(vertices, faces, rest, exclusion=0.0, reach=0.05)[0] == 0.0
    report = check_mesh(vertices, faces, rest_vertices=rest, exclusion=0.05)
    assert report.layer_distance == pytest.approx(gap, rel=1e-9) and report.clean


def test_two_panels_welded_along_their_seam_are_one_mesh_without_self_intersection():
    left, faces = _sheet(5, size=1.0)
    right = left + [1.0, 0, 0]
    vertices = np.concatenate((left, right))
    both = np.concatenate((faces, faces + len(left)))
    joined, joined_faces, kept = welded(vertices, both, tolerance=1e-9)
    assert len(vertices) - len(kept) == 5 and len(joined) == 45
    assert np.array_equal(vertices[kept], joined)
    assert np.allclose(joined[joined_faces], vertices[both])
    assert len(self_intersections(joined, joined_faces)) == 0


def test_a_seam_lapped_within_its_tolerance_is_joined_and_a_wider_lap_is_not():
    """Two panels whose seam edges lie 50 µm apart, lapping by that much (a seam closed to
    within its tolerance): welded at 1 µm the lapped faces cross; with seam_tolerance 0.1 mm
    the edges' vertices are merged and the seam is one mesh; with 10 µm it stays open."""
    left, faces = _sheet(5, size=1.0)
    right = left + [1.0 - 5e-5, 0, 0]
    vertices = np.concatenate((left, right))
    both = np.concatenate((faces, faces + len(left)))
    assert len(self_intersections(*welded(vertices, both, 1e-6)[:2])) > 0
    joined, joined_faces, kept = welded(vertices, both, 1e-6, seam_tolerance=1e-4)
    assert len(vertices) - len(kept) == 5
    assert len(self_intersections(joined, joined_faces)) == 0
    assert len(self_intersections(*welded(vertices, both, 1e-6, seam_tolerance=1e-5)[:2])) > 0


def test_the_seam_tolerance_merges_no_interior_vertex_so_a_crossing_stays_found():
    """A sheet tilted through another, every vertex within 55 µm of one of the other's: a
    weld of all vertices at 0.1 mm makes them one sheet and hides the crossing; the seam
    tolerance merges only the sheets' edge vertices, and the crossing is found."""
    flat, faces = _sheet(7, size=1.0)
    tilted = flat + np.stack((0 * flat[:, 0], 0 * flat[:, 0], (flat[:, 0] - 0.45) * 1e-4), axis=1)
    vertices = np.concatenate((flat, tilted))
    both = np.concatenate((faces, faces + len(flat)))
    assert len(self_intersections(*welded(vertices, both, 1e-4)[:2])) == 0  # hidden
    joined, joined_faces, kept = welded(vertices, both, 1e-6, seam_tolerance=1e-4)
    assert len(vertices) - len(kept) == 4 * 6  # the edge vertices only
    assert len(self_intersections(joined, joined_faces)) > 0
