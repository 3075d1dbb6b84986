"""The objective: a sum of energy terms of the displacement jets (docs/architecture.md).

Each term gives its value [J] and its gradient with respect to the displacement jets at the
samples; the objective adds them, and their Hessians: per-point blocks, and for a term that
joins points (a seam's stitches) blocks between pairs of points (`Couplings`). Minimisers see
only the objective, so a new term (contact, inertia, seams) needs no new solver.
"""

from taichi_ndf.objective.couplings import Couplings
from taichi_ndf.objective.objective import Objective, Term
from taichi_ndf.objective.terms import EndMomentTerm, FoundationTerm, ShellEnergyTerm, StitchTerm

__all__ = ["Objective", "Term", "Couplings", "ShellEnergyTerm", "EndMomentTerm", "StitchTerm",
           "FoundationTerm"]
