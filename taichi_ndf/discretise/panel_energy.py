"""The energy terms of a garment's panels over their joined points: the shell energy of
panels of different materials as one term (`PanelEnergy`, each panel's `ShellEnergyTerm` —
its material, its gravity through its own areal density — on its own rows of the joined
samples), and a seam sewn from where the panels start rather than from their rest shapes
(`SewnFromStart`)."""

from __future__ import annotations

import copy
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
    `evaluate`, `hessian_blocks`; its `stiffness_terms` are empty (no one material);
    `restricted(keep)`: the same panels on a subset of the rows (the contact rounds' shell
    blocks, `contact.newton_contact.ContactPotential`)."""

    def __init__(self, materials: Sequence, loads: Loads, rows: Sequence[slice]):
        if len(materials) != len(rows):
            raise ValueError(f"PanelEnergy: {len(materials)} materials for {len(rows)} panels")
        self.terms = [ShellEnergyTerm(m, loads) for m in materials]
        self.rows = list(rows)
        self.loads = loads

    def restricted(self, keep: torch.Tensor) -> PanelEnergy:
        """The same panels on the rows that `keep` (N,) bool selects of the joined samples, in
        their order: each panel's kept rows are again one slice of the subset."""
        counts = [int(keep[rows].sum()) for rows in self.rows]
        starts = [sum(counts[:i]) for i in range(len(counts))]
        part = copy.copy(self)
        part.rows = [slice(a, a + n) for a, n in zip(starts, counts, strict=True)]
        return part

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

    def tangent_length(self, samples: SurfaceSamples, u_jets: torch.Tensor
                       ) -> tuple[float, ...]:
        """Each panel's `ShellEnergyTerm.tangent_length` on its rows: what
        `hessian_blocks(tangent=)` takes."""
        return tuple(term.tangent_length(_part(samples, own), u_jets[own])
                     for term, own in zip(self.terms, self.rows, strict=True))

    def hessian_blocks(self, samples: SurfaceSamples, u_jets: torch.Tensor,
                       load_factor: float = 1.0, *, steps: torch.Tensor, psd: bool = False,
                       rows: slice | None = None, tangent: tuple[float, ...] | None = None
                       ) -> torch.Tensor:
        """Per-point blocks (N, 6, 3, 6, 3), or those of `rows` (a chunk, which may span
        panels): each panel's `ShellEnergyTerm.hessian_blocks` on its part of the chunk, with
        its `tangent_length` from `tangent` (computed per panel where None)."""
        start, stop, _ = (rows or slice(None)).indices(len(samples))
        blocks = []
        for i, (term, own) in enumerate(zip(self.terms, self.rows, strict=True)):
            lo, hi = max(start, own.start), min(stop, own.stop)
            if lo < hi:
                blocks.append(term.hessian_blocks(
                    _part(samples, own), u_jets[own], load_factor, steps=steps, psd=psd,
                    rows=slice(lo - own.start, hi - own.start),
                    tangent=None if tangent is None else tangent[i]))
        return torch.cat(blocks)


class SewnFromStart:
    """A seam term (`SeamTerm`) whose sewing starts from the start displacement jets `start`
    (N, 6, 3) [m] at the joined samples instead of the rest shape: at load factor λ its ties
    are to (1 − λ) times their values at the start, so a seam that the panels' placement
    closes stays closed at every load step, and one it leaves open is closed gradually from
    there (a flat-cut panel's rest shape is its pattern, far from where it is sewn). The
    seam's gap and tangent tie are affine in u, so this is the seam evaluated at
    u − (1 − λ) u_start (the same gradient; the same pair blocks, which do not depend on u);
    from λ = 1 on it is the seam itself."""

    def __init__(self, term, start: torch.Tensor):
        self.term = term
        self.spec = term.spec
        self.start = start

    def _shifted(self, u_jets: torch.Tensor, load_factor: float) -> torch.Tensor:
        open_ = 1.0 - min(max(float(load_factor), 0.0), 1.0)
        return u_jets - open_ * self.start.to(u_jets) if open_ else u_jets

    def evaluate(self, samples: SurfaceSamples, u_jets: torch.Tensor,
                 load_factor: float = 1.0, *, grad: bool = True
                 ) -> tuple[float, torch.Tensor | None]:
        return self.term.evaluate(samples, self._shifted(u_jets, load_factor), load_factor,
                                  grad=grad)

    def coupled_hessian(self, samples: SurfaceSamples, u_jets: torch.Tensor,
                        load_factor: float = 1.0):
        return self.term.coupled_hessian(samples, self._shifted(u_jets, load_factor),
                                         load_factor)
