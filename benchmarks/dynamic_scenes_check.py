"""The shipped dynamic scenes of issue 29, checked from their runs' outputs.

Run first (float64):

    python -m taichi_ndf.cli.sim scenes/cloth_pendulum.toml --precision f64 --no-pictures \
        --out PENDULUM
    python -m taichi_ndf.cli.sim scenes/sheet_slide_box.toml --precision f64 --no-pictures \
        --out SLIDE

then `python benchmarks/dynamic_scenes_check.py pendulum PENDULUM` and
`python benchmarks/dynamic_scenes_check.py slide SLIDE` (likewise `flag FLAG` for
scenes/flag_wind.toml, and `cost NAME=DIR ...`: one row of cost per run of any dynamic
scene; `crossings NAME=DIR ...`: the sheet's self-intersections in every output frame;
`video DIR`: the CPU of making a run's trajectory.mp4 again; `balance DIR`: the flag's wind
moment about its pole). Prints markdown tables:

- pendulum: the run (steps, Newton iterations, CPU per step and per simulated second), and the
  energy history every 0.1 s: T, Π, E = T + Π [J], the work of the mass damping
  W = ∫ α vᵀMv dt = ∫ 2 α T dt (trapezoidal over the steps) and E + W (its change from 0 is
  the scheme's drift: Newmark conserves E + W exactly only for linear problems), the far
  corner's height;
- slide: the run, no penetration from the meshes alone (the smallest signed distance of the
  mid-surface vertices of every output frame and of the final mesh to the rounded box,
  computed here from the scene's box), the centre's acceleration along the slope while the
  whole sheet is on the top (second differences of the centre probe) against
  g (sin θ − μ cos θ), and when the sheet left the top.
"""

from __future__ import annotations

import json
import math
import os
import sys
import tomllib
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def vertices(path: Path) -> np.ndarray:
    rows = [line.split()[1:4] for line in path.read_text().splitlines() if line.startswith("v ")]
    return np.array(rows, dtype=np.float64)


def run_table(d: dict) -> None:
    iterations = np.array(d["newton_iterations"])
    print("| steps | dt [s] | simulated [s] | Newton it./step mean (max) | substeps | "
          "CPU [s] | CPU/step [s] | CPU/simulated s [s] |")
    print("|---|---|---|---|---|---|---|---|")
    print(f"| {len(iterations)} | {d['dt']:g} | {d['times'][-1]:g} | {iterations.mean():.2f} "
          f"({iterations.max()}) | {sum(d['substeps'])} | {d['cpu_seconds']:.1f} | "
          f"{d['cpu_per_step']:.3f} | {d['cpu_per_simulated_second']:.1f} |")
    print()


def pendulum(out: Path) -> None:
    d = json.loads((out / "result.json").read_text())["dynamics"]
    run_table(d)
    t, kinetic, potential = (np.array(d[k]) for k in ("times", "kinetic", "potential"))
    total = kinetic + potential
    alpha = d["mass_damping"]
    rate = 2 * alpha * kinetic  # [W]: α vᵀMv
    work = np.concatenate([[0.0], np.cumsum(0.5 * (rate[1:] + rate[:-1]) * np.diff(t))])
    corner = np.array(d["probes"]["far_corner"])[:, 2]
    print("| t [s] | T [J] | Π [J] | E = T + Π [J] | damping work W [J] | E + W [J] | "
          "(E + W)/max T | far corner u_z [m] |")
    print("|---|---|---|---|---|---|---|---|")
    every = max(1, round(0.1 / d["dt"]))
    for i in range(0, len(t), every):
        print(f"| {t[i]:.2f} | {kinetic[i]:.4e} | {potential[i]:.4e} | {total[i]:.3e} | "
              f"{work[i]:.3e} | {total[i] + work[i]:+.3e} | "
              f"{(total[i] + work[i]) / kinetic.max():+.2e} | {corner[i]:.4f} |")
    print()
    print(f"max T = {kinetic.max():.4e} J at t = {t[kinetic.argmax()]:.2f} s; "
          f"lowest far corner {corner.min():.4f} m at t = {t[corner.argmin()]:.2f} s; "
          f"max |E + W| = {np.abs(total + work).max():.3e} J")


