"""The dynamic flag side by side with NVIDIA Newton's cloth (issue 29's peer item), in one run.

    python benchmarks/dynamics_peer.py [--newton-python PATH]
                                       [--cases strip flag curtain wind] [--duration 1.0]
                                       [--cells 30 20] [--keep DIR]

Newton (warp-lang + newton) lives in its own environment, not the project's: `python3.11 -m
venv /tmp/nwt && /tmp/nwt/bin/pip install numpy warp-lang newton` (measured with warp-lang
1.19.0, newton 1.8.0), then `--newton-python /tmp/nwt/bin/python` (or NEWTON_PYTHON; or `pip install
taichi-ndf[peers]` into the project's environment). Where it cannot import newton the Newton
runs are skipped with one line and ours still run. Results: benchmarks/RESULTS.md, "Dynamics:
the flag beside NVIDIA Newton's cloth" and "Dynamics: the flag in wind beside NVIDIA Newton's
cloth".

Newton has no aerodynamic forcing in its cloth solvers (1.8.0: `add_cloth_grid` takes
`tri_drag`/`tri_lift` but no solver reads them). scenes/flag_wind.toml's 0.6 m × 0.4 m sheet
hinged along its hoist (x = 0), released at rest: (a) `flag`: the pole vertical, gravity −y in
the sheet's plane (it sags in its plane), no wind; (b) `curtain`: the pole horizontal, gravity
−z, the sheet released horizontal swings down about the hinge (bending, membrane and inertia
together), no wind; (d) `wind`: the flag of (a) in flag_wind's gusting wind, w(t) = (2, 0, 2)
m/s × (1 + 0.4 sin(2π 1.5 Hz t)), ρ_air = 1.2 kg/m³, C_d = 1.2: ours the scene's
`[dynamics.wind]` (objective/wind.py: the drag linearised about each step's start, implicit in
the velocity); Newton's cloth gets the same law as external particle forces recomputed before
each of its steps from its current mesh (the child's `wind_forces`: per triangle its normal,
area and mean vertex velocity, a third to each vertex; equal to the project's own wind force
on the same mesh, tests/test_dynamics_peer.py), explicit in the velocity. (c) `strip`: the
static check of the bending mapping, a cantilever strip 0.2 m × 0.02 m clamped at x = 0 under
gravity scaled so that its sag is 5 % of its length (linear), against q L⁴/(8B).

The material: the polyester preset's means, isotropic, ν = 0 (Newton's membrane is isotropic;
the preset's shear G12 = 19 N/m is 100 × below an isotropic sheet's and cannot be matched):
membrane stiffness D = (a11 + a22)/2 = 4029.6 N/m, bending B = (warp + weft)/2 = 41.50e-6 N·m,
ρ_A = 0.128 kg/m². Ours: `type = "linear"` (the Koiter shell, Green strain, ν = 0). Newton's
VBD: a stable Neo-Hookean triangle with Lamé constants per area, tri_ke = μ, tri_ka = λ, whose
linearisation at rest is the plane-stress law μ = D (1 − ν)/2, λ = D ν [N/m] (here λ = 0);
the dihedral springs ½ edge_ke |e| θ² with edge_ke = B/Δ [N] on a grid of square cells Δ: a
cylindrical bending κ across the edges of length Δ turns each by θ = κΔ, so the springs store
½ (B/Δ) Δ (κΔ)² per cell of area Δ², the plate's ½ B κ². The twist is not matched (its ratio is
printed: the grid's diagonals carry it). ν = 0 because the springs have no κ₁₁κ₂₂ coupling.

Our discretisation: the flag scene's cubic spline, 8 × 6 spans, 4 × 4 Gauss points per span
(32 × 24 points, 11 × 9 coefficients); Newton's: `add_cloth_grid` with `--cells` square cells
(30 × 20: Δ = 20 mm, 651 vertices, near our 768 Gauss points), lumped masses ρ_A × ⅓ of each
vertex's triangles; the hinge = the first column of vertices held, the clamp = the first two
(the strip's grid starts one cell behind x = 0). Both implicit Euler, h = 10 ms, no damping
(ours: each step a converged Newton solve in float64; VBD: a fixed number of Gauss–Seidel
iterations per step in float32; its settings are rows of the tables). Energies: T and
Π = elastic − Σ m g·u [J] in each code by its own model (Newton's from its formulas in numpy).
CPU = user + sys: ours of the steps (result.json), Newton's per step from the steps after the
first (which loads Warp's kernels), and of each whole child process (os.wait4).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from fe_peer import run_child  # noqa: E402  (a child's CPU, wall and RSS by os.wait4)
from provenance import commit  # noqa: E402

from taichi_ndf.problem.wind import AIR_DENSITY, FLAT_PLATE_DRAG  # noqa: E402

NEWTON_SCRIPT = Path(__file__).resolve().parent / "dynamics_peer_newton.py"
MEMBRANE = (2 * 2002.08618 + 2 * 2027.48559) / 2  # N/m, the polyester preset's (a11 + a22)/2
BENDING = (51.713814e-6 + 31.282822e-6) / 2  # N·m, its (warp + weft)/2
DENSITY = 0.128  # kg/m²
POISSON = 0.0
FLAG = {"bounds": ((0.0, 0.6), (-0.2, 0.2)), "spans": (8, 6),
        "probes": {"fly_top": (0.6, 0.2), "fly_bottom": (0.6, -0.2), "centre": (0.3, 0.0)}}
STRIP = {"bounds": ((0.0, 0.2), (-0.01, 0.01)), "spans": (8, 1), "probes": {"tip": (0.2, 0.0)}}
STRIP_SAG = 0.05  # the strip's sag as a fraction of its length (linear regime)
# scenes/flag_wind.toml's wind: w(t) = U (1 + a sin(2π f t)), the project's ρ_air and C_d
WIND = {"velocity": [2.0, 0.0, 2.0], "gust_amplitude": 0.4, "gust_frequency": 1.5,
        "air_density": AIR_DENSITY, "drag_coefficient": FLAT_PLATE_DRAG}
SETTLE = 0.5  # s: the flapping's figures are taken over t >= SETTLE (the first swing left out)
# VBD's settings compared: (dt [s], iterations per step)
VBD_SETTINGS = ((0.01, 10), (0.01, 100), (0.001, 10), (0.001, 50))


def vbd_material(spacing: float) -> dict:
    """VBD's parameters matching D, B, ν on a grid of square cells of side `spacing` [m]."""
    return {"tri_ke": MEMBRANE * (1 - POISSON) / 2, "tri_ka": MEMBRANE * POISSON,
            "edge_ke": BENDING / spacing}


