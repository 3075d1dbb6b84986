"""How the command-line tools show `taichi_ndf.progress` reports: on a terminal a tqdm bar
per stage (its steps, the reported values, elapsed time; a stage inside another draws below
it and disappears when done); otherwise one line per finished stage on stdout (stages at most
one deep: a line per grid level, load step or fit, not per equilibrium inside a fit)."""

from __future__ import annotations

import contextlib
import os
import sys
from collections.abc import Iterator

from taichi_ndf import progress


class ProgressDisplay:
    """A `taichi_ndf.progress` listener (see the module docstring). stream: where it writes
    (default: stderr where that is a terminal, else stdout); terminal: draw bars (default:
    whether the stream is a terminal)."""

    def __init__(self, prog: str, *, stream=None, terminal: bool | None = None):
        self.prog = prog
        if stream is None:  # bars on a terminal's stderr; off a terminal the stage lines are
            # part of the run's record, on stdout, so that stderr holds only warnings and the
            # one line that names a failure
            stream = sys.stderr if sys.stderr.isatty() else sys.stdout
        self.stream = stream
        self.terminal = self.stream.isatty() if terminal is None else terminal
        self.bars: dict[str, object] = {}  # stage name -> its open tqdm bar

    def __call__(self, report: progress.Progress) -> None:
        if not self.terminal:
            if report.done and report.depth <= 1:  # not each equilibrium inside a fit
                print(f"{self.prog}: {progress.summary(report)}", file=self.stream, flush=True)
            return
        bar = self.bars.get(report.stage)
        if bar is None:
            from tqdm import tqdm

            bar = tqdm(total=report.total, desc=report.stage, file=self.stream,
                       leave=report.depth == 0, position=report.depth, **_width(self.stream))
            self.bars[report.stage] = bar
        bar.n = report.step
        if report.values:
            bar.set_postfix_str(progress.describe(report.values), refresh=False)
        bar.refresh()
        if report.done:
            bar.close()
            del self.bars[report.stage]


def _width(stream) -> dict:
    """tqdm's width options: follow the terminal, or 100 columns where it reports none (a
    pseudo-terminal without a window size, where tqdm would draw nothing)."""
    try:
        columns = os.get_terminal_size(stream.fileno()).columns
    except (AttributeError, OSError, ValueError):
        columns = 0
    return {"dynamic_ncols": True} if columns else {"ncols": 100}


@contextlib.contextmanager
def shown(prog: str) -> Iterator[ProgressDisplay]:
    """Show the progress of everything run inside the block (the tools wrap their work)."""
    display = ProgressDisplay(prog)
    with progress.listening(display):
        yield display