def box_distance(p: np.ndarray, centre, half, rounding) -> np.ndarray:
    """Signed distance [m] of points p (N, 3) to a rounded axis-aligned box."""
    q = np.abs(p - np.asarray(centre)) - (np.asarray(half) - rounding)
    outside = np.linalg.norm(np.clip(q, 0, None), axis=1)
    inside = np.clip(q.max(axis=1), None, 0)
    return outside + inside - rounding


def slide(out: Path) -> None:
    result = json.loads((out / "result.json").read_text())
    d = result["dynamics"]
    run_table(d)
    scene = tomllib.loads((ROOT / "scenes" / "sheet_slide_box.toml").read_text())
    box = scene["obstacles"][0]
    frames = sorted((out / "trajectory").glob("step_*.obj")) + [out / "mesh.obj"]
    distances = [float(box_distance(vertices(f), box["centre"], box["half_extents"],
                                    box["rounding"]).min()) for f in frames]
    worst = int(np.argmin(distances))
    print("| frames checked | vertices per frame | min signed distance to the box [m] (frame) | "
          "check grid's min gap over all steps [m] |")
    print("|---|---|---|---|")
    print(f"| {len(frames)} | {len(vertices(frames[0]))} | {min(distances):.4g} "
          f"({frames[worst].name}) | {min(g for g in d['gaps'] if g is not None):.4g} |")
    print()

    g = np.array(scene["loads"]["gravity"])
    theta = math.atan2(g[0], -g[2])
    mu = box["friction"]
    expected = np.linalg.norm(g) * (math.sin(theta) - mu * math.cos(theta))
    t = np.array(d["times"])
    x0 = scene["geometry"]["bounds"][0]
    edge = box["centre"][0] + box["half_extents"][0] - box["rounding"]  # the flat top's end
    centre = np.array(d["probes"]["centre"])[:, 0]
    downhill = np.array(d["probes"]["downhill_edge"])[:, 0] + x0[1]
    uphill = np.array(d["probes"]["uphill_edge"])[:, 0] + x0[0]
    on_top = np.nonzero(downhill < edge)[0]
    h = d["dt"]
    second = (centre[2:] - 2 * centre[1:-1] + centre[:-2]) / h**2  # at steps 1 … N−1
    # after the landing (the first 3 steps) while the downhill edge is on the flat top
    window = [i for i in range(3, len(t) - 1) if i + 1 in set(on_top)]
    accel = second[[i - 1 for i in window]]
    print("| θ [°] | μ | atan μ [°] | g(sin θ − μ cos θ) [m/s²] | centre's acceleration on the "
          "top, mean (min, max) [m/s²] | steps in the window | relative error of the mean |")
    print("|---|---|---|---|---|---|---|")
    print(f"| {math.degrees(theta):.2f} | {mu:g} | {math.degrees(math.atan(mu)):.2f} | "
          f"{expected:.4f} | {accel.mean():.4f} ({accel.min():.4f}, {accel.max():.4f}) | "
          f"{window[0]}–{window[-1]} | {(accel.mean() - expected) / expected:+.2%} |")
    print()
    left = np.nonzero(uphill > edge + box["rounding"])[0]
    print(f"downhill edge past the top's edge at t = {t[on_top[-1] + 1]:.2f} s; "
          f"uphill edge past the box (x > {edge + box['rounding']:.2f} m) at "
          f"{f't = {t[left[0]]:.2f} s' if len(left) else 'never'}; final centre "
          f"u = {np.array(d['probes']['centre'])[-1].round(4).tolist()} m")


