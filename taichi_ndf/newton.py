"""Last-layer Newton (Galerkin) solve: minimise Π exactly over the field's output layer.

The raw field output is linear in the output layer θ_k = (W_out[k], b_out[k]) of each component
k, and the boundary conditions compose affinely (u_k = φ_k·raw_k + g_k, Leibniz rule on jets;
minus raw_k(ξ₀) with a free pin: `BoundaryConditions.compose_jacobian`), so the displacement
jets are affine in θ: u = u(θ₀) + J (θ − θ₀) with J in closed form. Π is a
sum of per-sample terms, so its Hessian with respect to the jets is block diagonal, one 18 × 18
block (6 channels × 3 components) per sample; those blocks come from central differences of
the exact gradient dΠ/du_jets, perturbing one (channel, component) of all samples at once.
Then g_θ = Σ Jᵀ ∇_u Π and H_θ = Σ Jᵀ h J exactly, and a damped Newton step with a backtracking
line search on Π minimises over θ with the hidden layers (the features) held fixed. In the
linear regime one step reaches the Galerkin optimum over the span of the features; nonlinear
problems take a few.

A conditioned field u(ξ, c) (material parameters, load components as extra inputs) is solved
the same way: pass the per-sample conditioning c (N, k) of the fixed samples; the features
depend on it and the output layer is still linear, and the potential must evaluate each sample
with its own stiffness / load (the caller's closure: e.g. `ShellEnergy.evaluate(...,
stiffness=...)` and the samples' own point forces).

Why: Π is extremely ill-conditioned for thin shells (membrane stiffness ~10⁵ × bending/L²), so
first-order optimisers crawl; a second-order solve over the output layer does not care.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import torch

from taichi_ndf.field import NeuralField
from taichi_ndf.operator import DisplacementOperator
from taichi_ndf.sampling import SurfaceSamples
from taichi_ndf.shell.hessian import COMPONENTS, Potential, sample_hessians

log = logging.getLogger(__name__)

# Least Levenberg–Marquardt damping, relative to the mean diagonal of the Jacobi-scaled Hessian:
# nearly collinear features and zero-energy motions (rigid modes) would otherwise take steps
# made of rounding noise.
EIGEN_CUTOFF = 1e-14
LINE_SEARCH_HALVINGS = 12


@dataclass(frozen=True)
class NewtonConfig:
    """Settings of one last-layer Newton phase.

    iterations: most Newton steps.
    relative_decrease: stop when a step lowers Π by less than this × |Π|.
    fd_step: central-difference step of the Hessian blocks, relative to the RMS of each jet
        channel.
    """

    iterations: int = 8
    relative_decrease: float = 1e-10
    fd_step: float = 1e-4

    def __post_init__(self):
        if self.iterations < 1:
            raise ValueError(f"iterations must be >= 1, got {self.iterations}")
        if not 0 <= self.relative_decrease < 1:
            raise ValueError(f"relative_decrease must be in [0, 1), got {self.relative_decrease}")
        if not 0 < self.fd_step < 1:
            raise ValueError(f"fd_step must be in (0, 1), got {self.fd_step}")


@dataclass
class NewtonResult:
    energy_before: float  # Π [J] on the phase's samples
    energy_after: float
    steps: int  # accepted Newton steps


def output_jacobian(operator: DisplacementOperator, xi: torch.Tensor, load_factor: float,
                    conditioning: torch.Tensor | None = None
                    ) -> tuple[torch.Tensor, torch.Tensor]:
    """Displacement jets u (N, 6, 3) [m] of the operator's current field and their Jacobian
    with respect to the output layer, shape (3, N, 6, width + 1)
    (`DisplacementOperator.output_layer_jacobian`).
    conditioning: the field's extra inputs per sample (N, k), for a conditioned field."""
    return operator.output_layer_jacobian(xi, t=load_factor, conditioning=conditioning)


