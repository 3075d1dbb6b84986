"""Linear solvers for projected Newton's systems K d = −g on large spline grids: direct
(`damped_solve`) against CG preconditioned by the geometric multigrid V-cycle
(`LinearSolver`, kind "multigrid"), on the napkin (scenes/napkin.toml: a cloth square hanging
from a free pin; float64, cubic).

The systems are the ones a coarse-to-fine solve meets: the napkin solved on `--start` × `--start`
spans (from 2 × 2, coarse to fine, decrement tolerance 1e-4), prolonged exactly to each grid of
`--spans`, and K (projected Hessian blocks) and g assembled there. Per grid: unknowns, the
direct (`damped_solve`: banded Cholesky here) factor + solve time, and per smoother the
multigrid setup time (Galerkin operators, smoother and coarsest factorisations), CG
iterations, their time, and each solution's relative residual ‖K d + g‖/‖g‖ over the free
unknowns.

--newton S: also the end-to-end check, one full Newton solve on S × S spans from the prolonged
start with each solver (Newton iterations, solve time, total time, final Π).

    OMP_NUM_THREADS=1 python benchmarks/linear_solvers.py [--spans 32 64 128] [--start 8]
        [--newton 64] [--tolerance 1e-8]
"""

from __future__ import annotations

import argparse
import logging
import math
import time
from pathlib import Path

import numpy as np
import torch

import taichi_ndf
from taichi_ndf.field.spline import SplineConfig, SplineField
from taichi_ndf.minimise.assembly import Assembly, local_basis_at
from taichi_ndf.minimise.linear_solve import LinearSolver, LinearSolverConfig, damped_solve
from taichi_ndf.minimise.linearisation import SplineLinearisation
from taichi_ndf.minimise.newton import NewtonConfig, minimise
from taichi_ndf.minimise.refinement import held_unknowns, solve_levels
from taichi_ndf.objective import Objective
from taichi_ndf.problem.operator import DisplacementOperator
from taichi_ndf.problem.quadrature import span_quadrature
from taichi_ndf.scene.reader import load_scene
from taichi_ndf.shell.hessian import flat_blocks, indefinite_blocks, jet_steps, project_psd

SCENE = Path(__file__).resolve().parents[1] / "scenes" / "napkin.toml"
NEWTON = NewtonConfig(decrement_tolerance=1e-4)


def start_field(model, spans: int) -> SplineField:
    """The napkin solved on spans × spans (coarse to fine from 2 × 2)."""
    surface = model.surface
    field = SplineField(SplineConfig(spans=(2, 2), degree=3, domain=surface.domain.bounds))
    levels = int(round(math.log2(spans)))
    results = solve_levels(field, model.boundary,
                           lambda f: span_quadrature(surface, f.config, model.loads),
                           Objective.of_model(model), levels=levels, config=NEWTON,
                           probes={p.name: p.xi for p in model.probes},
                           length=math.sqrt(surface.domain.rectangle_area))
    for _ in range(levels - 1):
        field = field.refined()
    field.coefficients.copy_(results[-1][-1].coefficients)
    return field


def prolonged(field: SplineField, spans: int) -> SplineField:
    while field.config.spans[0] < spans:
        field = field.refined()
    return field


def newton_problem(model, field: SplineField):
    """Assembly (at load 1), the potential, held unknowns and length of the field's grid."""
    surface = model.surface
    samples = span_quadrature(surface, field.config, model.loads)
    operator = DisplacementOperator(field, model.boundary)
    basis = local_basis_at(operator, samples.xi)
    assembly = Assembly(samples, basis, field.coefficients.shape[0]).at_load(operator, 1.0)
    fixed = held_unknowns(field, model.boundary, basis)
    return assembly, Objective.of_model(model).potential(1.0), fixed


def system(model, field: SplineField):
    """K (projected), −g and the held unknowns at the field's coefficients."""
    assembly, potential, fixed = newton_problem(model, field)
    s = assembly.samples
    u = assembly.displacement(field.coefficients)
    result = potential(s, u, True)
    steps = jet_steps(s.r_jets, u, math.sqrt(model.surface.domain.rectangle_area), 1e-5)
    blocks = flat_blocks(potential.hessian_blocks(s, u, steps=steps))
    blocks, _ = project_psd(blocks, indefinite_blocks(blocks))
    matrix = assembly.hessian(blocks)
    rhs = -assembly.gradient(result.grad_u_jets).reshape(-1).double().numpy()
    rhs[fixed] = 0.0
    return matrix, rhs, fixed


