"""Bending stiffness from a sheet's swing (issue 27 item 3, `inverse.sft.swing`): a synthetic
check with a known material, then φ-SfT's R1.

Synthetic (`--part synthetic`): a W × H = 0.55 × 0.55 m sheet (ρ_A 0.197 kg/m², D 300 N/m, ν
0.25, B from `--bending-length` c: B = ρ_A g c³) hanging in the camera's x-y plane 1 m in
front of it (gravity (0, 9.81, 0), OpenCV axes), held at its top corners by handles that move
from rest over `--duration` s: corner a by (1, 0, −4) cm × s(t), corner b by (−1, 1, 3) cm ×
s(t), s(t) = ½ (1 − cos(2π t / duration)) (each corner out and back, opposite in depth: a
swing and a twist); each corner held at its point, or with `--grip` r over a patch of radius r
(truth and fit); with `--turn-degrees` θ the held edge also turns about its corner line, from
rest to θ over `--duration` (`true_turn`; the fit's turn `--turn`: none, read off the rows in
the handles' band, or the truth's). The truth is the project's dynamics (`PathStepper`,
Newmark, `--truth-spans`, `--truth-substeps` steps per frame, splines of `--truth-degree`)
from its rest state: the static equilibrium of the held sheet (`dynamics_adjoint.rest_start`,
Newton from 40 damped implicit-Euler steps of 0.05 s at α = 30 /s from the flat sheet: the
planar hanging state is a saddle — held at two points the sheet buckles out of its plane — so
the rest state is bent and depends on B); observed: a 17 × 17 vertex grid at `--fps` frames
per second, plus Gaussian noise σ = `--noise` [m] per coordinate and seed. The fit
(`swing_problem` + `fit_trajectory`): corners from the noisy corner vertices (smoothed; with
`--corners fitted` unknowns of the fit, a B-spline of `--corner-spans` spans), start from the
smoothed frame 0, B alone (D, ν, ρ_A stated at the truth), on `--spans` (0: the grid follows
the estimate's bending length, `inverse.sft.swing.fit_swing`, `--span-ratio`, `--max-spans`)
with `--substeps`, from `--start` × B_true, Gauss–Newton stopped at a step below 1e-4 B or
`--error-tolerance` × the s.e.; one line per iteration. The truth's buckle goes to −z (towards
the camera) on every grid (the rest problem is mirror-symmetric). `--bias` (with `--spans`):
instead of the fits, the fit grid's linearised bias against the truth — one Gauss–Newton step
from B_true on the clean truth with the truth's corner paths, B alone: what a fit on that grid
finds without noise, to first order — with its s.e. at `--noise` and its parts per frame and
per row of observed points (where the grid's error meets ∂r/∂B).

R1 (`--part r1 --run DIR`): DIR/meshes/*.obj (the default `ndf-sft --capture` run), held
vertices 0 and 992, gravity (0, 9.81, 0) or, with `--r1-gravity` PITCH ROLL [deg], image-down
made ⊥ frame 0's corner line and turned by them (`gravity_direction.tilted_gravity`; R1's
vertical is not stated), ρ_A 0.197 kg/m², D 300 N/m (stated), at each `--r1-fps`; per row
B ± s.e., c, χ²/dof (σ estimated: 1 by construction), the rms misfit per
frame against the reconstruction's rms distance to the Kinect cloud.

R1 jointly (`--part r1 --r1-joint P R S C`, `inverse.sft.swing_capture`): gravity's pitch and
roll [deg], the time scale s and the bending length c [m] fitted together from that start on
the first `--r1-spans` grid (given, ≥ 1) at the first `--r1-fps`, data or rest start
(`--start-state`); a table of each unknown with its s.e. (residuals as independent, and robust
over blocks of ⌈L⌉ frames, L the residual's correlation length over frames), the misfit rms;
then the profile of c (`--r1-profile` lengths [m]: the misfit re-fitted over p, r, s at each
fixed c, at most `--profile-evaluations` residual evaluations each) and the one-sided 95 %
upper bound on c with n_eff = (F − 1) / L, placed among the measured fabrics (Feng et al.
2022's 5th–95th percentile 1.1–3.3 cm). With `--joint-synthetic P R S C` the sequence is
first replaced by the model's own swing at that point (R1's corners and start), plus Gaussian
noise `--noise` [m] (seed 0): a synthetic check with a known answer under R1's conditions.

    OMP_NUM_THREADS=1 python benchmarks/sft_swing.py --part synthetic --seeds 0 1 2
    OMP_NUM_THREADS=1 python benchmarks/sft_swing.py --part synthetic --bias --spans 28 \
        --truth-spans 32 --truth-substeps 2 --truth-integrator implicit_euler --substeps 2 \
        --duration 1.0 --truth-cache /tmp/truth_32.npz
    OMP_NUM_THREADS=1 python benchmarks/sft_swing.py --part r1 --run /tmp/r1 --data DATA
    OMP_NUM_THREADS=1 python benchmarks/sft_swing.py --part r1 --run /tmp/r1 --r1-spans 8 \
        --substeps 2 --start-state data --r1-joint 9 0 0.3 0.02
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import math
import os
import resource
import sys
import time
from pathlib import Path

import numpy as np
import torch

import taichi_ndf
from inverse.material.trajectory_fit import TrajectoryFitConfig, fit_trajectory, observe
from inverse.sft.gravity_direction import tilted_gravity
from inverse.sft.hanging import hanging_across, hanging_model
from inverse.sft.swing import SPAN_RATIO, SwingConfig, fit_swing, swing_problem
from inverse.sft.swing_capture import (
    CaptureFitConfig,
    CaptureProblem,
    SwingCapture,
    fit_capture,
    likelihood_ratio,
    model_sequence,
    profile_lengths,
    upper_bound,
)
from inverse.sft.swing_knots import KNOTS, swing_spline
from taichi_ndf import jets, progress
from taichi_ndf.problem.dynamics import DynamicsConfig
from taichi_ndf.problem.spline_grid import SplinePlan
from taichi_ndf.shell.fabrics import FENG_2022_PERCENTILES, bending_length
from taichi_ndf.shell.materials import LinearIsotropic
from taichi_ndf.solve.dynamics_adjoint import record, rest_start
from taichi_ndf.solve.handle_paths import (
    HandlePath,
    PathStepper,
    boundary_displacement,
    moved_boundary,
)

sys.path.insert(0, str(Path(__file__).resolve().parent))
from provenance import commit  # noqa: E402

G = 9.81
RHO, D, NU, SIZE = 0.197, 300.0, 0.25, 0.55
MOVES = np.array([[0.01, 0.0, -0.04], [-0.01, 0.01, 0.03]])  # [m] per corner at s = 1


def cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def grid_mesh(n: int) -> tuple[np.ndarray, np.ndarray]:
    """ξ (n², 2) of an n × n vertex grid on the sheet (vertex j n + i at (i, j) / (n − 1) × W,
    row 0 the held edge) and its triangles."""
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="xy")
    xi = np.stack([i.ravel(), j.ravel()], axis=1) / (n - 1) * SIZE
    faces = []
    for r in range(n - 1):
        for c in range(n - 1):
            a = r * n + c
            faces += [[a, a + 1, a + n + 1], [a, a + n + 1, a + n]]
    return xi, np.array(faces)


CORNERS = np.array([[-SIZE / 2, -0.3, 1.0], [SIZE / 2, -0.3, 1.0]])  # [m] at rest


def true_turn(t: np.ndarray, args) -> np.ndarray:
    """The truth's turn of the held edge about its corner line (T,) [rad] at times t (T,) [s]:
    from rest to `--turn-degrees` over `--duration`, ½ (1 − cos(π t / duration))."""
    ramp = 0.5 * (1 - np.cos(np.pi * np.asarray(t, dtype=np.float64) / args.duration))
    return np.radians(args.turn_degrees) * ramp


def true_corners(t: np.ndarray, duration: float) -> np.ndarray:
    """The truth's held corner positions (T, 2, 3) [m] at times t (T,) [s]."""
    s = 0.5 * (1 - np.cos(2 * np.pi * np.asarray(t) / duration))
    return CORNERS[None] + s[:, None, None] * MOVES[None]


