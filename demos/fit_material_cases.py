"""Material and force estimation on observations from this project's forward solver.

Two cases (docs/inverse_material.md, "Results"):
- `flap`: the orthotropic flap of `scenes/inverse/orthotropic_flap.toml` (0.2 m square,
  clamped along one edge, gravity); the truth has stiffness scale 0.1 of the scene's values,
  which are the start (10x too stiff). Estimates `scale` by the bilevel method.
- `point_load`: the cantilever strip of `scenes/inverse/cantilever_strip.toml` with the true
  bending stiffness and a point load F = (4, 3, -10) mN at the middle of the free end;
  estimates the load's 3-vector by the bilevel method from the start (0, 0, -20) mN.

The observation is solved once with `taichi_ndf.solve.solver.Solver` and cached in the output
folder: either with the scene's field (`--solve` Adam + `--solve-lbfgs` L-BFGS iterations on
`--monitor-samples` samples) or, with `--solve-newton N`, by last-layer Newton alone (at most N
steps per load step of `--load-steps`, on `--solve-newton-samples` samples; field
`--obs-width` × 2 sine layers, ω₀ = 3, boundary band `--band`). The conditioned field
(`--width` × `--hidden-layers`, band `--band` when `--newton` is given, else the scene's) is
trained once (`--train` Adam + `--train-lbfgs` L-BFGS iterations on `--lbfgs-samples` samples
+ at most `--newton` last-layer Newton steps on `--newton-samples` samples) in a box `--decades`
around `--start` (flap) or ±`--load-box` |start| (point load), or around the residual
estimate where that is determined (`--box-centre`), and fitted to the observation with noise
0, 0.5 % and 2 %.

    python demos/fit_material_cases.py flap --out runs/flap --solve 1000 --solve-lbfgs 1000 \
        --train 300 --train-lbfgs 600 --start 0.115 --decades 0.3 --box-centre start
    python demos/fit_material_cases.py flap --out runs/flap_newton --solve-newton 40 \
        --train 300 --train-lbfgs 0 --newton 30 --width 256 --hidden-layers 2
    python demos/fit_material_cases.py point_load --out runs/pl_newton --solve-newton 40 \
        --train 1000 --train-lbfgs 0 --newton 30 --newton-samples 16384 --width 256 \
        --hidden-layers 2

With `--method implicit` the estimate is the implicit-function bilevel method
(`inverse.material.implicit`): fixed SIREN features `--width` × 2 (seeds `--seeds`), output
layer by last-layer Newton on `--newton-samples` Sobol samples, Levenberg–Marquardt outer
fit from the start for every noise level; no box, no training. A third case, `elastica`, is
the cantilever strip observed as the heavy elastica (scipy BVP of
tests/test_inverse_material_elastica.py, not this project's solver; 21 × 5 points), bending
stiffness estimated from the scene's 10.2× start. A fourth, `gravity`, is the strip with the true
bending stiffness under gravity 20° off vertical (tilted towards +x, away from the clamp),
observed by the forward solver; the gravity vector is estimated from vertical:

    python demos/fit_material_cases.py point_load --out runs/pl_newton --solve-newton 40 \
        --method implicit --width 256 --seeds 2 3
"""

import argparse
import dataclasses
import logging
import math
import sys
import time
from pathlib import Path

import numpy as np
import torch

import taichi_ndf
from inverse.material import Observation, apply, parse_unknowns, template_xi
from inverse.material.bilevel import BilevelConfig, bilevel_estimate
from inverse.material.conditioned import ConditionedConfig
from inverse.material.implicit import ImplicitConfig
from inverse.material.implicit_fit import implicit_estimate
from taichi_ndf.cli.progress import shown
from taichi_ndf.field import NeuralField
from taichi_ndf.problem.loads import PointLoad
from taichi_ndf.scene.reader import load_scene
from taichi_ndf.solve.solver import Solver

SCENES = Path(__file__).parents[1] / "scenes" / "inverse"
FORCE = (0.004, 0.003, -0.010)
TIP = (0.2, 0.02)
# True bending stiffness of the strip [N·m]: ρ_A g c³ with ρ_A = 0.2 kg/m², bending length 0.2 m.
STRIP_BENDING = 0.2 * 9.81 * 0.2**3


def case(name: str):
    """(scene, truth model, start model, unknowns spec, truth values)."""
    if name == "elastica":
        scene = load_scene(SCENES / "cantilever_strip.toml")
        return scene, None, scene.model, "bending", np.array([STRIP_BENDING])
    if name == "gravity":
        scene = load_scene(SCENES / "cantilever_strip.toml")
        model = apply(scene.model, parse_unknowns("bending", scene.model)[1],
                      [STRIP_BENDING])
        model, unknowns = parse_unknowns("gravity", model)
        tilt = math.radians(20.0)
        truth = (9.81 * math.sin(tilt), 0.0, -9.81 * math.cos(tilt))
        return scene, apply(model, unknowns, truth), model, "gravity", np.array(truth)
    if name == "flap":
        scene = load_scene(SCENES / "orthotropic_flap.toml")
        model, unknowns = parse_unknowns("scale", scene.model)
        return scene, apply(model, unknowns, [0.1]), scene.model, "scale", np.array([0.1])
    scene = load_scene(SCENES / "cantilever_strip.toml")
    model = apply(scene.model, parse_unknowns("bending", scene.model)[1], [STRIP_BENDING])

    def with_force(force):
        loads = dataclasses.replace(model.loads, point_loads=(PointLoad(TIP, force),))
        return model.with_loads(loads)

    return scene, with_force(FORCE), with_force((0.0, 0.0, -0.02)), "point_load:0", \
        np.array(FORCE)


