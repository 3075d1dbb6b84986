"""Reference surface fitted to a template triangle mesh over its UV chart.

The surface coordinates ξ are the mesh's UVs. The triangle mesh itself is only C⁰, so the
reference surface is a smooth fit: a tensor-product uniform cubic B-spline (C²) over the UV
bounding rectangle, found by least squares on the vertex positions plus a light thin-plate
penalty (which fixes the control points of cells with no vertices and does not bias affine
maps: a planar mesh with affine UVs is reproduced to round-off). Physical lengths come from r,
so UVs in [0, 1] are fine.
"""

from __future__ import annotations

import logging
import math
from pathlib import Path

import numpy as np
import torch

from taichi_ndf.geometry.domain import ParameterDomain
from taichi_ndf.geometry.surface import ReferenceSurface

log = logging.getLogger(__name__)

# Vertices per spline cell used to choose the default number of cells.
_VERTICES_PER_CELL = 4
_MAX_CELLS = 48
# Barycentric tolerance of the inside test: points on the chart's boundary are inside.
_INSIDE_TOL = 1e-9
# A UV or 3D triangle whose area is below this fraction of the median area is degenerate.
_DEGENERATE = 1e-10

# 4-point Gauss–Legendre rule on [0, 1]: exact for the degree-6 products of cubic B-splines.
_GAUSS_X = 0.5 + 0.5 * np.array(
    [-0.8611363115940526, -0.3399810435848563, 0.3399810435848563, 0.8611363115940526]
)
_GAUSS_W = 0.5 * np.array(
    [0.3478548451374538, 0.6521451548625461, 0.6521451548625461, 0.3478548451374538]
)


def _basis(f, order: int):
    """Uniform cubic B-spline basis (…, 4) at local cell coordinates f ∈ [0, 1] (derivatives
    with respect to f). Works on numpy arrays and torch tensors."""
    g = 1 - f
    if order == 0:
        parts = (
            g**3 / 6,
            (3 * f**3 - 6 * f**2 + 4) / 6,
            (-3 * f**3 + 3 * f**2 + 3 * f + 1) / 6,
            f**3 / 6,
        )
    elif order == 1:
        parts = (-(g**2) / 2, (3 * f**2 - 4 * f) / 2, (-3 * f**2 + 2 * f + 1) / 2, f**2 / 2)
    else:
        parts = (g, 3 * f - 2, 1 - 3 * f, f)
    if isinstance(f, torch.Tensor):
        return torch.stack(parts, dim=-1)
    return np.stack(parts, axis=-1)


def _gram(cells: int, order: int) -> np.ndarray:
    """∫ B_a^(k) B_b^(k) over [0, cells] in cell units, shape (cells + 3, cells + 3)."""
    gram = np.zeros((cells + 3, cells + 3))
    b = _basis(_GAUSS_X, order)  # (4 Gauss points, 4 functions)
    local = np.einsum("q,qa,qb->ab", _GAUSS_W, b, b)
    for i in range(cells):
        gram[i : i + 4, i : i + 4] += local
    return gram


class _UVChart:
    """Point location in the UV triangles through a uniform bucket grid."""

    def __init__(self, uv: np.ndarray, faces: np.ndarray):
        self.corners = uv[faces]  # (F, 3, 2)
        self.lo = self.corners.min(axis=(0, 1))
        self.span = self.corners.max(axis=(0, 1)) - self.lo
        self.grid = max(1, int(math.sqrt(len(faces))))
        cell_lo = self._cell(self.corners.min(axis=1))
        cell_hi = self._cell(self.corners.max(axis=1))
        # Every (bucket, triangle) pair of each triangle's bounding box of buckets.
        rows = cell_hi[:, 1] - cell_lo[:, 1] + 1
        count = (cell_hi[:, 0] - cell_lo[:, 0] + 1) * rows
        face = np.repeat(np.arange(len(faces)), count)
        local = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
        i = cell_lo[face, 0] + local // rows[face]
        j = cell_lo[face, 1] + local % rows[face]
        pairs = np.stack((i * self.grid + j, face), axis=1)
        pairs = pairs[np.argsort(pairs[:, 0], kind="stable")]
        counts = np.bincount(pairs[:, 0], minlength=self.grid**2)
        starts = np.concatenate(([0], np.cumsum(counts)[:-1]))
        self.table = np.full((self.grid**2, counts.max()), -1, dtype=np.int64)
        slot = np.arange(len(pairs)) - starts[pairs[:, 0]]
        self.table[pairs[:, 0], slot] = pairs[:, 1]

    def _cell(self, points: np.ndarray) -> np.ndarray:
        t = (points - self.lo) / self.span * self.grid
        return np.clip(np.floor(t).astype(np.int64), 0, self.grid - 1)

    def covering(self, points: np.ndarray, tol: float) -> tuple[np.ndarray, np.ndarray]:
        """Candidate triangles (N, K) of each point (−1 = none) and whether the point lies in
        each (barycentric coordinates ≥ −tol)."""
        cell = self._cell(points)
        cand = self.table[cell[:, 0] * self.grid + cell[:, 1]]
        tri = self.corners[np.maximum(cand, 0)]  # (N, K, 3, 2)
        a, b, c = tri[:, :, 0], tri[:, :, 1], tri[:, :, 2]
        p = points[:, None, :]

        def cross(u, v):
            return u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]

        area = cross(b - a, c - a)
        with np.errstate(divide="ignore", invalid="ignore"):
            l1 = cross(c - b, p - b) / area
            l2 = cross(a - c, p - c) / area
        l3 = 1.0 - l1 - l2
        inside = (cand >= 0) & (l1 >= -tol) & (l2 >= -tol) & (l3 >= -tol)
        return cand, inside

    def contains(self, xi: torch.Tensor) -> torch.Tensor:
        """Whether each ξ (N, 2) lies in a UV triangle; bool tensor (N,)."""
        points = xi.detach().cpu().double().numpy()
        inside = self.covering(points, _INSIDE_TOL)[1].any(axis=1)
        return torch.from_numpy(inside).to(xi.device)


