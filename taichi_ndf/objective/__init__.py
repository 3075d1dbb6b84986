"""The objective: a sum of energy terms of the displacement jets (docs/architecture.md).

Each term gives its value [J] and its gradient with respect to the displacement jets at the
samples; the objective adds them. Minimisers see only the objective, so a new term (contact,
inertia) needs no new solver.
"""

from taichi_ndf.objective.objective import Objective, Term
from taichi_ndf.objective.terms import EndMomentTerm, ShellEnergyTerm

__all__ = ["Objective", "Term", "ShellEnergyTerm", "EndMomentTerm"]
