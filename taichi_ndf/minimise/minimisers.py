"""Minimisers of an objective over a field's parameters, apart from any continuation.

Each takes `evaluate(grad) -> Π [J]`, which evaluates the objective on the minimiser's samples
and, if `grad`, fills the field's gradients (`Solver.energy_and_gradient` with fixed
arguments); they know nothing of samples, loads or files. The Newton minimiser is
`taichi_ndf.minimise.newton.minimise` (it needs the objective's per-point Hessian blocks and a
linearisation of the displacement rather than `evaluate`; a SIREN's output layer:
`taichi_ndf.minimise.last_layer.solve_last_layer`).
"""

from __future__ import annotations

import logging
from collections.abc import Callable

import torch

from taichi_ndf.problem.optim import Adam

log = logging.getLogger(__name__)

Evaluate = Callable[[bool], float]


def adam_iteration(optimiser: Adam, evaluate: Evaluate, check=None) -> tuple[float, float]:
    """One Adam step: Π and ‖∇Π‖ before the step. `check(energy, grad_norm)` runs before the
    step is taken (e.g. a divergence guard that raises on non-finite values)."""
    energy = evaluate(True)
    grad_norm = optimiser.gradient_norm()
    if check is not None:
        check(energy, grad_norm)
    optimiser.step()
    return energy, grad_norm


def lbfgs(field, evaluate: Evaluate, iterations: int, *, history_size: int = 20
          ) -> tuple[float, float]:
    """Deterministic L-BFGS (strong-Wolfe line search) over all of the field's parameters for
    `iterations` iterations; leaves the field at the result. Returns Π before and after.

    torch's default tolerances are absolute (1e-7 on the gradient, 1e-9 on Π) and stop at
    once when Π is small; the requested iterations are run instead."""
    flat = torch.nn.Parameter(field.get_flat().clone())
    opt = torch.optim.LBFGS([flat], lr=1.0, max_iter=iterations, history_size=history_size,
                            line_search_fn="strong_wolfe", tolerance_grad=0.0,
                            tolerance_change=0.0)

    def closure():
        field.set_flat(flat.detach())
        total = evaluate(True)
        flat.grad = field.get_flat_gradient().clone()
        return torch.tensor(total, dtype=flat.dtype)

    before = evaluate(False)
    opt.step(closure)
    field.set_flat(flat.detach())
    after = evaluate(False)
    return before, after