class MeshSurface(ReferenceSurface):
    """A reference surface fitted (C², cubic B-spline) to a triangle mesh with UVs.

    vertices: positions [m], shape (V, 3); faces: vertex indices (F, 3); uv: surface
        coordinates of the vertices (V, 2), one chart without overlaps.
    cells: spline cells along the longer UV side (default: about 4 vertices per cell, at most
        48); the other side gets a proportional number.
    smoothing: weight of the thin-plate energy of the spline (in cell units) relative to the
        mean squared vertex residual. It biases curved fits towards flat ones, so the default
        1e-6 is just enough to fix the control points of cells without vertices (on the bowl
        template 1e-3 gave 5 % curvature error, 1e-6 gives 0.07 %).

    The parameter domain is the UV bounding rectangle, masked by the UV triangles unless they
    cover it; its area is the UV chart's area. After fitting, `fit_error_max` and
    `fit_error_rms` hold the distance [m] between the fitted surface and the vertices.
    Raises ValueError naming the problem for a mesh that is not a valid single UV chart.
    """

    def __init__(
        self,
        vertices,
        faces,
        uv,
        *,
        cells: int | None = None,
        smoothing: float = 1e-6,
        name: str = "mesh",
    ):
        vertices = np.asarray(vertices, dtype=np.float64)
        faces = np.asarray(faces)
        uv = np.asarray(uv, dtype=np.float64)
        _validate(vertices, faces, uv, name)
        faces = faces.astype(np.int64)
        if cells is not None and not (isinstance(cells, int) and 1 <= cells <= 256):
            raise ValueError(f"cells must be an integer in [1, 256], got {cells!r}")
        if not (math.isfinite(smoothing) and smoothing > 0):
            raise ValueError(f"smoothing must be positive, got {smoothing!r}")
        self.name = name
        self.vertices = torch.from_numpy(vertices)
        self.faces = torch.from_numpy(faces)
        self.uv = torch.from_numpy(uv)

        chart = _UVChart(uv, faces)
        _check_overlaps(chart, faces, name)
        lo, hi = chart.lo, chart.lo + chart.span
        bounds = ((float(lo[0]), float(hi[0])), (float(lo[1]), float(hi[1])))
        chart_area = float(np.abs(_uv_areas(uv, faces)).sum())
        rect_area = float(np.prod(hi - lo))
        self.domain = ParameterDomain(
            bounds,
            inside=None if chart_area >= rect_area * (1 - 1e-9) else chart.contains,
            mask_area=None if chart_area >= rect_area * (1 - 1e-9) else chart_area,
        )

        used = torch.from_numpy(np.unique(faces))
        self.cells = self._choose_cells(cells, len(used), rect_area / chart_area, hi - lo)
        self.control_points = torch.from_numpy(
            self._fit(uv[used.numpy()], vertices[used.numpy()], smoothing)
        )
        distance = (self.positions(self.uv[used]) - self.vertices[used]).norm(dim=1)
        self.fit_error_max = float(distance.max())
        self.fit_error_rms = float(distance.square().mean().sqrt())
        log.info(
            "%s: %d vertices, %d triangles, %d x %d spline cells, fit error max %.3g m, rms %.3g m",
            name,
            len(vertices),
            len(faces),
            *self.cells,
            self.fit_error_max,
            self.fit_error_rms,
        )

    @classmethod
    def from_file(cls, path: str | Path, **options) -> MeshSurface:
        """Load an OBJ or PLY mesh with UVs (`read_mesh`: vertex order preserved, polygons
        triangulated) and fit it; `options` are those of the constructor."""
        from taichi_ndf.io import read_mesh

        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"mesh file {path} does not exist")
        mesh = read_mesh(path)
        uv = mesh.uvs
        if uv is None or len(uv) != len(mesh.vertices):
            raise ValueError(
                f"{path.name}: the mesh has no UV coordinates (one per vertex; trimesh also "
                "drops them when the file has vertices that no face uses)"
            )
        return cls(mesh.vertices, mesh.faces, uv, name=path.name, **options)

    def jets(self, xi: torch.Tensor) -> torch.Tensor:
        """Jets of r at ξ (N, 2): (N, 6, 3), r [m] and its derivatives with respect to UV."""
        (lo1, hi1), (lo2, hi2) = self.domain.bounds
        n1, n2 = self.cells
        h1, h2 = (hi1 - lo1) / n1, (hi2 - lo2) / n2
        t1, t2 = (xi[:, 0] - lo1) / h1, (xi[:, 1] - lo2) / h2
        # Points slightly outside the rectangle use the polynomial of the nearest cell.
        i1 = t1.floor().clamp(0, n1 - 1).long()
        i2 = t2.floor().clamp(0, n2 - 1).long()
        f1, f2 = t1 - i1, t2 - i2
        offsets = torch.arange(4, device=xi.device)
        ctrl = self.control_points.to(dtype=xi.dtype, device=xi.device)
        patch = ctrl[(i1[:, None] + offsets)[:, :, None], (i2[:, None] + offsets)[:, None, :]]
        b1 = [_basis(f1, k) / h1**k for k in range(3)]
        b2 = [_basis(f2, k) / h2**k for k in range(3)]

        def mix(k1, k2):
            return (b1[k1][:, :, None, None] * b2[k2][:, None, :, None] * patch).sum((1, 2))

        return torch.stack((mix(0, 0), mix(1, 0), mix(0, 1), mix(2, 0), mix(1, 1), mix(0, 2)), 1)

    @staticmethod
    def _choose_cells(cells, n_vertices, rect_over_chart, sides) -> tuple[int, int]:
        aspect = sides[0] / sides[1]
        if cells is None:
            total = n_vertices * rect_over_chart / _VERTICES_PER_CELL
            longer = math.sqrt(total * max(aspect, 1 / aspect))
            cells = int(min(_MAX_CELLS, max(1, round(longer))))
        other = max(1, round(cells / max(aspect, 1 / aspect)))
        return (cells, other) if aspect >= 1 else (other, cells)

    def _fit(self, uv: np.ndarray, positions: np.ndarray, smoothing: float) -> np.ndarray:
        """Control points (n1 + 3, n2 + 3, 3) minimising mean |r(uv) − x|² + smoothing × mean
        thin-plate energy per cell (in cell units)."""
        (lo1, hi1), (lo2, hi2) = self.domain.bounds
        n1, n2 = self.cells
        m1, m2 = n1 + 3, n2 + 3
        t1 = (uv[:, 0] - lo1) / (hi1 - lo1) * n1
        t2 = (uv[:, 1] - lo2) / (hi2 - lo2) * n2
        i1 = np.clip(np.floor(t1).astype(np.int64), 0, n1 - 1)
        i2 = np.clip(np.floor(t2).astype(np.int64), 0, n2 - 1)
        b1, b2 = _basis(t1 - i1, 0), _basis(t2 - i2, 0)
        # Each vertex touches 4 × 4 control points: flat indices and basis products (V, 16).
        index = (
            (i1[:, None] + np.arange(4))[:, :, None] * m2 + (i2[:, None] + np.arange(4))[:, None, :]
        ).reshape(len(uv), 16)
        value = (b1[:, :, None] * b2[:, None, :]).reshape(len(uv), 16)
        size = m1 * m2
        normal = np.bincount(
            (index[:, :, None] * size + index[:, None, :]).ravel(),
            weights=(value[:, :, None] * value[:, None, :]).ravel(),
            minlength=size * size,
        ).reshape(size, size) / len(uv)
        rhs = np.stack(
            [
                np.bincount(
                    index.ravel(), weights=(value * positions[:, c : c + 1]).ravel(), minlength=size
                )
                for c in range(3)
            ],
            axis=1,
        ) / len(uv)
        g1 = [_gram(n1, k) for k in range(3)]
        g2 = [_gram(n2, k) for k in range(3)]
        thin_plate = np.kron(g1[2], g2[0]) + 2 * np.kron(g1[1], g2[1]) + np.kron(g1[0], g2[2])
        system = normal + smoothing * thin_plate / (n1 * n2)
        return np.linalg.solve(system, rhs).reshape(m1, m2, 3)


