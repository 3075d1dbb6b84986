"""A bending-stiffness fit to a synthetic trajectory through the adjoint of the time steps
(issue 29, `taichi_ndf.solve.dynamics_adjoint`).

The strip: L = 4 m, b = 1 m, E = 1.2e6 Pa, h = 0.1 m, ν = 0.3, the material's
`bending_stiffness` B set to B_true = 100 N·m, ρ_A = 1 kg/m², clamped at x = 0,
released from rest in the reference state under gravity (−9.81 m/s² along z), Newmark (β = ¼,
γ = ½), h = `--dt` s, `--steps` steps, float64. The truth is run on `--truth-spans` spans,
the fit on `--spans` (a coarser grid than the data's unless equal). Observed: the
displacements of 3 points (ξ = (4, 0.5), (2, 0.5), (4, 0)) at 5 frames (every steps/5
steps), 45 values, plus Gaussian noise of σ = `--noise` × the RMS of the 45 values (one σ for
all). Fit: Gauss–Newton on B from `--start` × B_true, J = ½ Σ r²: the gradient Σ r dr/dB by the
adjoint (`gradient`), the Gauss–Newton Hessian H = Σ (dr/dB)² from the tangent (`tangent`),
ΔB = −∇J/H, until |ΔB| < 1e-8 B. s.e.(B) = σ/√H at the fit (the library's
`inverse.material.trajectory_fit.fit_trajectory`, σ stated). Per noise seed: B̂, its relative
error, s.e., |B̂ − B_true|/s.e., iterations, the largest relative gap between the adjoint's
gradient and the tangent's Σ r dr/dB at the start, CPU and wall seconds.

    OMP_NUM_THREADS=1 python benchmarks/dynamics_fit.py [--seeds 5] [--spans 12] [--truth-spans 24]
"""

from __future__ import annotations

import argparse
import copy
import os
import resource
import sys
import time
from pathlib import Path

import torch

import taichi_ndf
from inverse.material.trajectory_fit import TrajectoryData, fit_trajectory, observe
from taichi_ndf.problem.dynamics import DynamicsConfig
from taichi_ndf.scene.reader import parse_scene
from taichi_ndf.solve.dynamics import TimeStepper
from taichi_ndf.solve.dynamics_adjoint import record

sys.path.insert(0, str(Path(__file__).resolve().parent))
from provenance import commit  # noqa: E402  (the commit each benchmark states)

B_TRUE = 100.0
POINTS = torch.tensor([[4.0, 0.5], [2.0, 0.5], [4.0, 0.0]], dtype=torch.float64)


def document(spans: int) -> dict:
    return {
        "name": "strip",
        "geometry": {"type": "plane", "bounds": [[0.0, 4.0], [0.0, 1.0]]},
        "material": {"type": "linear", "young_modulus": 1.2e6, "poisson_ratio": 0.3,
                     "thickness": 0.1, "areal_density": 1.0},
        "boundary": {"length": 1.0,
                     "constraint": [{"type": "clamped_edge", "edge": "xi1_min"}]},
        "loads": {"gravity": [0.0, 0.0, -9.81]},
        "field": {"type": "spline", "spans": [spans, max(1, spans // 6)]},
        "training": {"load_steps": [1.0]},
    }


class Problem:
    """The stepper at a bending stiffness, and the observation of its states."""

    def __init__(self, spans: int, dt: float, steps: int):
        self.scene = parse_scene(copy.deepcopy(document(spans)), base_dir=Path("."))
        self.config = DynamicsConfig(dt=dt, duration=dt * steps, integrator="newmark")
        self.frames = [steps * (i + 1) // 5 for i in range(5)]

    def stepper(self, bending: float) -> TimeStepper:
        model = self.scene.model
        model = model.with_material(model.material.with_stiffness(bending_stiffness=bending))
        return TimeStepper(model, self.scene.field, self.config)

    def observe(self, stepper: TimeStepper, coefficients: torch.Tensor) -> torch.Tensor:
        """Displacements (3, 3) [m] of POINTS."""
        return observe(stepper, POINTS, coefficients)


def fit(problem: Problem, data: torch.Tensor, sigma: float, start: float
        ) -> tuple[float, float, int, float]:
    """B̂, s.e., Gauss–Newton iterations, relative adjoint/tangent gap of ∇J at the start
    (`inverse.material.trajectory_fit`)."""
    result = fit_trajectory(problem.stepper, TrajectoryData(POINTS, tuple(problem.frames),
                                                            data, sigma), start)
    return result.value, result.standard_error, result.iterations, result.gradient_gap


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--spans", type=int, default=12)
    parser.add_argument("--truth-spans", type=int, default=24)
    parser.add_argument("--dt", type=float, default=0.1)
    parser.add_argument("--steps", type=int, default=10)
    parser.add_argument("--noise", type=float, default=0.01)
    parser.add_argument("--start", type=float, default=1.5)
    args = parser.parse_args()
    if args.seeds < 1 or args.spans < 1 or args.truth_spans < 1 or args.steps < 5 \
            or not args.dt > 0 or not args.noise >= 0 or not args.start > 0:
        parser.exit(2, "dynamics_fit: seeds, spans, truth-spans >= 1, steps >= 5, dt > 0, "
                       "noise >= 0 and start > 0 required\n")
    taichi_ndf.init(arch="cpu", precision="f64", seed=0)
    print(f"commit {commit()}, load {os.getloadavg()[0]:.2f}, truth {args.truth_spans} spans, "
          f"fit {args.spans} spans, h = {args.dt} s, {args.steps} Newmark steps, noise "
          f"{args.noise:.0%} of the RMS, start {args.start} × B_true")
    truth = Problem(args.truth_spans, args.dt, args.steps)
    stepper = truth.stepper(B_TRUE)
    states = record(stepper)
    clean = torch.stack([truth.observe(stepper, states[k].displacement).detach()
                         for k in truth.frames])
    sigma = args.noise * float(clean.pow(2).mean().sqrt())
    print(f"observed: {clean.numel()} values, tip z at the frames "
          f"{[round(float(u), 5) for u in clean[:, 0, 2]]} m, σ = {sigma:.3e} m")
    problem = Problem(args.spans, args.dt, args.steps)
    print("| seed | B̂ [N·m] | error | s.e. [N·m] | |B̂−B|/s.e. | GN its | adjoint/tangent gap "
          "| CPU s | wall s |")
    print("|---|---|---|---|---|---|---|---|---|")
    for seed in range(args.seeds):
        generator = torch.Generator().manual_seed(seed)
        data = clean + sigma * torch.randn(clean.shape, generator=generator,
                                           dtype=torch.float64)
        usage, wall = resource.getrusage(resource.RUSAGE_SELF), time.perf_counter()
        b, se, iterations, gap = fit(problem, data, sigma, args.start * B_TRUE)
        after = resource.getrusage(resource.RUSAGE_SELF)
        cpu = after.ru_utime + after.ru_stime - usage.ru_utime - usage.ru_stime
        print(f"| {seed} | {b:.4f} | {b / B_TRUE - 1:+.3%} | {se:.4f} | "
              f"{abs(b - B_TRUE) / se:.2f} | {iterations} | {gap:.1e} | {cpu:.1f} | "
              f"{time.perf_counter() - wall:.1f} |", flush=True)


if __name__ == "__main__":
    main()
