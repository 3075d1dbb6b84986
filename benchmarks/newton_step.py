"""Where one projected-Newton step goes on the napkin, against the factorisation floor (issue 28).

The napkin (scenes/napkin.toml) is solved coarse to fine to 28² spans (`napkin_newton.solve`,
decrement tolerance 1e-4); at that solution, and at it prolonged exactly to 56² spans, each part
of a Newton step is timed (CPU ms, median of `--repeats`, one thread): the displacement, Π and
its gradient, the pull-back to the coefficients, the per-point Hessian blocks (exact; and
positive semi-definite through the strains where the code has them: `psd_hessian_blocks`), the
indefinite-block screen and the eigen-projection of the blocks it finds, the assembly
K = Σ Jᵀ H J and the factorisation + solve (`damped_solve`: banded Cholesky). Then three steps
and their ratio to the factorisation + solve: with the exact K (no projection), with the
clamped projection (screen + eigh) and with the "strain" treatment (PSD blocks, no screen).

    OMP_NUM_THREADS=1 python benchmarks/newton_step.py [--spans 28 56] [--repeats 3]

It imports only what the code before issue 28 had too, so the same file times an older
checkout (PYTHONPATH=that checkout).
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import torch

import taichi_ndf
from taichi_ndf.field.spline import SplineConfig, SplineField
from taichi_ndf.minimise.linear_solve import damped_solve
from taichi_ndf.minimise.newton import NewtonConfig
from taichi_ndf.scene.reader import load_scene
from taichi_ndf.shell.hessian import indefinite_blocks, project_psd

sys.path.insert(0, str(Path(__file__).resolve().parent))
from napkin_newton import SCENE, newton_system, solve  # noqa: E402


def cpu_ms(part, repeats: int) -> float:
    """Median CPU milliseconds of `repeats` calls after one warm-up call."""
    part()
    times = []
    for _ in range(repeats):
        started = time.process_time()
        part()
        times.append(time.process_time() - started)
    return 1000 * sorted(times)[len(times) // 2]


def parts_at(model, spans: int, coefficients: torch.Tensor, repeats: int) -> dict:
    """CPU ms of each part of a Newton step on `spans`² spans at these coefficients."""
    n = newton_system(model, (spans, spans), coefficients)
    out = {
        "unknowns": n.assembly.size, "points": len(n.s),
        "indefinite": int(n.bad.numel()),
        "displacement": cpu_ms(lambda: n.assembly.displacement(coefficients), repeats),
        "energy + gradient": cpu_ms(lambda: n.potential(n.s, n.u, True), repeats),
        "pull-back": cpu_ms(lambda: n.assembly.gradient(n.result.grad_u_jets), repeats),
        "blocks (exact)": cpu_ms(
            lambda: n.potential.hessian_blocks(n.s, n.u, steps=n.steps), repeats),
        "screen": cpu_ms(lambda: indefinite_blocks(n.blocks), repeats),
        "projection": cpu_ms(lambda: project_psd(n.blocks, n.bad), repeats),
        "assembly": cpu_ms(lambda: n.assembly.hessian(n.projected), repeats),
        "factorise + solve": cpu_ms(lambda: damped_solve(n.matrix, n.rhs, 0.0, n.fixed), repeats),
    }
    if hasattr(n.potential, "psd_hessian_blocks"):
        out["blocks (PSD, strains)"] = cpu_ms(
            lambda: n.potential.psd_hessian_blocks(n.s, n.u, steps=n.steps), repeats)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--spans", type=int, nargs="+", default=[28, 56])
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    torch.set_num_threads(1)
    taichi_ndf.init(arch="cpu", precision="f64")
    model = load_scene(SCENE).model
    coarsest = min(args.spans) // 4
    levels = solve(model, 3, coarsest, NewtonConfig(decrement_tolerance=1e-4))
    field = SplineField(SplineConfig(spans=levels[-1][-1].spans, degree=3,
                                     domain=model.surface.domain.bounds))
    field.coefficients.copy_(levels[-1][-1].coefficients)
    rows = []
    for spans in sorted(args.spans):
        while field.config.spans[0] < spans:
            field = field.refined()
        rows.append((spans, parts_at(model, spans, field.coefficients, args.repeats)))
    names = [k for k in rows[0][1] if k not in ("unknowns", "points", "indefinite")]
    print("| part [CPU ms] | " + " | ".join(
        f"{s}² ({p['unknowns']} unknowns, {p['indefinite']} of {p['points']} blocks "
        "indefinite)" for s, p in rows) + " |")
    print("|---|" + "---|" * len(rows))
    for name in names:
        print(f"| {name} | " + " | ".join(f"{p.get(name, math.nan):.1f}" for _, p in rows) + " |")
    common = ("displacement", "energy + gradient", "pull-back", "assembly", "factorise + solve")
    for label, extra in (("step, exact K", ("blocks (exact)",)),
                         ("step, clamped projection", ("blocks (exact)", "screen", "projection")),
                         ("step, strain PSD", ("blocks (PSD, strains)",))):
        cells = []
        for _, p in rows:
            total = sum(p.get(k, math.nan) for k in common + extra)
            cells.append(f"{total:.1f} ({total / p['factorise + solve']:.1f}×)")
        print(f"| {label} (× factorise + solve) | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
