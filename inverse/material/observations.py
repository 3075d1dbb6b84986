"""Observed equilibrium shapes of a sheet and the known conditions they were taken under."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from inverse.material.handles import check_free_handles
from taichi_ndf.io import read_mesh
from taichi_ndf.io.grid import grid_mesh
from taichi_ndf.problem.model import ShellModel


@dataclass(frozen=True)
class Observation:
    """One observed shape.

    model: the known conditions: reference surface, boundary conditions, the loads and the
        material as far as they are known (unknown parameters are replaced by the estimator).
    points: observed positions [m], shape (M, 3).
    xi: surface coordinates of each point, shape (M, 2), when the points correspond to known
        template points (a mesh in the template's vertex order); None for a point cloud
        without correspondence (fitted by point-to-surface distance).
    rows: which components of each point were observed, shape (M, k, 3), k ≤ 3: the fit's
        residuals of point m are rows[m] @ (x(ξ_m) − p_m) (needs xi); None: all three
        coordinates. E.g. a monocular reconstruction, accurate across the camera ray and
        poor along it, observes the two directions perpendicular to each point's ray
        (`ray_rows`). Honoured by the outer fit of the implicit-function estimates
        (`outer_fit.residuals`: the Newton and the implicit methods).
    free_handles: indices of the model's `Handle` constraints whose held position is itself
        uncertain (e.g. measured in the same reconstruction): their displacements are
        offset by unknowns of this observation alone, 3 each [m], fitted beside the shared
        ones (`inverse.material.handles`; the Newton method only). Empty: held as stated.
    """

    model: ShellModel
    points: torch.Tensor
    xi: torch.Tensor | None = None
    rows: torch.Tensor | None = None
    free_handles: tuple[int, ...] = ()

    def __post_init__(self):
        if self.points.ndim != 2 or self.points.shape[1] != 3 or len(self.points) < 3:
            raise ValueError(f"points must have shape (M >= 3, 3), got {tuple(self.points.shape)}")
        if not bool(torch.isfinite(self.points).all()):
            raise ValueError("points contain non-finite values")
        if self.xi is not None:
            if tuple(self.xi.shape) != (len(self.points), 2):
                raise ValueError(f"xi must have shape ({len(self.points)}, 2), "
                                 f"got {tuple(self.xi.shape)}")
            if not bool(self.model.surface.domain.contains(self.xi).all()):
                raise ValueError("some xi lie outside the reference surface's parameter domain")
        if self.rows is not None:
            if self.xi is None:
                raise ValueError("rows (observed components) need correspondence (xi)")
            if self.rows.ndim != 3 or self.rows.shape[0] != len(self.points) or \
                    self.rows.shape[2] != 3 or not 1 <= self.rows.shape[1] <= 3:
                raise ValueError(f"rows must have shape ({len(self.points)}, k <= 3, 3), "
                                 f"got {tuple(self.rows.shape)}")
            if not bool(torch.isfinite(self.rows).all()):
                raise ValueError("rows contain non-finite values")
        if self.free_handles:
            object.__setattr__(self, "free_handles",
                               check_free_handles(self.model.boundary, self.free_handles))

    @property
    def components(self) -> int:
        """Residual entries per point: k of `rows`, 3 with correspondence, 1 without."""
        if self.rows is not None:
            return int(self.rows.shape[1])
        return 3 if self.xi is not None else 1

    @property
    def size(self) -> float:
        """Diagonal of the observed points' bounding box [m] (the 'sheet size' of noise levels)."""
        span = self.points.max(dim=0).values - self.points.min(dim=0).values
        return float(span.norm())

    def with_noise(self, fraction: float, *, seed: int = 0) -> Observation:
        """A copy with isotropic Gaussian noise of standard deviation `fraction` · size per
        coordinate."""
        if not fraction >= 0:
            raise ValueError(f"noise fraction must be >= 0, got {fraction}")
        gen = torch.Generator().manual_seed(seed)
        noise = torch.randn(self.points.shape, generator=gen, dtype=self.points.dtype)
        return Observation(self.model, self.points + fraction * self.size * noise, self.xi,
                           self.rows, self.free_handles)

    def without_correspondence(self) -> Observation:
        """The same points as a point cloud (correspondence and `rows` dropped)."""
        return Observation(self.model, self.points, None)


def ray_rows(points: torch.Tensor, centre=(0.0, 0.0, 0.0)) -> torch.Tensor:
    """(M, 2, 3): for each point an orthonormal pair of directions perpendicular to the camera
    ray from `centre` through it — the components a monocular view observes (to first order
    the reprojection error times depth); the component along the ray, the depth, is left
    out."""
    ray = points - torch.as_tensor(centre, dtype=points.dtype)
    ray = ray / ray.norm(dim=1, keepdim=True)
    # a helper axis not parallel to the ray: the coordinate axis least aligned with it
    helper = torch.zeros_like(ray)
    helper[torch.arange(len(ray)), ray.abs().argmin(dim=1)] = 1.0
    first = torch.linalg.cross(ray, helper, dim=1)
    first = first / first.norm(dim=1, keepdim=True)
    second = torch.linalg.cross(ray, first, dim=1)
    return torch.stack([first, second], dim=1)


def template_xi(model: ShellModel, resolution: tuple[int, int]) -> torch.Tensor:
    """Surface coordinates (V, 2) of the template grid vertices, in the vertex order of the
    meshes `ndf-sim` exports for this model at this resolution."""
    grid = grid_mesh(model.surface.domain.bounds, resolution,
                     periodic=model.surface.domain.periodic)
    return torch.from_numpy(grid.xi)


def read_observation(path, model: ShellModel, resolution: tuple[int, int]) -> Observation:
    """An observed mesh or point cloud (OBJ/PLY). A file with exactly as many vertices as the
    template grid of `resolution` is taken to be in template vertex order; any other file is a
    point cloud without correspondence."""
    mesh = read_mesh(path)
    points = torch.from_numpy(np.asarray(mesh.vertices, dtype=np.float64))
    xi = template_xi(model, resolution)
    if len(points) == len(xi):
        return Observation(model, points, xi)
    return Observation(model, points, None)


def rms_point_distance(residuals: np.ndarray, observations: list[Observation]) -> float:
    """Root-mean-square 3-D distance [m] between the model and the observed points from the
    stacked residuals of all observations: a point with correspondence contributes its 3
    coordinate differences, a point-cloud point its signed distance, so Σ r² over the number
    of points (not of residual entries) is the mean squared point distance."""
    points = sum(len(obs.points) for obs in observations)
    return float(np.sqrt(float(residuals @ residuals) / max(points, 1)))
