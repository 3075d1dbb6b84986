"""Newton's line search on Π along a step d from P (`taichi_ndf.minimise.newton.minimise`).

Backtracking Armijo: α = 1, ½, ¼, … until Π(P + α d) ≤ Π(P) − c α λ² (λ² = −gᵀd, the
decrement), a trial that the caller's feasibility test rejects (contact: a step that could enter
an obstacle) counting as a failure. Two rules around the full step:

- **Second-order correction** (`second_order_step`; `NewtonConfig.second_order_correction`,
  off by default), where the full step is feasible and fails the test: the corrected full
  step d + s, s = −K⁻¹ r by the same K, tried on the same rule (α = 1, the same λ²) before
  backtracking along d. r is the potential's residual of the
  step's second-order stretch (`Objective.second_order_gradient`: the membrane stress of
  ε₂ = ½ ΔU_,α·ΔU_,β pulled back through dε/dU at P). A nearly inextensible sheet is a
  stiff constraint on a curved manifold: a straight Newton step stretches it at second order
  and its stiff energy rejects a step the quadratic model favours (the Maratos effect), so
  projected Newton backtracks at every other iteration and converges linearly (the napkin's
  finer grids, benchmarks/RESULTS.md "Newton on cloth drapes: the second-order correction
  (issue 28)": there the whole model error of a rejected step is membrane energy beyond
  second order; bending and the loads follow the model). s restores the linearised membrane
  strain at the least cost in K's norm, the penalty form of the constrained second-order
  correction (Nocedal & Wright, §15.4 / 18.3). The correction by the full gradient at
  P + d, s = −K⁻¹ g(P + d), does not work here: g(P + d) also carries the stiff stress of
  the stretch along soft directions (the rotated strain Jacobian), and K⁻¹ (eigenvalues 1e-4
  to 1e3) makes s 7–10⁵ × d.
- **Longer step** (`longer_step`): an accepted full step that lowered Π clearly more than the
  quadratic model predicts is doubled while Π keeps falling.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from functools import partial
from typing import Any

import torch

# A full step that lowered Π by more than this × the quadratic model's ½λ² is tried longer.
LONGER_STEP_RATIO = 1.25


def longer_step(energy_at: Callable[[float], float], start: float, full: float,
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


def second_order_step(linearisation, potential, matrix: Any, parameters: torch.Tensor,
                      u_jets: torch.Tensor, damping: float, step: torch.Tensor
                      ) -> torch.Tensor | None:
    """The corrected full step d + s (the parameters' shape; module docstring): s from
    (K + μ D) s = −r by `Linearisation.solve` with K = matrix and μ = damping (those of d),
    r = Jᵀ ∂r/∂U of the potential's `second_order_gradient` at U = u_jets (= U(P)) for the
    step ΔU = U(P + d) − U(P); None where the potential has no such residual."""
    residual_of = getattr(potential, "second_order_gradient", None)
    if residual_of is None:
        return None
    step_jets = linearisation.displacement(parameters + step) - u_jets
    residual = residual_of(linearisation.samples, u_jets, step_jets)
    if residual is None:
        return None
    correction, _ = linearisation.solve(matrix, linearisation.gradient(residual), damping)
    return step + correction


def backtrack(energy_at: Callable[[torch.Tensor, float], float], start: float,
              step: torch.Tensor, decrement: float, *, armijo: float, halvings: int,
              longer_steps: int,
              correct: Callable[[torch.Tensor], torch.Tensor | None] | None = None
              ) -> tuple[float, torch.Tensor, bool]:
    """The line search from Π = `start` along `step` (module docstring): (α, the step taken,
    whether it is the corrected full step). energy_at(step, α): Π at P + α step, inf where
    infeasible; decrement: λ² = −gᵀd [J] (> 0); armijo: the constant c; halvings: most trials
    along d (α = 1 to 2^(1 − halvings)); longer_steps: most doublings of an accepted full
    step; correct(d): the corrected full step (`second_order_step`) or None (no correction).
    α = 0: no trial decreased Π enough."""

    def sufficient(trial: float, alpha: float) -> bool:
        return math.isfinite(trial) and trial <= start - armijo * alpha * decrement

    full = energy_at(step, 1.0)
    if sufficient(full, 1.0):
        alpha = longer_step(partial(energy_at, step), start, full, decrement,
                            longer_steps) if longer_steps else 1.0
        return alpha, step, False
    if correct is not None and math.isfinite(full):
        corrected = correct(step)
        if corrected is not None and sufficient(energy_at(corrected, 1.0), 1.0):
            return 1.0, corrected, True
    alpha = 0.5
    for _ in range(halvings - 1):
        if sufficient(energy_at(step, alpha), alpha):
            return alpha, step, False
        alpha *= 0.5
    return 0.0, step, False
