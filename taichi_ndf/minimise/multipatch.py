"""Several spline patches in one Newton: the block-diagonal join of their linearisations, with
pair couplings between points of different patches (the seams of issue 30's panels).

Patch i has its own spline grid, boundary conditions and points (a `GridLinearisation` and
its samples); its coefficients C_i (n_i, 3) are rows o_i … o_i + n_i of the joint parameters
P (Σ n_i, 3) and its points rows r_i … of the joint samples. U(P) = (U_1(C_1), U_2(C_2), …),
so Jᵀ, the per-point Hessian K = Σ Jᵀ H J and the held unknowns are each patch's, side by side.
A term that couples two points (`Couplings`: a seam between patches) adds Σ_p A_pᵀ H_p A_p,
A_p the Jacobian of both points' jets over the coefficients of their patches, from each
patch's `GridLinearisation.at_points` (the local basis at the two points): a sparse
product Sᵀ diag(H_p) S, S (P·36, 3 Σ n_i). Not supported (refused): a free pin or a tilted
boundary frame in a patch (the pin's coefficients and the frame's rotation of the blocks are
the single-patch `Assembly`'s business).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import scipy.sparse as sp
import torch

from taichi_ndf.minimise.linear_solve import damped_solve
from taichi_ndf.minimise.linearisation import GridLinearisation, SplineLinearisation
from taichi_ndf.minimise.pair_hessian import scattered
from taichi_ndf.objective.couplings import PAIR_SIZE, Couplings
from taichi_ndf.shell.hessian import COMPONENTS, JET_SIZE, jet_steps


class MultiPatchLinearisation:
    """The patches `grids` (each assembled on its points) at load factor t, joined (module
    docstring); length: the FD steps' domain length [ξ units] (`jet_steps`)."""

    def __init__(self, grids: Sequence[GridLinearisation], load_factor: float, *,
                 length: float = 1.0):
        for grid in grids:
            if grid.boundary is not None and grid.boundary.frame is not None:
                raise ValueError("a multi-patch linearisation takes no boundary frame")
        self.grids = list(grids)
        self.load_factor = float(load_factor)
        self.length = length
        self.parts: list[SplineLinearisation] = [g.linearisation(load_factor) for g in grids]
        sizes = [p.assembly.n_coefficients for p in self.parts]
        counts = [len(p.samples.xi) for p in self.parts]
        self.coefficient_offsets = np.concatenate(([0], np.cumsum(sizes))).tolist()
        self.row_offsets = np.concatenate(([0], np.cumsum(counts))).tolist()
        self.samples = self.parts[0].samples
        for part in self.parts[1:]:
            self.samples = self.samples.joined(part.samples)
        held = [None if p.fixed is None else p.fixed + COMPONENTS * o
                for p, o in zip(self.parts, self.coefficient_offsets, strict=False)]
        held = [h for h in held if h is not None]
        self.fixed = np.concatenate(held) if held else None
        self.size = COMPONENTS * self.coefficient_offsets[-1]

    def rows(self, patch: int) -> slice:
        """The rows of patch `patch`'s points in `samples`."""
        return slice(self.row_offsets[patch], self.row_offsets[patch + 1])

    def _coefficients(self, parameters: torch.Tensor, patch: int) -> torch.Tensor:
        return parameters[self.coefficient_offsets[patch]:self.coefficient_offsets[patch + 1]]

    def displacement(self, parameters: torch.Tensor) -> torch.Tensor:
        return torch.cat([p.displacement(self._coefficients(parameters, i))
                          for i, p in enumerate(self.parts)])

    def gradient(self, grad_u_jets: torch.Tensor) -> torch.Tensor:
        return torch.cat([p.gradient(grad_u_jets[self.rows(i)])
                          for i, p in enumerate(self.parts)])

    def fd_steps(self, u_jets: torch.Tensor, parameters: torch.Tensor,
                 relative: float) -> torch.Tensor:
        return jet_steps(self.samples.r_jets, u_jets, self.length, relative)

    def hessian(self, blocks: torch.Tensor, couplings: Couplings | None = None
                ) -> sp.csr_matrix:
        matrix = sp.block_diag([p.hessian(blocks[self.rows(i)])
                                for i, p in enumerate(self.parts)], format="csr")
        if couplings is None or not len(couplings):
            return matrix
        return (matrix + self.coupled_hessian(couplings)).tocsr()

    def coupled_hessian(self, couplings: Couplings) -> sp.csr_matrix:
        """Σ_p A_pᵀ H_p A_p (3 Σ n_i square, CSR) of pair blocks whose points are rows of
        `samples` (in any patches)."""
        count = len(couplings)
        points = couplings.points.reshape(-1).cpu()  # (2P,): pair p's ends at 2p, 2p + 1
        patch = np.searchsorted(self.row_offsets, points.numpy(), side="right") - 1
        rows, cols, vals = [], [], []
        for i, grid in enumerate(self.grids):
            ends = np.nonzero(patch == i)[0]
            if not ends.size:
                continue
            xi = self.samples.xi[points[ends]]
            at = grid.at_points(xi, self.load_factor)  # index (M, k), jacobian (3, M, 6, k)
            if at.pin is not None:
                raise ValueError("a multi-patch linearisation takes no free pin")
            k = at.index.shape[1]
            jacobian = at.jacobian.dense().double().cpu().numpy()
            index = at.index.cpu().numpy() + self.coefficient_offsets[i]
            # row (end e of pair p) 18 e' + 3 j + c with e' = 2p + side; column 3 C + c
            end = torch.as_tensor(ends).numpy()
            for c in range(COMPONENTS):
                shape = (len(ends), JET_SIZE // COMPONENTS, k)
                rows.append((JET_SIZE * end[:, None, None]
                             + COMPONENTS * np.arange(shape[1])[None, :, None] + c
                             + np.zeros(shape, dtype=np.int64)).ravel())
                cols.append((COMPONENTS * index[:, None, :] + c
                             + np.zeros(shape, dtype=np.int64)).ravel())
                vals.append(jacobian[c].ravel())
        jac = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                            shape=(count * PAIR_SIZE, self.size))
        return scattered(jac, couplings.blocks)

    def solve(self, matrix: sp.csr_matrix, gradient: torch.Tensor, damping: float, *,
              require_definite: bool = False) -> tuple[torch.Tensor, float] | None:
        rhs = -gradient.reshape(-1).double().cpu().numpy()
        result = damped_solve(matrix, rhs, damping, self.fixed,
                              require_definite=require_definite)
        if result is None:
            return None
        step, damping = result
        return torch.from_numpy(step).to(gradient).reshape(gradient.shape), damping

