"""Observed equilibrium shapes of a sheet and the known conditions they were taken under."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from taichi_ndf.io import read_mesh
from taichi_ndf.io.grid import grid_mesh
from taichi_ndf.model import ShellModel


@dataclass(frozen=True)
class Observation:
    """One observed shape.

    model: the known conditions: reference surface, boundary conditions, the loads and the
        material as far as they are known (unknown parameters are replaced by the estimator).
    points: observed positions [m], shape (M, 3).
    xi: surface coordinates of each point, shape (M, 2), when the points correspond to known
        template points (a mesh in the template's vertex order); None for a point cloud
        without correspondence (fitted by point-to-surface distance).
    """

    model: ShellModel
    points: torch.Tensor
    xi: torch.Tensor | None = None

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
        return Observation(self.model, self.points + fraction * self.size * noise, self.xi)

    def without_correspondence(self) -> Observation:
        """The same points as a point cloud (correspondence dropped)."""
        return Observation(self.model, self.points, None)


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
