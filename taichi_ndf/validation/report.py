"""The validation report: results.md, results.json and one convergence plot per case."""

from __future__ import annotations

import dataclasses

import numpy as np

import taichi_ndf
from taichi_ndf.io import OutputDir
from taichi_ndf.render import plot_curves, save_png
from taichi_ndf.runtime import machine_description
from taichi_ndf.validation.runner import CaseResult, Row


def markdown_table(rows: list[Row]) -> str:
    """The results as a Markdown table."""
    lines = ["| case | quantity | load | computed | reference | rel. error | target | "
             "Adam iterations | Newton steps | wall time [s] | samples (Adam / Newton) |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        computed = "not run" if r.computed is None else f"{r.computed:.5g}"
        if r.relative_error is None:
            error = "–"
        else:
            error = f"{100 * r.relative_error:.2f} %" + ("" if r.passed else " ✗")
        lines.append(f"| {r.case} | {r.quantity} | {r.level:g} | {computed} | {r.reference:.5g} "
                     f"| {error} | {100 * r.tolerance:g} % | {r.iterations} | {r.newton_steps} | "
                     f"{r.wall_time:.0f} | {r.samples} / {r.newton_samples} |")
    return "\n".join(lines) + "\n"


def convergence_plot(result: CaseResult) -> np.ndarray:
    """Computed / reference of each quantity against the iteration count, or the grid level
    of a spline refinement study (BGR image)."""
    series = {}
    references = {f"{q.name} @ {q.level:g}": q.reference for q in result.case.quantities}
    for key, (iterations, values) in result.convergence.items():
        series[key] = (np.asarray(iterations, float),
                       np.asarray(values, float) / references[key])
    if series:
        first = min(min(x) for x, _ in series.values() if len(x))
        last = max(max(x) for x, _ in series.values() if len(x))
        series["reference"] = (np.array([first, last], float), np.ones(2))
    return plot_curves(series, title=f"{result.case.name}: value / reference",
                       xlabel=result.solver.get("convergence_axis", "iteration"),
                       ylabel="computed / reference")


def write_report(results: list[CaseResult], out: OutputDir, *, quick: bool) -> None:
    """results.md, results.json and <case>_convergence.png into `out`."""
    rows = [r for res in results for r in res.rows]
    machine = machine_description(taichi_ndf.current())
    header = (f"Protocol: {'--quick' if quick else 'full'} run; precision {machine['precision']}"
              f", {machine['arch']} ({machine['processor']}, {machine['cpus']} CPUs).\n\n")
    out.write_text("results.md", "# Validation results\n\n" + header + markdown_table(rows))
    out.write_json("results.json", {
        "quick": quick,
        "machine": machine,
        "rows": [dataclasses.asdict(r) for r in rows],
        "cases": {res.case.name: {"solver": res.solver,
                                  "convergence": {k: {"iteration": list(map(int, x)),
                                                      "value": list(map(float, y))}
                                                  for k, (x, y) in res.convergence.items()}}
                  for res in results},
    })
    for res in results:
        if res.convergence:
            save_png(out.file(f"{res.case.name}_convergence.png"), convergence_plot(res))
