"""Polygon panels (issue 30; `outline` in a garment file, `taichi_ndf.discretise.trimmed`).

Prints four tables (CPU = user + sys of this process, wall, load average, commit):

1. quadrature: an L-shape (0.2 m, notch [0, 0.13] × [0.07, 0.2]) and a non-convex 7-gon on
   n × n spans: the trimmed rule's points, its error in the area and the largest relative
   error of ∫ x^a y^b (against Green's boundary integral), beside the masked
   span rule (`span_quadrature` on the outline's masked domain: inside Gauss points kept, the
   staircase) — its area error; the monomials: total degree ≤ 8 and ≤ 7 in each coordinate
   (the whole spans' tensor rule, (p + 1)² points, is exact to degree 2p + 1 = 7 per
   coordinate);
2. held unknowns: the L-shaped cantilever (below) on n × n spans: unknowns, those held as
   unsupported, the smallest diagonal of the free coefficients' mass matrix Σ w N_i² relative
   to the largest (the trimmed splines' slivers), and the solve with them held against the
   solve with them free (Newton iterations, converged, CPU, the relative difference of Π, or
   the error);
3. refinement: cantilevers clamped along their top edge (y = 0.2 m), gravity across them
   (linear material: D = 6400 N/m, B = 0.1 N·m, ν = 0.25, 0.144 kg/m²), clamps over the whole
   panel (band ℓ = 1) — the rectangle 0.3 × 0.2 m, a trapezoid (0, 0), (0.3, 0), (0.22, 0.2),
   (0.08, 0.2), the L (clamped along its top e2, x ∈ [0.13, 0.2]) — on n × n spans, n = 4 … 32:
   Π, Newton iterations, CPU, then Richardson's observed order of Π over the last three grids;
4. two trapezoids (0, 0), (0.15, 0), (0.12, 0.2), (0, 0.2) and (0.15, 0), (0.3, 0), (0.3, 0.2),
   (0.12, 0.2) sewn along the slanted edge (bending transmitted) on n × n spans each, against
   the rectangle they make on 2n × n: Π of both, relative difference, the seam's gap;
5. trimming alone: the rectangle cantilever of 3 as a polygon on its own bounding box (no
   span cut) and on a chart widened by 0.013 m to the left and 0.02 m below (its free left
   and bottom edges cut through spans on every grid; the same shape, corners and clamp),
   n × n spans: Π, the order.

    PYTHONPATH=$PWD OMP_NUM_THREADS=1 python benchmarks/garment_outline.py [table ...]
"""

from __future__ import annotations

import copy
import dataclasses
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import torch

import taichi_ndf
from taichi_ndf.boundary import BoundaryConditions, ClampedEdge
from taichi_ndf.discretise import of_scene
from taichi_ndf.discretise.trimmed import TrimmedGrid, trimmed_points
from taichi_ndf.field import SplineField
from taichi_ndf.field.spline import SplineConfig
from taichi_ndf.minimise.assembly import local_basis_at
from taichi_ndf.minimise.extrapolation import richardson
from taichi_ndf.problem.outline import Outline, OutlinePlane
from taichi_ndf.problem.quadrature import span_quadrature
from taichi_ndf.scene.reader import parse_scene

L_SHAPE = ((0.0, 0.0), (0.2, 0.0), (0.2, 0.2), (0.13, 0.2), (0.13, 0.07), (0.0, 0.07))
STAR = ((0.0, 0.0), (1.3, 0.2), (0.9, 0.7), (1.5, 1.4), (0.6, 1.1), (0.1, 1.6), (0.3, 0.8))
TRAPEZOID = ((0.0, 0.0), (0.3, 0.0), (0.22, 0.2), (0.08, 0.2))
MATERIAL = {"type": "linear", "membrane_stiffness": 6400.0, "bending_stiffness": 0.1,
            "poisson_ratio": 0.25, "areal_density": 0.144}
PAIR = ({"name": "a", "outline": [[0, 0], [0.15, 0], [0.12, 0.2], [0, 0.2]], "clamped": ["e2"]},
        {"name": "b", "outline": [[0.15, 0], [0.3, 0], [0.3, 0.2], [0.12, 0.2]],
         "clamped": ["e2"]})
SEAM = {"name": "slant", "a": "a.e1", "b": "b.e3", "orientation": "reversed"}
RECTANGLE = {"name": "w", "width": 0.3, "height": 0.2, "clamped": ["xi2_max"]}


def cpu() -> float:
    return time.process_time()


def boundary_integral(points, a: int, b: int) -> float:
    """∫ x^a y^b over the polygon by Green's theorem, each edge by exact Gauss–Legendre."""
    nodes, weights = np.polynomial.legendre.leggauss(a + b + 2)
    t, w = (nodes + 1) / 2, weights / 2
    total = 0.0
    for i, (x0, y0) in enumerate(points):
        x1, y1 = points[(i + 1) % len(points)]
        x, y = x0 + t * (x1 - x0), y0 + t * (y1 - y0)
        total += float((w * x ** (a + 1) * y ** b).sum()) * (y1 - y0) / (a + 1)
    return total