def observe_elastica(model, bending: float):
    """The heavy elastica of the strip (independent reference, scipy BVP), 21 × 5 points."""
    sys.path.insert(0, str(Path(__file__).parents[1] / "tests"))
    from test_inverse_material_elastica import cantilever

    (lo1, length), (lo2, width) = model.surface.domain.bounds
    g = -model.loads.gravity[2]
    positions, _ = cantilever(length, bending, model.material.membrane_stiffness,
                              (0.0, -model.material.areal_density * g))
    s, y = np.meshgrid(np.linspace(lo1, length, 21), np.linspace(lo2, width, 5))
    xz = positions(s.ravel())
    points = torch.tensor(np.stack([xz[:, 0], y.ravel(), xz[:, 1]], axis=1))
    return torch.tensor(np.stack([s.ravel(), y.ravel()], axis=1)), points


def observe(scene, truth, args, path: Path):
    if truth is None:
        return observe_elastica(scene.model, STRIP_BENDING)
    if path.exists():
        return torch.load(path)
    if args.solve_newton:
        truth = truth.with_boundary_length(args.band)
        field = NeuralField(dataclasses.replace(scene.field, width=args.obs_width,
                                                hidden_layers=2, omega0=3.0), seed=1)
        config = dataclasses.replace(scene.solver, iterations=0, progress=False,
                                     checkpoint_every=0, monitor_samples=args.monitor_samples,
                                     lbfgs_iterations=0, newton_iterations=args.solve_newton,
                                     newton_samples=args.solve_newton_samples,
                                     load_steps=tuple(args.load_steps))
    else:
        field = NeuralField(scene.field, seed=1)
        config = dataclasses.replace(scene.solver.with_iterations(args.solve), progress=False,
                                     checkpoint_every=0, monitor_samples=args.monitor_samples,
                                     lbfgs_iterations=args.solve_lbfgs)
    start = time.perf_counter()
    result = Solver(truth, field, config).run()
    logging.info("observation solved in %.1f s, probes %s", time.perf_counter() - start,
                 result.probes)
    xi = template_xi(truth, scene.output.resolution)
    points = truth.surface.jets(xi)[:, 0] + truth.displacement(field, xi)
    torch.save((xi, points), path)
    return xi, points


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("case", choices=("flap", "point_load", "elastica", "gravity"))
    parser.add_argument("--out", required=True, help="folder (the observation is cached there)")
    parser.add_argument("--solve", type=int, default=1000, help="forward-solve Adam iterations")
    parser.add_argument("--solve-lbfgs", type=int, default=1000, help="forward-solve L-BFGS")
    parser.add_argument("--monitor-samples", type=int, default=2048,
                        help="samples of the forward solve's L-BFGS polish")
    parser.add_argument("--solve-newton", type=int, default=0,
                        help="forward solve by last-layer Newton alone, at most this many "
                             "steps per load step (0: Adam + L-BFGS)")
    parser.add_argument("--solve-newton-samples", type=int, default=8192)
    parser.add_argument("--obs-width", type=int, default=128,
                        help="width of the Newton forward solve's field (2 sine layers)")
    parser.add_argument("--load-steps", type=float, nargs="+", default=[0.5, 1.0],
                        help="load steps of the Newton forward solve")
    parser.add_argument("--band", type=float, default=2.0,
                        help="boundary band of the Newton solves (fraction of the domain)")
    parser.add_argument("--train", type=int, default=300, help="conditioned Adam iterations")
    parser.add_argument("--train-lbfgs", type=int, default=600, help="conditioned L-BFGS")
    parser.add_argument("--lbfgs-samples", type=int, default=2048,
                        help="samples of the conditioned L-BFGS polish")
    parser.add_argument("--newton", type=int, default=0,
                        help="last-layer Newton steps of the conditioned field (0: none)")
    parser.add_argument("--newton-samples", type=int, default=8192)
    parser.add_argument("--width", type=int, default=64, help="conditioned field width")
    parser.add_argument("--hidden-layers", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0, help="conditioned field seed")
    parser.add_argument("--box-centre", default="start", choices=("residual", "start"))
    parser.add_argument("--start", type=float, nargs="+", default=None,
                        help="start values (default: the scene's)")
    parser.add_argument("--decades", type=float, default=1.3, help="stiffness box half-width")
    parser.add_argument("--load-box", type=float, default=1.0,
                        help="point-load box half-width in units of |start force|")
    parser.add_argument("--method", default="conditioned", choices=("conditioned", "implicit"),
                        help="bilevel with a material-conditioned field, or with implicit-"
                             "function gradients of Newton equilibria")
    parser.add_argument("--seeds", type=int, nargs="+", default=[2, 3],
                        help="implicit: feature seeds (the spread enters the standard error)")
    parser.add_argument("--widths", type=int, nargs="*", default=[],
                        help="implicit: feature width per seed (default: --width for all)")
    parser.add_argument("--implicit-samples", type=int, default=4096,
                        help="implicit: Newton samples (Sobol)")
    parser.add_argument("--max-step", type=float, default=1.0,
                        help="implicit: largest outer step in normalised coordinates")
    parser.add_argument("--noise", type=float, nargs="+", default=[0.0, 0.005, 0.02])
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    torch.set_num_threads(1)
    taichi_ndf.init(arch="cpu", precision="f64")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    scene, truth, start_model, spec, true_values = case(args.case)
    name = (f"observation_newton_{args.solve_newton}_{args.solve_newton_samples}_"
            f"{args.obs_width}_{args.band}_{'_'.join(map(str, args.load_steps))}.pt"
            if args.solve_newton else f"observation_{args.solve}_{args.solve_lbfgs}.pt")
    with shown("fit_material_cases.py"):  # the observation's solve (minutes): its bar
        xi, points = observe(scene, truth, args, out / name)
    model, unknowns = parse_unknowns(spec, start_model)
    observation = Observation(model, points, xi)
    if args.method == "implicit":
        fit_implicit(args, observation, unknowns, true_values)
        return
    field = ConditionedConfig(iterations=args.train, samples=512,
                              lbfgs_iterations=args.train_lbfgs,
                              lbfgs_samples=args.lbfgs_samples,
                              newton_iterations=args.newton,
                              newton_samples=args.newton_samples, width=args.width,
                              hidden_layers=args.hidden_layers, seed=args.seed,
                              boundary_length=args.band if args.newton else None,
                              output_scale=scene.field.output_scale)
    config = BilevelConfig(field=field, decades=args.decades, load_box=args.load_box,
                           centre_on_residual=args.box_centre == "residual")
    start = time.perf_counter()
    result = bilevel_estimate([observation], unknowns, config, start=args.start)
    print(f"box centred on the {result.box_centre}: {result.ranges}; training "
          f"{result.equilibria[0].training_time:.1f} s, total {time.perf_counter() - start:.1f} s")
    for noise in args.noise:
        noisy = observation.with_noise(noise, seed=1) if noise else observation
        estimate = bilevel_estimate([noisy], unknowns, config,
                                    equilibria=result.equilibria).estimate
        print(f"noise {noise:.3f}: {summary(estimate, true_values)}")


