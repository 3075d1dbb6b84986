"""Tensor-product Legendre polynomials on the parameter rectangle, with exact jets.

Used twice by the equilibrium-residual estimate: as the smooth representation of an observed
displacement (a linear least-squares fit, so noise is controlled by the degree and the fit
needs no training) and as the virtual displacements δu the equilibrium equations are tested
against (low-order, so fit errors in the second derivatives are integrated, not amplified).
"""

from __future__ import annotations

import numpy as np
import torch


class LegendreBasis:
    """Functions P_a(η¹) P_b(η²), a ≤ degree[0], b ≤ degree[1],
    η = 2 (ξ − lo)/(hi − lo) − 1 ∈ [−1, 1].

    bounds: ((lo1, hi1), (lo2, hi2)) of ξ; degree: highest degree, one for both coordinates or
    one per coordinate (≥ 0).
    """

    def __init__(self, bounds, degree: int | tuple[int, int]):
        degrees = (degree, degree) if isinstance(degree, int) else tuple(degree)
        if len(degrees) != 2 or any(isinstance(d, bool) or not isinstance(d, int) or d < 0
                                    for d in degrees):
            raise ValueError(f"degree must be one or two non-negative integers, got {degree!r}")
        (lo1, hi1), (lo2, hi2) = bounds
        self.lo = np.array([lo1, lo2], dtype=np.float64)
        self.scale = 2.0 / np.array([hi1 - lo1, hi2 - lo2], dtype=np.float64)
        self.degree = degrees

    @property
    def size(self) -> int:
        return (self.degree[0] + 1) * (self.degree[1] + 1)

    @staticmethod
    def _univariate(eta: np.ndarray, degree: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """P_n, P_n', P_n'' at η, each shape (N, degree + 1)."""
        leg = np.polynomial.legendre
        vander = leg.legvander(eta, degree)
        eye = np.eye(degree + 1)
        first = np.stack([leg.legval(eta, leg.legder(c)) for c in eye], axis=1)
        second = np.stack([leg.legval(eta, leg.legder(c, 2)) for c in eye], axis=1)
        return vander, first, second

    def jets(self, xi: torch.Tensor) -> torch.Tensor:
        """Jets of every basis function at ξ (N, 2), shape (N, 6, size), derivatives with
        respect to ξ (not η)."""
        x = xi.detach().cpu().numpy().astype(np.float64)
        eta = (x - self.lo) * self.scale - 1.0
        p1, d1, s1 = self._univariate(eta[:, 0], self.degree[0])
        p2, d2, s2 = self._univariate(eta[:, 1], self.degree[1])
        c1, c2 = self.scale

        def outer(a, b):
            return (a[:, :, None] * b[:, None, :]).reshape(len(x), -1)

        channels = [outer(p1, p2), c1 * outer(d1, p2), c2 * outer(p1, d2),
                    c1 * c1 * outer(s1, p2), c1 * c2 * outer(d1, d2), c2 * c2 * outer(p1, s2)]
        out = np.stack(channels, axis=1)
        return torch.from_numpy(out).to(dtype=xi.dtype, device=xi.device)
