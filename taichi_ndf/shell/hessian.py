"""Per-point Hessian of the potential with respect to the displacement jets, and its
projection to positive semi-definite.

Π = Σ_q e_q(U_q) is a sum of per-point terms, U_q the 18 jet values (6 channels × 3
components) of the displacement at point q, so d²Π/dU² is block diagonal: one 18 × 18 block per
point. Taichi has no second-order autodiff, so the blocks are central differences of the exact
Taichi-autodiff gradient dΠ/dU: perturbing one (channel, component) of every point at once is
exact for a sum of per-point terms, so 36 gradient evaluations give all blocks (any material
law, any energy term that is a sum over points; linear terms such as the external loads add
nothing). In float64 with steps ~1e-4 of each channel's scale the truncation error is
~1e-8 relative.

Projection (projected Newton): a block with a negative eigenvalue (compressive stress, a
buckling or folding state) is replaced by V max(Λ, 0) Vᵀ (clamped, the default) or V |Λ| Vᵀ
(mirrored, as Chen et al. 2024, "Trust-region eigenvalue filtering for projected Newton"), so
Σ Jᵀ H J is positive semi-definite and the Newton direction descends. On this project's
draped sheets mirroring took as many or more Newton steps (benchmarks/RESULTS.md). Only the
blocks that need it are eigen-decomposed: a batched Cholesky of H + τ I (τ a tiny fraction of
the block's mean diagonal) finds them first; at an unstressed or tensile state that is none.
Both work on the rows that are not zero in every block (`active_rows`).
"""

from __future__ import annotations

from collections.abc import Callable

import torch

from taichi_ndf import jets
from taichi_ndf.problem.sampling import SurfaceSamples
from taichi_ndf.shell.energy import EnergyResult

COMPONENTS = 3
JET_SIZE = jets.CHANNELS * COMPONENTS  # 18 jet values per point
# Relative shift of the Cholesky test: a block whose least eigenvalue is above −PSD_SLACK × its
# mean diagonal counts as semi-definite (rounding and FD noise are ~1e-8 of it in float64; in
# float32 the shift is 1000 ε, or rank-deficient blocks would all fail the test).
PSD_SLACK = 1e-7
# Blocks per chunk of `used_entries`'s sum (a ~5 MB temporary of 18 × 18 float64 blocks).
USED_CHUNK = 2048
# Blocks per chunk of the PSD screen and projection (`project_psd`): bounds their copies and
# factors (the whole batch at once: 1.1 GB beside 0.8 GB of blocks at 322 k points).
PROJECT_CHUNK = 16384

# Potential at given displacement jets: (samples, u_jets (N, 6, 3), grad) -> EnergyResult.
Potential = Callable[[SurfaceSamples, torch.Tensor, bool], EnergyResult]


