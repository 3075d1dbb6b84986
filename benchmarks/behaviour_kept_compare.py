"""Behaviour kept (issue 26): the table of the before/after runs of benchmarks/behaviour_kept.sh.

For every SCENE_FIELD whose before and after runs both finished (WORK/out/SCENE_FIELD_before,
..._after, with their `/usr/bin/time` files): Π of each (result.json), identical or the
relative difference |Π_after − Π_before| / |Π_before|, the iterations (Newton or Adam), Adam's
backoffs, the probes (equal, or the largest component difference [m]), mesh.obj byte for byte,
CPU (user + sys) and wall [s] of each whole command. A run that did not finish shows its exit
code (152: stopped by the CPU cap).

    python benchmarks/behaviour_kept_compare.py WORK
"""

from __future__ import annotations

import filecmp
import json
import re
import sys
from pathlib import Path


def run(out: Path, name: str) -> dict | None:
    """One run's time file and result.json, or None while it is still running."""
    timing = (out / f"{name}.time").read_text() if (out / f"{name}.time").is_file() else ""
    if "rc" not in timing.split():
        return None
    words = timing.split()
    user, system, wall = (float(x) for x in [w for w in words
                                             if re.fullmatch(r"[0-9.]+", w)][:3])
    result = out / name / "result.json"
    return {"cpu": user + system, "wall": wall, "rc": words[words.index("rc") + 1],
            "result": json.loads(result.read_text()) if result.is_file() else None,
            "dir": out / name}


def row(scene: str, field: str, before: dict, after: dict) -> str:
    cost = (f"{before['cpu']:.1f} / {after['cpu']:.1f} | "
            f"{before['wall']:.0f} / {after['wall']:.0f}")
    b, a = before["result"], after["result"]
    if b is None or a is None:
        return f"| {scene} | {field} | exit {before['rc']} / {after['rc']} | | | | | | {cost} |"
    same = "identical" if a["energy"] == b["energy"] else \
        f"{abs(a['energy'] - b['energy']) / abs(b['energy']):.1e} rel"
    if a["probes"] == b["probes"]:
        probes = "probes ="
    else:
        worst = max(abs(x - y) for name, u in b["probes"].items()
                    for x, y in zip(u, a["probes"].get(name, [float("nan")] * 3), strict=True))
        probes = f"probes differ (max {worst:.2e} m)"
    mesh = "byte-identical" if filecmp.cmp(before["dir"] / "mesh.obj", after["dir"] / "mesh.obj",
                                           shallow=False) else "differs"
    backoffs = f"{b['backoffs']} / {a['backoffs']}" if "backoffs" in b else ""
    return (f"| {scene} | {field} | {b['energy']!r} | {a['energy']!r} | {same} | "
            f"{b['iterations']} / {a['iterations']} | {backoffs} | {probes}, mesh.obj {mesh} | "
            f"{cost} |")


def main(work: Path) -> None:
    out = work / "out"
    print("| scene | field | Π before [J] | Π after [J] | | iterations before / after | "
          "backoffs | also | CPU before / after [s] | wall before / after [s] |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for path in sorted(out.glob("*_before.time")):
        name = path.name[: -len("_before.time")]
        before, after = run(out, f"{name}_before"), run(out, f"{name}_after")
        if before is not None and after is not None:
            print(row(*name.rsplit("_", 1), before, after))


if __name__ == "__main__":
    if len(sys.argv) != 2 or not Path(sys.argv[1], "out").is_dir():
        print("usage: behaviour_kept_compare.py WORK (the folder with out/)", file=sys.stderr)
        sys.exit(2)
    main(Path(sys.argv[1]))