def flag(out: Path) -> None:
    """The flag in wind: the run, and every 0.1 s the angle of the flag about the pole (of the
    fly's mid-point, centre probe) towards the wind (atan2(z, x) from the flag's plane; the
    wind blows at 45°), the fly corners' positions and the energies."""
    d = json.loads((out / "result.json").read_text())["dynamics"]
    run_table(d)
    t = np.array(d["times"])
    scene = tomllib.loads((ROOT / "scenes" / "flag_wind.toml").read_text())
    (x0, x1), (y0, y1) = scene["geometry"]["bounds"]
    reference = {"centre": ((x0 + x1) / 2, (y0 + y1) / 2), "fly_top": (x1, y1),
                 "fly_bottom": (x1, y0)}
    position = {k: np.array(d["probes"][k]) + np.array([*xy, 0.0])
                for k, xy in reference.items()}
    print("| t [s] | wind factor | centre's angle about the pole [°] | fly top (x, y, z) [m] | "
          "fly bottom (x, y, z) [m] | T [J] | Π [J] |")
    print("|---|---|---|---|---|---|---|")
    wind = d["wind"]
    every = max(1, round(0.1 / d["dt"]))
    for i in range(0, len(t), every):
        c = position["centre"][i]
        factor = 1 + wind["gust_amplitude"] * math.sin(2 * math.pi * wind["gust_frequency"]
                                                         * t[i])
        top, bottom = (np.round(position[k][i], 3).tolist() for k in ("fly_top", "fly_bottom"))
        print(f"| {t[i]:.1f} | {factor:.2f} | {math.degrees(math.atan2(c[2], c[0])):.1f} | "
              f"{top} | {bottom} | {d['kinetic'][i]:.3e} | {d['potential'][i]:.3e} |")
    print()


