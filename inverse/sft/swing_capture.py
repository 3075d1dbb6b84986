"""A swing's capture unknowns fitted with its material: gravity's pitch and roll in the
camera's frame, the time scale and the bending length, together (issue 27, φ-SfT's R1).

A video states neither the vertical in its camera's frame nor, always, its frame rate
(`gravity_direction`, docs/sft.md). The swing model (`swing.swing_problem`) then has four
unknowns: z = (p, r, ln s, ln c) — gravity `tilted_gravity(frame 0's corners, p, r)` (image-down
made ⊥ the corner line, turned by the pitch p [deg] about it and the roll r [deg] towards
corner b), the time scale s > 0 (the model's frame interval is s Δt: s < 1, the model's clock
runs slower than the video's stated one) and the bending length c [m] (B = ρ_A g c³, which does
not depend on ρ_A's value: c does).

The time scale enters as mass, not as time: a run at frame interval s Δt under ρ_A and g is the
run at Δt under ρ_A / s² and s² g (ρ_A ü = f(u) + ρ_A g with t = s τ; the same steps of
implicit Euler or Newmark are the same maps; mass damping α becomes α s), so the data's
smoothing (`held_motion.smoothed`, whose GCV choice is not exactly invariant to the time unit)
is the same at every s and the residual is smooth in s. ρ_A g, the static rest and B are
unchanged.

Residuals (`capture_residuals`): those of `swing_problem` at z — every stride-th vertex of
frames 1 … F − 1, model − data [m] — from `trajectory_fit.fit_trajectory` with one iteration
at B: its run's residuals and dr/dB (the tangent, the rest start's dC₀/dB included) give the
ln c column exactly (3 B dr/dB). The columns of p, r and ln s are forward differences of runs at
z + h e_i (`CaptureFitConfig.angle_step`, `log_step`; backward at an upper bound). The fit
(`fit_capture`): scipy's trust-region least squares (`least_squares`, "trf", bounds on every
unknown, scaled by the Jacobian's columns) on those residuals and columns; unknowns in
`fixed` stay at the start (a profile's).

Uncertainty: σ̂² = Σ r² / (R − k) and the s.e. σ̂ √((JᵀJ)⁻¹)_ii (`errors`: residuals taken as
independent, which a reconstruction's are not); the residual's correlation length over frames L
(`frame_correlation_length`: 1 + 2 Σ_k ρ_k, ρ_k the lag-k correlation of the per-frame residual
vectors, summed while positive) and the s.e. robust to it (`robust_errors`: the sandwich
`outer_fit.clustered_std` over blocks of ⌈L⌉ consecutive frames, every correlation within a
block — across the sheet and between neighbouring frames — allowed). The profile of c
(`profile_lengths`: the misfit re-fitted over p, r, s at fixed c) gives a one-sided bound
(`upper_bound`) with the effective sample size n_eff = (F − 1) / L: each frame's residual
counted as one unit (within a frame the reconstruction's error is smooth across the sheet) and
frames as L-correlated, the likelihood ratio n_eff ln(SSE(c) / SSE_min) against χ²₁'s 90 %
point 2.706 (one-sided 95 %).
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from inverse.material.outer_fit import clustered_std
from inverse.material.trajectory_fit import (
    TrajectoryFitConfig,
    fit_trajectory,
    normal_inverse,
    observe,
)
from inverse.sft.gravity_direction import tilted_gravity
from inverse.sft.swing import SwingConfig, SwingProblem, swing_problem
from taichi_ndf.minimise.newton import NewtonConfig
from taichi_ndf.solve.dynamics_adjoint import record

log = logging.getLogger(__name__)
UNKNOWNS = ("pitch", "roll", "time_scale", "bending_length")
CHI2_ONE_SIDED_95 = 2.706  # χ²₁'s 90 % point: a one-sided 95 % bound on one unknown
# z within this of a bound [deg; ln] counts as at it: the trust region stays strictly inside
# (R1's c ended 0.8 % above its 0.2 cm bound, ln c 0.0075 from it)
AT_BOUND = 1e-2


@dataclass(frozen=True)
class SwingCapture:
    """A point of the joint fit: pitch, roll [deg] of gravity (`tilted_gravity`), time_scale
    s > 0 (the model's frame interval over the stated one) and bending_length c [m] > 0."""

    pitch: float
    roll: float
    time_scale: float
    bending_length: float

    def __post_init__(self):
        for name in ("pitch", "roll"):
            if not (math.isfinite(getattr(self, name)) and abs(getattr(self, name)) < 90):
                raise ValueError(f"{name} must be finite and in (-90, 90) degrees, got "
                                 f"{getattr(self, name)!r}")
        for name in ("time_scale", "bending_length"):
            if not (math.isfinite(getattr(self, name)) and getattr(self, name) > 0):
                raise ValueError(f"{name} must be finite and > 0, got {getattr(self, name)!r}")

    def vector(self) -> np.ndarray:
        """z = (p, r, ln s, ln c)."""
        return np.array([self.pitch, self.roll, math.log(self.time_scale),
                         math.log(self.bending_length)])

    @classmethod
    def of(cls, z: np.ndarray) -> SwingCapture:
        return cls(float(z[0]), float(z[1]), math.exp(z[2]), math.exp(z[3]))


@dataclass(frozen=True)
class CaptureFitConfig:
    """fixed: unknowns (of UNKNOWNS) held at the start's value; max_evaluations ≥ 1: the
    least squares' residual evaluations (each Jacobian costs 3 runs more, one per free angle
    or scale); tolerance > 0: its relative change of the cost and of z to stop; angle_step
    [deg] and log_step: the forward differences of p, r and of ln s; angle_limit [deg] on |p|
    and |r|, scale_bounds (s_min, s_max), length_bounds (c_min, c_max) [m]: the bounds;
    gravity g [m/s²]."""

    fixed: tuple[str, ...] = ()
    max_evaluations: int = 12
    tolerance: float = 1e-4
    angle_step: float = 0.05
    log_step: float = 1e-3
    angle_limit: float = 45.0
    scale_bounds: tuple[float, float] = (0.05, 5.0)
    length_bounds: tuple[float, float] = (0.002, 0.3)
    gravity: float = 9.81

    def __post_init__(self):
        unknown = [f for f in self.fixed if f not in UNKNOWNS]
        if unknown or len(set(self.fixed)) == len(UNKNOWNS):
            raise ValueError(f"fixed must name some (not all) of {UNKNOWNS}, got {self.fixed!r}")
        if int(self.max_evaluations) != self.max_evaluations or self.max_evaluations < 1:
            raise ValueError(f"max_evaluations must be an integer >= 1, got "
                             f"{self.max_evaluations!r}")
        for name in ("tolerance", "angle_step", "log_step", "gravity"):
            if not (math.isfinite(getattr(self, name)) and getattr(self, name) > 0):
                raise ValueError(f"{name} must be finite and > 0, got {getattr(self, name)!r}")
        if not 0 < self.angle_limit < 90:
            raise ValueError(f"angle_limit must be in (0, 90) degrees, got {self.angle_limit!r}")
        for name in ("scale_bounds", "length_bounds"):
            low, high = getattr(self, name)
            if not (math.isfinite(high) and 0 < low < high):
                raise ValueError(f"{name} must be (low, high) with 0 < low < high, got "
                                 f"{getattr(self, name)!r}")

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """z's lower and upper bounds (4,)."""
        a = self.angle_limit
        return (np.array([-a, -a, math.log(self.scale_bounds[0]),
                          math.log(self.length_bounds[0])]),
                np.array([a, a, math.log(self.scale_bounds[1]),
                          math.log(self.length_bounds[1])]))


@dataclass(frozen=True)
class CaptureProblem:
    """The sequence and settings of `swing_problem` (its arguments) that every point shares."""

    vertices: np.ndarray
    faces: np.ndarray
    held: tuple[int, int]
    frame_interval: float
    config: SwingConfig
    newton: NewtonConfig | None = None
    corners: Callable[[np.ndarray], np.ndarray] | None = None
    turn: Callable[[np.ndarray], np.ndarray] | None = None

    def at(self, point: SwingCapture, gravity: float = 9.81) -> SwingProblem:
        """The swing problem at the point: gravity tilted by p, r and, with the time scale,
        ρ_A / s², s² g and α s at the stated frame interval (module docstring)."""
        s2 = point.time_scale ** 2
        config = dataclasses.replace(self.config, areal_density=self.config.areal_density / s2,
                                     mass_damping=self.config.mass_damping * point.time_scale)
        down = tilted_gravity(np.asarray(self.vertices[0])[list(self.held)], point.pitch,
                              point.roll, magnitude=gravity * s2)
        return swing_problem(self.vertices, self.faces, self.held, self.frame_interval, down,
                             config, newton=self.newton, corners=self.corners, turn=self.turn)


def capture_residuals(problem: CaptureProblem, point: SwingCapture,
                      gravity: float = 9.81) -> tuple[np.ndarray, np.ndarray, SwingProblem]:
    """The swing's residuals r (R,) [m] (model − data) at the point, their derivative by ln c
    (R,) [m] and the point's `SwingProblem` (module docstring)."""
    swing = problem.at(point, gravity)
    bending = problem.config.areal_density * gravity * point.bending_length ** 3
    run = fit_trajectory(swing.stepper_at, swing.data, bending,
                         TrajectoryFitConfig(max_iterations=1), initial=swing.start)
    return run.residuals, 3.0 * bending * run.sensitivity, swing


@dataclass
class CaptureFit:
    """`fit_capture`'s answer: point (the estimate), free (the unknowns fitted), z's s.e. per
    free unknown in z's coordinates (p, r [deg]; ln s, ln c) — `errors` with the residuals as
    independent, `robust` over blocks of ⌈L⌉ frames (module docstring); rms: the misfit
    [m] (3-D, per observed point and frame); residuals (F − 1, P·3) [m] and jacobian (R, k)
    at the estimate; correlation_length L [frames]; evaluations: runs at a point (each
    Jacobian's differences included); at_bound: free unknowns that ended within AT_BOUND of a
    bound;
    message: the least squares' reason to stop."""

    point: SwingCapture
    free: tuple[str, ...]
    errors: dict[str, float]
    robust: dict[str, float]
    rms: float
    residuals: np.ndarray
    jacobian: np.ndarray
    correlation_length: float
    evaluations: int
    at_bound: tuple[str, ...]
    message: str

    @property
    def effective_frames(self) -> float:
        """n_eff = (F − 1) / L: the frames counted as independent units."""
        return len(self.residuals) / self.correlation_length

    def value_error(self, name: str) -> tuple[float, float, float]:
        """(value, s.e., robust s.e.) of a free unknown in its own unit (p, r [deg]; s; c
        [m]): the log-coordinates' s.e. times the value."""
        value = getattr(self.point, name)
        factor = 1.0 if name in ("pitch", "roll") else value
        return value, factor * self.errors[name], factor * self.robust[name]


def fit_capture(problem: CaptureProblem, start: SwingCapture,
                config: CaptureFitConfig = CaptureFitConfig()) -> CaptureFit:
    """The free unknowns of z fitted to the sequence from `start` (module docstring)."""
    z0 = start.vector()
    free = [i for i, name in enumerate(UNKNOWNS) if name not in config.fixed]
    low, high = config.bounds()
    z0 = np.clip(z0, low, high)
    cache: dict[bytes, tuple[np.ndarray, np.ndarray]] = {}
    count = [0]

    def full(x: np.ndarray) -> np.ndarray:
        z = z0.copy()
        z[free] = x
        return z

    def evaluate(z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        key = z.tobytes()
        if key not in cache:
            r, dr, _ = capture_residuals(problem, SwingCapture.of(z), config.gravity)
            count[0] += 1
            log.info("swing capture: p %.3f°, r %.3f°, s %.4f, c %.3f cm: rms %.3f mm",
                     z[0], z[1], math.exp(z[2]), 100 * math.exp(z[3]),
                     1000 * math.sqrt(3 * np.mean(r ** 2)))
            cache[key] = (r, dr)
        return cache[key]

    def residuals(x: np.ndarray) -> np.ndarray:
        return evaluate(full(x))[0]

    def jacobian(x: np.ndarray) -> np.ndarray:
        z = full(x)
        r, dr = evaluate(z)
        columns = []
        for i in free:
            if i == 3:
                columns.append(dr)
                continue
            h = config.angle_step if i < 2 else config.log_step
            if z[i] + h > high[i]:
                h = -h
            moved = z.copy()
            moved[i] += h
            columns.append((evaluate(moved)[0] - r) / h)
        return np.stack(columns, axis=1)

    found = least_squares(residuals, z0[free], jac=jacobian, bounds=(low[free], high[free]),
                          method="trf", x_scale="jac", ftol=config.tolerance,
                          xtol=config.tolerance, gtol=None, max_nfev=config.max_evaluations)
    z = full(found.x)
    r = evaluate(z)[0]
    a = jacobian(found.x)
    names = tuple(UNKNOWNS[i] for i in free)
    sigma = math.sqrt(float(r @ r) / max(len(r) - len(free), 1))
    naive = sigma * np.sqrt(np.maximum(np.diag(normal_inverse(a.T @ a)), 0.0))
    frames = r.reshape(len(problem.vertices) - 1, -1)
    length = frame_correlation_length(frames)
    robust = robust_errors(a, frames, length)
    ends = tuple(UNKNOWNS[i] for i in free if min(z[i] - low[i], high[i] - z[i]) < AT_BOUND)
    return CaptureFit(SwingCapture.of(z), names, dict(zip(names, naive.tolist(), strict=True)),
                      dict(zip(names, robust.tolist(), strict=True)),
                      math.sqrt(3 * float(np.mean(r ** 2))), frames, a, length, count[0],
                      ends, str(found.message))


def frame_correlation_length(residuals: np.ndarray) -> float:
    """L [frames] of residuals (F, m) (one row per frame): 1 + 2 Σ_{k ≥ 1} ρ_k, ρ_k =
    Σ_f ⟨r_f, r_{f+k}⟩ / Σ_f |r_f|², summed while ρ_k > 0 (1: frames uncorrelated)."""
    residuals = np.asarray(residuals, dtype=np.float64)
    total = float(np.sum(residuals ** 2))
    if not total > 0:
        return 1.0
    length = 1.0
    for k in range(1, len(residuals)):
        rho = float(np.sum(residuals[k:] * residuals[:-k])) / total
        if rho <= 0:
            break
        length += 2 * rho
    return length


def robust_errors(jacobian: np.ndarray, residuals: np.ndarray, length: float) -> np.ndarray:
    """The sandwich s.e. (`outer_fit.clustered_std`) of the unknowns of `jacobian` (R, k)
    with residuals (F, m) (R = F m, frame-major) clustered in blocks of ⌈length⌉ consecutive
    frames."""
    frames, width = residuals.shape
    block = max(1, math.ceil(length - 1e-9))
    clusters = [np.arange(f * width, min(f + block, frames) * width)
                for f in range(0, frames, block)]
    return clustered_std(jacobian, residuals.reshape(-1), clusters)


def profile_lengths(problem: CaptureProblem, start: SwingCapture, lengths: Sequence[float],
                    config: CaptureFitConfig = CaptureFitConfig()) -> list[CaptureFit]:
    """The misfit re-fitted over the other free unknowns at each fixed bending length c [m]
    of `lengths` (in order), each from the last one's p, r, s (the first from `start`'s)."""
    fixed = tuple(sorted(set(config.fixed) | {"bending_length"}))
    fits, point = [], start
    for length in lengths:
        point = dataclasses.replace(point, bending_length=float(length))
        fit = fit_capture(problem, point, dataclasses.replace(config, fixed=fixed))
        fits.append(fit)
        point = fit.point
    return fits


def likelihood_ratio(rms: float, best: float, effective: float) -> float:
    """n_eff ln(SSE / SSE_min) of a profile point's rms [m] against the best rms [m] with
    `effective` independent units (module docstring)."""
    return effective * 2.0 * math.log(rms / best)


def upper_bound(lengths: Sequence[float], rms: Sequence[float], best: float,
                effective: float, level: float = CHI2_ONE_SIDED_95) -> float | None:
    """The smallest c [m] above the best fit where the profile's `likelihood_ratio` (lengths
    increasing, their re-fitted rms [m], the best rms [m], n_eff) reaches `level`, linear in
    ln c between profile points; None: not reached within the profile (no bound)."""
    ratios = [likelihood_ratio(m, best, effective) for m in rms]
    for i in range(1, len(lengths)):
        if ratios[i] >= level > ratios[i - 1]:
            a, b = math.log(lengths[i - 1]), math.log(lengths[i])
            t = (level - ratios[i - 1]) / (ratios[i] - ratios[i - 1])
            return math.exp(a + t * (b - a))
    if ratios and ratios[0] >= level:
        return float(lengths[0])
    return None


def model_sequence(problem: CaptureProblem, point: SwingCapture,
                   gravity: float = 9.81) -> np.ndarray:
    """The model's own motion at the point (a synthetic check's truth): every template
    vertex's position (F, V, 3) [m] at the sequence's frames (frame 0 the start), the handles
    on the sequence's corners, the start the sequence's (`SwingConfig.start`)."""
    every = dataclasses.replace(problem, config=dataclasses.replace(problem.config, stride=1))
    swing = every.at(point, gravity)
    stepper = swing.stepper_at(problem.config.areal_density * gravity
                               * point.bending_length ** 3)
    begin = swing.start(stepper)
    states = record(stepper, begin.displacement, begin.velocity)
    out = np.array(problem.vertices, dtype=np.float64)
    index = swing.grid.index.ravel()
    for f, k in enumerate((0, *swing.data.steps)):
        moved = observe(stepper, swing.xi, states[k].displacement, states[k].time)
        out[f, index] = swing.flat + moved.numpy()
    return out