def quadrature_table() -> None:
    print("\n1. quadrature: trimmed rule vs masked span rule (staircase)")
    print(f"{'outline':8} {'spans':>7} {'points':>7} {'area err':>10} {'poly err':>10} "
          f"{'masked pts':>10} {'masked area err':>15}")
    for label, points in (("L", L_SHAPE), ("7-gon", STAR)):
        outline = Outline(points)
        for n in (8, 16, 32):
            config = SplineConfig(spans=(n, n), domain=outline.bounds)
            xi, w = trimmed_points(outline, config)
            x, y, w = xi[:, 0].numpy(), xi[:, 1].numpy(), w.numpy()
            worst = max(abs(float((w * x ** a * y ** b).sum()) / boundary_integral(points, a, b)
                            - 1) for a in range(8) for b in range(min(8, 9 - a)))
            masked = span_quadrature(OutlinePlane(outline=outline), config,
                                     dtype=torch.float64)
            print(f"{label:8} {n:>3} x{n:<3} {len(w):>7} {abs(w.sum() / outline.area - 1):10.1e}"
                  f" {worst:10.1e} {len(masked.weight):>10} "
                  f"{abs(float(masked.weight.sum()) / outline.area - 1):15.1e}")


def document(panels, seams=(), spans=(8, 8)) -> dict:
    """The garment document of `panels`, each with its clamps over the whole panel
    (`clamp_band = 1`: φ one polynomial)."""
    panels = [{**copy.deepcopy(p), "clamp_band": 1.0} for p in panels]
    return {"name": "outline", "material": dict(MATERIAL),
            "loads": {"gravity": [0.0, 0.0, -9.81]},
            "field": {"type": "spline", "spans": list(spans)},
            "training": {"method": "newton", "load_steps": [1.0]},
            "panels": panels, "seams": copy.deepcopy(list(seams))}


def solved(doc):
    """(Π, Newton iterations, all converged, seam gaps, CPU s, the discretisation)."""
    scene = parse_scene(doc, base_dir=Path("."), path=Path("outline.toml"))
    started = cpu()
    panels = of_scene(scene)
    panels.start(scene.solver, seed=0)
    solution = panels.solve(scene.solver)
    return (solution.energy, solution.iterations, all(panels.converged),
            solution.document["seam_gaps"], cpu() - started, panels)


def held_table() -> None:
    print("\n2. held unknowns: the L cantilever")
    print(f"{'spans':>7} {'unknowns':>8} {'held':>5} {'min mass diag':>13} "
          f"{'held: iters/conv/CPU':>22} {'free: iters/conv/CPU, ΔΠ':>30}")
    outline = Outline(L_SHAPE)
    panel = {"name": "L", "outline": [list(p) for p in L_SHAPE], "clamped": ["e2"]}
    for n in (8, 16):
        config = SplineConfig(spans=(n, n), domain=outline.bounds)
        xi, w = trimmed_points(outline, config)
        grid = TrimmedGrid(SplineField(config, dtype=torch.float64), None, xi)
        basis = local_basis_at(grid.operator, xi)
        mass = torch.zeros(config.num_coefficients, dtype=torch.float64)
        mass.index_add_(0, basis.index.reshape(-1),
                        (w[:, None] * basis.jets[:, 0] ** 2).reshape(-1))
        free = mass[mass > 0]
        energy, iterations, converged, _, seconds, _ = solved(document([panel], spans=(n, n)))
        held = f"{iterations}/{converged}/{seconds:.1f} s"
        original = TrimmedGrid.fixed
        TrimmedGrid.fixed = property(lambda self: super(TrimmedGrid, self).fixed)
        try:
            e2, it2, conv2, _, sec2, _ = solved(document([panel], spans=(n, n)))
            outcome = f"{it2}/{conv2}/{sec2:.1f} s, ΔΠ {abs(e2 / energy - 1):.0e}"
        except Exception as err:  # noqa: BLE001 - the outcome is what is measured
            outcome = f"{type(err).__name__}: {str(err)[:40]}"
        finally:
            TrimmedGrid.fixed = original
        print(f"{n:>3} x{n:<3} {3 * config.num_coefficients:>8} {grid.unsupported.size:>5} "
              f"{float(free.min() / free.max()):13.1e} {held:>22} {outcome:>30}")


