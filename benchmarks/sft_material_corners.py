"""Are the held corners worth fitting? B with each frame's corner positions as unknowns.

    python benchmarks/sft_material_corners.py --data W/hang_TAG [--meshes W/sft_TAG/meshes]
        [--spans 14 14] [--start B] [--max-evaluations 40] [--corners free|ray|clamped]
        [--weights W0 W1 ...] [--template-corners]

A measurement, not the estimate (issue 27 item 3; benchmarks/RESULTS.md, Material from
video, 2026-12-06 04:30): `material_from_video` clamps each frame's model at the
reconstructed held corners, so their error is imposed exactly (measured: two thirds of the
reconstruction's effect on B). Here the two corners of every frame are unknowns fitted with
ln B and ln D to all vertices of the frame (the corners stay observations, weighted like the
rest): one least-squares problem over (ln B, ln D, 6 per frame), each residual evaluation
every frame's equilibrium (`SplineEquilibrium`, quartic, on --spans, first solve from the
least-squares fit of the frame's points), the Jacobian by finite differences grouped by
frame (scipy `jac_sparsity`). The flat size is the true one (as `--rest flat`), ρ_A = 0.2
stated as in `sft_material.py`. The principled build — a per-frame prescribed-displacement
unknown of `inverse.material` with its implicit-function Jacobian (K_ff du_f = −K_fc du_c) and
the standard error over the joint Jacobian — is not done.

`--corners ray` (2026-12-06 09:30): each corner stays on the camera ray through its
reconstructed position — the image's evidence, accurate across the ray — and only its
distance along the ray is fitted (2 unknowns per frame instead of 6), since a monocular
reconstruction's error is mostly along the rays (measured at the corners: up to 3.3 mm along,
≤ 0.9 mm across).

`--template-corners` (10:40): frame 0's corners held at the template (the given shape),
only the reconstructed frames' corners fitted; `--weights`: per-frame residual weights (the
estimate's `frame_weights`). With both, the `ndf-sft` c = 5 / 3 cm sequences gave +2.75 % /
+2.50 % (benchmarks/RESULTS.md, Material from video, 2026-12-06 09:16).

--data: a `sft_material.py` work folder's truth sequence (hang_*); --meshes: `ndf-sft`'s
reconstructed meshes (default: the truth meshes, noise-free). Prints B, its error, D, the rms
misfit, the corners' distance to the truth before and after, CPU seconds.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch
from scipy.optimize import least_squares

import taichi_ndf
from inverse.material.spline_equilibrium import SplineEquilibrium, SplineModelConfig
from inverse.material.unknowns import parse_unknowns
from inverse.sft.hanging import SheetGrid, hanging_across, hanging_model
from inverse.sft.hanging_synth import HangingConfig, template_grid
from inverse.sft.settings import MaterialFromVideoConfig
from taichi_ndf.io import read_mesh


def meshes(folder: Path) -> list[np.ndarray]:
    return [np.asarray(read_mesh(p).vertices, dtype=np.float64)
            for p in sorted(folder.glob("*.obj"))]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--data", type=Path, required=True)
    p.add_argument("--meshes", type=Path)
    p.add_argument("--spans", type=int, nargs=2, default=(14, 14))
    p.add_argument("--start", type=float, help="start B [N·m] (default: c = 2 cm)")
    p.add_argument("--max-evaluations", type=int, default=40)
    p.add_argument("--weights", type=float, nargs="+",
                   help="per-frame weights of the residuals (e.g. an estimate's "
                   "frame_weights; default: 1)")
    p.add_argument("--template-corners", action="store_true",
                   help="frame 0's corners held where the template puts them (the given "
                   "shape), the other frames' fitted")
    p.add_argument("--corners", choices=("free", "ray", "clamped"), default="free",
                   help="free: each corner's 3 coordinates are unknowns; ray: each corner "
                   "stays on the camera ray through its reconstructed position (what the "
                   "image observed) and only its distance along the ray is fitted; clamped: "
                   "held where reconstructed (the estimate's model, here on one grid: the "
                   "reference)")
    args = p.parse_args()
    torch.set_num_threads(1)
    taichi_ndf.init(arch="cpu", precision="f64")
    settings = json.loads((args.data / "synth.json").read_text())["config"]
    truth = HangingConfig(**{k: tuple(v) if isinstance(v, list) else v
                             for k, v in settings.items()
                             if k in ("frames", "sheet_size", "cells", "bending_length",
                                      "areal_density", "membrane_stiffness", "poisson_ratio",
                                      "band", "spans", "degree")})
    template, _, held = template_grid(truth)
    gt = meshes(args.data / "gt")
    observed = meshes(args.meshes) if args.meshes else gt
    flat = np.column_stack([template.xi, np.zeros(len(template.xi))])
    grid = SheetGrid.from_template(flat, template.faces, held).with_size(truth.sheet_size)
    config = MaterialFromVideoConfig(areal_density=truth.areal_density)
    gravity = np.asarray(config.gravity, dtype=np.float64)
    spline = SplineModelConfig(spans=tuple(args.spans), degree=4, boundary_length=None)
    xi = torch.from_numpy(grid.xi)
    held = list(held)

    def model(corners):
        return hanging_model(grid.size, config.start_material, corners,
                             hanging_across(corners, gravity), gravity, band=config.band)

    _, unknowns = parse_unknowns("bending,stretch", model(observed[0][held]))

    def frame_residual(f, corners, theta):
        equilibrium = SplineEquilibrium(model(corners), unknowns, spline,
                                        spline.grid(model(corners)))
        points = torch.from_numpy(observed[f])
        equilibrium.solve(theta, start=equilibrium.fitted_state(xi, points))
        return (equilibrium.positions(xi) - points).numpy().ravel()

    frames = len(observed)
    per = {"free": 6, "ray": 2, "clamped": 0}[args.corners]  # unknowns per frame
    # the reconstructed corners' camera rays (unit, from the camera centre at the origin)
    rays = [o[held] / np.linalg.norm(o[held], axis=1, keepdims=True) for o in observed]

    def frame_corners(z, f):
        values = z[2 + per * f: 2 + per * (f + 1)]
        if args.corners == "clamped" or (f == 0 and args.template_corners):
            return observed[f][held]
        if args.corners == "free":
            return values.reshape(2, 3)
        return rays[f] * values[:, None]  # each corner on its ray at the fitted distance

    def unpack(z):
        return ([float(np.exp(z[0])), float(np.exp(z[1]))],
                [frame_corners(z, f) for f in range(frames)])

    weights = np.ones(frames) if args.weights is None else np.asarray(args.weights)
    if len(weights) != frames:
        raise SystemExit(f"--weights: {frames} frames, {len(weights)} weights")

    def residual(z):
        theta, corners = unpack(z)
        return np.concatenate([weights[f] * frame_residual(f, corners[f], theta)
                               for f in range(frames)])

    start_b = args.start or truth.areal_density * 9.81 * 0.02 ** 3
    corner_start = [o[held].ravel() if args.corners == "free" else
                    np.linalg.norm(o[held], axis=1)[:per] for o in observed]
    z0 = np.concatenate([[np.log(start_b), np.log(config.start_material.membrane_stiffness)],
                         *corner_start])
    rows = 3 * len(xi)
    sparsity = np.zeros((frames * rows, len(z0)), dtype=int)
    sparsity[:, :2] = 1
    for f in range(frames):
        if not (f == 0 and args.template_corners):  # else those unknowns are unused
            sparsity[f * rows:(f + 1) * rows, 2 + per * f: 2 + per * (f + 1)] = 1
    cpu = time.process_time()
    solution = least_squares(residual, z0, jac_sparsity=sparsity,
                             x_scale=np.r_[1.0, 1.0, np.full(per * frames, 1e-3)],
                             diff_step=np.r_[1e-4, 1e-4, np.full(per * frames, 1e-7)],
                             xtol=1e-6, ftol=1e-8, max_nfev=args.max_evaluations)
    theta, corners = unpack(solution.x)
    true_b = truth.material.bending_stiffness
    rms = 1e3 * np.sqrt(np.mean((solution.fun.reshape(frames, -1) / weights[:, None]) ** 2)
                        * 3)
    print(f"spans {tuple(args.spans)}, {'reconstructed' if args.meshes else 'truth'} meshes: "
          f"B {theta[0]:.4g} N·m ({100 * (theta[0] / true_b - 1):+.2f} %), D {theta[1]:.4g} "
          f"N/m, rms misfit {rms:.3f} mm, {solution.nfev} evaluations, "
          f"{time.process_time() - cpu:.0f} s CPU ({solution.message})")
    for f in range(frames):
        before = 1e3 * np.linalg.norm(observed[f][held] - gt[f][held], axis=1)
        after = 1e3 * np.linalg.norm(corners[f] - gt[f][held], axis=1)
        print(f"frame {f}: corners' distance to the truth [mm]: reconstructed "
              f"{np.round(before, 2).tolist()}, fitted {np.round(after, 2).tolist()}")


if __name__ == "__main__":
    main()
