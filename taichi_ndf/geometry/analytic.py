"""Analytic reference surfaces with exact jets: plane, cylinder, cone, cylindrical roof,
annulus.

All are defined in local axes and placed in the world by `origin` and `frame`
(see `PlacedSurface`). Jets are exact closed forms, differentiable in torch with respect to ξ.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from taichi_ndf.geometry.domain import Bounds, ParameterDomain
from taichi_ndf.geometry.surface import PlacedSurface, require_positive, require_turn


def _stack(*channels: tuple[torch.Tensor, torch.Tensor, torch.Tensor]) -> torch.Tensor:
    """Six (x, y, z) channel triples of broadcastable tensors -> jets (N, 6, 3)."""
    n = max(c.shape[0] for channel in channels for c in channel if c.dim() > 0)
    rows = [torch.stack([c.expand(n) for c in channel], dim=1) for channel in channels]
    return torch.stack(rows, dim=1)


@dataclass(frozen=True)
class Plane(PlacedSurface):
    """Flat rectangle r(ξ) = (ξ¹, ξ², 0) in local axes.

    bounds: ((x_min, x_max), (y_min, y_max)) [m]; ξ¹ and ξ² are arclengths [m] along the local
    x and y axes. Normal a₃ = local +z.
    """

    bounds: Bounds = ((0.0, 1.0), (0.0, 1.0))

    def __post_init__(self):
        super().__post_init__()
        object.__setattr__(self, "bounds", ParameterDomain(self.bounds).bounds)

    @property
    def domain(self) -> ParameterDomain:
        return ParameterDomain(self.bounds)

    def local_jets(self, xi: torch.Tensor) -> torch.Tensor:
        x, y = xi[:, 0], xi[:, 1]
        zero, one = torch.zeros_like(x), torch.ones_like(x)
        return _stack((x, y, zero), (one, zero, zero), (zero, one, zero),
                      (zero, zero, zero), (zero, zero, zero), (zero, zero, zero))


@dataclass(frozen=True)
class Cylinder(PlacedSurface):
    """Closed circular cylinder about the local z axis.

    r(θ, z) = (R cos θ, R sin θ, z): ξ¹ = θ ∈ [0, angle] is the angle [rad], periodic for a
    whole turn (angle = 2π, the default), else a part of the cylinder with edges at θ = 0 and
    θ = angle (where symmetry planes cut it: a quarter or octant model); ξ² = z ∈ [0, length]
    is the axial position [m]. radius R [m], length [m]. Normal a₃ points outwards.
    """

    radius: float = 1.0
    length: float = 1.0
    angle: float = 2 * math.pi

    def __post_init__(self):
        super().__post_init__()
        require_positive(self, "radius", "m")
        require_positive(self, "length", "m")
        require_turn(self, "angle")

    @property
    def domain(self) -> ParameterDomain:
        full = self.angle >= 2 * math.pi * (1 - 1e-12)
        return ParameterDomain(((0.0, 2 * math.pi if full else self.angle),
                                (0.0, self.length)), periodic=(full, False))

    def local_jets(self, xi: torch.Tensor) -> torch.Tensor:
        c, s = torch.cos(xi[:, 0]), torch.sin(xi[:, 0])
        zero, one, rad = torch.zeros_like(c), torch.ones_like(c), self.radius
        return _stack((rad * c, rad * s, xi[:, 1]), (-rad * s, rad * c, zero), (zero, zero, one),
                      (-rad * c, -rad * s, zero), (zero, zero, zero), (zero, zero, zero))


@dataclass(frozen=True)
class Cone(PlacedSurface):
    """Truncated cone (frustum) about the local z axis.

    r(θ, z) = (ρ(z) cos θ, ρ(z) sin θ, z) with ρ(z) = bottom_radius + (top_radius −
    bottom_radius) z / height: ξ¹ = θ ∈ [0, 2π) [rad], periodic; ξ² = z ∈ [0, height] is the
    axial height [m] (not the slant length). Radii [m] must be positive (the apex is a singular
    point of the surface and is refused). Normal a₃ points away from the axis.
    """

    bottom_radius: float = 1.0
    top_radius: float = 0.5
    height: float = 1.0

    def __post_init__(self):
        super().__post_init__()
        require_positive(self, "bottom_radius", "m")
        require_positive(self, "top_radius", "m")
        require_positive(self, "height", "m")

    @property
    def domain(self) -> ParameterDomain:
        return ParameterDomain(((0.0, 2 * math.pi), (0.0, self.height)), periodic=(True, False))

    def local_jets(self, xi: torch.Tensor) -> torch.Tensor:
        c, s = torch.cos(xi[:, 0]), torch.sin(xi[:, 0])
        slope = (self.top_radius - self.bottom_radius) / self.height
        rho = self.bottom_radius + slope * xi[:, 1]
        zero, one = torch.zeros_like(c), torch.ones_like(c)
        return _stack((rho * c, rho * s, xi[:, 1]), (-rho * s, rho * c, zero),
                      (slope * c, slope * s, one), (-rho * c, -rho * s, zero),
                      (-slope * s, slope * c, zero), (zero, zero, zero))


@dataclass(frozen=True)
class CylindricalRoof(PlacedSurface):
    """Open cylindrical shell segment (e.g. the Scordelis–Lo roof), axis along local y.

    r(φ, y) = (R sin φ, y, R cos φ): ξ¹ = φ ∈ [−half_angle, half_angle] is the angle from the
    crown [rad] (not periodic); ξ² = y ∈ [0, length] is the axial position [m]. The crown is at
    local z = R, the axis of the cylinder is the local y axis. Normal a₃ points outwards (up at
    the crown). radius [m], length [m], half_angle [rad] in (0, π).
    """

    radius: float = 25.0
    length: float = 50.0
    half_angle: float = math.radians(40.0)

    def __post_init__(self):
        super().__post_init__()
        require_positive(self, "radius", "m")
        require_positive(self, "length", "m")
        half = require_positive(self, "half_angle", "rad")
        if half >= math.pi:
            raise ValueError(f"half_angle must be < π (use Cylinder for a closed tube), got {half}")

    @property
    def domain(self) -> ParameterDomain:
        return ParameterDomain(((-self.half_angle, self.half_angle), (0.0, self.length)))

    def local_jets(self, xi: torch.Tensor) -> torch.Tensor:
        c, s = torch.cos(xi[:, 0]), torch.sin(xi[:, 0])
        zero, one, rad = torch.zeros_like(c), torch.ones_like(c), self.radius
        return _stack((rad * s, xi[:, 1], rad * c), (rad * c, zero, -rad * s), (zero, one, zero),
                      (-rad * s, zero, -rad * c), (zero, zero, zero), (zero, zero, zero))


@dataclass(frozen=True)
class Annulus(PlacedSurface):
    """Flat annulus (or annular sector) in the local x–y plane, in polar coordinates.

    r(ρ, θ) = (ρ cos θ, ρ sin θ, 0): ξ¹ = ρ ∈ [inner_radius, outer_radius] is the radius [m],
    ξ² = θ ∈ [start_angle, start_angle + angle] the polar angle [rad]. Normal a₃ = local +z.
    A full annulus (angle = 2π) is periodic in θ unless `slit`: then θ = start and θ = start
    + 2π are the two faces of a radial cut (the slit annular plate), edges `xi2_min` and
    `xi2_max`; a sector (angle < 2π) is never periodic. Edges `xi1_min` / `xi1_max` are the
    inner / outer rims. inner_radius > 0 (the centre of a disk is a singular point of polar
    coordinates).
    """

    inner_radius: float = 0.5
    outer_radius: float = 1.0
    angle: float = 2 * math.pi
    start_angle: float = 0.0
    slit: bool = False

    def __post_init__(self):
        super().__post_init__()
        inner = require_positive(self, "inner_radius", "m")
        if require_positive(self, "outer_radius", "m") <= inner:
            raise ValueError(f"outer_radius must exceed inner_radius {inner}, got "
                             f"{self.outer_radius}")
        full = require_turn(self, "angle")
        start = float(self.start_angle)
        if not math.isfinite(start):
            raise ValueError(f"start_angle must be a finite number [rad], got {start}")
        object.__setattr__(self, "start_angle", start)
        if not isinstance(self.slit, bool):
            raise ValueError(f"slit must be true or false, got {self.slit!r}")
        if self.slit and not full:
            raise ValueError("slit applies to a full annulus (angle = 2π); a sector has its "
                             "two radial edges already")

    @property
    def full(self) -> bool:
        """Whether θ covers one turn."""
        return self.angle >= 2 * math.pi * (1 - 1e-12)

    @property
    def domain(self) -> ParameterDomain:
        angles = (self.start_angle, self.start_angle + self.angle)
        return ParameterDomain(((self.inner_radius, self.outer_radius), angles),
                               periodic=(False, self.full and not self.slit))

    def local_jets(self, xi: torch.Tensor) -> torch.Tensor:
        rho, c, s = xi[:, 0], torch.cos(xi[:, 1]), torch.sin(xi[:, 1])
        zero = torch.zeros_like(c)
        return _stack((rho * c, rho * s, zero), (c, s, zero), (-rho * s, rho * c, zero),
                      (zero, zero, zero), (-s, c, zero), (-rho * c, -rho * s, zero))