def refinement_table() -> None:
    print("\n3. refinement: cantilevers clamped along their top edge")
    cases = (("rectangle", RECTANGLE),
             ("trapezoid", {"name": "t", "outline": [list(p) for p in TRAPEZOID],
                            "clamped": ["e2"]}),
             ("L", {"name": "L", "outline": [list(p) for p in L_SHAPE], "clamped": ["e2"]}))
    print(f"{'panel':10} {'spans':>7} {'Π [J]':>16} {'iters':>5} {'CPU s':>6}")
    for label, panel in cases:
        values, flags = [], []
        for n in (4, 8, 16, 32):
            energy, iterations, converged, _, seconds, _ = solved(document([panel],
                                                                           spans=(n, n)))
            values.append(energy)
            flags.append(converged)
            print(f"{label:10} {n:>3} x{n:<3} {energy:16.10e} {iterations:>5} {seconds:6.1f}",
                  flush=True)
        result = richardson(values, converged=flags)
        order = "none" if result.order is None else f"{result.order:.2f}"
        print(f"{label:10} observed order {order} ({result.basis}), extrapolated Π "
              f"{result.value:.10e} ± {result.error:.1e}")


def pair_table() -> None:
    print("\n4. two trapezoids sewn along the slanted edge vs the rectangle they make")
    print(f"{'spans':>7} {'Π pair [J]':>16} {'Π rectangle [J]':>16} {'rel diff':>9} "
          f"{'seam gap m':>10} {'CPU s':>6}")
    for n in (4, 8, 16):
        pair, _, ok1, gaps, s1, _ = solved(document(PAIR, [SEAM], spans=(n, n)))
        whole, _, ok2, _, s2, _ = solved(document([RECTANGLE], spans=(2 * n, n)))
        assert ok1 and ok2
        print(f"{n:>3} x{n:<3} {pair:16.10e} {whole:16.10e} {abs(pair / whole - 1):9.1e} "
              f"{gaps['slant']:10.1e} {s1 + s2:6.1f}", flush=True)


def widened(scene, left: float, below: float):
    """The one-panel scene with its panel's chart (and grid) widened by `left` and `below` [m]
    to the left of and below its outline: the outline's left and bottom edges then cut
    through spans (trimmed) while its shape, corners and clamp (the chart's top side, band
    ℓ = 1) stay."""
    (patch,) = scene.field.patches
    (x0, x1), (y0, y1) = patch.outline.bounds
    chart = ((x0 - left, x1), (y0 - below, y1))
    surface = OutlinePlane(outline=patch.outline, chart=chart)
    boundary = BoundaryConditions([ClampedEdge("xi2_max", length=1.0)], domain=surface.domain)
    model = dataclasses.replace(patch.model, surface=surface, boundary=boundary)
    config = dataclasses.replace(patch.config, domain=chart)
    patch = dataclasses.replace(patch, model=model, config=config)
    return dataclasses.replace(scene, field=dataclasses.replace(scene.field, patches=(patch,)))


def trimming_table() -> None:
    print("\n5. trimming alone: the rectangle cantilever, its free bottom and left edges "
          "trimmed")
    polygon = {"name": "r", "outline": [[0, 0], [0.3, 0], [0.3, 0.2], [0, 0.2]],
               "clamped": ["e2"]}
    print(f"{'left, below':>12} {'spans':>7} {'Π [J]':>16} {'iters':>5} {'CPU s':>6}")
    for margin in ((0.0, 0.0), (0.013, 0.02)):
        values, flags = [], []
        for n in (4, 8, 16, 32):
            scene = parse_scene(document([polygon], spans=(n, n)), base_dir=Path("."),
                                path=Path("outline.toml"))
            if any(margin):
                scene = widened(scene, *margin)
            started = cpu()
            panels = of_scene(scene)
            panels.start(scene.solver, seed=0)
            solution = panels.solve(scene.solver)
            values.append(solution.energy)
            flags.append(all(panels.converged))
            print(f"{str(margin):>12} {n:>3} x{n:<3} {solution.energy:16.10e} "
                  f"{solution.iterations:>5} {cpu() - started:6.1f}", flush=True)
        result = richardson(values, converged=flags)
        order = "none" if result.order is None else f"{result.order:.2f}"
        print(f"{str(margin):>12} observed order {order} ({result.basis}), extrapolated Π "
              f"{result.value:.10e} ± {result.error:.1e}")


def main() -> None:
    taichi_ndf.init(arch="cpu", precision="f64")
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True,
                            text=True, check=False).stdout.strip()
    print(f"commit {commit}, load {os.getloadavg()}")
    started, wall = cpu(), time.perf_counter()
    tables = {"1": quadrature_table, "2": held_table, "3": refinement_table, "4": pair_table,
              "5": trimming_table}
    for key in sys.argv[1:] or tables:
        tables[key]()
    print(f"\ntotal CPU {cpu() - started:.1f} s, wall {time.perf_counter() - wall:.1f} s, "
          f"load {os.getloadavg()}")


if __name__ == "__main__":
    main()