def strip_gravity() -> float:
    """g [m/s²] that sags the strip by STRIP_SAG × L: q L⁴/(8B) = STRIP_SAG L, q = ρ_A g."""
    length = STRIP["bounds"][0][1]
    return STRIP_SAG * 8 * BENDING / (DENSITY * length ** 3)


def scene_text(name: str, case: dict, gravity: tuple, edge: str,
               dynamics: tuple[float, float] | None, wind: dict | None = None) -> str:
    """Our scene: the case's rectangle, the matched linear material, the edge constraint,
    and with `dynamics` = (dt, duration) implicit Euler without damping, in `wind` (WIND's
    keys) if given."""
    (x0, x1), (y0, y1) = case["bounds"]
    lines = [f'name = "{name}"', "[geometry]", 'type = "plane"',
             f"bounds = [[{x0}, {x1}], [{y0}, {y1}]]", "[material]", 'type = "linear"',
             f"areal_density = {DENSITY}", f"poisson_ratio = {POISSON}",
             f"membrane_stiffness = {MEMBRANE!r}", f"bending_stiffness = {BENDING!r}",
             "[loads]", f"gravity = [{gravity[0]!r}, {gravity[1]!r}, {gravity[2]!r}]",
             "[[boundary.constraint]]", f'type = "{edge}"', 'edge = "xi1_min"', "[field]",
             'type = "spline"', f"spans = [{case['spans'][0]}, {case['spans'][1]}]",
             "[training]", 'method = "newton"']
    if dynamics is not None:
        lines += ["[dynamics]", 'integrator = "implicit_euler"', f"dt = {dynamics[0]}",
                  f"duration = {dynamics[1]}"]
        if wind is not None:
            u = wind["velocity"]
            lines += ["[dynamics.wind]", f"velocity = [{u[0]!r}, {u[1]!r}, {u[2]!r}]"] + [
                f"{key} = {wind[key]!r}" for key in ("gust_amplitude", "gust_frequency",
                                                     "air_density", "drag_coefficient")]
    for probe, xi in case["probes"].items():
        lines += ["[[probes]]", f'name = "{probe}"', f"xi = [{xi[0]}, {xi[1]}]"]
    return "\n".join(lines) + "\n"


