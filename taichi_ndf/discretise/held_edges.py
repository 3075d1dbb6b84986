"""Held edges of flat-cut garment panels (`problem.multipatch.Patch.held`): the joined
linearisation with the held rows of coefficients fixed (`HeldEdges`), and the path of those
rows towards a held target over the load steps (`held_moves`: a gathered waist)."""

from __future__ import annotations

import numpy as np
import torch

from taichi_ndf.minimise.multipatch import MultiPatchLinearisation


class HeldEdges(MultiPatchLinearisation):
    """`MultiPatchLinearisation` with further unknowns `held` (sorted indices into the joint
    unknowns, or None): no step and no gradient there (`Patch.held`)."""

    def __init__(self, grids, load_factor: float, held: np.ndarray | None):
        super().__init__(grids, load_factor)
        self.held = held
        if held is not None:
            self.fixed = held if self.fixed is None else np.union1d(self.fixed, held)

    def gradient(self, grad_u_jets: torch.Tensor) -> torch.Tensor:
        gradient = super().gradient(grad_u_jets)
        if self.held is not None:
            gradient.reshape(-1)[torch.from_numpy(self.held)] = 0.0
        return gradient


def _offsets(fields) -> np.ndarray:
    """Each patch's first joint unknown (3 per coefficient, in the plan's order)."""
    return np.cumsum([0] + [3 * f.coefficients.shape[0] for f in fields])


def joined(patches, fields, grids, load_factor: float) -> HeldEdges:
    """The patches' (`Patch`, with their `SplineField`s `fields`) joined linearisation of
    `grids` at `load_factor`, the held edges' unknowns held too."""
    held = [p.held_unknowns() + o for p, o in zip(patches, _offsets(fields), strict=False)
            if p.held]
    return HeldEdges(grids, load_factor, np.concatenate(held) if held else None)


def held_moves(patches, targets, fields, start: torch.Tensor):
    """(unknowns, start values, target values) of the held rows of the patches that have a
    held target (`targets`: per patch the fitted target field or None), the start values
    from the joint start coefficients `start` (the fitted placement); None: none."""
    index, target = [], []
    for patch, field, offset in zip(patches, targets, _offsets(fields), strict=False):
        if field is not None:
            held = patch.held_unknowns()
            index.append(torch.from_numpy(held + offset))
            target.append(field.coefficients.detach().reshape(-1)[held])
    if not index:
        return None
    index = torch.cat(index)
    return index, start.reshape(-1)[index].clone(), torch.cat(target).to(start)
