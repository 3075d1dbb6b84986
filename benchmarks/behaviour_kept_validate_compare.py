"""Behaviour kept (issue 26): the validation table of benchmarks/behaviour_kept_validate.sh's
before and after runs side by side.

For every TAG whose before and after runs both finished (WORK/val/TAG_before, TAG_after with
results.json): per row (case, quantity, load level) the value of each, the relative change
|after − before| / |before| (or "identical"), the reference, each run's error against it [%],
the target, whether each is within it, the Adam iterations and the Newton steps of the case;
then each case's grids (spans per level) and the CPU (user + sys) and wall [s] of each whole
command. A run that did not
finish shows its exit code (152: stopped by the CPU cap).

    python benchmarks/behaviour_kept_validate_compare.py WORK [TAG_PREFIX]
"""

from __future__ import annotations

import json
import sys
from pathlib import Path


def run(val: Path, name: str) -> dict | None:
    """One run's time file and results.json rows, or None while it is still running."""
    words = (val / f"{name}.time").read_text().split() if (val / f"{name}.time").is_file() else []
    if "rc" not in words:
        return None
    user, system, wall = (float(x) for x in words[:3])
    result = val / name / "results.json"
    document = json.loads(result.read_text()) if result.is_file() else {}
    return {"cpu": user + system, "wall": wall, "rc": words[words.index("rc") + 1],
            "rows": document.get("rows"), "cases": document.get("cases", {})}


def cell(row: dict | None, key: str, form: str = "{!r}") -> str:
    return "—" if row is None or row.get(key) is None else form.format(row[key])


def table(tag: str, before: dict, after: dict) -> None:
    print(f"\n{tag}: CPU before / after {before['cpu']:.1f} / {after['cpu']:.1f} s, wall "
          f"{before['wall']:.0f} / {after['wall']:.0f} s, exit {before['rc']} / {after['rc']}")
    if before["rows"] is None or after["rows"] is None:
        return
    print("| case | quantity | load | value before | value after | change (rel) | reference | "
          "error before / after [%] | target [%] | within before / after | Adam iterations "
          "before / after | Newton steps before / after |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    key = ("case", "quantity", "level")
    afters = {tuple(r[k] for k in key): r for r in after["rows"]}
    for b in before["rows"]:
        a = afters.pop(tuple(b[k] for k in key), None)
        vb, va = b["computed"], None if a is None else a["computed"]
        change = ("" if vb is None or va is None else "identical" if va == vb
                  else f"{abs(va - vb) / abs(vb):.1e}")
        error = f"{cell(b, 'relative_error', '{:.3g}')} / {cell(a, 'relative_error', '{:.3g}')}"
        if b.get("relative_error") is not None and a and a.get("relative_error") is not None:
            error = f"{100 * b['relative_error']:.3g} / {100 * a['relative_error']:.3g}"
        print(f"| {b['case']} | {b['quantity']} | {b['level']:g} | {cell(b, 'computed')} | "
              f"{cell(a, 'computed')} | {change} | {b['reference']:.6g} | {error} | "
              f"{100 * b['tolerance']:g} | {cell(b, 'passed', '{}')} / {cell(a, 'passed', '{}')} | "
              f"{b['iterations']} / {cell(a, 'iterations', '{}')} | "
              f"{b.get('newton_steps')} / {cell(a, 'newton_steps', '{}')} |")
    for a in afters.values():
        print(f"| {a['case']} | {a['quantity']} | {a['level']:g} | — | {a['computed']!r} | "
              f"(after only) | {a['reference']:.6g} | | | | | |")
    for case in before["cases"]:
        spans = [run["cases"].get(case, {}).get("solver", {}).get("spans")
                 for run in (before, after)]
        if spans != [None, None]:
            print(f"{case}: spans before {spans[0]}, after {spans[1]}")


def main(work: Path, prefix: str) -> None:
    val = work / "val"
    for path in sorted(val.glob(f"{prefix}*_before.time")):
        tag = path.name[: -len("_before.time")]
        before, after = run(val, f"{tag}_before"), run(val, f"{tag}_after")
        if before is not None and after is not None:
            table(tag, before, after)


if __name__ == "__main__":
    if len(sys.argv) not in (2, 3) or not Path(sys.argv[1], "val").is_dir():
        print("usage: behaviour_kept_validate_compare.py WORK [TAG_PREFIX] (WORK with val/)",
              file=sys.stderr)
        sys.exit(2)
    main(Path(sys.argv[1]), sys.argv[2] if len(sys.argv) == 3 else "")
