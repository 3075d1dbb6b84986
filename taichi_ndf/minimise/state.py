"""The state of a minimisation: everything that changes while Π is minimised.

One `State` for both solve paths, tagged by its `method`:
- "adam" (a SIREN, `taichi_ndf.solve.solver`): the field's parameters (the field itself), the
  optimiser's moments, the sampling random-number generator, the iteration and load-step
  counters, the monitor history (`MonitorRecord`) and the best monitored state of the
  learning-rate backoff (`taichi_ndf.minimise.backoff`);
- "newton" (a spline by projected Newton, `taichi_ndf.solve.spline_solver`): the field of the last
  finished grid level, the per-iteration history (`NewtonRecord`), the finished levels'
  summaries (`LevelSummary`) and, inside a grid level, where in it the run is (`InsideLevel`:
  the level's finished load steps, the coarser level's solutions it starts from, Newton's
  iterate of the load step in progress); no optimiser, no generator. A garment's run
  (several spline patches, `taichi_ndf.discretise.multipatch`) is one too: its field the
  panels' (`PanelFields`), its history the Newton iterations (`NewtonIteration`, no grid
  level), `load_step` the finished load steps and `steps` their summaries.
The model and the objective are immutable and live elsewhere, so a state saved with `save`
and read back with `restore` continues a run where it stopped (checkpoint file I/O, with the
field type and the method as tags: `taichi_ndf.minimise.checkpoint`).
"""

from __future__ import annotations

import logging
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch

from taichi_ndf.minimise.backoff import BestState
from taichi_ndf.minimise.checkpoint import CheckpointError, load_checkpoint, save_checkpoint
from taichi_ndf.minimise.newton_state import NewtonIterate, NewtonIteration
from taichi_ndf.minimise.refinement import LevelSolution
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
    iterations and seconds over all its load steps, whether every load step converged, and
    the probes' solve errors per component [m] by name (`LevelSolution.probe_errors`; None:
    not measured)."""

    level: int
    spans: tuple[int, int]
    energy: float
    probes: dict[str, list[float]]
    iterations: int
    seconds: float
    converged: bool
    probe_errors: dict[str, list[float]] | None = None

    @classmethod
    def of(cls, level: int, solutions: list[LevelSolution], seconds: float) -> LevelSummary:
        """A level's summary from its load steps' solutions (the last at the final load)."""
        last = solutions[-1]
        return cls(level, last.spans, last.energy, last.probe_lists(),
                   sum(len(s.history) for s in solutions), seconds,
                   all(s.converged for s in solutions), last.probe_error_lists())


def load_step_records(solutions: list[LevelSolution]) -> list[dict]:
    """Per load step of a level: its load factor, Π [J], probes [m] and whether Newton
    converged, as plain values (result.json's `load_steps`)."""
    return [{"load_factor": s.load_factor, "energy": s.energy, "probes": s.probe_lists(),
             "converged": s.converged} for s in solutions]


@dataclass
class InsideLevel:
    """Where a Newton run is inside a grid level (`taichi_ndf.solve.spline_solver`): enough to go
    on bit for bit (`continuation.solve_over`'s done and coarser, `GridLevels`' resume).

    level: the grid level (its grid: the last finished level's refined, or the first grid);
    first_step: the run's first load step on every level; done: this level's finished load
    steps; coarser: the coarser level's solutions (None on the run's first level); step: the
    load step in progress with Newton's `iterate` (None: the next load step starts afresh);
    records: how many of the state's history records precede it (an interrupt between a
    record and its iterate drops that record); contact: a run with obstacles' contact state
    (`NewtonContact.to_dict`: check points, κ, the round in progress; plain values)."""

    level: int
    first_step: int
    done: list[LevelSolution]
    coarser: list[LevelSolution] | None
    records: int
    step: int | None = None
    iterate: NewtonIterate | None = None
    contact: dict | None = None

    def fits(self, load_steps: tuple[float, ...]) -> bool:
        """Whether the run went over these load steps (its finished and coarser solutions
        stand at the load steps from `first_step` on)."""
        ahead = list(load_steps[self.first_step:])
        return (self.first_step < len(load_steps)
                and [s.load_factor for s in self.done] == ahead[:len(self.done)]
                and (self.coarser is None or [s.load_factor for s in self.coarser] == ahead))

    def to_dict(self) -> dict:
        return {"level": self.level, "first_step": self.first_step, "records": self.records,
                "done": [_solution_dict(s) for s in self.done],
                "coarser": None if self.coarser is None else [
                    _solution_dict(s, history=False) for s in self.coarser],
                "step": self.step,
                "iterate": None if self.iterate is None else self.iterate.to_dict(),
                "contact": self.contact}

    @classmethod
    def from_dict(cls, values: dict) -> InsideLevel:
        coarser = values["coarser"]
        iterate = values["iterate"]
        return cls(int(values["level"]), int(values["first_step"]),
                   [_solution(s) for s in values["done"]],
                   None if coarser is None else [_solution(s) for s in coarser],
                   int(values["records"]), values["step"],
                   None if iterate is None else NewtonIterate.from_dict(iterate),
                   values.get("contact"))  # absent before contact runs resumed inside


def _solution_dict(solution: LevelSolution, history: bool = True) -> dict:
    """A `LevelSolution` as plain values (history: its iterations, else none)."""
    values = asdict(solution)
    values["coefficients"] = solution.coefficients
    values["probes"] = solution.probe_lists()
    values["probe_errors"] = solution.probe_error_lists()
    values["history"] = values["history"] if history else []
    return values


def _solution(values: dict) -> LevelSolution:
    errors = values.get("probe_errors")
    return LevelSolution(**{**values, "spans": tuple(values["spans"]),
                            "probes": {k: np.array(v) for k, v in values["probes"].items()},
                            "probe_errors": None if errors is None else {
                                k: np.array(v) for k, v in errors.items()},
                            "history": [NewtonIteration(**h) for h in values["history"]]})


METHODS = ("adam", "newton")


@dataclass
class State:
    """Field (its parameters), the optimiser (Adam's moments; None for Newton), sampling
    generator (None for Newton), counters, history (module docstring).

    iteration: Adam iterations, or Newton iterations over all levels and load steps.
    load_step: index of the load step in progress (the number of load steps once finished).
    best: the lowest monitored Π at the current load factor and its state (`backoff`).
    backoffs: learning-rate backoffs so far. levels: a Newton run's finished grid levels.
    inside: where a Newton run is inside a grid level (None: at the end of its last level).
    steps: a garment's finished load steps (load factor, Π [J], Newton iterations,
    converged), in order; empty otherwise.
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
    inside: InsideLevel | None = None
    steps: list[dict] = field(default_factory=list)

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
        """Write the state (and `extra`, e.g. the scene) to a checkpoint file; inside a grid
        level, the history up to the level's iterate."""
        history = self.history if self.inside is None else self.history[:self.inside.records]
        values = {**(extra or {}), "method": self.method, "iteration": len(history)
                  if self.method == "newton" else self.iteration,
                  "load_step": self.load_step, "newton_steps": self.newton_steps,
                  "history": [asdict(h) for h in history], "backoffs": self.backoffs,
                  "best": None if self.best is None else self.best.to_dict()}
        if self.generator is not None:
            values["sampling_rng"] = self.generator.get_state()
        if self.method == "newton":
            values["levels"] = [asdict(lv) for lv in self.levels]
            values["inside"] = None if self.inside is None else self.inside.to_dict()
        if self.steps:
            values["steps"] = self.steps
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
        self.history = [NewtonRecord(**{**h, "spans": tuple(h["spans"])}) if "spans" in h
                        else NewtonIteration(**h)  # a garment's: no grid level
                        for h in extra["history"]]
        self.levels = [LevelSummary(**{**d, "spans": tuple(d["spans"])})
                       for d in extra["levels"]]
        self.iteration = len(self.history)
        self.load_step = int(extra.get("load_step", 0))
        self.steps = list(extra.get("steps", []))
        inside = extra.get("inside")  # absent before checkpoints inside a level
        self.inside = None if inside is None else InsideLevel.from_dict(inside)
        where = "" if self.inside is None else (
            f", inside level {self.inside.level} at load step "
            f"{self.inside.first_step + len(self.inside.done)}")
        log.info("resumed from %s after %d grid levels%s", path, len(self.levels), where)
        return extra


def _check_method(path: Path, extra: dict, method: str) -> None:
    """CheckpointError unless the checkpoint holds a state of `method` (checkpoints written
    before the tag: a Newton run's hold "levels")."""
    stored = extra.get("method", "newton" if isinstance(extra.get("levels"), list) else "adam")
    if stored != method:
        raise CheckpointError(f"{path} holds the state of a method = \"{stored}\" run, not of "
                              f"a method = \"{method}\" one; resume it with its own scene")