def summary(estimate, true_values) -> str:
    """Values ± standard errors, error against the truth, determined flags, fit time."""
    values = estimate.values
    error = np.linalg.norm(values - true_values) / np.linalg.norm(true_values)
    line = (f"{np.array2string(values, formatter={'float': '{:.6g}'.format})} ± "
            f"{np.array2string(estimate.standard_errors, formatter={'float': '{:.2e}'.format})}"
            f", error {100 * error:.2f} %, determined {estimate.identifiability.determined}, "
            f"fit {estimate.time:.2f} s")
    if len(values) == 3:
        cosine = values @ true_values / np.linalg.norm(values) / np.linalg.norm(true_values)
        line += f", angle {math.degrees(math.acos(min(cosine, 1.0))):.2f}°"
    return line


def fit_implicit(args, observation, unknowns, true_values):
    """The implicit-function estimate for every noise level, from the start each time; the
    forward models (and their start solution) are shared between the noise levels."""
    config = ImplicitConfig(width=args.width, hidden_layers=2, seeds=tuple(args.seeds),
                            widths=tuple(args.widths),
                            boundary_length=args.band, samples=args.implicit_samples,
                            max_step=args.max_step)
    equilibria = None
    for noise in args.noise:
        noisy = observation.with_noise(noise, seed=1) if noise else observation
        result = implicit_estimate([noisy], unknowns, config, start=args.start,
                                   equilibria=equilibria)
        equilibria = result.equilibria
        bases = "; ".join(
            f"seed {f.seed} width {f.width}: "
            f"{np.array2string(f.values, formatter={'float': '{:.6g}'.format})} "
            f"({f.iterations} outer it., {f.newton_steps} Newton steps, {f.time:.1f} s)"
            for f in result.fits)
        print(f"noise {noise:.3f}: {summary(result.estimate, true_values)}; Fisher s.e. "
              f"{np.array2string(result.fisher_errors, formatter={'float': '{:.2e}'.format})}"
              f", spread {np.array2string(result.spread, formatter={'float': '{:.2e}'.format})}"
              f"; {bases}", flush=True)


if __name__ == "__main__":
    main()
