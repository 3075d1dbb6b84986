"""The bending stiffness of a sheet from its swing: a video's sheet held at two MOVING corners
as one dynamic run, fitted to all its frames.

Input: per-frame vertex positions (F, V, 3) [m] of a grid template held at two corner
vertices (e.g. `ndf-sft`'s meshes, camera coordinates), the frame interval Δt [s] (a video's
1/fps) and gravity (3,) [m/s²] in their frame. The model (`swing_problem`):
- the flat sheet of frame 0's grid-line lengths (`hanging.SheetGrid`; `size` when stated),
  placed hanging vertically from frame 0's corner line (`hanging.hanging_across`,
  `hanging.hanging_model`), corner a at frame 0's and corner b at the sheet's width W from it
  along that line, each held by a handle (slope held in the handle's band);
- the handles follow the observed corner vertices (`solve.handle_paths.PathStepper`): each
  corner coordinate smoothed in time by a cubic smoothing spline whose smoothing GCV chooses
  (`scipy.interpolate.make_smoothing_spline`: the reconstruction's corner noise would
  otherwise enter as accelerations of ~σ/Δt²), sampled at every time step; or
  (`SwingConfig.corners` "fitted") unknowns of the fit with B: each corner coordinate a cubic
  B-spline in time (`corner_spans` uniform spans over the sequence, clamped; None: one per
  frame interval), started at the least-squares fit to those smoothed tracks
  (`trajectory_fit`: the paths' columns of the tangent; the s.e. of B then the marginal one,
  carrying the corners' uncertainty). Measured on the synthetic swing, the truth's own grid
  (16², 2 mm noise, seeds 0/1): smoothed −27 / −19 % (z 34 / 32), fitted (6 spans) +2.1 /
  +3.0 % (z 1.4 / 1.9) (benchmarks/RESULTS.md, "the corner paths as unknowns");
- the turn (`SwingConfig.turn` "read"): the held edge also turns about the corner line (the
  handles' spots turning with it, `HandlePath.turns`) by the angle of the vertex rows in the
  handles' band from the corner line (`held_motion.edge_turn`), smoothed as the corners, zero
  at frame 0 (a grip that the hands turn; "none", the default: the slope stays the reference's);
- the start (`SwingConfig.start`): "rest" (default) — the sheet at rest in the static
  equilibrium under gravity with its corners at frame 0's (`dynamics_adjoint.rest_start`:
  Newton from the spline field's least-squares fit to frame 0, so the equilibrium whose basin
  holds the observed shape; V₀ = 0), recomputed at every trial B with its derivative
  dC₀/dB in the tangent and the adjoint. It is a state of the model itself, so it carries no
  strain energy from the data's noise (a least-squares fit of noisy positions stores
  membrane energy that the run turns into motion), and it holds for any capture whose first
  frame shows the sheet still: a property of the recording that `start_velocity` measures
  (the smoothed data's rms vertex speed at t = 0), not a setting fitted to one capture.
  "data" — frame 0's shape and velocity: the field's least-squares fit (free part J C, the
  handles' part g(0) taken off) to the vertices' positions and velocities at t = 0 from the
  same smoothing of each vertex coordinate over the frames (an energetic, noisy start);
- `substeps` time steps per frame (implicit Euler by default), gravity, the material
  LinearIsotropic(D, B, ν, ρ_A) with D, ν and ρ_A stated.
Observed: every `stride`-th vertex (in each grid direction) of frames 1 … F − 1, as
displacements from the flat reference; B fitted by `inverse.material.trajectory_fit`
(Gauss–Newton, gradient by the adjoint, Hessian by the tangent through every step), the noise
estimated from the residuals (the s.e. is then σ̂/√H: it treats the residuals as independent,
which a reconstruction's are not — the report states it). B scales with ρ_A; the bending
length c = (B / (ρ_A g))^(1/3) does not.
The grid (`fit_swing`, `SwingConfig.spans` None): a sheet held at two points buckles at the
bending length's scale, so the swing's model error is set by span / c; the spans are chosen
no longer than `span_ratio` × c of the current estimate (`resolving_spans`: from the start
value first, then a warm-started refit on the finer grid whenever the estimate's c asks for
one), whatever the sheet's size, the motion or the frame rate; then (`grid_check`) one
Gauss–Newton step on a grid GROWTH × finer confirms it: where that step moves B by more than
its s.e., the fit goes on on the finer grid. The check measures the grid's effect on the
answer itself, so it does not depend on span_ratio being right. The knots (`swing_knots`):
uniform, or "graded" towards the held points (the rest's B bias, 32², degree 3: −21 → −0.3 %).
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch

from inverse.material.trajectory_fit import (
    TrajectoryData,
    TrajectoryFit,
    TrajectoryFitConfig,
    fit_trajectory,
    observe,
)
from inverse.sft.hanging import SheetGrid, hanging_across, hanging_model
from inverse.sft.held_motion import edge_turn, evaluate_smoothed, smoothed
from inverse.sft.swing_knots import check_knots, swing_spline
from taichi_ndf import jets
from taichi_ndf.minimise.newton import NewtonConfig
from taichi_ndf.problem.dynamics import DynamicsConfig
from taichi_ndf.problem.model import ShellModel
from taichi_ndf.problem.spline_grid import SplinePlan
from taichi_ndf.shell.fabrics import bending_length
from taichi_ndf.shell.materials import LinearIsotropic
from taichi_ndf.solve.dynamics_adjoint import Start, rest_start
from taichi_ndf.solve.handle_paths import HandlePath, PathStepper, moved_boundary, spline_basis

log = logging.getLogger(__name__)
SPAN_RATIO = 1.0  # the longest span, in bending lengths c (RESULTS.md, issue 27, the buckle)
GROWTH = 4 / 3  # the grid check's spans, per direction, over the fit's


@dataclass(frozen=True)
class SwingConfig:
    """spans: the spline grid (n1, n2) [spans along ξ¹ (the held edge), ξ²], or None: from
    the bending length of the current estimate (`resolving_spans`, `fit_swing`): no span
    longer than span_ratio × c, at most max_spans per direction; grid_check: there, confirm
    the grid by one Gauss–Newton step on a finer one (`fit_swing`); degree 3 or 4; knots:
    "uniform" or "graded" towards the held points (`swing_knots`);
    substeps ≥ 1 time steps per frame; integrator "implicit_euler" or "newmark";
    mass_damping α [1/s] ≥ 0; membrane_stiffness D [N/m], poisson_ratio ν, areal_density ρ_A
    [kg/m²] (stated); band: the handles' band (fraction of the domain); grip ≥ 0 [m]: each
    corner held at its point (0) or over a patch of that radius (`hanging.hanging_model`);
    stride ≥ 1: every stride-th vertex per grid direction observed; size: the flat sheet
    (W, H) [m] or None (frame 0's grid-line lengths); start: "rest" or "data"; corners:
    "smoothed" or "fitted", corner_spans ≥ 1 or None (one per frame interval): the fitted
    corners' B-spline (module docstring); turn: "none" (the held slope stays the reference's)
    or "read" (the held edge turns about the corner line by the angle read off the rows in
    the handles' band, module docstring)."""

    spans: tuple[int, int] | None = None
    span_ratio: float = SPAN_RATIO
    max_spans: int = 32
    grid_check: bool = True
    degree: int = 3
    knots: str = "uniform"
    substeps: int = 1
    integrator: str = "implicit_euler"
    mass_damping: float = 0.0
    membrane_stiffness: float = 300.0
    poisson_ratio: float = 0.25
    areal_density: float = 0.197
    band: float = 0.1
    grip: float = 0.0
    stride: int = 1
    size: tuple[float, float] | None = None
    start: str = "rest"
    corners: str = "smoothed"
    corner_spans: int | None = None
    turn: str = "none"

    def __post_init__(self):
        if self.start not in ("rest", "data"):
            raise ValueError(f"start must be rest or data, got {self.start!r}")
        if self.corners not in ("smoothed", "fitted"):
            raise ValueError(f"corners must be smoothed or fitted, got {self.corners!r}")
        if self.turn not in ("none", "read"):
            raise ValueError(f"turn must be none or read, got {self.turn!r}")
        if self.corner_spans is not None and (int(self.corner_spans) != self.corner_spans
                                              or self.corner_spans < 1):
            raise ValueError(f"corner_spans must be None or an integer >= 1, got "
                             f"{self.corner_spans!r}")
        if self.spans is not None and (len(self.spans) != 2 or any(
                int(s) != s or s < 1 for s in self.spans)):
            raise ValueError(f"spans must be None or two integers >= 1, got {self.spans!r}")
        if not (math.isfinite(self.span_ratio) and self.span_ratio > 0):
            raise ValueError(f"span_ratio must be finite and > 0, got {self.span_ratio!r}")
        if int(self.max_spans) != self.max_spans or self.max_spans < 1:
            raise ValueError(f"max_spans must be an integer >= 1, got {self.max_spans!r}")
        if self.degree not in (3, 4):
            raise ValueError(f"degree must be 3 or 4, got {self.degree!r}")
        check_knots(self.knots)
        if int(self.substeps) != self.substeps or self.substeps < 1:
            raise ValueError(f"substeps must be an integer >= 1, got {self.substeps!r}")
        if self.integrator not in ("implicit_euler", "newmark"):
            raise ValueError(f"integrator must be implicit_euler or newmark, got "
                             f"{self.integrator!r}")
        for name in ("membrane_stiffness", "areal_density", "band"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be finite and > 0, got {value!r}")
        for name in ("mass_damping", "grip"):
            if not (math.isfinite(getattr(self, name)) and getattr(self, name) >= 0):
                raise ValueError(f"{name} must be finite and >= 0, got {getattr(self, name)!r}")
        if not -1 < self.poisson_ratio < 0.5:
            raise ValueError(f"poisson_ratio must be in (-1, 0.5), got {self.poisson_ratio!r}")
        if int(self.stride) != self.stride or self.stride < 1:
            raise ValueError(f"stride must be an integer >= 1, got {self.stride!r}")
        if self.size is not None and not (len(self.size) == 2 and all(
                math.isfinite(s) and s > 0 for s in self.size)):
            raise ValueError(f"size must be two lengths > 0 [m], got {self.size!r}")


@dataclass
class SwingProblem:
    """What `fit_trajectory` needs: stepper_at(B) (the run's stepper at bending stiffness B
    [N·m]), start(stepper) (its `Start`, `fit_trajectory`'s initial), the observations, and
    the model's pieces for the report: grid (the template's ξ), the flat reference model, the
    handles' path, frame interval Δt [s], the observed points' ξ (P, 2), flat positions and
    frame-0 positions (P, 3) [m], and start_velocity: the smoothed data's rms vertex speed at
    t = 0 [m/s] (a rest start assumes it is at the noise's level); path_start: the fitted
    corners' start q₀ (p,) [m] (then stepper_at(B, q)), None where they are smoothed."""

    stepper_at: Callable[[float], PathStepper]
    start: Callable[[PathStepper], Start]
    data: TrajectoryData
    grid: SheetGrid
    model: ShellModel
    path: HandlePath
    frame_interval: float
    xi: torch.Tensor
    flat: np.ndarray
    frame0: np.ndarray
    start_velocity: float
    path_start: np.ndarray | None = None

    def start_misfit(self, bending: float) -> float:
        """rms distance [m] of the start's shape at B [N·m] to frame 0's observed points."""
        stepper = self.stepper_at(bending)
        c0 = self.start(stepper).displacement
        fitted = observe(stepper, self.xi, c0, 0.0).numpy() + self.flat
        return float(np.sqrt(np.mean(np.sum((fitted - self.frame0) ** 2, axis=1))))


def _fit_free(stepper: PathStepper, xi: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Coefficients C (n, 3) minimising Σ |J C − target|² at ξ (P, 2), target (P, 3) [m]
    (J: the free part, linear; least squares of minimum norm)."""
    zeros = torch.zeros_like(stepper.field.coefficients)
    jacobian = torch.autograd.functional.jacobian(lambda c: observe(stepper, xi, c), zeros)
    matrix = jacobian.reshape(target.numel(), zeros.numel())
    solution = np.linalg.lstsq(matrix.numpy(), target.reshape(-1).numpy(), rcond=1e-10)[0]
    return torch.from_numpy(solution).reshape(zeros.shape).to(zeros.dtype)


def swing_problem(vertices: np.ndarray, faces: np.ndarray, held: tuple[int, int],
                  frame_interval: float, gravity: np.ndarray,
                  config: SwingConfig = SwingConfig(), *,
                  newton: NewtonConfig | None = None,
                  corners: Callable[[np.ndarray], np.ndarray] | None = None,
                  turn: Callable[[np.ndarray], np.ndarray] | None = None) -> SwingProblem:
    """The dynamic model of the sequence and its observations (module docstring); vertices
    (F, V, 3) [m], F ≥ 5; faces of the grid template; held: the two corner vertex indices;
    frame_interval Δt [s] > 0; gravity (3,) [m/s²]; corners(t): the held corners' positions
    (T, 2, 3) [m] at times t (T,) [s] where they are known otherwise (a synthetic check's
    truth; None: the observed corner vertices, smoothed); turn(t): the held edge's turn
    (T,) [rad] about the corner line where known otherwise (None: config.turn's).
    ValueError on bad input."""
    if config.spans is None:
        raise ValueError("swing problem: spans None (the grid from the estimate's bending "
                         "length) is `fit_swing`'s; give spans here")
    vertices = np.asarray(vertices, dtype=np.float64)
    if vertices.ndim != 3 or vertices.shape[0] < 5 or vertices.shape[2] != 3:
        raise ValueError(f"vertices must be (F, V, 3) with F >= 5 frames (the smoothing), got "
                         f"{vertices.shape}")
    if not np.isfinite(vertices).all():
        raise ValueError("vertices must be finite")
    if not (math.isfinite(frame_interval) and frame_interval > 0):
        raise ValueError(f"frame interval must be finite and > 0 [s], got {frame_interval!r}")
    gravity = np.asarray(gravity, dtype=np.float64)
    frames = len(vertices)
    times = frame_interval * np.arange(frames)
    grid = SheetGrid.from_template(vertices[0], faces, held)
    if config.size is not None:
        grid = grid.with_size(config.size)
    width, height = grid.size
    # each vertex coordinate smoothed over the frames: the start's shape and velocity
    smooth = smoothed(vertices, times)
    if corners is None:
        corner_smooth = smoothed(vertices[:, list(held)], times)

        def corners(t: np.ndarray) -> np.ndarray:
            return evaluate_smoothed(corner_smooth, t)
    first = corners(np.zeros(1))[0]
    line = first[1] - first[0]
    e1 = line / np.linalg.norm(line)
    reference = np.stack([first[0], first[0] + width * e1])
    material = LinearIsotropic(config.membrane_stiffness, 1.0, config.poisson_ratio,
                               config.areal_density)
    across = hanging_across(reference, gravity)
    model = hanging_model(grid.size, material, reference, across, gravity, band=config.band,
                          grip=config.grip)
    model = dataclasses.replace(model, boundary=moved_boundary(model.boundary,
                                                               np.zeros((2, 3))))
    dt = frame_interval / config.substeps
    steps = config.substeps * (frames - 1)
    step_times = dt * np.arange(steps + 1)
    if turn is None and config.turn == "read":
        rows = grid.index[:, 1:max(2, 1 + int(config.band * (grid.shape[1] - 1)))].ravel()
        angle = smoothed(edge_turn(vertices, corners(times), rows, e1, across), times)

        def turn(t: np.ndarray) -> np.ndarray:
            return evaluate_smoothed(angle, t) - evaluate_smoothed(angle, np.zeros(1))
    turns = None if turn is None else turn(step_times)[:, None] * e1[None]
    path = HandlePath(tuple(step_times), corners(step_times) - reference, turns=turns)
    basis, path_start = None, None
    if config.corners == "fitted":  # q₀: the B-spline's least-squares fit to the smoothing
        basis = spline_basis(step_times, 2, config.corner_spans or frames - 1)
        path_start = np.linalg.lstsq(basis.reshape(-1, basis.shape[-1]),
                                     path.displacements.reshape(-1), rcond=None)[0]
    plan = SplinePlan(swing_spline(model, config.spans, config.degree, config.knots))
    dynamics = DynamicsConfig(dt=dt, duration=steps * dt, integrator=config.integrator,
                              mass_damping=config.mass_damping)
    newton = newton or NewtonConfig()

    def stepper_at(bending: float, q: np.ndarray | None = None) -> PathStepper:
        with_b = model.with_material(material.with_stiffness(bending_stiffness=bending))
        moved = path if q is None else HandlePath(path.times, basis @ q, basis, path.turns)
        return PathStepper(with_b, plan, dynamics, moved, newton=newton)

    stepper = stepper_at(1e-5)
    pick = grid.index[::config.stride, ::config.stride].ravel()
    xi = torch.from_numpy(grid.xi[pick]).double()
    flat = model.surface.jets(xi)[:, jets.VALUE].double().numpy()
    position0 = evaluate_smoothed(smooth, np.array(0.0))[pick]
    velocity0 = evaluate_smoothed(smooth, np.array(0.0), nu=1)[pick]
    g0 = stepper.boundary_at(xi, 0.0, torch.float64)[:, jets.VALUE].numpy()
    gv = stepper.boundary_velocity(xi, torch.float64)[:, jets.VALUE].numpy()
    c0 = _fit_free(stepper, xi, torch.from_numpy(position0 - flat - g0))
    v0 = _fit_free(stepper, xi, torch.from_numpy(velocity0 - gv))

    def start(stepper: PathStepper) -> Start:
        if config.start == "data":
            return Start(c0, v0)
        return rest_start(stepper, c0, "bending_stiffness")

    speed = float(np.sqrt(np.mean(np.sum(velocity0 ** 2, axis=1))))
    observed = torch.from_numpy(vertices[1:, pick] - flat[None])
    data = TrajectoryData(xi, tuple(config.substeps * f for f in range(1, frames)), observed)
    return SwingProblem(stepper_at, start, data, grid, model, path, frame_interval, xi, flat,
                        vertices[0][pick], speed, path_start)


def resolving_spans(size: tuple[float, float], length: float, ratio: float = SPAN_RATIO,
                    limit: int = 32) -> tuple[int, int]:
    """The spans (n1, n2) of a sheet (W, H) [m] whose spans are at most ratio × `length` [m]
    (the bending length c: the held sheet buckles at c's scale, so the grid scales with c
    whatever the sheet or the frame rate — a first guess that `fit_swing`'s check confirms,
    since the motion's folds may need finer), each at most `limit`."""
    if not (math.isfinite(length) and length > 0):
        return (limit, limit)
    return tuple(min(limit, max(1, math.ceil(side / (ratio * length) - 1e-9)))
                 for side in size)


@dataclass
class SwingFit:
    """`fit_swing`'s answer: the last fit's problem and fit; levels: per grid, in order,
    (spans, θ̂, s.e., iterations, "fit" or "check"); resolved: the last fit converged (not
    stopped at its cap), its grid resolves the estimate's bending length and, with
    `grid_check`, one Gauss–Newton step on the next finer grid moved θ̂ by at most its s.e.
    (False where that needed more than max_spans);
    grid_change: that last check's |Δθ| / s.e. (None: not checked)."""

    problem: SwingProblem
    fit: TrajectoryFit
    levels: list[tuple[tuple[int, int], float, float, int, str]]
    resolved: bool
    grid_change: float | None = None


def fit_swing(vertices: np.ndarray, faces: np.ndarray, held: tuple[int, int],
              frame_interval: float, gravity: np.ndarray, config: SwingConfig, start: float,
              fit_config: TrajectoryFitConfig | None = None, *,
              newton: NewtonConfig | None = None,
              corners: Callable[[np.ndarray], np.ndarray] | None = None,
              turn: Callable[[np.ndarray], np.ndarray] | None = None) -> SwingFit:
    """B [N·m] fitted to the sequence (`swing_problem`'s arguments) by `fit_trajectory` from
    `start` [N·m]. With config.spans None the grid follows the estimate: the first fit on
    `resolving_spans` of the start's bending length, then, while the estimate's bending length
    needs finer spans than the last grid's, a refit on those, warm-started at the last
    estimate (each level's grid never coarser than the one before); with `grid_check`, then
    one Gauss–Newton step from θ̂ on spans × GROWTH: where it moves θ̂ by more than its s.e.
    the grid does not yet hold the answer, and the fit goes on there (warm-started at the
    step's value). Fitted corners: every refit and the check start from the last fit's
    corner paths q̂ (the check's step then measures the grid, not the corners' start).
    Given spans: one fit."""
    size = config.size or SheetGrid.from_template(np.asarray(vertices[0], dtype=np.float64),
                                                  faces, held).size
    g = float(np.linalg.norm(gravity))
    fit_config = fit_config or TrajectoryFitConfig()

    def needed(value: float, limit: int | None = config.max_spans) -> tuple[int, int]:
        c = bending_length(value, config.areal_density, g)
        return resolving_spans(size, c, config.span_ratio, limit or 10**9)

    def run(spans: tuple[int, int], theta: float, fit_with: TrajectoryFitConfig,
            path: np.ndarray | None):
        problem = swing_problem(vertices, faces, held, frame_interval, gravity,
                                dataclasses.replace(config, spans=spans), newton=newton,
                                corners=corners, turn=turn)
        path = problem.path_start if path is None or problem.path_start is None else path
        return problem, fit_trajectory(problem.stepper_at, problem.data, theta, fit_with,
                                       initial=problem.start, path_start=path)

    spans, theta, levels, path = config.spans or needed(start), float(start), [], None
    while True:
        problem, fit = run(spans, theta, fit_config, path)
        path = fit.path_values
        levels.append((spans, fit.value, fit.standard_error, fit.iterations, "fit"))
        log.info("swing fit on %s spans: B = %.4e ± %.2e N·m, %d iterations", spans,
                 fit.value, fit.standard_error, fit.iterations)
        if config.spans is not None:
            return SwingFit(problem, fit, levels, fit.converged)
        finer = tuple(max(a, b) for a, b in zip(needed(fit.value), spans, strict=True))
        if finer != spans:
            spans, theta = finer, fit.value
            continue
        resolved = all(a <= b for a, b in zip(needed(fit.value, None), spans, strict=True))
        check = tuple(min(config.max_spans, math.ceil(GROWTH * s)) for s in spans)
        if not config.grid_check or not resolved or check == spans:
            return SwingFit(problem, fit, levels,
                            resolved and fit.converged and not config.grid_check)
        _, step = run(check, fit.value, dataclasses.replace(fit_config, max_iterations=1),
                      path)
        change = abs(step.value - fit.value) / fit.standard_error
        levels.append((check, step.value, step.standard_error, 1, "check"))
        log.info("swing fit: one step on %s spans moves B by %.2f s.e.", check, change)
        if change <= 1.0:
            return SwingFit(problem, fit, levels, fit.converged, change)
        spans, theta, path = check, step.value, step.path_values
