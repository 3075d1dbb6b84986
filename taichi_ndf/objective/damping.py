"""Stiffness-proportional (Rayleigh) damping of a time step as an energy term:
½ c (u − y)ᵀ K₀ (u − y), K₀ the shell's tangent stiffness held fixed over the step.

With K₀ = Σ_q J_qᵀ H_q J_q (H_q the per-point Hessian blocks of the strain energy at the
step's start, positive semi-definite so that the term only dissipates), the term is
½ c Σ_q (U_q − Y_q)ᵀ H_q (U_q − Y_q) over the 18 jet values of each point, and its Hessian
is c H_q per point: like the inertia (`taichi_ndf.objective.inertia`) a per-point term whose
assembly is the matrix it stands for. `taichi_ndf.solve.dynamics` sets c and y from the
integrator (the damping force −β_R K₀ v, β_R [s]).
"""

from __future__ import annotations

import math

import torch

from taichi_ndf import jets
from taichi_ndf.problem.sampling import SurfaceSamples

JET_VALUES = jets.CHANNELS * 3


class StiffnessDampingTerm:
    """E = ½ c Σ_q (U_q − Y_q)ᵀ H_q (U_q − Y_q) [J] = ½ c (P − P_y)ᵀ K₀ (P − P_y).

    blocks: H_q (N, 6, 3, 6, 3) [J/m²], the per-point blocks of K₀ (symmetric, positive
    semi-definite: the strain treatment's, `ShellEnergyTerm.hessian_blocks(..., psd=True)`);
    scale: c ≥ 0, dimensionless (β_R/h for implicit Euler, β_R γ/(β h) for Newmark); target:
    Y (N, 6, 3) [m], the jets of the state the damping measures from, in the samples' order.
    Not scaled by the load factor."""

    def __init__(self, blocks: torch.Tensor, scale: float, target: torch.Tensor):
        if not (math.isfinite(scale) and scale >= 0):
            raise ValueError(f"StiffnessDampingTerm: scale must be finite and >= 0, got "
                             f"{scale!r}")
        count = target.shape[0]
        if target.shape != (count, jets.CHANNELS, 3) or \
                blocks.shape != (count, jets.CHANNELS, 3, jets.CHANNELS, 3):
            raise ValueError(f"StiffnessDampingTerm: blocks (N, 6, 3, 6, 3) and target (N, 6, 3) "
                             f"of the same N, got {tuple(blocks.shape)} and "
                             f"{tuple(target.shape)}")
        self.blocks = blocks.reshape(count, JET_VALUES, JET_VALUES)
        self.scale = float(scale)
        self.target = target

    def evaluate(self, samples: SurfaceSamples, u_jets: torch.Tensor,
                 load_factor: float | torch.Tensor = 1.0, *, grad: bool = True
                 ) -> tuple[float, torch.Tensor | None]:
        """E [J] and dE/du_jets (N, 6, 3)."""
        gap = (u_jets - self.target.to(u_jets.dtype)).reshape(-1, JET_VALUES, 1)
        force = self.scale * torch.bmm(self.blocks.to(u_jets.dtype), gap)
        value = 0.5 * float((gap * force).sum())
        if not grad:
            return value, None
        return value, force.reshape(u_jets.shape)

    def hessian_blocks(self, samples: SurfaceSamples, u_jets: torch.Tensor,
                       load_factor: float | torch.Tensor = 1.0, *,
                       steps: torch.Tensor | None = None, rows: slice | None = None
                       ) -> torch.Tensor:
        """c H_q (N, 6, 3, 6, 3) (exact: E is quadratic), or (n, 6, 3, 6, 3) of the points
        `rows` (a chunk of the samples)."""
        blocks = self.blocks if rows is None else self.blocks[rows]
        return (self.scale * blocks.to(u_jets.dtype)).reshape(
            blocks.shape[0], jets.CHANNELS, 3, jets.CHANNELS, 3).clone()
