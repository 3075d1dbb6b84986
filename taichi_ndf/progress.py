"""Progress of long computations: library code reports, the application renders.

One hook for every long loop (Adam iterations, projected-Newton iterations, material fits,
SfT frames, exports): `report(step, **values)` inside a `stage(name, total)`. The library
does no terminal output; a listener installed with `listening` decides what to show
(`taichi_ndf.cli.progress.ProgressDisplay`: a tqdm bar on a terminal, one line per finished
stage otherwise). Without a listener a report costs one list lookup; every finished stage is
also logged at INFO (`logging`), so a library user sees one line per stage with
``logging.basicConfig(level=logging.INFO)``.
"""

from __future__ import annotations

import contextlib
import logging
import time
from collections.abc import Callable, Iterable, Iterator, Sized
from dataclasses import dataclass, field
from typing import TypeVar

log = logging.getLogger(__name__)
T = TypeVar("T")


@dataclass(frozen=True)
class Progress:
    """One report: the stage it belongs to (e.g. "Newton level 1 (16 × 16 spans), load 0.5"),
    steps done in it and the most it takes (None: unknown), the values to show (Π, decrement,
    …, by name), the seconds since the stage began, how many stages enclose it, and whether
    the stage has finished."""

    stage: str
    step: int
    total: int | None
    values: dict[str, float] = field(default_factory=dict)
    elapsed: float = 0.0
    depth: int = 0  # stages open around this one
    done: bool = False


Listener = Callable[[Progress], None]
_listeners: list[Listener] = []
_stages: list[list] = []  # the open stages: [name, total, start, last step, last values]


@contextlib.contextmanager
def listening(listener: Listener) -> Iterator[None]:
    """Send every report made inside the block to `listener` too."""
    _listeners.append(listener)
    try:
        yield
    finally:
        _listeners.remove(listener)


@contextlib.contextmanager
def stage(name: str, total: int | None = None) -> Iterator[None]:
    """A stage of at most `total` steps: the reports inside belong to it; a final report
    (done) goes out when it ends, with the last step and values reported in it."""
    entry = [name, total, time.perf_counter(), 0, {}]
    _stages.append(entry)
    depth = len(_stages) - 1
    _send(Progress(name, 0, total, depth=depth))
    try:
        yield
    finally:
        _stages.remove(entry)
        finished = Progress(name, entry[3], total, entry[4], time.perf_counter() - entry[2],
                            depth=depth, done=True)
        log.info("%s", summary(finished))
        _send(finished)


def counted(items: Iterable[T], name: str, total: int | None = None) -> Iterator[T]:
    """The items of `items`, each reported as one step of a stage `name` when its turn is
    over (`total` steps, default len(items) where it has one): a loop gets its progress by
    iterating over `counted(...)` (values reported inside the loop body are kept)."""
    if total is None and isinstance(items, Sized):
        total = len(items)
    with stage(name, total):
        for step, item in enumerate(items, 1):
            yield item
            report(step, **_stages[-1][4])


def report(step: int, **values: float) -> None:
    """`step` steps of the innermost open stage are done; `values` to show (Π, λ², …). Outside
    any stage: nothing."""
    if not _stages:
        return
    entry = _stages[-1]
    entry[3], entry[4] = step, values
    if _listeners:
        _send(Progress(entry[0], step, entry[1], values, time.perf_counter() - entry[2],
                       depth=len(_stages) - 1))


def _send(progress: Progress) -> None:
    for listener in tuple(_listeners):
        listener(progress)


def summary(progress: Progress) -> str:
    """One line: "stage: N steps, name value, …, S s" (no step count where none was
    reported)."""
    parts = [f"{progress.step} step{'' if progress.step == 1 else 's'}"] if progress.step else []
    parts += [_value(k, v) for k, v in progress.values.items()]
    return f"{progress.stage}: {', '.join([*parts, f'{progress.elapsed:.1f} s'])}"


def describe(values: dict) -> str:
    """The values as "name value, …" (floats to 6 significant digits)."""
    return ", ".join(_value(k, v) for k, v in values.items())


def _value(name: str, value) -> str:
    return f"{name} {value:.6g}" if isinstance(value, float) else f"{name} {value}"