def ours(name: str, text: str, work: Path, timeout: float) -> dict:
    """Run our scene with ndf-sim (float64, no pictures) as a child; result.json and cost."""
    scene, out = work / f"{name}.toml", work / f"{name}_ours"
    scene.write_text(text)
    cost = run_child([sys.executable, "-m", "taichi_ndf.cli.sim", str(scene), "--precision",
                      "f64", "--no-pictures", "--out", str(out)], work / f"{name}_ours.log",
                     timeout)
    try:
        return {**cost, "result": json.loads((out / "result.json").read_text())}
    except (OSError, ValueError):
        return {**cost, "result": None}


def newton_missing(python: str) -> str | None:
    """Why Newton cannot run with `python` (one line), or None."""
    try:
        probe = subprocess.run([python, "-c", "import warp, newton; newton.solvers.SolverVBD"],
                               capture_output=True, text=True, timeout=300)
    except OSError as err:
        return f"{python}: {err}"
    if probe.returncode == 0:
        return None
    lines = probe.stderr.strip().splitlines()
    return lines[-1] if lines else f"exit code {probe.returncode}"


def newton(name: str, job: dict, python: str, work: Path, timeout: float) -> dict:
    """One VBD run (dynamics_peer_newton.py in Newton's environment) with its process cost."""
    path, result = work / f"{name}.json", work / f"{name}_result.json"
    path.write_text(json.dumps(job))
    cost = run_child([python, str(NEWTON_SCRIPT), str(path), str(result)],
                     work / f"{name}.log", timeout)
    try:
        return {**cost, "result": json.loads(result.read_text())}
    except (OSError, ValueError):
        return {**cost, "result": None}


def newton_job(case: dict, cells: tuple[int, int], gravity: tuple, fixed: int, dt: float,
               steps: int, iterations: int, behind: int = 0, wind: dict | None = None) -> dict:
    """The job of dynamics_peer_newton.py for a case; `behind` cells added behind x = 0;
    `wind` (WIND's keys) or None."""
    (x0, x1), (y0, y1) = case["bounds"]
    spacing = (x1 - x0) / cells[0]
    return {"cells": [cells[0] + behind, cells[1]], "size": [x1 - x0 + behind * spacing, y1 - y0],
            "x0": x0 - behind * spacing, "y0": y0, "areal_density": DENSITY,
            "fixed_columns": fixed, "gravity": list(gravity), **vbd_material(spacing),
            "bending_stiffness": BENDING, "dt": dt, "steps": steps, "iterations": iterations,
            "probes": {k: [p[0], p[1], 0.0] for k, p in case["probes"].items()},
            **({} if wind is None else {"wind": wind})}


def at(times: list, values: list, t: float):
    """The value recorded at the time nearest t."""
    return values[int(np.argmin(np.abs(np.asarray(times) - t)))]


