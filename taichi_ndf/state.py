"""The state of a minimisation: everything that changes while Π is minimised.

A `State` holds the field's parameters (the field itself), the optimiser's moments, the
sampling random-number generator, the iteration and load-step counters, the convergence
history and the best monitored state of the learning-rate backoff (`taichi_ndf.backoff`).
The model and the objective are immutable and live elsewhere, so a state saved with `save`
and read back with `restore` continues a run exactly where it stopped (checkpoint file I/O:
`taichi_ndf.checkpoint`).
"""

from __future__ import annotations

import logging
from dataclasses import asdict, dataclass, field
from pathlib import Path

import torch

from taichi_ndf.backoff import BestState
from taichi_ndf.checkpoint import load_checkpoint, save_checkpoint
from taichi_ndf.optim import Adam, AdamConfig

log = logging.getLogger(__name__)


@dataclass
class MonitorRecord:
    """One row of the convergence history."""

    iteration: int  # counted over all load steps
    load_factor: float
    energy: float  # Π on the monitor samples [J]
    grad_norm: float  # ‖∂Π/∂weights‖ of the last training step
    learning_rate: float
    probes: dict[str, list[float]]  # displacement [m] at each probe
    wall_time: float  # seconds since the start of this run


@dataclass
class State:
    """Field (its parameters), Adam (its moments), sampling generator, counters, history.

    load_step: index of the load step in progress (the number of load steps once finished).
    best: the lowest monitored Π at the current load factor and its state (`backoff`).
    backoffs: learning-rate backoffs so far.
    """

    field: object
    optimiser: Adam
    generator: torch.Generator
    iteration: int = 0
    load_step: int = 0
    newton_steps: int = 0
    history: list[MonitorRecord] = field(default_factory=list)
    best: BestState | None = None
    backoffs: int = 0

    def energies_at(self, load_factor: float) -> list[float]:
        """Π [J] of every monitor record at this load factor, in order."""
        return [h.energy for h in self.history if h.load_factor == load_factor]

    @classmethod
    def initial(cls, field, adam: AdamConfig, seed: int) -> State:
        """A fresh state: the field as given, zero Adam moments, the generator seeded."""
        return cls(field=field, optimiser=Adam(field.parameters, field.gradients, config=adam),
                   generator=torch.Generator().manual_seed(seed))

    def save(self, path: str | Path, extra: dict | None = None) -> None:
        """Write the state (and `extra`, e.g. the scene) to a checkpoint file."""
        save_checkpoint(path, self.field, self.optimiser, extra={
            **(extra or {}), "iteration": self.iteration, "load_step": self.load_step,
            "newton_steps": self.newton_steps, "history": [asdict(h) for h in self.history],
            "sampling_rng": self.generator.get_state(), "backoffs": self.backoffs,
            "best": None if self.best is None else self.best.to_dict()})

    def restore(self, path: str | Path) -> dict:
        """Read a state written by `save` into this one (in place); returns the checkpoint's
        extra dictionary."""
        path = Path(path)
        if not path.exists():
            raise FileNotFoundError(f"no checkpoint to resume from at {path}")
        extra = load_checkpoint(path, self.field, optimiser=self.optimiser).extra
        self.iteration = int(extra["iteration"])
        self.load_step = int(extra["load_step"])
        self.newton_steps = int(extra.get("newton_steps", 0))  # absent in older checkpoints
        self.history = [MonitorRecord(**h) for h in extra["history"]]
        if "sampling_rng" in extra:  # absent in checkpoints written before it was kept
            self.generator.set_state(extra["sampling_rng"])
        self.backoffs = int(extra.get("backoffs", 0))  # absent before the backoff existed
        best = extra.get("best")
        self.best = None if best is None else BestState.from_dict(best)
        log.info("resumed from %s at iteration %d", path, self.iteration)
        return extra
