"""Free vibration of a clamped cantilever plate strip by implicit time stepping (issue 29).

The strip: L = 10 m, b = 1 m, h = 0.1 m, E = 1.2e6 Pa, ν = 0, ρ_A = 1 kg/m² (Sze, Liu & Lo's
cantilever), clamped at x = 0, the other edges free, no load, no damping, float64, a cubic
spline field on `--spans` × 2 spans. With ν = 0 the y-independent beam modes are exact modes
of the Kirchhoff plate (the free long edges' moment B (w_,yy + ν w_,xx) and Kirchhoff shear
vanish for w = w(x)), so the bending frequencies are the Euler–Bernoulli cantilever's:
ω_n = (β_n L)² √(B / (ρ_A L⁴)), B = E h³/12 = 100 N·m, β₁L = 1.875104069, β₂L = 4.694091133
(R. D. Blevins, Formulas for Natural Frequency and Mode Shape, 1979, table 8-1; the shell has
no rotary inertia, as the beam). The motion starts in the reference state with the velocity
of mode n, ω_n A φ_n(x)/φ_n(L) along z (A = 0.01 m = L/1000 at the tip: small amplitude),
projected on the spline in the mass norm (`solve.dynamics.initial_velocity`).

Tables:
1. frequencies of modes 1 and 2 (Newmark, `--per-period` steps per period, `--periods`
   periods) from the tip's zero crossings (linear interpolation between steps; period = twice
   the mean spacing of the crossings) against the analytic value;
2. the period error of mode 1 at h = T/10, T/20, T/40, T/80 for both integrators, with the
   observed order log₂(e(h)/e(h/2)), beside the schemes' own error on one mode (`scheme_error`:
   Newmark's phase 2 atan(ωh/2) per step, implicit Euler's atan(ωh));
3. energy: the largest |E/E₀ − 1| of Newmark over 10 periods (E = ½VᵀMV + Π) at A = L/1000 and
   at A = L/10 (geometrically nonlinear), and implicit Euler's loss per period against its
   factor (1 + (ωh)²)^(−steps per period);
4. CPU per step (user + sys of this process, `time.process_time`) and per simulated second,
   with the Newton iterations per step;
5. Rayleigh damping (α = 0.01 1/s, β_R = 0.02 s) of modes 1 and 2: the energy left after 4
   periods against the damped oscillator's closed form with ζ_n = α/(2ω_n) + β_R ω_n/2.

    OMP_NUM_THREADS=1 python benchmarks/dynamics_plate.py [--spans 16] [--quick] [--damping-only]
"""

from __future__ import annotations

import argparse
import copy
import math
import os
import sys
import time
from pathlib import Path

import torch

import taichi_ndf
from taichi_ndf.problem.dynamics import DynamicsConfig
from taichi_ndf.scene.reader import parse_scene
from taichi_ndf.solve.dynamics import TimeStepper, initial_velocity

sys.path.insert(0, str(Path(__file__).resolve().parent))
from provenance import commit  # noqa: E402  (the commit each benchmark states)

L, B, RHO = 10.0, 100.0, 1.0
MODES = {1: (1.875104069, 0.734095514), 2: (4.694091133, 1.018467319)}  # β_n L, σ_n


def document(spans: int) -> dict:
    return {
        "name": "cantilever strip",
        "geometry": {"type": "plane", "bounds": [[0.0, L], [0.0, 1.0]]},
        "material": {"type": "linear", "young_modulus": 1.2e6, "poisson_ratio": 0.0,
                     "thickness": 0.1, "areal_density": RHO},
        "boundary": {"length": 2.0,
                     "constraint": [{"type": "clamped_edge", "edge": "xi1_min"}]},
        "field": {"type": "spline", "spans": [spans, 2]},
        "training": {"load_steps": [1.0]},
        "probes": [{"name": "tip", "xi": [L, 0.5]}],
    }


def omega(mode: int) -> float:
    """ω_n [rad/s] of the Euler–Bernoulli cantilever."""
    return MODES[mode][0] ** 2 * math.sqrt(B / (RHO * L**4))


def mode_velocity(mode: int, amplitude: float):
    """ω_n A φ_n(x)/φ_n(L) along z (N, 3) [m/s] at ξ (N, 2)."""
    beta_l, sigma = MODES[mode]

    def phi(x):
        return torch.cosh(x) - torch.cos(x) - sigma * (torch.sinh(x) - torch.sin(x))

    tip = float(phi(torch.tensor(beta_l, dtype=torch.float64)))

    def rate(xi):
        out = torch.zeros(len(xi), 3, dtype=xi.dtype)
        out[:, 2] = omega(mode) * amplitude * phi(xi[:, 0] * beta_l / L) / tip
        return out
    return rate


