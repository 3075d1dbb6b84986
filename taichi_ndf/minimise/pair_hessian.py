"""The block products of the spline assembly and the pair blocks' part of K.

For per-point blocks H (n, 6, 3, 6, 3) and per-component Jacobians J (3, n, 6, k) of the
points' jets over the k coefficients acting at each (`taichi_ndf.minimise.assembly`):
`weighted` is H J, `contract` Jᵀ (H J), the (n, k, 3, k, 3) local stiffness of each point.

A term that joins two points (`taichi_ndf.objective.couplings`: a seam's stitches, self-
contact) adds Σ_p A_pᵀ H_p A_p, A_p the Jacobian of both points' jets over the coefficients
acting at either (and the pin's), per pair p (`coupled_hessian`). Only the jet channels some
pair block touches enter the products (those terms act on the value channel only: 1 of the
6 channels, a 36 × 36 pair block with 6 × 6 non-zero entries); the rest are exact zeros.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import torch

from taichi_ndf import jets
from taichi_ndf.objective.couplings import Couplings
from taichi_ndf.shell.hessian import COMPONENTS, used_entries


def weighted(blocks: torch.Tensor, jacobian: torch.Tensor) -> torch.Tensor:
    """T[q, i, c, b, d] = Σ_j H[q, i, c, j, d] J[d, q, j, b]: blocks (n, ch, 3, ch', 3) times
    Jacobians (3, n, ch', k); shape (n, ch, 3, k, 3)."""
    return torch.einsum("qicjd,dqjb->qicbd", blocks, jacobian)


def contract(jacobian: torch.Tensor, weighted_blocks: torch.Tensor) -> torch.Tensor:
    """M[q, a, c, b, d] = Σ_i J[c, q, i, a] T[q, i, c, b, d], shape (n, k, 3, k, 3)."""
    return torch.einsum("cqia,qicbd->qacbd", jacobian, weighted_blocks)


def dofs(index: torch.Tensor) -> np.ndarray:
    """Unknown numbers (…, 3k) of coefficient indices (…, k): coefficient × 3 + component."""
    idx = index.cpu().numpy().astype(np.int64)
    return (idx[..., :, None] * COMPONENTS + np.arange(COMPONENTS)).reshape(*idx.shape[:-1], -1)


def touched_channels(blocks: torch.Tensor) -> torch.Tensor:
    """The jet channels (int64, ascending) that some block (n, 6, 3, 6, 3) has an entry in
    (NaN and ±inf count); channel 0 where all blocks are zero."""
    touched = used_entries(blocks).any(dim=3).any(dim=1)
    used = torch.nonzero(touched.any(dim=0) | touched.any(dim=1)).flatten()
    return used if used.numel() else torch.zeros(1, dtype=torch.int64, device=used.device)


def coupled_hessian(assembly, couplings: Couplings, *, all_channels: bool = False
                    ) -> sp.csr_matrix:
    """Σ_p A_pᵀ H_p A_p (3n × 3n, CSR, float64) of pair blocks H_p (`Couplings`; their points
    in the `Assembly`'s order) over the channels the pair blocks touch (`all_channels`: all
    six, the products over exact zeros too; the same K to rounding)."""
    ends = couplings.endpoint_blocks()  # (P, 2, 6, 3, 2, 6, 3)
    count = len(couplings)
    # to the boundary frame's components, each endpoint pair's 18 × 18 block alike
    ends = assembly._operator.blocks_to_frame(
        ends.permute(0, 1, 4, 2, 3, 5, 6).reshape(count * 4, jets.CHANNELS * COMPONENTS,
                                                  jets.CHANNELS * COMPONENTS)
    ).reshape(count, 2, 2, jets.CHANNELS, COMPONENTS, jets.CHANNELS, COMPONENTS)
    used = torch.arange(jets.CHANNELS) if all_channels else touched_channels(
        ends.reshape(count * 4, jets.CHANNELS, COMPONENTS, jets.CHANNELS, COMPONENTS))
    if used.numel() < jets.CHANNELS:
        ends = ends[:, :, :, used][:, :, :, :, :, used]
    jacobians, numbers = [], []
    for end in range(2):
        rows = couplings.points[:, end].to(assembly.jacobian.device)
        jacobian = assembly.jacobian.rows(rows).channels(used).dense()  # (3, P, ch, k)
        index = dofs(assembly.basis.index[rows])  # (P, 3k)
        if assembly.pin_jacobian is not None:
            jacobian = torch.cat((jacobian, assembly.pin_jacobian[:, rows][:, :, used]), dim=3)
            index = np.concatenate((index, np.broadcast_to(assembly.pin_dofs,
                                                           (count, assembly.pin_dofs.size))), 1)
        jacobians.append(jacobian)
        numbers.append(index)
    matrix = sp.csr_matrix((assembly.size, assembly.size))
    for a, b in ((0, 0), (0, 1), (1, 0), (1, 1)):
        block = contract(jacobians[a], weighted(ends[:, a, b].to(assembly.jacobian.dtype),
                                                jacobians[b]))
        shape = (count, numbers[a].shape[1], numbers[b].shape[1])
        matrix = matrix + sp.coo_matrix((
            block.reshape(shape).double().cpu().numpy().ravel(),
            (np.broadcast_to(numbers[a][:, :, None], shape).ravel(),
             np.broadcast_to(numbers[b][:, None, :], shape).ravel())), shape=matrix.shape)
    return matrix.tocsr()
