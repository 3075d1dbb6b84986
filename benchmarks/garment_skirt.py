"""The two-panel skirt (issue 30, "Garments") against the periodic one-patch skirt.

scenes/skirt_panels.toml: a front and a back panel, each a half-cylinder of radius 0.15 m and
length 0.4 m (cotton/polyester), sewn at both sides with bending transmitted, the waist
(ξ² = 0.4 m) clamped, gravity at load steps 0.5, 1 — solved by `MultiPatchDiscretisation`
(one projected Newton over both panels, float64) on n × m spans per panel; the reference is
the same skirt as one periodic cylinder (`[geometry] type = "cylinder"`, a whole turn, the same
waist clamped) on 2n × m spans by the spline path. Prints per grid: Π of both, their relative
difference, the largest displacement difference [m] over 25 × 7 points per panel (the back
panel's ξ¹ shifted by π: it is turned by π about z), the largest displacement, the seams'
largest gap, Newton iterations, convergence, CPU and wall time of each solve, load average,
commit.

    PYTHONPATH=$PWD OMP_NUM_THREADS=1 python benchmarks/garment_skirt.py [n m ...]

--four: scenes/skirt_four_panels.toml (four flat-cut knit panels, the waist gathered from a
0.1875 m onto a 0.15 m circle) on n × m spans per panel, and the same skirt with its waist
held on the wrap's circle (no `held_radius`): per case Π, Newton iterations, convergence, the
seams' largest gap, the waist's and the hem's radius (min / mean / max over 17 points per
panel) and the hem's mean height (placed at z = 0), CPU and wall time.

    PYTHONPATH=$PWD OMP_NUM_THREADS=1 python benchmarks/garment_skirt.py --four [n m ...]
"""

from __future__ import annotations

import math
import os
import resource
import sys
import time
import tomllib
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from provenance import commit  # noqa: E402

import taichi_ndf  # noqa: E402
from taichi_ndf.discretise import of_scene  # noqa: E402
from taichi_ndf.scene.reader import parse_scene  # noqa: E402

SCENE = ROOT / "scenes" / "skirt_panels.toml"
FOUR = ROOT / "scenes" / "skirt_four_panels.toml"
GRIDS = ((16, 8), (32, 8))
FOUR_GRIDS = ((8, 12), (12, 18))


def _cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def _solve(scene):
    d = of_scene(scene)
    cpu, wall = _cpu(), time.perf_counter()
    d.start(scene.solver, seed=0)
    solution = d.solve(scene.solver)
    d.check_solution(solution)
    return d, solution, _cpu() - cpu, time.perf_counter() - wall


def periodic_document(garment: dict, spans) -> dict:
    """The garment's skirt as one periodic cylinder on (2 n, m) spans."""
    front = garment["panels"][0]
    return {"name": "skirt_periodic", "material": garment["material"],
            "loads": garment["loads"],
            "geometry": {"type": "cylinder", "radius": front["wrap_radius"],
                         "length": front["height"]},
            "boundary": {"constraint": [{"type": "clamped_edge", "edge": "xi2_max"}]},
            "field": {"type": "spline", "spans": [2 * spans[0], spans[1]]},
            "training": garment["training"]}


def run(spans) -> dict:
    garment = tomllib.loads(SCENE.read_text())
    garment["field"]["spans"] = list(spans)
    panels, panel_solution, panel_cpu, panel_wall = _solve(
        parse_scene(garment, base_dir=SCENE.parent, path=SCENE))
    periodic_scene = parse_scene(periodic_document(garment, spans), base_dir=SCENE.parent)
    periodic, solution, cpu, wall = _solve(periodic_scene)
    dt = torch.float64
    theta = torch.linspace(0.0, math.pi, 25, dtype=dt)
    xi = torch.stack(torch.meshgrid(theta, torch.linspace(0.0, 0.4, 7, dtype=dt),
                                    indexing="ij"), dim=-1).reshape(-1, 2)
    difference, largest = 0.0, 0.0
    for i in range(2):
        u = panels.displacement_of(i, xi)[:, 0]
        at = xi + torch.tensor([math.pi * i, 0.0], dtype=dt)
        reference = periodic.displacement(at, 1.0)[:, 0]
        difference = max(difference, float((u - reference).norm(dim=1).max()))
        largest = max(largest, float(reference.norm(dim=1).max()))
    return {"spans": spans, "energy": panel_solution.energy, "reference": solution.energy,
            "relative": abs(panel_solution.energy - solution.energy) / abs(solution.energy),
            "difference": difference, "largest": largest,
            "gap": max(panel_solution.document["seam_gaps"].values()),
            "iterations": panel_solution.iterations, "converged": all(panels.converged),
            "cpu": panel_cpu, "wall": panel_wall, "reference_iterations": solution.iterations,
            "reference_cpu": cpu, "reference_wall": wall}


