"""J's products over the points of a knot span, one batched GEMM per span.

The m Gauss points of a span act on the same k coefficients, so the assembly
(`taichi_ndf.minimise.assembly`) takes them together: U = J C of a span's points is one
(m ch × k)(k × 3) product (`span_displacement`), the pull-back Jᵀ g one (k × m ch)(m ch × 3)
(`span_pullback`), and K's point-local part Σ_q J_qᵀ H_q J_q of the span (`pair_sums`) a
product per point, H_q J_q for all component pairs at once, then one (k × m ch)(m ch × 6k)
product: J's stored arrays (`ComponentJacobian`) give one product each, one in all where the
three components share one. Rounding: the sums run in another order than point by point and
component by component (relative differences ~1e-16; tests/test_assembly_extra_points.py checks
them against the sums written out).
"""

from __future__ import annotations

import torch

from taichi_ndf import jets
from taichi_ndf.minimise.group_pattern import PAIRS
from taichi_ndf.minimise.jacobian import ComponentJacobian
from taichi_ndf.shell.hessian import COMPONENTS


def by_array(jacobian: ComponentJacobian) -> list[tuple[torch.Tensor, slice | list[int]]]:
    """Each stored array of J (N, ch, k) with the components that use it: a slice where it
    serves all three (views, no copies), else a list."""
    if len(jacobian.arrays) == 1:
        return [(jacobian.arrays[0], slice(None))]
    return [(array, [c for c in range(COMPONENTS) if jacobian.slots[c] == s])
            for s, array in enumerate(jacobian.arrays)]


def pairs_of(components: slice | list[int], side: int) -> slice | list[int]:
    """The indices into `PAIRS` whose component on `side` (0: c, 1: d) is among
    `components` (a slice for all)."""
    if isinstance(components, slice):
        return components
    return [i for i, pair in enumerate(PAIRS) if pair[side] in components]


def pair_entries(channels: torch.Tensor) -> torch.Tensor:
    """Where the pairs' blocks H[:, c, :, d] on `channels` (ascending, ch of the 6 jet
    channels) lie in a flat per-point block (18 × 18, index channel × 3 + component): (ch ·
    6 · ch,) int64, laid out [j, p, l] for the pairs p of `PAIRS`."""
    grid = torch.arange((jets.CHANNELS * COMPONENTS) ** 2).reshape(
        jets.CHANNELS, COMPONENTS, jets.CHANNELS, COMPONENTS)[channels][:, :, channels]
    return torch.stack([grid[:, c, :, d] for c, d in PAIRS], dim=1).reshape(-1)


def span_displacement(jacobian: ComponentJacobian, local: torch.Tensor, m: int
                      ) -> torch.Tensor:
    """U[q, j, c] = Σ_a J[c, q, j, a] C_s[a, c] of the first G m points (G spans of m
    consecutive points; span s's coefficients C_s: `local` (G, k, 3)): (N, ch, 3), the rows
    past G m left unset."""
    (_, points, channels, k), count = jacobian.shape, local.shape[0]
    regular = count * m
    out = local.new_empty(points, channels, COMPONENTS)
    for array, cs in by_array(jacobian):
        spans = array[:regular].reshape(count, m * channels, k)
        out[:regular, :, cs] = torch.bmm(spans, local[:, :, cs]).reshape(regular, channels, -1)
    return out


def span_pullback(jacobian: ComponentJacobian, grad: torch.Tensor, count: int, m: int
                  ) -> torch.Tensor:
    """G[s, a, c] = Σ_{q in span s} Σ_j J[c, q, j, a] g[q, j, c] of g (N, ch, 3) over the first
    `count` spans of m consecutive points: (count, k, 3)."""
    (_, _, channels, k), regular = jacobian.shape, count * m
    out = grad.new_empty(count, k, COMPONENTS)
    for array, cs in by_array(jacobian):
        spans = array[:regular].reshape(count, m * channels, k)
        right = grad[:regular, :, cs].reshape(count, m * channels, -1)
        out[:, :, cs] = torch.bmm(spans.transpose(1, 2), right)
    return out


def pair_sums(jacobian: ComponentJacobian, blocks: torch.Tensor, entries: torch.Tensor, m: int
              ) -> torch.Tensor:
    """R[s, a, p, b] = Σ_{q in span s} J_c,qᵀ H_q[:, c, :, d] J_d,q for the pairs p = (c, d) of
    `PAIRS` (c ≤ d; the others are their transposes): J (3, G m, ch, k) on the channels the
    blocks touch, blocks (G m, 18 · 18) flat, `entries` the pairs' blocks on those channels in
    them (`pair_entries`, gathered per point); (G, k, 6, k). T = H J for all pairs in one
    batched GEMM per point, then Jᵀ T in one per span (the span's points in the inner
    dimension), each per stored array of J."""
    (_, n, channels, k), count = jacobian.shape, blocks.shape[0] // m
    # the same copy as index_select along dim 1 (whose CPU path copies element by element):
    # 49.7 against 52.1 ms of the napkin's 32² assembly (benchmarks/RESULTS.md, wip-speed36)
    gathered = torch.gather(blocks, 1, entries.expand(n, -1)).reshape(
        n, channels, len(PAIRS), channels)
    weighted = gathered.new_empty(n, channels, len(PAIRS), k)  # [q, j, p, b]
    out = gathered.new_empty(count, k, len(PAIRS), k)  # [s, a, p, b]
    arrays = by_array(jacobian)
    local = [array.contiguous() for array, _ in arrays]  # batched BLAS (a strided J: ≤ 4× slower)
    for array, (_, components) in zip(local, arrays, strict=True):
        ps = pairs_of(components, 1)
        if isinstance(ps, slice):  # all pairs: straight into `weighted`
            torch.bmm(gathered.reshape(n, -1, channels), array, out=weighted.view(n, -1, k))
        else:
            weighted[:, :, ps] = torch.bmm(gathered[:, :, ps].reshape(n, -1, channels),
                                           array).reshape(n, channels, len(ps), k)
    right = weighted.reshape(count, m * channels, len(PAIRS), k)
    for array, (_, components) in zip(local, arrays, strict=True):
        left, ps = array.reshape(count, m * channels, k).transpose(1, 2), pairs_of(components, 0)
        if isinstance(ps, slice):
            torch.bmm(left, right.reshape(count, m * channels, -1), out=out.view(count, k, -1))
        else:
            out[:, :, ps] = torch.bmm(left, right[:, :, ps].reshape(count, m * channels, -1)
                                      ).reshape(count, k, len(ps), k)
    return out
