"""A napkin dropped onto a sphere (scenes/napkin_drop_sphere.toml) against the quasistatic
solve of scenes/napkin_sphere.toml on the same grid (issue 29), from the two runs' outputs.

Run first (float64, the same 10 × 10-span cubic spline grid):

    python -m taichi_ndf.cli.sim scenes/napkin_drop_sphere.toml --precision f64 \
        --no-pictures --out DROP
    python -m taichi_ndf.cli.sim scenes/napkin_sphere.toml --field spline --quick \
        --precision f64 --out STATIC

then `python benchmarks/napkin_drop_check.py DROP STATIC`. Prints:
1. the run: steps, dt, simulated time, Newton iterations per step (mean, max), substeps, CPU
   per step and per simulated second (result.json `dynamics`);
2. penetration, computed here from the meshes alone: the smallest signed distance
   |x − c| − R [m] of the vertices of every output frame (trajectory/step_*.obj) and of the
   final mesh to the sphere (centre and radius read from the scene), beside the dense check
   grid's smallest gap over all steps (result.json; the barrier's gap, net of half the
   thickness and the margin);
3. the rest state: kinetic energy at the last steps, Π at rest (with the barrier, as the
   quasistatic Π) against the quasistatic Π, and the probes of both (a different drape shows
   there).
"""

from __future__ import annotations

import json
import sys
import tomllib
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from dynamic_scenes_check import run_table  # noqa: E402  (the run's table, one place)

ROOT = Path(__file__).resolve().parents[1]


def vertices(path: Path) -> np.ndarray:
    rows = [line.split()[1:4] for line in path.read_text().splitlines() if line.startswith("v ")]
    return np.array(rows, dtype=np.float64)


def _vector(v) -> str:
    return "—" if v is None else "(" + ", ".join(f"{x:.4g}" for x in v) + ")"


def main(drop: Path, static: Path) -> None:
    run = json.loads((drop / "result.json").read_text())
    quasi = json.loads((static / "result.json").read_text())
    d = run["dynamics"]
    scene = tomllib.loads((ROOT / "scenes" / "napkin_drop_sphere.toml").read_text())
    sphere = scene["obstacles"][0]
    centre, radius = np.array(sphere["centre"]), float(sphere["radius"])
    run_table(d)

    frames = sorted((drop / "trajectory").glob("step_*.obj")) + [drop / "mesh.obj"]
    gaps = [float((np.linalg.norm(vertices(f) - centre, axis=1) - radius).min())
            for f in frames]
    worst = int(np.argmin(gaps))
    print()
    print("| frames checked | vertices per frame | min |x − c| − R [m] (frame) | "
          "check grid's min gap over all steps [m] |")
    print("|---|---|---|---|")
    print(f"| {len(frames)} | {len(vertices(frames[0]))} | {min(gaps):.4g} ({frames[worst].name}) "
          f"| {min(g for g in d['gaps'] if g is not None):.4g} |")

    kinetic, potential = d["kinetic"], d["potential"]
    rest, reference = potential[-1], quasi["energy"]
    print()
    print("| T at t_end [J] | max T over the last 0.5 s [J] | Π at rest [J] | quasistatic Π [J] | "
          "relative difference |")
    print("|---|---|---|---|---|")
    last = [k for t, k in zip(d["times"], kinetic, strict=True) if t >= d["times"][-1] - 0.5]
    print(f"| {kinetic[-1]:.3g} | {max(last):.3g} | {rest:.8g} | {reference:.8g} | "
          f"{(rest - reference) / abs(reference):+.3%} |")
    print()
    print("| probe | dynamic rest u [m] | quasistatic u [m] |")
    print("|---|---|---|")
    for name, u in run["probes"].items():
        q = quasi["probes"].get(name)
        print(f"| {name} | {_vector(u)} | {_vector(q)} |")


if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit("usage: python benchmarks/napkin_drop_check.py DROP_RUN STATIC_RUN")
    main(Path(sys.argv[1]), Path(sys.argv[2]))
