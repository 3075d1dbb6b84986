"""External loads on the shell (physics.md §4).

The distributed load per unit reference area is f = ρ_A g + b + p a₃ [N/m²]: gravity g through
the material's areal density ρ_A, a uniform body force b, and a uniform pressure p along the
normal a₃ of the *reference* surface (a dead load: its direction does not follow the
deformation; positive p pushes along a₃, i.e. outwards on the closed analytic surfaces).
Point loads P_k [N] act at surface coordinates ξ_k; line loads q [N/m] along curves in ξ
(`taichi_ndf.problem.line_loads`). All loads are dead loads and conservative:
Π_ext = −∫ f·u √a dξ − Σ_k P_k·u(ξ_k) − Σ_lines ∫ q·u dℓ.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from taichi_ndf.checks import finite_vector
from taichi_ndf.geometry import ParameterDomain
from taichi_ndf.problem.line_loads import LineLoad

Vector3 = tuple[float, float, float]


@dataclass(frozen=True)
class PointLoad:
    """Concentrated force [N] at surface coordinates xi = (ξ¹, ξ²)."""

    xi: tuple[float, float]
    force: Vector3

    def __post_init__(self):
        object.__setattr__(self, "xi", finite_vector("point load xi", self.xi, 2, "units of ξ"))
        object.__setattr__(self, "force", finite_vector("point load force", self.force, 3, "N"))


@dataclass(frozen=True)
class Loads:
    """Loads of a scene.

    gravity: acceleration g [m/s²], e.g. (0, 0, −9.81); acts through the material's areal
        density.
    body_force: uniform force per unit reference area [N/m²] (wind, etc.).
    pressure: uniform pressure [Pa] along the reference normal a₃ (dead load).
    point_loads: concentrated forces; `PointLoad` or (xi, force) pairs.
    line_loads: forces per unit length along curves in ξ; `LineLoad`.
    """

    gravity: Vector3 = (0.0, 0.0, 0.0)
    body_force: Vector3 = (0.0, 0.0, 0.0)
    pressure: float = 0.0
    point_loads: tuple[PointLoad, ...] = ()
    line_loads: tuple[LineLoad, ...] = ()

    def __post_init__(self):
        object.__setattr__(self, "gravity", finite_vector("gravity", self.gravity, 3, "m/s²"))
        body_force = finite_vector("body_force", self.body_force, 3, "N/m²")
        object.__setattr__(self, "body_force", body_force)
        pressure = float(self.pressure)
        if not math.isfinite(pressure):
            raise ValueError(f"pressure must be a finite number [Pa], got {self.pressure!r}")
        object.__setattr__(self, "pressure", pressure)
        points = tuple(p if isinstance(p, PointLoad) else PointLoad(*p) for p in self.point_loads)
        object.__setattr__(self, "point_loads", points)
        lines = tuple(self.line_loads)
        if not all(isinstance(line, LineLoad) for line in lines):
            raise ValueError(f"line_loads must be LineLoad objects, got {self.line_loads!r}")
        object.__setattr__(self, "line_loads", lines)

    def distributed_force(self, areal_density: float) -> Vector3:
        """Uniform part ρ_A g + b of the load per unit reference area [N/m²] (pressure, which
        follows the reference normal, not included)."""
        return tuple(areal_density * g + b for g, b in zip(self.gravity, self.body_force,
                                                            strict=True))

    def scaled(self, factor: float) -> Loads:
        """All loads multiplied by `factor` (load stepping)."""
        factor = float(factor)
        if not math.isfinite(factor):
            raise ValueError(f"load factor must be finite, got {factor}")
        return Loads(
            gravity=tuple(factor * v for v in self.gravity),
            body_force=tuple(factor * v for v in self.body_force),
            pressure=factor * self.pressure,
            point_loads=tuple(PointLoad(p.xi, tuple(factor * v for v in p.force))
                              for p in self.point_loads),
            line_loads=tuple(line.scaled(factor) for line in self.line_loads),
        )

    def check_domain(self, domain: ParameterDomain) -> None:
        """Raise ValueError if a point load or a vertex of a line load's path lies outside the
        parameter domain."""
        points = [(f"point load at ξ = {p.xi}", p.xi) for p in self.point_loads]
        points += [(f"line load path point ξ = {xi}", xi)
                   for line in self.line_loads for xi in line.path]
        if not points:
            return
        inside = domain.contains(torch.tensor([xi for _, xi in points], dtype=torch.float64))
        for (what, _), ok in zip(points, inside.tolist(), strict=True):
            if not ok:
                raise ValueError(f"{what} lies outside the parameter domain {domain.bounds}")