def output_parameters(field: NeuralField) -> torch.Tensor:
    """θ = (W_out | b_out), shape (3, width + 1): a copy of the field's output layer."""
    weight, bias = field.output_layer()
    return torch.cat((weight, bias[:, None]), dim=1)


def parameter_gradient(jacobian: torch.Tensor, grad_u_jets: torch.Tensor) -> torch.Tensor:
    """dΠ/dθ, shape (3, width + 1), from dΠ/du_jets (N, 6, 3)."""
    return torch.einsum("knca,nck->ka", jacobian, grad_u_jets)


def parameter_hessian(jacobian: torch.Tensor, hessians: torch.Tensor) -> torch.Tensor:
    """d²Π/dθ², shape (3 (width + 1), 3 (width + 1)), from the per-sample blocks: exact, since
    u is affine in θ."""
    _, n, channels, p = jacobian.shape
    blocks = {}
    for k in range(COMPONENTS):
        flat_k = jacobian[k].reshape(n * channels, p)
        for m in range(k, COMPONENTS):  # the blocks below the diagonal are transposes
            block = hessians[:, :, k, :, m]  # (N, 6, 6)
            # Σ_d h[n, c, d] J[n, d, a] as six broadcast products: batched 6 × 6 GEMMs are
            # ~50 × slower on the CPU.
            weighted = sum(block[:, :, d, None] * jacobian[m][:, d, None, :]
                           for d in range(channels))
            blocks[k, m] = flat_k.t() @ weighted.reshape(n * channels, p)
            blocks[m, k] = blocks[k, m].t()
    return torch.cat([torch.cat([blocks[k, m] for m in range(COMPONENTS)], dim=1)
                      for k in range(COMPONENTS)], dim=0)


def damped_step(hessian: torch.Tensor, gradient: torch.Tensor, damping: float) -> torch.Tensor:
    """Levenberg–Marquardt step −(H + μ)⁻¹ g on the Jacobi-scaled Hessian, μ = damping × its
    mean diagonal (at least EIGEN_CUTOFF ×), raised until the Cholesky factorisation succeeds
    (negative curvature)."""
    diag = hessian.diagonal().abs()
    scale = 1.0 / torch.sqrt(torch.clamp(diag, min=float(diag.max()) * 1e-30 + 1e-300))
    scaled = scale[:, None] * hessian * scale[None, :]
    scaled = 0.5 * (scaled + scaled.t())
    mu = max(damping, EIGEN_CUTOFF) * float(scaled.diagonal().mean())
    eye = torch.eye(scaled.shape[0], dtype=scaled.dtype, device=scaled.device)
    while True:
        factor, info = torch.linalg.cholesky_ex(scaled + mu * eye)
        if int(info) == 0:
            break
        mu *= 10
    solution = torch.cholesky_solve((scale * gradient)[:, None], factor)[:, 0]
    return -scale * solution


def _channel_steps(u_jets: torch.Tensor, jacobian: torch.Tensor, theta: torch.Tensor,
                   relative: float) -> torch.Tensor:
    """FD step per jet channel: `relative` × the channel's RMS, or the RMS a typical change of
    θ would make where the displacement vanishes."""
    rms_u = u_jets.pow(2).mean(dim=(0, 2)).sqrt()
    rms_theta = theta.pow(2).mean().sqrt()
    rms_j = jacobian.pow(2).mean(dim=(0, 1, 3)).sqrt()
    scale = torch.maximum(rms_u, rms_j * rms_theta)
    return relative * torch.where(scale > 0, scale, torch.ones_like(scale))


def _hessian_at(potential: Potential, samples: SurfaceSamples, u_jets: torch.Tensor,
                jacobian: torch.Tensor, theta: torch.Tensor, fd_step: float) -> torch.Tensor:
    """d²Π/dθ² at displacement jets u_jets (output layer θ): per-sample blocks by central
    differences with steps `fd_step` × each channel's scale, assembled through J."""
    hessians = sample_hessians(potential, samples, u_jets,
                               steps=_channel_steps(u_jets, jacobian, theta, fd_step))
    return parameter_hessian(jacobian, hessians)


