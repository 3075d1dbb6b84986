"""Last-layer Newton (Galerkin) solve: minimise Π exactly over a SIREN's output layer.

The raw field output is linear in the output layer θ_k = (W_out[k], b_out[k]) of each component
k, and the boundary conditions compose affinely (u_k = φ_k·raw_k + g_k, Leibniz rule on jets;
minus raw_k(ξ₀) with a free pin: `BoundaryConditions.compose_jacobian`), so the displacement
jets are affine in θ: u = u(θ₀) + J (θ − θ₀) with J in closed form — a `DenseLinearisation`
(`output_linearisation`) over the change θ − θ₀. The one Newton (`taichi_ndf.minimise.newton`)
minimises over it with the hidden layers (the features) held fixed, with the settings of
`LAST_LAYER`: plain damped Newton (no projection: the Jacobi-scaled K + μ I is factorised
with μ raised until it is definite), a backtracking line search, and a stop when a step lowers
Π by less than `relative_decrease` × |Π|. In the linear regime one step reaches the Galerkin
optimum over the span of the features; nonlinear problems take a few.

A conditioned field u(ξ, c) (material parameters, load components as extra inputs) is solved
the same way: pass the per-sample conditioning c (N, k) of the fixed samples; the features
depend on it and the output layer is still linear, and the potential must evaluate each sample
with its own stiffness / load (the caller's closure: e.g. `ShellEnergy.evaluate(...,
stiffness=...)` and the samples' own point forces).

Why: Π is extremely ill-conditioned for thin shells (membrane stiffness ~10⁵ × bending/L²), so
first-order optimisers crawl; a second-order solve over the output layer does not care.
"""

from __future__ import annotations

import dataclasses
import logging

import torch

from taichi_ndf.contact.hook import ContactHook
from taichi_ndf.field import NeuralField
from taichi_ndf.minimise.linearisation import DenseLinearisation
from taichi_ndf.minimise.newton import (
    NewtonConfig,
    NewtonSolution,
    coupled_blocks,
    minimise,
    point_blocks,
)
from taichi_ndf.problem.operator import DisplacementOperator
from taichi_ndf.problem.sampling import SurfaceSamples
from taichi_ndf.shell.hessian import Potential

log = logging.getLogger(__name__)

# Newton over an output layer: at most 8 steps, FD step 1e-4 of each channel's scale, plain
# damped Newton (the features' Hessian is positive semi-definite in the linear regime; nearly
# collinear features make it singular, which the damping handles), 12 halvings and 4 line
# searches (damping from 1e-6) per step, stop when a step lowers Π by ≤ 1e-10 |Π|.
LAST_LAYER = NewtonConfig(max_iterations=8, decrement_tolerance=0.0, gradient_tolerance=0.0,
                          relative_decrease=1e-10, fd_step=1e-4, floor_tolerance=0.0,
                          halvings=12, line_searches=4, retry_damping=1e-6, project=False,
                          longer_steps=0)


def last_layer_config(**changes) -> NewtonConfig:
    """`LAST_LAYER` with some fields changed (e.g. max_iterations, relative_decrease)."""
    return dataclasses.replace(LAST_LAYER, **changes)


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


def output_linearisation(operator: DisplacementOperator, samples: SurfaceSamples,
                         load_factor: float, conditioning: torch.Tensor | None = None
                         ) -> DenseLinearisation:
    """u(θ₀ + P) = u(θ₀) + J P at the samples: the dense linearisation of the operator's field
    over the change P (3, width + 1) of its output layer from θ₀ (its current one)."""
    u, jacobian = output_jacobian(operator, samples.xi, load_factor, conditioning)
    return DenseLinearisation(samples, u, jacobian, origin=output_parameters(operator.field))


def output_hessian(operator: DisplacementOperator, potential: Potential,
                   samples: SurfaceSamples, load_factor: float,
                   config: NewtonConfig | None = None, *,
                   conditioning: torch.Tensor | None = None
                   ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Displacement jets u (N, 6, 3) [m] of the current field at the samples, their Jacobian
    J (3, N, 6, width + 1) with respect to the output layer (`output_jacobian`) and the
    output-layer Hessian H = d²Π/dθ² (3 (width + 1), 3 (width + 1)) (`parameter_hessian` of
    the blocks `point_blocks`, FD step `config.fd_step`). At a converged solve (∇_θ Π = 0)
    this is what the implicit-function theorem needs: dθ*/dp = −H⁻¹ ∂(∇_θ Π)/∂p for any
    parameter p of the potential, with ∂(∇_θ Π)/∂p = Jᵀ ∂(dΠ/du)/∂p."""
    config = config or LAST_LAYER
    linear = output_linearisation(operator, samples, load_factor, conditioning)
    zero = torch.zeros_like(linear.origin)
    blocks = point_blocks(linear, potential, zero, linear.offset, config.fd_step)
    couplings = coupled_blocks(potential, linear.samples, linear.offset)
    return linear.offset, linear.jacobian, linear.hessian(blocks, couplings)


def solve_last_layer(operator: DisplacementOperator, potential: Potential,
                     samples: SurfaceSamples, load_factor: float,
                     config: NewtonConfig | None = None, *,
                     conditioning: torch.Tensor | None = None,
                     contact: ContactHook | None = None) -> NewtonSolution:
    """Minimise Π (potential: the objective at a load factor, `Objective.potential`) over the
    output layer of the operator's field on fixed samples: `minimise_output_layer` over
    `output_linearisation`. conditioning: per-sample extra inputs (N, k) of a conditioned
    field (module docstring); contact: as in `minimise_output_layer`."""
    linear = output_linearisation(operator, samples, load_factor, conditioning)
    return minimise_output_layer(operator.field, linear, potential, load_factor, config,
                                 contact=contact)


def minimise_output_layer(field: NeuralField, linear: DenseLinearisation,
                          potential: Potential, load_factor: float,
                          config: NewtonConfig | None = None, *,
                          contact: ContactHook | None = None) -> NewtonSolution:
    """Minimise Π over the output layer of `field` through `linear`, the field's output-layer
    linearisation at fixed samples about its current output layer (`output_linearisation`,
    or a discretisation's: `SirenDiscretisation.linearisation`), by the one Newton
    (`minimise`, settings `LAST_LAYER` by default); updates W_out and b_out in place. The
    solution's parameters are the change of the output layer (3, width + 1).

    contact: the run's `ContactHook` (samples: with its check points): its line-search test
    `feasible` on the checked points (`ContactPoints.checked`), each trial from the current
    iterate, as in projected Newton; None: every trial is feasible."""
    feasible = None
    if contact is not None:
        keep = contact.points.checked(linear.samples)
        r = linear.samples.r_jets[keep, 0]
        feasible = contact.feasible(lambda p: r + linear.displacement(p)[keep, 0], load_factor)
    solution = minimise(linear, potential, torch.zeros_like(linear.origin),
                        config or LAST_LAYER, load_factor=load_factor, feasible=feasible,
                        report=False)
    weight, bias = field.output_layer()
    with torch.no_grad():
        weight.add_(solution.parameters[:, :-1])
        bias.add_(solution.parameters[:, -1])
    log.info("last-layer Newton at load factor %.4g: Π %.10g -> %.10g J in %d steps",
             load_factor, solution.energy_before, solution.energy, solution.steps)
    return solution
