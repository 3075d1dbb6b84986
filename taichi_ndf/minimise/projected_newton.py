"""Projected-Newton minimisation of Π over the coefficients of a local-support field.

Per iteration at coefficients C (n, 3), on fixed quadrature points:
1. Π and g = dΠ/dC (Taichi-autodiff gradient with respect to the jets, pulled back through the
   composition: `Assembly.gradient`);
2. per-point Hessian blocks, the potential's own (`Objective.hessian_blocks`: the shell's
   through its strains, `taichi_ndf.shell.strain_hessian`) or central differences of its
   gradient, projected to positive semi-definite where needed (`taichi_ndf.shell.hessian`);
3. K = Σ Jᵀ H J, sparse (`Assembly.hessian`) — of the exact blocks when that K is positive
   definite (checked by the pivots of its factorisation: a stable state may have indefinite
   blocks, and the exact Newton step then converges quadratically), else of the blocks
   projected to positive semi-definite (`project_psd`: screened and projected only then;
   the first iteration and the iteration after a failed attempt skip it and screen: far from
   the minimum attempts fail in a row and each costs an assembly and a factorisation);
4. d from (K + μ diag K) d = −g (`damped_solve`, or the given `linear_solver`; μ = 0 unless
   the system is singular or a step failed);
5. backtracking Armijo line search on Π: α = 1, ½, ¼, … until Π(C + α d) ≤ Π(C) + c α gᵀd
   (and, with a `feasible` test, the trial is feasible: contact never steps into an obstacle);
   a full step that lowered Π clearly more than the quadratic model predicts is doubled while
   Π keeps falling (`_longer_step`: the model overestimates the curvature along d).
Stops, without taking that step, when the Newton decrement λ² = −gᵀd satisfies
λ²/2 ≤ decrement_tolerance × |Π| (λ²/2 estimates Π − Π* near the minimum), or when
‖g‖ ≤ gradient_tolerance × ‖g₀‖ (g₀: the gradient at the start of the load step). Each
iteration logs Π, λ², α, μ and the time split (energy, Hessian, assembly, solve), and returns
them as `NewtonIteration` records.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial

import numpy as np
import torch

from taichi_ndf import progress
from taichi_ndf.minimise.assembly import Assembly
from taichi_ndf.minimise.linear_solve import LinearSolver, damped_solve
from taichi_ndf.shell.hessian import (
    PROJECTIONS,
    Potential,
    flat_blocks,
    jet_steps,
    project_psd,
    sample_hessians,
)

log = logging.getLogger(__name__)


def hessian_blocks(potential: Potential, samples, u_jets: torch.Tensor, steps: torch.Tensor
                   ) -> torch.Tensor:
    """Per-point Hessian blocks (N, 6, 3, 6, 3): the potential's own `hessian_blocks` (an
    `Objective.potential`: term by term) where it has one, else central differences of its
    gradient."""
    own = getattr(potential, "hessian_blocks", None)
    if own is not None:
        return own(samples, u_jets, steps=steps)
    return sample_hessians(potential, samples, u_jets, steps=steps)

# Least Levenberg–Marquardt damping after a failed line search.
RETRY_DAMPING = 1e-8


@dataclass(frozen=True)
class ProjectedNewtonConfig:
    """Settings of projected Newton.

    max_iterations: most Newton iterations per load step.
    decrement_tolerance: stop when λ²/2 ≤ this × |Π| (λ² = −gᵀd, the Newton decrement).
    gradient_tolerance: stop when ‖g‖ ≤ this × ‖g₀‖.
    fd_step: central-difference step of the Hessian blocks relative to each jet channel's scale
        (`jet_steps`); 1e-5 suits float64 (1e-4 left a 1e-4 relative error in the bending part
        of a thin cylinder's Hessian, h/R = 0.01: the membrane terms' truncation error), about
        3e-3 float32.
    floor_tolerance: also stop, after taking the step, when the line search had to shorten a
        step whose decrement is already below this × |Π|: the rounding floor of Π and of the
        solve is reached.
    armijo: sufficient-decrease constant c of the line search.
    halvings: most step halvings before the damping is raised.
    project: make the Newton matrix positive definite where it is not (off: plain Newton with
        damping, for convex problems).
    longer_steps: most doublings of an accepted full step (`_longer_step`) when it lowered Π
        by clearly more than the quadratic model predicts; 0: never longer than the Newton
        step.
    hessian: how an indefinite block is projected (`project_psd`) when the exact K is not
        definite: "clamp" (default) sets its negative eigenvalues to 0, "abs" mirrors them.
        Measured (benchmarks/RESULTS.md): clamp took fewer or as many Newton steps as abs and
        as the exact K shifted by μ diag K until definite (Levenberg–Marquardt), on the
        napkin and the flag.
    """

    max_iterations: int = 100
    decrement_tolerance: float = 1e-12
    gradient_tolerance: float = 1e-10
    fd_step: float = 1e-5
    floor_tolerance: float = 1e-8
    armijo: float = 1e-4
    halvings: int = 30
    project: bool = True
    hessian: str = "clamp"
    longer_steps: int = 4

    def __post_init__(self):
        if self.hessian not in PROJECTIONS:
            raise ValueError(f"hessian must be one of {PROJECTIONS}, got {self.hessian!r}")
        if self.max_iterations < 1:
            raise ValueError(f"max_iterations must be >= 1, got {self.max_iterations}")
        for name in ("decrement_tolerance", "gradient_tolerance", "floor_tolerance"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be finite and >= 0, got {value!r}")
        if not 0 < self.fd_step < 1:
            raise ValueError(f"fd_step must be in (0, 1), got {self.fd_step}")
        if not 0 < self.armijo < 0.5:
            raise ValueError(f"armijo must be in (0, 0.5), got {self.armijo}")
        if self.longer_steps < 0:
            raise ValueError(f"longer_steps must be >= 0, got {self.longer_steps}")
        if self.halvings < 1:
            raise ValueError(f"halvings must be >= 1, got {self.halvings}")


@dataclass
class NewtonIteration:
    """One projected-Newton iteration: Π [J] before the step, the decrement λ² = −gᵀd [J],
    the accepted step length α (0: none; above 1: a lengthened full step), the damping μ, the
    number of indefinite blocks projected (0 also when the exact K was definite and used), ‖g‖,
    and seconds spent on energy + gradient, Hessian blocks, assembly and the linear solve."""

    load_factor: float
    iteration: int
    energy: float
    decrement: float
    step_length: float
    damping: float
    projected_blocks: int
    gradient_norm: float
    time_energy: float
    time_hessian: float
    time_assembly: float
    time_solve: float


@dataclass
class NewtonSolution:
    coefficients: torch.Tensor  # (n, 3)
    energy: float  # Π [J] at the solution
    converged: bool
    history: list[NewtonIteration] = field(default_factory=list)


# A full step that lowered Π by more than this × the quadratic model's ½λ² is tried longer.
LONGER_STEP_RATIO = 1.25


def _longer_step(energy_at: Callable[[float], float], start: float, full: float,
                 decrement: float, doublings: int) -> float:
    """The step length from α = 1 (accepted, Π = `full`; Π = `start` at α = 0): doubled while Π
    keeps falling, at most `doublings` times, when the full step lowered Π by more than
    LONGER_STEP_RATIO × ½λ² — the model overestimates the curvature along d (a projected K, or
    far from the minimum: a draped cloth's soft folds), so d is too short."""
    alpha, best = 1.0, full
    if not start - full > LONGER_STEP_RATIO * 0.5 * decrement:
        return alpha
    for _ in range(doublings):
        trial = energy_at(2 * alpha)
        if not (math.isfinite(trial) and trial < best):
            break
        alpha, best = 2 * alpha, trial
    return alpha


def minimise(assembly: Assembly, potential: Potential, coefficients: torch.Tensor,
             config: ProjectedNewtonConfig | None = None, *, load_factor: float = 1.0,
             length: float = 1.0, fixed: np.ndarray | None = None,
             feasible: Callable[[torch.Tensor, torch.Tensor], bool] | None = None,
             on_step: Callable[[torch.Tensor], bool] | None = None,
             linear_solver: LinearSolver | None = None) -> NewtonSolution:
    """Minimise Π(C) = potential(U(C)) by projected Newton from `coefficients` (n, 3).

    assembly: linearised at this load factor (`Assembly.at_load`); potential: Π at the
    assembly's samples for this load factor. length: a length of the parameter domain for the
    FD steps (`jet_steps`). fixed: unknowns (coefficient × 3 + component) held.
    feasible(C, C_trial): False rejects a line-search trial (halved like an Armijo failure;
    contact: a step that could enter an obstacle). on_step(C): called with each accepted
    iterate; True stops the minimisation there, not converged (contact: the caller adds
    quadrature points and solves again). linear_solver: solves the Newton systems with
    `damped_solve`'s contract (`LinearSolver.for_grid`: multigrid on large grids); None: the
    direct `damped_solve`.
    """
    config = config or ProjectedNewtonConfig()
    solve = linear_solver or damped_solve
    samples = assembly.samples
    c = coefficients.detach().clone()
    history: list[NewtonIteration] = []
    # The first iteration screens the blocks instead of trying the exact K (a start from a
    # coarser grid or the flat sheet is rarely a definite state; a definite one costs a screen)
    damping, converged, first_norm, exact_failed = 0.0, False, None, True

    def _trial_energy(step, a):  # Π at C + a d; inf where `feasible` rejects it
        if feasible is not None and not feasible(c, c + a * step):
            return math.inf
        return potential(samples, assembly.displacement(c + a * step), False).total

    for iteration in range(config.max_iterations):
        started = time.perf_counter()
        u = assembly.displacement(c)
        current = potential(samples, u, True)
        gradient = assembly.gradient(current.grad_u_jets)
        if fixed is not None:
            gradient.reshape(-1)[torch.from_numpy(fixed).to(gradient.device)] = 0.0
        norm = float(gradient.norm())
        first_norm = norm if first_norm is None else first_norm
        t_energy = time.perf_counter() - started
        if norm <= config.gradient_tolerance * first_norm or norm == 0.0:
            converged = True
            break
        started = time.perf_counter()
        steps = jet_steps(samples.r_jets, u, length, config.fd_step)
        blocks = flat_blocks(hessian_blocks(potential, samples, u, steps))
        t_hessian = time.perf_counter() - started
        rhs = -gradient.reshape(-1).double().cpu().numpy()
        t_assembly = t_solve = 0.0
        first_step = matrix = None  # (step, damping) of a factorisation checked definite
        if config.project and damping == 0.0 and not exact_failed:
            # The exact K may be definite although some blocks are not (a stable state under
            # compression): then its Newton step converges quadratically.
            started = time.perf_counter()
            matrix = assembly.hessian(blocks)
            t_assembly += time.perf_counter() - started
            started = time.perf_counter()
            first_step = solve(matrix, rhs, 0.0, fixed, require_definite=True)
            exact_failed = first_step is None
            t_solve += time.perf_counter() - started
        else:  # after a failed attempt the next iteration goes straight to the projected K
            exact_failed = False
        projected = 0
        if first_step is None:
            if config.project:
                started = time.perf_counter()
                blocks, projected = project_psd(blocks, mode=config.hessian)
                t_hessian += time.perf_counter() - started
            if matrix is None or projected:
                started = time.perf_counter()
                matrix = assembly.hessian(blocks)
                t_assembly += time.perf_counter() - started
        alpha, small = 0.0, False
        for _attempt in range(6):
            started = time.perf_counter()
            if first_step is not None:
                (step_np, damping), first_step = first_step, None
            else:
                step_np, damping = solve(matrix, rhs, damping, fixed)
            t_solve += time.perf_counter() - started
            step = torch.from_numpy(step_np).to(c).reshape(c.shape)
            decrement = float(-(gradient * step).sum())
            small = 0.5 * abs(decrement) <= config.decrement_tolerance * abs(current.total)
            if small:
                break  # converged: the step would change Π by less than the tolerance
            if decrement < 0:  # K (nearly) singular along d, e.g. a flat sheet's rigid
                damping = max(10 * damping, RETRY_DAMPING)  # rotations: damp and solve again
                continue
            started = time.perf_counter()
            alpha = 1.0
            for _ in range(config.halvings):
                trial = _trial_energy(step, alpha)
                if math.isfinite(trial) and (
                        trial <= current.total - config.armijo * alpha * decrement):
                    break
                alpha *= 0.5
            else:
                alpha = 0.0
            if alpha == 1.0 and config.longer_steps:
                alpha = _longer_step(partial(_trial_energy, step), current.total, trial,
                                     decrement, config.longer_steps)
            t_energy += time.perf_counter() - started
            if alpha > 0:
                break
            damping = max(10 * damping, RETRY_DAMPING)
        record = NewtonIteration(load_factor, iteration, current.total, decrement, alpha,
                                 damping, projected, norm, t_energy, t_hessian, t_assembly,
                                 t_solve)
        history.append(record)
        log.info("Newton %2d at λ=%.3g: Π %.12g J, λ² %.3e, α %.3g, μ %.1e, %d projected, "
                 "time energy %.3f hessian %.3f assembly %.3f solve %.3f s", iteration,
                 load_factor, current.total, decrement, alpha, damping, projected, t_energy,
                 t_hessian, t_assembly, t_solve)
        progress.report(iteration + 1, **{"Π": current.total, "λ²": decrement})
        near = 0.5 * abs(decrement) <= config.floor_tolerance * abs(current.total)
        if alpha == 0.0:  # stopped on the decrement tolerance, or no step decreased Π
            converged = small or near
            break
        c = c + alpha * step
        if on_step is not None and on_step(c):
            break
        if alpha < 1.0 and near:  # the quadratic model no longer predicts Π: rounding floor
            converged = True
            break
        damping = damping / 10 if alpha >= 1.0 else damping
        if damping < RETRY_DAMPING:
            damping = 0.0
    energy = potential(samples, assembly.displacement(c), False).total
    return NewtonSolution(coefficients=c, energy=energy, converged=converged, history=history)