def cost(runs: list[str]) -> None:
    """One row per run NAME=DIR: the scene's steps, Newton iterations, substeps, CPU (user +
    sys of the run's process, its steps only) and wall per step and per simulated second."""
    print("| scene | spans | dt [s] | steps | simulated [s] | Newton it./step | substeps | "
          "CPU [s] | CPU/step [s] | CPU/simulated s [s] | wall/step [s] |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for run in runs:
        name, path = run.split("=", 1)
        d = json.loads((Path(path) / "result.json").read_text())["dynamics"]
        steps = len(d["newton_iterations"])
        print(f"| {name} | {d['spans'][0]}×{d['spans'][1]} | {d['dt']:g} | {steps} | "
              f"{d['times'][-1]:g} | {np.mean(d['newton_iterations']):.2f} | "
              f"{sum(d['substeps'])} | {d['cpu_seconds']:.1f} | {d['cpu_per_step']:.3f} | "
              f"{d['cpu_per_simulated_second']:.1f} | {d['wall_seconds'] / steps:.3f} |")


def faces_of(path: Path) -> np.ndarray:
    rows = [[int(w.split("/")[0]) - 1 for w in line.split()[1:4]]
            for line in path.read_text().splitlines() if line.startswith("f ")]
    return np.array(rows, dtype=np.int64)


def crossings(runs: list[str]) -> None:
    """Per run NAME=DIR: whether the sheet passes through itself, from the output meshes alone
    (taichi_ndf/io/mesh_check.py, independent of the solver): the intersecting face pairs
    of every trajectory frame and of mesh.obj; the frames with any, and the most."""
    sys.path.insert(0, str(ROOT / "tests"))
    from taichi_ndf.io.mesh_check import self_intersections

    print("| run | frames checked | frames with crossings | most crossing face pairs (frame, "
          "t [s]) | final mesh's crossing pairs |")
    print("|---|---|---|---|---|")
    for run in runs:
        name, path = run.split("=", 1)
        out = Path(path)
        times = json.loads((out / "result.json").read_text())["trajectory"]["times"]
        frames = sorted((out / "trajectory").glob("step_*.obj"))
        counts = [len(self_intersections(vertices(f), faces_of(f))) for f in frames]
        final = len(self_intersections(vertices(out / "mesh.obj"), faces_of(out / "mesh.obj")))
        worst = int(np.argmax(counts))
        print(f"| {name} | {len(frames)} | {sum(c > 0 for c in counts)} | {counts[worst]} "
              f"({worst}, {times[worst]:.2f}) | {final} |")


def video(out: Path) -> None:
    """CPU (user + sys of this process) and wall of a run's trajectory.mp4 made again from its
    output frames (trajectory/*.obj, result.json's times): the frames' rendering and the
    encoding separately (the taichi_ndf on PYTHONPATH: run it with each version to compare)."""
    import resource
    import tempfile
    import time

    from taichi_ndf.render.trajectory import FPS, trajectory_frames
    from taichi_ndf.render.video import write_video

    def cpu() -> float:
        r = resource.getrusage(resource.RUSAGE_SELF)
        return r.ru_utime + r.ru_stime

    result = json.loads((out / "result.json").read_text())
    times = result["trajectory"]["times"]
    frames = sorted((out / "trajectory").glob("step_*.obj"))
    states, faces = [vertices(f) for f in frames], faces_of(frames[0])
    gravity = np.array(result["resolved"]["scene_file"]["loads"]["gravity"], dtype=np.float64)
    up = -gravity / np.linalg.norm(gravity)
    c0, w0 = cpu(), time.time()
    pictures = trajectory_frames(states, faces, times, reference=vertices(
        out / "reference.obj"), up=up, physical_time=True)
    c1, w1 = cpu(), time.time()
    with tempfile.TemporaryDirectory() as scratch:
        write_video(Path(scratch) / "trajectory.mp4", pictures, FPS)
    c2, w2 = cpu(), time.time()
    print(f"| {len(states)} states, {len(pictures)} video frames | {c1 - c0:.1f} | "
          f"{w1 - w0:.1f} | {c2 - c1:.1f} | {w2 - w1:.1f} | {os.getloadavg()[0]:.1f} |")


def balance(out: Path) -> None:
    """The flag's wind moment about the pole (the y axis) at its last output frame: the
    quadratic normal drag p = ½ ρ C_d s|s|, s = w·n of the mean wind (still air speed of the
    cloth neglected), summed over the faces of the frame's mesh: M_y [N m], and the mean
    angle of the faces' normals about the pole. A rigid flat plate hinged on a vertical pole
    has its gravity along the pole (no moment about it), so it balances where w·n = 0: the
    wind's direction, 45°."""
    result = json.loads((out / "result.json").read_text())
    wind = np.array(result["dynamics"]["wind"]["velocity"], dtype=np.float64)
    frames = sorted((out / "trajectory").glob("step_*.obj"))
    times = result["trajectory"]["times"]
    print("| t [s] | centre's angle [°] | area-weighted normal's angle [°] | |n_y| mean | "
          "drag moment about the pole M_y [N m] | moment of a plate at that angle [N m] |")
    print("|---|---|---|---|---|---|")
    for k in range(max(0, len(frames) - 6), len(frames)):
        x, f = vertices(frames[k]), faces_of(frames[k])
        a, b, c = x[f[:, 0]], x[f[:, 1]], x[f[:, 2]]
        cross = np.cross(b - a, c - a)
        area = 0.5 * np.linalg.norm(cross, axis=1)
        n = cross / np.linalg.norm(cross, axis=1, keepdims=True)
        s = n @ wind
        force = (0.5 * 1.2 * 1.2 * s * np.abs(s) * area)[:, None] * n
        centroid = (a + b + c) / 3
        moment = float(np.cross(centroid, force)[:, 1].sum())
        mean_n = (n * np.sign(n[:, 2:3] + 1e-300) * area[:, None]).sum(axis=0)
        normal_angle = math.degrees(math.atan2(-mean_n[0], mean_n[2]))
        centre = x.mean(axis=0)
        theta = math.atan2(centre[2], centre[0])
        plate_n = np.array([-math.sin(theta), 0.0, math.cos(theta)])
        sp = plate_n @ wind
        lever = np.array([math.cos(theta), 0.0, math.sin(theta)]) * 0.3
        plate = float(np.cross(lever, 0.5 * 1.44 * sp * abs(sp) * area.sum() * plate_n)[1])
        print(f"| {times[k]:.2f} | {math.degrees(theta):.1f} | {normal_angle:.1f} | "
              f"{np.abs(n[:, 1]) @ area / area.sum():.3f} | {moment:.3e} | {plate:.3e} |")


if __name__ == "__main__":
    if sys.argv[1] in ("cost", "crossings"):
        {"cost": cost, "crossings": crossings}[sys.argv[1]](sys.argv[2:])
    else:
        {"pendulum": pendulum, "slide": slide, "flag": flag, "video": video,
         "balance": balance}[sys.argv[1]](Path(sys.argv[2]))
