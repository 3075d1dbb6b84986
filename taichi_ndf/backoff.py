"""Learning-rate backoff: Adam's answer to a step that is too long.

Adam moves every weight by about the learning rate per step, so a SIREN field's displacement
step is about learning rate × output_scale (docs/scenes.md, "Field output scale"). Where that
is too long for the shell's stiff directions, Π does not just fluctuate: it climbs by orders of
magnitude (flag with a 1.78 m output scale: −0.419 J at iteration 50, +141 J at 100, +4.8e5 J
at 250). At every monitor record the solver compares Π on the fixed monitor samples with the
best Π recorded at the same load factor (from the load step's start on), measured in units of
the largest |Π| recorded up to the best. Where Π lies above the best by more than
DIVERGED_FACTOR such units (two orders of magnitude), or by more than CLIMB_FACTOR (one) at
two records in a row, or is not finite, the field's parameters and Adam's moments go back to
the best state and the learning rate is halved (`Adam.lr_scale`), at most MAX_BACKOFFS times
per run. One order of magnitude at one record is not enough: Adam overshoots early in a run,
while |Π| is still small, and comes back down by the next record (napkin_interior_line: from
−0.011 to +0.112 J at iteration 100). Nor is waiting for a second record always harmless: a
run that climbed by two orders and came back can come back into a worse state (flag: waiting
ended at −0.136 J instead of −1.18 J). Training noise moves the monitored Π by a fraction of
|Π|, so a run whose steps are short enough does not back off.

The best state is part of the solver's `State` (a checkpoint keeps it), so a resumed run backs
off exactly as an uninterrupted one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

# Π above the best by more than this many times the largest |Π| recorded up to the best has
# climbed; at two records in a row, or by DIVERGED_FACTOR at one, the run backs off.
CLIMB_FACTOR = 10.0
DIVERGED_FACTOR = 100.0
# The most halvings of the learning rate in one run (1/1024 of the schedule's after all).
MAX_BACKOFFS = 10


@dataclass
class BestState:
    """The lowest monitored Π at a load factor and the state that had it.

    parameters: the field's flat parameter vector; optimiser: `Adam.state_dict()`."""

    iteration: int
    load_factor: float
    energy: float  # Π on the monitor samples [J]
    magnitude: float  # the largest |Π| [J] recorded at this load factor up to this state
    parameters: torch.Tensor
    optimiser: dict

    def to_dict(self) -> dict:
        return {"iteration": self.iteration, "load_factor": self.load_factor,
                "energy": self.energy, "magnitude": self.magnitude,
                "parameters": self.parameters, "optimiser": self.optimiser}

    @classmethod
    def from_dict(cls, data: dict) -> BestState:
        return cls(iteration=int(data["iteration"]), load_factor=float(data["load_factor"]),
                   energy=float(data["energy"]), magnitude=float(data["magnitude"]),
                   parameters=data["parameters"], optimiser=data["optimiser"])


def climbed(energy: float, best: BestState, factor: float = CLIMB_FACTOR) -> bool:
    """Π [J] lies above the best by more than `factor` times the largest |Π| recorded up to
    the best (or is not finite)."""
    if not math.isfinite(energy):
        return True
    return energy - best.energy > factor * best.magnitude


def should_back_off(energy: float, previous: float | None, best: BestState) -> bool:
    """Back off at a record of Π = `energy` [J]: it is not finite or has climbed by
    DIVERGED_FACTOR, or it has climbed (CLIMB_FACTOR) and so had the `previous` record at this
    load factor since the best (None: there is none)."""
    if climbed(energy, best, DIVERGED_FACTOR):
        return True
    return climbed(energy, best) and previous is not None and climbed(previous, best)