def synthetic(bending: float, args) -> tuple[np.ndarray, np.ndarray, tuple[int, int]]:
    """The truth's vertex positions (F, n², 3) at the frames, faces, held vertices."""
    corners = CORNERS
    gravity = np.array([0.0, G, 0.0])
    material = LinearIsotropic(D, bending, NU, RHO)
    model = hanging_model((SIZE, SIZE), material, corners, hanging_across(corners, gravity),
                          gravity, grip=args.grip)
    model = dataclasses.replace(model, boundary=moved_boundary(model.boundary,
                                                               np.zeros((2, 3))))
    plan = SplinePlan(swing_spline(model, (args.truth_spans,) * 2, args.truth_degree,
                                   args.truth_knots))
    still = HandlePath((0.0, 1.0), np.zeros((2, 2, 3)))
    settle = PathStepper(model, plan, DynamicsConfig(dt=0.05, duration=2.0,
                                                     integrator="implicit_euler",
                                                     mass_damping=30.0), still)
    settled = record(settle)[-1].displacement
    # the rest problem is symmetric about the corners' plane: which way the sheet buckles is
    # round-off's choice (24² spans went +z, 12²–20² −z); the truth takes −z (to the camera) on
    # every grid: the mirror image (z coefficients negated) is an equilibrium as well. Checked
    # on the equilibrium itself (Newton from the settled state may cross to the other side:
    # the 12² grip did)
    rest = rest_start(settle, settled, "bending_stiffness").displacement  # in equilibrium
    middle = torch.tensor([[SIZE / 2, 0.0]], dtype=torch.float64)
    if float(observe(settle, middle, rest)[0, 2]) > 0:
        rest = rest * torch.tensor([1.0, 1.0, -1.0], dtype=rest.dtype)
    frames = int(round(args.duration * args.fps)) + 1
    dt = 1.0 / args.fps / args.truth_substeps
    steps = (frames - 1) * args.truth_substeps
    times = dt * np.arange(steps + 1)
    s = 0.5 * (1 - np.cos(2 * np.pi * times / args.duration))
    axis = (CORNERS[1] - CORNERS[0]) / np.linalg.norm(CORNERS[1] - CORNERS[0])
    path = HandlePath(tuple(times), s[:, None, None] * MOVES[None],
                      turns=true_turn(times, args)[:, None] * axis[None])
    truth = PathStepper(model, plan, DynamicsConfig(dt=dt, duration=steps * dt,
                                                    integrator=args.truth_integrator), path)
    states = record(truth, rest)
    xi_np, faces = grid_mesh(17)
    xi = torch.from_numpy(xi_np)
    flat = model.surface.jets(xi)[:, jets.VALUE].double().numpy()
    positions = np.stack([flat + observe(truth, xi, states[k].displacement,
                                         states[k].time).numpy()
                          for k in range(0, steps + 1, args.truth_substeps)])
    return positions, faces, (0, 16)


