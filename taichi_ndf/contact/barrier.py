"""The IPC log-barrier and the contact energy term of the objective (shared/spec/newton.md).

Gap of a surface point x = r + u to obstacle o: g = d_o(x) − h/2 − margin (d_o the signed
distance, h the shell's thickness). Barrier (Li et al. 2020):

    b(g) = −(g − ĝ)² ln(g / ĝ)  for 0 < g < ĝ,   0 for g ≥ ĝ,

C² at the activation distance ĝ and unbounded as g → 0. Below g_min = ĝ · FLOOR_RATIO it
continues as its second-order Taylor polynomial at g_min, so a stray sample inside an obstacle
(a fresh random sample between checked points) gives a finite, steeply repelling energy; the
penetration filter (`ContactPoints.step_allowed`) keeps accepted states outside.

Energy term: Π_c = κ Σ_i w_i √a_i Σ_o b(g_io) over the samples (quadrature weight w_i, or the
samples' `barrier_weight` where given: the dense check points), κ [N/m³] the barrier stiffness
(`taichi_ndf.contact.config`). It depends on the displacement's value channel only.
"""

from __future__ import annotations

import math

import torch

from taichi_ndf import jets
from taichi_ndf.problem.sampling import SurfaceSamples

FLOOR_RATIO = 1e-3


def barrier(gap: torch.Tensor, activation: float
            ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """b(g), b'(g), b''(g) [m², m, 1] of gaps (any shape) [m] (module docstring)."""
    floor = activation * FLOOR_RATIO
    g = gap.clamp(min=floor, max=activation)
    s = g - activation
    log = torch.log(g / activation)
    b = -s * s * log
    db = -2 * s * log - s * s / g
    ddb = -2 * log - 4 * s / g + s * s / (g * g)
    below = gap - floor
    low = gap < floor
    b = torch.where(low, b + db * below + 0.5 * ddb * below * below, b)
    db = torch.where(low, db + ddb * below, db)
    return b, db, ddb


def barrier_slope_at_half() -> float:
    """|b'(ĝ/2)| / ĝ = ln 2 + 1/2: the force per unit κ ĝ of a point held at half the
    activation distance (the stiffness rule of `taichi_ndf.contact.config`)."""
    return math.log(2.0) + 0.5


def area_element(samples: SurfaceSamples) -> torch.Tensor:
    """√a = |r_,1 × r_,2| per sample (N,)."""
    r = samples.r_jets
    return torch.linalg.cross(r[:, jets.D1], r[:, jets.D2], dim=-1).norm(dim=-1)


class ContactTerm:
    """κ Σ w √a b(g) against a set of obstacles (module docstring); the `Term` protocol of
    `taichi_ndf.objective`.

    obstacles: `taichi_ndf.contact.obstacles` instances (none: the term is zero, its gaps
    (N, 0); a sheet with self-contact alone, `ContactConfig.self_only`, stiffness 0);
    offset: h/2 + margin [m]; activation: ĝ [m]; stiffness: κ [N/m³]."""

    def __init__(self, obstacles, *, offset: float, activation: float, stiffness: float):
        for name, value in (("offset", offset), ("activation", activation),
                            ("stiffness", stiffness)):
            zero = name == "offset" or (name == "stiffness" and not obstacles)
            if not math.isfinite(value) or value < 0 or (not zero and value == 0):
                raise ValueError(f"contact {name} must be finite and > 0, got {value!r}")
        self.obstacles = tuple(obstacles)
        self.offset = float(offset)
        self.activation = float(activation)
        self.stiffness = float(stiffness)

    def gaps(self, points: torch.Tensor, load_factor: float = 1.0
             ) -> tuple[torch.Tensor, torch.Tensor]:
        """Gaps g (N, K) [m] of points (N, 3) [m] to the K obstacles and their gradients
        ∂g/∂x (N, K, 3)."""
        if not self.obstacles:
            return points.new_zeros(len(points), 0), points.new_zeros(len(points), 0, 3)
        gaps, normals = [], []
        for obstacle in self.obstacles:
            d, n = obstacle.signed_distance(points, load_factor)
            gaps.append(d - self.offset)
            normals.append(n)
        return torch.stack(gaps, dim=1), torch.stack(normals, dim=1)

    def weights(self, samples: SurfaceSamples) -> torch.Tensor:
        """κ w √a per sample (N,) [N/m] (b(g) [m²] times it: joules)."""
        weight = samples.weight if samples.barrier_weight is None else samples.barrier_weight
        return self.stiffness * weight * area_element(samples)

    def evaluate(self, samples: SurfaceSamples, u_jets: torch.Tensor,
                 load_factor: float | torch.Tensor = 1.0, *, grad: bool = True
                 ) -> tuple[float, torch.Tensor | None]:
        """Π_c [J] and dΠ_c/du_jets (N, 6, 3) (value channel only)."""
        if isinstance(load_factor, torch.Tensor):
            raise ValueError("contact takes one load factor, not one per sample")
        x = samples.r_jets[:, jets.VALUE] + u_jets[:, jets.VALUE]
        gap, normal = self.gaps(x, load_factor)
        b, db, _ = barrier(gap, self.activation)
        weight = self.weights(samples)
        value = float((weight[:, None] * b).sum())
        if not grad:
            return value, None
        out = torch.zeros_like(u_jets)
        out[:, jets.VALUE] = (weight[:, None, None] * db[:, :, None] * normal).sum(dim=1)
        return value, out

    def hessian_blocks(self, samples: SurfaceSamples, u_jets: torch.Tensor,
                       load_factor: float = 1.0, *, steps: torch.Tensor | None = None
                       ) -> torch.Tensor:
        """Positive semi-definite d²Π_c/du_jets² blocks (N, 6, 3, 6, 3), non-zero only in the
        value channel: κ w √a Σ_o b''(g) n nᵀ. The exact Hessian adds κ w √a b'(g) ∇²d (the
        obstacle's curvature, zero for a plane), which can be indefinite and is left out
        (projected Newton). steps: unused (the blocks are analytic)."""
        x = samples.r_jets[:, jets.VALUE] + u_jets[:, jets.VALUE]
        gap, normal = self.gaps(x, load_factor)
        _, _, ddb = barrier(gap, self.activation)
        ddb = torch.where(gap < self.activation, ddb, torch.zeros_like(ddb))
        weight = self.weights(samples)
        value = torch.einsum("n,nk,nki,nkj->nij", weight, ddb, normal, normal)
        blocks = u_jets.new_zeros(u_jets.shape[0], jets.CHANNELS, 3, jets.CHANNELS, 3)
        blocks[:, jets.VALUE, :, jets.VALUE, :] = value
        return blocks
