"""The four-panel tube top on a capsule torso (issue 30, "Garments: flat-cut panels on a body").

scenes/tube_top_body.toml: four flat-cut polyester_knit panels (0.2356 × 0.4 m) wrapped round
a 0.15 m circle, sewn into a tube, the top band held and gathered onto a 0.142 m circle round
a capsule torso of radius 0.14 m standing upright (gravity along it), solved with the contact
rounds (`MultiPatchDiscretisation`, flat-cut panels through `discretise.panel_contact`) on
n × m spans per panel (default 4 × 6, 8 × 12, 16 × 24). Per grid: Π, Newton iterations per
load step, convergence (Newton's own test at every load step), contact rounds and check
points, the seams' largest gap, the top band's radius (min / max over 17 points per panel),
the hem's radius (min / mean / max) and mean height (placed at z = 0), the smallest radius
and the smallest gap beyond h/2 + margin over a 61² grid per panel, CPU and wall time, load;
then Richardson's observed order and extrapolation of Π and of the mean hem radius
(`taichi_ndf.minimise.extrapolation.richardson`, expected order 4). --no-body: the same tube
top without the torso (what the body changes: its smallest radius then).

    PYTHONPATH=$PWD OMP_NUM_THREADS=1 python benchmarks/garment_tube_top.py [--no-body] [n m ...]
"""

from __future__ import annotations

import argparse
import os
import sys
import tomllib
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))

from garment_skirt import _rim, _solve  # noqa: E402
from provenance import commit  # noqa: E402

import taichi_ndf  # noqa: E402
from taichi_ndf.minimise.extrapolation import richardson  # noqa: E402
from taichi_ndf.scene.reader import parse_scene  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "scenes" / "tube_top_body.toml"
GRIDS = ((4, 6), (8, 12), (16, 24))
BODY = 0.14  # [m] the torso's radius


def _surface(panels, count: int = 61) -> torch.Tensor:
    """Deformed positions (4 × count², 3) [m] of a count² grid over every panel."""
    s = torch.linspace(0.0, 1.0, count, dtype=torch.float64)
    out = []
    for i, patch in enumerate(panels.spec.patches):
        (lo1, hi1), (lo2, hi2) = patch.model.surface.domain.bounds
        xi = torch.stack(torch.meshgrid(lo1 + (hi1 - lo1) * s, lo2 + (hi2 - lo2) * s,
                                        indexing="ij"), dim=-1).reshape(-1, 2)
        out.append(patch.model.surface.jets(xi)[:, 0] + panels.displacement_of(i, xi)[:, 0])
    return torch.cat(out)


def row(spans, body: bool) -> dict:
    """The tube top on `spans` per panel (with or without the torso): the module's figures."""
    document = tomllib.loads(SCENE.read_text())
    document["field"]["spans"] = list(spans)
    if not body:
        del document["obstacles"], document["contact"]
    scene = parse_scene(document, base_dir=SCENE.parent, path=SCENE)
    panels, solution, cpu, wall = _solve(scene)
    height = document["panels"][0]["height"]
    top, hem = (_rim(panels, z) for z in (height, 0.0))
    x = _surface(panels)
    gap = (float(scene.model.contact.term().gaps(x, 1.0)[0].min()) if body else None)
    steps = solution.document["load_steps"]
    return {"spans": spans, "energy": solution.energy,
            "iterations": [s["iterations"] for s in steps],
            "converged": [s["converged"] for s in steps],
            "rounds": solution.contact_counts.get("newton_rounds"),
            "points": None if solution.contact is None else solution.contact.count,
            "seam_gap": max(solution.document["seam_gaps"].values()),
            "top": top[:, :2].norm(dim=1), "hem": hem[:, :2].norm(dim=1),
            "hem_z": float(hem[:, 2].mean()), "smallest": float(x[:, :2].norm(dim=1).min()),
            "gap": gap, "cpu": cpu, "wall": wall, "load": os.getloadavg()[0]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--no-body", action="store_true", help="without the torso")
    parser.add_argument("spans", nargs="*", type=int, help="n m per grid (pairs)")
    args = parser.parse_args()
    taichi_ndf.init(arch="cpu", precision="f64")
    grids = (tuple(zip(args.spans[::2], args.spans[1::2], strict=True)) if args.spans
             else GRIDS)
    body = not args.no_body
    print(f"commit {commit()}, load average {os.getloadavg()[0]:.1f} (start); "
          f"{'with' if body else 'without'} the torso (radius {BODY} m)")
    print("| spans per panel | Π [J] | Newton it. per load step | converged | rounds / check "
          "points | seam gap [m] | top radius min / max [m] | hem radius min / mean / max [m] "
          "| hem height [mm] | smallest radius [m] | smallest gap [mm] | CPU [s] | wall [s] "
          "| load |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    rows = []
    for spans in grids:
        r = row(spans, body)
        rows.append(r)
        gap = "—" if r["gap"] is None else f"{1e3 * r['gap']:.3f}"
        print(f"| {spans[0]} × {spans[1]} | {r['energy']:.7g} | "
              f"{' '.join(map(str, r['iterations']))} | {all(r['converged'])} | "
              f"{r['rounds'] or '—'} / {r['points'] if r['points'] is not None else '—'} | "
              f"{r['seam_gap']:.1e} | {float(r['top'].min()):.4f} / {float(r['top'].max()):.4f}"
              f" | {float(r['hem'].min()):.4f} / {float(r['hem'].mean()):.4f} / "
              f"{float(r['hem'].max()):.4f} | {1e3 * r['hem_z']:.2f} | {r['smallest']:.4f} | "
              f"{gap} | {r['cpu']:.1f} | {r['wall']:.1f} | {r['load']:.1f} |", flush=True)
    if len(rows) >= 2:
        converged = [all(r["converged"]) for r in rows]
        for name, values in (("Π [J]", [r["energy"] for r in rows]),
                             ("mean hem radius [m]", [float(r["hem"].mean()) for r in rows]),
                             ("hem height [m]", [r["hem_z"] for r in rows])):
            e = richardson(values, order=4.0, converged=converged)
            changes = " ".join(f"{b - a:+.4g}" for a, b in zip(values, values[1:], strict=False))
            print(f"{name}: changes {changes}; Richardson {e.describe()}")
    print(f"load average {os.getloadavg()[0]:.1f} (end)")


if __name__ == "__main__":
    main()
