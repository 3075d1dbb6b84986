"""An output mesh checked for crossings, independently of the solver: self-intersections,
crossings of and vertices inside an obstacle's triangulated surface, the clearance to it and
the smallest distance between two layers of a fold (numpy and scipy only; the primitives in
`io/tri_tri.py`, nothing from the contact path).

Candidate pairs of triangles: centroids closer than the sum of the two triangles' circumradii
about their centroids (every corner within that radius), found with scipy's cKDTree; every
candidate is then tested exactly. Lengths in the mesh's units (metres for a run's meshes).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from taichi_ndf.io.tri_tri import (
    edges_meet,
    point_triangle_distance,
    triangles_intersect,
    winding_numbers,
)

CHUNK = 2048  # points whose candidate pairs are found and measured at once


def _spheres(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Centroids (F, 3) and the radii (F,) of spheres about them holding each triangle."""
    corners = vertices[faces]
    centroid = corners.mean(axis=1)
    return centroid, np.linalg.norm(corners - centroid[:, None], axis=2).max(axis=1)


def _as_mesh(vertices, faces) -> tuple[np.ndarray, np.ndarray]:
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    if v.ndim != 2 or v.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3:
        raise ValueError(f"a triangle mesh needs vertices (V, 3) and faces (F, 3), got "
                         f"{v.shape} and {f.shape}")
    return v, f


def _near_pairs(centres_a, radii_a, centres_b, radii_b) -> np.ndarray:
    """Index pairs (K, 2) (a, b) whose holding spheres overlap."""
    if not len(centres_a) or not len(centres_b):
        return np.zeros((0, 2), dtype=np.int64)
    lists = cKDTree(centres_b).query_ball_point(centres_a, radii_a + radii_b.max())
    i = np.repeat(np.arange(len(centres_a)), [len(x) for x in lists])
    j = np.fromiter((k for x in lists for k in x), dtype=np.int64, count=len(i))
    near = np.linalg.norm(centres_a[i] - centres_b[j], axis=1) <= (radii_a[i] + radii_b[j]) * (
        1 + 1e-9)
    return np.stack((i[near], j[near]), axis=1)


def _chunks(count: int, size: int = CHUNK):
    for start in range(0, count, size):
        yield np.arange(start, min(start + size, count))


def self_intersections(vertices, faces) -> np.ndarray:
    """Pairs (K, 2), i < j, of faces of one mesh that intersect. Pairs sharing an edge (two
    vertices) are neighbours and skipped; pairs sharing one vertex touch there and intersect
    only when the edge of one opposite the shared vertex meets the other (the general,
    non-coplanar case: a coplanar fan folded onto itself is not seen)."""
    v, f = _as_mesh(vertices, faces)
    centres, radii = _spheres(v, f)
    found = [np.zeros((0, 2), dtype=np.int64)]
    for rows in _chunks(len(f)):
        pairs = _near_pairs(centres[rows], radii[rows], centres, radii)
        pairs[:, 0] = rows[pairs[:, 0]]
        pairs = pairs[pairs[:, 0] < pairs[:, 1]]
        found.append(pairs[_intersect_in_one_mesh(v, f, pairs)])
    return np.concatenate(found)


def _intersect_in_one_mesh(v: np.ndarray, f: np.ndarray, pairs: np.ndarray) -> np.ndarray:
    same = f[pairs[:, 0]][:, :, None] == f[pairs[:, 1]][:, None, :]       # (K, 3, 3)
    shared = same.sum(axis=(1, 2))
    hit = np.zeros(len(pairs), dtype=bool)
    apart = shared == 0
    hit[apart] = triangles_intersect(v[f[pairs[apart, 0]]], v[f[pairs[apart, 1]]])
    one = np.flatnonzero(shared == 1)
    if len(one):
        t1, t2 = v[f[pairs[one, 0]]], v[f[pairs[one, 1]]]
        # Edge k runs from corner k to k + 1: the edge opposite corner c is (c + 1) % 3.
        c1 = same[one].any(axis=2).argmax(axis=1)
        c2 = same[one].any(axis=1).argmax(axis=1)
        for c in range(3):
            first, second = c1 == c, c2 == c
            hit[one[first]] |= edges_meet(t1[first], t2[first], edges=((c + 1) % 3,))
            hit[one[second]] |= edges_meet(t2[second], t1[second], edges=((c + 1) % 3,))
    return hit