def strip(args, work: Path, python: str | None) -> None:
    """The cantilever strip's static sag in both codes against q L⁴/(8B)."""
    g = strip_gravity()
    length = STRIP["bounds"][0][1]
    exact = DENSITY * g * length ** 4 / (8 * BENDING)
    print(f"## strip: cantilever {length} m × 0.02 m, clamped at x = 0, g = {g:.5g} m/s² "
          f"(q L⁴/(8B) = {exact:.6g} m = {STRIP_SAG:.0%} of L)\n")
    print("| code | discretisation | settings | tip sag [m] | / q L⁴/(8B) | dihedral springs' "
          "energy / plate's, bent along x | process CPU [s] | wall [s] |")
    print("|---|---|---|---|---|---|---|---|")
    for spans in ((8, 1), (32, 2), (64, 2)):
        case = {**STRIP, "spans": spans}
        run = ours(f"strip_{spans[0]}", scene_text("peer_strip", case, (0.0, 0.0, -g),
                                                  "clamped_edge", None), work, args.timeout)
        if run["result"] is None:
            print(f"| taichi-ndf | {spans}: failed (exit {run['rc']}) |")
            continue
        sag = -run["result"]["probes"]["tip"][2]
        print(f"| taichi-ndf | cubic spline {spans[0]} × {spans[1]} spans | quasistatic Newton, "
              f"f64 | {sag:.6g} | {sag / exact:.4f} | — | {run['cpu_s']:.1f} | "
              f"{run['wall_s']:.1f} |")
    if python is None:
        return
    for cells in (10, 20, 40):
        job = newton_job(STRIP, (cells, 2), (0.0, 0.0, -g), 2, 0.5, 40, 500, behind=1)
        run = newton(f"strip_vbd_{cells}", job, python, work, args.timeout)
        r = run["result"]
        if r is None:
            print(f"| Newton VBD | {cells} cells: failed (exit {run['rc']}) |")
            continue
        tip = [-u[2] for u in r["probes"]["tip"]]
        print(f"| Newton VBD | {cells + 1} × 2 cells, Δ = {length / cells * 1e3:g} mm, "
              f"{r['particles']} vertices | 40 steps of 0.5 s × 500 it. (last change "
              f"{abs(tip[-1] - tip[-2]):.1e} m), f32 | {tip[-1]:.6g} | {tip[-1] / exact:.4f} | "
              f"{r['bending_modes']['x']:.3f} | {run['cpu_s']:.1f} | {run['wall_s']:.1f} |")
    print()


def flapping(times: list, corner: list, kinetic: list) -> dict:
    """Over t >= SETTLE: the corner's half peak-to-peak per coordinate [m] (3,), the dominant
    frequency [Hz] of its x and of its z (the largest |FFT| of the coordinate less its mean,
    resolution 1/(the window's length)), and the mean kinetic energy [J] over the whole run
    and over the window."""
    t, u, k = np.asarray(times), np.asarray(corner), np.asarray(kinetic)
    window = t >= SETTLE - 1e-9
    tail = u[window]
    step = t[1] - t[0]
    frequencies = np.fft.rfftfreq(len(tail), step)

    def dominant(c: np.ndarray) -> float:
        spectrum = np.abs(np.fft.rfft(c - c.mean()))
        return float(frequencies[1 + int(np.argmax(spectrum[1:]))])

    return {"amplitude": 0.5 * (tail.max(axis=0) - tail.min(axis=0)),
            "frequency_x": dominant(tail[:, 0]), "frequency_z": dominant(tail[:, 2]),
            "resolution": 1.0 / (len(tail) * step), "mean_kinetic": float(k.mean()),
            "mean_kinetic_window": float(k[window].mean())}


