"""What the application layer hooks into a solve: checkpoint writing and the divergence
guard. The solver itself does no I/O (its progress goes to `taichi_ndf.progress`).

A callback has any of `on_start(solver)`, `on_step(solver, energy, grad_norm)` (before each
Adam step), `on_iteration(solver, record)` (record: the `MonitorRecord` of this iteration or
None), `on_record(solver, energy, grad_norm, load_factor)` (Π on the monitor samples, before
the record is kept), `on_polish(solver, before, after)` (Π around an L-BFGS polish),
`on_load_step(solver, load_factor)` and `on_end(solver)`. A hook may raise to stop the solve.
"""

from __future__ import annotations

import math
from pathlib import Path

from taichi_ndf.backoff import climbed

BLOW_UP_FACTOR = 1e3


class DivergenceError(RuntimeError):
    """Training produced a non-finite energy or gradient; the last good state was kept."""


class DivergenceGuard:
    """Refuses non-finite Π or gradients and a Π far above anything seen at a load factor;
    then resets the field to its last monitored good state and raises `DivergenceError`.
    A callback: installed by the application (`taichi_ndf.simulation`, the validation
    runner); a solve without it does not stop on divergence.

    checkpoint_path: named in the error message (where the last checkpoint lies), or None."""

    def __init__(self, checkpoint_path: str | Path | None = None):
        self.checkpoint_path = checkpoint_path
        self._good = None

    def on_start(self, solver) -> None:
        self._good = solver.field.get_flat().clone()

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
        self._good = solver.field.get_flat().clone()

    @staticmethod
    def _blown_up(solver, energy: float, load_factor: float) -> bool:
        """Π far above anything seen at this load factor: a minimiser must not climb by
        orders of magnitude (1000× the largest magnitude recorded so far)."""
        seen = solver.state.energies_at(load_factor)
        return bool(seen) and climbed(energy, seen[0], seen, BLOW_UP_FACTOR)

    def fail(self, solver, energy: float, grad_norm: float):
        if self._good is not None:
            solver.field.set_flat(self._good)
        saved = self.checkpoint_path is not None and Path(self.checkpoint_path).is_file()
        where = f" (checkpoint {self.checkpoint_path})" if saved else ""
        history = solver.state.history
        last = history[-1].iteration if history else 0
        raise DivergenceError(
            f"training diverged at iteration {solver.state.iteration}: Π = {energy}, "
            f"‖∇Π‖ = {grad_norm}; the field was reset to its last good state from iteration "
            f"{last}{where}. Lower the learning rate or the load step.")


class CheckpointWriter:
    """Writes the solver's state to `path` every `solver.config.checkpoint_every` iterations
    (0: never in between) and at the end; `extra` (e.g. the scene) goes with it."""

    def __init__(self, path: str | Path, extra: dict | None = None):
        self.path = Path(path)
        self.extra = extra or {}

    def on_iteration(self, solver, record) -> None:
        every = solver.config.checkpoint_every
        if every and solver.state.iteration % every == 0:
            solver.state.save(self.path, self.extra)

    def on_end(self, solver) -> None:
        solver.state.save(self.path, self.extra)
