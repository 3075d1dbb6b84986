"""One run of a study: the tool as a subprocess with one thread, timed, its outputs as a row.

`execute` is what every engine calls (a pool thread here, a Ray task on a cluster node): it
removes what an earlier, unfinished attempt left in the run directory, runs the command with
one CPU thread (Taichi's pool, torch, OpenMP and MKL), and returns the results row: the
point's parameters, status (ok, failed, diverged) and the one-line reason of a failure, the
outputs the job reads from the run directory, and the run's wall time, CPU time (user + system)
[s] and peak resident memory [MiB] (`os.wait4`), seed, package commit and machine.
"""

from __future__ import annotations

import ctypes
import os
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from taichi_ndf.io import incomplete_path
from taichi_ndf.sweep.jobs import JOBS
from taichi_ndf.sweep.provenance import machine, package_commit

ONE_THREAD = {"TI_CPU_MAX_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1",
              "OPENBLAS_NUM_THREADS": "1"}
_CODE_ROOT = str(Path(__file__).resolve().parents[2])  # the folder holding taichi_ndf/
_DIVERGED = re.compile(r"non-finite|diverg|\bnan\b", re.IGNORECASE)
_INTERRUPTED = (130, -signal.SIGINT, -signal.SIGTERM)


class RunInterrupted(Exception):
    """The run's process was interrupted (Ctrl-C or a stop): no result, redo it on resume."""


@dataclass(frozen=True)
class RunSpec:
    """A run to do, as plain data (it travels to a Ray worker): the point's index, name and
    parameters, the job kind, the command line, the run directory and the log file prefix."""

    index: int
    name: str
    parameters: dict
    seed: int | None
    job: str
    command: tuple[str, ...]
    run_dir: str
    log: str


_live: set[subprocess.Popen] = set()
_live_lock = threading.Lock()


def stop_all() -> None:
    """Interrupt (SIGINT) every run process this process started that is still running."""
    with _live_lock:
        for process in _live:
            if process.poll() is None:
                process.send_signal(signal.SIGINT)


try:  # looked up here: the child of a threaded process must not load libraries
    _PRCTL = ctypes.CDLL(None).prctl if sys.platform == "linux" else None
except (OSError, AttributeError):
    _PRCTL = None


def _die_with_parent() -> None:
    """In the child: be terminated when the thread that started it ends (Linux
    PR_SET_PDEATHSIG), so a killed study or Ray worker leaves no run behind writing into the
    run directory."""
    _PRCTL(1, signal.SIGTERM)


def last_line(path: Path) -> str:
    """The last non-empty line of a text file ('' if none), at most 300 characters."""
    try:
        lines = [x.strip() for x in path.read_text(errors="replace").splitlines() if x.strip()]
    except FileNotFoundError:
        return ""
    return lines[-1][:300] if lines else ""


def clear_attempt(run_dir: Path) -> None:
    """Remove what an unfinished attempt of this run left (the run directory and its
    ``.incomplete`` staging directory)."""
    for path in (run_dir, incomplete_path(run_dir)):
        if path.exists():
            shutil.rmtree(path)


def execute(spec: RunSpec) -> dict:
    """Run one point (module docstring); raises RunInterrupted if its process was stopped."""
    run_dir, log = Path(spec.run_dir), Path(spec.log)
    clear_attempt(run_dir)
    log.parent.mkdir(parents=True, exist_ok=True)
    # The tool runs the code this process runs (a Ray worker's checkout, not another copy).
    path = os.pathsep.join(filter(None, [_CODE_ROOT, os.environ.get("PYTHONPATH")]))
    env = {**os.environ, **ONE_THREAD, "PYTHONPATH": path}
    started = time.perf_counter()
    with open(f"{log}.out", "w") as out, open(f"{log}.err", "w") as err:
        process = subprocess.Popen(spec.command, stdout=out, stderr=err, env=env,
                                   preexec_fn=_die_with_parent if _PRCTL else None)
        with _live_lock:
            _live.add(process)
        try:
            _, status, usage = os.wait4(process.pid, 0)
            process.returncode = os.waitstatus_to_exitcode(status)
        except BaseException:  # Ctrl-C or a Ray cancel: stop the run, then pass it on
            process.send_signal(signal.SIGINT)
            process.wait()
            raise
        finally:
            with _live_lock:
                _live.discard(process)
    wall = time.perf_counter() - started
    code = process.returncode
    if code in _INTERRUPTED:
        raise RunInterrupted(spec.name)
    row = {"point": spec.name, **spec.parameters}
    outputs, reason = {}, ""
    if code == 0:
        try:
            outputs = JOBS[spec.job].outputs(run_dir)
        except (OSError, ValueError, KeyError, TypeError) as error:
            code, reason = 1, f"unreadable {JOBS[spec.job].result}: {error}"
    else:
        reason = last_line(Path(f"{log}.err")) or (
            f"killed by signal {-code}" if code < 0 else f"exit code {code}")
    status = "ok" if code == 0 else ("diverged" if _DIVERGED.search(reason) else "failed")
    seed = outputs.pop("seed", spec.seed)
    row.update(status=status, reason=reason, **outputs)
    row.update(seed="" if seed is None else seed, wall_s=round(wall, 3),
               cpu_s=round(usage.ru_utime + usage.ru_stime, 3),
               peak_memory_MiB=round(usage.ru_maxrss / 1024, 1), commit=package_commit(),
               machine=machine())
    return row
