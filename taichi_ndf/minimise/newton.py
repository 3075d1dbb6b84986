"""Newton minimisation of Π over the parameters of a linearised displacement: the one Newton.

The displacement jets at fixed points are affine in the parameters P, U = U₀ + J P (a
`Linearisation`: dense for a SIREN's output layer, `last_layer`; sparse for a spline's
coefficients, `SplineLinearisation`). Π = Σ_q e_q(U_q) is a sum of per-point terms, so its
Hessian over the jets is one 18 × 18 block per point and, U being affine in P,
g = Jᵀ ∂Π/∂U and K = Jᵀ H J exactly. Per iteration from P:
1. Π and g (`Linearisation.gradient`: held unknowns zero);
2. per-point Hessian blocks (`PointBlocks`: built chunk by chunk of points as the assembly of
   K asks, never all at once): the potential's own (`Objective.hessian_blocks`:
   the shell's through its strains, `taichi_ndf.shell.strain_hessian`) or central differences
   of its gradient, with the linearisation's step per jet channel (`Linearisation.fd_steps`);
   — and, for terms that join points (a seam's stitches), blocks between pairs of points
   (`coupled_blocks`, `taichi_ndf.objective.couplings`);
3. K = Jᵀ H J (`Linearisation.hessian`) — with `project`: of the exact blocks when that K is
   positive definite (checked by its factorisation: a stable state may have indefinite
   blocks, and the exact Newton step then converges quadratically), else of the blocks
   projected to positive semi-definite (`project_psd`: screened and projected only then; the
   first iteration and the iteration after a failed attempt skip it and screen: far from the
   minimum attempts fail in a row and each costs an assembly and a factorisation); in the
   endgame (the last decrement below the floor) the exact K every iteration, shifted by the
   least μ D that makes it definite before any projection (`_shifted_step`: a soft mode);
4. d from (K + μ D) d = −g (`Linearisation.solve`: the dense Jacobi-scaled Cholesky or the
   sparse direct / multigrid solve, D the diagonal of K; μ = 0 unless the system is singular
   or a line search failed: then raised tenfold, from at least `retry_damping`);
5. backtracking Armijo line search on Π (`line_search.backtrack`): α = 1, ½, ¼, … until
   Π(P + α d) ≤ Π(P) + c α gᵀd (and, with a `feasible` test, the trial is feasible: contact
   never steps into an obstacle); with `second_order_correction`, a feasible full step that
   fails is first tried with its second-order correction d + s by the same K
   (`second_order_step`: a nearly inextensible sheet stretched at second order by the
   straight step); a full step that lowered Π clearly more than the quadratic model predicts
   is doubled while Π keeps falling (`longer_step`).
Stops, without taking that step, when the Newton decrement λ² = −gᵀd satisfies
λ²/2 ≤ decrement_tolerance × |Π| (λ²/2 estimates Π − Π* near the minimum), or, given the
coarser grid's Π (`coarse_energy`), λ²/2 ≤ discretisation_fraction × |Π − Π_coarse| (that
change estimates the discretisation error of Π; both are squared energy-norm errors: no
polishing to the rounding floor), when ‖g‖ ≤ gradient_tolerance × ‖g₀‖ (g₀: at the start),
or when the last step lowered Π by at most relative_decrease × |Π|. Each iteration is logged
(Π, λ², α, whether the step was corrected, μ, time: energy — the line search's, its correction
included —, Hessian, assembly, solve) and returned as a `NewtonIteration`.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial
from typing import Any, Protocol

import torch

from taichi_ndf import progress
from taichi_ndf.minimise.line_search import backtrack, second_order_step
from taichi_ndf.minimise.newton_state import NewtonIterate, NewtonIteration
from taichi_ndf.minimise.point_blocks import PointBlocks, coupled_blocks, state_tangent
from taichi_ndf.minimise.point_blocks import hessian_blocks as hessian_blocks
from taichi_ndf.minimise.point_blocks import point_blocks as point_blocks
from taichi_ndf.objective.couplings import Couplings
from taichi_ndf.problem.sampling import SurfaceSamples
from taichi_ndf.shell.hessian import (
    PROJECTIONS,
    Potential,
)

log = logging.getLogger(__name__)

# The endgame's shifts of the exact K: μ = retry_damping × 10^k, k < this (`_shifted_step`).
SHIFTS = 8


class Linearisation(Protocol):
    """Displacement jets U(P) = U₀ + J P (N, 6, 3) [m] at fixed points, affine in parameters P
    (a tensor of the linearisation's own shape), with the products Newton needs."""

    samples: SurfaceSamples  # the points, in the linearisation's order

    def displacement(self, parameters: torch.Tensor) -> torch.Tensor:
        """U (N, 6, 3) [m] at parameters P."""

    def gradient(self, grad_u_jets: torch.Tensor) -> torch.Tensor:
        """dΠ/dP = Jᵀ dΠ/dU (P's shape) from dΠ/dU (N, 6, 3); held unknowns 0."""

    def fd_steps(self, u_jets: torch.Tensor, parameters: torch.Tensor,
                 relative: float) -> torch.Tensor:
        """Central-difference step per jet channel (6,) of the Hessian blocks at U(P)."""

    def hessian(self, blocks: torch.Tensor | Callable[[slice], torch.Tensor],
                couplings: Couplings | None = None) -> Any:
        """K = Jᵀ H J (dense torch matrix or scipy sparse) from blocks H (N, 18, 18), or a
        function of a slice of points giving theirs (asked chunk by chunk, `PointBlocks`), and
        the pair blocks of terms that couple points (`Couplings`, None: none)."""

    def solve(self, matrix: Any, gradient: torch.Tensor, damping: float, *,
              require_definite: bool = False) -> tuple[torch.Tensor, float] | None:
        """d = −(K + μ D)⁻¹ g (P's shape; held unknowns 0) and the damping to go on with;
        with require_definite None unless K + μ D is positive definite."""


@dataclass(frozen=True)
class NewtonConfig:
    """Settings of Newton. The defaults are projected Newton's on a spline's coefficients;
    `last_layer.LAST_LAYER` holds a SIREN output layer's.

    max_iterations: most Newton iterations (per load step).
    decrement_tolerance: stop when λ²/2 ≤ this × |Π| (λ² = −gᵀd, the Newton decrement).
    gradient_tolerance: stop when ‖g‖ ≤ this × ‖g₀‖.
    relative_decrease: stop when the last step lowered Π by at most this × |Π| (0: never).
    fd_step: central-difference step of the Hessian blocks relative to each jet channel's scale
        (`Linearisation.fd_steps`); 1e-5 suits float64 on a spline (1e-4: a 1e-4 relative error
        in a thin cylinder's bending Hessian), about 3e-3 float32.
    floor_tolerance: also stop, after taking the step, when the line search had to shorten a
        step whose decrement is already below this × |Π|: the rounding floor of Π and of the
        solve is reached.
    armijo: sufficient-decrease constant c of the line search.
    halvings: most step halvings of one line search.
    line_searches: most line searches per iteration (the damping raised before each retry).
    retry_damping: least damping μ after a failed line search (decayed below it: 0).
    project: make the Newton matrix positive definite where it is not (off: plain Newton with
        damping, for convex problems).
    longer_steps: most doublings of an accepted full step (`line_search.longer_step`) when it
        lowered Π by clearly more than the quadratic model predicts; 0: never.
    second_order_correction: where the full step is feasible and fails the sufficient-decrease
        test, try it corrected for its second-order membrane stretch before backtracking
        (`line_search.second_order_step`; the potential's `second_order_gradient`, without
        one: nothing); False (default): plain backtracking. Off by default because it cuts
        Newton's iterations but not, with the clamped projection, the CPU of the README's
        demo: 321 → 207 iterations, 34 → 36 s CPU (its iterates sit on the inextensible
        manifold, where the exact K is indefinite in compressed folds: projected at 24 of 43
        iterations on 32² against 1 of 73); with hessian "strain" 210 iterations, 27 s; the
        nonlinear cantilevers' CPU −18 % (benchmarks/RESULTS.md, "Newton on cloth drapes: the
        second-order correction (issue 28)"). Re-validated with "strain" as a pair: the demo
        −17 % CPU, every validation value kept, but tablecloth_box +27 % (+25 % with the
        correction alone): its corrected path reaches a state from which projected Newton
        creeps with doubled steps for ~20 iterations ("Newton defaults re-validated, and the
        step against the factorisation (issue 28)").
    discretisation_fraction: given the coarser grid's Π (`minimise`'s coarse_energy), also stop
        when λ²/2 ≤ this × |Π − Π_coarse|; 0: the exact-tolerance mode (1e-4 kept the
        validation's probes to 5 digits, 1e-3 moved one by 3e-4: benchmarks/RESULTS.md).
    hessian: how an indefinite block is projected (`project_psd`) when the exact K is not
        definite: "clamp" (default) sets its negative eigenvalues to 0, "abs" mirrors them
        (clamp took as many or fewer steps than abs and Levenberg–Marquardt on the napkin and
        the flag, benchmarks/RESULTS.md); "strain": all blocks positive semi-definite through
        the strains (`psd_hessian_blocks`, `strain_hessian`: no screen, no eigh; a contact
        round's too, `ContactPotential`). Alone no faster than clamp on the demo and the
        contact scenes (the re-validation above).
    """

    max_iterations: int = 100
    decrement_tolerance: float = 1e-12
    gradient_tolerance: float = 1e-10
    relative_decrease: float = 0.0
    discretisation_fraction: float = 1e-4
    fd_step: float = 1e-5
    floor_tolerance: float = 1e-8
    armijo: float = 1e-4
    halvings: int = 30
    line_searches: int = 6
    retry_damping: float = 1e-8
    project: bool = True
    hessian: str = "clamp"
    longer_steps: int = 4
    second_order_correction: bool = False

    def __post_init__(self):
        if self.hessian not in PROJECTIONS:
            raise ValueError(f"hessian must be one of {PROJECTIONS}, got {self.hessian!r}")
        for name in ("max_iterations", "halvings", "line_searches"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        for name in ("decrement_tolerance", "gradient_tolerance", "floor_tolerance"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be finite and >= 0, got {value!r}")
        for name in ("relative_decrease", "discretisation_fraction"):
            if not 0 <= getattr(self, name) < 1:
                raise ValueError(f"{name} must be in [0, 1), got {getattr(self, name)!r}")
        if not 0 < self.fd_step < 1:
            raise ValueError(f"fd_step must be in (0, 1), got {self.fd_step}")
        if not 0 < self.armijo < 0.5:
            raise ValueError(f"armijo must be in (0, 0.5), got {self.armijo}")
        if not (math.isfinite(self.retry_damping) and self.retry_damping > 0):
            raise ValueError(f"retry_damping must be finite and > 0, got {self.retry_damping}")
        if self.longer_steps < 0:
            raise ValueError(f"longer_steps must be >= 0, got {self.longer_steps}")


@dataclass
class NewtonSolution:
    """The parameters reached (the linearisation's shape), Π [J] there, whether a stopping
    test was met, and the iterations."""

    parameters: torch.Tensor
    energy: float
    converged: bool
    history: list[NewtonIteration] = field(default_factory=list)

    @property
    def steps(self) -> int:
        """Accepted Newton steps."""
        return sum(h.step_length > 0 for h in self.history)

    @property
    def energy_before(self) -> float:  # Π [J] at the start
        return self.history[0].energy if self.history else self.energy


def _tolerance(config: NewtonConfig, energy: float, coarse_energy: float | None) -> float:
    """The stopping bound [J] on λ²/2 at Π = energy: decrement_tolerance × |Π|, or
    discretisation_fraction × |Π − Π_coarse| where that is larger (module docstring)."""
    bound = config.decrement_tolerance * abs(energy)
    if coarse_energy is None or not config.discretisation_fraction:
        return bound
    return max(bound, config.discretisation_fraction * abs(energy - coarse_energy))


def _below_floor(config: NewtonConfig, record: NewtonIteration) -> bool:
    """Whether an iteration's decrement λ² [J] was below the rounding floor: λ²/2 ≤
    floor_tolerance × |Π|."""
    return 0.5 * abs(record.decrement) <= config.floor_tolerance * abs(record.energy)


def _shifted_step(linearisation: Linearisation, matrix: Any, gradient: torch.Tensor,
                  config: NewtonConfig) -> tuple[torch.Tensor, float] | None:
    """The step of the exact K + μ D with the least μ = retry_damping × 10^k (k < SHIFTS)
    that makes it definite, and that μ; None where none does. In the endgame the per-block
    projection misstates the curvature along a soft mode (a nearly neutral fold of a twisted
    sleeve: exact K's least eigenvalue −1e-5 of 1e2, Π there nearly linear along it), so
    projected Newton creeps, its decrement far below Π's true remaining change
    (benchmarks/RESULTS.md, "Gallery 5"); the exact K barely shifted models it."""
    mu = config.retry_damping
    for _ in range(SHIFTS):
        result = linearisation.solve(matrix, gradient, mu, require_definite=True)
        if result is not None:
            return result
        mu *= 10
    return None


def minimise(linearisation: Linearisation, potential: Potential, start: torch.Tensor,
             config: NewtonConfig | None = None, *, load_factor: float = 1.0,
             feasible: Callable[[torch.Tensor, torch.Tensor], bool] | None = None,
             on_step: Callable[[torch.Tensor], bool] | None = None,
             on_iteration: Callable[[NewtonIteration], None] | None = None,
             report: bool = True, coarse_energy: float | None = None,
             resume: NewtonIterate | None = None,
             on_iterate: Callable[[NewtonIterate], None] | None = None) -> NewtonSolution:
    """Minimise Π(P) = potential(U(P)) by Newton from parameters `start` (module docstring).

    linearisation: U(P) at the potential's load factor; potential: Π at the linearisation's
    samples. load_factor: recorded in the iterations. feasible(P, P_trial): False rejects a
    line-search trial (halved like an Armijo failure; contact: a step that could enter an
    obstacle). on_step(P): called with each accepted iterate; True stops the minimisation
    there, not converged (contact: the caller adds quadrature points and solves again).
    on_iteration(record): called with each iteration's record before its step is taken (the
    application's callbacks: the divergence guard, checkpoints); it may raise to stop.
    report: each iteration goes to the innermost progress stage and the log at INFO; False:
    the log at DEBUG only (short solves inside another stage: a SIREN's Newton phases).
    coarse_energy: Π [J] of the coarser grid's solution at this load factor (module docstring).
    resume: Newton's state between two iterations (`NewtonIterate`, from `on_iterate`): go
    on from there (`start` unused), bit for bit as if it had not stopped. on_iterate(iterate):
    called after each accepted step that the minimisation goes on from (a checkpoint).
    """
    config = config or NewtonConfig()
    samples = linearisation.samples
    # The first iteration screens the blocks instead of trying the exact K (a start from a
    # coarser grid or the flat sheet is rarely a definite state; a definite one costs a screen)
    it = resume or NewtonIterate(start)
    c, history, converged = it.parameters.detach().clone(), list(it.history), False
    damping, first_norm, exact_failed = it.damping, it.first_norm, it.exact_failed
    previous = it.previous  # Π before the last accepted step

    def _trial_energy(step, a):  # Π at P + a d; inf where `feasible` rejects it
        if feasible is not None and not feasible(c, c + a * step):
            return math.inf
        return potential(samples, linearisation.displacement(c + a * step), False).total

    for iteration in range(it.iteration, config.max_iterations):
        started = time.perf_counter()
        u = linearisation.displacement(c)
        current = potential(samples, u, True)
        gradient = linearisation.gradient(current.grad_u_jets)
        norm = float(gradient.norm())
        first_norm = norm if first_norm is None else first_norm
        t_energy = time.perf_counter() - started
        if norm <= config.gradient_tolerance * first_norm or norm == 0.0 or (
                config.relative_decrease > 0 and previous is not None and
                previous - current.total <= config.relative_decrease * abs(current.total)):
            converged = True
            break
        started, matrix = time.perf_counter(), None  # free the last K before the blocks
        # the endgame (the last decrement already below the floor): the exact K, shifted where
        # it is not definite, every iteration (`_shifted_step`)
        endgame = config.project and bool(history) and _below_floor(config, history[-1])
        exact = config.project and damping == 0.0 and (endgame or not exact_failed)
        strain = config.project and config.hessian == "strain" and hasattr(
            potential, "psd_hessian_blocks")
        # the blocks are built chunk by chunk inside the assemblies (`PointBlocks`), the
        # shell's strain-step scale once for this state
        blocks = partial(PointBlocks, linearisation, potential, c, u, config.fd_step,
                         tangent=state_tangent(potential, samples, u))
        couplings = coupled_blocks(potential, samples, u)
        t_hessian = time.perf_counter() - started
        t_assembly, t_solve, first_step = 0.0, 0.0, None  # first: (step, μ) of a definite K
        if exact or not config.project:
            # The exact K may be definite although some blocks are not (a stable state under
            # compression): then its Newton step converges quadratically.
            started, exact_blocks = time.perf_counter(), blocks()
            matrix = linearisation.hessian(exact_blocks, couplings)
            t_assembly += time.perf_counter() - started - exact_blocks.seconds
            t_hessian += exact_blocks.seconds
        if exact:
            started = time.perf_counter()
            first_step = linearisation.solve(matrix, gradient, 0.0, require_definite=True)
            if first_step is None and endgame:
                first_step = _shifted_step(linearisation, matrix, gradient, config)
            exact_failed = first_step is None
            t_solve += time.perf_counter() - started
        else:  # after a failed attempt the next iteration goes straight to the projected K
            exact_failed = False
        projected = 0
        if first_step is None and config.project:
            started = time.perf_counter()
            if couplings is not None:
                couplings, pairs = couplings.projected(config.hessian)
                projected += pairs
            t_hessian += time.perf_counter() - started
            started, matrix = time.perf_counter(), None  # free the exact K first
            # through the strains: every block; else the exact blocks screened and projected
            psd_blocks = blocks(psd=True) if strain else blocks(project=config.hessian)
            matrix = linearisation.hessian(psd_blocks, couplings)
            projected += len(samples) if strain else psd_blocks.projected
            t_assembly += time.perf_counter() - started - psd_blocks.seconds
            t_hessian += psd_blocks.seconds
        blocks = couplings = None  # K holds what the solves need
        alpha, small, shifted, corrected = 0.0, False, False, False
        for _attempt in range(config.line_searches):
            started = time.perf_counter()
            if first_step is not None:
                (step, damping), first_step = first_step, None
                shifted = damping > 0  # the exact K's shift: not carried to the next iteration
            else:
                step, damping = linearisation.solve(matrix, gradient, damping)
            t_solve += time.perf_counter() - started
            decrement = float(-(gradient * step).sum())
            small = 0.5 * abs(decrement) <= _tolerance(config, current.total, coarse_energy)
            if small:
                break  # converged: the step would change Π by less than the tolerance
            if decrement < 0:  # K (nearly) singular along d, e.g. a flat sheet's rigid
                damping = max(10 * damping, config.retry_damping)  # rotations: damp, again
                continue
            started = time.perf_counter()
            correct = partial(second_order_step, linearisation, potential, matrix, c, u,
                              damping) if config.second_order_correction else None
            alpha, step, corrected = backtrack(
                _trial_energy, current.total, step, decrement, armijo=config.armijo,
                halvings=config.halvings, longer_steps=config.longer_steps, correct=correct)
            t_energy += time.perf_counter() - started
            if alpha > 0:
                break
            damping = max(10 * damping, config.retry_damping)
        history.append(NewtonIteration(load_factor, iteration, current.total, decrement, alpha,
                                       damping, projected, norm, t_energy, t_hessian,
                                       t_assembly, t_solve, corrected))
        log.log(logging.INFO if report else logging.DEBUG,
                "Newton %2d at λ=%.3g: Π %.12g J, λ² %.3e, α %.3g%s, μ %.1e, %d projected, "
                "time energy %.3f hessian %.3f assembly %.3f solve %.3f s", iteration,
                load_factor, current.total, decrement, alpha, " corrected" if corrected else "",
                damping, projected, t_energy, t_hessian, t_assembly, t_solve)
        if report:
            progress.report(iteration + 1, **{"Π": current.total, "λ²": decrement})
        if on_iteration is not None:
            on_iteration(history[-1])
        near = _below_floor(config, history[-1])
        if alpha == 0.0:  # stopped on the decrement tolerance, or no step decreased Π
            converged = small or near
            break
        c = c + alpha * step
        previous = current.total
        if on_step is not None and on_step(c):
            break
        if alpha < 1.0 and near:  # the quadratic model no longer predicts Π: rounding floor
            converged = True
            break
        damping = damping / 10 if alpha >= 1.0 and not shifted else damping
        if damping < config.retry_damping or shifted:
            damping = 0.0
        if on_iterate is not None:
            on_iterate(NewtonIterate(c, iteration + 1, damping, exact_failed, first_norm,
                                     previous, list(history)))
    energy = potential(samples, linearisation.displacement(c), False).total
    return NewtonSolution(parameters=c, energy=energy, converged=converged, history=history)
