"""The one continuation loop: over grid levels × steps, for every solve path.

A solve of a quasistatic problem goes through its load factors in turn (load continuation)
and, for a field with a grid hierarchy, through successively refined grids (coarse to fine);
a shape-from-template reconstruction goes through its frames in turn, each warm-started from
the frame before (`inverse.sft.sequential`). `solve_over` owns that loop; a step's value
(`Step.value`) is a load factor on the forward paths, a frame index for the SfT frames and
the physical time [s] at a step's end for a dynamic run's time steps, whose count is found as
the loop goes (`next_value`: the step control, `taichi_ndf.solve.time_steps`). A solve path
gives the loop what differs (`Stages`):

- `solve(step, start)`: minimise at one step (a load step, a frame) from its start; returns
  the step's result (a spline level's `LevelSolution`, a last-layer solve's step count, a
  fitted frame, ...);
- `start(step, previous, coarser)`: where a step starts, from the result of the previous step
  on the same level (None at the run's first step on it) and the result of the same step on
  the coarser level (None on the run's first level; a spline prolongs it onto the finer
  grid). Without it the start is None: the state lives in place (a SIREN's weights);
- `enter_level(level)`: set a level up (refine the grid, its quadrature and assembly);
- `after_step(step, result)`, `after_level(level, results)`, `before_end()`: the path's
  bookkeeping (its `State`, its log lines), run before the callbacks see the state;
- `interrupted()`: Ctrl-C (KeyboardInterrupt) inside a step or its bookkeeping or callbacks:
  bring the state back to the last finished step (a garment's), before it propagates.

The callbacks (`taichi_ndf.minimise.callbacks`, called with `subject`, the object they see as
`solver`) are called here for every path: on_start before the first step, on_load_step(solver,
step value) after each step, on_level(solver) after each grid level (only where the field has
grid levels: `levels` given, or `next_level`: grids chosen as the loop goes, the adaptive
path's), on_end after the last. The per-iteration hooks (on_step,
on_record, on_iteration, on_polish) come from inside a step's minimiser. With `stage` named,
the loop also reports each finished step to a progress stage of that name
(`taichi_ndf.progress.counted`; the SfT frames); the forward paths report from inside their
minimisers instead.

A resumed run (`resume_point`) starts at the state's load step (Adam); a Newton state goes on
inside the grid level it was saved in (`State.inside`: the level's finished steps are given
as `done`, the coarser level's results as `coarser`, and the step in progress resumes its
Newton iterate, `GridLevels`), or, from a checkpoint without it (the end of the last level,
or one written before it existed), re-solves its last finished level; `first_step` applies on
every level of the run, so the finer levels of a resumed Newton run solve the same load steps
as the level it resumed on.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from taichi_ndf import progress
from taichi_ndf.minimise.callbacks import call

__all__ = ["Hook", "Stages", "Step", "resume_point", "solve_over"]


@dataclass(frozen=True)
class Step:
    """Where the loop is: the grid level (0: the coarsest; 0 for a field without levels), the
    index of the step in the loop's steps and its value: a load factor (forward solves, the
    equilibria of material fitting) or a frame index (the SfT frames)."""

    level: int
    index: int
    value: float

    @property
    def load_factor(self) -> float:
        """The value as the load factor of a load step (the forward paths' name for it)."""
        return self.value


@dataclass(frozen=True)
class Stages:
    """What a solve path gives the loop (module docstring); every hook but `solve` may be
    None."""

    solve: Callable[[Step, Any], Any]
    start: Callable[[Step, Any, Any], Any] | None = None
    enter_level: Callable[[int], None] | None = None
    after_step: Callable[[Step, Any], None] | None = None
    after_level: Callable[[int, list], None] | None = None
    before_end: Callable[[], None] | None = None
    interrupted: Callable[[], None] | None = None


def solve_over(stages: Stages, steps: Sequence[float], *, levels: int | None = None,
               first_level: int = 0, first_step: int = 0, callbacks: Sequence[Any] = (),
               subject: Any = None, stage: str | None = None, done: Sequence[Any] = (),
               coarser: list[Any] | None = None,
               next_value: Callable[[int, Any], float | None] | None = None,
               next_level: Callable[[int], bool] | None = None
               ) -> list[list[Any]]:
    """Solve every step (`steps`: their values, load factors or frame indices) from
    `first_step` on, on every grid level from `first_level` below `levels` (None: a field
    without grid levels, one pass and no on_level; there `first_step` may be len(steps): a
    finished run resumed, nothing left to solve), calling the stages and the callbacks, and
    with `stage` the progress reports (module docstring). done: the results of the first
    level's steps from `first_step` on that are already solved (a run resumed inside a
    level: they are not solved again); coarser: the results of the level below the first
    (None: none). next_value(index, the previous step's result or None): the value of step
    `index` or None (the end), for steps not known in advance (`steps` then unused: give ()),
    without `stage`. next_level(level): whether grid level `level` (from `first_level` on) is
    solved, for levels chosen as the loop goes (adaptive grids: `levels` then None; the
    on_level callbacks and `after_level` as with `levels`). Returns the results per level of
    this run, per step solved."""
    if next_level is not None and levels is not None:
        raise ValueError("solve_over: levels found as the loop goes are not counted")
    if levels is not None and not 0 <= first_level < levels:
        raise ValueError(f"first_level must be in [0, {levels}), got {first_level}")
    if next_value is not None:
        if stage is not None:
            raise ValueError("solve_over: steps found as the loop goes cannot be counted")
    else:  # one pass (no levels) may have nothing left: a finished run resumed
        last = len(steps) + (levels is None and next_level is None)
        if not 0 <= first_step < last:
            raise ValueError(f"first_step must be in [0, {last}), got {first_step}")
    call(callbacks, "on_start", subject)
    try:
        results = _levels(stages, steps, levels, first_level, first_step, callbacks, subject,
                          stage, done, coarser, next_value, next_level)
    except KeyboardInterrupt:
        if stages.interrupted is not None:
            stages.interrupted()
        raise
    if stages.before_end is not None:
        stages.before_end()
    call(callbacks, "on_end", subject)
    return results


def _levels(stages: Stages, steps, levels, first_level, first_step, callbacks, subject, stage,
            done, coarser, next_value, next_level) -> list[list[Any]]:
    """`solve_over`'s loop over the levels and their steps (its arguments)."""
    results: list[list[Any]] = []
    for level in _level_numbers(levels, first_level, next_level):
        if stages.enter_level is not None:
            stages.enter_level(level)
        coarser = results[-1] if results else coarser
        per_step: list[Any] = [] if results else list(done)
        for step in _steps(level, steps, first_step, per_step, next_value, stage):
            start = None if stages.start is None else stages.start(
                step, per_step[-1] if per_step else None,
                None if coarser is None else coarser[len(per_step)])
            result = stages.solve(step, start)
            per_step.append(result)
            if stages.after_step is not None:
                stages.after_step(step, result)
            call(callbacks, "on_load_step", subject, step.value)
        results.append(per_step)
        if levels is not None or next_level is not None:
            if stages.after_level is not None:
                stages.after_level(level, per_step)
            call(callbacks, "on_level", subject)
    return results


def _level_numbers(levels: int | None, first_level: int, next_level):
    """The levels from `first_level` on: below `levels`, one (None), or while next_level."""
    if next_level is None:
        yield from range(first_level, first_level + 1 if levels is None else levels)
        return
    level = first_level
    while next_level(level):
        yield level
        level += 1


def _steps(level: int, steps: Sequence[float], first_step: int, per_step: list, next_value,
           stage: str | None):
    """The level's steps (`Step`) from `first_step` + the steps already in `per_step`."""
    index = first_step + len(per_step)
    if next_value is None:
        indices = range(index, len(steps))
        for i in indices if stage is None else progress.counted(indices, stage):
            yield Step(level, i, steps[i])
        return
    while (value := next_value(index, per_step[-1] if per_step else None)) is not None:
        yield Step(level, index, value)
        index += 1


def resume_point(state, load_steps: int) -> tuple[int, int]:
    """(first level, first load step) of a run from `state` (`taichi_ndf.minimise.state.State`) over
    `load_steps` load steps: an Adam state goes on at its load step (a finished one re-runs its
    last); a Newton state inside a grid level goes on there (`State.inside`: its level and its
    run's first load step), one with finished levels re-solves its last level at the last
    load step (and refines from there), a fresh one starts at (0, 0)."""
    if state.method == "newton" and getattr(state, "inside", None) is not None:
        return state.inside.level, state.inside.first_step
    if state.method == "newton":
        return (len(state.levels) - 1, load_steps - 1) if state.levels else (0, 0)
    return 0, min(state.load_step, load_steps - 1)


class Hook:
    """A plain function as a callback, called after the callbacks before it: `Hook(
    "on_load_step", f)` calls f(load_factor) where the loop calls on_load_step(solver,
    load_factor) (the solver left out)."""

    def __init__(self, name: str, function: Callable[..., None]):
        setattr(self, name, lambda _solver, *args: function(*args))
