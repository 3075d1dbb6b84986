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
from taichi_ndf.minimise.assembly import Assembly, gauge_unknowns, local_basis_at
from taichi_ndf.minimise.linear_solve import damped_solve
from taichi_ndf.minimise.newton import NewtonConfig
from taichi_ndf.objective import Objective
from taichi_ndf.problem.operator import DisplacementOperator
from taichi_ndf.problem.quadrature import span_quadrature
from taichi_ndf.scene.reader import load_scene
from taichi_ndf.shell.hessian import flat_blocks, indefinite_blocks, jet_steps, project_psd

sys.path.insert(0, str(Path(__file__).resolve().parent))
from napkin_newton import SCENE, solve  # noqa: E402


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
    surface = model.surface
    field = SplineField(SplineConfig(spans=(spans, spans), degree=3,
                                     domain=surface.domain.bounds))
    samples = span_quadrature(surface, field.config, model.loads)
    operator = DisplacementOperator(field, model.boundary)
    basis = local_basis_at(operator, samples.xi)
    assembly = Assembly(samples, basis, field.coefficients.shape[0]).at_load(operator, 1.0)
    fixed = gauge_unknowns(model.boundary, basis)
    potential = Objective.of_model(model).potential(1.0)
    s = assembly.samples
    u = assembly.displacement(coefficients)
    result = potential(s, u, True)
    steps = jet_steps(s.r_jets, u, math.sqrt(surface.domain.rectangle_area), 1e-5)
    blocks = flat_blocks(potential.hessian_blocks(s, u, steps=steps))
    bad = indefinite_blocks(blocks)
    projected, _ = project_psd(blocks, bad)
    matrix = assembly.hessian(projected)
    rhs = -assembly.gradient(result.grad_u_jets).reshape(-1).numpy()
    out = {
        "unknowns": assembly.size, "points": len(s), "indefinite": int(bad.numel()),
        "displacement": cpu_ms(lambda: assembly.displacement(coefficients), repeats),
        "energy + gradient": cpu_ms(lambda: potential(s, u, True), repeats),
        "pull-back": cpu_ms(lambda: assembly.gradient(result.grad_u_jets), repeats),
        "blocks (exact)": cpu_ms(lambda: potential.hessian_blocks(s, u, steps=steps), repeats),
        "screen": cpu_ms(lambda: indefinite_blocks(blocks), repeats),
        "projection": cpu_ms(lambda: project_psd(blocks, bad), repeats),
        "assembly": cpu_ms(lambda: assembly.hessian(projected), repeats),
        "factorise + solve": cpu_ms(lambda: damped_solve(matrix, rhs, 0.0, fixed), repeats),
    }
    if hasattr(potential, "psd_hessian_blocks"):
        out["blocks (PSD, strains)"] = cpu_ms(
            lambda: potential.psd_hessian_blocks(s, u, steps=steps), repeats)
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