def run(spans: int, integrator: str, mode: int, per_period: int, periods: float,
        amplitude: float = 0.01, mass_damping: float = 0.0, stiffness_damping: float = 0.0):
    """The trajectory, its CPU seconds and wall seconds (the whole run: setup + steps)."""
    scene = parse_scene(copy.deepcopy(document(spans)), base_dir=Path("."))
    period = 2 * math.pi / omega(mode)
    dt = period / per_period
    config = DynamicsConfig(dt=dt, duration=dt * round(periods * per_period),
                            integrator=integrator, mass_damping=mass_damping,
                            stiffness_damping=stiffness_damping)
    cpu, wall = time.process_time(), time.perf_counter()
    stepper = TimeStepper(scene.model, scene.field, config)
    trajectory = stepper.run(velocity=initial_velocity(stepper, mode_velocity(mode, amplitude)))
    return trajectory, time.process_time() - cpu, time.perf_counter() - wall


def measured_period(trajectory) -> tuple[float, int]:
    """Twice the mean spacing [s] of the tip's zero crossings (linear interpolation; t = 0
    left out) and how many crossings."""
    w, t = [u[2] for u in trajectory.probes["tip"]], trajectory.times
    crossings = [t[i] - w[i] * (t[i + 1] - t[i]) / (w[i + 1] - w[i])
                 for i in range(1, len(w) - 1) if w[i] * w[i + 1] < 0]
    return 2 * (crossings[-1] - crossings[0]) / (len(crossings) - 1), len(crossings)


def scheme_error(integrator: str, per_period: int) -> float:
    """The period error T_h/T − 1 of the scheme on ẍ = −ω² x at h = T/per_period: its phase
    per step is 2 atan(ωh/2) (Newmark β = 1/4, γ = 1/2: +(ωh)²/12 + O(h⁴)) or atan(ωh)
    (implicit Euler: +(ωh)²/3 + O(h⁴)) instead of ωh."""
    wh = 2 * math.pi / per_period
    phase = 2 * math.atan(wh / 2) if integrator == "newmark" else math.atan(wh)
    return wh / phase - 1


def totals(trajectory) -> list[float]:
    return [trajectory.initial.total] + [r.total for r in trajectory.records]


def cost_row(label: str, trajectory, cpu: float, wall: float) -> str:
    records = trajectory.records
    steps = len(records)
    step_cpu = sum(r.cpu_seconds for r in records)
    return (f"| {label} | {steps} | {sum(r.newton_iterations for r in records) / steps:.2f} | "
            f"{1000 * step_cpu / steps:.1f} | {step_cpu / trajectory.times[-1]:.3g} | "
            f"{1000 * sum(r.wall_seconds for r in records) / steps:.1f} | {cpu:.1f} | "
            f"{wall:.1f} |")


def damped_energy(w: float, zeta: float, t: float) -> float:
    """(ẋ² + ω² x²)(t) of ẍ + 2ζω ẋ + ω² x = 0 from x = 0, ẋ = 1 (closed form)."""
    wd = w * math.sqrt(1 - zeta**2)
    decay = math.exp(-zeta * w * t)
    x = decay * math.sin(wd * t) / wd
    v = decay * (math.cos(wd * t) - zeta * w / wd * math.sin(wd * t))
    return v * v + w * w * x * x


