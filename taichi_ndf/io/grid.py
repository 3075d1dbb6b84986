"""Regular triangulated grids over a rectangle of surface coordinates ξ."""

from dataclasses import dataclass

import numpy as np

__all__ = ["GridMesh", "grid_mesh"]


@dataclass(frozen=True)
class GridMesh:
    """A triangulated grid of the parameter rectangle [lo1, hi1] x [lo2, hi2].

    Vertex (i, j), i along ξ¹ (0..n1) and j along ξ² (0..n2), has index j (n1 + 1) + i, so
    ``xi.reshape(n2 + 1, n1 + 1, 2)`` is laid out like an image with ξ¹ along the columns.
    A periodic coordinate keeps its seam duplicated: the last column (ξ = hi) lies on the same
    surface points as the first (ξ = lo). That keeps per-vertex UVs valid everywhere (textures
    wrap correctly, OBJ and PLY need no special case); ``canonical`` tells which vertices
    coincide, for anything that must treat the surface as closed (normals, welding).

    xi: surface coordinates of the vertices, shape (V, 2).
    faces: triangles, vertex indices counter-clockwise in the (ξ¹, ξ²) plane, so their normal
        points along r_,1 x r_,2; shape (F, 3), int64.
    uv: texture coordinates (ξ - lo) / (hi - lo) in [0, 1], shape (V, 2).
    canonical: for each vertex, the index of the first vertex at the same surface point (itself
        unless it sits on the far side of a periodic seam), shape (V,), int64.
    cells: number of grid cells along (ξ¹, ξ²).
    """

    xi: np.ndarray
    faces: np.ndarray
    uv: np.ndarray
    canonical: np.ndarray
    cells: tuple[int, int]

    @property
    def lines(self) -> tuple[np.ndarray, np.ndarray]:
        """The grid lines: their ξ¹ values (n1 + 1,) and ξ² values (n2 + 1,)."""
        n1 = self.cells[0]
        return self.xi[:n1 + 1, 0], self.xi[::n1 + 1, 1]


def grid_mesh(
    domain_bounds,
    resolution: int | tuple[int, int],
    *,
    periodic: tuple[bool, bool] = (False, False),
) -> GridMesh:
    """Triangulate the parameter rectangle with ``resolution`` cells per coordinate.

    domain_bounds: ((lo1, hi1), (lo2, hi2)) in the units of ξ.
    resolution: cells along both coordinates, or (cells along ξ¹, cells along ξ²). Grids whose
        cell counts divide one another share vertices (a 32-cell grid's vertices are on the
        256-cell grid).
    periodic: which coordinates wrap around; see `GridMesh` for how the seam is kept.
    """
    (lo1, hi1), (lo2, hi2) = np.asarray(domain_bounds, dtype=np.float64)
    if not (hi1 > lo1 and hi2 > lo2):
        raise ValueError(f"domain_bounds must satisfy lo < hi per coordinate, got {domain_bounds}")
    n1, n2 = (resolution, resolution) if np.isscalar(resolution) else resolution
    if int(n1) != n1 or int(n2) != n2 or n1 < 1 or n2 < 1:
        raise ValueError(f"resolution must be positive integers of cells, got {resolution}")
    n1, n2 = int(n1), int(n2)

    u1, u2 = np.meshgrid(np.linspace(0.0, 1.0, n1 + 1), np.linspace(0.0, 1.0, n2 + 1))
    uv = np.stack([u1.ravel(), u2.ravel()], axis=1)
    xi = np.stack([lo1 + (hi1 - lo1) * uv[:, 0], lo2 + (hi2 - lo2) * uv[:, 1]], axis=1)

    corner = (np.arange(n2)[:, None] * (n1 + 1) + np.arange(n1)[None, :]).ravel()
    right, up, diagonal = corner + 1, corner + n1 + 1, corner + n1 + 2
    faces = np.concatenate(
        [np.stack([corner, right, diagonal], axis=1), np.stack([corner, diagonal, up], axis=1)]
    ).astype(np.int64)

    i, j = np.meshgrid(np.arange(n1 + 1), np.arange(n2 + 1))
    if periodic[0]:
        i = np.where(i == n1, 0, i)
    if periodic[1]:
        j = np.where(j == n2, 0, j)
    canonical = (j * (n1 + 1) + i).ravel().astype(np.int64)
    return GridMesh(xi=xi, faces=faces, uv=uv, canonical=canonical, cells=(n1, n2))
