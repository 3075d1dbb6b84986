"""End to end material estimation: cantilever bending test with a synthetic observation.

1. The observed shape: a strip of bending length 0.2 m (B = 1.57e-2 N·m) under its own weight,
   solved by projected Newton on a quartic spline grid of 40 × 8 spans (a finer grid of
   another degree than the estimator's cubic ones) and its accuracy stated: the Richardson
   error of its positions from the same solve on 10 × 2 and 20 × 4 spans
   (`calibration.converged_observation`), which must be far below the noise; exported on
   the scene's template grid, with noise of 0.5 % of the sheet size. (It was a SIREN trained
   by Adam for 1000 iterations: under-solved, B = 0.0161216 ± 7e-5 against the true 0.015696,
   6 standard errors off.)
2. `ndf-fit-material` estimates B by its default method (newton) from the scene's start
   value, which is 10× too stiff, with the noise stated (`--noise`, for the goodness-of-fit
   test), and writes estimate.json and overlay.png.

    python demos/fit_material.py --out runs/fit_material [--quick]
"""

import argparse
import logging
from pathlib import Path

import torch

import taichi_ndf
from inverse.cli.fit_material import main as fit_material
from inverse.material import Observation, apply, parse_unknowns, template_xi
from inverse.material.calibration import converged_observation
from taichi_ndf.cli.progress import shown
from taichi_ndf.io import write_obj
from taichi_ndf.io.grid import grid_mesh
from taichi_ndf.scene.reader import load_scene

SCENE = Path(__file__).parents[1] / "scenes" / "inverse" / "cantilever_strip.toml"
B_TRUE = 0.2 * 9.81 * 0.2**3


NOISE = 0.005  # of the sheet size, per coordinate


def observe(out: Path, quick: bool) -> tuple[Path, float]:
    """The noisy observation's file and its noise σ [m]."""
    scene = load_scene(SCENE)
    model, unknowns = parse_unknowns("bending", scene.model)
    truth = apply(model, unknowns, [B_TRUE])
    xi = template_xi(truth, scene.output.resolution)
    spans = (20, 4) if quick else (40, 8)
    points, order, error = converged_observation(truth, unknowns, [B_TRUE], xi, spans)
    clean = Observation(truth, points, xi)
    sigma = NOISE * clean.size
    print(f"observation: quartic spline {spans[0]} × {spans[1]} spans, largest position error "
          f"{error:.2g} m (Richardson, observed order {order:.2f}) against noise σ = "
          f"{sigma:.2g} m")
    noisy = clean.with_noise(NOISE, seed=0).points
    grid = grid_mesh(truth.surface.domain.bounds, scene.output.resolution)
    path = out / "observed.obj"
    write_obj(path, noisy.numpy(), grid.faces)
    return path, sigma


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", default="runs/fit_material", help="output folder (new)")
    parser.add_argument("--quick", action="store_true", help="short trainings (about 1 min)")
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=False)
    taichi_ndf.init(arch="cpu", precision="f64")
    with shown("fit_material.py"):  # the observation's three solves: a bar each load step
        observed, sigma = observe(out, args.quick)
    argv = [str(SCENE), "--observed", str(observed), "--estimate", "bending",
            "--noise", repr(sigma), "--out", str(out / "estimate")]
    fit_material([*argv, "--quick"] if args.quick else argv)
    print(f"truth: bending_stiffness = {B_TRUE:.6g} N·m")


if __name__ == "__main__":
    torch.set_num_threads(1)
    main()
