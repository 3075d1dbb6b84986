"""Hessian entries of Π between pairs of points: the couplings a per-point block cannot hold.

Most terms of Π are sums of per-point energies e_q(U_q), whose Hessian over the jets is one
18 × 18 block per point (`Objective.hessian_blocks`). A term that joins two points — a stitch
of a seam (`StitchTerm`), a mass matrix between quadrature points, a data term over a pair —
has entries between their jets as well. Such a term gives its whole Hessian as a sum over
pairs p of points (a_p, b_p):

    d²Π_term/dU² = Σ_p E_pᵀ H_p E_p,    E_p U = (U_{a_p}, U_{b_p}) (36 jet entries),

H_p a 36 × 36 block, index endpoint × 18 + channel × 3 + component (each endpoint's 18 entries
in the order of `taichi_ndf.shell.hessian.flat_blocks`). The assembly maps each pair block to
the coefficients acting at its two points (`Assembly.hessian`, `DenseLinearisation.hessian`);
projected Newton projects each pair block to positive semi-definite as it does the per-point
blocks (a sum of PSD pair blocks is PSD).

A term with couplings has a method ``coupled_hessian(samples, u_jets, load_factor) ->
Couplings``; its per-point part, if any, comes from its own ``hessian_blocks`` (no central
differences are taken of a coupled term: perturbing every point at once, as
`sample_hessians` does, would fold the couplings into the per-point blocks).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import torch

from taichi_ndf.shell.hessian import JET_SIZE, project_psd

PAIR_SIZE = 2 * JET_SIZE  # 36: both endpoints' jets


@dataclass(frozen=True)
class Couplings:
    """Pair blocks of Π's Hessian (module docstring): points (P, 2) int64 row numbers of the
    two points of each pair in the samples the term was given; blocks (P, 36, 36)."""

    points: torch.Tensor
    blocks: torch.Tensor

    def __post_init__(self):
        if self.points.dim() != 2 or self.points.shape[1] != 2:
            raise ValueError(f"Couplings.points must be (P, 2), got {tuple(self.points.shape)}")
        if self.points.dtype != torch.int64:
            raise ValueError(f"Couplings.points must be int64, got {self.points.dtype}")
        if tuple(self.blocks.shape) != (self.points.shape[0], PAIR_SIZE, PAIR_SIZE):
            raise ValueError(f"Couplings.blocks must be ({self.points.shape[0]}, {PAIR_SIZE}, "
                             f"{PAIR_SIZE}), got {tuple(self.blocks.shape)}")

    def __len__(self) -> int:
        return self.points.shape[0]

    def endpoint_blocks(self) -> torch.Tensor:
        """The blocks as (P, 2, 6, 3, 2, 6, 3): [p, a, i, c, b, j, d] = ∂²Π/∂U_a[i, c]∂U_b[j, d]
        (a, b: first or second point)."""
        return self.blocks.reshape(len(self), 2, JET_SIZE // 3, 3, 2, JET_SIZE // 3, 3)

    def projected(self, mode: str = "clamp") -> tuple[Couplings, int]:
        """The pair blocks projected to positive semi-definite (`project_psd`) and how many
        were indefinite."""
        if not len(self):
            return self, 0
        blocks, count = project_psd(self.blocks, mode=mode)
        return Couplings(self.points, blocks), count

    @staticmethod
    def join(parts: Iterable[Couplings | None]) -> Couplings | None:
        """All pairs of `parts` (None where there are none)."""
        parts = [p for p in parts if p is not None and len(p)]
        if not parts:
            return None
        if len(parts) == 1:
            return parts[0]
        return Couplings(torch.cat([p.points for p in parts]),
                         torch.cat([p.blocks for p in parts]))