def damping_table(spans: int, alpha: float, beta_r: float, periods: float) -> list[str]:
    """5. Rayleigh damping per mode: the energy left after `periods` periods against the
    damped oscillator's with ζ_n = α/(2ω_n) + β_R ω_n/2 (Newmark, T/100, A = L/10 000)."""
    print(f"\n5. Rayleigh damping (α = {alpha:g} 1/s, β_R = {beta_r:g} s; Newmark, T_n/100, "
          f"tip amplitude 1e-3 m, {periods:g} periods)\n")
    print("| mode | ζ_n = α/(2ω) + β_R ω/2 | E/E₀ measured | E/E₀ damped oscillator | "
          "relative difference | ζ from the measured decay |")
    print("|---|---|---|---|---|---|")
    costs = []
    for mode in (1, 2):
        w = omega(mode)
        zeta = alpha / (2 * w) + beta_r * w / 2
        trajectory, cpu, wall = run(spans, "newmark", mode, 100, periods, 1e-3, alpha, beta_r)
        t = trajectory.times[-1]
        measured = totals(trajectory)[-1] / totals(trajectory)[0]
        expected = damped_energy(w, zeta, t)
        # ζ whose closed form gives the measured ratio (bisection: the ratio falls with ζ)
        lo, hi = 0.0, 0.5
        for _ in range(100):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if damped_energy(w, mid, t) > measured else (lo, mid)
        print(f"| {mode} | {zeta:.5f} | {measured:.6f} | {expected:.6f} | "
              f"{measured / expected - 1:+.2e} | {0.5 * (lo + hi):.5f} |", flush=True)
        costs.append(cost_row(f"mode {mode}, Newmark, T/100, Rayleigh", trajectory, cpu, wall))
    return costs


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--spans", type=int, default=16, help="spans along the strip")
    parser.add_argument("--per-period", type=int, default=100,
                        help="Newmark steps per period of the frequency table")
    parser.add_argument("--periods", type=float, default=4.0,
                        help="periods simulated for the frequency table")
    parser.add_argument("--quick", action="store_true", help="fewer steps (a smoke run)")
    parser.add_argument("--damping-only", action="store_true",
                        help="only table 5 (Rayleigh damping) and its cost")
    args = parser.parse_args()
    taichi_ndf.init(arch="cpu", precision="f64", seed=0)
    torch.set_num_threads(1)
    print(f"commit {commit()}, load average at start {os.getloadavg()}, spans {args.spans} × 2")
    per_period = 20 if args.quick else args.per_period
    periods = 2.0 if args.quick else args.periods
    costs = []
    if args.damping_only:
        for row in damping_table(args.spans, 0.01, 0.02, 2.0 if args.quick else 4.0):
            print(row)
        print(f"\nload average at end {os.getloadavg()}")
        return

    print("\n1. Bending frequencies (Newmark β = 1/4, γ = 1/2; tip zero crossings)\n")
    print("| mode | analytic f [Hz] | measured f [Hz] | frequency error | steps per period | "
          "periods | zero crossings | Newmark's own frequency error |")
    print("|---|---|---|---|---|---|---|---|")
    for mode in (1, 2):
        trajectory, cpu, wall = run(args.spans, "newmark", mode, per_period, periods)
        period, count = measured_period(trajectory)
        exact = omega(mode) / (2 * math.pi)
        print(f"| {mode} | {exact:.6f} | {1 / period:.6f} | {1 / (exact * period) - 1:+.2e} | "
              f"{per_period} | {periods:g} | {count} | "
              f"{1 / (1 + scheme_error('newmark', per_period)) - 1:+.2e} |", flush=True)
        costs.append(cost_row(f"mode {mode}, Newmark, T/{per_period}", trajectory, cpu, wall))

    print("\n2. Period error of mode 1 against the time step (2 periods each)\n")
    print("| integrator | h | period error | observed order | the scheme's own error |")
    print("|---|---|---|---|---|")
    dissipation = []
    for integrator in ("newmark", "implicit_euler"):
        previous = None
        for n in ((10, 20) if args.quick else (10, 20, 40, 80)):
            trajectory, cpu, wall = run(args.spans, integrator, 1, n, 2.0)
            period, _ = measured_period(trajectory)
            error = period * omega(1) / (2 * math.pi) - 1
            wh = 2 * math.pi / n
            own = scheme_error(integrator, n)
            order = "" if previous is None else f"{math.log2(abs(previous / error)):.2f}"
            print(f"| {integrator} | T/{n} | {error:+.3e} | {order} | {own:+.3e} |", flush=True)
            previous = error
            if integrator == "implicit_euler":
                energy = totals(trajectory)
                lost = 1 - energy[n] / energy[0]
                dissipation.append((n, lost, 1 - (1 + wh**2) ** (-n)))
            costs.append(cost_row(f"mode 1, {integrator}, T/{n}", trajectory, cpu, wall))

    print("\n3. Energy E = ½VᵀMV + Π\n")
    print("| integrator | h | tip amplitude | periods | max abs(E/E₀ − 1) | E/E₀ at the end |")
    print("|---|---|---|---|---|---|")
    long = 2.0 if args.quick else 10.0
    for amplitude in (0.01, 1.0):
        trajectory, cpu, wall = run(args.spans, "newmark", 1, 40, long, amplitude)
        energy = totals(trajectory)
        drift = max(abs(e / energy[0] - 1) for e in energy)
        print(f"| newmark | T/40 | {amplitude:g} m (L/{L / amplitude:g}) | {long:g} | "
              f"{drift:.2e} | {energy[-1] / energy[0]:.8f} |", flush=True)
        costs.append(cost_row(f"mode 1, Newmark, T/40, A = {amplitude:g} m", trajectory, cpu,
                              wall))
    print("\n| implicit Euler h | energy lost in the first period | 1 − (1 + (ωh)²)^(−T/h) |")
    print("|---|---|---|")
    for n, lost, own in dissipation:
        print(f"| T/{n} | {lost:.4f} | {own:.4f} |")

    costs += damping_table(args.spans, 0.01, 0.02, 2.0 if args.quick else 4.0)

    print("\n4. Cost (CPU: user + sys of this process; per step: the steps only)\n")
    print("| run | steps | Newton iterations per step | CPU ms per step | CPU s per simulated "
          "s | wall ms per step | CPU s whole run | wall s whole run |")
    print("|---|---|---|---|---|---|---|---|")
    for row in costs:
        print(row)
    print(f"\nload average at end {os.getloadavg()}")


if __name__ == "__main__":
    main()
