"""The cost of mapping self-contact-like pair blocks onto the spline coefficients (issue 28/30).

P value-channel pair blocks (random PSD 6 × 6 on the two points' values, as self-contact's)
between random Gauss points of napkin_fold's grid (0.6 m × 0.15 m plane, cubic 32 × 8 spans,
clamped at ξ¹ = 0), assembled by `pair_hessian.coupled_hessian`; with `--reference FILE` the
same K by another implementation of `coupled_hessian` (a copy of the module) side by side.
Prints CPU (user + sys) and wall seconds per call, and the largest relative difference.

    PYTHONPATH=$PWD python benchmarks/pair_scatter.py --pairs 50000 [--reference old.py]
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import resource
import time

import torch

import taichi_ndf
from taichi_ndf.boundary import BoundaryConditions, ClampedEdge
from taichi_ndf.field.spline import SplineConfig, SplineField
from taichi_ndf.geometry import Plane
from taichi_ndf.minimise.assembly import Assembly, local_basis_at
from taichi_ndf.minimise.pair_hessian import coupled_hessian
from taichi_ndf.objective.couplings import Couplings
from taichi_ndf.problem.operator import DisplacementOperator
from taichi_ndf.problem.quadrature import span_quadrature

F64 = torch.float64


def napkin_assembly() -> Assembly:
    surface = Plane(bounds=((0.0, 0.6), (0.0, 0.15)))
    boundary = BoundaryConditions([ClampedEdge(edge="xi1_min")], domain=surface.domain,
                                  surface=surface, length=0.15)
    field = SplineField(SplineConfig(spans=(32, 8), domain=surface.domain.bounds), dtype=F64)
    samples = span_quadrature(surface, field.config, dtype=F64)
    operator = DisplacementOperator(field, boundary)
    return Assembly(samples, local_basis_at(operator, samples.xi),
                    field.coefficients.shape[0]).at_load(operator, 1.0)


def value_pairs(n_points: int, count: int, seed: int = 0) -> Couplings:
    gen = torch.Generator().manual_seed(seed)
    points = torch.randint(0, n_points, (count, 2), generator=gen)
    root = torch.randn(count, 6, 6, generator=gen, dtype=F64)
    blocks = torch.zeros(count, 36, 36, dtype=F64)
    at = torch.tensor([0, 1, 2, 18, 19, 20])
    blocks[:, at[:, None], at[None, :]] = root @ root.transpose(1, 2)
    return Couplings(points, blocks)


def timed(function, repeats: int):
    start, wall = resource.getrusage(resource.RUSAGE_SELF), time.perf_counter()
    for _ in range(repeats):
        out = function()
    end = resource.getrusage(resource.RUSAGE_SELF)
    cpu = (end.ru_utime - start.ru_utime) + (end.ru_stime - start.ru_stime)
    return out, cpu / repeats, (time.perf_counter() - wall) / repeats


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pairs", type=int, default=50000)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--reference", help="a file defining coupled_hessian to compare")
    args = parser.parse_args()
    if args.pairs < 1 or args.repeats < 1:
        parser.error("--pairs and --repeats must be positive")
    taichi_ndf.init(arch="cpu", precision="f64", seed=0)
    assembly = napkin_assembly()
    couplings = value_pairs(len(assembly.samples), args.pairs)
    contenders = {"current": coupled_hessian}
    if args.reference:
        spec = importlib.util.spec_from_file_location("reference", args.reference)
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        contenders = {"reference": module.coupled_hessian, **contenders}
    print(f"points {len(assembly.samples)}, unknowns {assembly.size}, pairs {args.pairs}, "
          f"load {os.getloadavg()[0]:.2f}")
    print(f"{'implementation':>15} {'CPU s/call':>11} {'wall s/call':>12} {'nnz':>9}")
    results = {}
    for name, function in contenders.items():
        function(assembly, couplings)  # warm-up
        matrix, cpu, wall = timed(lambda f=function: f(assembly, couplings), args.repeats)
        results[name] = matrix
        print(f"{name:>15} {cpu:11.3f} {wall:12.3f} {matrix.nnz:9d}")
    if len(results) == 2:
        a, b = results.values()
        print(f"max |K_ref - K| / max |K_ref| = {abs(a - b).max() / abs(a).max():.3e}")


if __name__ == "__main__":
    main()
