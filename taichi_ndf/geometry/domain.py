"""Parameter domain Ω of a reference surface: a rectangle of surface coordinates ξ = (ξ¹, ξ²),
optionally periodic in either coordinate and optionally restricted by an inside-mask.

Units of ξ are those of the surface that owns the domain (metres for a plane, radians for an
angle); the area is in the product of those units (m², rad·m, …).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property

import torch

Bounds = tuple[tuple[float, float], tuple[float, float]]

# Resolution of the midpoint grid that estimates the area of a masked domain when no exact
# area is given: the relative error is about (perimeter cells)/(inside cells) ~ 1e-3.
_MASK_AREA_GRID = 1024


@dataclass(frozen=True)
class ParameterDomain:
    """Rectangle [lo1, hi1] × [lo2, hi2] of surface coordinates, optionally masked.

    bounds: ((lo1, hi1), (lo2, hi2)) with lo < hi, finite.
    periodic: per coordinate, whether the surface closes on itself (ξ = lo and ξ = hi are the
        same points); the rectangle then covers exactly one period.
    inside: optional mask for non-rectangular charts (e.g. a mesh's UV chart): a callable
        taking ξ (N, 2) and returning a bool tensor (N,). Points outside the mask are not part
        of Ω.
    mask_area: exact area of the masked domain if known; otherwise it is estimated on a
        1024 × 1024 midpoint grid of the rectangle (computed once, on first use).
    """

    bounds: Bounds
    periodic: tuple[bool, bool] = (False, False)
    inside: Callable[[torch.Tensor], torch.Tensor] | None = None
    mask_area: float | None = None

    def __post_init__(self):
        try:
            (lo1, hi1), (lo2, hi2) = self.bounds
            bounds = ((float(lo1), float(hi1)), (float(lo2), float(hi2)))
        except (TypeError, ValueError) as err:
            raise ValueError(
                f"bounds must be ((lo1, hi1), (lo2, hi2)), got {self.bounds!r}"
            ) from err
        for k, (lo, hi) in enumerate(bounds):
            if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
                raise ValueError(f"bounds[{k}] must be finite with lo < hi, got {(lo, hi)}")
        object.__setattr__(self, "bounds", bounds)
        if len(self.periodic) != 2:
            raise ValueError(f"periodic must be two flags, got {self.periodic!r}")
        object.__setattr__(self, "periodic", (bool(self.periodic[0]), bool(self.periodic[1])))
        if self.inside is not None and not callable(self.inside):
            raise ValueError("inside must be a callable ξ (N, 2) -> bool (N,) or None")
        if self.mask_area is not None:
            if self.inside is None:
                raise ValueError("mask_area is only meaningful together with an inside mask")
            if not (math.isfinite(self.mask_area) and 0 < self.mask_area <= self.rectangle_area):
                raise ValueError(
                    f"mask_area must be in (0, {self.rectangle_area}], got {self.mask_area}"
                )

    @property
    def lengths(self) -> tuple[float, float]:
        """Side lengths (hi − lo) of the rectangle, in the units of ξ¹ and ξ²."""
        return tuple(hi - lo for lo, hi in self.bounds)

    @property
    def rectangle_area(self) -> float:
        """Area of the bounding rectangle."""
        l1, l2 = self.lengths
        return l1 * l2

    @cached_property
    def area(self) -> float:
        """Area of the part of parameter space actually used (mask included)."""
        if self.inside is None:
            return self.rectangle_area
        if self.mask_area is not None:
            return self.mask_area
        m = _MASK_AREA_GRID
        (lo1, hi1), (lo2, hi2) = self.bounds
        t = (torch.arange(m, dtype=torch.float64) + 0.5) / m
        g1, g2 = torch.meshgrid(lo1 + (hi1 - lo1) * t, lo2 + (hi2 - lo2) * t, indexing="ij")
        xi = torch.stack((g1.reshape(-1), g2.reshape(-1)), dim=1)
        fraction = self._mask(xi).double().mean().item()
        if fraction == 0.0:
            raise ValueError("the inside mask excludes the whole rectangle: the domain is empty")
        return fraction * self.rectangle_area

    def contains(self, xi: torch.Tensor, *, tol: float = 1e-12) -> torch.Tensor:
        """Whether each ξ (N, 2) lies in Ω (closed rectangle, tolerance `tol` relative to the
        side lengths, and inside the mask); bool tensor (N,)."""
        ok = torch.ones(xi.shape[0], dtype=torch.bool, device=xi.device)
        for k, (lo, hi) in enumerate(self.bounds):
            pad = tol * (hi - lo)
            ok &= (xi[:, k] >= lo - pad) & (xi[:, k] <= hi + pad)
        if self.inside is not None:
            ok &= self._mask(xi)
        return ok

    def sample(
        self,
        n: int,
        generator: torch.Generator | None = None,
        *,
        dtype: torch.dtype = torch.float64,
        device: torch.device | str = "cpu",
    ) -> torch.Tensor:
        """Stratified jittered samples of Ω, shape (M, 2).

        The rectangle is cut into n1 × n2 ≤ n cells of similar shape, one uniform sample per
        cell; the remaining n − n1·n2 samples are uniform in the rectangle. With a mask, only
        the candidates inside are returned (M ≤ n); without one, M = n. Equal weights
        `area` / M make Σ w f a consistent estimate of ∫_Ω f (unbiased without a mask).
        """
        if int(n) != n or n < 1:
            raise ValueError(f"number of samples n must be a positive integer, got {n!r}")
        n = int(n)
        l1, l2 = self.lengths
        n1 = min(n, max(1, round(math.sqrt(n * l1 / l2))))
        n2 = max(1, n // n1)
        cells = n1 * n2
        u = torch.rand(n, 2, generator=generator, dtype=torch.float64)
        i = torch.arange(cells)
        u[:cells, 0] = (i // n2 + u[:cells, 0]) / n1
        u[:cells, 1] = (i % n2 + u[:cells, 1]) / n2
        (lo1, _), (lo2, _) = self.bounds
        xi = torch.stack((lo1 + l1 * u[:, 0], lo2 + l2 * u[:, 1]), dim=1)
        if self.inside is not None:
            xi = xi[self._mask(xi)]
        return xi.to(dtype=dtype, device=device)

    def _mask(self, xi: torch.Tensor) -> torch.Tensor:
        mask = torch.as_tensor(self.inside(xi), device=xi.device)
        if mask.dtype != torch.bool or mask.shape != xi.shape[:1]:
            raise ValueError(
                f"inside mask must return a bool tensor of shape ({xi.shape[0]},), "
                f"got {mask.dtype} {tuple(mask.shape)}"
            )
        return mask
