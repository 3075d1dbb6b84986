"""The block products of the spline assembly and the pair blocks' part of K.

For per-point blocks H (n, 6, 3, 6, 3) and per-component Jacobians J (3, n, 6, k) of the
points' jets over the k coefficients acting at each (`taichi_ndf.minimise.assembly`):
`weighted` is H J, `contract` Jᵀ (H J), the (n, k, 3, k, 3) local stiffness of each point.

A term that joins two points (`taichi_ndf.objective.couplings`: a seam's stitches, self-
contact) adds Σ_p A_pᵀ H_p A_p, A_p the Jacobian of both points' jets over the coefficients
acting at either (and the pin's), per pair p (`coupled_hessian`). Only the jet channels some
pair block touches enter the products (those terms act on the value channel only: 1 of the
6 channels, a 36 × 36 pair block with 6 × 6 non-zero entries); the rest are exact zeros.
All pairs at once: K = Aᵀ H A, A all A_p stacked (sparse), H the pair blocks as a block
diagonal; one sparse product sums the entries per row (the same K as Σ_p to rounding;
benchmarks/pair_scatter.py).
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
    jacobian, numbers = [], []
    for end in range(2):
        rows = couplings.points[:, end].to(assembly.jacobian.device)
        part = assembly.jacobian.rows(rows).channels(used).dense()  # (3, P, ch, k)
        index = dofs(assembly.basis.index[rows])  # (P, 3k)
        if assembly.pin_jacobian is not None:
            part = torch.cat((part, assembly.pin_jacobian[:, rows][:, :, used]), dim=3)
            index = np.concatenate((index, np.broadcast_to(assembly.pin_dofs,
                                                           (count, assembly.pin_dofs.size))), 1)
        jacobian.append(part)
        numbers.append(index)
    return scattered(_pair_jacobian(jacobian, numbers, assembly.size),
                      ends.permute(0, 1, 3, 4, 2, 5, 6)  # (P, 2, ch, 3, 2, ch, 3)
                      .reshape(count, 2 * used.numel() * COMPONENTS, -1))


def _pair_jacobian(jacobian: list[torch.Tensor], numbers: list[np.ndarray], size: int
                   ) -> sp.csr_matrix:
    """All pairs' A_p stacked (P m × size, CSR, float64; m = 2 ch 3): row p m + (end ch + i) 3
    + c of pair p holds J_end[c, p, i, a] at unknown numbers_end[p, 3 a + c], from the ends'
    Jacobians (3, P, ch, k) and unknown numbers (P, 3k)."""
    count, channels = jacobian[0].shape[1], jacobian[0].shape[2]
    values, columns = [], []
    for part, index in zip(jacobian, numbers, strict=True):
        k = part.shape[3]
        values.append(part.permute(1, 2, 0, 3).double().cpu().numpy())  # (P, ch, 3, k)
        columns.append(np.broadcast_to(  # (P, ch, 3, k): unknown 3 a + c
            index.reshape(count, 1, k, COMPONENTS).transpose(0, 1, 3, 2),
            (count, channels, COMPONENTS, k)))
    values = np.stack(values, axis=1).reshape(count * 2 * channels * COMPONENTS, -1)
    columns = np.stack(columns, axis=1).reshape(values.shape)
    rows = np.broadcast_to(np.arange(values.shape[0])[:, None], values.shape)
    return sp.csr_matrix((values.ravel(), (rows.ravel(), columns.ravel())),
                         shape=(values.shape[0], size))


def scattered(pair_jacobian: sp.csr_matrix, blocks: torch.Tensor) -> sp.csr_matrix:
    """Aᵀ H A (size × size, CSR) of the stacked Jacobians A (P m × size) and the pair blocks
    H (P, m, m) as a block diagonal: one sparse product, its sums accumulated per row (no
    triplet per entry of every A_pᵀ H_p A_p)."""
    count, m = blocks.shape[0], blocks.shape[1]
    diagonal = sp.bsr_matrix((blocks.double().cpu().numpy(), np.arange(count),
                              np.arange(count + 1)), shape=(count * m, count * m))
    transposed = pair_jacobian.T.tocsr()
    return (transposed @ (diagonal.tocsr() @ pair_jacobian)).tocsr()
