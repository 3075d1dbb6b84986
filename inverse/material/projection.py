"""Closest points of a parametrised surface x(ξ) to given points: seeds on a grid of the
parameter domain, the nearest seed per point (k-d tree), then Gauss–Newton on |x(ξ) − p|²
clipped to the parameter rectangle. One definition for the fitted shapes and the equilibria."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch
from scipy.spatial import cKDTree

from taichi_ndf import jets


def grid_seeds(domain, grid: int, dtype: torch.dtype) -> torch.Tensor:
    """grid × grid points (M, 2) of the domain's rectangle, those outside its mask dropped."""
    (lo1, hi1), (lo2, hi2) = domain.bounds
    g1, g2 = torch.meshgrid(torch.linspace(lo1, hi1, grid, dtype=dtype),
                            torch.linspace(lo2, hi2, grid, dtype=dtype), indexing="ij")
    seeds = torch.stack([g1.ravel(), g2.ravel()], dim=1)
    return seeds[domain.contains(seeds)]


def nearest_seeds(seeds: torch.Tensor, seed_positions: torch.Tensor,
                  points: torch.Tensor) -> torch.Tensor:
    """The seed ξ (N, 2) whose position (M, 3) [m] is nearest to each point (N, 3) [m]."""
    _, nearest = cKDTree(seed_positions.numpy()).query(points.numpy())
    return seeds[torch.from_numpy(np.asarray(nearest))]


def closest_points(position_jets: Callable[[torch.Tensor], torch.Tensor], bounds,
                   points: torch.Tensor, xi0: torch.Tensor, steps: int) -> torch.Tensor:
    """Surface coordinates (N, 2) of the closest surface points to `points` (N, 3) [m]:
    `steps` Gauss–Newton steps from xi0 on the positions' jets (`position_jets(ξ)` (N, 6, 3)),
    clipped to the rectangle `bounds`."""
    (lo1, hi1), (lo2, hi2) = bounds
    lo = xi0.new_tensor([lo1, lo2])
    hi = xi0.new_tensor([hi1, hi2])
    xi = xi0.clone()
    for _ in range(steps):
        x = position_jets(xi)
        tangent = torch.stack([x[:, jets.D1], x[:, jets.D2]], dim=1)  # (N, 2, 3)
        gap = points - x[:, jets.VALUE]
        normal = tangent @ tangent.transpose(1, 2)
        rhs = (tangent @ gap[:, :, None])[:, :, 0]
        xi = torch.minimum(torch.maximum(xi + torch.linalg.solve(normal, rhs), lo), hi)
    return xi
