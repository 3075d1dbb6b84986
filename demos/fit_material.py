"""End to end material estimation: cantilever bending test with a synthetic observation.

1. The observed shape: a strip of bending length 0.2 m (B = 1.57e-2 N·m) under its own weight,
   solved with this project's forward solver, exported on the scene's template grid, with
   noise of 0.5 % of the sheet size.
2. `ndf-fit-material` estimates B by its default method (newton) from the scene's start
   value, which is 10× too stiff, and writes estimate.json and overlay.png.

    python demos/fit_material.py --out runs/fit_material [--quick]
"""

import argparse
import dataclasses
import logging
from pathlib import Path

import torch

import taichi_ndf
from inverse.cli.fit_material import main as fit_material
from inverse.material import Observation, apply, parse_unknowns, template_xi
from taichi_ndf.field import NeuralField
from taichi_ndf.io import write_obj
from taichi_ndf.io.grid import grid_mesh
from taichi_ndf.scene import load_scene
from taichi_ndf.solver import Solver

SCENE = Path(__file__).parents[1] / "scenes" / "inverse" / "cantilever_strip.toml"
B_TRUE = 0.2 * 9.81 * 0.2**3


def observe(out: Path, quick: bool) -> Path:
    scene = load_scene(SCENE)
    model, unknowns = parse_unknowns("bending", scene.model)
    truth = apply(model, unknowns, [B_TRUE])
    field = NeuralField(scene.field, seed=1)
    iterations = 300 if quick else 1000
    config = dataclasses.replace(scene.solver.with_iterations(iterations), progress=False,
                                 checkpoint_every=0, monitor_samples=2048,
                                 lbfgs_iterations=iterations)
    Solver(truth, field, config).run()
    xi = template_xi(truth, scene.output.resolution)
    points = truth.surface.jets(xi)[:, 0] + truth.displacement(field, xi)
    noisy = Observation(truth, points, xi).with_noise(0.005, seed=0).points
    grid = grid_mesh(truth.surface.domain.bounds, scene.output.resolution)
    path = out / "observed.obj"
    write_obj(path, noisy.numpy(), grid.faces)
    return path


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", default="runs/fit_material", help="output folder (new)")
    parser.add_argument("--quick", action="store_true", help="short trainings (about 1 min)")
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=False)
    taichi_ndf.init(arch="cpu", precision="f64")
    observed = observe(out, args.quick)
    argv = [str(SCENE), "--observed", str(observed), "--estimate", "bending",
            "--out", str(out / "estimate")]
    fit_material([*argv, "--quick"] if args.quick else argv)
    print(f"truth: bending_stiffness = {B_TRUE:.6g} N·m")


if __name__ == "__main__":
    torch.set_num_threads(1)
    main()