def sample_hessians(potential: Potential, samples: SurfaceSamples, u_jets: torch.Tensor, *,
                    steps: torch.Tensor, stacked_points: int = 0) -> torch.Tensor:
    """Per-point Hessian blocks d²Π/du_jets², shape (N, 6, 3, 6, 3), symmetrised.

    steps: central-difference step of each jet channel, shape (6,) [m per unit ξ^order].
    Perturbing one (channel, component) of every point at once is exact for a sum of per-point
    terms. stacked_points: for a potential whose every point's term depends on that point's
    sample and jets alone (the shell energy), up to this many points per call: several of the
    36 perturbed copies of the samples stacked into one evaluation (one kernel launch instead
    of one per copy; each point's gradient, so each block, the same bit for bit); 0: one copy
    per call (any potential).
    """
    n = u_jets.shape[0]
    hessian = u_jets.new_zeros(n, jets.CHANNELS, COMPONENTS, jets.CHANNELS, COMPONENTS)
    shifts = [(c, k, sign) for c in range(jets.CHANNELS) for k in range(COMPONENTS)
              for sign in (1.0, -1.0)]
    copies = max(1, min(len(shifts), stacked_points // max(n, 1)))
    plus = None  # the gradient at +step of the shift being differenced
    for first in range(0, len(shifts), copies):
        batch = shifts[first:first + copies]
        shifted = u_jets.repeat(len(batch), 1, 1).reshape(len(batch), n, *u_jets.shape[1:])
        for copy, (c, k, sign) in enumerate(batch):
            shifted[copy, :, c, k] += sign * float(steps[c])
        stacked = samples if len(batch) == 1 else _repeated(samples, len(batch))
        grads = potential(stacked, shifted.reshape(-1, *u_jets.shape[1:]), True).grad_u_jets
        for (c, k, sign), grad in zip(batch, grads.reshape(len(batch), n, *u_jets.shape[1:]),
                                      strict=True):
            if sign > 0:
                plus = grad
            else:
                hessian[:, :, :, c, k] = (plus - grad) / (2 * float(steps[c]))
    return 0.5 * (hessian + hessian.permute(0, 3, 4, 1, 2))


def _repeated(samples: SurfaceSamples, copies: int) -> SurfaceSamples:
    """The samples `copies` times one after the other."""
    return SurfaceSamples(*(None if t is None else t.repeat(copies, *(1,) * (t.dim() - 1))
                            for t in (samples.xi, samples.r_jets, samples.weight,
                                      samples.point_force, samples.barrier_weight)))


def jet_steps(r_jets: torch.Tensor, u_jets: torch.Tensor, length: float,
              relative: float) -> torch.Tensor:
    """Central-difference step per jet channel, shape (6,): `relative` × the channel's scale,
    the RMS of the deformed position jets x = r + u, and at least the RMS of the first
    derivatives (over both directions) / length^(order − 1) — a flat reference has no second
    derivatives to take a scale from.

    length: a length of the parameter domain [ξ units], e.g. √(its area)."""
    x = r_jets + u_jets
    rms = x.pow(2).mean(dim=(0, 2)).sqrt()
    slope = float(rms[jets.D1:jets.D2 + 1].pow(2).mean().sqrt())
    floor = torch.tensor([slope * length, slope, slope, slope / length, slope / length,
                          slope / length], dtype=rms.dtype, device=rms.device)
    return relative * torch.maximum(rms, floor)


def flat_blocks(hessians: torch.Tensor) -> torch.Tensor:
    """The per-point blocks (N, 6, 3, 6, 3) as matrices (N, 18, 18), index channel × 3 +
    component."""
    return hessians.reshape(hessians.shape[0], JET_SIZE, JET_SIZE)


def used_entries(blocks: torch.Tensor) -> torch.Tensor:
    """Which entries of blocks (N, …) are not zero in every block, shape blocks.shape[1:]
    (bool; NaN and ±inf count as not zero): Σ |blocks| over the batch, summed in chunks of
    `USED_CHUNK` blocks (no full-size temporary: 7 against 18 ms for `torch.count_nonzero`
    over the batch, 12 544 blocks of 18 × 18, one core under load)."""
    flat = blocks.reshape(blocks.shape[0], -1)
    total = flat.new_zeros(flat.shape[1])
    for start in range(0, flat.shape[0], USED_CHUNK):
        total += flat[start:start + USED_CHUNK].abs().sum(dim=0)
    return (total != 0).reshape(blocks.shape[1:])


def active_rows(blocks: torch.Tensor) -> slice | torch.Tensor:
    """The rows (and columns) of blocks (N, m, m) that are not zero in every block, as a slice
    when they are a range (the shell's blocks: all but the value channel's 3): a block is
    positive semi-definite iff its part on them is, so the screen and the eigen-decompositions
    work on that part only."""
    rows = torch.nonzero(used_entries(blocks).any(dim=1)).flatten()
    if rows.numel() == 0:
        return slice(0, 0)
    first, last = int(rows[0]), int(rows[-1]) + 1
    return slice(first, last) if last - first == rows.numel() else rows


def _part(blocks: torch.Tensor, rows: slice | torch.Tensor) -> torch.Tensor:
    """blocks[:, rows][:, :, rows]."""
    if isinstance(rows, slice):
        return blocks[:, rows, rows]
    return blocks[:, rows][:, :, rows]


def indefinite_blocks(blocks: torch.Tensor, rows: slice | torch.Tensor | None = None
                      ) -> torch.Tensor:
    """Indices of the blocks (N, m, m) that are not positive semi-definite, by a batched
    Cholesky of H + τ I on their active rows (`active_rows`, or `rows` if given) (module
    docstring)."""
    blocks = _part(blocks, active_rows(blocks) if rows is None else rows)
    if blocks.shape[1] == 0:
        return torch.zeros(0, dtype=torch.int64, device=blocks.device)
    shifted = blocks.clone()
    diagonal = shifted.diagonal(dim1=1, dim2=2)
    scale = diagonal.abs().mean(dim=1, keepdim=True).clamp_min(torch.finfo(blocks.dtype).tiny)
    slack = max(PSD_SLACK, 1000 * torch.finfo(blocks.dtype).eps)  # float32: 1.2e-4
    diagonal.add_(slack * scale)
    _, info = torch.linalg.cholesky_ex(shifted)
    return torch.nonzero(info != 0).flatten()


# "strain": the blocks through the strains (`strain_hessian`, psd); blocks given alone: clamp.
PROJECTIONS = ("abs", "clamp", "strain")


def project_psd(blocks: torch.Tensor, bad: torch.Tensor | None = None, mode: str = "clamp",
                *, overwrite: bool = False) -> tuple[torch.Tensor, int]:
    """Blocks (N, m, m) projected to positive semi-definite, and how many were indefinite;
    overwrite: projected in place in `blocks` (no copy; for a caller done with the originals).
    mode "abs": negative eigenvalues replaced by their absolute values; "clamp" (and
    "strain", for blocks without their strains): by 0. Only
    the indefinite blocks (`indefinite_blocks`, or `bad` if given) are eigen-decomposed
    (module docstring). Screened and projected in chunks of at most `PROJECT_CHUNK` blocks
    (each block on its own: the same numbers as all at once)."""
    if mode not in PROJECTIONS:
        raise ValueError(f"projection must be one of {PROJECTIONS}, got {mode!r}")
    rows = active_rows(blocks)
    if bad is None:
        bad = torch.cat([indefinite_blocks(blocks[start:start + PROJECT_CHUNK], rows) + start
                         for start in range(0, blocks.shape[0], PROJECT_CHUNK)] or [
                             torch.zeros(0, dtype=torch.int64, device=blocks.device)])
    if bad.numel() == 0:
        return blocks, 0
    projected = blocks if overwrite else blocks.clone()
    # equal parts of at most PROJECT_CHUNK blocks: no small last batch (torch's eigh rounds
    # batches of a few matrices otherwise than large ones)
    for some in bad.tensor_split(-(-bad.numel() // PROJECT_CHUNK)):
        values, vectors = torch.linalg.eigh(_part(projected[some], rows))
        values = values.abs() if mode == "abs" else values.clamp_min(0.0)
        part = (vectors * values[:, None, :]) @ vectors.transpose(1, 2)
        if isinstance(rows, slice):
            projected[:, rows, rows].index_copy_(0, some, part)
        else:
            changed = projected[some]
            changed[:, rows[:, None], rows[None, :]] = part
            projected[some] = changed
    return projected, int(bad.numel())
