"""Do refinement error bars cover the converged value? (issue 35)

Each case is a shipped scene or a validation scene solved on a spline field (cubic, the scene's
load steps, float64, projected Newton to its default tolerance) on `levels` grids from a given
coarsest grid, each dyadically refined from the last (`solve_spline`, the `ndf-sim --refine`
path). For a quantity (Π or a probe component at the last load step) it reads:

- the three-grid bar (`richardson` on grids 0, 1, 2, and for the napkin also 1, 2, 3 — the
  demo's 8 / 16 / 32): value ± error from the observed order;
- the two-grid bar on grids 1, 2 (order 2(p − 1) = 4 assumed, error = the change) and, for
  comparison, the rule it replaces (error = |v∞ − v₂| at the assumed order);
- the fine-grid reference: the finest grid's value (4× or 2× finer than the bar's finest) with
  its own error from `richardson` on the last three grids.

A bar covers when |reference − value| ≤ error. The table goes into benchmarks/RESULTS.md
("Refinement error bars"). Long (about 20–40 minutes on one shared core): run under nice.

    nice python benchmarks/refinement_coverage.py [--cases napkin,square_plate] [--json out]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import time
from pathlib import Path

import torch

import taichi_ndf
from taichi_ndf.minimise.refinement import richardson
from taichi_ndf.scene import load_scene
from taichi_ndf.spline_solver import solve_spline

ROOT = Path(__file__).resolve().parents[1]
ORDER = 4.0  # 2(p − 1) for cubic splines

# name: (scene file, coarsest spans, levels, quantities, bar windows (first grid of three))
CASES = {
    "napkin": ("scenes/napkin.toml", (4, 4), 5, ("energy", "free_corner:2"), (0, 1)),
    "napkin_coarse": ("scenes/napkin.toml", (2, 2), 5, ("energy", "free_corner:2"), (0, 1)),
    "napkin_clamped_edges": ("scenes/napkin_clamped_edges.toml", (5, 5), 5, ("energy",), (0,)),
    "membrane_stretch": ("scenes/membrane_stretch.toml", (2, 2), 5, ("energy", "centre:0"),
                         (0,)),
    "bowl": ("scenes/bowl.toml", (2, 2), 5, ("energy",), (0,)),
    "square_plate": ("validation/scenes/square_plate.toml", (2, 2), 5,
                     ("energy", "centre:2"), (0,)),
    "cantilever_shear": ("validation/scenes/cantilever_shear.toml", (4, 1), 5, ("tip:2",),
                         (0,)),
    "scordelis_lo_roof": ("validation/scenes/scordelis_lo_roof.toml", (4, 5), 5,
                          ("free_edge_mid:2",), (0,)),
}


def read(level, quantity: str) -> float:
    if quantity == "energy":
        return level.energy
    name, component = quantity.split(":")
    return level.probes[name][int(component)]


def covers(bar, reference: float) -> bool:
    return abs(reference - bar.value) <= bar.error


def run_case(name: str) -> dict:
    path, spans, levels, quantities, windows = CASES[name]
    scene = load_scene(ROOT / path, field="spline")
    plan = dataclasses.replace(scene.field, levels=levels,
                               config=dataclasses.replace(scene.field.config, spans=spans))
    solver = dataclasses.replace(scene.solver, max_levels=0)
    started, cpu = time.perf_counter(), time.process_time()
    run = solve_spline(scene.model, plan, solver)
    wall, cpu = time.perf_counter() - started, time.process_time() - cpu
    rows = []
    for q in quantities:
        values = [read(lv, q) for lv in run.levels]
        reference = values[-1]
        ref_bar = richardson(values[-3:], order=ORDER)
        for first in windows:
            three = richardson(values[first:first + 3], order=ORDER)
            two = richardson(values[first + 1:first + 3], order=ORDER)
            old_error = abs(two.value - values[first + 2])  # the replaced two-grid rule
            rows.append({
                "quantity": q, "grids": [list(run.levels[k].spans)
                                         for k in range(first, first + 3)],
                "values": values[first:first + 3],
                "three": three.to_dict(), "three_covers": covers(three, reference),
                "two": two.to_dict(), "two_covers": covers(two, reference),
                "old_two_error": old_error,
                "old_two_covers": abs(reference - two.value) <= old_error,
                "reference": reference, "reference_spans": list(run.levels[-1].spans),
                "reference_error": ref_bar.error, "reference_how": ref_bar.how(),
                "reference_ratio": (run.levels[-1].spans[0]
                                    // run.levels[first + 2].spans[0]),
            })
    return {"case": name, "scene": path, "spans": [list(lv.spans) for lv in run.levels],
            "all_values": {q: [read(lv, q) for lv in run.levels] for q in quantities},
            "converged": [lv.converged for lv in run.levels],
            "iterations": [lv.iterations for lv in run.levels],
            "seconds": [lv.seconds for lv in run.levels], "wall": wall, "cpu": cpu,
            "rows": rows}


def table(results: list[dict]) -> str:
    lines = ["| case | quantity | grids | 3 grids: value ± bar (order) | covers | "
             "2 grids, order 4 assumed: value ± change | covers | old 2-grid bar | covers | "
             "reference (spans) ± its error | converged | wall / CPU [s] |",
             "|" + "---|" * 12]
    yes = {True: "yes", False: "**no**"}
    for r in results:
        for row in r["rows"]:
            t, w = row["three"], row["two"]
            order = ("not monotone" if t["order_basis"] == "not converging"
                     else f"p = {t['order']:.2f}")
            grids = " / ".join(str(g[0]) + "×" + str(g[1]) for g in row["grids"])
            lines.append(
                f"| {r['case']} | {row['quantity']} | {grids} | {t['extrapolated']:.6g} ± "
                f"{t['estimated_error']:.2g} ({order}) | {yes[row['three_covers']]} | "
                f"{w['extrapolated']:.6g} ± {w['estimated_error']:.2g} | "
                f"{yes[row['two_covers']]} | ± {row['old_two_error']:.2g} | "
                f"{yes[row['old_two_covers']]} | {row['reference']:.6g} "
                f"({'×'.join(map(str, row['reference_spans']))}) ± "
                f"{row['reference_error']:.2g} | {'yes' if all(r['converged']) else 'no'} | "
                f"{r['wall']:.0f} / {r['cpu']:.0f} |")
    rows = [row for r in results for row in r["rows"]]
    lines.append("")
    lines.append(f"three-grid bars covering the reference: "
                 f"{sum(row['three_covers'] for row in rows)} of {len(rows)}; two-grid "
                 f"(change): {sum(row['two_covers'] for row in rows)} of {len(rows)}; old "
                 f"two-grid rule: {sum(row['old_two_covers'] for row in rows)} of {len(rows)}")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", default=",".join(CASES))
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    logging.basicConfig(level=logging.WARNING, format="%(asctime)s %(name)s: %(message)s")
    torch.set_num_threads(1)
    taichi_ndf.init(arch="cpu", precision="f64")
    results = []
    for name in [c for c in args.cases.split(",") if c]:
        if name not in CASES:
            raise SystemExit(f"unknown case {name!r}; choose from {', '.join(CASES)}")
        results.append(run_case(name))
        print(json.dumps(results[-1], default=float), flush=True)
        if args.json:
            args.json.write_text(json.dumps(results, indent=1, default=float))
    print(table(results))


if __name__ == "__main__":
    main()
