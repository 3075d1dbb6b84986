"""Where one Newton step goes on the napkin, against the factorisation floor (issue 28).

The napkin (scenes/napkin.toml) is solved coarse to fine over three grids (`napkin_newton.solve`,
decrement tolerance 1e-4, `NewtonConfig`'s defaults otherwise) to s² spans, s = each `--spans`
halved while above 40 (32: 8² → 16² → 32², the README demo's grids; 144: 9² → 36²); the
solution is prolonged exactly to `--spans`² where that is finer. There each part of a Newton
step is timed (CPU ms, median of `--repeats` after one warm-up, one thread): the displacement,
Π and its gradient, the pull-back to the coefficients, one line-search trial (displacement + Π),
the per-point Hessian blocks — exact, and positive semi-definite through the strains (the
"strain" PSD treatment) — chunk by chunk as Newton builds them (`POINT_CHUNK` points), the
assembly K = Σ Jᵀ H J (of the PSD blocks), the factorisation + solve by the grid's linear
solver (`LinearSolver.for_grid`: banded Cholesky, multigrid-CG from 60 000 unknowns), and the
second-order correction's extra work (`line_search.second_order_step`: the residual of the
step's membrane stretch and its pull-back; then its solve by the same K). `--clamp` adds the
clamped projection's parts (the indefinite-block screen and the eigen-projection).

Then the steps as `newton.minimise` takes them, and their ratio to the factorisation + solve:
with "strain", a definite K of PSD blocks (a step after a failed exact attempt: those parts
only); a projected step with its failed exact attempt (exact blocks, assembly, factorisation)
first; each with the correction (its residual, pull-back, solve and one more trial) where the
full step fails; with `--clamp` also the default's: the exact K definite, and a projected step
(the failed exact attempt, then the exact blocks again, screened, projected, assembled).

    OMP_NUM_THREADS=1 python benchmarks/newton_step.py [--spans 32 144] [--repeats 3] [--clamp]
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
from taichi_ndf.minimise.assembly import POINT_CHUNK, Assembly, gauge_unknowns, local_basis_at
from taichi_ndf.minimise.linear_solve import LinearSolver
from taichi_ndf.minimise.newton import NewtonConfig
from taichi_ndf.objective import Objective
from taichi_ndf.problem.operator import DisplacementOperator
from taichi_ndf.problem.quadrature import span_quadrature
from taichi_ndf.scene.reader import load_scene
from taichi_ndf.shell.hessian import flat_blocks, indefinite_blocks, jet_steps, project_psd

sys.path.insert(0, str(Path(__file__).resolve().parent))
from napkin_newton import SCENE, solve  # noqa: E402

SOLVED_MAX = 40  # the finest grid solved (spans); finer ones are prolonged from it


def cpu_ms(part, repeats: int) -> float:
    """Median CPU milliseconds of `repeats` calls after one warm-up call."""
    part()
    times = []
    for _ in range(repeats):
        started = time.process_time()
        part()
        times.append(time.process_time() - started)
    return 1000 * sorted(times)[len(times) // 2]


def chunked(build, count: int):
    """A function of nothing that builds the blocks of all `count` points chunk by chunk
    (`build(rows)`), as Newton's assembly asks for them, and keeps none."""
    def run():
        for start in range(0, count, POINT_CHUNK):
            build(slice(start, min(count, start + POINT_CHUNK)))
    return run


def blocks_by_rows(potential, samples, u, steps, psd: bool = False):
    """The blocks of a slice of rows at U as Newton asks them chunk by chunk (`PointBlocks`):
    the shell's strain-step scale (`tangent_length`) computed once, passed to every chunk."""
    tangent = potential.tangent_length(samples, u)
    own = potential.psd_hessian_blocks if psd else potential.hessian_blocks
    return lambda rows: own(samples, u, steps=steps, rows=rows, tangent=tangent)


def all_blocks(build, count: int) -> torch.Tensor:
    """The blocks (count, 18, 18) of all points, built chunk by chunk (`build(rows)`)."""
    return torch.cat([flat_blocks(build(slice(start, min(count, start + POINT_CHUNK))))
                      for start in range(0, count, POINT_CHUNK)])


