"""The work of `ndf-fit-material` (`inverse.cli.fit_material`): the observations read and
checked, the estimate by the chosen method, estimate.json and overlay.png written."""

from __future__ import annotations

import json
import logging
from collections.abc import Callable
from dataclasses import dataclass

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
from taichi_ndf.cli.common import machine_description
from taichi_ndf.field import FieldConfig
from taichi_ndf.io import read_mesh
from taichi_ndf.io.grid import grid_mesh
from taichi_ndf.io.output_dir import OutputDir, check_output_dir
from taichi_ndf.io.run_lock import RunLock
from taichi_ndf.problem.run_size import check_siren_size, check_spline_size
from taichi_ndf.problem.spline_grid import SplinePlan
from taichi_ndf.render import save_png
from taichi_ndf.scene.reader import SceneError, load_scene

log = logging.getLogger(__name__)


class InputError(ValueError):
    """Bad command-line input, reported without a traceback."""


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


def _check_newton_size(args, model, itemsize: int) -> None:
    """The Newton estimate's finest grid (its Hessian work is float64: itemsize unused)."""
    config = _newton_config(args)
    plan = SplinePlan(config.model.grid(model), levels=config.levels,
                      quadrature_points=config.model.quadrature_points)
    check_spline_size(plan, advice="choose fewer --spans")


def _check_implicit_size(args, model, itemsize: int) -> None:
    """The implicit estimate's SIREN features on its Newton samples."""
    width, samples = _implicit_sizes(args)
    field = FieldConfig(width=width, hidden_layers=ImplicitConfig.hidden_layers)
    check_siren_size(field, samples, itemsize, advice="choose a smaller --width or fewer "
                                                      "--samples")


@dataclass(frozen=True)
class _FieldFit:
    """A method that fits the unknowns on one field type's equilibria (`newton_estimate` on
    a spline grid, `implicit_estimate` on fixed SIREN features): its memory check
    (args, model, itemsize; ValueError in one line), its estimate (args, observations,
    unknowns -> `OuterResult`; InputError on bad settings) and, in estimate.json, the name of
    the forward model's part of the standard error and of the list of its fits."""

    check_size: Callable[..., None]
    estimate: Callable[..., object]
    model_error: str
    fits: str


def _check_sizes(args, scene, model, itemsize: int) -> None:
    """The memory of the method's largest solve against the machine's, before any work
    (`taichi_ndf.problem.run_size`, the check ndf-sim makes); ValueError in one line beyond it."""
    fit = FIELD_FITS.get(args.method)
    if fit is not None:
        fit.check_size(args, model, itemsize)
    elif args.method == "bilevel":  # a SIREN field: `_conditioned` refused any other
        check_siren_size(scene.field, max(_bilevel_samples(args)), itemsize,
                         advice="choose a narrower [field] in the scene")


def _conditioned(args, scene) -> ConditionedConfig:
    """The bilevel method's conditioned field: the scene's SIREN architecture with the
    command line's training (InputError where the scene's field is not a SIREN)."""
    iterations = args.iterations or (300 if args.quick else 1000)
    try:
        return ConditionedConfig.of_field(
            scene.field, iterations=iterations, samples=_bilevel_samples(args)[0],
            lbfgs_iterations=iterations, lbfgs_samples=_bilevel_samples(args)[1],
            newton_iterations=args.newton, boundary_length=args.band, seed=args.seed)
    except ValueError as err:
        raise InputError(str(err)) from None


def _newton(args, observations, unknowns):
    """The Newton estimate with the command line's settings."""
    try:
        return newton_estimate(observations, unknowns, _newton_config(args))
    except ValueError as err:
        raise InputError(str(err)) from None


# The --method choices that fit on one field type's equilibria, by name.
FIELD_FITS: dict[str, _FieldFit] = {
    "newton": _FieldFit(_check_newton_size, _newton, model_error="discretisation",
                        fits="grids"),
    "implicit": _FieldFit(_check_implicit_size, _implicit, model_error="feature_spread",
                          fits="feature_bases"),
}


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
    if args.trajectory is not None:
        from inverse.cli.fit_material_trajectory import run_trajectory

        return run_trajectory(args, runtime, InputError)
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
    field = _conditioned(args, scene) if args.method == "bilevel" else None
    if field is not None and scene.model.terms:  # its per-sample energy is the shell's alone
        raise InputError("--method bilevel trains its conditioned field on the shell energy "
                         "alone and would leave out the scene's [[terms]] "
                         f"({', '.join(type(t).__name__ for t in scene.model.terms)}): use "
                         "--method newton or implicit")
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
    elif args.method in FIELD_FITS:
        fit = FIELD_FITS[args.method]
        result = fit.estimate(args, observations, unknowns)
        estimate = result.estimate
        document = estimate_document(estimate, model, ratios=result.ratios, notes=result.notes,
                                     goodness=goodness(estimate, result.fits))
        _add_fits(document, result, unknowns, fit.model_error, fit.fits)
        fitted = result.fitted_positions(0, grid_xi).numpy()
    else:
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


