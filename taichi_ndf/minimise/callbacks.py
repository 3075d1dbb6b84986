"""What the application layer hooks into a solve: checkpoint writing and the divergence
guard. The solvers themselves do no I/O (their progress goes to `taichi_ndf.progress`).

The same callbacks serve both solve paths: the Adam driver (`taichi_ndf.solve.solver.Solver`) and
the projected-Newton driver (`taichi_ndf.solve.spline_solver.solve_spline`, whose `SplineRun` is the
`solver` here). Either has `.field`, `.state` (`taichi_ndf.minimise.state.State`) and `.config`.
A callback has any of `on_start(solver)`, `on_step(solver, energy, grad_norm)` (before each
Adam step), `on_iteration(solver, record)` (after each Adam iteration, record: its
`MonitorRecord` or None; after each Newton step a load step goes on from, record None),
`on_record(solver, energy, grad_norm, load_factor)` (Π before the record is kept: Adam's
monitor samples, every Newton iteration), `on_polish(solver, before, after)` (Π around an
L-BFGS polish), `on_load_step(solver, load_factor)`, `on_level(solver)` (after each Newton
grid level), `on_interrupt(solver)` (Ctrl-C on the Newton path, whose state is whole between
two iterations), `on_resume_point(solver)` (a garment's run, `discretise.multipatch`: after
each load step, and on Ctrl-C with the last finished load step's state) and `on_end(solver)`.
A hook may raise to stop the solve.
"""

from __future__ import annotations

import math
from pathlib import Path

from taichi_ndf.minimise.backoff import climbed

BLOW_UP_FACTOR = 1e3


def call(callbacks, hook: str, *args) -> None:
    """Call `hook(*args)` on every callback that has it, in order."""
    for callback in callbacks:
        method = getattr(callback, hook, None)
        if method is not None:
            method(*args)


class DivergenceError(RuntimeError):
    """A solve produced a non-finite energy or gradient; the last good state was kept."""


class DivergenceGuard:
    """Refuses non-finite Π or gradients and a Π far above anything seen at a load factor;
    then resets the field to its last monitored good state and raises `DivergenceError`.
    A callback: installed by the application (`taichi_ndf.app.simulation`, the validation
    runner); a solve without it does not stop on divergence.

    checkpoint_path: named in the error message (where the last checkpoint lies), or None."""

    def __init__(self, checkpoint_path: str | Path | None = None):
        self.checkpoint_path = checkpoint_path
        self._good = None

    def on_start(self, solver) -> None:
        self._good = (solver.field, solver.field.get_flat().clone())

    def on_step(self, solver, energy: float, grad_norm: float) -> None:
        """Before an optimiser step: Π and ‖∇Π‖ must be finite."""
        if not (math.isfinite(energy) and math.isfinite(grad_norm)):
            self.fail(solver, energy, grad_norm)

    def on_polish(self, solver, before: float, after: float) -> None:
        """After an L-BFGS polish: Π must be finite."""
        if not math.isfinite(after):
            self.fail(solver, after, float("nan"))

    def on_record(self, solver, energy: float, grad_norm: float, load_factor: float) -> None:
        """At a monitor record: Π finite and not blown up; then the state is the good one."""
        if not math.isfinite(energy) or self._blown_up(solver, energy, load_factor):
            self.fail(solver, energy, grad_norm)
        self._good = (solver.field, solver.field.get_flat().clone())

    def on_level(self, solver) -> None:
        """After a Newton grid level (before it is checkpointed): its closing Π, evaluated
        after the last recorded iteration, must be finite."""
        energy = solver.state.levels[-1].energy
        if not math.isfinite(energy):
            self.fail(solver, energy, float("nan"))

    @staticmethod
    def _blown_up(solver, energy: float, load_factor: float) -> bool:
        """Π far above anything seen at this load factor: a minimiser must not climb by
        orders of magnitude (1000× the largest magnitude recorded so far)."""
        seen = solver.state.energies_at(load_factor)
        return bool(seen) and climbed(energy, seen[0], seen, BLOW_UP_FACTOR)

    def fail(self, solver, energy: float, grad_norm: float):
        if self._good is not None:  # the field of that time (a Newton run's: its level's)
            field, flat = self._good
            field.set_flat(flat)
        saved = self.checkpoint_path is not None and Path(self.checkpoint_path).is_file()
        where = f" (checkpoint {self.checkpoint_path})" if saved else ""
        history = solver.state.history
        last = history[-1].iteration if history else 0
        raise DivergenceError(
            f"{_what(solver)} diverged at iteration {solver.state.iteration}: Π = {energy}, "
            f"‖∇Π‖ = {grad_norm}; the field was reset to its last good state from iteration "
            f"{last}{where}. {_advice(solver)}")


def _what(solver) -> str:
    return "projected Newton" if solver.state.method == "newton" else "training"


def _advice(solver) -> str:
    if solver.state.method == "newton":
        return "Use more load steps or a finer coarsest grid."
    return "Lower the learning rate or the load step."


class CheckpointWriter:
    """Writes the solver's state to `path` every `solver.config.checkpoint_every` iterations
    (Adam's, or Newton's over all levels and load steps: the iterate inside the level; 0:
    never in between), after each Newton grid level, on Ctrl-C inside a Newton level and at
    the end, and at a garment's resume points (after each load step, on Ctrl-C); `extra`
    (e.g. the scene) goes with it."""

    def __init__(self, path: str | Path, extra: dict | None = None):
        self.path = Path(path)
        self.extra = extra or {}

    def on_iteration(self, solver, record) -> None:
        every = solver.config.checkpoint_every
        if every and solver.state.iteration % every == 0:
            solver.state.save(self.path, self.extra)

    def on_level(self, solver) -> None:
        solver.state.save(self.path, self.extra)

    def on_interrupt(self, solver) -> None:
        """Ctrl-C: a Newton run's state inside its level (its last iterate), if it has one."""
        if getattr(solver.state, "inside", None) is not None:
            solver.state.save(self.path, self.extra)

    def on_resume_point(self, solver) -> None:
        """A state a run resumes from bit for bit (a garment's after a load step)."""
        solver.state.save(self.path, self.extra)

    def on_end(self, solver) -> None:
        solver.state.save(self.path, self.extra)
