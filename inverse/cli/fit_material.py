"""`ndf-fit-material`: estimate material parameters and loads from observed equilibrium shapes.

    ndf-fit-material S.toml --observed OBS.obj [OBS2.ply ...] --estimate bending \
        [--method newton|implicit|bilevel|residual] --out DIR

The scene gives everything known (geometry, boundary conditions, known loads) and start values
of the unknowns. An observation whose vertex count equals the scene's exported template grid
([output] resolution) is taken in template vertex order (correspondence); with
`--point-cloud` the points are fitted without correspondence (point-to-surface distance).
Writes DIR/estimate.json and DIR/overlay.png (observed points over the fitted shape).
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path

import numpy as np
import torch

from inverse.material import (
    Observation,
    ResidualConfig,
    parse_unknowns,
    residual_estimate,
    template_xi,
)
from inverse.material.bilevel import BilevelConfig, bilevel_estimate
from inverse.material.conditioned import ConditionedConfig, to_values
from inverse.material.goodness import forward_model_error, goodness_of_fit, observation_noise
from inverse.material.identifiability import finite_or_none
from inverse.material.implicit import ImplicitConfig
from inverse.material.implicit_fit import implicit_estimate
from inverse.material.newton_fit import NewtonEstimateConfig, newton_estimate
from inverse.material.report import estimate_document, overlay_image
from inverse.material.spline_equilibrium import SplineModelConfig
from taichi_ndf.cli.common import (
    ArgumentParser,
    add_runtime_options,
    description,
    finite_float,
    interruptible,
    machine_description,
    start,
)
from taichi_ndf.field import FieldConfig
from taichi_ndf.io import read_mesh
from taichi_ndf.io.grid import grid_mesh
from taichi_ndf.io.output_dir import OutputDir, check_output_dir
from taichi_ndf.io.run_lock import RunLock
from taichi_ndf.render import save_png
from taichi_ndf.run_size import check_siren_size, check_spline_size
from taichi_ndf.scene import SceneError, load_scene
from taichi_ndf.spline_grid import SplinePlan

log = logging.getLogger(__name__)


class InputError(ValueError):
    """Bad command-line input, reported without a traceback."""


def build_parser() -> argparse.ArgumentParser:
    p = ArgumentParser(prog="ndf-fit-material", description=description(__doc__))
    p.add_argument("scene", nargs="?", type=Path,
                   help="scene TOML: known conditions, start values")
    p.add_argument("--scene", dest="scene_option", type=Path, metavar="SCENE",
                   help="the scene, as an option (the same as the positional)")
    p.add_argument("--observed", required=True, nargs="+",
                   help="observed shape(s), OBJ or PLY, all under the scene's conditions")
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
    p.set_defaults(precision="f64")
    return p


def _observations(paths, model, resolution, point_cloud: bool) -> list[Observation]:
    xi = template_xi(model, resolution)
    out = []
    for path in paths:
        try:
            mesh = read_mesh(path)
        except FileNotFoundError as err:
            raise InputError(str(err)) from None
        except Exception as err:  # trimesh raises many kinds on a malformed file
            raise InputError(f"cannot read observation {path}: {err}") from None
        points = torch.from_numpy(np.asarray(mesh.vertices, dtype=np.float64))
        if not torch.isfinite(points).all():
            bad = int((~torch.isfinite(points).all(dim=1)).sum())
            raise InputError(f"observation {path}: {bad} vertices are not finite (NaN or "
                             "infinity)")
        if point_cloud:
            out.append(Observation(model, points, None))
            continue
        if len(points) != len(xi):
            raise InputError(
                f"observation {path} has {len(points)} vertices but the template grid of the "
                f"scene ([output] resolution {list(resolution)}) has {len(xi)}: give meshes in "
                f"template vertex order, or pass --point-cloud")
        out.append(Observation(model, points, xi))
    return out


def _implicit(args, observations, unknowns):
    """The implicit-function estimate with the command line's settings."""
    width, samples = _implicit_sizes(args)
    try:
        config = ImplicitConfig(width=width, samples=samples,
                                seeds=tuple(args.seeds or (2, 3)),
                                boundary_length=2.0 if args.band is None else args.band)
        return implicit_estimate(observations, unknowns, config)
    except ValueError as err:
        raise InputError(str(err)) from None


