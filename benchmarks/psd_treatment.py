"""Projected Newton's PSD treatments compared on whole solves (issue 28): "clamp" (indefinite
blocks found by a batched Cholesky screen, eigen-decomposed, negative eigenvalues set to 0),
"abs" (mirrored) and "strain" (every block positive semi-definite through the strains: the law
Hessian clamped, the membrane stress clamped in closed form, the bending stress dropped; no
screen, no eigh). All three still try the exact K first where the last attempt did not fail.

Per scene and treatment: Newton iterations (all levels), Π on the finest grid, CPU seconds of
the solve (one thread; kernels compiled before the clock), treatments interleaved per scene.

    OMP_NUM_THREADS=1 python benchmarks/psd_treatment.py [--treatments clamp strain abs]

Scenes: the napkin 7² → 14² → 28² spans (decrement tolerance 1e-4, as napkin_newton.py), the
draped flag on 4 × 3 spans (`cloth`, tolerance 1e-10, as the projection test), and the
Scordelis–Lo roof 14 × 20 → 28 × 40 (a linear case whose exact K is indefinite at the start
of its second step).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import time
from pathlib import Path

import torch

import taichi_ndf
from taichi_ndf.field.spline import SplineConfig, SplineField
from taichi_ndf.minimise.newton import NewtonConfig
from taichi_ndf.minimise.refinement import solve_levels
from taichi_ndf.objective import Objective
from taichi_ndf.problem.quadrature import span_quadrature
from taichi_ndf.scene.reader import load_scene
from taichi_ndf.validation import CASES, load_case_scene

SCENES = Path(__file__).resolve().parents[1] / "scenes"


def _solve(model, spans, levels, config):
    surface = model.surface
    field = SplineField(SplineConfig(spans=spans, degree=3, domain=surface.domain.bounds))
    return solve_levels(field, model.boundary,
                        lambda f: span_quadrature(surface, f.config, model.loads),
                        Objective.of_model(model), levels=levels, config=config,
                        length=math.sqrt(surface.domain.rectangle_area))


def scenes():
    """(name, model, coarsest spans, levels, Newton settings) of each scene."""
    napkin = load_scene(SCENES / "napkin.toml").model
    flag = load_scene(SCENES / "flag.toml", material="cloth").model
    _, roof, _ = load_case_scene(CASES["scordelis_lo_roof"])
    return [("napkin 7² → 28²", napkin, (7, 7), 3, NewtonConfig(decrement_tolerance=1e-4)),
            ("flag 4 × 3", flag, (4, 3), 1,
             NewtonConfig(decrement_tolerance=1e-10, max_iterations=200)),
            ("roof 14 × 20 → 28 × 40", roof, (14, 20), 2, NewtonConfig())]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--treatments", nargs="+", default=["clamp", "strain", "abs"])
    args = parser.parse_args()
    torch.set_num_threads(1)
    taichi_ndf.init(arch="cpu", precision="f64")
    cases = scenes()
    for _, model, spans, _, _ in cases:  # compile / load the kernels
        _solve(model, spans, 1, NewtonConfig(max_iterations=1))
    print("| scene | treatment | Newton iterations | projected blocks | Π finest [J] | "
          "CPU [s] |")
    print("|---|---|---|---|---|---|")
    for name, model, spans, levels, config in cases:
        for treatment in args.treatments:
            settings = dataclasses.replace(config, hessian=treatment)
            started = time.process_time()
            results = _solve(model, spans, levels, settings)
            cpu = time.process_time() - started
            history = [h for level in results for s in level for h in s.history]
            projected = sum(h.projected_blocks for h in history)
            print(f"| {name} | {treatment} | {len(history)} | {projected} | "
                  f"{results[-1][-1].energy:.9g} | {cpu:.2f} |")


if __name__ == "__main__":
    main()