def crossings(vertices, faces, other_vertices, other_faces) -> np.ndarray:
    """Pairs (K, 2) (face of the first mesh, face of the second) that intersect."""
    v, f = _as_mesh(vertices, faces)
    w, g = _as_mesh(other_vertices, other_faces)
    centres, radii = _spheres(v, f)
    others = _spheres(w, g)
    found = [np.zeros((0, 2), dtype=np.int64)]
    for rows in _chunks(len(f)):
        pairs = _near_pairs(centres[rows], radii[rows], *others)
        pairs[:, 0] = rows[pairs[:, 0]]
        found.append(pairs[triangles_intersect(v[f[pairs[:, 0]]], w[g[pairs[:, 1]]])])
    return np.concatenate(found)


def boundary_vertices(faces, count: int) -> np.ndarray:
    """Whether each of `count` vertices is on the mesh's boundary: an end of an edge that
    only one face has (count,) bool."""
    f = np.asarray(faces, dtype=np.int64)
    edges = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    unique, counts = np.unique(edges, axis=0, return_counts=True)
    on = np.zeros(count, dtype=bool)
    on[unique[counts == 1].ravel()] = True
    return on


def welded(vertices, faces, tolerance: float, *, seam_tolerance: float = 0.0
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The mesh with vertices closer than `tolerance` [m] merged into one (the first of each
    group): panels' meshes joined along their seams. seam_tolerance [m]: also the vertices
    on the boundary of the mesh as given (`boundary_vertices`: the panels' own edges, before
    any merge) closer than this merged — a sewn seam counts as joined where its two sides
    are within its stated tolerance; interior vertices are merged at `tolerance` only, so a
    crossing away from the panels' edges is never hidden. Returns (vertices, faces, the
    indices of the vertices kept (the same selection for another array per vertex))."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    v, f = _as_mesh(vertices, faces)
    pairs = cKDTree(v).query_pairs(tolerance, output_type="ndarray")
    if seam_tolerance > tolerance:
        edge = np.flatnonzero(boundary_vertices(f, len(v)))
        near = cKDTree(v[edge]).query_pairs(seam_tolerance, output_type="ndarray")
        pairs = np.concatenate((pairs.reshape(-1, 2), edge[near].reshape(-1, 2)))
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(v),) * 2)
    count, label = connected_components(graph, directed=False)
    first = np.full(count, len(v))
    np.minimum.at(first, label, np.arange(len(v)))
    keep = np.unique(first)
    index = np.searchsorted(keep, first[label])
    return v[keep], index[f], keep


def is_closed(faces) -> bool:
    """Whether every edge of the mesh is shared by exactly two faces (a closed surface)."""
    f = np.asarray(faces, dtype=np.int64)
    edges = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    return bool(len(counts)) and bool((counts == 2).all())


def inside(points, vertices, faces) -> np.ndarray:
    """Whether each point (N, 3) is inside the closed mesh: |winding number| > 1/2 (points
    outside the mesh's bounding box are outside without computing it). (N,) bool."""
    p = np.asarray(points, dtype=np.float64)
    v, f = _as_mesh(vertices, faces)
    if not is_closed(f):
        raise ValueError("inside: the mesh is not closed (an edge not shared by two faces)")
    box = ((p >= v.min(axis=0)) & (p <= v.max(axis=0))).all(axis=1)
    out = np.zeros(len(p), dtype=bool)
    out[box] = np.abs(winding_numbers(p[box], v, f)) > 0.5
    return out


def distances_to_mesh(points, vertices, faces, reach: float) -> np.ndarray:
    """Each point's (N, 3) distance to the nearest triangle of the mesh, inf where none is
    within `reach` (N,). Points taken CHUNK at a time (the candidate pairs' memory)."""
    p = np.asarray(points, dtype=np.float64)
    v, f = _as_mesh(vertices, faces)
    centres, radii = _spheres(v, f)
    out = np.full(len(p), np.inf)
    for rows in _chunks(len(p)):
        pairs = _near_pairs(p[rows], np.full(len(rows), float(reach)), centres, radii)
        if len(pairs):
            d = point_triangle_distance(p[rows[pairs[:, 0]]], v[f[pairs[:, 1]]])
            np.minimum.at(out, rows[pairs[:, 0]], d)
    out[out > reach] = np.inf
    return out


