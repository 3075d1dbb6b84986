"""A stiffness parameter fitted to observed motion: Gauss–Newton through the time steps.

Data: the displacements d_fp [m] of P points ξ_p at F observed states k_f (time k_f × dt, the
states of `taichi_ndf.solve.dynamics_adjoint.record` from rest), noise σ [m] per coordinate
known or not. Model: r_fp(θ) = u(ξ_p, C_{k_f}(θ)) − d_fp, C_k the coefficients of the run of
the scene's `TimeStepper` at the stiffness parameter θ (e.g. `bending_stiffness` B [N·m]).
J(θ) = ½ Σ r²; per iteration one run (`record`), the gradient ∇J = Σ r dr/dθ by the adjoint
(`gradient`, weights ∂J/∂C_k), the Gauss–Newton Hessian H = Σ (dr/dθ)² from the tangent
(`tangent`: dC_k/dθ, mapped to the points by the free part J alone: u = g(t) + J C, the
boundary's part g(t) at the state's time — a scene's motion μ(t) or handles on paths,
`solve.handle_paths` — does not depend on θ), and θ ← θ − ∇J/H (a step to θ ≤ 0 is cut
to θ/2) until |Δθ| < `tolerance` |θ| or, with `error_tolerance`, |Δθ| < error_tolerance × the
s.e. σ/√H of that run (a step far below the estimate's own uncertainty changes nothing the
fit can tell).
At the last run: s.e.(θ) = σ/√H, the residuals, and the χ² test of
`goodness.goodness_of_fit` (1 unknown). With σ unknown it is
estimated from the residuals, σ̂² = Σ r²/(R − 1) for R residual entries: then χ²/dof = 1 by
construction and the test says nothing (the noise source says so). The relative gap between
the adjoint's ∇J and the tangent's Σ r dr/dθ at the start is returned as a check (4e-15 on
benchmarks/dynamics_fit.py's strip).

The held points' paths as unknowns too (`path_start`: q₀ (p,) of a `HandlePath.basis`, the
stepper then `stepper_at(θ, q)`): the unknowns are (θ, q), the tangent gives every column
(`dynamics_adjoint.tangent`), the observed points move by J dC/dq + U dd(t)/dq besides (the
handles' part, `PathStepper.units`), and the step solves the normal equations N δ = −Aᵀ r of
the Jacobian A (R, 1 + p) (the same step for p = 0). The s.e. of θ is then the marginal one,
σ √(N⁻¹)_θθ: it carries the paths' uncertainty; `correlation` is θ's multiple correlation with
q (√(1 − 1/(N_θθ (N⁻¹)_θθ)): 1 where q can mimic θ). The stop: |Δθ| < tolerance |θ| and
the whole step inside the estimate's one-s.e. ellipsoid (√(δᵀ N δ)/σ < 1), or that size below
error_tolerance (for p = 0: |Δθ|/s.e.).

Not covered (ValueError from the adjoint, before any step): contact, wind,
stiffness-proportional damping, a per-sample stiffness; states halved by a step that did not
converge (DynamicsError from `record`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch

from inverse.material.goodness import GoodnessOfFit, goodness_of_fit
from taichi_ndf import jets, progress
from taichi_ndf.minimise.assembly import displacement_at
from taichi_ndf.problem.operator import DisplacementOperator
from taichi_ndf.solve.dynamics import TimeStepper
from taichi_ndf.solve.dynamics_adjoint import Start, gradient, record, tangent
from taichi_ndf.solve.handle_paths import boundary_displacement

ESTIMATED = "estimated from the residuals (χ²/dof = 1 by construction: not a test)"


@dataclass(frozen=True)
class TrajectoryData:
    """Observed motion. xi: (P, 2) surface coordinates of the points; steps: the observed
    states' step indices k ≥ 1 (time k × dt [s]), increasing; displacements: (F, P, 3) [m],
    F = len(steps); noise: σ [m] per coordinate, None to estimate it from the residuals."""

    xi: torch.Tensor
    steps: tuple[int, ...]
    displacements: torch.Tensor
    noise: float | None = None

    def __post_init__(self):
        steps = tuple(int(k) for k in self.steps)
        object.__setattr__(self, "steps", steps)
        if self.xi.ndim != 2 or self.xi.shape[1] != 2 or len(self.xi) == 0:
            raise ValueError(f"trajectory data: xi must be (P, 2), P >= 1, got "
                             f"{tuple(self.xi.shape)}")
        if not steps or min(steps) < 1 \
                or any(b <= a for a, b in zip(steps, steps[1:], strict=False)):
            raise ValueError(f"trajectory data: steps must be increasing integers >= 1, got "
                             f"{list(steps)}")
        if tuple(self.displacements.shape) != (len(steps), len(self.xi), 3):
            raise ValueError(f"trajectory data: displacements must be (F, P, 3) = "
                             f"({len(steps)}, {len(self.xi)}, 3), got "
                             f"{tuple(self.displacements.shape)}")
        if not bool(torch.isfinite(self.displacements).all()):
            raise ValueError("trajectory data: displacements must be finite")
        if self.noise is not None and not (math.isfinite(self.noise) and self.noise > 0):
            raise ValueError(f"trajectory data: noise must be finite and > 0 [m], got "
                             f"{self.noise!r}")


@dataclass(frozen=True)
class TrajectoryFitConfig:
    """parameter: a stiffness name of the material; max_iterations ≥ 1 Gauss–Newton
    iterations; tolerance > 0: stop when |Δθ| < tolerance |θ|; error_tolerance > 0 or None:
    also stop when |Δθ| < error_tolerance × s.e. (σ/√H at that run)."""

    parameter: str = "bending_stiffness"
    max_iterations: int = 15
    tolerance: float = 1e-8
    error_tolerance: float | None = None

    def __post_init__(self):
        if self.max_iterations < 1:
            raise ValueError(f"max_iterations must be >= 1, got {self.max_iterations}")
        if not self.tolerance > 0:
            raise ValueError(f"tolerance must be > 0, got {self.tolerance}")
        if self.error_tolerance is not None and not self.error_tolerance > 0:
            raise ValueError(f"error_tolerance must be > 0 or None, got {self.error_tolerance}")


@dataclass(frozen=True)
class TrajectoryFit:
    """value: θ̂; standard_error: σ/√H [θ's unit]; iterations; converged (the step fell below
    the tolerance); residuals (F·P·3,) [m] and sensitivity dr/dθ (same shape) at the last run;
    noise σ [m] and its source; goodness: the χ² test; gradient_gap: relative gap of the
    adjoint's and the tangent's ∇J at the start; time_s: wall seconds; with path unknowns:
    path_values q̂ (p,), path_errors their marginal s.e. (p,) and correlation (module
    docstring; None without)."""

    value: float
    standard_error: float
    iterations: int
    converged: bool
    residuals: np.ndarray
    sensitivity: np.ndarray
    noise: float
    noise_source: str
    goodness: GoodnessOfFit
    gradient_gap: float
    time_s: float
    path_values: np.ndarray | None = None
    path_errors: np.ndarray | None = None
    correlation: float | None = None


def observe(stepper: TimeStepper, xi: torch.Tensor, coefficients: torch.Tensor,
            time: float | None = None) -> torch.Tensor:
    """Displacements (P, 3) [m] at ξ (P, 2) of the stepper's field with `coefficients` (n, 3)
    at time t [s]: J C + g(t); time None: the free part J C alone (linear in C: the map of
    the tangent dC/dθ)."""
    operator = DisplacementOperator(stepper.field, stepper.model.boundary)
    free = displacement_at(operator, xi.to(coefficients.dtype), coefficients, 0.0)[:, jets.VALUE]
    if time is None:
        return free
    return free + boundary_displacement(stepper, xi, time, coefficients.dtype)


def fit_trajectory(stepper_at: Callable[..., TimeStepper], data: TrajectoryData,
                   start: float, config: TrajectoryFitConfig = TrajectoryFitConfig(), *,
                   initial: tuple[torch.Tensor, torch.Tensor]
                   | Callable[[TimeStepper], Start] | None = None,
                   path_start: np.ndarray | None = None) -> TrajectoryFit:
    """θ̂ by Gauss–Newton from `start` (module docstring); stepper_at(θ): the scene's stepper
    with the material's `config.parameter` set to θ; initial: the runs' start (C₀, V₀)
    (coefficients (n, 3) [m], [m/s]; None: rest), given, not fitted; or a function of the
    stepper at θ giving the `Start` (e.g. `rest_start`: the static equilibrium at θ), whose
    derivative by θ enters the tangent and the adjoint; path_start: q₀ (p,) of the held
    points' path unknowns, fitted with θ (then stepper_at(θ, q), its path's basis the
    derivative by q). The adjoint's ∇J (θ's) is
    computed at the first iteration (its gap to the tangent's is the check); later
    iterations step with the tangent's Σ r dr/dθ, the same number (to 1e-10, tested), at
    one solve per step less. One progress report per iteration (stage "trajectory fit",
    values θ and |Δθ|/|θ|)."""
    began = time.perf_counter()
    theta, gap, converged = float(start), 0.0, False
    q = None if path_start is None else np.asarray(path_start, dtype=np.float64).copy()
    with progress.stage(f"trajectory fit ({config.parameter})", config.max_iterations):
        for iteration in range(1, config.max_iterations + 1):
            stepper = stepper_at(theta) if q is None else stepper_at(theta, q)
            begin = initial(stepper) if callable(initial) else Start(*(initial or (None,)))
            derivative = begin.derivative
            states = record(stepper, begin.displacement, begin.velocity)
            if data.steps[-1] >= len(states):
                raise ValueError(f"trajectory data: step {data.steps[-1]} is past the run's "
                                 f"last ({len(states) - 1})")
            forward = tangent(stepper, states, config.parameter, derivative)
            observed = _observation(stepper, data.xi)
            weights, residuals, columns = {}, [], []
            for i, k in enumerate(data.steps):
                c = states[k].displacement.clone().requires_grad_(True)
                r = observe(stepper, data.xi, c, states[k].time) \
                    - data.displacements[i].to(c.dtype)
                (weights[k],) = torch.autograd.grad((0.5 * r * r).sum(), c)
                residuals.append(r.detach().reshape(-1))
                columns.append(observed(forward[k], states[k].time))
            a = torch.cat(columns).numpy()
            normal, slope = a.T @ a, a.T @ torch.cat(residuals).numpy()
            if iteration == 1:  # away from the fit, where ∇J is not ~0
                own = None if derivative is None else tuple(
                    v if v.dim() == 2 else v[..., 0] for v in derivative)
                adjoint = gradient(stepper, states, config.parameter, weights, own)
                gap = abs(adjoint - slope[0]) / max(abs(slope[0]), 1e-300)
                slope[0] = adjoint
            if not normal[0, 0] > 0:
                raise ValueError(f"trajectory fit: the observed points do not move with "
                                 f"{config.parameter} (H = {normal[0, 0]:.3g})")
            step = -_solved(normal, slope)
            if theta + step[0] <= 0:  # a stiffness stays positive: halve it instead
                step *= -0.5 * theta / step[0]
            theta += float(step[0])
            if q is not None:
                q = q + step[1:]
            progress.report(iteration, **{config.parameter: theta,
                                          "relative_step": abs(step[0]) / abs(theta)})
            size = float(np.sqrt(max(step @ normal @ step, 0.0))) \
                / _noise(residuals, data.noise, len(step))
            if (abs(step[0]) < config.tolerance * abs(theta) and (q is None or size < 1.0)) \
                    or (config.error_tolerance is not None and size < config.error_tolerance):
                converged = True
                break
    r = torch.cat(residuals).numpy()
    unknowns = normal.shape[0]
    noise = _noise(residuals, data.noise, unknowns)
    source = ESTIMATED if data.noise is None else "stated"
    inverse = normal_inverse(normal)
    errors = noise * np.sqrt(np.maximum(np.diag(inverse), 0.0))
    path = {}
    if q is not None:
        path = {"path_values": q, "path_errors": errors[1:], "correlation": float(np.sqrt(
            max(0.0, 1.0 - 1.0 / (normal[0, 0] * inverse[0, 0]))))}
    return TrajectoryFit(theta, float(errors[0]), iteration, converged, r, a[:, 0].copy(),
                         noise, source, goodness_of_fit(r, unknowns, noise, source), gap,
                         time.perf_counter() - began, **path)


def _observation(stepper: TimeStepper, xi: torch.Tensor):
    """dr(dC, t) (P·3, m): the observed points' move for coefficient columns dC (n, 3[, m])
    at time t [s]: J dC (the free part, linear: one matrix for all), plus, with a path's
    unknowns (columns 1…), the handles' part U dd(t)/dq (`PathStepper.units`)."""
    zeros = torch.zeros_like(stepper.field.coefficients)
    matrix = torch.autograd.functional.jacobian(lambda c: observe(stepper, xi, c), zeros)
    matrix = matrix.reshape(3 * len(xi), zeros.numel())
    path = getattr(stepper, "path", None)
    units = None
    if path is not None and path.unknowns:
        units = stepper.units(xi.to(torch.float64), torch.float64)[:, jets.VALUE]

    def moved(columns: torch.Tensor, t: float) -> torch.Tensor:
        out = matrix @ columns.reshape(zeros.numel(), -1)
        if units is not None:
            handles = units @ torch.from_numpy(path.derivative_at(t))  # (P, 3, p)
            out[:, 1:] += handles.reshape(3 * len(xi), -1)
        return out.detach()

    return moved


def _scaled(normal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """N with a unit diagonal (θ [N·m] and q [m] differ by orders) and the scale."""
    scale = 1.0 / np.sqrt(np.maximum(np.diag(normal), 1e-300))
    return normal * scale[:, None] * scale[None, :], scale


def _solved(normal: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """N⁻¹ rhs (`_scaled`; least squares where N is singular)."""
    scaled, scale = _scaled(normal)
    return scale * np.linalg.lstsq(scaled, scale * rhs, rcond=1e-12)[0]


def normal_inverse(normal: np.ndarray) -> np.ndarray:
    """N⁻¹ (`_scaled`; a pseudo-inverse where N is singular)."""
    scaled, scale = _scaled(normal)
    return np.linalg.pinv(scaled, rcond=1e-12) * scale[:, None] * scale[None, :]


def _noise(residuals: list[torch.Tensor], stated: float | None, unknowns: int = 1) -> float:
    """σ [m]: stated, or σ̂ = √(Σ r² / (R − m)) over the R residual entries, m unknowns."""
    if stated is not None:
        return float(stated)
    r = torch.cat(residuals)
    return float(torch.sqrt((r @ r) / max(len(r) - unknowns, 1)))
