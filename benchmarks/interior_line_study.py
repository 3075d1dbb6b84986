"""The spline field on scenes/napkin_interior_line.toml (a towel hinged along x = 0.5 m): Π per
grid with the hinged line's vanishing factor (the composition every field uses), on uniform knots
and on knots graded towards the line (docs/scenes.md, "Hinged interior lines with a spline
field").

Grading is measured without a field option: the napkin's plane is given the parametrisation
x = g(ξ¹), y = ξ², so the spline's uniform knots in ξ¹ are graded in x. g is monotone, maps
[0, 1] onto itself, fixes the line (g(0.5) = 0.5) and has g' = K (1 − B exp(−((ξ¹ − 0.5)/W)²)),
so the knot spacing at the line is K (1 − B) times the uniform one (B = 0.9, W = 0.05: 0.109).
float64, projected Newton to its default tolerance (at most 200 iterations), one level per run.

    python benchmarks/interior_line_study.py [--spans 10,20] [--grading uniform,graded]
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import time
from pathlib import Path

import torch

import taichi_ndf
from taichi_ndf.boundary import BoundaryConditions
from taichi_ndf.geometry.analytic import Plane, _stack
from taichi_ndf.scene.reader import load_scene
from taichi_ndf.solve.spline_solver import solve_spline

SCENE = Path(__file__).resolve().parents[1] / "scenes" / "napkin_interior_line.toml"
B, W = 0.9, 0.05  # the grading: depth and width (fraction of the side) of g's dip at the line
K = 0.5 / (0.5 - B * W * math.sqrt(math.pi) / 2 * math.erf(0.5 / W))


@dataclasses.dataclass(frozen=True)
class GradedPlane(Plane):
    """The unit plane with x = g(ξ¹) (module docstring)."""

    def local_jets(self, xi: torch.Tensor) -> torch.Tensor:
        s, y = xi[:, 0] - 0.5, xi[:, 1]
        dip = torch.exp(-(s / W) ** 2)
        x = 0.5 + K * (s - B * W * math.sqrt(math.pi) / 2 * torch.erf(s / W))
        zero, one = torch.zeros_like(s), torch.ones_like(s)
        return _stack((x, y, zero), (K * (1 - B * dip), zero, zero), (zero, one, zero),
                      (K * B * 2 * s / W**2 * dip, zero, zero), (zero, zero, zero),
                      (zero, zero, zero))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--spans", default="8,10,16,20")
    parser.add_argument("--grading", default="uniform,graded")
    args = parser.parse_args()
    taichi_ndf.init(arch="cpu", precision="f64", seed=0)
    torch.set_num_threads(1)
    scene = load_scene(SCENE, field="spline")
    solver = dataclasses.replace(scene.solver, progress=False, newton_max_iterations=200)
    print("| grid | spans | Π [J] | converged | iterations | seconds |")
    print("|---|---|---|---|---|---|")
    for grading in args.grading.split(","):
        model = scene.model
        if grading == "graded":
            surface = GradedPlane(bounds=((0.0, 1.0), (0.0, 1.0)))
            old = model.boundary
            boundary = BoundaryConditions(old.constraints, old.domain, surface=surface,
                                          length=old.length)
            model = dataclasses.replace(model, surface=surface, boundary=boundary)
        for n in (int(v) for v in args.spans.split(",")):
            config = dataclasses.replace(scene.field.config, spans=(n, n))
            started = time.perf_counter()
            run = solve_spline(model, dataclasses.replace(scene.field, config=config), solver)
            level = run.levels[-1]
            print(f"| {grading} | {n} × {n} | {level.energy:.6f} | {level.converged} | "
                  f"{level.iterations} | {time.perf_counter() - started:.1f} |", flush=True)


if __name__ == "__main__":
    main()
