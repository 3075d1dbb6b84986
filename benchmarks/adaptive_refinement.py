"""Adaptive refinement to a tolerance (`--tolerance`, issue 33) against uniform refinement,
spline field + projected Newton, float64, one thread, side by side in one process.

Parts (`--parts`):
- napkin: scenes/napkin.toml (free pin at a corner) from n × n spans (`--start`), the rows of
  `NAPKIN_ROWS` named by `--napkin-rows`: uniform dyadic refinement (`solve_spline`, 3
  levels, from n² or 8²), the adaptive loop (`solve_adaptive`: `--indicator`, from a uniform
  or a features-graded first grid, or every grid graded towards the pin by its own spans) within
  `--napkin-budget` unknowns, one features-graded 24² from zero (what the warm start saves);
  Π against Π∞ = −1.64998 J (benchmarks/RESULTS.md, "Graded knots"), the estimate and
  whether its bar holds Π∞;
- interior: the scenes `--scenes` (shipped or validation scenes; default
  napkin_interior_point, napkin_interior_line) from the grid rule's grid: uniform (3 grids)
  and `--tolerance` graded per level within `--scene-budget`; result.json's estimates (Π and
  each probe component) against the next grid of the sequence, and the SIREN's Π
  (benchmarks/spline_vs_siren.json);
- validation: the validation cases with `--tolerance` (the adaptive loop through the
  validation runner, from the grid rule's grid) beside `ndf-validate --field spline` (3
  uniform grids): each quantity against its published reference, and the adaptive
  estimate of the quantity at the last load (the guarded three-grid rule over the adaptive
  sequence) against a fine reference: the case solved on a uniform grid of 2 × the final
  adaptive spans per direction (the band ends' knot lines kept), warm-started from the final
  adaptive solution (`--no-fine`:
  none; each quantity's values on the three grids of both rows and their estimates instead).

- coverage: issue 33's ten cases with an affordable finer reference, the adaptive rows only
  with the default rule (`COVERAGE`: the napkin's "features per level" against Π∞, the
  interior part on five scenes within 10 000 unknowns, the validation part on four cases
  within 15 000; benchmarks/RESULTS.md, "Adaptive refinement: gauges, honest bars, coverage").

CPU: user + sys of this process (`resource.getrusage`) per solve; load: the 1-minute load
average after it (the machine is shared).

    python benchmarks/adaptive_refinement.py [--parts napkin,interior,validation,coverage]
        [--start 6]
        [--tolerance 1e-3] [--budget 20000] [--cases a,b] [--indicator features] [--no-fine]
        [--no-uniform]
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import resource
import sys
import time
from pathlib import Path

import numpy as np
import torch

import taichi_ndf
from taichi_ndf.field.knot_lines import KnotLines
from taichi_ndf.minimise.refinement import richardson
from taichi_ndf.objective import Objective
from taichi_ndf.scene.reader import load_scene
from taichi_ndf.solve.adaptive import AdaptiveConfig, solve_adaptive, solve_on, unknowns
from taichi_ndf.solve.spline_solver import solve_spline

ROOT = Path(__file__).resolve().parents[1]

sys.path.insert(0, str(Path(__file__).resolve().parent))
from provenance import commit  # noqa: E402  (the commit each benchmark states)

INDICATOR = ["density"]  # the adaptive rows' indicator (--indicator)
COVERAGE = {"scenes": ("square_plate_quarter", "membrane_stretch", "napkin_interior_line",
                       "pinched_cylinder_octant", "napkin_clamped_edges"),
            "cases": ("cantilever_shear", "square_plate", "scordelis_lo_roof",
                      "cantilever_moment")}
PI_INF = -1.64998  # the napkin's Π∞ [J] (RESULTS.md, "Graded knots", both sequences)


def cpu_seconds() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


# napkin rows: label -> (first spans: None = --start; [field] grading; the solve: "uniform"
# (`solve_spline`, --napkin-levels dyadic grids), "adaptive" (`solve_adaptive` with
# --indicator), "features" (`solve_adaptive`, every grid graded by its own spans), or "single"
# (one grid by load continuation from zero: what the projection warm start saves))
NAPKIN_ROWS = {
    "uniform": (None, "uniform", "uniform"),
    "adaptive": (None, "uniform", "adaptive"),
    "adaptive, features first": (None, "features", "adaptive"),
    "uniform, features": (None, "features", "uniform"),
    "features per level": (None, "uniform", "features"),
    "uniform 8²": (8, "uniform", "uniform"),
    "features 24² single": (24, "features", "single"),
}


def napkin_rows(start: int, budget: int, tolerance: float, levels: int = 3,
                rows: tuple[str, ...] = ("uniform", "adaptive", "adaptive, features first",
                                         "uniform, features")) -> None:
    print(f"\nnapkin from {start} × {start} spans, Π∞ = {PI_INF} J\n")
    print("| refinement | grids | finest unknowns | Π [J] | Π − Π∞ | estimate ± bar (how) | "
          "holds Π∞ | bar / distance | free corner u_z [m] | finest grid: Newton its, s | "
          "CPU [s] | wall [s] | load |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for label in rows:
        first, grading, how = NAPKIN_ROWS[label]
        n = first or start
        scene = load_scene(ROOT / "scenes" / "napkin.toml", field="spline",
                           overrides={"field.spans": [n, n], "field.grading": grading})
        solver = dataclasses.replace(scene.solver, progress=False)
        cpu, wall = cpu_seconds(), time.perf_counter()
        if how in ("adaptive", "features"):
            rule = INDICATOR[0] if how == "adaptive" else "features"
            run = solve_adaptive(scene.model, scene.field, solver,
                                 AdaptiveConfig(tolerance, budget, rule))
        else:
            run = solve_spline(scene.model, dataclasses.replace(
                scene.field, levels=1 if how == "single" else levels),
                dataclasses.replace(solver, max_levels=0))
        cpu, wall = cpu_seconds() - cpu, time.perf_counter() - wall
        energies = [lv.energy for lv in run.levels]
        if len(energies) >= 3:
            estimate = richardson(energies[-3:], order=4.0, smooth=run.smooth)
            distance = abs(estimate.value - PI_INF)
            holds = "yes" if distance <= estimate.error else "**no**"
            described, ratio = estimate.describe(), f"{estimate.error / distance:.3g}"
        else:
            described, holds, ratio = "—", "—", "—"
        grids = " / ".join(f"{lv.spans[0]}²" for lv in run.levels)
        last = run.levels[-1]
        print(f"| {label} | {grids} | {unknowns(run.field.config)} | {run.energy:.6f} | "
              f"{100 * (run.energy - PI_INF) / abs(PI_INF):+.2f} % | {described} | {holds} | "
              f"{ratio} | {run.probes['free_corner'][2]:.6f} | {last.iterations}, "
              f"{last.seconds:.1f}{'' if last.converged else ' (not converged)'} | "
              f"{cpu:.1f} | {wall:.1f} | {os.getloadavg()[0]:.1f} |", flush=True)


def interior_rows(names, tolerance: float, budget: int, levels: int = 3, fine: bool = True,
                  uniform: bool = True) -> None:
    """Shipped (or validation) scenes from the grid rule's grid: uniform dyadic refinement
    (`levels` grids; `uniform`) and the default `--tolerance` grids within `budget`;
    result.json's estimates (`SplineRun.refinement`: Π and every probe component) against a
    finer solve: the next grid of the sequence (2 × the final spans, graded by its own spans
    where the scene has features) at the last load step from the final solution projected;
    the SIREN's Π of benchmarks/spline_vs_siren.json where it has the scene. A component the
    same on every grid (prescribed) or below 1e-6 of its point's size is not counted."""
    import json

    from taichi_ndf.solve.adaptive import features_grid

    table = json.loads((ROOT / "benchmarks" / "spline_vs_siren.json").read_text())
    print(f"\nscenes: uniform {levels} grids and --tolerance {tolerance:g} (budget {budget}), "
          "graded per level\n")
    print("| scene | refinement | grids | finest unknowns | Π [J] | estimate ± bar (how) | "
          "finer solve Π [J] (spans, its, CPU s) | distance | bar / distance | holds | "
          "SIREN Π [J] | ≤ SIREN | CPU [s] | wall [s] | load |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    coverage, outcomes = [], []
    for name in names:
        path = ROOT / "scenes" / f"{name}.toml"
        path = path if path.exists() else ROOT / "validation" / "scenes" / f"{name}.toml"
        siren = table.get(name, {}).get("siren", {}).get("energy")
        for label in ("uniform", "features per level")[0 if uniform else 1:]:
            scene = load_scene(path, field="spline")
            solver = dataclasses.replace(scene.solver, progress=False)
            cpu, wall = cpu_seconds(), time.perf_counter()
            if label == "uniform":
                run = solve_spline(scene.model, dataclasses.replace(scene.field, levels=levels),
                                   dataclasses.replace(solver, max_levels=0))
            else:
                run = solve_adaptive(scene.model, scene.field, solver,
                                     AdaptiveConfig(tolerance, budget, "features"))
            cpu, wall = cpu_seconds() - cpu, time.perf_counter() - wall
            document = run.refinement(scene.field.config.degree)
            estimate = richardson([lv.energy for lv in run.levels][-3:], order=4.0,
                                  smooth=run.smooth)
            fine_text, distance, ratio, holds = "—", "—", "—", "—"
            if label != "uniform" and fine:
                fine_config = features_grid(run.field.config.refined(), scene.model)
                fine_cpu = cpu_seconds()
                _, fine = solve_on(scene.model, run.field, fine_config, scene.field, solver,
                                   Objective.of_model(scene.model), coarse_energy=run.energy,
                                   smooth=run.smooth, gauge_moved=run.gauge_moved)
                fine_cpu = cpu_seconds() - fine_cpu
                d = abs(estimate.value - fine.energy)
                fine_text = (f"{fine.energy:.6f} ({fine_config.spans[0]}×"
                             f"{fine_config.spans[1]}, {len(fine.history)}, {fine_cpu:.0f})")
                distance, ratio = f"{d:.2g}", f"{estimate.error / d:.3g}" if d else "inf"
                holds = "yes" if d <= estimate.error else "**no**"
                coverage += estimate_rows(name, run, document, fine, fine_config, fine_cpu)
            if label != "uniform":
                outcomes.append(outcome_line(name, run))
            grids = " / ".join(f"{lv.spans[0]}×{lv.spans[1]}" for lv in run.levels)
            below = "—" if siren is None else ("yes" if run.energy <= siren else "no")
            print(f"| {name} | {label} | {grids} | {unknowns(run.field.config)} | "
                  f"{run.energy:.6f} | {estimate.describe()} | {fine_text} | {distance} | "
                  f"{ratio} | {holds} | {'—' if siren is None else f'{siren:.6f}'} | {below} "
                  f"| {cpu:.1f} | {wall:.1f} | {os.getloadavg()[0]:.1f} |", flush=True)
    print_coverage(coverage)
    print("\n" + "\n".join(outcomes))


def outcome_line(name: str, run) -> str:
    """Why the adaptive loop stopped, and its unknowns per grid (result.json's record)."""
    a, sizes = run.adaptive, ", ".join(str(lv["unknowns"]) for lv in run.adaptive["levels"])
    why = (a["stopped"] or a.get("worst")) + (f"; {a['gauge']['line']}" if "gauge" in a else "")
    return f"- {name}: {a['outcome']}; unknowns per grid {sizes}; {why}"


def estimate_rows(name, run, document, fine, fine_config, fine_cpu) -> list[str]:
    """Coverage rows of a scene: result.json's estimate of Π and of each counted probe
    component (`interior_rows`) against the finer solve's."""
    grids = " / ".join(f"{lv.spans[0]}×{lv.spans[1]}" for lv in run.levels)
    spans = f"{fine_config.spans[0]}×{fine_config.spans[1]}"
    entries = [("Π [J]", document["energy"], fine.energy)]
    for probe, parts in document["probes"].items():
        size = max(float(np.linalg.norm(v)) for v in [fine.probes[probe]] + [
            lv.probes[probe] for lv in run.levels])
        for c, part in enumerate(parts):
            values = part["values"] + [float(fine.probes[probe][c])]
            if (max(values) - min(values) <= 1e-12 * max(abs(v) for v in values)
                    or max(abs(v) for v in values) <= 1e-6 * size):
                continue  # prescribed, or zero by symmetry
            entries.append((f"{probe}:{c}", part, float(fine.probes[probe][c])))
    return [coverage_row(name, q, grids, e["values"], e["text"], e["extrapolated"],
                         e["estimated_error"], reference, spans, fine_cpu)
            for q, e, reference in entries]


def coverage_row(case, quantity, grids, values, text, value, error, reference, spans,
                 cpu) -> str:
    distance = abs(value - reference)
    ratio = error / distance if distance > 0 else float("inf")
    return (f"| {case} | {quantity} | {grids} | {', '.join(f'{v:.10g}' for v in values[-3:])} "
            f"| {text} | {reference:.10g} ({spans}) | {distance:.2g} | {ratio:.3g} | "
            f"{'yes' if error >= distance else '**no**'} | {cpu:.1f} |")


def print_coverage(rows: list[str]) -> None:
    if not rows:
        return
    print("\nestimate of the adaptive run (last load) against the finer solve (per row)\n")
    print("| case | quantity | adaptive grids | last three values | estimate ± bar (how) | "
          "finer reference (spans) | distance | bar / distance | holds | CPU fine [s] |")
    print("|---|---|---|---|---|---|---|---|---|---|\n" + "\n".join(rows), flush=True)


def validation_rows(cases, tolerance: float, budget: int, fine: bool = True,
                    uniform: bool = True) -> None:
    from taichi_ndf.discretise.adaptive import AdaptiveDiscretisation
    from taichi_ndf.validation import CASES, runner
    from taichi_ndf.validation.catalogue import LINEARISATION

    original = runner.discretisation

    def adaptive_factory(spec, model, *, objective=None, estimate=None):
        d = AdaptiveDiscretisation(spec, model, AdaptiveConfig(tolerance, budget, INDICATOR[0]),
                                   objective=objective)
        d.for_case = lambda scene_solver, quick_solver, **_: (d, scene_solver)
        captured.append(d)
        return d

    print(f"\nvalidation cases: --tolerance {tolerance:g} (budget {budget} unknowns) and 3 "
          "uniform grids (`ndf-validate --field spline`)\n")
    print("| case | quantity | load | refinement | grids | finest unknowns | value | "
          "reference | error | CPU [s] | wall [s] | load avg |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    coverage, outcomes = [], []
    for name in cases:
        case = CASES[name]
        for label in ("uniform", "adaptive")[0 if uniform else 1:]:
            captured: list = []
            runner.discretisation = original if label == "uniform" else adaptive_factory
            cpu, wall = cpu_seconds(), time.perf_counter()
            result = runner.run_case(case, field="spline")
            cpu, wall = cpu_seconds() - cpu, time.perf_counter() - wall
            spans = result.solver.get("spans", [[0, 0]])
            grids = " / ".join(f"{s[0]}×{s[1]}" for s in spans)
            finest = unknowns(captured[-1].run.field.config) if captured else None
            if finest is None:
                _, _, plan = runner.load_case_scene(case, field="spline")
                config = plan.config
                for _ in range(len(spans) - 1):
                    config = config.refined()
                finest = unknowns(config)
            for row in result.rows:
                error = "—" if row.relative_error is None else f"{100 * row.relative_error:.3f} %"
                print(f"| {name} | {row.quantity} | {row.level:g} | {label} | {grids} | "
                      f"{finest} | {row.computed:.7g} | {row.reference:.6g} | {error} | "
                      f"{cpu:.1f} | {wall:.1f} | {os.getloadavg()[0]:.1f} |", flush=True)
            if label == "uniform" and not fine:  # its grids' values and their estimate
                order = 4.0  # 2(p − 1), cubic
                for key, (_axis, values) in result.convergence.items():
                    if not key.endswith(f"@ {result.rows[-1].level:g}") or len(values) < 3:
                        continue
                    estimate = richardson(list(values), order=order)
                    coverage.append(f"| {name} (uniform) | {key} | "
                                    f"{', '.join(f'{v:.7g}' for v in values)} | "
                                    f"{estimate.describe()} | | | | | |")
            if label == "adaptive":
                outcomes.append(outcome_line(name, captured[-1].run))
                coverage += case_coverage(case, result, captured[-1], LINEARISATION, runner,
                                          fine)
        runner.discretisation = original
    print_coverage(coverage)
    print("\n" + "\n".join(outcomes))


def case_coverage(case, result, discretisation, linearisation, runner, fine: bool = True
                  ) -> list[str]:
    """Rows: each quantity at the last load factor and Π, the adaptive estimate against a
    solve on a uniform grid of 2 × the final spans per direction (fine: else the estimate
    alone, with its published reference where the quantity has one); the uniform grid keeps
    the band ends' knot lines (`spline_grid.band_end_config`)."""
    run, model = discretisation.run, discretisation.model
    unit = linearisation if case.linear else 1.0
    last = run.load_steps[-1]["load_factor"]
    positions = runner._reference_positions(model, run.field.coefficients.dtype)
    fine_config = dataclasses.replace(  # uniform, but the band ends' knot lines stay: without
        run.field.config, spans=tuple(2 * n for n in run.field.config.spans),  # them the finer
        grading=tuple(g if isinstance(g, KnotLines) else None  # solve is the less accurate one
                      for g in run.field.config.grading))
    if not fine:
        rows = []
        for q in case.quantities:
            if abs(q.level - last) > 1e-12:
                continue
            values = [q.read({n: np.asarray(v) / unit for n, v in lv.probes.items()}, positions)
                      for lv in run.levels]
            estimate = richardson(values, order=2.0 * (run.field.config.degree - 1))
            rows.append(f"| {case.name} | {q.name} | {', '.join(f'{v:.7g}' for v in values)} "
                        f"| {estimate.describe()} | published {q.reference:.6g} (no fine solve) "
                        f"| {abs(estimate.value - q.reference):.2g} | | "
                        f"{'yes' if abs(estimate.value - q.reference) <= estimate.error else 'no'}"
                        " | |")
        return rows
    cpu = cpu_seconds()
    _, fine = solve_on(model, run.field, fine_config, discretisation.spec, run.config,
                       discretisation.objective or runner._objective(case, model),
                       coarse_energy=run.energy, smooth=run.smooth,
                       gauge_moved=run.gauge_moved)
    cpu = cpu_seconds() - cpu
    fine_readings = {n: np.asarray(v, dtype=np.float64) / unit for n, v in fine.probes.items()}
    grids = " / ".join(f"{lv.spans[0]}×{lv.spans[1]}" for lv in run.levels)
    spans = f"{fine_config.spans[0]}×{fine_config.spans[1]}"
    rows = []
    quantities = [("Π [J]", [lv.energy for lv in run.levels], fine.energy)]
    for q in case.quantities:
        if abs(q.level - last) > 1e-12:
            continue
        per_level = [q.read({n: np.asarray(v) / unit for n, v in lv.probes.items()}, positions)
                     for lv in run.levels]
        quantities.append((q.name, per_level, q.read(fine_readings, positions)))
    errors = [None] + [read_errors(q, run, positions, unit) for q in case.quantities
                       if abs(q.level - last) <= 1e-12]
    for (name, values, reference), solve_errors in zip(quantities, errors, strict=True):
        # as result.json's: Π of a smooth model, and a probe's with its solve errors
        # (`GridLevels`' probe stop), at the a-priori order past the floor
        estimate = richardson(values, order=2.0 * (run.field.config.degree - 1),
                              smooth=run.smooth and (name == "Π [J]" or solve_errors is not None),
                              solve_errors=solve_errors)
        rows.append(coverage_row(case.name, name, grids, values, estimate.describe(),
                                 estimate.value, estimate.error, reference, spans, cpu))
    return rows


def read_errors(quantity, run, positions, unit: float) -> list[float] | None:
    """A quantity's solve error per level from its probes' (`LevelSummary.probe_errors`,
    per component): the sum over probe components of the read's change when that component
    alone moves by its solve error (None: a level without them, or a read that a component
    a gauge motion moves changes: `SplineRun.gauge_moved`, no solve error of its own)."""
    out = []
    for lv in run.levels:
        if lv.probe_errors is None:
            return None
        probes = {n: np.asarray(v, dtype=np.float64) / unit for n, v in lv.probes.items()}
        base, total = quantity.read(probes, positions), 0.0
        for name, error in lv.probe_errors.items():
            for c, e in enumerate(error):
                gauge = f"{name}:{c}" in run.gauge_moved  # does the read depend on it?
                moved = {n: v.copy() for n, v in probes.items()}
                moved[name][c] += 1e-6 * max(float(np.linalg.norm(probes[name])), 1e-300) \
                    if gauge else e / unit
                change = abs(quantity.read(moved, positions) - base)
                if gauge and change > 0.0:
                    return None
                total += 0.0 if gauge else change
        out.append(total)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--parts", default="napkin,validation")
    parser.add_argument("--start", type=int, default=6, help="napkin: n × n first spans")
    parser.add_argument("--napkin-budget", type=int, default=3000)
    parser.add_argument("--napkin-tolerance", type=float, default=3e-3)
    parser.add_argument("--napkin-levels", type=int, default=3, help="uniform: grids")
    parser.add_argument("--napkin-rows", default="uniform;uniform 8²;features per level;"
                        "features 24² single", help="semicolon-separated row labels "
                        "(NAPKIN_ROWS)")
    parser.add_argument("--tolerance", type=float, default=1e-3)
    parser.add_argument("--budget", type=int, default=20000)
    parser.add_argument("--indicator", default="density",
                        help="the adaptive rows' indicator (none: dyadic, as uniform)")
    parser.add_argument("--scenes", default="napkin_interior_point,napkin_interior_line",
                        help="interior: the shipped scenes")
    parser.add_argument("--scene-budget", type=int, default=6000,
                        help="interior: the budget of unknowns")
    parser.add_argument("--no-fine", action="store_true",
                        help="validation, interior: no fine reference solve (too large for "
                        "the machine)")
    parser.add_argument("--cases", default="square_plate,cantilever_shear,scordelis_lo_roof")
    parser.add_argument("--no-uniform", action="store_true",
                        help="validation, interior: the adaptive rows only")
    args = parser.parse_args()
    INDICATOR[0] = args.indicator
    taichi_ndf.init(arch="cpu", precision="f64", seed=0)
    torch.set_num_threads(1)
    print(f"commit {commit()}, {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, "
          f"load {os.getloadavg()[0]:.1f}")
    parts = args.parts.split(",")
    if "coverage" in parts:
        INDICATOR[0] = "features"
        napkin_rows(6, 3000, 3e-3, rows=("features per level",))
        interior_rows(COVERAGE["scenes"], 1e-3, 10_000, uniform=False)
        validation_rows(COVERAGE["cases"], 1e-3, 15_000, uniform=False)
    if "napkin" in parts:
        rows = tuple(args.napkin_rows.split(";"))
        napkin_rows(args.start, args.napkin_budget, args.napkin_tolerance, args.napkin_levels,
                    rows)
    if "interior" in parts:
        interior_rows(args.scenes.split(","), args.tolerance, args.scene_budget,
                      fine=not args.no_fine, uniform=not args.no_uniform)
    if "validation" in parts:
        validation_rows(args.cases.split(","), args.tolerance, args.budget, not args.no_fine,
                        not args.no_uniform)


if __name__ == "__main__":
    main()
