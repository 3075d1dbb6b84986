"""`ndf-fit-material`: estimate material parameters and loads from observed equilibrium shapes.

    ndf-fit-material S.toml --observed OBS.obj [OBS2.ply ...] --estimate bending \
        [--method newton|implicit|bilevel|residual] --out DIR
    ndf-fit-material DYNAMIC.toml --trajectory OBS.json --estimate bending --out DIR

The scene gives everything known (geometry, boundary conditions, known loads) and start values
of the unknowns. An observation whose vertex count equals the scene's exported template grid
([output] resolution) is taken in template vertex order (correspondence); with
`--point-cloud` the points are fitted without correspondence (point-to-surface distance).
Writes DIR/estimate.json and DIR/overlay.png (observed points over the fitted shape).
With `--trajectory` a scene with [dynamics] is fitted to observed motion instead (one stiffness
parameter, Gauss–Newton through the time steps' adjoint: `inverse.cli.fit_material_trajectory`;
estimate.json only, method "trajectory").
The fit itself is `inverse.cli.fit_material_run` (imported after the command line is read, so
--help imports neither torch nor Taichi).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from taichi_ndf.cli.common import (
    ArgumentParser,
    add_runtime_options,
    description,
    finite_float,
    interruptible,
    start,
)


def build_parser() -> argparse.ArgumentParser:
    p = ArgumentParser(prog="ndf-fit-material", description=description(__doc__))
    p.add_argument("scene", nargs="?", type=Path,
                   help="scene TOML: known conditions, start values")
    p.add_argument("--scene", dest="scene_option", type=Path, metavar="SCENE",
                   help="the scene, as an option (the same as the positional)")
    p.add_argument("--observed", nargs="+",
                   help="observed shape(s), OBJ or PLY, all under the scene's conditions")
    p.add_argument("--trajectory", type=Path, metavar="OBS.json",
                   help="observed motion of a scene with [dynamics] instead of --observed: "
                        "points (ξ or probe names), times [s] on the scene's steps, positions "
                        "or displacements [m], optional noise [m]; or a dynamic run's "
                        "result.json (its probes at every step). Fits one stiffness parameter "
                        "(--estimate) by Gauss–Newton through the time steps")
    p.add_argument("--estimate", required=True, action="append",
                   help="unknowns, comma separated or repeated: bending, stretch, scale, "
                        "young_modulus (E; linear isotropic), density, gravity, body_force, "
                        "pressure, point_load:NAME, or a stiffness name of the scene's "
                        "material")
    p.add_argument("--method", default="newton",
                   choices=("newton", "implicit", "bilevel", "residual"),
                   help="newton: fit projected-Newton equilibria on a spline grid and its "
                        "refinement with implicit-function gradients (every unknown; the "
                        "difference between the two grids enters the standard error); "
                        "implicit: the same on last-layer Newton equilibria of fixed SIREN "
                        "features (minutes); bilevel: fit equilibria of a material-conditioned "
                        "field (stiffness and point loads; biased, its standard errors are too "
                        "small); residual: equilibrium-residual least squares (fast, also "
                        "distributed loads; needs clean data, refuses an observation that is "
                        "not an equilibrium). Default: newton")
    p.add_argument("--spans", type=int, nargs=2, default=None, metavar=("N1", "N2"),
                   help="newton: knot spans of the coarse grid (default: the grid rule, "
                        "docs/scenes.md, with the band); the fine grid halves the spans")
    p.add_argument("--seeds", type=int, nargs="+", default=None,
                   help="implicit: feature seeds, one estimate each (default 2 3)")
    p.add_argument("--width", type=int, default=None,
                   help="implicit: width of the 2 fixed sine layers (default 256; 64 with "
                        "--quick)")
    p.add_argument("--samples", type=int, default=None,
                   help="implicit: Newton samples (default 4096; 2048 with --quick)")
    p.add_argument("--out", required=True, help="output directory (new or empty unless "
                   "--overwrite)")
    p.add_argument("--overwrite", action="store_true",
                   help="allow writing into a non-empty output directory (the files this tool "
                   "writes are replaced)")
    p.add_argument("--point-cloud", action="store_true",
                   help="treat observations as point clouds without correspondence")
    p.add_argument("--decades", type=finite_float, default=1.3,
                   help="bilevel search box: decades either side of the start (default 1.3)")
    p.add_argument("--box-centre", default="start", choices=("residual", "start"),
                   help="bilevel search box centre: the equilibrium-residual estimate when it "
                        "determines every unknown (box ±0.3 decades, the start otherwise), "
                        "or always the start (default: start; the narrower residual box was "
                        "measured less accurate, docs/inverse_material.md)")
    p.add_argument("--iterations", type=int, default=None,
                   help="Adam iterations of the material-conditioned field, followed by as "
                        "many L-BFGS iterations (default 1000; 300 with --quick)")
    p.add_argument("--newton", type=int, default=0, metavar="STEPS",
                   help="bilevel: a last-layer Newton phase of at most STEPS steps after the "
                        "conditioned field's training (default 0: none); with a wide --band it "
                        "brought the orthotropic flap from +31 %% to -0.3 %% "
                        "(docs/inverse_material.md)")
    p.add_argument("--band", type=finite_float, default=None,
                   help="band width of the boundary conditions' vanishing factors, a fraction "
                        "of the domain (edges accept > 1; default: 2 for newton and implicit, "
                        "the scene's for bilevel)")
    p.add_argument("--noise", type=finite_float, default=None, metavar="SIGMA",
                   help="observation noise [m], standard deviation per coordinate, for the "
                        "goodness-of-fit test (χ²/dof and its p-value against the residuals); "
                        "default: estimated from the observation's scatter about local planes")
    p.add_argument("--quick", action="store_true", help="short training, for smoke tests")
    add_runtime_options(p)
    return p


# The options of the shape fits (--observed) that --trajectory has no use for, with their defaults.
SHAPE_OPTIONS = {"method": "newton", "spans": None, "seeds": None, "width": None,
                 "samples": None, "point_cloud": False, "decades": 1.3, "box_centre": "start",
                 "iterations": None, "newton": 0, "band": None, "quick": False}


def parse_args(argv: list[str] | None):
    """The command line, with the scene given once (positional or --scene)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.scene is not None and args.scene_option is not None \
            and args.scene != args.scene_option:
        parser.error(f"two scenes given: {args.scene} and --scene {args.scene_option}")
    args.scene = args.scene or args.scene_option
    if (args.observed is None) == (args.trajectory is None):
        parser.error("give the observations: --observed (shapes) or --trajectory (motion), "
                     "one of them")
    if args.trajectory is not None:
        shapes_only = [f"--{name.replace('_', '-')}" for name, default in SHAPE_OPTIONS.items()
                       if getattr(args, name) != default]
        if shapes_only:
            parser.error(f"{', '.join(shapes_only)}: for --observed shapes, not --trajectory")
    if args.scene is None:
        parser.error("the scene is required (SCENE.toml, or --scene SCENE.toml)")
    return args


