"""Behaviour kept (issue 26): one before/after pair of benchmarks/behaviour_kept.sh compared
load step by load step and Newton iteration by iteration.

Per load factor: the load step's closing Π of each run (result.json's trajectory: the last
Newton record at that load factor, as ndf-sim reports it), |ΔΠ|/|Π|, the Newton iterations of
each, and the largest vertex distance [m] between the two runs' trajectory meshes
(trajectory/step_NNN.obj). Then the first Newton iteration (load factor, index within the load
step) where the two runs' Π differ by more than --tolerance relative: "where the runs part".
A run that did not finish (stopped by the CPU cap, no result.json) is read from its -v log
(the "Newton k at λ=t: Π v J" lines, Π to 12 digits; load factors to 3 digits in both), so
two capped runs compare as far as both got.

    python benchmarks/behaviour_kept_steps.py WORK SCENE_FIELD [--tolerance 1e-6]
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path

import numpy as np

NEWTON_LINE = re.compile(r"Newton +(\d+) at λ=([0-9.e+-]+): Π ([0-9.e+-]+) J")


def records(out: Path, name: str) -> tuple[list[tuple[float, int, float]], str]:
    """(load factor, iteration within its load step, Π [J]) of every Newton iteration of one
    run, from result.json's history when the run finished, else from its log; and the source."""
    result = out / name / "result.json"
    if result.is_file():
        history = json.loads(result.read_text())["history"]
        rows, counts = [], {}
        for h in history:
            t = float(f"{h['load_factor']:.3g}")  # as the log prints it (the two sources meet)
            rows.append((t, counts.get(t, 0), h["energy"]))
            counts[t] = counts.get(t, 0) + 1
        return rows, "result.json"
    log = (out / f"{name}.log").read_text()
    return [(float(t), int(k), float(v)) for k, t, v in NEWTON_LINE.findall(log)], "log"


def vertices(path: Path) -> np.ndarray | None:
    """The vertex positions (V, 3) of an OBJ file, None when it is missing."""
    if not path.is_file():
        return None
    return np.array([[float(x) for x in line.split()[1:4]]
                     for line in path.read_text().splitlines() if line.startswith("v ")])


def compare(work: Path, name: str, tolerance: float) -> None:
    out = work / "out"
    runs = {tree: records(out, f"{name}_{tree}") for tree in ("before", "after")}
    for tree, (rows, source) in runs.items():
        print(f"{tree}: {len(rows)} Newton iterations read from {source}")
    factors = sorted({t for rows, _ in runs.values() for t, _, _ in rows})
    print("\n| load step | load factor | Π before [J] | Π after [J] | |ΔΠ|/|Π| | "
          "iterations before / after | max vertex distance [m] |")
    print("|---|---|---|---|---|---|---|")
    for index, t in enumerate(factors):
        last = {tree: [v for f, _, v in rows if f == t] for tree, (rows, _) in runs.items()}
        b, a = last["before"], last["after"]
        rel = (f"{abs(a[-1] - b[-1]) / abs(b[-1]):.1e}" if a and b and a[-1] != b[-1]
               else "identical" if a and b else "")
        meshes = [vertices(out / f"{name}_{tree}" / f"trajectory/step_{index:03d}.obj")
                  for tree in ("before", "after")]
        distance = ("" if any(m is None for m in meshes) or meshes[0].shape != meshes[1].shape
                    else f"{np.linalg.norm(meshes[0] - meshes[1], axis=1).max():.2e}")
        closing = [repr(x[-1]) if x else "—" for x in (b, a)]
        print(f"| {index} | {t:.6g} | {closing[0]} | {closing[1]} | {rel} | "
              f"{len(b)} / {len(a)} | {distance} |")
    before = {(t, k): v for t, k, v in runs["before"][0]}
    after = {(t, k): v for t, k, v in runs["after"][0]}
    common = [key for key, _ in sorted(before.items()) if key in after]
    worst = 0.0
    for t, k in common:
        rel = abs(after[(t, k)] - before[(t, k)]) / max(abs(before[(t, k)]), 1e-300)
        if rel > tolerance:
            print(f"\nthe runs part at Newton {k} of load factor {t:.6g}: Π {before[(t, k)]!r} "
                  f"before, {after[(t, k)]!r} after ({rel:.1e} relative); up to there the "
                  f"largest difference was {worst:.1e} relative")
            return
        worst = max(worst, rel)
    print(f"\n{len(common)} Newton iterations in both: Π within {tolerance:g} relative at every "
          f"one (largest {worst:.1e})")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("work", type=Path, help="the folder with out/ (behaviour_kept.sh's WORK)")
    parser.add_argument("name", help="SCENE_FIELD, e.g. sleeve_twist_path_spline")
    parser.add_argument("--tolerance", type=float, default=1e-6,
                        help="relative difference of Π at which the runs part (default 1e-6)")
    args = parser.parse_args()
    if not all((args.work / "out" / f"{args.name}_{tree}.log").is_file()
               for tree in ("before", "after")):
        print(f"behaviour_kept_steps.py: error: no {args.name}_before.log and _after.log in "
              f"{args.work / 'out'}", file=sys.stderr)
        sys.exit(2)
    compare(args.work, args.name, args.tolerance)
