"""Newton's per-point Hessian blocks, built chunk by chunk of points as the assembly asks.

K = Σ_q J_qᵀ H_q J_q needs each point's 18 × 18 block H_q once: `PointBlocks` builds the blocks
of a slice of points when `Linearisation.hessian` asks for them (`Assembly.hessian`: chunks of
`POINT_CHUNK` points, each let go after its scatter), so that the blocks of all points — 2.6 kB
per point in float64, and the strain Hessian's temporaries — are never held at once. The
potential's own blocks by rows (`Objective.hessian_blocks`' rows) where it takes them, else all
points' at the first ask (`hessian_blocks`: its own or central differences of its gradient).
"""

from __future__ import annotations

import inspect
import time
from collections.abc import Callable
from functools import partial

import torch

from taichi_ndf.objective.couplings import Couplings
from taichi_ndf.shell.hessian import Potential, flat_blocks, project_psd, sample_hessians


def hessian_blocks(potential: Potential, samples, u_jets: torch.Tensor, steps: torch.Tensor
                   ) -> torch.Tensor:
    """Per-point Hessian blocks (N, 6, 3, 6, 3): the potential's own `hessian_blocks` (an
    `Objective.potential`: term by term) where it has one, else central differences of its
    gradient."""
    own = getattr(potential, "hessian_blocks", None)
    if own is not None:
        return own(samples, u_jets, steps=steps)
    return sample_hessians(potential, samples, u_jets, steps=steps)


def coupled_blocks(potential: Potential, samples, u_jets: torch.Tensor) -> Couplings | None:
    """The potential's Hessian entries between pairs of points (`Objective.coupled_blocks`),
    None where it has none."""
    own = getattr(potential, "coupled_blocks", None)
    return None if own is None else own(samples, u_jets)


def state_tangent(potential: Potential, samples, u_jets: torch.Tensor):
    """The shell's strain-step scale at U = u_jets where the potential has one
    (`tangent_length`: `Objective.potential`'s, whose blocks then take `tangent=`), else
    None: for a caller that builds several `PointBlocks` at one state (Newton's exact K, then
    its projected one), computed once."""
    length = getattr(potential, "tangent_length", None)
    return None if length is None else length(samples, u_jets)


class PointBlocks:
    """The per-point blocks (n, 18, 18) of a slice of points at U(P) = u_jets, built when
    asked (`Linearisation.hessian` asks chunk by chunk, so that the blocks of all points are
    never held): the exact (unprojected) ones with the FD steps `fd_step` × each channel's
    scale (`hessian_blocks`); psd: `psd_hessian_blocks`'; project: the exact ones projected
    (`project_psd` in that mode; `projected` counts the blocks it changed). A potential whose
    blocks cannot be asked by rows gives all of them on the first ask (kept, then cut); one
    with a `tangent_length` (`Objective.potential`'s) gets the shell's strain-step scale of
    all points (`state_tangent`) for every chunk: `tangent` where the caller has it for
    this state, else computed here.
    `seconds`: the time spent building and projecting blocks."""

    def __init__(self, linearisation, potential: Potential,
                 parameters: torch.Tensor, u_jets: torch.Tensor, fd_step: float,
                 psd: bool = False, project: str | None = None, tangent=None):
        self.samples, self.u_jets, self.project = linearisation.samples, u_jets, project
        self.steps = linearisation.fd_steps(u_jets, parameters, fd_step)
        own = potential.psd_hessian_blocks if psd else getattr(potential, "hessian_blocks",
                                                                None)
        self._own = own if own is not None and "rows" in inspect.signature(
            own).parameters else None
        if self._own is not None:
            # the shell's strain-step scale over all points, once per state, not per chunk
            if tangent is None:
                tangent = state_tangent(potential, self.samples, u_jets)
            if tangent is not None:
                self._own = partial(self._own, tangent=tangent)
        self._all = None if self._own is not None else (
            own if psd else partial(hessian_blocks, potential))
        self.projected, self.seconds = 0, 0.0

    def __call__(self, rows: slice) -> torch.Tensor:
        started = time.perf_counter()
        if self._own is not None:
            blocks = flat_blocks(self._own(self.samples, self.u_jets, steps=self.steps,
                                           rows=rows))
        else:
            if not isinstance(self._all, torch.Tensor):
                self._all = flat_blocks(self._all(self.samples, self.u_jets, steps=self.steps))
            blocks = self._all[rows]
        if self.project is not None:
            blocks, count = project_psd(blocks, mode=self.project, overwrite=self._own is not None)
            self.projected += count
        self.seconds += time.perf_counter() - started
        return blocks

    def __getitem__(self, rows: slice) -> Callable[[slice], torch.Tensor]:
        """The blocks of the points `rows` as a function of a slice of those (a patch's
        points: `taichi_ndf.minimise.multipatch`)."""
        return lambda part: self(slice(rows.start + part.start, rows.start + part.stop))


def point_blocks(linearisation, potential: Potential, parameters: torch.Tensor,
                 u_jets: torch.Tensor, fd_step: float, psd: bool = False) -> torch.Tensor:
    """The exact (unprojected) per-point blocks (N, 18, 18) of all points at U(P) = u_jets
    (`PointBlocks`); psd: `psd_hessian_blocks`'."""
    return PointBlocks(linearisation, potential, parameters, u_jets, fd_step, psd)(
        slice(0, len(linearisation.samples)))
