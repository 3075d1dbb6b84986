"""Napkin (scenes/napkin.toml: 1 m cloth square hanging from a free pin at one corner) by
spline + projected Newton, coarse to fine: the time to a Π within 1 % of the
refinement-extrapolated Π (issue 19's target: ≤ 10 s on one core).

Per grid: Newton steps, Π, its gap to the reference Π∞, the time to reach this grid (all
coarser grids included; setup of each grid included) and the split of the Newton iterations'
time (energy + line search, Hessian blocks, assembly, solve); then Richardson from the last
three grids. Kernels are compiled (or loaded from the cache) before the clock starts, on a
2 × 2 grid: that time is printed apart.

    OMP_NUM_THREADS=1 python benchmarks/napkin_newton.py [--levels 3] [--coarsest 7]
        [--tolerance 1e-4] [--coarse-tolerance T] [--reference -1.3318] [--precision f64]
        [--hessian clamp|abs] [--parts]

The default grids 7², 14², 28² reach 0.90 % from Π∞ (benchmarks/RESULTS.md; 3² → 24²: 0.96 %,
2² → 16²: 1.30 %, 2² → 32²: 0.79 %: the napkin converges with order ~0.75 under refinement).

--parts: also the CPU time of each part of one Newton step at the finest grid's solution
(median of 3), with the central-difference Hessian blocks (`sample_hessians`) for comparison.
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import math
import time
from pathlib import Path
from types import SimpleNamespace

import torch

import taichi_ndf
from taichi_ndf.field.spline import SplineConfig, SplineField
from taichi_ndf.minimise.assembly import Assembly, gauge_unknowns, local_basis_at
from taichi_ndf.minimise.linear_solve import damped_solve
from taichi_ndf.minimise.newton import NewtonConfig
from taichi_ndf.minimise.refinement import richardson, solve_levels
from taichi_ndf.objective import Objective
from taichi_ndf.problem.operator import DisplacementOperator
from taichi_ndf.problem.quadrature import span_quadrature
from taichi_ndf.scene.reader import load_scene
from taichi_ndf.shell.hessian import (
    PROJECTIONS,
    flat_blocks,
    indefinite_blocks,
    jet_steps,
    project_psd,
    sample_hessians,
)

SCENE = Path(__file__).resolve().parents[1] / "scenes" / "napkin.toml"
# Richardson from 8², 16², 32² spans solved to the rounding floor (benchmarks/RESULTS.md,
# 2026-12-01): −1.3318 J, estimated error 0.0096 J.
REFERENCE = -1.3318
SPLIT = ("energy", "hessian", "assembly", "solve")


def solve(model, levels: int, coarsest: int, config: NewtonConfig,
          coarse_config: NewtonConfig | None = None, on_level=None):
    surface = model.surface
    field = SplineField(SplineConfig(spans=(coarsest, coarsest), degree=3,
                                     domain=surface.domain.bounds))
    return solve_levels(field, model.boundary,
                        lambda f: span_quadrature(surface, f.config, model.loads),
                        Objective.of_model(model), levels=levels, config=config,
                        coarse_config=coarse_config, on_level=on_level,
                        probes={p.name: p.xi for p in model.probes},
                        length=math.sqrt(surface.domain.rectangle_area))


def newton_system(model, spans: tuple[int, int], coefficients: torch.Tensor
                  ) -> SimpleNamespace:
    """One projected-Newton step's pieces on `spans` at these coefficients (C (n, 3)): the
    assembly, its samples s, the jets u, Π (potential) and its result, the FD steps, the exact
    blocks, the indefinite ones (bad) and the projected ones, the matrix K, the right-hand side
    −g and the held (gauge) unknowns."""
    surface = model.surface
    field = SplineField(SplineConfig(spans=spans, degree=3, domain=surface.domain.bounds))
    samples = span_quadrature(surface, field.config, model.loads)
    operator = DisplacementOperator(field, model.boundary)
    basis = local_basis_at(operator, samples.xi)
    assembly = Assembly(samples, basis, field.coefficients.shape[0]).at_load(operator, 1.0)
    potential = Objective.of_model(model).potential(1.0)
    s = assembly.samples
    u = assembly.displacement(coefficients)
    result = potential(s, u, True)
    steps = jet_steps(s.r_jets, u, math.sqrt(surface.domain.rectangle_area), 1e-5)
    blocks = flat_blocks(potential.hessian_blocks(s, u, steps=steps))
    bad = indefinite_blocks(blocks)
    projected, _ = project_psd(blocks, bad)
    return SimpleNamespace(
        assembly=assembly, s=s, u=u, potential=potential, result=result, steps=steps,
        blocks=blocks, bad=bad, projected=projected, matrix=assembly.hessian(projected),
        rhs=-assembly.gradient(result.grad_u_jets).reshape(-1).numpy(),
        fixed=gauge_unknowns(model.boundary, basis))


def step_parts(model, spans: tuple[int, int], coefficients: torch.Tensor) -> list[tuple]:
    """CPU seconds (median of 3) of each part of a Newton step at these coefficients."""
    n = newton_system(model, spans, coefficients)
    parts = [
        ("displacement U = offset + J C", lambda: n.assembly.displacement(coefficients)),
        ("energy + autodiff gradient dΠ/dU", lambda: n.potential(n.s, n.u, True)),
        ("energy alone (a line-search trial)", lambda: n.potential(n.s, n.u, False)),
        ("gradient pull-back dΠ/dC", lambda: n.assembly.gradient(n.result.grad_u_jets)),
        ("Hessian blocks through the strains", lambda: n.potential.hessian_blocks(
            n.s, n.u, steps=n.steps)),
        ("Hessian blocks by central differences (before)", lambda: sample_hessians(
            n.potential, n.s, n.u, steps=n.steps)),
        ("indefinite-block screen (batched Cholesky)", lambda: indefinite_blocks(n.blocks)),
        (f"projection ({n.bad.numel()} of {len(n.s)} blocks eigen-decomposed)",
         lambda: project_psd(n.blocks, n.bad)),
        ("assembly K = Σ Jᵀ H J", lambda: n.assembly.hessian(n.projected)),
        ("factorise + solve (damped_solve: banded Cholesky)",
         lambda: damped_solve(n.matrix, n.rhs, 0.0, n.fixed)),
    ]
    out = []
    for name, part in parts:
        part()
        times = []
        for _ in range(3):
            started = time.process_time()
            part()
            times.append(time.process_time() - started)
        out.append((name, sorted(times)[1]))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--levels", type=int, default=3)
    parser.add_argument("--coarsest", type=int, default=7)
    parser.add_argument("--tolerance", type=float, default=1e-4,
                        help="Newton decrement tolerance λ²/2 relative to |Π|")
    parser.add_argument("--coarse-tolerance", type=float, default=None,
                        help="decrement tolerance of the levels before the finest (default: "
                        "--tolerance)")
    parser.add_argument("--reference", type=float, default=REFERENCE,
                        help="the extrapolated Π∞ [J] the gap is measured against")
    parser.add_argument("--precision", choices=("f32", "f64"), default="f64")
    parser.add_argument("--hessian", choices=PROJECTIONS, default=NewtonConfig.hessian,
                        help="Hessian modification of projected Newton (NewtonConfig)")
    parser.add_argument("--verbose", action="store_true", help="log every Newton iteration")
    parser.add_argument("--parts", action="store_true",
                        help="time each part of a Newton step at the finest grid")
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(asctime)s %(name)s: %(message)s")
    torch.set_num_threads(1)
    taichi_ndf.init(arch="cpu", precision=args.precision)
    model = load_scene(SCENE).model
    f64 = args.precision == "f64"
    config = NewtonConfig(fd_step=1e-5 if f64 else 3e-3,
                                   decrement_tolerance=args.tolerance,
                                   gradient_tolerance=1e-10 if f64 else 1e-5,
                                   floor_tolerance=1e-8 if f64 else 1e-6,
                                   hessian=args.hessian)
    coarse = None if args.coarse_tolerance is None else dataclasses.replace(
        config, decrement_tolerance=args.coarse_tolerance)
    started = time.perf_counter()
    solve(model, 1, 2, NewtonConfig(max_iterations=2))  # compile / load kernels
    compile_seconds = time.perf_counter() - started
    started, cpu = time.perf_counter(), time.process_time()
    level_cpu = []
    results = solve(model, args.levels, args.coarsest, config, coarse,
                    on_level=lambda *_: level_cpu.append(time.process_time() - cpu))
    wall, cpu = time.perf_counter() - started, time.process_time() - cpu
    print(f"napkin, spline cubic + projected Newton ({args.hessian}), {args.precision}, "
          f"decrement tolerance {args.tolerance:g} (coarser levels "
          f"{args.coarse_tolerance or args.tolerance:g}); kernels compiled/loaded before: "
          f"{compile_seconds:.1f} s")
    print(f"reference Π∞ = {args.reference} J")
    print("| spans | Newton steps | Π [J] | gap to Π∞ | wall to this grid [s] | "
          "CPU to this grid [s] | energy / Hessian / assembly / solve [s, wall] |")
    print("|---|---|---|---|---|---|---|")
    elapsed = 0.0
    for level, level_seconds in zip(results, level_cpu, strict=True):
        last = level[-1]
        elapsed += sum(s.seconds for s in level)
        history = [h for s in level for h in s.history]
        split = " / ".join(f"{sum(getattr(h, 'time_' + k) for h in history):.2f}"
                           for k in SPLIT)
        gap = (last.energy - args.reference) / abs(args.reference)
        print(f"| {last.spans[0]} × {last.spans[1]} | {len(history)} | {last.energy:.5f} | "
              f"{100 * gap:+.2f} % | {elapsed:.2f} | {level_seconds:.2f} | {split} |")
    energies = [level[-1].energy for level in results]
    if len(energies) >= 3:
        e = richardson(energies)
        gap = (e.value - args.reference) / abs(args.reference)
        order = "not trusted" if e.order is None else f"order {e.order:.2f}"
        print(f"Richardson from the last three grids: Π∞ = {e.value:.5f} J ({order}, "
              f"estimated error {e.error:.4f} J), {100 * gap:+.2f} % from the reference")
    print(f"wall {wall:.2f} s, CPU {cpu:.2f} s (this process; the two differ by the time the "
          "machine's other load took the core)")
    if args.parts:
        last = results[-1][-1]
        print(f"\nparts of one Newton step at {last.spans[0]} × {last.spans[1]} spans "
              "(CPU ms, median of 3):")
        for name, seconds in step_parts(model, last.spans, last.coefficients):
            print(f"| {name} | {1000 * seconds:.1f} |")


if __name__ == "__main__":
    main()