def gauss_newton_trace(report) -> None:
    """One line per Gauss–Newton iteration of the trajectory fit: B, the relative step, CPU."""
    if report.stage.startswith("trajectory fit") and not report.done and report.step > 0:
        values = report.values
        print(f"    iteration {report.step}: B → {values.get('bending_stiffness', 0):.5e}, "
              f"|ΔB|/B {values.get('relative_step', 0):.1e}, process CPU {cpu():.0f} s",
              flush=True)


def fit(vertices, faces, held, fps, config, start, gravity=(0.0, G, 0.0), corners=None,
        error_tolerance=None, turn=None):
    with progress.listening(gauss_newton_trace):
        swing = fit_swing(vertices, faces, held, 1.0 / fps, np.array(gravity), config, start,
                          TrajectoryFitConfig(max_iterations=10, tolerance=1e-4,
                                              error_tolerance=error_tolerance),
                          corners=corners, turn=turn)
    levels = "; ".join(f"{kind} {s[0]}×{s[1]}: {b:.4e} ± {e:.1e} ({i} it)"
                       for s, b, e, i, kind in swing.levels)
    print(f"  grid levels: {levels}; resolved {swing.resolved}, last check's |ΔB|/s.e. "
          f"{swing.grid_change}", flush=True)
    return swing.problem, swing.fit


@dataclasses.dataclass(frozen=True)
class LinearisedBias:
    """One Gauss–Newton step from the true B on clean data (`linearised_bias`): residuals r
    [m] and sensitivity s = dr/dB [m/(N·m)] at B_true, each (F − 1, P, 3) over the observed
    frames and points, and the points' ξ (P, 2) [m]."""

    residuals: np.ndarray
    sensitivity: np.ndarray
    xi: np.ndarray

    @property
    def h(self) -> float:
        """Σ s² [m²/(N·m)²]: the s.e. at noise σ per coordinate is σ/√h."""
        return float(np.sum(self.sensitivity ** 2))

    @property
    def parts(self) -> np.ndarray:
        """−(r·s)/h per frame and point (F − 1, P) [N·m]: the step's parts."""
        return -np.sum(self.residuals * self.sensitivity, axis=-1) / self.h

    @property
    def bias(self) -> float:
        """The step ΔB = −Σ r s / Σ s² [N·m]: the bias of a fit on this grid, to first order."""
        return float(self.parts.sum())

    @property
    def misfit(self) -> float:
        """rms 3-D distance [m] of the model at B_true from the truth."""
        return float(np.sqrt(np.mean(np.sum(self.residuals ** 2, axis=-1))))

    def standard_error(self, noise: float) -> float:
        """The s.e. [N·m] of B at noise σ [m] per coordinate."""
        return noise / np.sqrt(self.h)


def linearised_bias(clean, faces, held, fps, config, b_true, corners,
                    turn=None) -> LinearisedBias:
    """The fit's own bias on `config`'s grid against a truth (F, V, 3) [m] at `fps`: the
    swing model with the truth's corner paths corners(t) (T, 2, 3) [m] (and its turn(t) (T,)
    [rad] where given, else config.turn's) and B alone, one Gauss–Newton step from b_true
    [N·m] on the clean frames (what a fit there would find, to first order, with no noise)."""
    problem = swing_problem(clean, faces, held, 1.0 / fps, np.array([0.0, G, 0.0]), config,
                            corners=corners, turn=turn)
    r = fit_trajectory(problem.stepper_at, problem.data, b_true,
                       TrajectoryFitConfig(max_iterations=1), initial=problem.start)
    shape = (len(problem.data.steps), len(problem.xi), 3)
    return LinearisedBias(r.residuals.reshape(shape), r.sensitivity.reshape(shape),
                          problem.xi.numpy())


