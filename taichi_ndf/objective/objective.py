"""The objective Π = Σ_terms Π_term of displacement jets at samples, and the term protocol."""

from __future__ import annotations

import inspect
from dataclasses import dataclass
from typing import Protocol

import torch

from taichi_ndf.objective.couplings import Couplings
from taichi_ndf.objective.terms import ShellEnergyTerm
from taichi_ndf.problem.sampling import SurfaceSamples
from taichi_ndf.shell.energy import EnergyResult
from taichi_ndf.shell.hessian import JET_SIZE, project_psd, sample_hessians


class Term(Protocol):
    """An energy term of the displacement jets.

    evaluate(samples, u_jets (N, 6, 3) [m], load_factor, *, grad) -> (value [J], dΠ/du_jets
    (N, 6, 3) or None). load_factor: one number or one per sample (N,) (a pseudo-time field);
    the samples carry unscaled point forces and the term applies the load factor.

    Optional: hessian_blocks(samples, u_jets, load_factor, *, steps) -> its per-point blocks
    (N, 6, 3, 6, 3) (without it: central differences of its gradient); coupled_hessian(samples,
    u_jets, load_factor) -> `Couplings`, its Hessian entries between pairs of points (a term
    with couplings gets no central differences: `taichi_ndf.objective.couplings`).
    """

    def evaluate(self, samples: SurfaceSamples, u_jets: torch.Tensor,
                 load_factor: float | torch.Tensor, *, grad: bool = True
                 ) -> tuple[float, torch.Tensor | None]: ...


class Objective:
    """The shell's potential energy plus further terms (work of an end moment, ...).

    shell: the term whose `EnergyResult` (strain energy density, parts) the objective reports
    (`ShellEnergyTerm`); extra: further terms, counted as external work.
    """

    def __init__(self, shell: ShellEnergyTerm, extra: tuple[Term, ...] = ()):
        self.shell = shell
        self.extra = tuple(extra)

    @classmethod
    def of_model(cls, model) -> Objective:
        """The potential energy of a `ShellModel`: its material under its loads, plus the
        model's further terms (`ShellModel.terms`, e.g. an elastic foundation)."""
        return cls(ShellEnergyTerm(model.material, model.loads), model.terms)

    def with_terms(self, *terms: Term) -> Objective:
        """The objective with further terms added."""
        return Objective(self.shell, self.extra + terms)

    def evaluate(self, samples: SurfaceSamples, u_jets: torch.Tensor,
                 load_factor: float | torch.Tensor = 1.0, *, grad: bool = True
                 ) -> EnergyResult:
        """Π [J] of the displacement jets u_jets (N, 6, 3) [m] at the samples, with dΠ/du_jets
        if `grad`: the shell term's result with the other terms' values added to its total
        and external work and their gradients to its gradient."""
        result = self.shell.result(samples, u_jets, load_factor, grad=grad)
        for term in self.extra:
            value, term_grad = term.evaluate(samples, u_jets, load_factor, grad=grad)
            result.total += value
            result.external += value
            if grad:
                result.grad_u_jets = result.grad_u_jets + term_grad
        return result

    def potential(self, load_factor: float | torch.Tensor = 1.0) -> FixedLoadPotential:
        """Π at a fixed load factor: callable (samples, u_jets, grad) -> EnergyResult (the
        form the Newton solvers take), with its per-point Hessian blocks."""
        return FixedLoadPotential(self, load_factor)

    def tangent_length(self, samples: SurfaceSamples, u_jets: torch.Tensor):
        """The shell term's scale of its strain steps at U = u_jets (its `tangent_length`), for
        `hessian_blocks(tangent=)`: computed once per state by a caller that asks the blocks
        chunk by chunk of rows (`taichi_ndf.minimise.point_blocks.PointBlocks`); None where
        the shell term has none (its blocks then take no `tangent`)."""
        length = getattr(self.shell, "tangent_length", None)
        return None if length is None else length(samples, u_jets)

    def hessian_blocks(self, samples: SurfaceSamples, u_jets: torch.Tensor,
                       load_factor: float | torch.Tensor = 1.0, *, steps: torch.Tensor,
                       psd: bool = False, rows: slice | None = None, tangent=None
                       ) -> torch.Tensor:
        """Per-point Hessian blocks d²Π/du_jets² (N, 6, 3, 6, 3), not projected: the sum of
        each term's own `hessian_blocks(samples, u_jets, load_factor, steps=steps)` where the
        term has one, else central differences of that term's gradient (`sample_hessians`,
        steps (6,) per jet channel) — except for a term with couplings, whose Hessian is in
        `coupled_blocks`. psd: positive semi-definite instead, the shell's through its strains
        (`ShellEnergyTerm.hessian_blocks`' psd), the other terms' clamped (`project_psd`).
        rows: only the blocks of these points (n, 6, 3, 6, 3) (a chunk: Newton assembles K
        chunk by chunk), the same values as those rows of all points' blocks: a term whose
        `hessian_blocks` takes `rows` (the shell's, the stiffness damping, inertia, wind)
        given them, any other term's built at all points and cut (per-point data of their
        own: the contact terms; their blocks are cheap). tangent: the shell's
        `tangent_length` at these samples and U, passed to the shell term (None: it computes
        its own)."""
        total, part = None, (lambda b: b) if rows is None else (lambda b: b[rows])
        for term in (self.shell, *self.extra):
            own = getattr(term, "hessian_blocks", None)
            scale = {} if tangent is None or term is not self.shell else {"tangent": tangent}
            if own is not None and psd and term is self.shell:
                blocks = own(samples, u_jets, load_factor, steps=steps, psd=True,
                             **({} if rows is None else {"rows": rows}), **scale)
            elif own is not None and "rows" in inspect.signature(own).parameters:
                blocks = own(samples, u_jets, load_factor, steps=steps, rows=rows, **scale)
            elif own is not None:
                blocks = part(own(samples, u_jets, load_factor, steps=steps))
            elif hasattr(term, "coupled_hessian"):  # its Hessian is all in its couplings
                continue
            else:
                blocks = part(sample_hessians(_term_potential(term, load_factor), samples,
                                              u_jets, steps=steps))
            if psd and term is not self.shell:
                blocks = project_psd(blocks.reshape(blocks.shape[0], JET_SIZE, JET_SIZE)
                                     )[0].reshape(blocks.shape)
            # the first term's blocks are its own new tensor: the others are added in place
            total = blocks if total is None else total.add_(blocks)
        return total

    def second_order_gradient(self, samples: SurfaceSamples, u_jets: torch.Tensor,
                              step_jets: torch.Tensor) -> torch.Tensor | None:
        """The residual (N, 6, 3) of Newton's second-order correction of a step ΔU = step_jets
        from U = u_jets: the sum of the terms' `second_order_gradient` (the shell's membrane
        stretch; the loads are linear, the other terms have none); None where none has one."""
        parts = [term.second_order_gradient(samples, u_jets, step_jets)
                 for term in (self.shell, *self.extra) if hasattr(term, "second_order_gradient")]
        return None if not parts else sum(parts[1:], parts[0])

    def coupled_blocks(self, samples: SurfaceSamples, u_jets: torch.Tensor,
                       load_factor: float | torch.Tensor = 1.0) -> Couplings | None:
        """The Hessian entries between pairs of points of the terms that have them
        (`coupled_hessian`), joined; None where no term has any."""
        return Couplings.join(term.coupled_hessian(samples, u_jets, load_factor)
                              for term in (self.shell, *self.extra)
                              if hasattr(term, "coupled_hessian"))