def _implicit_sizes(args) -> tuple[int, int]:
    """The implicit method's feature width and Newton samples."""
    return (args.width or (64 if args.quick else ImplicitConfig.width),
            args.samples or (2048 if args.quick else ImplicitConfig.samples))


def _newton_config(args) -> NewtonEstimateConfig:
    """The Newton estimate's settings from the command line."""
    model = SplineModelConfig(spans=tuple(args.spans) if args.spans else None,
                              boundary_length=2.0 if args.band is None else args.band)
    return NewtonEstimateConfig(model=model)


def _bilevel_samples(args) -> tuple[int, int]:
    """The bilevel method's Adam and L-BFGS samples."""
    return (512, 2048) if args.quick else (1024, 4096)


def _check_sizes(args, scene, model, itemsize: int) -> None:
    """The memory of the method's largest solve against the machine's, before any work
    (`taichi_ndf.run_size`, the check ndf-sim makes); ValueError in one line beyond it."""
    if args.method == "newton":
        config = _newton_config(args)
        plan = SplinePlan(config.model.grid(model), levels=config.levels,
                          quadrature_points=config.model.quadrature_points)
        check_spline_size(plan, advice="choose fewer --spans")
    elif args.method == "implicit":
        width, samples = _implicit_sizes(args)
        field = FieldConfig(width=width, hidden_layers=ImplicitConfig.hidden_layers)
        check_siren_size(field, samples, itemsize, advice="choose a smaller --width or fewer "
                                                          "--samples")
    elif args.method == "bilevel" and isinstance(scene.field, FieldConfig):
        check_siren_size(scene.field, max(_bilevel_samples(args)), itemsize,
                         advice="choose a narrower [field] in the scene")


def _newton(args, observations, unknowns):
    """The Newton estimate with the command line's settings."""
    try:
        return newton_estimate(observations, unknowns, _newton_config(args))
    except ValueError as err:
        raise InputError(str(err)) from None


def _add_fits(document: dict, result, unknowns, part: str, fits: str) -> None:
    """The standard error's parts (`fisher` and the forward model's `part`) per unknown and
    every forward model's fit (under `fits`) of an `OuterResult`, into the document; a fit's
    `converged` is true only where the outer iteration and every equilibrium solve in it
    converged."""
    document["standard_error_parts"] = {
        u.name: {"fisher": finite_or_none(f), part: finite_or_none(m)}
        for u, f, m in zip(unknowns, result.fisher_errors, result.model_errors, strict=True)}
    document[fits] = [
        {**f.label, "values": f.values.tolist(), "outer_iterations": f.iterations,
         "newton_steps": f.newton_steps,
         "converged": bool(f.converged and f.solves_converged),
         "outer_converged": f.converged, "unconverged_solves": f.unconverged_solves,
         "stable": f.stable, "time_s": f.time} for f in result.fits]


