"""Learning-rate backoff: Adam's answer to a step that is too long.

Adam moves every weight by about the learning rate per step, so a SIREN field's displacement
step is about learning rate × output_scale (docs/scenes.md, "Field output scale"). Where that
is too long for the shell's stiff directions, Π does not just fluctuate: it climbs by orders of
magnitude (flag with a 1.78 m output scale: −0.419 J at iteration 50, +141 J at 100, +4.8e5 J
at 250). At every monitor record the solver compares Π on the fixed monitor samples with the
best Π recorded at the same load factor (from the load step's start on); if Π has climbed
above it by more than CLIMB_FACTOR times the largest |Π| recorded at that load factor, the
field's parameters and Adam's moments go back to the best state and the learning rate is
halved (`Adam.lr_scale`), at most MAX_BACKOFFS times per run. Training noise moves the
monitored Π by a fraction of |Π|, so a run whose steps are short enough does not back off; a
step so long that Π climbs an order of magnitude above anything recorded is not a step a
minimiser should keep. Gentler rules (wait for a second climbed record; back off at once only
at two orders of magnitude) were measured and let Adam come back from a climb into a worse
state (docs/scenes.md, "Learning-rate backoff"). A non-finite Π or gradient between records
is the divergence guard's (`taichi_ndf.minimise.callbacks`), which stops the run.

The best state is part of the solver's `State` (a checkpoint keeps it), so a resumed run backs
off exactly as an uninterrupted one. `should_back_off`, `back_to_best` and `keep_if_best` act
on that `State` and the field it trains (`taichi_ndf.solve.solver` calls them at its records).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

# A climb above the best Π by more than this many times the largest |Π| recorded backs off.
CLIMB_FACTOR = 10.0
# The most halvings of the learning rate in one run (1/1024 of the schedule's after all).
MAX_BACKOFFS = 10


@dataclass
class BestState:
    """The lowest monitored Π at a load factor and the state that had it.

    parameters: the field's flat parameter vector; optimiser: `Adam.state_dict()`."""

    iteration: int
    load_factor: float
    energy: float  # Π on the monitor samples [J]
    parameters: torch.Tensor
    optimiser: dict

    def to_dict(self) -> dict:
        return {"iteration": self.iteration, "load_factor": self.load_factor,
                "energy": self.energy, "parameters": self.parameters,
                "optimiser": self.optimiser}

    @classmethod
    def from_dict(cls, data: dict) -> BestState:
        return cls(iteration=int(data["iteration"]), load_factor=float(data["load_factor"]),
                   energy=float(data["energy"]), parameters=data["parameters"],
                   optimiser=data["optimiser"])


def climbed(energy: float, reference: float, recorded: list[float],
            factor: float = CLIMB_FACTOR) -> bool:
    """Π [J] has climbed too far: non-finite, or above `reference` (the backoff: the best Π)
    by more than `factor` times the largest |Π| among `recorded` (the monitored Π at this
    load factor, the reference among them). The divergence guard's blow-up test is the same
    with a factor of 1000 (`callbacks.BLOW_UP_FACTOR`)."""
    if not math.isfinite(energy):
        return True
    return energy - reference > factor * max(abs(e) for e in recorded)


def should_back_off(state, load_factor: float, energy: float) -> bool:
    """Whether Π [J] on the monitor samples at `load_factor` has climbed too far (`climbed`)
    above the `state`'s best state at that load factor, with backoffs left (MAX_BACKOFFS)."""
    best = state.best
    if best is None or best.load_factor != load_factor or state.backoffs >= MAX_BACKOFFS:
        return False
    return climbed(energy, best.energy, [best.energy, *state.energies_at(load_factor)])


def back_to_best(state, field) -> None:
    """The field's parameters and Adam's moments back to `state.best`, the learning rate
    halved (`Adam.lr_scale`; the schedule goes on from the current step), the backoff
    counted."""
    best, optimiser = state.best, state.optimiser
    flat = field.get_flat()
    field.set_flat(best.parameters.to(device=flat.device, dtype=flat.dtype))
    step, scale = optimiser.step_count, optimiser.lr_scale
    optimiser.load_state_dict(best.optimiser)
    optimiser.step_count, optimiser.lr_scale = step, 0.5 * scale
    state.backoffs += 1


def keep_if_best(state, field, load_factor: float, energy: float) -> None:
    """The field's parameters and Adam's moments become `state.best` where Π [J] is finite
    and the lowest at `load_factor` (a best state at another load factor is replaced)."""
    best = state.best
    if math.isfinite(energy) and (best is None or best.load_factor != load_factor
                                  or energy < best.energy):
        state.best = BestState(iteration=state.iteration, load_factor=load_factor,
                               energy=energy, parameters=field.get_flat().detach().clone(),
                               optimiser=state.optimiser.state_dict())