@interruptible("ndf-fit-material")
def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    from inverse.cli.fit_material_run import InputError, run

    runtime = start(args)
    try:
        document = run(args, runtime)
    except (InputError, FileExistsError) as err:
        print(f"ndf-fit-material: error: {err}", file=sys.stderr)
        return 2
    for name, entry in document["parameters"].items():
        if entry["determined"]:
            print(f"{name} = {entry['value']:.6g} ± {entry['standard_error']:.2g} "
                  f"{entry['unit']}")
        elif "best_fit_value" in entry:
            print(f"{name}: {entry['status']} (best fit {entry['best_fit_value']:.6g} "
                  f"{entry['unit']}, no error bar)")
        else:
            print(f"{name}: not determined by the data (no value reported)")
    fit = document.get("goodness_of_fit")
    print(f"goodness of fit: {fit['statement']}" if fit else
          "goodness of fit: not tested (the residual method fits no equilibrium shape)")
    if "trajectory" in document:
        fit = document["trajectory"]
        print(f"trajectory fit: {document['iterations']} Gauss–Newton iterations, "
              f"converged {fit['converged']}, noise {fit['noise_m']:.3g} m "
              f"({fit['noise_source']})")
    for note in document.get("notes", []):
        print(f"note: {note}")
    print(f"wrote {Path(args.out) / 'estimate.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
