"""K's fixed sparse pattern over groups of coefficients acting together.

The Gauss points of one knot span act on the same k coefficients (a group); the assembly
(`taichi_ndf.minimise.assembly`) sums each group's points' stiffness J_qᵀ H_q J_q into one
(3k)² block and scatters it into K's CSR data at positions found once per grid
(`csr_pattern`), reused across Newton and load steps without sorting. Points beyond a group's
first m (contact's check points, SfT's data points: their number differs from span to span)
are laid out in batches of one size per group (`batch_slots`), so that they are summed per
group by the same batched products before the scatter, not point by point.
"""

from __future__ import annotations

import numpy as np
import torch

from taichi_ndf.shell.hessian import COMPONENTS


def csr_pattern(groups: np.ndarray, n_coefficients: int
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """K's CSR pattern for groups of coefficients acting together (G, k): the position in K's
    data of each entry [c, d, g, a, b] of the per-group sums (3, 3, G, k, k) (`Assembly._pair_sums`:
    unknowns (3 groups[g, a] + c, 3 groups[g, b] + d)), the column of each datum (int32) and
    the row starts (3n + 1, int32); positions int32 where K has < 2³¹ entries. Found on the
    coefficient pairs (9× fewer keys than the unknown pairs): unknown row 3a + c holds the
    columns 3b + d of the coefficients b coupled to a, in order, so it starts at
    9 start[a] + 3 c count[a] (start, count: of coefficient row a)."""
    count_groups, k = groups.shape
    n = n_coefficients
    keys = (groups[:, :, None] * n + groups[:, None, :]).ravel()
    pairs, pair = np.unique(keys, return_inverse=True)
    per_row = np.bincount(pairs // n, minlength=n)
    start = np.concatenate(([0], np.cumsum(per_row)))
    first = start[groups][:, :, None]  # (G, k, 1): start of coefficient row a
    within = pair.reshape(count_groups, k, k) - first  # position of b in row a
    comps, base, rows = np.arange(COMPONENTS), 9 * first + 3 * within, per_row[groups][..., None]
    scatter = np.empty((COMPONENTS, COMPONENTS, *base.shape),
                       np.int32 if 9 * len(pairs) < 2 ** 31 else np.int64)
    for c, d in np.ndindex(COMPONENTS, COMPONENTS):
        scatter[c, d] = base + (3 * c * rows + d)
    lengths = np.repeat(3 * per_row, COMPONENTS)  # unknown rows: 3 columns per coefficient
    row_starts = np.concatenate(([0], np.cumsum(lengths)))
    columns3 = (3 * (pairs % n)[:, None] + comps).ravel()  # coefficient row a's at 3 start[a]
    index = np.arange(row_starts[-1]) - np.repeat(
        row_starts[:-1] - np.repeat(3 * start[:-1], COMPONENTS), lengths)
    return (scatter.ravel(), columns3[index].astype(np.int32),
            row_starts.astype(np.int32))


def batch_slots(groups: torch.Tensor) -> tuple[torch.Tensor, np.ndarray, int]:
    """Points of sorted group numbers (n,) laid out in batches of s = ⌈n / groups present⌉
    slots, each batch within one group (a group's last batch short, its slots left empty):
    the slot of each point (n,) (int64), the group of each batch (b,) and s. At most n + (s −
    1) × groups present slots, < 2 n."""
    present, counts = torch.unique_consecutive(groups, return_counts=True)
    size = -(-len(groups) // len(present))
    batches = -(-counts // size)  # per group
    first_point = torch.cumsum(counts, 0) - counts
    first_slot = (torch.cumsum(batches, 0) - batches) * size
    rank = torch.arange(len(groups), device=groups.device) - torch.repeat_interleave(
        first_point, counts)
    slots = torch.repeat_interleave(first_slot, counts) + rank
    return slots, torch.repeat_interleave(present, batches).cpu().numpy(), size


# The component pairs (c, d), c ≤ d, whose per-group sums the assembly computes; the others
# are their transposes (K is symmetric).
PAIRS = tuple((c, d) for c in range(COMPONENTS) for d in range(c, COMPONENTS))
MIRRORED = tuple(i for i, (c, d) in enumerate(PAIRS) if c != d)


def pair_scatter(scatter: np.ndarray, groups: int, k: int) -> tuple[np.ndarray, np.ndarray]:
    """`csr_pattern`'s positions (3, 3, G, k, k) laid out for per-group sums R (G, k, 6, k) of
    the pairs `PAIRS` (R[g, a, p, b]: unknowns (3 groups[g, a] + c, 3 groups[g, b] + d) for
    p = (c, d)): the positions of R (G, k, 6, k), and of R's `MIRRORED` pairs as their
    transposes (G, k, 3, k): R[g, a, p, b] at unknowns (3 groups[g, b] + d, 3 groups[g, a]
    + c)."""
    full = scatter.reshape(COMPONENTS, COMPONENTS, groups, k, k)
    upper = np.stack([full[c, d] for c, d in PAIRS], axis=2)  # (G, k, 6, k)
    lower = np.stack([full[d, c].transpose(0, 2, 1) for c, d in (PAIRS[i] for i in MIRRORED)],
                     axis=2)
    return upper, lower

