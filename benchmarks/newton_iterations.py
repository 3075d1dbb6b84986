"""Where a spline run's Newton iterations went, per grid level and load step (issue 28).

Reads the per-iteration history that `ndf-sim --field spline` (or `ndf-validate`'s spline path)
writes into result.json (`history`: one record per Newton iteration with its level, spans, load
factor, Π before the step, decrement λ², step length α, damping μ, projected blocks and the
seconds of its parts) and tabulates, for every (level, load step):

- iterations; of their steps: full (α = 1), shortened by the line search (0 < α < 1),
  lengthened (α > 1), none (α = 0: the iteration that stopped, or a failed line search);
- the Newton phases: iterations on a projected K (projected blocks > 0: the exact K was not
  definite), damped (μ > 0), in the endgame (λ²/2 ≤ `--floor` × |Π|: below the rounding floor);
- iterations until Π was within 1e-3, 1e-4 and 1e-5 (relative) of the load step's last Π;
- the model's share: the median, over the iterations that took a step, of λ²/2 / (Π − Π_last),
  the fall of Π the iteration's quadratic model predicts for its full step against what was
  still to fall to the load step's last Π (about 1 in Newton's quadratic range, where λ²/2
  estimates Π − Π*; well below 1 in a linearly converging tail, where each step's model sees
  only a share of the way; Π_last is Newton's stop, not Π*, so the last iterations read high);
- Π at the first and the last iteration, and the seconds of the Newton parts (wall clock, as
  recorded: energy, Hessian blocks, assembly, solve).

    python benchmarks/newton_iterations.py RUN/result.json [--floor 1e-8]

Bad input (no such file, no Newton history in it): exit code 2 and one line.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections import OrderedDict
from pathlib import Path

NEAR = (1e-3, 1e-4, 1e-5)  # relative distances to the step's last Π counted in the table

HEADER = ("| level | spans | load | iterations | α = 1 / < 1 / > 1 / 0 | projected | damped | "
          "endgame | to 1e-3 / 1e-4 / 1e-5 of last Π | model's share | Π first → last [J] | "
          "Newton s |")


def groups(history: list[dict]) -> OrderedDict:
    """The records of each (level, spans, load factor), in the run's order."""
    out: OrderedDict = OrderedDict()
    for record in history:
        key = (record["level"], tuple(record["spans"]), record["load_factor"])
        out.setdefault(key, []).append(record)
    return out


def iterations_until(records: list[dict], relative: float) -> int:
    """How many iterations came before the first whose Π is within `relative` × |last Π| of
    the last iteration's Π (len(records) where none is)."""
    last = records[-1]["energy"]
    for index, record in enumerate(records):
        if abs(record["energy"] - last) <= relative * abs(last):
            return index
    return len(records)


def model_share(records: list[dict]) -> float:
    """The median of λ²/2 / (Π − Π_last) over the records that took a step (α > 0) with a
    positive decrement and Π above the last record's (module docstring); nan where none."""
    last = records[-1]["energy"]
    shares = sorted(0.5 * r["decrement"] / (r["energy"] - last) for r in records
                    if r["step_length"] > 0 and r["decrement"] > 0 and r["energy"] > last)
    if not shares:
        return math.nan
    middle = len(shares) // 2
    return shares[middle] if len(shares) % 2 else 0.5 * (shares[middle - 1] + shares[middle])


def summary(records: list[dict], floor: float) -> dict:
    """The counts of one load step on one level (module docstring)."""
    alphas = [r["step_length"] for r in records]
    return {
        "iterations": len(records),
        "full": sum(a == 1.0 for a in alphas),
        "shortened": sum(0.0 < a < 1.0 for a in alphas),
        "lengthened": sum(a > 1.0 for a in alphas),
        "none": sum(a == 0.0 for a in alphas),
        "projected": sum(r["projected_blocks"] > 0 for r in records),
        "damped": sum(r["damping"] > 0 for r in records),
        "endgame": sum(0.5 * abs(r["decrement"]) <= floor * abs(r["energy"]) for r in records),
        "until": [iterations_until(records, near) for near in NEAR],
        "share": model_share(records),
        "first": records[0]["energy"],
        "last": records[-1]["energy"],
        "seconds": sum(r["time_energy"] + r["time_hessian"] + r["time_assembly"]
                       + r["time_solve"] for r in records),
    }


def table(history: list[dict], floor: float) -> list[str]:
    """The markdown table: a row per (level, load step), then a row per level's totals."""
    rows = [HEADER, "|" + "---|" * HEADER.count(" | ") + "---|"]
    per_level: OrderedDict = OrderedDict()
    for (level, spans, load), records in groups(history).items():
        s = summary(records, floor)
        per_level.setdefault((level, spans), []).append(s)
        rows.append(
            f"| {level} | {spans[0]} × {spans[1]} | {load:g} | {s['iterations']} | "
            f"{s['full']} / {s['shortened']} / {s['lengthened']} / {s['none']} | "
            f"{s['projected']} | {s['damped']} | {s['endgame']} | "
            f"{' / '.join(str(n) for n in s['until'])} | {s['share']:.3g} | "
            f"{s['first']:.8g} → {s['last']:.10g} | {s['seconds']:.2f} |")
    for (level, spans), steps in per_level.items():
        total = {k: sum(s[k] for s in steps) for k in (
            "iterations", "full", "shortened", "lengthened", "none", "projected", "damped",
            "endgame", "seconds")}
        rows.append(
            f"| {level} | {spans[0]} × {spans[1]} | all {len(steps)} | {total['iterations']} | "
            f"{total['full']} / {total['shortened']} / {total['lengthened']} / "
            f"{total['none']} | {total['projected']} | {total['damped']} | "
            f"{total['endgame']} | | | | {total['seconds']:.2f} |")
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("result", type=Path, help="a spline run's result.json")
    parser.add_argument("--floor", type=float, default=1e-8,
                        help="the endgame's bound: λ²/2 ≤ FLOOR × |Π| (NewtonConfig."
                        "floor_tolerance: 1e-8 in float64, 1e-6 in float32)")
    args = parser.parse_args(argv)
    try:
        document = json.loads(args.result.read_text())
    except (OSError, ValueError) as error:
        print(f"newton_iterations: cannot read {args.result}: {error}", file=sys.stderr)
        return 2
    history = document.get("history") if isinstance(document, dict) else None
    if not history or "level" not in history[0]:
        print(f"newton_iterations: {args.result} holds no Newton history (a spline run's "
              "result.json has one)", file=sys.stderr)
        return 2
    print("\n".join(table(history, args.floor)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
