"""The web viewer of a run still being written: `ndf-view DIR` while `ndf-sim` writes
DIR.incomplete. Shows the stage in progress (its step of total, the reported values, seconds)
and the convergence plot (`viewer.convergence`: Π and the Newton decrement per report) from the
run's progress.jsonl (`io.progress_log`), refreshed by `poll()`; `poll()` says when the run has
finished (DIR holds its result.json and the staging folder is gone), so the tool can open the
finished run (`viewer.app.RunViewer`)."""

from __future__ import annotations

import logging
import time
from pathlib import Path

from taichi_ndf.io import incomplete_path
from taichi_ndf.io.progress_log import PROGRESS_FILE, read_progress
from taichi_ndf.io.run_lock import held_by_a_live_run
from taichi_ndf.viewer.convergence import add_convergence_plot, convergence_data

__all__ = ["LiveViewer", "live_run"]

log = logging.getLogger(__name__)


def live_run(path: str | Path) -> Path | None:
    """The final directory DIR of the run `path` names (DIR or DIR.incomplete) if a live run
    is writing it (its staging folder exists and a running process holds its claim,
    `io.run_lock`), else None."""
    path = Path(path)
    final = path.with_name(path.name.removesuffix(".incomplete"))
    if incomplete_path(final).is_dir() and held_by_a_live_run(final):
        return final
    return None


def iteration_series(reports: list[dict]) -> tuple[list[float], list[float], list[float] | None]:
    """Report number, Π [J] and (where any report has it) the decrement λ² [J] of every report
    with a Π, in order (NaN λ² where a report has none)."""
    rows = [r["values"] for r in reports if "Π" in r.get("values", {}) and not r.get("done")]
    iterations = [float(k) for k in range(1, len(rows) + 1)]
    energies = [v["Π"] for v in rows]
    decrements = None
    if any("λ²" in v for v in rows):
        decrements = [v.get("λ²", float("nan")) for v in rows]
    return iterations, energies, decrements


def status_text(final: Path, reports: list[dict], seconds: float) -> str:
    """Markdown: which run, the newest report (stage, step of total, values), its age."""
    head = f"**{final.name}** — running, `{incomplete_path(final)}`"
    if not reports:
        return head + "\n\nno progress reported yet"
    last = reports[-1]
    step = f"{last['step']}" + (f" of {last['total']}" if last.get("total") else "")
    values = ", ".join(f"{k} {v:.6g}" for k, v in last.get("values", {}).items())
    state = "finished" if last.get("done") else "step " + step
    return (f"{head}\n\n{last['stage']}: {state}" + (f", {values}" if values else "")
            + f" (reported {seconds:.0f} s ago)")


class LiveViewer:
    """A viser server following the run whose final directory is `final` (see the module
    docstring); `url` and `port` as `RunViewer`'s."""

    def __init__(self, final: str | Path, *, host: str = "127.0.0.1", port: int = 8080):
        from taichi_ndf.viewer.app import require_viewer

        viser = require_viewer()
        self.final = Path(final)
        self.server = viser.ViserServer(host=host, port=port, verbose=False)
        self.port = self.server.get_port()
        self.url = f"http://{host}:{self.port}"
        self.server.gui.main_panel.dock_right()
        self.status = self.server.gui.add_markdown("")
        self.plot = None
        self.with_decrements = None
        self.reports: list[dict] = []
        self.poll()

    @property
    def progress_file(self) -> Path:
        return incomplete_path(self.final) / PROGRESS_FILE

    def finished(self) -> bool:
        return (self.final / "result.json").is_file() and not incomplete_path(self.final).exists()

    def poll(self) -> bool:
        """Read the progress file again and redraw what changed; True once the run finished."""
        if self.finished():
            self.status.content = f"**{self.final.name}** — finished; opening the run"
            return True
        try:
            reports = read_progress(self.progress_file)
        except (OSError, ValueError) as err:  # moved into place between the check and the read
            log.info("progress file not read: %s", err)
            return self.finished()
        age = time.time() - reports[-1]["time"] if reports else 0.0
        self.status.content = status_text(self.final, reports, age)
        if len(reports) == len(self.reports):
            return False
        self.reports = reports
        iterations, energies, decrements = iteration_series(reports)
        if not iterations:
            return False
        if self.plot is None or self.with_decrements != (decrements is not None):
            if self.plot is not None:
                self.plot.remove()
            self.with_decrements = decrements is not None
            self.plot = add_convergence_plot(self.server.gui, iterations, energies, decrements,
                                             title="convergence (live)")
        else:
            self.plot.data = convergence_data(iterations, energies, decrements)
        return False

    def stop(self) -> None:
        self.server.stop()
