"""Every shipped scene solved by both contenders in one run: SIREN + Adam (the scene as
written) and spline + projected Newton (`ndf-sim --field spline`: the grid rule's grid, one
level). Each run is `ndf-sim` in its own process (one thread); reported per scene and
contender: Π reached [J], wall time [s] of the whole process (start, compile, solve, outputs),
the solve time result.json reports, and the peak resident memory of the process [MiB]
(`os.wait4`); the renders are copied to docs/spline_vs_siren/ for docs/spline_vs_siren.md.

Π is each run's own estimate of the same integral (the SIREN's on its monitor samples, the
spline's on its Gauss points), so the two columns compare the minimum each method found.

    python benchmarks/spline_vs_siren.py [--scenes napkin,flag] [--precision f32] [--json out]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCENES = ROOT / "scenes"
RENDERS = ROOT / "docs" / "spline_vs_siren"
CONTENDERS = {"siren_adam": [], "spline_newton": ["--field", "spline"]}


def run_one(scene: Path, extra: list[str], out: Path, precision: str) -> dict:
    """One ndf-sim process: Π, times and peak memory."""
    env = {**os.environ, "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    command = [sys.executable, "-m", "taichi_ndf.cli.sim", str(scene), "--out", str(out),
               "--precision", precision, "--arch", "cpu", *extra]
    started = time.perf_counter()
    process = subprocess.Popen(command, env=env, stdout=subprocess.DEVNULL,
                               stderr=subprocess.PIPE)
    _, status, usage = os.wait4(process.pid, 0)
    wall = time.perf_counter() - started
    stderr = process.stderr.read().decode(errors="replace")
    if os.waitstatus_to_exitcode(status) != 0:
        return {"error": stderr.strip().splitlines()[-1] if stderr.strip() else "failed",
                "wall": wall}
    result = json.loads((out / "result.json").read_text())
    return {"energy": result["energy"], "wall": wall, "solve": result["wall_time"],
            "iterations": result["iterations"], "peak_mib": usage.ru_maxrss / 1024,
            "spans": result.get("resolved", {}).get("field", {}).get("finest_spans")}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", default=",".join(p.stem for p in sorted(SCENES.glob("*.toml"))))
    parser.add_argument("--precision", choices=("f32", "f64"), default="f32")
    parser.add_argument("--json", default=None)
    args = parser.parse_args()
    RENDERS.mkdir(parents=True, exist_ok=True)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name in [s for s in args.scenes.split(",") if s]:
            row = {"scene": name}
            for contender, extra in CONTENDERS.items():
                out = Path(tmp) / f"{name}_{contender}"
                row[contender] = run_one(SCENES / f"{name}.toml", extra, out, args.precision)
                if (out / "render.png").is_file():
                    shutil.copy(out / "render.png", RENDERS / f"{name}_{contender}.png")
                print(json.dumps({name: {contender: row[contender]}}), flush=True)
            rows.append(row)
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
