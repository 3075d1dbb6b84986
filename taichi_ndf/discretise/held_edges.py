"""Held edges of flat-cut garment panels (`problem.multipatch.Patch.held`): the joined
linearisation with the held rows of coefficients fixed (`HeldEdges`), and the path of those
rows towards a held target over the load steps (`held_moves`: a gathered waist)."""

from __future__ import annotations

import numpy as np
import torch

from taichi_ndf.minimise.multipatch import MultiPatchLinearisation


class HeldEdges(MultiPatchLinearisation):
    """`MultiPatchLinearisation` of `grids` with the held edges' unknowns of `patches`
    (`Patch.held`) held too: no step and no gradient there. held: their sorted indices into
    the joint unknowns (None: no patch has held edges)."""

    def __init__(self, grids, load_factor: float, patches):
        super().__init__(grids, load_factor)
        held = [p.held_unknowns() + o for p, o in zip(patches, self.unknown_offsets(),
                                                       strict=False) if p.held]
        self.held = np.concatenate(held) if held else None
        if self.held is not None:
            self.fixed = self.held if self.fixed is None else np.union1d(self.fixed, self.held)

    def unknown_offsets(self) -> list[int]:
        """Each patch's first joint unknown (3 per coefficient, in the plan's order)."""
        return [3 * o for o in self.coefficient_offsets[:-1]]

    def gradient(self, grad_u_jets: torch.Tensor) -> torch.Tensor:
        gradient = super().gradient(grad_u_jets)
        if self.held is not None:
            gradient.reshape(-1)[torch.from_numpy(self.held)] = 0.0
        return gradient


def held_moves(patches, targets, linear: HeldEdges, start: torch.Tensor):
    """(unknowns, start values, target values) of the held rows of the patches that have a
    held target (`targets`: per patch the fitted target field or None), numbered as `linear`'s
    joint unknowns, the start values from the joint start coefficients `start` (the fitted
    placement); None: none."""
    index, target = [], []
    for patch, field, offset in zip(patches, targets, linear.unknown_offsets(), strict=False):
        if field is not None:
            held = patch.held_unknowns()
            index.append(torch.from_numpy(held + offset))
            target.append(field.coefficients.detach().reshape(-1)[held])
    if not index:
        return None
    index = torch.cat(index)
    return index, start.reshape(-1)[index].clone(), torch.cat(target).to(start)
