"""The progress of a run as a file, so that a run can be followed while it is written.

`ProgressLog` is a `taichi_ndf.progress` listener that appends each report carrying new values
(Π, the Newton decrement λ², ‖∇Π‖, …) and each finished stage as one JSON line to the run's
``progress.jsonl``, flushed at once; `read_progress` reads such a file back while it grows (a
half-written last line is left for the next read). `ndf-sim` writes it into the run's staging
folder, where `ndf-view` plots it live (`taichi_ndf.viewer.live`), and it stays in the
finished run as the record of every report.

One line: {"time": Unix seconds, "stage": name, "step": steps done, "total": steps or null,
"depth": enclosing stages, "done": bool, "elapsed": seconds in the stage, "values": {name: float}}.
"""

from __future__ import annotations

import contextlib
import json
import os
import time
from collections.abc import Iterator
from pathlib import Path

from taichi_ndf import progress

__all__ = ["PROGRESS_FILE", "ProgressLog", "logged_progress", "read_progress"]

PROGRESS_FILE = "progress.jsonl"


class ProgressLog:
    """Appends reports to `path` (see the module docstring): a report whose values are those
    of the last line of its stage (an Adam step between two monitor evaluations) is skipped,
    so each line is a new value."""

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        self._file = open(self.path, "a", encoding="utf-8")  # noqa: SIM115 (closed in close())
        self._last: dict[str, dict] = {}

    def __call__(self, report: progress.Progress) -> None:
        values = {k: float(v) for k, v in report.values.items() if isinstance(v, int | float)}
        if not report.done and (not values or self._last.get(report.stage) == values):
            return
        self._last[report.stage] = values
        line = {"time": time.time(), "stage": report.stage, "step": report.step,
                "total": report.total, "depth": report.depth, "done": report.done,
                "elapsed": report.elapsed, "values": values}
        self._file.write(json.dumps(line, ensure_ascii=False) + "\n")
        self._file.flush()

    def close(self) -> None:
        self._file.close()


@contextlib.contextmanager
def logged_progress(path: str | os.PathLike) -> Iterator[ProgressLog]:
    """Write the progress of everything run inside the block to `path`."""
    log = ProgressLog(path)
    try:
        with progress.listening(log):
            yield log
    finally:
        log.close()


def read_progress(path: str | os.PathLike) -> list[dict]:
    """The lines of a progress file as dicts, in order; [] where there is no file yet. A last
    line without its newline (being written) is not read; ValueError names a broken line."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        return []
    lines = text.split("\n")[:-1]  # the part after the last newline is not finished
    try:
        return [json.loads(line) for line in lines if line.strip()]
    except json.JSONDecodeError as err:
        raise ValueError(f"{path} is not a progress file: {err}") from err