def print_bias(found: LinearisedBias, b_true: float, noise: float) -> None:
    """The bias in % of B_true with its s.e. at `noise`, and where it comes from: per frame
    and per row of observed points (ξ², row 0 the held edge)."""
    rows = np.unique(found.xi[:, 1])
    by_row = [found.parts[:, found.xi[:, 1] == y].sum() for y in rows]
    print(f"linearised bias: {100 * found.bias / b_true:+.2f} % of B "
          f"(s.e. at σ = {1000 * noise:.1f} mm: "
          f"{100 * found.standard_error(noise) / b_true:.2f} %), rms misfit at B_true "
          f"{1000 * found.misfit:.2f} mm")
    print("  per frame [% of B]: " + ", ".join(
        f"{100 * v / b_true:+.1f}" for v in found.parts.sum(1)))
    print("  per row of observed points from the held edge [% of B]: " + ", ".join(
        f"{100 * v / b_true:+.1f}" for v in by_row), flush=True)


def part_synthetic(args) -> None:
    b_true = RHO * G * args.bending_length ** 3
    c0 = cpu()
    if args.truth_cache is not None and args.truth_cache.exists():  # the same truth, solved once
        cached = np.load(args.truth_cache)
        clean, faces, held = cached["clean"], cached["faces"], tuple(cached["held"])
        print(f"truth read from {args.truth_cache} (its settings: {cached['settings']})")
    else:
        clean, faces, held = synthetic(b_true, args)
        if args.truth_cache is not None:
            settings = str({k: getattr(args, k) for k in (
                "bending_length", "duration", "fps", "truth_spans", "truth_substeps",
                "truth_integrator", "grip", "truth_degree", "turn_degrees", "truth_knots")})
            np.savez(args.truth_cache, clean=clean, faces=faces, held=np.array(held),
                     settings=settings)
    print(f"truth: {len(clean)} frames at {args.fps} fps, B = {b_true:.4e} N·m "
          f"(c = {100 * args.bending_length:.2f} cm), {args.truth_spans}² spans, "
          f"{args.truth_substeps} {args.truth_integrator} steps per frame: "
          f"{cpu() - c0:.0f} s CPU; the held edge turning by {args.turn_degrees}° about its "
          f"corner line; corner "
          f"moves {MOVES.tolist()} m; sheet rms displacement from frame 0 at the last frame "
          f"{1000 * np.sqrt(np.mean(np.sum((clean[-1] - clean[0]) ** 2, 1))):.1f} mm; frame 0 "
          f"out of the corners' plane by up to {1000 * np.abs(clean[0, :, 2] - 1.0).max():.1f}"
          f" mm")
    config = SwingConfig(spans=(args.spans,) * 2 if args.spans else None,
                         span_ratio=args.span_ratio, max_spans=args.max_spans,
                         grid_check=not args.no_grid_check, substeps=args.substeps,
                         integrator=args.integrator, membrane_stiffness=D, poisson_ratio=NU,
                         areal_density=RHO, size=(SIZE, SIZE), start=args.start_state,
                         grip=args.grip, degree=args.degree, knots=args.knots,
                         corners=args.corners, corner_spans=args.corner_spans or None,
                         turn="read" if args.turn == "read" else "none")
    turn = (lambda t: true_turn(t, args)) if args.turn == "true" else None
    if args.bias:
        c0, t0 = cpu(), time.perf_counter()
        found = linearised_bias(clean, faces, held, args.fps, config, b_true,
                                lambda t: true_corners(t, args.duration), turn)
        print(f"the fit's grid {args.spans}² against the truth's {args.truth_spans}², true "
              f"corners, turn {args.turn}, clean data, one Gauss–Newton step from B_true: "
              f"{cpu() - c0:.0f} s CPU, {time.perf_counter() - t0:.0f} s wall")
        print_bias(found, b_true, args.noise)
        return
    corners = ((lambda t: true_corners(t, args.duration)) if args.true_corners else None)
    print(f"start: {args.start_state}; turn: {args.turn}; corners: "
          f"{'true' if args.true_corners else args.corners} "
          f"(spans {args.corner_spans or 'per frame'})")
    print("| seed | σ [mm] | B ± s.e. [N·m] | B error | z | c [cm] | χ²/dof | rms misfit [mm] "
          "| start fit [mm] | start speed [mm/s] | iterations | converged "
          "| adjoint–tangent gap | B's correlation with the corners | corners' rms error [mm] "
          "| CPU s | wall s |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for seed in args.seeds:  # seed −1: the clean sequence (the model's and grid's own bias)
        rng = np.random.default_rng(max(seed, 0))
        noise = args.noise if seed >= 0 else 0.0
        noisy = clean + rng.normal(0.0, 1.0, clean.shape) * noise
        c0, t0 = cpu(), time.perf_counter()
        problem, r = fit(noisy, faces, held, args.fps, config, args.start * b_true,
                         corners=corners, error_tolerance=args.error_tolerance, turn=turn)
        err = r.value / b_true - 1
        misfit = 1000 * np.sqrt(np.mean(r.residuals ** 2) * 3)
        print(f"| {seed if seed >= 0 else 'none'} | {1000 * noise:.1f} | "
              f"{r.value:.4e} ± {r.standard_error:.2e} | "
              f"{100 * err:+.2f} % | {abs(r.value - b_true) / r.standard_error:.2f} | "
              f"{100 * bending_length(r.value, RHO, G):.3f} | "
              f"{r.goodness.reduced:.2f} | {misfit:.2f} | "
              f"{1000 * problem.start_misfit(r.value):.2f} | "
              f"{1000 * problem.start_velocity:.1f} | {r.iterations} | {r.converged} | "
              f"{r.gradient_gap:.1e} | {_value(r.correlation, '.3f')} | "
              f"{1000 * corner_error(problem, r, args.duration):.2f} | {cpu() - c0:.0f} | "
              f"{time.perf_counter() - t0:.0f} |", flush=True)


def _value(value, form: str) -> str:
    return "—" if value is None else format(value, form)


def corner_error(problem, r, duration: float) -> float:
    """rms over the frames and both corners of the model's held corners (the fit's paths) from
    the truth's [m]."""
    stepper = (problem.stepper_at(r.value) if r.path_values is None
               else problem.stepper_at(r.value, r.path_values))
    xi = torch.tensor([[0.0, 0.0], [SIZE, 0.0]], dtype=torch.float64)
    flat = problem.model.surface.jets(xi)[:, jets.VALUE].double().numpy()
    times = problem.frame_interval * np.arange(len(problem.data.steps) + 1)
    fitted = np.stack([flat + boundary_displacement(stepper, xi, t).numpy() for t in times])
    return float(np.sqrt(np.mean(np.sum((fitted - true_corners(times, duration)) ** 2, -1))))


def part_r1(args) -> None:
    from taichi_ndf.io import read_mesh

    files = sorted((args.run / "meshes").glob("*.obj"))
    vertices = np.stack([np.asarray(read_mesh(f).vertices, dtype=np.float64) for f in files])
    faces = np.asarray(read_mesh(files[0]).faces)
    clouds = None
    if args.data is not None:
        from scipy.spatial import cKDTree
        clouds = [np.load(args.data / "ground_truth" / f"point_cloud_{f:03d}.npy")
                  for f in range(len(vertices))]
        errors = [float(np.sqrt(np.mean(cKDTree(c.reshape(-1, 3)).query(v)[0] ** 2)))
                  for c, v in zip(clouds, vertices, strict=True)]
    frames = vertices[: args.r1_frames] if args.r1_frames else vertices
    if args.r1_joint is not None:
        part_r1_joint(args, frames, faces)
        return
    gravity = (np.array([0.0, G, 0.0]) if args.r1_gravity is None else
               tilted_gravity(vertices[0, [0, 992]], *args.r1_gravity, magnitude=G))
    print(f"R1: {len(frames)} of {len(vertices)} frames of {vertices.shape[1]} vertices, "
          f"held 0 and 992, gravity {np.round(gravity, 4)} m/s² (pitch, roll "
          f"{args.r1_gravity} deg), ρ_A {RHO} kg/m², D {D} N/m stated")
    for fps in args.r1_fps:
        for spans in args.r1_spans:
            config = SwingConfig(spans=(spans, spans) if spans else None,
                                 span_ratio=args.span_ratio, max_spans=args.max_spans,
                         grid_check=not args.no_grid_check, substeps=args.substeps,
                                 integrator=args.integrator, membrane_stiffness=D,
                                 poisson_ratio=NU, areal_density=RHO, stride=args.stride,
                                 start=args.start_state,
                                 turn="read" if args.turn == "read" else "none")
            c0, t0 = cpu(), time.perf_counter()
            try:
                problem, r = fit(frames, faces, (0, 992), fps, config,
                                 RHO * G * args.r1_start ** 3, gravity=gravity,
                                 error_tolerance=args.error_tolerance)
            except Exception as err:  # noqa: BLE001  (a row that failed says why)
                print(f"| {fps} | {spans}² | failed: {type(err).__name__}: {err} | "
                      f"{cpu() - c0:.0f} s CPU |", flush=True)
                continue
            per_frame = np.sqrt(np.mean(r.residuals.reshape(len(problem.data.steps), -1) ** 2,
                                        axis=1) * 3)
            # cluster-robust s.e. (one cluster per frame): a reconstruction's errors are
            # smooth over the sheet, so the residuals of a frame are not independent
            scores = (r.residuals * r.sensitivity).reshape(len(problem.data.steps), -1).sum(1)
            robust = float(np.sqrt(np.sum(scores ** 2)) / np.sum(r.sensitivity ** 2))
            if args.save:
                np.savez(args.save / f"r1_fps{fps:g}_spans{spans}.npz", value=r.value,
                         residuals=r.residuals, sensitivity=r.sensitivity,
                         steps=np.array(problem.data.steps), se=r.standard_error)
            print(f"fps {fps}, spans {spans or 'auto'}: B = {r.value:.4e} ± "
                  f"{r.standard_error:.2e} N·m "
                  f"(σ̂/√H, rel {r.standard_error / r.value:.3f}; cluster-robust per frame "
                  f"{robust:.2e}, rel {robust / r.value:.3f}), χ²/dof "
                  f"{r.goodness.reduced:.2f} (σ̂ {1000 * r.noise:.2f} mm), c = "
                  f"{100 * bending_length(r.value, RHO, G):.3f} cm, iterations {r.iterations}"
                  f" converged {r.converged}, start fit {1000 * problem.start_misfit(r.value):.2f}"
                  f" mm, data's speed at t = 0 {1000 * problem.start_velocity:.1f} mm/s, "
                  f"rms misfit {1000 * np.sqrt(np.mean(r.residuals ** 2) * 3):.2f} mm; "
                  f"{cpu() - c0:.0f} s CPU, {time.perf_counter() - t0:.0f} s wall, load "
                  f"{os.getloadavg()[0]:.1f}", flush=True)
            rows = [f"{f}: {1000 * m:.1f}" + (f" ({1000 * errors[f]:.1f})" if clouds else "")
                    for f, m in zip(range(1, len(frames)), per_frame, strict=True)]
            print("  per-frame rms misfit [mm] (reconstruction's rms distance to the cloud): "
                  + ", ".join(rows[::3]), flush=True)


def print_capture(fit, truth=None) -> None:
    """One row per free unknown of a `CaptureFit`: value, s.e. (independent, blocks)."""
    print("| unknown | estimate | s.e. (residuals independent) | s.e. (blocks of ⌈L⌉ frames) "
          "| truth |")
    print("|---|---|---|---|---|")
    units = {"pitch": ("p [deg]", 1.0), "roll": ("r [deg]", 1.0), "time_scale": ("s", 1.0),
             "bending_length": ("c [cm]", 100.0)}
    for name in fit.free:
        value, se, robust = fit.value_error(name)
        label, k = units[name]
        known = "—" if truth is None else f"{k * getattr(truth, name):.4g}"
        print(f"| {label} | {k * value:.4g} | {k * se:.2g} | {k * robust:.2g} | {known} |")
    if "bending_length" in fit.free:
        print(f"| ln c | {math.log(fit.point.bending_length):.3f} | "
              f"{fit.errors['bending_length']:.2g} | {fit.robust['bending_length']:.2g} | "
              + ("—" if truth is None else f"{math.log(truth.bending_length):.3f}") + " |")
    print(f"misfit rms {1000 * fit.rms:.2f} mm over {fit.residuals.shape[0]} frames; residual "
          f"correlation length L = {fit.correlation_length:.1f} frames, n_eff = "
          f"{fit.effective_frames:.1f}; at a bound: {fit.at_bound or 'none'}; "
          f"{fit.evaluations} runs; stopped: {fit.message}", flush=True)


def part_r1_joint(args, vertices, faces) -> None:
    """`--r1-joint` (module docstring)."""
    logging.basicConfig(format="    %(message)s")
    logging.getLogger("inverse.sft.swing_capture").setLevel(logging.INFO)
    config = SwingConfig(spans=(args.r1_spans[0],) * 2, substeps=args.substeps,
                         integrator=args.integrator, membrane_stiffness=D, poisson_ratio=NU,
                         areal_density=RHO, stride=args.stride, start=args.start_state)
    start = SwingCapture(*args.r1_joint)
    truth = None
    problem = CaptureProblem(vertices, faces, (0, 992), 1.0 / args.r1_fps[0], config)
    if args.joint_synthetic is not None:
        c0, t0 = cpu(), time.perf_counter()
        truth = SwingCapture(*args.joint_synthetic)
        clean = model_sequence(problem, truth, G)
        noisy = clean + np.random.default_rng(0).normal(0.0, args.noise, clean.shape)
        problem = dataclasses.replace(problem, vertices=noisy)
        print(f"synthetic: the model's own swing at {truth} on R1's corners and start, noise "
              f"{1000 * args.noise:.1f} mm (seed 0); rms from R1's reconstruction "
              f"{1000 * np.sqrt(np.mean(np.sum((clean - vertices) ** 2, -1))):.1f} mm; "
              f"{cpu() - c0:.0f} s CPU, {time.perf_counter() - t0:.0f} s wall", flush=True)
    print(f"joint fit: {config.spans} spans, {config.substeps} steps per frame, start "
          f"{config.start}, stride {config.stride}, {1 / problem.frame_interval:g} fps stated, "
          f"from {start}")
    settings = CaptureFitConfig(max_evaluations=args.joint_evaluations, gravity=G)
    c0, t0 = cpu(), time.perf_counter()
    joint = fit_capture(problem, start, settings)
    print_capture(joint, truth)
    print(f"  {cpu() - c0:.0f} s CPU, {time.perf_counter() - t0:.0f} s wall, load "
          f"{os.getloadavg()[0]:.1f}", flush=True)
    if not args.r1_profile:
        return
    print("| c [cm] | p [deg] | r [deg] | s | rms misfit [mm] | − joint's [mm] "
          "| n_eff ln(SSE/SSE_joint) | runs | CPU s | wall s | load |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    fits, point = [], joint.point
    settings = dataclasses.replace(settings, max_evaluations=args.profile_evaluations)
    for length in sorted(args.r1_profile):
        c0, t0 = cpu(), time.perf_counter()
        (fit,) = profile_lengths(problem, point, [length], settings)
        fits.append(fit)
        point = fit.point
        print(f"| {100 * length:g} | {fit.point.pitch:.3f} | {fit.point.roll:.3f} | "
              f"{fit.point.time_scale:.4f} | {1000 * fit.rms:.3f} | "
              f"{1000 * (fit.rms - joint.rms):+.3f} | "
              f"{likelihood_ratio(fit.rms, min(joint.rms, fit.rms), joint.effective_frames):.3f} | "
              f"{fit.evaluations} | {cpu() - c0:.0f} | {time.perf_counter() - t0:.0f} | "
              f"{os.getloadavg()[0]:.1f} |", flush=True)
    lengths = [f.point.bending_length for f in fits]
    best = min([joint.rms] + [f.rms for f in fits])
    bound = upper_bound(lengths, [f.rms for f in fits], best, joint.effective_frames)
    low, _, high = FENG_2022_PERCENTILES["bending_length"]
    print(f"one-sided 95 % upper bound on c: n_eff ln(SSE(c)/SSE_min) ≥ 2.706 with n_eff = "
          f"(F − 1)/L = {joint.effective_frames:.2f} (L = {joint.correlation_length:.1f} "
          f"frames, each frame one unit), SSE_min at the best rms {1000 * best:.3f} mm: "
          + ("none within the profile (c up to "
             f"{100 * max(lengths):g} cm not excluded)" if bound is None else
             f"c < {100 * bound:.2f} cm")
          + f"; measured fabrics (Feng et al. 2022, 90 %): {100 * low:.1f}–{100 * high:.1f} cm",
          flush=True)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--part", choices=("synthetic", "r1"), required=True)
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    p.add_argument("--noise", type=float, default=0.002)
    p.add_argument("--bending-length", type=float, default=0.02)
    p.add_argument("--duration", type=float, default=1.5)
    p.add_argument("--fps", type=float, default=30.0)
    p.add_argument("--truth-spans", type=int, default=12)
    p.add_argument("--truth-substeps", type=int, default=4)
    p.add_argument("--truth-integrator", default="newmark")
    p.add_argument("--truth-degree", type=int, choices=(3, 4), default=3,
                   help="synthetic: the truth's spline degree")
    p.add_argument("--degree", type=int, choices=(3, 4), default=3,
                   help="synthetic: the fit's spline degree")
    p.add_argument("--knots", choices=KNOTS, default="uniform",
                   help="synthetic: the fit's knots, uniform or graded towards the held points")
    p.add_argument("--truth-knots", choices=KNOTS, default="uniform",
                   help="synthetic: the truth's knots, uniform or graded towards the held points")
    p.add_argument("--spans", type=int, default=0,
                   help="synthetic: the fit's spans per direction; 0: from the estimate's "
                        "bending length (SwingConfig.spans None, `fit_swing`)")
    p.add_argument("--max-spans", type=int, default=32,
                   help="the most spans per direction where the grid follows c")
    p.add_argument("--no-grid-check", action="store_true",
                   help="where the grid follows c: no check step on a finer grid")
    p.add_argument("--error-tolerance", type=float, default=0.1,
                   help="stop Gauss–Newton once a step is below this × the s.e. (0: off)")
    p.add_argument("--span-ratio", type=float, default=SPAN_RATIO,
                   help="the longest span in bending lengths where the grid follows c")
    p.add_argument("--substeps", type=int, default=1)
    p.add_argument("--integrator", default="implicit_euler")
    p.add_argument("--start", type=float, default=1.5)
    p.add_argument("--start-state", choices=("rest", "data"), default="rest",
                   help="the run's start: the static equilibrium at rest, or frame 0's fit")
    p.add_argument("--corners", choices=("smoothed", "fitted"), default="smoothed",
                   help="the held corners' paths: smoothed from the data, or unknowns of the fit")
    p.add_argument("--corner-spans", type=int, default=0,
                   help="the fitted corners' B-spline spans over the sequence (0: per frame)")
    p.add_argument("--true-corners", action="store_true",
                   help="synthetic: the held corners on their true paths, not the smoothed data")
    p.add_argument("--grip", type=float, default=0.0,
                   help="synthetic: each corner held over a patch of this radius [m] (truth "
                        "and fit; 0: at its point)")
    p.add_argument("--turn-degrees", type=float, default=0.0,
                   help="synthetic: the truth's held edge turns about its corner line by this "
                        "angle [deg] over --duration (true_turn; 0: no turn)")
    p.add_argument("--turn", choices=("none", "read", "true"), default="none",
                   help="the fit's turn of the held edge: none, read off the rows in the "
                        "handles' band (SwingConfig.turn), or the truth's (synthetic)")
    p.add_argument("--truth-cache", type=Path, default=None,
                   help="synthetic: an .npz to read the truth from (written when missing)")
    p.add_argument("--bias", action="store_true",
                   help="synthetic: instead of the fits, the fit grid's (--spans) linearised "
                        "bias: one Gauss–Newton step from B_true on the clean truth, true "
                        "corners, B alone, with its s.e. at --noise and its parts per frame "
                        "and row")
    p.add_argument("--run", type=Path, default=None)
    p.add_argument("--data", type=Path, default=None)
    p.add_argument("--r1-fps", type=float, nargs="+", default=[30.0])
    p.add_argument("--r1-spans", type=int, nargs="+", default=[0],
                   help="R1's spans per direction per row; 0: from the estimate's c")
    p.add_argument("--r1-frames", type=int, default=0)
    p.add_argument("--r1-start", type=float, default=0.02)
    p.add_argument("--r1-gravity", type=float, nargs=2, default=None,
                   metavar=("PITCH", "ROLL"),
                   help="R1: gravity turned from image-down by PITCH about frame 0's corner "
                        "line and ROLL towards corner b [deg] (tilted_gravity; default: "
                        "(0, 9.81, 0) as given)")
    p.add_argument("--r1-joint", type=float, nargs=4, default=None,
                   metavar=("PITCH", "ROLL", "SCALE", "LENGTH"),
                   help="R1: fit gravity's pitch and roll [deg], the time scale and the "
                        "bending length [m] together from these (inverse.sft.swing_capture)")
    p.add_argument("--joint-synthetic", type=float, nargs=4, default=None,
                   metavar=("PITCH", "ROLL", "SCALE", "LENGTH"),
                   help="with --r1-joint: fit the model's own swing at this point (R1's "
                        "corners and start) plus --noise instead of R1")
    p.add_argument("--joint-evaluations", type=int, default=10,
                   help="--r1-joint: the joint fit's residual evaluations at most")
    p.add_argument("--r1-profile", type=float, nargs="*",
                   default=[0.005, 0.01, 0.02, 0.04, 0.08],
                   help="--r1-joint: bending lengths [m] of the profile (none: no profile)")
    p.add_argument("--profile-evaluations", type=int, default=4,
                   help="--r1-joint: residual evaluations per profile point at most")
    p.add_argument("--stride", type=int, default=2)
    p.add_argument("--save", type=Path, default=None, help="folder for the R1 fits' npz")
    args = p.parse_args()
    if args.bias and (args.part != "synthetic" or args.spans < 1):
        print("sft_swing.py: --bias needs --part synthetic and the fit's grid --spans N >= 1",
              file=sys.stderr)
        sys.exit(2)
    if not math.isfinite(args.turn_degrees) or (args.turn == "true" and args.part != "synthetic"):
        print("sft_swing.py: --turn-degrees must be finite, and --turn true needs --part "
              "synthetic (a truth's turn)", file=sys.stderr)
        sys.exit(2)
    if args.r1_gravity is not None and not all(math.isfinite(a) and abs(a) < 90
                                               for a in args.r1_gravity):
        print("sft_swing.py: --r1-gravity PITCH ROLL must be finite angles in (-90, 90) "
              "degrees", file=sys.stderr)
        sys.exit(2)
    for name in ("r1_joint", "joint_synthetic"):
        point = getattr(args, name)
        try:
            if point is not None:
                SwingCapture(*point)
        except ValueError as err:
            print(f"sft_swing.py: --{name.replace('_', '-')}: {err}", file=sys.stderr)
            sys.exit(2)
    if args.r1_joint is not None and (args.part != "r1" or args.r1_spans[0] < 1
                                      or min(args.r1_profile, default=1.0) <= 0
                                      or args.joint_evaluations < 1
                                      or args.profile_evaluations < 1):
        print("sft_swing.py: --r1-joint needs --part r1, --r1-spans N >= 1, profile lengths "
              "> 0 [m] and evaluations >= 1", file=sys.stderr)
        sys.exit(2)
    if args.joint_synthetic is not None and args.r1_joint is None:
        print("sft_swing.py: --joint-synthetic needs --r1-joint", file=sys.stderr)
        sys.exit(2)
    args.error_tolerance = args.error_tolerance or None
    torch.set_num_threads(1)
    taichi_ndf.init(arch="cpu", precision="f64", seed=0)
    print(f"commit {commit()}; load average before {os.getloadavg()}; {vars(args)}")
    c0, t0 = cpu(), time.perf_counter()
    (part_synthetic if args.part == "synthetic" else part_r1)(args)
    print(f"whole part: {cpu() - c0:.0f} s CPU (user + sys), {time.perf_counter() - t0:.0f} s "
          f"wall; load average after {os.getloadavg()}")


if __name__ == "__main__":
    main()
