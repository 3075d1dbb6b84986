"""Calibration of an estimator's standard errors: test cases with known truth and noise draws.

Cases (`CASES`; each builds the model with wrong start values, the unknowns, the truth and a
noise-free observation):
- `strip`: the heavy elastica (`taichi_ndf.validation.elastica`, scipy BVP, none of the
  project's solver) of a strip 0.15 × 0.03 m, ρ_A = 0.35 kg/m², bending length 0.06 m
  (B = 7.416e-4 N·m), D = 300 N/m, ν = 0, clamped at 20° above the horizontal (gravity rotated
  by −20° in the strip's frame), observed at 31 × 7 points; unknown B, start 10× the truth.
- `flap`: the orthotropic flap (`scenes/inverse/orthotropic_flap.toml`), truth `scale` = 0.1 of
  the scene's stiffness, start 1.0; observed at 21 × 21 points of an equilibrium computed on a
  quartic spline grid (40 × 40 spans, band 1), not nested in the estimator's (cubic, 8 × 8 and
  16 × 16 spans, band 2).
- `point_load`: the cantilever strip (`scenes/inverse/cantilever_strip.toml`) with the true B
  under a tip load F = (4, 3, −10) mN at ξ = (0.2, 0.02), observed at 41 × 9 points of a
  quartic 40 × 8-span equilibrium (band 1); unknown F (3 components), start (0, 0, −20) mN.

The solved observations (flap, point load) are this project's projected Newton on a finer grid
of another degree and band than the estimator's: a different discretisation of the same
equations, not an independent solver. Their own error is estimated by Richardson extrapolation
(`position_refinement`) from the same equilibrium on the grids with 1/4 and 1/2 of the spans,
and kept in `Case.observation_error`.

`calibrate` fits `draws` noisy copies (Gaussian, σ = noise × bounding-box diagonal per
coordinate, seeds 1..draws) and reports per unknown how many fits determine it and the
coverage: the fraction of those fits with |estimate − truth| ≤ 2 reported standard errors.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from inverse.material.forward_model import forward_model
from inverse.material.observations import Observation
from inverse.material.spline_equilibrium import SplineModelConfig
from inverse.material.unknowns import Unknown, parse_unknowns
from taichi_ndf.boundary import BoundaryConditions, ClampedEdge
from taichi_ndf.field import SplineConfig
from taichi_ndf.geometry import Plane
from taichi_ndf.minimise.refinement import extrapolate_changes
from taichi_ndf.problem.loads import Loads, PointLoad
from taichi_ndf.problem.model import ShellModel
from taichi_ndf.scene.reader import load_scene
from taichi_ndf.shell.materials import LinearIsotropic
from taichi_ndf.validation.elastica import cantilever

log = logging.getLogger(__name__)

# A case's solved observation: positions (M, 3) [m], Richardson order, error [m] (or None).
Solved = tuple[torch.Tensor, float | None, float | None]

SCENES = Path(__file__).resolve().parents[2] / "scenes" / "inverse"


@dataclass
class Case:
    """A test case: name, the model (unknowns at their start values), the unknowns, the true
    values, the noise-free observation, how it was made, and for a solved observation the
    Richardson estimate of its largest position error [m] and the observed order
    (`position_refinement`; None for the strip's BVP)."""

    name: str
    model: ShellModel
    unknowns: list[Unknown]
    truth: np.ndarray
    observation: Observation
    source: str
    observation_error: float | None = None
    observation_order: float | None = None

    def solved(self) -> Solved:
        """What the case's builder computed: the noise-free observed positions (M, 3) [m],
        its Richardson order and error [m] (None for the strip); the builder given it
        (``solved=``) makes the same case without solving again (a study's cache)."""
        return self.observation.points, self.observation_order, self.observation_error


def _grid_points(bounds, counts) -> torch.Tensor:
    (lo1, hi1), (lo2, hi2) = bounds
    s, y = np.meshgrid(np.linspace(lo1, hi1, counts[0]), np.linspace(lo2, hi2, counts[1]))
    return torch.tensor(np.stack([s.ravel(), y.ravel()], axis=1))


def strip_case(length: float = 0.15, width: float = 0.03, density: float = 0.35,
               bending_length: float = 0.06, membrane: float = 300.0,
               clamp_degrees: float = 20.0, points: tuple[int, int] = (31, 7),
               start_factor: float = 10.0, solved: Solved | None = None) -> Case:
    """The heavy-elastica strip (module docstring); the clamp tilted up by `clamp_degrees`.
    solved: the observation of an earlier build of the same case (`Case.solved`); None:
    solve the elastica here."""
    g = 9.81
    bending = density * g * bending_length**3
    angle = math.radians(clamp_degrees)
    gravity = (-g * math.sin(angle), 0.0, -g * math.cos(angle))
    xi = _grid_points(((0.0, length), (0.0, width)), points)
    if solved is None:
        positions, _ = cantilever(length, bending, membrane, (density * gravity[0],
                                                              density * gravity[2]))
        xz = positions(xi[:, 0].numpy())
        observed = torch.tensor(np.stack([xz[:, 0], xi[:, 1].numpy(), xz[:, 1]], axis=1))
    else:
        observed = solved[0]
    surface = Plane(bounds=((0.0, length), (0.0, width)))
    model = ShellModel(surface, LinearIsotropic(membrane, start_factor * bending, 0.0, density),
                       Loads(gravity=gravity),
                       BoundaryConditions([ClampedEdge("xi1_min")], surface.domain))
    model, unknowns = parse_unknowns("bending", model)
    return Case("strip", model, unknowns, np.array([bending]),
                Observation(model, observed, xi), "heavy elastica, scipy solve_bvp")


def solved_observation(model: ShellModel, unknowns: list[Unknown], truth, points,
                       spans: tuple[int, int], degree: int = 4,
                       boundary_length: float = 1.0) -> torch.Tensor:
    """Positions (M, 3) at ξ `points` of the equilibrium with the unknowns at `truth`, on a
    spline grid of its own (projected Newton through 8 load steps)."""
    config = SplineModelConfig(spans=spans, degree=degree, boundary_length=boundary_length,
                               load_steps=tuple(np.linspace(0.125, 1.0, 8).tolist()),
                               newton_iterations=100)
    domain = model.surface.domain
    grid = SplineConfig(spans=spans, degree=degree, domain=domain.bounds,
                        periodic=domain.periodic)
    equilibrium = forward_model(grid, model, unknowns, config)
    equilibrium.solve(truth)
    return equilibrium.positions(points)


def position_refinement(coarse, medium, fine) -> tuple[float, float]:
    """Observed order p and error bar of the finest of three solutions (arrays (M, 3) of
    positions at the same points) on grids h, h/2 and h/4: Richardson's rule
    (`taichi_ndf.minimise.refinement.extrapolate_changes`) on the changes
    d₁ = max‖x_{h/2} − x_h‖ and d₂ = max‖x_{h/4} − x_{h/2}‖, so the error of x_{h/4} is
    d₂ / (2^p − 1) in the asymptotic range, and the bar 1.25 times that; where the order is
    unreliable (d₂ ≥ d₁ or p < 0.5) the bar is 3 (d₁ + d₂), and the order nan where the
    changes do not fall. No rounding check: positions are not what converges, and these solves
    are float64."""
    d1 = float(np.linalg.norm(np.asarray(medium) - np.asarray(coarse), axis=1).max())
    d2 = float(np.linalg.norm(np.asarray(fine) - np.asarray(medium), axis=1).max())
    estimate = extrapolate_changes([d1, d2])
    return (math.nan if estimate.order is None else estimate.order), estimate.error


def converged_observation(model: ShellModel, unknowns: list[Unknown], truth, points,
                          spans: tuple[int, int]) -> tuple[torch.Tensor, float, float]:
    """`solved_observation` on `spans` (each divisible by 4) with its Richardson order and
    error [m] from the solutions on spans / 4 and spans / 2."""
    if any(n % 4 for n in spans):
        raise ValueError(f"spans must be divisible by 4 for the Richardson check, got {spans}")
    solutions = [solved_observation(model, unknowns, truth, points, (spans[0] // k,
                                                                     spans[1] // k))
                 for k in (4, 2, 1)]
    order, error = position_refinement(*[x.numpy() for x in solutions])
    log.info("observation on %s spans: Richardson order %.2f, error %.3g m", spans, order,
             error)
    return solutions[-1], order, error


def flap_case(spans: tuple[int, int] = (40, 40), solved: Solved | None = None) -> Case:
    """The orthotropic flap (module docstring). solved: the observation of an earlier build
    of the same case (`Case.solved`); None: solve it here (`converged_observation`)."""
    model, unknowns = parse_unknowns("scale", load_scene(SCENES / "orthotropic_flap.toml").model)
    truth = np.array([0.1])
    xi = _grid_points(model.surface.domain.bounds, (21, 21))
    if solved is None:
        solved = converged_observation(model, unknowns, truth, xi, spans)
    observed, order, error = solved
    return Case("flap", model, unknowns, truth, Observation(model, observed, xi),
                f"quartic spline {spans[0]} × {spans[1]} spans, band 1", error, order)


def point_load_case(spans: tuple[int, int] = (40, 8), solved: Solved | None = None) -> Case:
    """The strip with an unknown tip load (module docstring). solved: the observation of an
    earlier build of the same case (`Case.solved`); None: solve it here
    (`converged_observation`)."""
    scene = load_scene(SCENES / "cantilever_strip.toml")
    bending = 0.2 * 9.81 * 0.2**3
    truth = np.array([0.004, 0.003, -0.010])
    model = scene.model.with_material(scene.model.material.with_stiffness(
        bending_stiffness=bending))
    loads = dataclasses.replace(model.loads, point_loads=(PointLoad((0.2, 0.02), tuple(truth)),))
    model, unknowns = parse_unknowns("point_load:0", model.with_loads(loads))
    xi = _grid_points(model.surface.domain.bounds, (41, 9))
    if solved is None:
        solved = converged_observation(model, unknowns, truth, xi, spans)
    observed, order, error = solved
    start_loads = dataclasses.replace(
        model.loads, point_loads=(PointLoad((0.2, 0.02), (0.0, 0.0, -0.020)),))
    start_model = model.with_loads(start_loads)
    return Case("point_load", start_model, unknowns, truth,
                Observation(start_model, observed, xi),
                f"quartic spline {spans[0]} × {spans[1]} spans, band 1", error, order)


CASES: dict[str, Callable[[], Case]] = {"strip": strip_case, "flap": flap_case,
                                        "point_load": point_load_case}


@dataclass
class Draw:
    """One fit: noise seed (0: noise-free), estimate, reported standard error and its parts,
    wall time and this process's CPU time [s] (one core: the estimators are single-threaded
    with torch.set_num_threads(1))."""

    seed: int
    values: np.ndarray
    errors: np.ndarray
    fisher: np.ndarray
    model_part: np.ndarray
    seconds: float
    cpu_seconds: float = 0.0


@dataclass
class Calibration:
    """Fits of one case at one noise level and their summary per unknown."""

    case: str
    noise: float
    truth: np.ndarray
    draws: list[Draw]

    def relative_errors(self) -> np.ndarray:
        """(estimate − truth) / |truth| per draw and unknown (|truth vector| for a vector)."""
        scale = np.linalg.norm(self.truth) if len(self.truth) > 1 else abs(self.truth)
        return (np.array([d.values for d in self.draws]) - self.truth) / scale

    def determined(self) -> np.ndarray:
        """Number of draws that determine each unknown (a finite standard error)."""
        return np.sum([np.isfinite(d.errors) for d in self.draws], axis=0)

    def coverage(self) -> np.ndarray:
        """Fraction of the draws that determine an unknown with |estimate − truth| ≤ 2 s.e.,
        per unknown (nan where no draw determines it)."""
        inside = np.array([np.abs(d.values - self.truth) <= 2 * d.errors for d in self.draws])
        finite = np.array([np.isfinite(d.errors) for d in self.draws])
        with np.errstate(invalid="ignore"):
            return (inside & finite).sum(axis=0) / finite.sum(axis=0)


def newton_fit(observations: list[Observation], unknowns: list[Unknown]) -> tuple:
    """The calibrated estimator: `newton_estimate` with its defaults (grid rule, cubic, band
    2, grids h and h/2) -> (values, standard errors, Fisher part, discretisation part)."""
    from inverse.material.newton_fit import newton_estimate

    result = newton_estimate(observations, unknowns)
    e = result.estimate
    return e.values, e.standard_errors, result.fisher_errors, result.discretisation


def fit_draw(case: Case, estimator: Callable[[list[Observation], list[Unknown]], tuple],
             noise: float, seed: int) -> Draw:
    """One fit of the case's observation with noise `noise` drawn with `seed` (seed 0: the
    noise-free observation), timed (wall and this process's CPU time)."""
    observation = case.observation.with_noise(noise, seed=seed) if seed else case.observation
    started, cpu = time.perf_counter(), time.process_time()
    values, errors, fisher, part = estimator([observation], case.unknowns)
    draw = Draw(seed, np.asarray(values), np.asarray(errors), np.asarray(fisher),
                np.asarray(part), time.perf_counter() - started, time.process_time() - cpu)
    log.info("%s noise %g seed %d: %s ± %s (Fisher %s; forward model %s; %.1f s, CPU %.1f s)",
             case.name, noise, seed, draw.values.tolist(), draw.errors.tolist(),
             draw.fisher.tolist(), draw.model_part.tolist(), draw.seconds, draw.cpu_seconds)
    return draw


def calibrate(case: Case, estimator: Callable[[list[Observation], list[Unknown]], tuple],
              noise: float, draws: int) -> Calibration:
    """Fit `draws` noisy copies of the case's observation (seeds 1..draws; noise 0: one
    noise-free fit). estimator(observations, unknowns) -> (values, standard errors, Fisher
    part, forward-model part), absolute."""
    seeds = [0] if noise == 0 else list(range(1, draws + 1))
    return Calibration(case.name, noise, case.truth,
                       [fit_draw(case, estimator, noise, seed) for seed in seeds])
