"""Spline field + projected Newton on the validation cases and the napkin (issue 19).

One configuration for every case: cubic B-splines, 4 × 4 Gauss–Legendre points per knot span
(`span_quadrature`),
`NewtonConfig()` defaults, the scene's load steps; the coarsest grid follows one rule
from the geometry (`taichi_ndf.problem.spline_grid.grid_spans`, `span_length = "auto"` of a scene),
then two exact dyadic refinements (three grids), each solved
from the coarser solution prolonged. Reported per case and quantity: the value on each grid,
the Richardson-extrapolated value with its estimated error, and the error of the finest grid
against the published reference.

    python benchmarks/spline_newton.py [--cases a,b] [--levels 3] [--napkin] [--json out]
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import time
from pathlib import Path

import numpy as np
import torch

import taichi_ndf
from taichi_ndf import jets
from taichi_ndf.field.spline import SplineConfig, SplineField
from taichi_ndf.minimise.newton import NewtonConfig
from taichi_ndf.minimise.refinement import richardson, solve_levels
from taichi_ndf.objective import EndMomentTerm, Objective
from taichi_ndf.problem.quadrature import span_quadrature
from taichi_ndf.problem.spline_grid import grid_spans
from taichi_ndf.scene.reader import load_scene
from taichi_ndf.validation import CASES, LINEARISATION, load_case_scene

SCENE_DIR = Path(__file__).resolve().parents[1] / "scenes"
DEGREE = 3


def run_validation_case(name: str, levels: int, config: NewtonConfig) -> dict:
    case = CASES[name]
    scene, model, _ = load_case_scene(case)
    surface = model.surface
    spans = grid_spans(surface, model.material.thickness, model.boundary.narrowest_band)
    domain = surface.domain
    field = SplineField(SplineConfig(spans=spans, degree=DEGREE, domain=domain.bounds,
                                     periodic=domain.periodic))
    objective = Objective.of_model(model)
    if case.end_moment is not None:
        objective = objective.with_terms(
            EndMomentTerm(case.end_moment(model), domain.lengths[1]))
    probes = {p.name: p.xi for p in model.probes}
    load_steps = tuple(scene.solver.load_steps)
    started = time.perf_counter()
    results = solve_levels(
        field, model.boundary, lambda f: span_quadrature(surface, f.config, model.loads),
        objective, levels=levels,
        load_steps=load_steps, config=config, probes=probes,
        length=math.sqrt(domain.rectangle_area))
    wall = time.perf_counter() - started
    xi = torch.tensor(list(probes.values()), dtype=torch.float64)
    positions = surface.jets(xi)[:, jets.VALUE].double().numpy()
    reference_positions = {n: positions[k] for k, n in enumerate(probes)}
    unit = LINEARISATION if case.linear else 1.0
    rows = []
    for q in case.quantities:
        k = min(range(len(load_steps)), key=lambda i: abs(load_steps[i] - q.level))
        values = [q.read({n: v / unit for n, v in level[k].probes.items()},
                         reference_positions) for level in results]
        extrapolated = richardson(values) if len(values) >= 3 else None
        rows.append({
            "case": name, "quantity": q.name, "level": q.level, "reference": q.reference,
            "values": values, "errors": [abs(v - q.reference) / abs(q.reference) for v in values],
            "extrapolated": None if extrapolated is None else extrapolated.value,
            "estimated_error": None if extrapolated is None else extrapolated.error,
            "order": None if extrapolated is None else extrapolated.order,
        })
    energies = [level[-1].energy for level in results]
    return {"case": name, "spans": [list(level[0].spans) for level in results],
            "seconds": [sum(s.seconds for s in level) for level in results],
            "newton_steps": [sum(len(s.history) for s in level) for level in results],
            "converged": all(s.converged for level in results for s in level),
            "energy": energies, "wall": wall, "rows": rows}


def run_napkin(levels: int, coarsest: int, config: NewtonConfig) -> dict:
    """The napkin (scenes/napkin.toml, free pin) from coarsest × coarsest spans through
    `levels` grids: Π per level, the cumulative time, and the first level within 1 % of the
    Π extrapolated from the last three."""
    scene = load_scene(SCENE_DIR / "napkin.toml")
    model = scene.model
    surface = model.surface
    field = SplineField(SplineConfig(spans=(coarsest, coarsest), degree=DEGREE,
                                     domain=surface.domain.bounds))
    # Compile (or load from the cache) the energy and basis kernels first: reported apart.
    started = time.perf_counter()
    warm = span_quadrature(surface, field.config, model.loads)
    Objective.of_model(model).potential(1.0)(
        warm, torch.zeros(len(warm), jets.CHANNELS, 3, dtype=field.coefficients.dtype), True)
    field.local_basis(warm.xi)
    compile_seconds = time.perf_counter() - started
    started = time.perf_counter()
    results = solve_levels(
        field, model.boundary, lambda f: span_quadrature(surface, f.config, model.loads),
        Objective.of_model(model), levels=levels, config=config,
        probes={p.name: p.xi for p in model.probes},
        length=math.sqrt(surface.domain.rectangle_area))
    wall = time.perf_counter() - started
    energies = [level[-1].energy for level in results]
    cumulative = np.cumsum([level[-1].seconds for level in results]).tolist()
    limit = richardson(energies)
    within = [abs(e - limit.value) <= 0.01 * abs(limit.value) for e in energies]
    first = within.index(True) if any(within) else None
    return {"case": "napkin", "precision": taichi_ndf.current().precision,
            "spans": [list(level[-1].spans) for level in results], "energy": energies,
            "cumulative_seconds": cumulative, "compile_seconds": compile_seconds,
            "newton_steps": [len(level[-1].history) for level in results],
            "time_split": [{key: sum(getattr(h, f"time_{key}") for h in level[-1].history)
                            for key in ("energy", "hessian", "assembly", "solve")}
                           for level in results],
            "extrapolated": limit.value, "estimated_error": limit.error, "order": limit.order,
            "first_within_1pct": first,
            "seconds_to_1pct": None if first is None else cumulative[first],
            "free_corner": [level[-1].probes["free_corner"].tolist() for level in results],
            "wall": wall}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", default=",".join(CASES))
    parser.add_argument("--levels", type=int, default=3)
    parser.add_argument("--json", default=None)
    parser.add_argument("--napkin", action="store_true", help="run the napkin instead")
    parser.add_argument("--napkin-levels", type=int, default=5)
    parser.add_argument("--napkin-coarsest", type=int, default=2)
    parser.add_argument("--precision", choices=("f32", "f64"), default="f64")
    parser.add_argument("--napkin-tolerance", type=float, default=1e-12,
                        help="Newton decrement tolerance (relative to |Π|) of the napkin")
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s")
    torch.set_num_threads(1)
    taichi_ndf.init(arch="cpu", precision=args.precision)
    out = []
    if args.napkin:
        config = NewtonConfig(fd_step=1e-4 if args.precision == "f64" else 3e-3,
                                       decrement_tolerance=args.napkin_tolerance)
        out.append(run_napkin(args.napkin_levels, args.napkin_coarsest, config))
        print(json.dumps(out[-1], default=float))
        args.cases = ""
    for name in [c for c in args.cases.split(",") if c]:
        if name not in CASES:
            raise SystemExit(f"unknown case {name!r}; choose from {', '.join(CASES)}")
        result = run_validation_case(name, args.levels, NewtonConfig())
        out.append(result)
        print(json.dumps(result, default=float))
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f, indent=1, default=float)


if __name__ == "__main__":
    main()