def _term_potential(term: Term, load_factor):
    """One term at a fixed load factor as (samples, u_jets, grad) -> an object with
    `.grad_u_jets` (what `sample_hessians` differentiates)."""
    if isinstance(term, ShellEnergyTerm):
        return lambda samples, u_jets, grad: term.result(samples, u_jets, load_factor, grad=grad)

    def evaluate(samples, u_jets, grad):
        value, gradient = term.evaluate(samples, u_jets, load_factor, grad=grad)
        return _Gradient(value, gradient)
    return evaluate


@dataclass(frozen=True)
class _Gradient:
    total: float
    grad_u_jets: torch.Tensor | None


@dataclass(frozen=True)
class FixedLoadPotential:
    """Π of an objective at one load factor (`Objective.potential`)."""

    objective: Objective
    load_factor: float | torch.Tensor

    def __call__(self, samples: SurfaceSamples, u_jets: torch.Tensor, grad: bool
                 ) -> EnergyResult:
        return self.objective.evaluate(samples, u_jets, self.load_factor, grad=grad)

    def tangent_length(self, samples: SurfaceSamples, u_jets: torch.Tensor):
        """The shell's strain-step scale at U = u_jets, for `hessian_blocks(tangent=)`
        (`Objective.tangent_length`)."""
        return self.objective.tangent_length(samples, u_jets)

    def hessian_blocks(self, samples: SurfaceSamples, u_jets: torch.Tensor, *,
                       steps: torch.Tensor, rows: slice | None = None, tangent=None
                       ) -> torch.Tensor:
        """Per-point Hessian blocks (N, 6, 3, 6, 3), or those of `rows`
        (`Objective.hessian_blocks`)."""
        return self.objective.hessian_blocks(samples, u_jets, self.load_factor, steps=steps,
                                             rows=rows, tangent=tangent)

    def psd_hessian_blocks(self, samples: SurfaceSamples, u_jets: torch.Tensor, *,
                           steps: torch.Tensor, rows: slice | None = None, tangent=None
                           ) -> torch.Tensor:
        """Positive semi-definite per-point blocks (N, 6, 3, 6, 3), or those of `rows`
        (`Objective.hessian_blocks`' psd: projected Newton's "strain" treatment)."""
        return self.objective.hessian_blocks(samples, u_jets, self.load_factor, steps=steps,
                                             psd=True, rows=rows, tangent=tangent)

    def second_order_gradient(self, samples: SurfaceSamples, u_jets: torch.Tensor,
                              step_jets: torch.Tensor) -> torch.Tensor | None:
        """The second-order correction's residual (`Objective.second_order_gradient`)."""
        return self.objective.second_order_gradient(samples, u_jets, step_jets)

    def coupled_blocks(self, samples: SurfaceSamples, u_jets: torch.Tensor
                       ) -> Couplings | None:
        """Hessian entries between pairs of points (`Objective.coupled_blocks`)."""
        return self.objective.coupled_blocks(samples, u_jets, self.load_factor)
