"""The inertia of a time step as an energy term: ½ s (u − û)ᵀ M (u − û), M the consistent mass
matrix of the field.

On displacement jets at quadrature points (weights w_q [m² of parameter area], reference area
element √a_q) the consistent mass matrix of any field that is linear in its parameters P,
u(ξ_q) = U₀ + J_q P, is M = Σ_q J_qᵀ m_q J_q with m_q = ρ_A w_q √a_q [kg] the mass the point
carries: so Σ_q ½ s m_q |u_q − û_q|² over the points *is* ½ s (P − P̂)ᵀ M (P − P̂), and its
Hessian is one 3 × 3 block m_q s I per point on the value channel. That is why the term is a
per-point term (`hessian_blocks`) and not a coupling (`taichi_ndf.objective.couplings`): the
assembly K = Σ_q J_qᵀ H_q J_q already couples every pair of coefficients acting at a point,
which is the consistent (not lumped) mass matrix.
"""

from __future__ import annotations

import math

import torch

from taichi_ndf import jets
from taichi_ndf.problem.sampling import SurfaceSamples


def point_masses(samples: SurfaceSamples, areal_density: float, dtype: torch.dtype
                 ) -> torch.Tensor:
    """m_q = ρ_A w_q √a_q (N,) [kg]: the mass each sample carries (ρ_A [kg/m²] the material's
    areal density, w_q the parameter-area weights, √a_q = |r_,1 × r_,2|); Σ m_q = ρ_A × the
    reference area. The one place the mass of the sheet is computed."""
    r = samples.r_jets
    sqrt_a = torch.linalg.cross(r[:, jets.D1], r[:, jets.D2], dim=-1).norm(dim=-1)
    return (areal_density * samples.weight * sqrt_a).to(dtype)


def kinetic_energy(samples: SurfaceSamples, areal_density: float,
                   velocity_jets: torch.Tensor) -> float:
    """T = ½ Σ_q m_q |v_q|² [J] = ½ Vᵀ M V of velocity jets (N, 6, 3) [m/s] at the samples."""
    v = velocity_jets[:, jets.VALUE]
    masses = point_masses(samples, areal_density, v.dtype)
    return 0.5 * float((masses * (v * v).sum(dim=1)).sum())


class InertiaTerm:
    """E = ½ s Σ_q m_q |u_q − û_q|² [J] = ½ s (P − P̂)ᵀ M (P − P̂): the inertia part of a time
    step's incremental potential (`taichi_ndf.solve.dynamics`).

    areal_density: ρ_A [kg/m²]; scale: s [1/s²] > 0 (1/(β h²) for Newmark, 1/h² for implicit
    Euler, h the step [s]; plus the mass-proportional damping's share); target: û (N, 6, 3) [m],
    the displacement jets of the predicted state at the samples the term is evaluated on, in
    their order (for an `Assembly`: its own order; only the value channel is read). Not
    scaled by the load factor (inertia is not a load)."""

    def __init__(self, areal_density: float, scale: float, target: torch.Tensor):
        if not (math.isfinite(areal_density) and areal_density > 0):
            raise ValueError(f"InertiaTerm: areal_density must be finite and > 0 [kg/m²], got "
                             f"{areal_density!r}")
        if not (math.isfinite(scale) and scale > 0):
            raise ValueError(f"InertiaTerm: scale must be finite and > 0 [1/s²], got {scale!r}")
        if target.dim() != 3 or target.shape[1:] != (jets.CHANNELS, 3):
            raise ValueError(f"InertiaTerm: target must be (N, 6, 3) jets, got "
                             f"{tuple(target.shape)}")
        self.areal_density = float(areal_density)
        self.scale = float(scale)
        self.target = target

    def _springs(self, samples: SurfaceSamples, u_jets: torch.Tensor) -> torch.Tensor:
        """s m_q (N,) [kg/s²]."""
        if u_jets.shape[0] != self.target.shape[0]:
            raise ValueError(f"InertiaTerm: {u_jets.shape[0]} points, but the target has "
                             f"{self.target.shape[0]}")
        return self.scale * point_masses(samples, self.areal_density, u_jets.dtype)

    def evaluate(self, samples: SurfaceSamples, u_jets: torch.Tensor,
                 load_factor: float | torch.Tensor = 1.0, *, grad: bool = True
                 ) -> tuple[float, torch.Tensor | None]:
        """E [J] and dE/du_jets (N, 6, 3) [N]."""
        springs = self._springs(samples, u_jets)
        gap = u_jets[:, jets.VALUE] - self.target[:, jets.VALUE].to(u_jets.dtype)
        value = 0.5 * float((springs * (gap * gap).sum(dim=1)).sum())
        if not grad:
            return value, None
        gradient = torch.zeros_like(u_jets)
        gradient[:, jets.VALUE] = springs[:, None] * gap
        return value, gradient

    def hessian_blocks(self, samples: SurfaceSamples, u_jets: torch.Tensor,
                       load_factor: float | torch.Tensor = 1.0, *,
                       steps: torch.Tensor | None = None, rows: slice | None = None
                       ) -> torch.Tensor:
        """Per-point blocks (N, 6, 3, 6, 3): s m_q I on the value channel (exact: E is
        quadratic); assembled, s M. rows: only those points' blocks (n, 6, 3, 6, 3)."""
        springs = self._springs(samples, u_jets)
        if rows is not None:
            springs = springs[rows]
        blocks = u_jets.new_zeros(springs.shape[0], jets.CHANNELS, 3, jets.CHANNELS, 3)
        eye = torch.eye(3, dtype=u_jets.dtype, device=u_jets.device)
        blocks[:, jets.VALUE, :, jets.VALUE, :] = springs[:, None, None] * eye
        return blocks