def parts_at(model, field: SplineField, repeats: int, clamp: bool) -> dict:
    """CPU ms of each part of a Newton step on `field`'s grid at its coefficients."""
    surface, c = model.surface, field.coefficients
    samples = span_quadrature(surface, field.config, model.loads)
    operator = DisplacementOperator(field, model.boundary)
    basis = local_basis_at(operator, samples.xi)
    assembly = Assembly(samples, basis, c.shape[0]).at_load(operator, 1.0)
    potential = Objective.of_model(model).potential(1.0)
    s = assembly.samples
    u = assembly.displacement(c)
    result = potential(s, u, True)
    steps = jet_steps(s.r_jets, u, math.sqrt(surface.domain.rectangle_area), 1e-5)
    psd = all_blocks(blocks_by_rows(potential, s, u, steps, psd=True), len(s))
    matrix = assembly.hessian(psd)
    rhs = -assembly.gradient(result.grad_u_jets).reshape(-1).numpy()
    fixed = gauge_unknowns(model.boundary, basis)
    solver = LinearSolver.for_grid(field.config)
    step = torch.from_numpy(solver(matrix, rhs, 0.0, fixed)[0]).reshape(c.shape)

    def residual():  # the correction's residual r = Jᵀ ∂r/∂U of the step's stretch
        stretch = assembly.displacement(c + step) - u
        return assembly.gradient(potential.second_order_gradient(s, u, stretch))

    r = residual().reshape(-1).numpy()
    out = {
        "unknowns": assembly.size, "points": len(s),
        "solver": "multigrid-CG" if solver.multigrid and assembly.size >= (
            solver.config.band_threshold) else "banded Cholesky",
        "displacement": cpu_ms(lambda: assembly.displacement(c), repeats),
        "energy + gradient": cpu_ms(lambda: potential(s, u, True), repeats),
        "pull-back": cpu_ms(lambda: assembly.gradient(result.grad_u_jets), repeats),
        "line-search trial": cpu_ms(
            lambda: potential(s, assembly.displacement(c + step), False), repeats),
        "blocks (exact)": cpu_ms(
            lambda: chunked(blocks_by_rows(potential, s, u, steps), len(s))(), repeats),
        "blocks (PSD, strains)": cpu_ms(
            lambda: chunked(blocks_by_rows(potential, s, u, steps, psd=True), len(s))(),
            repeats),
        "assembly": cpu_ms(lambda: assembly.hessian(psd), repeats),
        "factorise + solve": cpu_ms(lambda: solver(matrix, rhs, 0.0, fixed), repeats),
        "correction: residual + pull-back": cpu_ms(residual, repeats),
        "correction: solve": cpu_ms(lambda: solver(matrix, -r, 0.0, fixed), repeats),
    }
    if clamp:
        exact = all_blocks(blocks_by_rows(potential, s, u, steps), len(s))
        bad = indefinite_blocks(exact)
        out["indefinite"] = int(bad.numel())
        out["screen"] = cpu_ms(lambda: indefinite_blocks(exact), repeats)
        out["projection (eigh of the indefinite blocks)"] = cpu_ms(
            lambda: project_psd(exact, bad), repeats)
    return out


COMMON = ("displacement", "energy + gradient", "pull-back", "assembly", "factorise + solve",
          "line-search trial")
# the parts of each step as `newton.minimise` takes it: cumulative within each group
STEPS = ({
    "strain: a definite K of PSD blocks": COMMON + ("blocks (PSD, strains)",),
    "strain: the same + a failed exact attempt first": (
        "blocks (exact)", "assembly", "factorise + solve"),
    "strain: + the correction where the full step fails": (
        "correction: residual + pull-back", "correction: solve", "line-search trial"),
}, {
    "clamp (the default): the exact K definite": COMMON + ("blocks (exact)",),
    "clamp: + a failed exact attempt, then screened and projected blocks": (
        "blocks (exact)", "screen", "projection (eigh of the indefinite blocks)", "assembly",
        "factorise + solve"),
})


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--spans", type=int, nargs="+", default=[32, 144])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--clamp", action="store_true",
                        help="also time the clamped projection's screen and eigh")
    args = parser.parse_args()
    if any(s < 4 for s in args.spans):
        sys.exit("newton_step.py: --spans must be at least 4")
    torch.set_num_threads(1)
    taichi_ndf.init(arch="cpu", precision="f64")
    model = load_scene(SCENE).model
    rows = []
    for spans in args.spans:
        solved = spans
        while solved > SOLVED_MAX and solved % 2 == 0:
            solved //= 2
        levels = solve(model, 3, max(1, solved // 4), NewtonConfig(decrement_tolerance=1e-4))
        field = SplineField(SplineConfig(spans=levels[-1][-1].spans, degree=3,
                                         domain=model.surface.domain.bounds))
        field.coefficients.copy_(levels[-1][-1].coefficients)
        while field.config.spans[0] < spans:
            field = field.refined()
        rows.append((field.config.spans[0], parts_at(model, field, args.repeats, args.clamp)))
    skip = ("unknowns", "points", "indefinite", "solver")
    names = [k for k in rows[0][1] if k not in skip]
    print("| part [CPU ms] | " + " | ".join(
        f"{s}² ({p['unknowns']} unknowns, {p['points']} points, {p['solver']})"
        for s, p in rows) + " |")
    print("|---|" + "---|" * len(rows))
    for name in names:
        print(f"| {name} | " + " | ".join(f"{p.get(name, math.nan):.1f}" for _, p in rows) + " |")
    for group in STEPS if args.clamp else STEPS[:1]:
        totals = [0.0] * len(rows)
        for label, parts in group.items():
            cells = []
            for i, (_, p) in enumerate(rows):
                totals[i] += sum(p[k] for k in parts)
                cells.append(f"{totals[i]:.1f} ({totals[i] / p['factorise + solve']:.1f}×)")
            print(f"| {label} (× factorise + solve) | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