def layer_distance(vertices, faces, rest_vertices, exclusion: float, reach: float
                   ) -> tuple[float, int, int]:
    """The smallest distance between a vertex and a triangle of the same mesh that were at
    least `exclusion` apart at rest (the rest distance: from the vertex's rest position to
    the nearest rest corner of the triangle): the gap between two layers of a fold, the
    surface's neighbours left out. Returns (distance, vertex, face); (inf, -1, -1) where no
    such pair is within `reach`."""
    v, f = _as_mesh(vertices, faces)
    rest = np.asarray(rest_vertices, dtype=np.float64)
    if rest.shape != v.shape:
        raise ValueError(f"layer_distance: rest vertices {rest.shape} do not match {v.shape}")
    centres, radii = _spheres(v, f)
    best = (np.inf, -1, -1)
    for rows in _chunks(len(v)):
        pairs = _near_pairs(v[rows], np.full(len(rows), float(reach)), centres, radii)
        pairs[:, 0] = rows[pairs[:, 0]]
        at_rest = np.linalg.norm(rest[f[pairs[:, 1]]] - rest[pairs[:, 0], None],
                                 axis=2).min(axis=1)
        pairs = pairs[at_rest >= exclusion]
        if not len(pairs):
            continue
        d = point_triangle_distance(v[pairs[:, 0]], v[f[pairs[:, 1]]])
        k = int(d.argmin())
        if d[k] < best[0]:
            best = (float(d[k]), int(pairs[k, 0]), int(pairs[k, 1]))
    return best if best[0] <= reach else (np.inf, -1, -1)


@dataclass(frozen=True)
class ObstacleCheck:
    """One obstacle against the mesh: `crossings` pairs of triangles that intersect,
    `inside` vertices within it (None: its surface is not closed, no inside), `clearance`
    [m] the smallest distance of a vertex to its surface (negative: the deepest inside
    vertex's; inf: none within reach)."""

    name: str
    crossings: int
    inside: int | None
    clearance: float


@dataclass(frozen=True)
class MeshCheck:
    """What `check_mesh` found: vertex and face counts, self-intersecting face pairs, one
    `ObstacleCheck` per obstacle, and the layer distance [m] (None: not asked)."""

    vertices: int
    faces: int
    self_intersections: int
    obstacles: tuple[ObstacleCheck, ...]
    layer_distance: float | None

    @property
    def clean(self) -> bool:
        """No self-intersection, no crossing of an obstacle, no vertex inside one."""
        return self.self_intersections == 0 and all(
            o.crossings == 0 and not o.inside for o in self.obstacles)


def check_mesh(vertices, faces, obstacles=(), rest_vertices=None, exclusion: float = 0.0,
               reach: float = 0.05, layer_reach: float | None = None) -> MeshCheck:
    """Check a triangle mesh (vertices (V, 3) [m], faces (F, 3)): its self-intersections,
    against each obstacle (name, vertices, faces) its crossings, the vertices inside it
    (closed surfaces only) and the clearance within `reach` [m], and with `rest_vertices`
    (V, 3) the layer distance over pairs at least `exclusion` [m] apart at rest, within
    `layer_reach` [m] (default `reach`; its cost grows with its square)."""
    v, f = _as_mesh(vertices, faces)
    found = []
    for name, ov, of in obstacles:
        ov, of = _as_mesh(ov, of)
        distance = distances_to_mesh(v, ov, of, reach)
        within = inside(v, ov, of) if is_closed(of) else None
        if within is not None and within.any():
            distance = np.where(within, -distance, distance)
        found.append(ObstacleCheck(
            name=str(name), crossings=len(crossings(v, f, ov, of)),
            inside=None if within is None else int(within.sum()),
            clearance=float(distance.min()) if len(distance) else np.inf))
    layers = None
    if rest_vertices is not None:
        layers = layer_distance(v, f, rest_vertices, exclusion,
                                reach if layer_reach is None else layer_reach)[0]
    return MeshCheck(vertices=len(v), faces=len(f),
                     self_intersections=len(self_intersections(v, f)),
                     obstacles=tuple(found), layer_distance=layers)
