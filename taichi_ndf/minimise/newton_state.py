"""What one Newton minimisation carries from an iteration to the next: its records and its iterate.

`NewtonIteration` is one iteration's record (Π, the decrement, the step, the damping, the
time split). `NewtonIterate` is Newton's state between two iterations (`minimise.newton.
minimise`): the parameters, the damping μ the next solve starts from, whether the last try of
the exact K failed, ‖g₀‖ of the gradient test, Π before the last accepted step (the
relative-decrease test) and the iterations so far. Handed to `minimise(..., resume=)`, it
continues the minimisation bit for bit as if it had not stopped (a checkpoint inside a grid
level: `minimise.state.InsideLevel`).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import torch


@dataclass
class NewtonIteration:
    """One Newton iteration: Π [J] before the step, the decrement λ² = −gᵀd [J], the accepted
    step length α (0: none; above 1: a lengthened full step), the damping μ, the blocks
    projected (0 also when the exact K was definite and used; "strain": all), ‖g‖, seconds
    spent on energy + gradient, Hessian blocks, assembly and the linear solve, and whether the
    step taken was the full step with its second-order correction (`minimise.line_search`;
    absent from records written before it: False)."""

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
    corrected: bool = False


@dataclass
class NewtonIterate:
    """Newton between two iterations (module docstring).

    iteration: the next iteration's index; parameters: P (the linearisation's shape);
    damping: μ of the next solve; exact_failed: the last try of the exact K was not definite
    (the next iteration screens instead); first_norm: ‖g₀‖ [J per unit of P] (None before the
    first iteration); previous: Π [J] before the last accepted step (None: none yet);
    history: the iterations so far."""

    parameters: torch.Tensor
    iteration: int = 0
    damping: float = 0.0
    exact_failed: bool = True
    first_norm: float | None = None
    previous: float | None = None
    history: list[NewtonIteration] = field(default_factory=list)

    def to_dict(self) -> dict:
        """Plain values for a checkpoint (`minimise.checkpoint`: tensors, numbers, lists)."""
        return {"parameters": self.parameters, "iteration": self.iteration,
                "damping": self.damping, "exact_failed": self.exact_failed,
                "first_norm": self.first_norm, "previous": self.previous,
                "history": [asdict(h) for h in self.history]}

    @classmethod
    def from_dict(cls, values: dict) -> NewtonIterate:
        return cls(values["parameters"], int(values["iteration"]), float(values["damping"]),
                   bool(values["exact_failed"]), values["first_norm"], values["previous"],
                   [NewtonIteration(**h) for h in values["history"]])