def _rim(panels, height: float) -> torch.Tensor:
    """Deformed positions (4 × 17, 3) [m] of every panel's edge at ξ² = height."""
    out = []
    for i, patch in enumerate(panels.spec.patches):
        (lo, hi), _ = patch.model.surface.domain.bounds
        s = torch.linspace(lo, hi, 17, dtype=torch.float64)
        xi = torch.stack((s, torch.full_like(s, height)), dim=1)
        out.append(patch.model.surface.jets(xi)[:, 0] + panels.displacement_of(i, xi)[:, 0])
    return torch.cat(out)


def four(spans, gathered: bool) -> str:
    """One row of the four-panel table."""
    garment = tomllib.loads(FOUR.read_text())
    garment["field"]["spans"] = list(spans)
    if not gathered:
        for panel in garment["panels"]:
            del panel["held_radius"]
    panels, solution, cpu, wall = _solve(parse_scene(garment, base_dir=FOUR.parent, path=FOUR))
    height = garment["panels"][0]["height"]
    waist, hem = (_rim(panels, z)[:, :2].norm(dim=1) for z in (height, 0.0))
    z = float(_rim(panels, 0.0)[:, 2].mean())
    return (f"| {spans[0]} × {spans[1]} | {'0.15' if gathered else 'none'} | "
            f"{solution.energy:.6g} | {solution.iterations} | {all(panels.converged)} | "
            f"{max(solution.document['seam_gaps'].values()):.1e} | {float(waist.min()):.4f} / "
            f"{float(waist.max()):.4f} | {float(hem.min()):.4f} / {float(hem.mean()):.4f} / "
            f"{float(hem.max()):.4f} | {z * 1e3:.2f} | {cpu:.1f} | {wall:.1f} |")


def main() -> None:
    taichi_ndf.init(arch="cpu", precision="f64")
    torch.set_num_threads(1)
    if sys.argv[1:2] == ["--four"]:
        args = [int(v) for v in sys.argv[2:]]
        grids = tuple(zip(args[::2], args[1::2], strict=True)) if args else FOUR_GRIDS
        print(f"commit {commit()}, load average {os.getloadavg()[0]:.1f} (start)")
        print("| spans per panel | waist held on [m] | Π [J] | Newton it. | converged | "
              "seam gap [m] | waist radius min / max [m] | hem radius min / mean / max [m] | "
              "hem height [mm] | CPU [s] | wall [s] |")
        print("|---|---|---|---|---|---|---|---|---|---|---|")
        for spans in grids:
            for gathered in (True, False):
                print(four(spans, gathered), flush=True)
        print(f"load average {os.getloadavg()[0]:.1f} (end)")
        return
    args = [int(v) for v in sys.argv[1:]]
    grids = tuple(zip(args[::2], args[1::2], strict=True)) if args else GRIDS
    print(f"commit {commit()}, load average {os.getloadavg()[0]:.1f} (start)")
    print("| spans per panel | Π panels [J] | Π periodic [J] (2n × m) | Π rel. diff. | "
          "max |u − u_periodic| [m] | max |u| [m] | seam gap [m] | Newton it. panels / "
          "periodic | converged | CPU panels [s] | wall panels [s] | CPU periodic [s] | "
          "wall periodic [s] |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for spans in grids:
        r = run(spans)
        print(f"| {spans[0]} × {spans[1]} | {r['energy']:.8g} | {r['reference']:.8g} | "
              f"{r['relative']:.2e} | {r['difference']:.2e} | {r['largest']:.3e} | "
              f"{r['gap']:.1e} | {r['iterations']} / {r['reference_iterations']} | "
              f"{r['converged']} | {r['cpu']:.1f} | {r['wall']:.1f} | {r['reference_cpu']:.1f} | "
              f"{r['reference_wall']:.1f} |", flush=True)
    print(f"load average {os.getloadavg()[0]:.1f} (end)")


if __name__ == "__main__":
    main()
