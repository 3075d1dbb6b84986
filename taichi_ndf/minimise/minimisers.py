"""Minimisers of an objective over a field's parameters, apart from any continuation, and
the one interface every minimiser of a step is run through.

`adam_iteration` and `lbfgs` take `evaluate(grad) -> Π [J]`, which evaluates the objective on
the minimiser's samples and, if `grad`, fills the field's gradients
(`Solver.energy_and_gradient` with fixed arguments); they know nothing of samples, loads or
files. The Newton minimiser is `taichi_ndf.minimise.newton.minimise` (it needs the
objective's per-point Hessian blocks and a linearisation of the displacement rather than
`evaluate`; a SIREN's output layer: `taichi_ndf.minimise.last_layer.minimise_output_layer`).

One interface (`Minimiser`): `minimise(objective, parameters, hooks) -> MinimiseResult`, with
the same hooks for all (`Hooks`: on_step before a step is taken, on_iteration after each
iteration, on_iterate after each Newton step it goes on from); `AdamMinimiser`,
`LBFGSMinimiser`, `NewtonMinimiser` (a spline's coefficients, sparse) and
`OutputLayerNewton` (a SIREN's output layer, dense) implement it. A driver's step is a list of
`Phase`s (a minimiser with its objective, parameters, hooks and progress stage) that
`run_phases` runs in order: the SIREN's load step (last-layer Newton, Adam with its Newton
phases, last-layer Newton, the L-BFGS polish, `Solver.phases`), a spline level's load step
(projected Newton, `GridLevels.solve`).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from contextlib import nullcontext
from dataclasses import dataclass, field
from typing import Any, Protocol

import torch

from taichi_ndf import progress
from taichi_ndf.minimise.last_layer import minimise_output_layer
from taichi_ndf.minimise.newton import NewtonConfig, minimise
from taichi_ndf.minimise.newton_state import NewtonIterate
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


@dataclass
class MinimiseResult:
    """What one minimiser reached: its steps (Adam or L-BFGS iterations, accepted Newton
    steps), Π [J] before and after where it evaluates them (None: Adam's Π is on each
    iteration's own samples), whether a stopping test was met, and a Newton's parameters at
    the end (the linearisation's shape; None where the field was changed in place) and its
    iterations."""

    steps: int
    energy_before: float | None = None
    energy: float | None = None
    converged: bool = False
    parameters: torch.Tensor | None = None
    history: list = field(default_factory=list)


@dataclass(frozen=True)
class Hooks:
    """What a minimiser calls while it runs, each optional: on_step(Π, ‖∇Π‖) before an Adam
    step is taken (the divergence guard), on_iteration(record) after each iteration (Adam:
    its ‖∇Π‖ before the step; Newton: its `NewtonIteration`, before the step; it may raise to
    stop), on_iterate(iterate) after each Newton step the minimisation goes on from (its
    `NewtonIterate`: a checkpoint)."""

    on_step: Callable[[float, float], None] | None = None
    on_iteration: Callable[[Any], None] | None = None
    on_iterate: Callable[[NewtonIterate], None] | None = None


class Minimiser(Protocol):
    """A minimiser of Π at one step behind one call. objective: Π in the minimiser's form
    (Adam: a draw of each iteration's objective; L-BFGS: evaluate(grad) on fixed samples;
    Newton: (linearisation, potential)); parameters: what it changes (a field, in place, or
    Newton's starting P)."""

    def minimise(self, objective: Any, parameters: Any, hooks: Hooks) -> MinimiseResult:
        """Minimise from `parameters`; the result (module docstring)."""


class AdamMinimiser:
    """Adam iterations `first` .. `iterations` − 1: each draws its objective (`objective()`:
    the iteration's fresh samples) and takes one step (`step(drawn, check) -> ‖∇Π‖`: by
    default `adam_iteration` on `optimiser` with drawn = evaluate; a caller's policy around
    it, contact's); hooks.on_iteration(‖∇Π‖) after each."""

    def __init__(self, optimiser: Adam, iterations: int, *, first: int = 0,
                 step: Callable[[Any, Callable | None], float] | None = None):
        self.optimiser, self.iterations, self.first = optimiser, iterations, first
        self.step = step or (lambda evaluate, check: adam_iteration(optimiser, evaluate,
                                                                    check)[1])

    def minimise(self, objective: Callable[[], Any], parameters: Any = None,
                 hooks: Hooks = Hooks()) -> MinimiseResult:
        for _ in range(self.first, self.iterations):
            grad_norm = self.step(objective(), hooks.on_step)
            if hooks.on_iteration is not None:
                hooks.on_iteration(grad_norm)
        return MinimiseResult(steps=max(self.iterations - self.first, 0))


class LBFGSMinimiser:
    """`lbfgs` for `iterations` iterations over the field (parameters) on fixed samples
    (objective: evaluate(grad) -> Π)."""

    def __init__(self, iterations: int):
        self.iterations = iterations

    def minimise(self, objective: Evaluate, parameters: Any, hooks: Hooks = Hooks()
                 ) -> MinimiseResult:
        before, after = lbfgs(parameters, objective, self.iterations)
        return MinimiseResult(steps=self.iterations, energy_before=before, energy=after)


def value_and_gradient(potential):
    """`potential` as a plain (samples, u_jets, grad) -> EnergyResult callable, without its
    `hessian_blocks` / `coupled_blocks` (Newton then differences its gradient)."""
    return lambda samples, u_jets, grad: potential(samples, u_jets, grad)


def _newton_result(solution) -> MinimiseResult:
    return MinimiseResult(solution.steps, solution.energy_before, solution.energy,
                          solution.converged, solution.parameters, solution.history)


class NewtonMinimiser:
    """The one Newton (`newton.minimise`) over objective = (linearisation, potential) from P
    = parameters, with `config` and its keyword settings (load_factor, coarse_energy,
    feasible, on_step, report, resume: `newton.minimise`'s)."""

    def __init__(self, config: NewtonConfig | None = None, **settings):
        self.config, self.settings = config, settings

    def minimise(self, objective: tuple, parameters: torch.Tensor, hooks: Hooks = Hooks()
                 ) -> MinimiseResult:
        linearisation, potential = objective
        return _newton_result(minimise(
            linearisation, potential, parameters, self.config, on_iteration=hooks.on_iteration,
            on_iterate=hooks.on_iterate, **self.settings))


class OutputLayerNewton:
    """Newton over a SIREN's output layer (`last_layer.minimise_output_layer`): objective =
    (its output-layer linearisation, potential), parameters = the field (changed in place)."""

    def __init__(self, load_factor: float, config: NewtonConfig | None = None, *,
                 contact=None):
        self.load_factor, self.config, self.contact = load_factor, config, contact

    def minimise(self, objective: tuple, parameters: Any, hooks: Hooks = Hooks()
                 ) -> MinimiseResult:
        linear, potential = objective
        return _newton_result(minimise_output_layer(parameters, linear, potential,
                                                    self.load_factor, self.config,
                                                    contact=self.contact))


@dataclass
class Phase:
    """One minimiser of a step with what it is run on (`run_phases`): objective()
    (built when the phase starts: after the phases before it) and parameters() likewise,
    hooks, a progress stage (name, total) around it or None, and `after(result)`."""

    minimiser: Minimiser
    objective: Callable[[], Any]
    parameters: Callable[[], Any] = lambda: None
    hooks: Hooks = Hooks()
    stage: tuple[str, int | None] | None = None
    after: Callable[[MinimiseResult], None] | None = None


def run_phases(phases: Sequence[Phase]) -> list[MinimiseResult]:
    """Run the phases in order (`Phase`); their results."""
    results = []
    for phase in phases:
        with progress.stage(*phase.stage) if phase.stage else nullcontext():
            result = phase.minimiser.minimise(phase.objective(), phase.parameters(),
                                              phase.hooks)
        if phase.after is not None:
            phase.after(result)
        results.append(result)
    return results
