"""Where the memory of a spline Newton solve goes (issue 28): resident memory around each stage
and the largest live arrays at chosen stages, one in-process run of `ndf-validate`.

    python benchmarks/memory_stages.py [--case pinched_cylinder] [--level 3] [--out DIR]

The case is the FE peer's level scene (`fe_peer.py`: a cubic spline on the grid rule's spans ×
2^(level − 1), `--field spline --quick --precision f64`), run in this process with the named
functions wrapped. Per call of a stage: RSS in and out (MiB) and the peak during it (the
kernel's high-water mark, reset at the stage's start through /proc/self/clear_refs: exact, no
sampling; Linux only). At the stages marked `snapshot` the largest live arrays (torch tensors
by storage, scipy sparse matrices' arrays, numpy arrays held in an object's attributes) are
listed, largest first. A wrapped name missing in this tree (another commit) is skipped.
Consecutive calls of one stage (the per-chunk blocks, `PointBlocks`) are shown as one row.
"""

from __future__ import annotations

import argparse
import gc
import importlib
import os
import resource
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent))
from fe_peer import CASES, ROOT, spline_scene  # noqa: E402
from provenance import commit  # noqa: E402

# (module, attribute path, label, snapshot of the largest arrays at the stage's end)
STAGES = [
    ("taichi_ndf.minimise.linearisation", "local_basis_at", "local_basis_at", False),
    ("taichi_ndf.minimise.assembly", "Assembly.__init__", "Assembly.__init__", True),
    ("taichi_ndf.minimise.assembly", "Assembly.at_load", "Assembly.at_load", True),
    ("taichi_ndf.minimise.newton", "point_blocks", "point blocks", True),
    ("taichi_ndf.minimise.point_blocks", "PointBlocks.__call__", "blocks of a chunk", False),
    ("taichi_ndf.minimise.newton", "project_psd", "project_psd", False),
    ("taichi_ndf.minimise.linearisation", "SplineLinearisation.hessian", "assembly of K", True),
    ("taichi_ndf.minimise.linearisation", "SplineLinearisation.solve", "solve", True),
]
MIB = 2 ** 20


def _status(key: str) -> float:
    """VmRSS or VmHWM of this process [MiB]."""
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith(key):
                return int(line.split()[1]) / 1024
    raise KeyError(key)


class Recorder:
    """Wraps functions: RSS in/out and the peak during each call (nested calls fold their
    peaks into the enclosing ones)."""

    def __init__(self):
        self.rows: list[dict] = []
        self.open: list[dict] = []
        self.snapshots: list[tuple[str, list[tuple[str, float]]]] = []

    def _reset_peak(self):
        peak = _status("VmHWM")
        for row in self.open:
            row["peak"] = max(row["peak"], peak)
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")

    def wrap(self, owner, name: str, label: str, snapshot: bool):
        original = getattr(owner, name)

        def wrapped(*args, **kwargs):
            row = {"stage": label, "in": _status("VmRSS"), "peak": 0.0,
                   "cpu": time.process_time()}
            self._reset_peak()
            self.open.append(row)
            try:
                return original(*args, **kwargs)
            finally:
                self.open.pop()
                row["peak"] = max(row["peak"], _status("VmHWM"))
                for outer in self.open:
                    outer["peak"] = max(outer["peak"], row["peak"])
                row["out"] = _status("VmRSS")
                row["cpu"] = time.process_time() - row["cpu"]
                self.rows.append(row)
                if snapshot and len([r for r in self.rows if r["stage"] == label]) <= 2:
                    self.snapshots.append((f"{label} (call {len(self.rows)})", largest()))

        setattr(owner, name, wrapped)


