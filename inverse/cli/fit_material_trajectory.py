"""`ndf-fit-material SCENE --trajectory OBS.json`: one stiffness parameter of a dynamic scene
fitted to observed motion (`inverse.material.trajectory_fit`), estimate.json written.

OBS.json, either
- observations: {"points": [ξ pair [ξ¹, ξ²] or a name of the scene's [[probes]], …],
  "times": [t_f [s], …], "positions": [[[x, y, z] per point] per time] [m] (deformed positions)
  or "displacements" (the same shape, from the reference state) [m], optional "noise": σ [m]
  per coordinate}; or
- a dynamic run's result.json (`ndf-sim` on the scene: `dynamics.times` and
  `dynamics.probes`, every probe's displacement at every step): every probe at every step
  after t = 0 is observed, σ unknown unless --noise.
Every time must be a step of the scene's [dynamics] (k × dt, 1 ≤ k ≤ steps, to 1e-6 dt): the
run is recomputed from rest with the scene's settings at each trial value. Every check (scene
dynamic with fixed steps, the unknown one stiffness parameter, the points and times, the
output directory, the adjoint's refusals of contact, wind and stiffness damping) is
made before the first time step (InputError: exit 2 in one line).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import torch

from inverse.material.identifiability import analyse
from inverse.material.report import estimate_document
from inverse.material.residual import Estimate
from inverse.material.trajectory_fit import TrajectoryData, TrajectoryFitConfig, fit_trajectory
from inverse.material.unknowns import parse_unknowns
from taichi_ndf import jets
from taichi_ndf.cli.common import machine_description
from taichi_ndf.io.output_dir import OutputDir, check_output_dir
from taichi_ndf.io.run_lock import RunLock
from taichi_ndf.solve.dynamics import DynamicsError, TimeStepper
from taichi_ndf.solve.dynamics_adjoint import tangent
from taichi_ndf.solve.dynamics_trajectory import Motion
from taichi_ndf.solve.spline_solver import newton_config

STEP_TOLERANCE = 1e-6  # a time is on the step grid within this fraction of dt


def _read(path: Path, error) -> dict:
    try:
        document = json.loads(Path(path).read_text())
    except FileNotFoundError:
        raise error(f"--trajectory: no such file: {path}") from None
    except (OSError, ValueError) as err:
        raise error(f"--trajectory: cannot read {path} as JSON: {err}") from None
    if not isinstance(document, dict):
        raise error(f"--trajectory {path}: a JSON object expected")
    return document


def _from_run(document: dict) -> tuple[list, list, np.ndarray, str, float | None]:
    """(points, times, values, kind, noise) of a dynamic run's result.json."""
    dynamics = document["dynamics"]
    names = list(dynamics.get("probes") or {})
    times = list(dynamics["times"])[1:]  # t = 0: the reference state, not an observation
    values = np.array([dynamics["probes"][n][1:] for n in names], dtype=float)
    return names, times, values.transpose(1, 0, 2) if values.size else values, \
        "displacements", None


def _fields(document: dict, path, error) -> tuple[list, list, np.ndarray, str, float | None]:
    """(points, times, values (F, P, 3), "positions" | "displacements", noise) of OBS.json."""
    if "dynamics" in document:
        try:
            return _from_run(document)
        except (KeyError, TypeError, ValueError) as err:
            raise error(f"--trajectory {path}: not a dynamic run's result.json "
                        f"(dynamics.times, dynamics.probes): {err}") from None
    kinds = [k for k in ("positions", "displacements") if k in document]
    missing = [k for k in ("points", "times") if k not in document]
    if missing or len(kinds) != 1:
        raise error(f"--trajectory {path}: give points, times and one of positions or "
                    f"displacements (or a dynamic run's result.json)")
    try:
        values = np.array(document[kinds[0]], dtype=float)
        times = [float(t) for t in document["times"]]
        noise = None if document.get("noise") is None else float(document["noise"])
    except (TypeError, ValueError) as err:
        raise error(f"--trajectory {path}: {err}") from None
    return list(document["points"]), times, values, kinds[0], noise


def _xi(points: list, model, error) -> torch.Tensor:
    """(P, 2) ξ of the points: pairs, or names of the scene's probes."""
    probes = {p.name: p.xi for p in model.probes}
    xi = []
    for point in points:
        if isinstance(point, str):
            if point not in probes:
                raise error(f"--trajectory: unknown probe {point!r}; the scene's probes: "
                            f"{sorted(probes) or 'none'}")
            xi.append(probes[point])
        elif isinstance(point, list) and len(point) == 2 \
                and all(isinstance(v, (int, float)) and math.isfinite(v) for v in point):
            xi.append(tuple(float(v) for v in point))
        else:
            raise error(f"--trajectory: a point must be [ξ¹, ξ²] or a probe name, got {point!r}")
    return torch.tensor(xi, dtype=torch.float64).reshape(-1, 2)


def _steps(times: list, config, error) -> tuple[int, ...]:
    """The step index k of each time t = k dt (1 ≤ k ≤ steps)."""
    steps = []
    for t in times:
        k = round(t / config.dt)
        if not (math.isfinite(t) and abs(t - k * config.dt) <= STEP_TOLERANCE * config.dt
                and 1 <= k <= config.steps):
            raise error(f"--trajectory: time {t} s is not a step of the scene's run (k × dt, "
                        f"dt = {config.dt} s, 1 <= k <= {config.steps})")
        steps.append(k)
    return tuple(steps)


