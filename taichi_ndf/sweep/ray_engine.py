"""The Ray engine: the same runs as Ray tasks on a cluster (`ndf-sweep --ray auto|ADDRESS`).

Each run is a task of one CPU that calls `run.execute` on whichever node Ray picks; the row
comes back to this process, which writes the results table. The run directories are written
by the node that runs them, at the same path: OUT must be on a file system every node mounts
at the same place (docs/sweeps.md). ``auto`` joins the cluster this machine is part of
(``ray start`` ran here), anything else is a cluster's address (``HOST:PORT`` or
``ray://HOST:PORT``).
Ray is the optional extra ``ray``.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterable

from taichi_ndf.sweep.run import RunInterrupted, RunSpec, execute

log = logging.getLogger(__name__)

MISSING = "--ray needs Ray, which is not installed: pip install 'taichi-ndf[ray]'"


class EngineError(RuntimeError):
    """The engine cannot start (Ray missing or the cluster unreachable); one line."""


def require_ray():
    try:
        import ray
    except ImportError:
        raise EngineError(MISSING) from None
    return ray


def _remote_execute(spec: RunSpec) -> dict:
    try:
        return {"row": execute(spec)}
    except RunInterrupted:
        return {"interrupted": spec.name}


def connect(address: str) -> None:
    """ray.init for `address` (module docstring); EngineError with one line if it fails."""
    ray = require_ray()
    try:
        ray.init(address=address, log_to_driver=False, configure_logging=False)
    except (ConnectionError, RuntimeError, ValueError) as err:
        raise EngineError(f"--ray {address}: cannot connect: {str(err).splitlines()[0]}") \
            from None
    log.info("Ray cluster resources: %s", ray.cluster_resources())


def run_ray(specs: Iterable[RunSpec], address: str,
            on_row: Callable[[RunSpec, dict], None]) -> None:
    """Run every spec as a Ray task; on_row(spec, row) as each one finishes. On Ctrl-C the
    tasks are cancelled (their runs interrupted) and KeyboardInterrupt is raised."""
    ray = require_ray()
    connect(address)
    task = ray.remote(num_cpus=1, max_retries=0)(_remote_execute)
    pending = {task.remote(spec): spec for spec in specs}
    try:
        while pending:
            done, _ = ray.wait(list(pending), num_returns=1)
            for ref in done:
                spec = pending.pop(ref)
                try:
                    result = ray.get(ref)
                except ray.exceptions.RayError as err:
                    result = {"row": _lost(spec, err)}
                if "interrupted" in result:
                    raise KeyboardInterrupt
                on_row(spec, result["row"])
    except BaseException:
        for ref in pending:
            ray.cancel(ref)
        for ref in pending:
            try:
                ray.get(ref, timeout=60)
            except Exception:  # noqa: BLE001 - cancelled tasks raise; nothing to keep
                pass
        raise
    finally:
        ray.shutdown()


def _lost(spec: RunSpec, err: Exception) -> dict:
    """The row of a task Ray lost (its worker or node died): failed, with Ray's reason."""
    reason = f"Ray: {type(err).__name__}: {str(err).strip().splitlines()[0] if str(err) else ''}"
    return {"point": spec.name, **spec.parameters, "status": "failed", "reason": reason[:300],
            "seed": "" if spec.seed is None else spec.seed}