def output_hessian(operator: DisplacementOperator, potential: Potential,
                   samples: SurfaceSamples, load_factor: float,
                   config: NewtonConfig | None = None, *,
                   conditioning: torch.Tensor | None = None
                   ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Displacement jets u (N, 6, 3) [m] of the current field at the samples, their Jacobian
    J (3, N, 6, width + 1) with respect to the output layer (`output_jacobian`) and the
    output-layer Hessian H = d²Π/dθ² (3 (width + 1), 3 (width + 1)) (`parameter_hessian`,
    blocks by central differences with `config.fd_step`). At a converged solve (∇_θ Π = 0)
    this is what the implicit-function theorem needs: dθ*/dp = −H⁻¹ ∂(∇_θ Π)/∂p for any
    parameter p of the potential, with ∂(∇_θ Π)/∂p = Jᵀ ∂(dΠ/du)/∂p."""
    config = config or NewtonConfig()
    u, jacobian = output_jacobian(operator, samples.xi, load_factor, conditioning)
    theta = output_parameters(operator.field)
    return u, jacobian, _hessian_at(potential, samples, u, jacobian, theta, config.fd_step)


def solve_last_layer(operator: DisplacementOperator, potential: Potential,
                     samples: SurfaceSamples, load_factor: float,
                     config: NewtonConfig | None = None, *,
                     conditioning: torch.Tensor | None = None) -> NewtonResult:
    """Minimise Π (potential: the objective at a load factor, `Objective.potential`) over the
    output layer of the operator's field on fixed samples (damped Newton with a backtracking
    line search); updates W_out and b_out in place.

    conditioning: per-sample extra inputs (N, k) of a conditioned field (module docstring)."""
    config = config or NewtonConfig()
    field = operator.field
    weight, bias = field.output_layer()
    u, jacobian = output_jacobian(operator, samples.xi, load_factor, conditioning)
    theta = output_parameters(field)
    shape = theta.shape
    delta = torch.zeros_like(theta)  # θ − θ₀, with u(θ) = u + J·(θ − θ₀)

    def displacement(change: torch.Tensor) -> torch.Tensor:
        return u + torch.einsum("knca,ka->nck", jacobian, change)

    current = potential(samples, u, True)
    before = energy = current.total
    damping, steps = 0.0, 0
    for _ in range(config.iterations):
        gradient = parameter_gradient(jacobian, current.grad_u_jets).reshape(-1)
        u_now = displacement(delta)
        hessian = _hessian_at(potential, samples, u_now, jacobian, theta + delta,
                              config.fd_step)
        accepted = False
        for _attempt in range(4):
            step = damped_step(hessian, gradient, damping).reshape(shape)
            slope = float((gradient * step.reshape(-1)).sum())
            alpha = 1.0
            for _ in range(LINE_SEARCH_HALVINGS):
                trial = potential(samples, displacement(delta + alpha * step), False).total
                # Armijo condition on Π; rounding of Π bounds how small a decrease can show.
                if math.isfinite(trial) and trial <= energy + 1e-4 * alpha * slope:
                    accepted = True
                    break
                alpha *= 0.5
            if accepted:
                break
            damping = max(10 * damping, 1e-6)
        if not accepted:
            break
        delta = delta + alpha * step
        steps += 1
        log.debug("Newton step %d: Π %.10g -> %.10g J, step length %g, damping %g", steps,
                  energy, trial, alpha, damping)
        decrease = energy - trial
        energy = trial
        damping = damping / 10 if alpha == 1.0 else damping
        current = potential(samples, displacement(delta), True)
        if decrease <= config.relative_decrease * abs(energy):
            break
    with torch.no_grad():
        weight.add_(delta[:, :-1])
        bias.add_(delta[:, -1])
    log.info("last-layer Newton at load factor %.4g: Π %.10g -> %.10g J in %d steps",
             load_factor, before, energy, steps)
    return NewtonResult(energy_before=before, energy_after=energy, steps=steps)
