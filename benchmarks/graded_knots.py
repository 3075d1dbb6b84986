"""Graded knots towards known singular features against uniform knots (issue 33), spline
field + projected Newton, float64, one thread, side by side in one process.

Parts (`--parts`):
- napkin: scenes/napkin.toml (free pin at a corner) on n × n spans, one level, uniform and
  graded (`[field] grading = "features"`): Π, the free corner's u_z, unknowns, Newton
  iterations, CPU and wall time;
- interior: napkin_interior_point and napkin_interior_line on the grid rule's spans, one
  level, both gradings;
- validation: the validation cases as `ndf-validate --field spline` solves them (the grid
  rule's grid and two dyadic refinements, read on the finest), both gradings: each quantity
  against its reference.

CPU: user + sys of this process (`resource.getrusage`) per solve; load: the 1-minute load
average after the solve (the machine is shared).

    python benchmarks/graded_knots.py [--parts napkin,interior,validation] [--spans 8,16,32]
        [--cases a,b] [--levels 3] [--gradings uniform,features]
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import resource
import sys
import time
from pathlib import Path

import torch

import taichi_ndf
from taichi_ndf.boundary.gauges import gauge_points
from taichi_ndf.problem.spline_grid import graded_config
from taichi_ndf.scene.reader import load_scene
from taichi_ndf.solve.spline_solver import solve_spline

ROOT = Path(__file__).resolve().parents[1]

sys.path.insert(0, str(Path(__file__).resolve().parent))
from provenance import commit  # noqa: E402  (the commit each benchmark states)

GRADINGS = ("uniform", "features")


def cpu_seconds() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def unknowns(config) -> int:
    """3 × the coefficients that are read (a mirrored end's aliases are held)."""
    return 3 * int(config.alias_map().unique().numel())


def solve_scene(name: str, grading: str, spans: tuple[int, int] | None) -> dict:
    overrides = {"field.grading": grading}
    if spans is not None:
        overrides["field.spans"] = list(spans)
    scene = load_scene(ROOT / "scenes" / f"{name}.toml", field="spline", overrides=overrides)
    solver = dataclasses.replace(scene.solver, progress=False)
    cpu, wall = cpu_seconds(), time.perf_counter()
    run = solve_spline(scene.model, scene.field, solver)
    level = run.levels[-1]
    return {"energy": level.energy, "converged": level.converged,
            "iterations": level.iterations, "probes": run.probes,
            "spans": tuple(run.field.config.spans), "unknowns": unknowns(run.field.config),
            "cpu": cpu_seconds() - cpu, "wall": time.perf_counter() - wall,
            "load": os.getloadavg()[0]}


def scene_rows(name: str, spans_list, probe: str | None) -> None:
    print(f"\n{name}\n")
    print("| grading | spans | unknowns | Π [J] | " + (f"{probe} u_z [m] | " if probe else "")
          + "Newton its | converged | CPU [s] | wall [s] | load |")
    print("|---|---|---|---|" + ("---|" if probe else "") + "---|---|---|---|---|")
    for spans in spans_list:
        for grading in GRADINGS:
            r = solve_scene(name, grading, spans)
            z = f" {r['probes'][probe][2]:.6f} |" if probe else ""
            print(f"| {grading} | {r['spans'][0]} × {r['spans'][1]} | {r['unknowns']} | "
                  f"{r['energy']:.6f} |{z} {r['iterations']} | {r['converged']} | "
                  f"{r['cpu']:.1f} | {r['wall']:.1f} | {r['load']:.1f} |", flush=True)


def validation_rows(cases, levels: int, gradings=GRADINGS) -> None:
    from taichi_ndf.validation import CASES, runner

    original = runner.load_case_scene

    def graded_scene(case, scenes_dir=runner.SCENES_DIR, field=None):
        scene, model, plan = original(case, scenes_dir, field)
        config = graded_config(plan.config, model.boundary, model.loads, model.surface.domain,
                               gauges=gauge_points(model))
        return scene, model, dataclasses.replace(plan, config=config)

    print(f"\nvalidation cases, spline on {levels} grids (the grid rule's and its refinements)\n")
    print("| case | quantity | grading | finest spans | unknowns | value | reference | error | "
          "CPU [s] | wall [s] | load |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for name in cases:
        for grading in gradings:
            runner.load_case_scene = original if grading == "uniform" else graded_scene
            cpu, wall = cpu_seconds(), time.perf_counter()
            result = runner.run_case(CASES[name], field="spline", levels=levels)
            cpu, wall = cpu_seconds() - cpu, time.perf_counter() - wall
            spans = result.solver.get("spans", [[0, 0]])[-1]
            _, _, plan = runner.load_case_scene(CASES[name], field="spline")
            finest = plan.config
            for _ in range(levels - 1):
                finest = finest.refined()
            for row in result.rows:
                error = "—" if row.relative_error is None else f"{100 * row.relative_error:.2f} %"
                print(f"| {name} | {row.quantity} | {grading} | {spans[0]} × {spans[1]} | "
                      f"{unknowns(finest)} | {row.computed:.6g} | {row.reference:.6g} | "
                      f"{error} | {cpu:.1f} | {wall:.1f} | {os.getloadavg()[0]:.1f} |",
                      flush=True)
    runner.load_case_scene = original


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--parts", default="napkin,interior,validation")
    parser.add_argument("--spans", default="8,16,32", help="napkin: n for n × n spans")
    parser.add_argument("--cases", default="square_plate,scordelis_lo_roof,pinched_cylinder,"
                        "pinched_hemisphere,cantilever_shear,cantilever_moment")
    parser.add_argument("--levels", type=int, default=3)
    parser.add_argument("--gradings", default=",".join(GRADINGS),
                        help="validation: the gradings to run")
    args = parser.parse_args()
    taichi_ndf.init(arch="cpu", precision="f64", seed=0)
    torch.set_num_threads(1)
    print(f"commit {commit()}, {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, "
          f"load {os.getloadavg()[0]:.1f}")
    parts = args.parts.split(",")
    if "napkin" in parts:
        scene_rows("napkin", [(n, n) for n in map(int, args.spans.split(","))], "free_corner")
    if "interior" in parts:
        scene_rows("napkin_interior_point", [None], "corner")
        scene_rows("napkin_interior_line", [None], "left_edge_middle")
    if "validation" in parts:
        validation_rows(args.cases.split(","), args.levels, args.gradings.split(","))


if __name__ == "__main__":
    main()
