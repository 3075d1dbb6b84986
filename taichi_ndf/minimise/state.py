"""The state of a minimisation: everything that changes while Π is minimised.

One `State` for both solve paths, tagged by its `method`:
- "adam" (a SIREN, `taichi_ndf.solve.solver`): the field's parameters (the field itself), the
  optimiser's moments, the sampling random-number generator, the iteration and load-step
  counters, the monitor history (`MonitorRecord`) and the best monitored state of the
  learning-rate backoff (`taichi_ndf.minimise.backoff`);
- "newton" (a spline by projected Newton, `taichi_ndf.solve.spline_solver`): the field of the last
  finished grid level, the per-iteration history (`NewtonRecord`) and the finished levels'
  summaries (`LevelSummary`); no optimiser, no generator.
The model and the objective are immutable and live elsewhere, so a state saved with `save`
and read back with `restore` continues a run where it stopped (checkpoint file I/O, with the
field type and the method as tags: `taichi_ndf.minimise.checkpoint`).
"""

from __future__ import annotations

import logging
from dataclasses import asdict, dataclass, field
from pathlib import Path

import torch

from taichi_ndf.minimise.backoff import BestState
from taichi_ndf.minimise.checkpoint import CheckpointError, load_checkpoint, save_checkpoint
from taichi_ndf.minimise.newton import NewtonIteration
from taichi_ndf.problem.optim import Adam, AdamConfig

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
class NewtonRecord(NewtonIteration):
    """One projected-Newton iteration of a run with its place: its grid level and spans;
    `iteration` counts over all levels and load steps."""

    level: int = 0
    spans: tuple[int, int] = (0, 0)


@dataclass
class LevelSummary:
    """The final load step on one grid: Π [J], probes (displacement [m] by name), Newton
    iterations and seconds over all its load steps, whether every load step converged."""

    level: int
    spans: tuple[int, int]
    energy: float
    probes: dict[str, list[float]]
    iterations: int
    seconds: float
    converged: bool


METHODS = ("adam", "newton")


@dataclass
class State:
    """Field (its parameters), the optimiser (Adam's moments; None for Newton), sampling
    generator (None for Newton), counters, history (module docstring).

    iteration: Adam iterations, or Newton iterations over all levels and load steps.
    load_step: index of the load step in progress (the number of load steps once finished).
    best: the lowest monitored Π at the current load factor and its state (`backoff`).
    backoffs: learning-rate backoffs so far. levels: a Newton run's finished grid levels.
    """

    field: object
    optimiser: Adam | None = None
    generator: torch.Generator | None = None
    iteration: int = 0
    load_step: int = 0
    newton_steps: int = 0
    history: list = field(default_factory=list)  # MonitorRecord (adam) or NewtonRecord
    best: BestState | None = None
    backoffs: int = 0
    method: str = "adam"
    levels: list[LevelSummary] = field(default_factory=list)

    def __post_init__(self):
        if self.method not in METHODS:
            raise ValueError(f"method must be one of {list(METHODS)}, got {self.method!r}")

    def energies_at(self, load_factor: float) -> list[float]:
        """Π [J] of every monitor record at this load factor, in order."""
        return [h.energy for h in self.history if h.load_factor == load_factor]

    @classmethod
    def initial(cls, field, adam: AdamConfig, seed: int) -> State:
        """A fresh state: the field as given, zero Adam moments, the generator seeded."""
        return cls(field=field, optimiser=Adam(field.parameters, field.gradients, config=adam),
                   generator=torch.Generator().manual_seed(seed))

    @classmethod
    def newton(cls, field) -> State:
        """A fresh projected-Newton state on `field` (the coarsest grid's starting point)."""
        return cls(field=field, method="newton")

    def save(self, path: str | Path, extra: dict | None = None) -> None:
        """Write the state (and `extra`, e.g. the scene) to a checkpoint file."""
        values = {**(extra or {}), "method": self.method, "iteration": self.iteration,
                  "load_step": self.load_step, "newton_steps": self.newton_steps,
                  "history": [asdict(h) for h in self.history], "backoffs": self.backoffs,
                  "best": None if self.best is None else self.best.to_dict()}
        if self.generator is not None:
            values["sampling_rng"] = self.generator.get_state()
        if self.method == "newton":
            values["levels"] = [asdict(lv) for lv in self.levels]
        save_checkpoint(path, self.field, self.optimiser, extra=values)

    def restore(self, path: str | Path) -> dict:
        """Read a state written by `save` into this one (in place; a Newton state takes the
        stored field, the last finished level's grid); returns the checkpoint's extra
        dictionary. CheckpointError where the file holds the other method's state."""
        path = Path(path)
        if not path.exists():
            raise FileNotFoundError(f"no checkpoint to resume from at {path}")
        if self.method == "newton":
            return self._restore_newton(path)
        extra = load_checkpoint(path, self.field, optimiser=self.optimiser).extra
        _check_method(path, extra, self.method)
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

    def _restore_newton(self, path: Path) -> dict:
        stored = load_checkpoint(path)
        extra = stored.extra
        _check_method(path, extra, "newton")
        self.field = stored.field
        self.history = [NewtonRecord(**{**h, "spans": tuple(h["spans"])})
                        for h in extra["history"]]
        self.levels = [LevelSummary(**{**d, "spans": tuple(d["spans"])})
                       for d in extra["levels"]]
        self.iteration = len(self.history)
        self.load_step = int(extra.get("load_step", 0))
        log.info("resumed from %s after %d grid levels", path, len(self.levels))
        return extra


def _check_method(path: Path, extra: dict, method: str) -> None:
    """CheckpointError unless the checkpoint holds a state of `method` (checkpoints written
    before the tag: a Newton run's hold "levels")."""
    stored = extra.get("method", "newton" if isinstance(extra.get("levels"), list) else "adam")
    if stored != method:
        raise CheckpointError(f"{path} holds the state of a method = \"{stored}\" run, not of "
                              f"a method = \"{method}\" one; resume it with its own scene")