def observations(path, scene, model, noise: float | None, error) -> TrajectoryData:
    """OBS.json (module docstring) as `TrajectoryData` on the scene's step grid; `noise` (the
    command line's, [m]) replaces the file's absent one; `error` raised on bad input."""
    points, times, values, kind, stated = _fields(_read(path, error), path, error)
    if not points or not times:
        raise error(f"--trajectory {path}: no points or no times")
    if values.shape != (len(times), len(points), 3) or not np.isfinite(values).all():
        raise error(f"--trajectory {path}: {kind} must be finite, one [x, y, z] per point "
                    f"per time: ({len(times)}, {len(points)}, 3), got {values.shape}")
    if noise is not None and stated is not None and noise != stated:
        raise error(f"--noise {noise} and the observations' noise {stated} differ: give one")
    sigma = noise if noise is not None else stated
    if sigma is not None and not (math.isfinite(sigma) and sigma > 0):
        raise error(f"noise must be finite and > 0 [m], got {sigma}")
    xi = _xi(points, model, error)
    observed = torch.from_numpy(values)
    if kind == "positions":
        observed = observed - model.surface.jets(xi)[:, jets.VALUE].double()
    try:  # the steps' order, checked there
        return TrajectoryData(xi, _steps(times, scene.dynamics, error), observed, sigma)
    except ValueError as err:
        raise error(f"--trajectory {path}: {err}") from None


def run_trajectory(args, runtime, error) -> dict:
    """The trajectory fit of `ndf-fit-material --trajectory` (module docstring)."""
    from taichi_ndf.scene.reader import SceneError, load_scene

    try:
        scene = load_scene(args.scene)
        model, unknowns = parse_unknowns(",".join(args.estimate), scene.model)
    except (SceneError, ValueError) as err:
        raise error(str(err)) from None
    if scene.dynamics is None:
        raise error(f"--trajectory: scene {args.scene} has no [dynamics] section (a run in "
                    "physical time is needed)")
    if scene.dynamics.adaptive is not None:
        raise error("--trajectory: the fit recomputes fixed steps; [dynamics] adaptive = true "
                    "is not supported")
    if len(unknowns) != 1 or unknowns[0].kind != "stiffness":
        raise error(f"--trajectory fits one stiffness parameter of the material (e.g. bending), "
                    f"got {[u.name for u in unknowns]}")
    if args.noise is not None and not args.noise > 0:
        raise error(f"--noise must be > 0 (metres) with --trajectory, got {args.noise}")
    unknown = unknowns[0]
    data = observations(args.trajectory, scene, model, args.noise, error)
    newton = newton_config(scene.solver, runtime.dtype)

    def stepper_at(value: float) -> TimeStepper:
        material = model.material.with_stiffness(**{unknown.key: value})
        return TimeStepper(model.with_material(material), scene.field, scene.dynamics,
                           newton=newton)

    start = unknown.value(model)
    try:
        stepper = stepper_at(start)
        zeros = torch.zeros_like(stepper.field.coefficients)
        # the tangent of a run with no step: the adjoint's refusals (contact, wind,
        # stiffness damping, per-sample stiffness) before any time step is taken
        tangent(stepper, [Motion(0.0, zeros, zeros, zeros)], unknown.key)
    except ValueError as err:
        raise error(str(err)) from None
    lock = RunLock(args.out)
    check_output_dir(args.out, args.overwrite)
    out = OutputDir(args.out, overwrite=args.overwrite, lock=lock)
    try:
        fit = fit_trajectory(stepper_at, data, start,
                             TrajectoryFitConfig(parameter=unknown.key))
    except (ValueError, DynamicsError) as err:  # DynamicsError: a step of a trial run halved
        raise error(str(err)) from None
    notes = [] if fit.converged else [
        f"Gauss–Newton did not converge in {fit.iterations} iterations (last relative step "
        f"above {TrajectoryFitConfig.tolerance}): the value is the last iterate"]
    document = estimate_document(_estimate(fit, unknown), model, goodness=fit.goodness,
                                 notes=notes)
    document["trajectory"] = {
        "times_s": [k * scene.dynamics.dt for k in data.steps], "steps": list(data.steps),
        "points_xi": data.xi.tolist(), "converged": fit.converged,
        "adjoint_tangent_gap": fit.gradient_gap, "noise_m": fit.noise,
        "noise_source": fit.noise_source}
    document["scene"] = str(scene.path)
    document["observed"] = [str(args.trajectory)]
    document["start"] = {unknown.name: start}
    document["machine"] = machine_description(runtime)
    out.file("estimate.json").write_text(json.dumps(document, indent=2))
    return document


def _estimate(fit, unknown) -> Estimate:
    """The fit as the static methods' `Estimate` (identifiability in log θ: the relative s.e.)."""
    jacobian = (fit.value * fit.sensitivity)[:, None]
    identifiability = analyse(jacobian, fit.noise**2, [unknown.name], [True])
    misfit = float(np.sqrt(np.mean(fit.residuals**2)))
    return Estimate([unknown], np.array([fit.value]), np.array([fit.standard_error]),
                    identifiability, misfit, fit.iterations, fit.time_s, "trajectory",
                    residuals=fit.residuals)
