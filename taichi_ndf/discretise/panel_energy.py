"""The shell energy of several panels of different materials as one term over their joined
points: `PanelEnergy`, each panel's `ShellEnergyTerm` (its material, its gravity through its
own areal density) on its own rows of the joined samples."""

from __future__ import annotations

from collections.abc import Sequence

import torch

from taichi_ndf.objective import ShellEnergyTerm
from taichi_ndf.problem.loads import Loads
from taichi_ndf.problem.sampling import SurfaceSamples
from taichi_ndf.shell.energy import EnergyResult


def _part(samples: SurfaceSamples, rows: slice) -> SurfaceSamples:
    """The samples of `rows`."""
    barrier = None if samples.barrier_weight is None else samples.barrier_weight[rows]
    return SurfaceSamples(samples.xi[rows], samples.r_jets[rows], samples.weight[rows],
                          samples.point_force[rows], barrier)


class PanelEnergy:
    """Σ_i Π_shell(material_i) over the rows `rows[i]` of the joined samples (a slice per
    panel, together every row, in order), under `loads` (gravity acts through each panel's
    own areal density). Behaves as the objective's shell term (`ShellEnergyTerm`): `result`,
    `evaluate`, `hessian_blocks`; its `stiffness_terms` are empty (no one material)."""

    def __init__(self, materials: Sequence, loads: Loads, rows: Sequence[slice]):
        if len(materials) != len(rows):
            raise ValueError(f"PanelEnergy: {len(materials)} materials for {len(rows)} panels")
        self.terms = [ShellEnergyTerm(m, loads) for m in materials]
        self.rows = list(rows)
        self.loads = loads

    def result(self, samples: SurfaceSamples, u_jets: torch.Tensor,
               load_factor: float = 1.0, *, grad: bool = True) -> EnergyResult:
        """The panels' results joined: totals summed, per-point fields concatenated."""
        parts = [term.result(_part(samples, rows), u_jets[rows], load_factor, grad=grad)
                 for term, rows in zip(self.terms, self.rows, strict=True)]
        return EnergyResult(
            total=sum(p.total for p in parts), internal=sum(p.internal for p in parts),
            external=sum(p.external for p in parts),
            density=torch.cat([p.density for p in parts]),
            sqrt_a=torch.cat([p.sqrt_a for p in parts]), stiffness_terms=(),
            grad_u_jets=torch.cat([p.grad_u_jets for p in parts]) if grad else None)

    def evaluate(self, samples: SurfaceSamples, u_jets: torch.Tensor,
                 load_factor: float = 1.0, *, grad: bool = True
                 ) -> tuple[float, torch.Tensor | None]:
        result = self.result(samples, u_jets, load_factor, grad=grad)
        return result.total, result.grad_u_jets

    def hessian_blocks(self, samples: SurfaceSamples, u_jets: torch.Tensor,
                       load_factor: float = 1.0, *, steps: torch.Tensor, psd: bool = False,
                       rows: slice | None = None) -> torch.Tensor:
        """Per-point blocks (N, 6, 3, 6, 3), or those of `rows` (a chunk, which may span
        panels): each panel's `ShellEnergyTerm.hessian_blocks` on its part of the chunk."""
        start, stop, _ = (rows or slice(None)).indices(len(samples))
        blocks = []
        for term, own in zip(self.terms, self.rows, strict=True):
            lo, hi = max(start, own.start), min(stop, own.stop)
            if lo < hi:
                blocks.append(term.hessian_blocks(
                    _part(samples, own), u_jets[own], load_factor, steps=steps, psd=psd,
                    rows=slice(lo - own.start, hi - own.start)))
        return torch.cat(blocks)
