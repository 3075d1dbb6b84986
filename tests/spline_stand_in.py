"""A small uniform cubic B-spline basis with the `local_basis` interface of a spline field, for
the tests of the coefficient-space assembly and projected Newton (independent of
`taichi_ndf.field.spline`), and Gauss–Legendre points per knot span."""

from __future__ import annotations

import numpy as np
import torch

from taichi_ndf.sampling import SurfaceSamples, with_point_loads


def _cubic(s: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The 4 uniform cubic B-splines acting on a span at local s ∈ [0, 1) and their first
    and second derivatives in s, each (N, 4)."""
    value = torch.stack(((1 - s) ** 3, 3 * s**3 - 6 * s**2 + 4,
                         -3 * s**3 + 3 * s**2 + 3 * s + 1, s**3), dim=1) / 6
    first = torch.stack((-3 * (1 - s) ** 2, 9 * s**2 - 12 * s, -9 * s**2 + 6 * s + 3,
                         3 * s**2), dim=1) / 6
    second = torch.stack((6 * (1 - s), 18 * s - 12, -18 * s + 6, 6 * s), dim=1) / 6
    return value, first, second


class StandInSpline:
    """Cubic tensor-product B-spline on a rectangle with `spans` knot spans per direction,
    unclamped (spans + 3 coefficients per direction); coefficient (i, j) is number
    i · (spans[1] + 3) + j."""

    def __init__(self, bounds, spans: tuple[int, int], dtype=torch.float64):
        self.bounds = bounds
        self.spans = spans
        self.shape = (spans[0] + 3, spans[1] + 3)
        self.parameters = [torch.zeros(self.shape[0] * self.shape[1], 3, dtype=dtype)]

    def local_basis(self, xi: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        per_direction = []
        for d in range(2):
            lo, hi = self.bounds[d]
            h = (hi - lo) / self.spans[d]
            t = (xi[:, d] - lo) / h
            span = torch.clamp(torch.floor(t), 0, self.spans[d] - 1)
            value, first, second = _cubic(t - span)
            per_direction.append((span.long(), value, first / h, second / h**2))
        (s1, v1, d1, dd1), (s2, v2, d2, dd2) = per_direction
        a = torch.arange(4)
        index = ((s1[:, None, None] + a[None, :, None]) * self.shape[1]
                 + s2[:, None, None] + a[None, None, :]).reshape(-1, 16)

        def outer(p, q):
            return (p[:, :, None] * q[:, None, :]).reshape(-1, 16)

        jets = torch.stack((outer(v1, v2), outer(d1, v2), outer(v1, d2), outer(dd1, v2),
                            outer(d1, d2), outer(v1, dd2)), dim=1)
        return index, jets


def gauss_samples(surface, bounds, spans, order, loads=None, dtype=torch.float64
                  ) -> SurfaceSamples:
    """order × order Gauss–Legendre points per knot span of a rectangle, plus point loads."""
    nodes, weights = np.polynomial.legendre.leggauss(order)
    axes, axis_weights = [], []
    for d in range(2):
        lo, hi = bounds[d]
        h = (hi - lo) / spans[d]
        left = lo + h * np.arange(spans[d])
        axes.append((left[:, None] + h * (nodes + 1) / 2).ravel())
        axis_weights.append(np.tile(weights * h / 2, spans[d]))
    x1, x2 = np.meshgrid(axes[0], axes[1], indexing="ij")
    w = np.outer(axis_weights[0], axis_weights[1]).ravel()
    xi = torch.tensor(np.stack((x1.ravel(), x2.ravel()), axis=1), dtype=dtype)
    return with_point_loads(surface, xi, torch.tensor(w, dtype=dtype), loads)