def dynamic(name: str, gravity: tuple, args, work: Path, python: str | None,
            wind: dict | None = None) -> None:
    """One dynamic case in both codes: the probes' trajectories, energies, the flapping and
    the costs; in `wind` (WIND) if given."""
    dt, duration = 0.01, args.duration
    print(f"## {name}: gravity {gravity} m/s², hinged at x = 0, {duration:g} s"
          + ("" if wind is None else f", wind {wind}") + "\n")
    rows = []
    run = ours(name, scene_text(f"peer_{name}", FLAG, gravity, "hinged_edge", (dt, duration),
                                wind), work, args.timeout)
    if run["result"] is None:
        print(f"taichi-ndf failed (exit {run['rc']}, {work / (name + '_ours.log')})\n")
    else:
        d = run["result"]["dynamics"]
        rows.append(("taichi-ndf", f"spline {FLAG['spans'][0]} × {FLAG['spans'][1]} spans "
                     f"(32 × 24 Gauss points), f64", f"h = 10 ms, Newton "
                     f"{np.mean(d['newton_iterations']):.1f} it./step", d["times"],
                     {k: v for k, v in d["probes"].items()}, d["kinetic"], d["potential"],
                     d["cpu_per_step"], d["cpu_seconds"], d["cpu_per_simulated_second"], run))
    for step, iterations in (() if python is None else VBD_SETTINGS):
        n = round(duration / step)
        job = newton_job(FLAG, tuple(args.cells), gravity, 1, step, n, iterations, wind=wind)
        run = newton(f"{name}_vbd_{step:g}_{iterations}", job, python, work, args.timeout)
        r = run["result"]
        if r is None:
            print(f"Newton VBD h = {step:g} s × {iterations} it. failed (exit {run['rc']})\n")
            continue
        forces = "" if wind is None else (f"; the wind's forces (numpy, in the steps' CPU): "
                                          f"{r['wind_cpu_per_step'] * 1e3:.2f} ms/step")
        rows.append(("Newton VBD", f"{args.cells[0]} × {args.cells[1]} cells, "
                     f"{r['particles']} vertices, f32{forces}", f"h = {step * 1e3:g} ms, "
                     f"{iterations} it./step", r["times"], r["probes"], r["kinetic"],
                     r["potential"], r["cpu_per_step"], r["cpu_per_step"] * n,
                     r["cpu_per_step"] / step, run))
    marks = [t for t in (0.1, 0.25, 0.5, 1.0, 2.0, 4.0) if t <= duration + 1e-9]
    for corner in ("fly_top", "fly_bottom"):
        print(f"{corner} corner's displacement (x, y, z) [m] at t [s]:\n")
        print("| code | settings | " + " | ".join(f"t = {t:g}" for t in marks) + " |")
        print("|---|---|" + "---|" * len(marks))
        for code, _, setting, times, probes, *_ in rows:
            cells = [" ".join(f"{c:+.3f}" for c in at(times, probes[corner], t))
                     for t in marks]
            print(f"| {code} | {setting} | " + " | ".join(cells) + " |")
        print()
    print("\nT, Π and T + Π [J] at t [s] (Π = elastic − Σ m g·u, each code's own model):\n")
    print("| code | settings | " + " | ".join(f"t = {t:g}" for t in marks) + " |")
    print("|---|---|" + "---|" * len(marks))
    for code, _, setting, times, _, kinetic, potential, *_ in rows:
        cells = [f"{at(times, kinetic, t):.3g}, {at(times, potential, t):.3g}, "
                 f"{at(times, kinetic, t) + at(times, potential, t):.3g}" for t in marks]
        print(f"| {code} | {setting} | " + " | ".join(cells) + " |")
    if duration > SETTLE + 0.1:
        print(f"\nThe flapping over t >= {SETTLE:g} s: fly_top's half peak-to-peak (x, y, z), "
              "the dominant frequency of its x and z (FFT), the mean kinetic energy over the "
              "whole run and over the window:\n")
        print("| code | settings | half peak-to-peak x, y, z [m] | dominant f of x, of z [Hz] "
              "(resolution) | mean T, whole run; window [J] |")
        print("|---|---|---|---|---|")
        for code, _, setting, times, probes, kinetic, *_ in rows:
            f = flapping(times, probes["fly_top"], kinetic)
            print(f"| {code} | {setting} | " + " ".join(f"{a:.3f}" for a in f["amplitude"])
                  + f" | {f['frequency_x']:.2f}, {f['frequency_z']:.2f} "
                  f"(±{f['resolution'] / 2:.2f}) | {f['mean_kinetic']:.3g}; "
                  f"{f['mean_kinetic_window']:.3g} |")
    print("\nCost (CPU = user + sys; the steps alone, and the whole child process with "
          "start-up and compilation):\n")
    print("| code | discretisation | settings | CPU/step [s] | CPU/simulated s [s] | steps' CPU "
          "[s] | process CPU, wall [s] | fly_top vs taichi-ndf: final, largest over the run "
          "[m] |")
    print("|---|---|---|---|---|---|---|---|")
    for code, mesh, setting, times, probes, _, _, per_step, cpu, per_second, run in rows:
        final = largest = float("nan")
        if rows[0][0] == "taichi-ndf":
            ours_times, ours_top = rows[0][3], rows[0][4]["fly_top"]
            gaps = [np.linalg.norm(np.asarray(at(times, probes["fly_top"], t)) - np.asarray(u))
                    for t, u in zip(ours_times, ours_top, strict=True)]
            final, largest = gaps[-1], max(gaps)
        print(f"| {code} | {mesh} | {setting} | {per_step:.4f} | {per_second:.2f} | "
              f"{cpu:.2f} | {run['cpu_s']:.1f}, {run['wall_s']:.1f} | {final:.3g}, "
              f"{largest:.3g} |")
    print()


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--newton-python", default=os.environ.get("NEWTON_PYTHON", sys.executable),
                   help="the Python of an environment with warp-lang and newton")
    p.add_argument("--cases", nargs="+", default=["strip", "flag", "curtain", "wind"],
                   choices=("strip", "flag", "curtain", "wind"))
    p.add_argument("--duration", type=float, default=1.0, help="simulated seconds [s]")
    p.add_argument("--cells", type=int, nargs=2, default=[30, 20],
                   help="Newton's grid over the flag (square cells)")
    p.add_argument("--timeout", type=float, default=3600.0, help="per child process [s]")
    p.add_argument("--keep", type=Path, help="keep the runs' files here")
    args = p.parse_args(argv)
    lx, ly = (b[1] - b[0] for b in FLAG["bounds"])
    if args.duration <= 0 or round(args.duration / 0.01) < 2:
        print(f"dynamics_peer: --duration must be at least 0.02 s, got {args.duration}",
              file=sys.stderr)
        return 2
    if min(args.cells) < 2 or abs(lx / args.cells[0] - ly / args.cells[1]) > 1e-12:
        print(f"dynamics_peer: --cells must give square cells on {lx} × {ly} m, got "
              f"{args.cells}", file=sys.stderr)
        return 2
    missing = newton_missing(args.newton_python)
    if missing:
        print(f"NVIDIA Newton skipped ({args.newton_python}: {missing}); install it in its own "
              "environment (pip install warp-lang newton) and pass --newton-python")
    python = None if missing else args.newton_python
    load = os.getloadavg()
    print(f"commit {commit()}, load average {load[0]:.1f} {load[1]:.1f} {load[2]:.1f}\n")
    with tempfile.TemporaryDirectory() as tmp:
        work = args.keep or Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        for case in args.cases:
            if case == "strip":
                strip(args, work, python)
            else:
                dynamic(case, (0.0, 0.0, -9.81) if case == "curtain" else (0.0, -9.81, 0.0),
                        args, work, python, WIND if case == "wind" else None)
    load = os.getloadavg()
    print(f"load average at the end {load[0]:.1f} {load[1]:.1f} {load[2]:.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
