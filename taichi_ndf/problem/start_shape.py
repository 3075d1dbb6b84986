"""Start shapes: where a solve starts, distinct from the rest shape (docs/scenes.md, "Start").

A start shape maps the rest positions r(ξ) (N, 3) [m] of a flat sheet to start positions
(N, 3) [m]; the start displacement is their difference, fitted by the spline field's
coefficients (`taichi_ndf.discretise.start.fitted_start`). The sheet's chart must be
isometric (a `Plane`): `along` is the chart direction e = ∂r/∂ξ^axis / |∂r/∂ξ^axis|, `n` the
unit normal ∂r/∂ξ¹ × ∂r/∂ξ² / |…|.

- `Fold`: the part ξ^axis > `at` turned over onto the side +n, around a crease of radius ρ:
  flat up to a = at − πρ/2, a half circle of radius ρ, then back over the first part 2ρ above
  it (isometric).
- `Wrap`: the sheet bent onto the cylinder of radius R on the side −n, tangent to it along
  ξ^axis = `at` (isometric: arc length s − at ↦ angle (s − at)/R).
Each then moved rigidly: rotated by `angle` [deg] about `rotation_axis` through `about`, then
translated by `translation` [m] (a plain `Rigid` start is this alone).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

KINDS = ("rigid", "fold", "wrap")


@dataclass(frozen=True)
class StartShape:
    """kind: one of KINDS; axis: the chart coordinate (0: ξ¹, 1: ξ²) the fold or the wrap
    runs along; at: ξ^axis of the crease's middle (fold) or of the tangent line (wrap) [m];
    radius: the crease's ρ or the cylinder's R [m]; then the rigid motion."""

    kind: str = "rigid"
    axis: int = 0
    at: float = 0.0
    radius: float = 0.0
    rotation_axis: tuple[float, float, float] = (0.0, 0.0, 1.0)
    angle: float = 0.0  # [deg]
    about: tuple[float, float, float] = (0.0, 0.0, 0.0)
    translation: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self):
        if self.kind not in KINDS:
            raise ValueError(f"type must be one of {', '.join(KINDS)}, got {self.kind!r}")
        if self.axis not in (0, 1):
            raise ValueError(f"axis must be 0 (ξ¹) or 1 (ξ²), got {self.axis}")
        if self.kind != "rigid" and not (math.isfinite(self.radius) and self.radius > 0):
            raise ValueError(f"radius must be > 0 for a {self.kind}, got {self.radius}")
        if math.hypot(*self.rotation_axis) == 0:
            raise ValueError("rotation_axis must not be zero")

    def positions(self, xi: torch.Tensor, r: torch.Tensor, r1: torch.Tensor,
                  r2: torch.Tensor) -> torch.Tensor:
        """Start positions (N, 3) [m] of the points at ξ (N, 2) with rest positions r (N, 3)
        and tangents r1 = ∂r/∂ξ¹, r2 = ∂r/∂ξ² (N, 3)."""
        along = (r1, r2)[self.axis]
        e = along / along.norm(dim=1, keepdim=True)
        n = torch.linalg.cross(r1, r2, dim=1)
        n = n / n.norm(dim=1, keepdim=True)
        s = xi[:, self.axis] - self.at
        if self.kind == "fold":
            x = r + _fold_offset(s, self.radius, e, n)
        elif self.kind == "wrap":
            theta = s / self.radius
            x = r + ((self.radius * torch.sin(theta) - s)[:, None] * e
                     + (self.radius * (torch.cos(theta) - 1))[:, None] * n)
        else:
            x = r
        return self._moved(x)

    def _moved(self, x: torch.Tensor) -> torch.Tensor:
        """x (N, 3) rotated about `about` then translated (Rodrigues' formula)."""
        k = torch.tensor(self.rotation_axis, dtype=x.dtype)
        k = k / k.norm()
        c = torch.tensor(self.about, dtype=x.dtype)
        a = math.radians(self.angle)
        v = x - c
        rotated = (v * math.cos(a) + torch.linalg.cross(k.expand_as(v), v, dim=1) * math.sin(a)
                   + k * (v @ k)[:, None] * (1 - math.cos(a)))
        return rotated + c + torch.tensor(self.translation, dtype=x.dtype)


def _fold_offset(s: torch.Tensor, radius: float, e: torch.Tensor, n: torch.Tensor
                 ) -> torch.Tensor:
    """The fold's displacement (N, 3) [m] at the signed distance s (N,) [m] from the crease's
    middle: flat to −πρ/2, a half circle, then back 2ρ above."""
    half = 0.5 * math.pi * radius
    theta = ((s + half) / radius).clamp(0.0, math.pi)
    along = torch.where(s <= -half, s, -half + radius * torch.sin(theta))
    up = torch.where(s <= -half, torch.zeros_like(s), radius * (1 - torch.cos(theta)))
    beyond = s > half
    along = torch.where(beyond, -half - (s - half), along)
    up = torch.where(beyond, torch.full_like(s, 2 * radius), up)
    return (along - s)[:, None] * e + up[:, None] * n