def largest(count: int = 12) -> list[tuple[str, float]]:
    """The largest live arrays [MiB]: torch tensors by storage (views of one storage once),
    the arrays of scipy sparse matrices, numpy arrays in objects' attributes."""
    import scipy.sparse as sp
    import torch

    seen: dict[int, tuple[str, float]] = {}
    for obj in gc.get_objects():
        try:
            if isinstance(obj, torch.Tensor):
                storage = obj.untyped_storage()
                key = storage.data_ptr()
                size = storage.nbytes() / MIB
                if size > 1 and (key not in seen or seen[key][1] < size):
                    seen[key] = (f"tensor {tuple(obj.shape)} {obj.dtype}".replace("torch.", ""),
                                 size)
            elif isinstance(obj, sp.spmatrix | sp.sparray):
                size = sum(a.nbytes for a in (obj.data, obj.indices, obj.indptr)
                           if isinstance(a, np.ndarray)) / MIB if hasattr(obj, "indptr") else 0
                if size > 1:
                    seen[id(obj)] = (f"sparse {obj.shape} nnz {obj.nnz}", size)
            elif hasattr(obj, "__dict__") and not isinstance(obj, type):
                for attr, value in vars(obj).items():
                    if isinstance(value, np.ndarray) and value.nbytes > MIB:
                        base = value if value.base is None else value.base
                        if isinstance(base, np.ndarray):
                            seen[id(base)] = (f"ndarray {type(obj).__name__}.{attr} "
                                              f"{value.shape} {value.dtype}",
                                              base.nbytes / MIB)
        except (ReferenceError, RuntimeError, TypeError):
            continue
    return sorted(seen.values(), key=lambda item: -item[1])[:count]


def merged(rows: list[dict]) -> list[dict]:
    """Consecutive calls of one stage (the blocks of each chunk) as one row "stage × n": RSS
    in of the first, out of the last, the highest peak, the CPU summed."""
    out: list[dict] = []
    for row in rows:
        last = out[-1] if out else None
        if last is not None and last["name"] == row["stage"]:
            last["count"] += 1
            last.update(out=row["out"], peak=max(last["peak"], row["peak"]),
                        cpu=last["cpu"] + row["cpu"], stage=f"{row['stage']} × {last['count']}")
        else:
            out.append(dict(row, name=row["stage"], count=1))
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--case", default="cylinder", choices=list(CASES))
    p.add_argument("--level", type=int, default=3)
    p.add_argument("--out", type=Path, default=None, help="keep the run's files here")
    args = p.parse_args(argv)
    case = CASES[args.case]
    recorder = Recorder()
    for module, path, label, snapshot in STAGES:
        owner = importlib.import_module(module)
        *parents, name = path.split(".")
        for parent in parents:
            owner = getattr(owner, parent, None)
        if owner is None or not hasattr(owner, name):
            print(f"(skipped: {module}.{path} not in this tree)")
            continue
        recorder.wrap(owner, name, label, snapshot)
    from taichi_ndf.cli import validate

    work = args.out or Path(tempfile.mkdtemp(prefix="memory_stages_"))
    work.mkdir(parents=True, exist_ok=True)
    spans = (case.spans[0] * 2 ** (args.level - 1), case.spans[1] * 2 ** (args.level - 1))
    src = ROOT / "validation" / "cases" / f"{case.case_file}.toml"
    import tomllib

    scene_rel = tomllib.loads(src.read_text())["scene"]
    scene = spline_scene((src.parent / scene_rel).resolve(), spans, work / "scene.toml")
    case_path = work / "case.toml"
    case_path.write_text(src.read_text().replace(f'"{scene_rel}"', f'"{scene}"'))
    load = os.getloadavg()
    print(f"commit {commit()}, {case.case_file} level {args.level} ({spans[0]} × {spans[1]} "
          f"spans), load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f} at start")
    start = time.process_time()
    rc = validate.main([str(case_path), "--field", "spline", "--quick", "--precision", "f64",
                        "--out", str(work / "out")])
    usage = resource.getrusage(resource.RUSAGE_SELF)
    print(f"rc {rc}; CPU {time.process_time() - start:.2f} s in the run (user "
          f"{usage.ru_utime:.2f} s, sys {usage.ru_stime:.2f} s in the process); peak RSS "
          f"{usage.ru_maxrss / 1024:.0f} MiB; load average {os.getloadavg()[0]:.2f} at end\n")
    print("| stage | RSS in MiB | RSS out MiB | peak during MiB | CPU s |")
    print("|---|---|---|---|---|")
    for row in merged(recorder.rows):
        print(f"| {row['stage']} | {row['in']:.0f} | {row['out']:.0f} | {row['peak']:.0f} | "
              f"{row['cpu']:.2f} |")
    for label, items in recorder.snapshots:
        print(f"\nLargest live arrays at the end of {label}:\n")
        print("| array | MiB |")
        print("|---|---|")
        for what, size in items:
            print(f"| {what} | {size:.0f} |")
    return 0 if rc == 0 else 1


if __name__ == "__main__":
    raise SystemExit(main())