def residual(matrix, rhs, x, fixed) -> float:
    r = matrix @ x - rhs
    r[fixed] = 0.0
    return float(np.linalg.norm(r) / np.linalg.norm(rhs))


def linear_table(model, start: SplineField, spans_list, tolerance: float) -> None:
    print(f"napkin Newton systems (start: {start.config.spans[0]}² solution prolonged), "
          f"CG tolerance {tolerance:g}")
    print("| spans | unknowns | non-zeros | direct factor + solve [s] | residual | "
          "smoother | MG levels | MG setup [s] | CG iterations | CG [s] | MG total [s] | "
          "residual |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for spans in spans_list:
        field = prolonged(start, spans)
        matrix, rhs, fixed = system(model, field)
        started = time.perf_counter()
        direct, _ = damped_solve(matrix, rhs, 0.0, fixed)
        direct_seconds = time.perf_counter() - started
        head = (f"| {spans} × {spans} | {matrix.shape[0]} | {matrix.nnz} | "
                f"{direct_seconds:.2f} | {residual(matrix, rhs, direct, fixed):.1e} |")
        for smoother in ("gauss_seidel", "jacobi"):
            config = LinearSolverConfig(kind="multigrid", tolerance=tolerance,
                                        smoother=smoother, max_iterations=1000)
            solver = LinearSolver.for_grid(field.config, config)
            x, _ = solver(matrix, rhs, 0.0, fixed)
            cg = solver.last
            levels = 1 + len(solver.prolongations)
            if cg is None:
                print(f"{head} {smoother} | {levels} | direct fallback | | | | "
                      f"{residual(matrix, rhs, x, fixed):.1e} |")
            else:
                print(f"{head} {smoother} | {levels} | {cg.setup_seconds:.2f} | "
                      f"{cg.iterations} ({cg.status}) | {cg.solve_seconds:.2f} | "
                      f"{cg.setup_seconds + cg.solve_seconds:.2f} | "
                      f"{residual(matrix, rhs, x, fixed):.1e} |")
            head = "| | | | | |"


def newton_check(model, start: SplineField, spans: int, tolerances) -> None:
    field = prolonged(start, spans)
    assembly, potential, fixed = newton_problem(model, field)
    length = math.sqrt(model.surface.domain.rectangle_area)
    print(f"\none Newton solve on {spans} × {spans} spans from the {start.config.spans[0]}² "
          f"solution prolonged (decrement tolerance {NEWTON.decrement_tolerance:g})")
    print("| linear solver | Newton iterations | solve time [s] | total [s] | total CPU [s] | "
          "final Π [J] |")
    print("|---|---|---|---|---|---|")
    runs = [("direct (banded Cholesky)", None)] + [
        (f"multigrid, CG tolerance {t:g}", LinearSolver.for_grid(
            field.config, LinearSolverConfig(kind="multigrid", tolerance=t)))
        for t in tolerances]
    for name, solver in runs:
        started, cpu = time.perf_counter(), time.process_time()
        linearisation = SplineLinearisation(assembly, fixed=fixed, solver=solver, length=length)
        solution = minimise(linearisation, potential, field.coefficients, NEWTON)
        total, cpu = time.perf_counter() - started, time.process_time() - cpu
        solve = sum(h.time_solve for h in solution.history)
        print(f"| {name} | {len(solution.history)} | {solve:.2f} | {total:.2f} | {cpu:.2f} | "
              f"{solution.energy:.10f} |", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--spans", type=int, nargs="*", default=[32, 64, 128])
    parser.add_argument("--start", type=int, default=8)
    parser.add_argument("--tolerance", type=float, default=1e-8)
    parser.add_argument("--newton", type=int, default=0,
                        help="spans of the end-to-end Newton check (0: none)")
    parser.add_argument("--newton-tolerances", type=float, nargs="+", default=[1e-8, 1e-6])
    parser.add_argument("--verbose", action="store_true")
    args = parser.parse_args()
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.WARNING,
                        format="%(asctime)s %(name)s: %(message)s")
    torch.set_num_threads(1)
    taichi_ndf.init(arch="cpu", precision="f64")
    model = load_scene(SCENE).model
    started = time.perf_counter()
    start = start_field(model, args.start)
    print(f"start: {args.start}² napkin solve, {time.perf_counter() - started:.1f} s")
    if args.spans:
        linear_table(model, start, args.spans, args.tolerance)
    if args.newton:
        newton_check(model, start, args.newton, args.newton_tolerances)


if __name__ == "__main__":
    main()
