"""Hemisphere and spherical caps, with or without a polar hole."""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from taichi_ndf.geometry.domain import ParameterDomain
from taichi_ndf.geometry.surface import PlacedSurface, require_positive, require_turn

# Power series of sin(√u)/√u and cos(√u): 25 terms reach round-off for u ≤ π² (any cap).
_SERIES_TERMS = 25
_SIN_SERIES = [(-1) ** k / math.factorial(2 * k + 1) for k in range(_SERIES_TERMS)]
_COS_SERIES = [(-1) ** k / math.factorial(2 * k) for k in range(_SERIES_TERMS)]


def _series_jet(coefficients: list[float], u: torch.Tensor):
    """Value, first and second derivative of Σ c_k u^k (Horner)."""
    value, first, second = torch.zeros_like(u), torch.zeros_like(u), torch.zeros_like(u)
    for k in range(len(coefficients) - 1, -1, -1):
        second = second * u + 2 * first
        first = first * u + value
        value = value * u + coefficients[k]
    return value, first, second


@dataclass(frozen=True)
class Hemisphere(PlacedSurface):
    """Sphere of radius R [m] centred at the local origin, the part within polar angle
    `rim_angle` [rad] of the pole (local +z); default π/2, a hemisphere; smaller values give a
    spherical cap. An optional polar hole removes polar angles below `hole_half_angle` [rad].
    Normal a₃ points outwards.

    The chart depends on the hole, because polar coordinates are singular at the pole:

    - with a hole (hole_half_angle > 0): polar chart, ξ¹ = φ ∈ [0, azimuth] the azimuth
      [rad], periodic for a whole turn (azimuth = 2π, the default), else a part with edges at
      φ = 0 and φ = azimuth, on which symmetry planes cut the shell (a quarter model);
      ξ² = λ the elevation above the equator [rad], λ ∈ [π/2 − rim_angle,
      π/2 − hole_half_angle]; r = R (cos λ cos φ, cos λ sin φ, sin λ).
    - without a hole: azimuthal-equidistant chart, regular at the pole: ξ = (x, y) [m] on the
      disk |ξ| ≤ R·rim_angle, where |ξ| is the arclength from the pole along a meridian and
      ξ/|ξ| the azimuth direction; r = (R sin(|ξ|/R) ξ/|ξ|, R cos(|ξ|/R)). The domain is the
      masked square [−R·rim_angle, R·rim_angle]² with the exact disk area.
    """

    radius: float = 1.0
    hole_half_angle: float = 0.0
    rim_angle: float = math.pi / 2
    azimuth: float = 2 * math.pi

    def __post_init__(self):
        super().__post_init__()
        require_positive(self, "radius", "m")
        rim = require_positive(self, "rim_angle", "rad")
        if rim >= math.pi:
            raise ValueError(f"rim_angle must be < π (the antipode is singular), got {rim}")
        hole = float(self.hole_half_angle)
        if not (math.isfinite(hole) and 0.0 <= hole < rim):
            raise ValueError(f"hole_half_angle must be in [0, rim_angle={rim}) [rad], got {hole}")
        object.__setattr__(self, "hole_half_angle", hole)
        if not require_turn(self, "azimuth") and hole == 0.0:
            raise ValueError("azimuth below 2π needs the polar chart, i.e. a polar hole "
                             "(hole_half_angle > 0): the chart without a hole has no azimuth "
                             "edges")

    @property
    def chart(self) -> str:
        """"polar" (with a hole) or "disk" (azimuthal-equidistant, without a hole)."""
        return "polar" if self.hole_half_angle > 0 else "disk"

    @property
    def domain(self) -> ParameterDomain:
        if self.chart == "polar":
            elevation = (math.pi / 2 - self.rim_angle, math.pi / 2 - self.hole_half_angle)
            full = self.azimuth >= 2 * math.pi * (1 - 1e-12)
            return ParameterDomain(((0.0, 2 * math.pi if full else self.azimuth), elevation),
                                   periodic=(full, False))
        rho = self.radius * self.rim_angle
        return ParameterDomain(
            ((-rho, rho), (-rho, rho)),
            inside=lambda xi: (xi * xi).sum(dim=1) <= rho * rho,
            mask_area=math.pi * rho * rho,
        )

    def local_jets(self, xi: torch.Tensor) -> torch.Tensor:
        if self.chart == "polar":
            return self._polar_jets(xi)
        return self._disk_jets(xi)

    def _polar_jets(self, xi: torch.Tensor) -> torch.Tensor:
        cp, sp = torch.cos(xi[:, 0]), torch.sin(xi[:, 0])
        cl, sl = torch.cos(xi[:, 1]), torch.sin(xi[:, 1])
        zero = torch.zeros_like(cp)
        channels = (
            (cl * cp, cl * sp, sl),
            (-cl * sp, cl * cp, zero),
            (-sl * cp, -sl * sp, cl),
            (-cl * cp, -cl * sp, zero),
            (sl * sp, -sl * cp, zero),
            (-cl * cp, -cl * sp, -sl),
        )
        return self.radius * torch.stack([torch.stack(c, dim=1) for c in channels], dim=1)

    def _disk_jets(self, xi: torch.Tensor) -> torch.Tensor:
        # r = (F(q) x, F(q) y, G(q)) with q = |ξ|², F = R sin(√q/R)/√q, G = R cos(√q/R): both
        # are power series in q, hence smooth through the pole.
        rad = self.radius
        q = (xi * xi).sum(dim=1)
        s, s_u, s_uu = _series_jet(_SIN_SERIES, q / rad**2)
        c, c_u, c_uu = _series_jet(_COS_SERIES, q / rad**2)
        f, f_q, f_qq = s, s_u / rad**2, s_uu / rad**4
        g, g_q, g_qq = rad * c, c_u / rad, c_uu / rad**3
        n = xi.shape[0]
        eye = torch.eye(2, dtype=xi.dtype, device=xi.device)
        x_ab = xi[:, :, None] * xi[:, None, :]                                   # (N, 2, 2)
        f_a = 2 * f_q[:, None] * xi                                              # F_,α
        f_ab = 4 * f_qq[:, None, None] * x_ab + 2 * f_q[:, None, None] * eye     # F_,αβ
        g_a = 2 * g_q[:, None] * xi
        g_ab = 4 * g_qq[:, None, None] * x_ab + 2 * g_q[:, None, None] * eye
        # components i = 1, 2 of F ξ_i: first derivatives d[n, α, i], second dd[n, α, β, i]
        d = f_a[:, :, None] * xi[:, None, :] + f[:, None, None] * eye
        dd = (f_ab[..., None] * xi[:, None, None, :]
              + f_a[:, :, None, None] * eye[None, None, :, :]
              + f_a[:, None, :, None] * eye[None, :, None, :])
        jets = xi.new_empty(n, 6, 3)
        jets[:, 0, :2] = f[:, None] * xi
        jets[:, 0, 2] = g
        for channel, (alpha, beta) in ((3, (0, 0)), (4, (0, 1)), (5, (1, 1))):
            jets[:, channel, :2] = dd[:, alpha, beta]
            jets[:, channel, 2] = g_ab[:, alpha, beta]
        for channel, alpha in ((1, 0), (2, 1)):
            jets[:, channel, :2] = d[:, alpha]
            jets[:, channel, 2] = g_a[:, alpha]
        return jets
