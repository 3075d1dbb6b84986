"""The local engine: at most N runs at once on this machine (`ndf-sweep --workers N`).

Each run is its own process with one thread (`run.execute`), so N workers use N cores; the
pool's threads only start them and wait. Ctrl-C interrupts the running processes (they get
SIGINT from the terminal too), waits for them and stops; their runs are redone on resume.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from concurrent.futures import FIRST_COMPLETED, ThreadPoolExecutor, wait

from taichi_ndf.sweep.run import RunInterrupted, RunSpec, execute, stop_all


def run_local(specs: Iterable[RunSpec], workers: int, on_row: Callable[[RunSpec, dict], None]
              ) -> None:
    """Run every spec with `workers` at a time; on_row(spec, row) as each one finishes (in
    this thread). Raises KeyboardInterrupt after stopping the runs when interrupted."""
    if workers < 1:
        raise ValueError(f"--workers must be >= 1, got {workers}")
    pool = ThreadPoolExecutor(max_workers=workers, thread_name_prefix="sweep-run")
    pending = {pool.submit(execute, spec): spec for spec in specs}
    try:
        while pending:
            done, _ = wait(pending, return_when=FIRST_COMPLETED)
            for future in done:
                spec = pending.pop(future)
                try:
                    row = future.result()
                except RunInterrupted:
                    raise KeyboardInterrupt from None
                on_row(spec, row)
    except BaseException:
        for future in pending:
            future.cancel()
        stop_all()
        raise
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
