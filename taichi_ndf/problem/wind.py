"""Wind on a sheet in time: the air's velocity w(t) and the quadratic drag law on the normal
component of the relative velocity (a scene's `[dynamics.wind]`; docs/dynamics.md).

The air moves at w(t) = U (1 + a sin(2π f t)) [m/s] (U the mean velocity vector, a the gust
amplitude as a fraction of U, f the gust frequency [Hz]). On a piece of the deformed surface
with unit normal n and cloth velocity v the relative normal velocity is s = (w − v)·n [m/s],
and the air pushes along n with the pressure

    p = ½ ρ_air C_d s |s|   [Pa],

ρ_air the air's density [kg/m³], C_d the drag coefficient of a flat plate normal to the flow
(dimensionless): the force per deformed area is p n (along n where the air overtakes the
cloth, against it where the cloth overtakes the air). The tangential component of w − v is
not felt (no skin friction). The law is written here once; the time stepper linearises it in
the cloth's velocity about the step's start (`taichi_ndf.solve.dynamics`):
p(s) ≈ p(s₀) + dp/ds (s − s₀), dp/ds = ρ_air C_d |s₀| [Pa·s/m].
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from taichi_ndf.checks import finite_vector

AIR_DENSITY = 1.2  # kg/m³, dry air at 20 °C and sea level
FLAT_PLATE_DRAG = 1.2  # C_d of a flat plate normal to the flow (Hoerner 1965, ~1.17-1.28)


@dataclass(frozen=True)
class Wind:
    """velocity: the mean air velocity U [m/s] (3,); gust_amplitude: a ≥ 0, the gusts'
    amplitude as a fraction of U (w = U (1 + a sin(2π f t))); gust_frequency: f ≥ 0 [Hz];
    air_density: ρ_air > 0 [kg/m³]; drag_coefficient: C_d > 0 (dimensionless)."""

    velocity: tuple[float, float, float]
    gust_amplitude: float = 0.0
    gust_frequency: float = 0.0
    air_density: float = AIR_DENSITY
    drag_coefficient: float = FLAT_PLATE_DRAG

    def __post_init__(self):
        object.__setattr__(self, "velocity", finite_vector("wind velocity", self.velocity, 3,
                                                           "m/s"))
        for name, unit, positive in (("gust_amplitude", "", False), ("gust_frequency", " [Hz]",
                                     False), ("air_density", " [kg/m³]", True),
                                     ("drag_coefficient", "", True)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or \
                    not math.isfinite(value) or value < 0 or (positive and value == 0):
                bound = "> 0" if positive else ">= 0"
                raise ValueError(f"wind {name} must be finite and {bound}{unit}, got {value!r}")
            object.__setattr__(self, name, float(value))

    def at(self, t: float) -> tuple[float, float, float]:
        """w(t) [m/s] at time t [s]."""
        factor = 1.0 + self.gust_amplitude * math.sin(2 * math.pi * self.gust_frequency * t)
        return tuple(factor * u for u in self.velocity)

    def pressure(self, normal_speed: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """p = ½ ρ_air C_d s |s| [Pa] and dp/ds = ρ_air C_d |s| [Pa·s/m] of relative normal
        velocities s = (w − v)·n [m/s] (any shape)."""
        k = self.air_density * self.drag_coefficient
        return 0.5 * k * normal_speed * normal_speed.abs(), k * normal_speed.abs()

    def to_dict(self) -> dict:
        return {"velocity": list(self.velocity), "gust_amplitude": self.gust_amplitude,
                "gust_frequency": self.gust_frequency, "air_density": self.air_density,
                "drag_coefficient": self.drag_coefficient}