def run(args, runtime) -> dict:
    try:
        scene = load_scene(args.scene)
    except SceneError as err:
        raise InputError(str(err)) from None
    try:
        model, unknowns = parse_unknowns(",".join(args.estimate), scene.model)
    except ValueError as err:
        raise InputError(str(err)) from None
    if args.iterations is not None and args.iterations < 1:
        raise InputError(f"--iterations must be >= 1, got {args.iterations}")
    if args.newton < 0:
        raise InputError(f"--newton must be >= 0, got {args.newton}")
    if args.band is not None and not args.band > 0:
        raise InputError(f"--band must be positive, got {args.band}")
    for name in ("width", "samples"):
        if getattr(args, name) is not None and getattr(args, name) < 1:
            raise InputError(f"--{name} must be >= 1, got {getattr(args, name)}")
    if args.noise is not None and not args.noise >= 0:
        raise InputError(f"--noise must be >= 0 (metres), got {args.noise}")
    if args.spans is not None and min(args.spans) < 1:
        raise InputError(f"--spans must be two integers >= 1, got {args.spans}")
    try:
        _check_sizes(args, scene, model, runtime.dtype.itemsize)
    except ValueError as err:
        raise InputError(str(err)) from None
    lock = RunLock(args.out)  # a directory another run holds is refused before any work,
    check_output_dir(args.out, args.overwrite)  # and so is a non-empty one without --overwrite
    observations = _observations(args.observed, model, scene.output.resolution,
                                 args.point_cloud)
    out = OutputDir(args.out, overwrite=args.overwrite, lock=lock)
    resolution = scene.output.resolution
    grid = grid_mesh(model.surface.domain.bounds, resolution,
                     periodic=model.surface.domain.periodic)
    grid_xi = torch.from_numpy(grid.xi)
    noise, noise_source = observation_noise(observations, args.noise)

    def goodness(estimate, fits=()):
        return goodness_of_fit(estimate.residuals, len(unknowns), noise, noise_source,
                               forward_model_error(fits))

    if args.method == "residual":
        estimate = residual_estimate(observations, unknowns, ResidualConfig(samples=16384))
        document = estimate_document(estimate, model, notes=estimate.notes)
        fitted = estimate.shapes[0].positions(grid_xi).numpy()
    elif args.method in ("newton", "implicit"):
        newton = args.method == "newton"
        result = (_newton if newton else _implicit)(args, observations, unknowns)
        estimate = result.estimate
        document = estimate_document(estimate, model, ratios=result.ratios, notes=result.notes,
                                     goodness=goodness(estimate, result.fits))
        _add_fits(document, result, unknowns,
                  *(("discretisation", "grids") if newton else ("feature_spread",
                                                               "feature_bases")))
        fitted = result.fitted_positions(0, grid_xi).numpy()
    else:
        iterations = args.iterations or (300 if args.quick else 1000)
        field = ConditionedConfig(
            width=scene.field.width, hidden_layers=scene.field.hidden_layers,
            omega0=scene.field.omega0, output_scale=scene.field.output_scale,
            iterations=iterations, samples=_bilevel_samples(args)[0],
            lbfgs_iterations=iterations, lbfgs_samples=_bilevel_samples(args)[1],
            newton_iterations=args.newton, boundary_length=args.band, seed=args.seed)
        try:
            config = BilevelConfig(decades=args.decades, field=field,
                                   centre_on_residual=args.box_centre == "residual")
        except ValueError as err:
            raise InputError(str(err)) from None
        try:
            result = bilevel_estimate(observations, unknowns, config)
        except ValueError as err:
            raise InputError(str(err)) from None
        estimate = result.estimate
        document = estimate_document(estimate, model, ratios=result.ratios, notes=result.notes,
                                     goodness=goodness(estimate))
        lower = to_values(unknowns, [lo for lo, _ in result.ranges])
        upper = to_values(unknowns, [hi for _, hi in result.ranges])
        document["search_box"] = {u.name: [lo, hi]
                                  for u, lo, hi in zip(unknowns, lower, upper, strict=True)}
        document["search_box_centre"] = {
            "source": result.box_centre,
            "values": {u.name: v for u, v in zip(unknowns, result.box_centre_values,
                                                 strict=True)}}
        fitted = result.fitted_positions(0, grid_xi).numpy()
    document["scene"] = str(scene.path)
    document["observed"] = [str(p) for p in args.observed]
    document["start"] = {u.name: u.value(model) for u in unknowns}
    document["machine"] = machine_description(runtime)
    out.file("estimate.json").write_text(json.dumps(document, indent=2))
    save_png(out.file("overlay.png"),
             overlay_image(fitted, grid.faces, observations[0].points.numpy()))
    return document


def parse_args(argv: list[str] | None):
    """The command line, with the scene given once (positional or --scene)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.scene is not None and args.scene_option is not None \
            and args.scene != args.scene_option:
        parser.error(f"two scenes given: {args.scene} and --scene {args.scene_option}")
    args.scene = args.scene or args.scene_option
    if args.scene is None:
        parser.error("the scene is required (SCENE.toml, or --scene SCENE.toml)")
    return args


@interruptible("ndf-fit-material")
def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
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
    for note in document.get("notes", []):
        print(f"note: {note}")
    print(f"wrote {Path(args.out) / 'estimate.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