def _uv_areas(uv: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Signed UV areas of the triangles (F,), positive for counter-clockwise corners."""
    a, b, c = uv[faces[:, 0]], uv[faces[:, 1]], uv[faces[:, 2]]
    e1, e2 = b - a, c - a
    return 0.5 * (e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])


def _listing(indices: np.ndarray) -> str:
    shown = ", ".join(str(int(i)) for i in indices[:5])
    return f"{shown}{', …' if len(indices) > 5 else ''} ({len(indices)} in all)"


def _validate(vertices: np.ndarray, faces: np.ndarray, uv: np.ndarray, name: str) -> None:
    if vertices.ndim != 2 or vertices.shape[1] != 3:
        raise ValueError(f"{name}: vertices must have shape (V, 3), got {vertices.shape}")
    if uv.shape != (len(vertices), 2):
        raise ValueError(
            f"{name}: needs one UV coordinate pair per vertex, shape ({len(vertices)}, 2); "
            f"got {uv.shape}"
        )
    if faces.ndim != 2 or faces.shape[1] != 3 or len(faces) == 0:
        raise ValueError(
            f"{name}: faces must be a non-empty (F, 3) array of triangles, got {faces.shape}"
        )
    if not np.issubdtype(faces.dtype, np.integer):
        raise ValueError(f"{name}: face indices must be integers, got {faces.dtype}")
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise ValueError(f"{name}: face indices out of range [0, {len(vertices)})")
    bad = np.flatnonzero(~np.isfinite(vertices).all(axis=1))
    if len(bad):
        raise ValueError(f"{name}: non-finite (NaN or inf) positions at vertices {_listing(bad)}")
    bad = np.flatnonzero(~np.isfinite(uv).all(axis=1))
    if len(bad):
        raise ValueError(f"{name}: non-finite (NaN or inf) UVs at vertices {_listing(bad)}")

    p = vertices[faces]
    area3d = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    bad = np.flatnonzero(area3d <= _DEGENERATE * np.median(area3d))
    if len(bad):
        raise ValueError(f"{name}: degenerate triangles (zero area in 3D): {_listing(bad)}")
    area = _uv_areas(uv, faces)
    bad = np.flatnonzero(np.abs(area) <= _DEGENERATE * np.median(np.abs(area)))
    if len(bad):
        raise ValueError(f"{name}: degenerate UV triangles (zero UV area): {_listing(bad)}")
    orientation = 1.0 if (area > 0).sum() >= (area < 0).sum() else -1.0
    bad = np.flatnonzero(area * orientation < 0)
    if len(bad):
        raise ValueError(
            f"{name}: flipped UV triangles (orientation opposite to the rest of the chart): "
            f"{_listing(bad)}"
        )
    if orientation < 0:
        log.warning(
            "%s: the UV chart is mirrored (its triangles run clockwise in UV): the shell's "
            "normal a1 x a2 points opposite to the normals of the file's face winding, so "
            "pressure, the sign of curvature and the rendered front side follow the UV chart", name)

    edges = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    unique, counts = np.unique(edges, axis=0, return_counts=True)
    bad = unique[counts > 2]
    if len(bad):
        raise ValueError(
            f"{name}: non-manifold edges (shared by more than two triangles), e.g. between "
            f"vertices {int(bad[0, 0])} and {int(bad[0, 1])} ({len(bad)} in all)"
        )


def _check_overlaps(chart: _UVChart, faces: np.ndarray, name: str) -> None:
    """Refuse UV charts where triangles overlap: the centroid and three points near the corners
    of each triangle must lie strictly inside no other triangle."""
    weights = np.array([[1 / 3, 1 / 3, 1 / 3], [0.8, 0.1, 0.1], [0.1, 0.8, 0.1], [0.1, 0.1, 0.8]])
    probes = np.einsum("pk,fkd->fpd", weights, chart.corners).reshape(-1, 2)
    owner = np.repeat(np.arange(len(faces)), len(weights))
    cand, inside = chart.covering(probes, -_INSIDE_TOL)
    inside &= cand != owner[:, None]
    bad = np.unique(owner[inside.any(axis=1)])
    if len(bad):
        raise ValueError(
            f"{name}: overlapping UV triangles (the UV chart folds over itself): {_listing(bad)}"
        )
