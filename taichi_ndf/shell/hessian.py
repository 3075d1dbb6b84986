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
buckling or folding state) is replaced by V max(Λ, 0) Vᵀ, so Σ Jᵀ H J is positive
semi-definite and the Newton direction descends. Only the blocks that need it are
eigen-decomposed: a batched Cholesky of H + τ I (τ a tiny fraction of the block's mean
diagonal) finds them first; at an unstressed or tensile state that is none.
"""

from __future__ import annotations

from collections.abc import Callable

import torch

from taichi_ndf import jets
from taichi_ndf.sampling import SurfaceSamples
from taichi_ndf.shell.energy import EnergyResult

COMPONENTS = 3
JET_SIZE = jets.CHANNELS * COMPONENTS  # 18 jet values per point
# Relative shift of the Cholesky test: a block whose least eigenvalue is above −PSD_SLACK × its
# mean diagonal counts as semi-definite (rounding and FD noise are ~1e-8 of it in float64; in
# float32 the shift is 1000 ε, or rank-deficient blocks would all fail the test).
PSD_SLACK = 1e-7

# Potential at given displacement jets: (samples, u_jets (N, 6, 3), grad) -> EnergyResult.
Potential = Callable[[SurfaceSamples, torch.Tensor, bool], EnergyResult]


def sample_hessians(potential: Potential, samples: SurfaceSamples, u_jets: torch.Tensor, *,
                    steps: torch.Tensor) -> torch.Tensor:
    """Per-point Hessian blocks d²Π/du_jets², shape (N, 6, 3, 6, 3), symmetrised.

    steps: central-difference step of each jet channel, shape (6,) [m per unit ξ^order].
    Perturbing one (channel, component) of every point at once is exact for a sum of per-point
    terms.
    """
    n = u_jets.shape[0]
    hessian = u_jets.new_zeros(n, jets.CHANNELS, COMPONENTS, jets.CHANNELS, COMPONENTS)
    for c in range(jets.CHANNELS):
        step = float(steps[c])
        for k in range(COMPONENTS):
            grads = []
            for sign in (1.0, -1.0):
                shifted = u_jets.clone()
                shifted[:, c, k] += sign * step
                grads.append(potential(samples, shifted, True).grad_u_jets)
            hessian[:, :, :, c, k] = (grads[0] - grads[1]) / (2 * step)
    return 0.5 * (hessian + hessian.permute(0, 3, 4, 1, 2))


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


def indefinite_blocks(blocks: torch.Tensor) -> torch.Tensor:
    """Indices of the blocks (N, m, m) that are not positive semi-definite, by a batched
    Cholesky of H + τ I (module docstring)."""
    scale = blocks.diagonal(dim1=1, dim2=2).abs().mean(dim=1).clamp_min(
        torch.finfo(blocks.dtype).tiny)
    slack = max(PSD_SLACK, 1000 * torch.finfo(blocks.dtype).eps)  # float32: 1.2e-4
    shift = slack * scale[:, None, None] * torch.eye(
        blocks.shape[1], dtype=blocks.dtype, device=blocks.device)
    _, info = torch.linalg.cholesky_ex(blocks + shift)
    return torch.nonzero(info != 0).flatten()


def project_psd(blocks: torch.Tensor, bad: torch.Tensor | None = None
                ) -> tuple[torch.Tensor, int]:
    """Blocks (N, m, m) projected to positive semi-definite (negative eigenvalues clamped to
    0), and how many were indefinite. Only those (`indefinite_blocks`, or `bad` if given) are
    eigen-decomposed (module docstring)."""
    if bad is None:
        bad = indefinite_blocks(blocks)
    if bad.numel() == 0:
        return blocks, 0
    values, vectors = torch.linalg.eigh(blocks[bad])
    projected = blocks.clone()
    projected[bad] = (vectors * values.clamp_min(0.0)[:, None, :]) @ vectors.transpose(1, 2)
    return projected, int(bad.numel())
