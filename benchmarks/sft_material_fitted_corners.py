"""Material from video, the held corners held vs fitted (the estimate's `corners`), side by side.

    python benchmarks/sft_material_fitted_corners.py --work W --tag c0.05_cells12x12_f3
        [--source sft|gt] [--sft-suffix _template_wmisfit] [--vertex-noise 0.001]
        [--seeds 0 1 2] [--corners held fitted] [--frames 0]

Runs `material_from_video.estimate_material` (the library's estimate, every default but the
stated ρ_A = 0.2 and all frames used) on stored meshes of a `benchmarks/sft_material.py` work
folder W (the sequence W/hang_TAG_SEED per seed), once per `--corners` value:
- `--source sft`: `ndf-sft`'s reconstructed meshes (W/sft_TAG_SEED<suffix>/meshes, written by
  `sft_material.py --source sft`; the reconstruction is deterministic) with the template (frame
  0's true shape, W/hang_TAG_SEED/template.obj) as `rest` — what `ndf-sft --estimate-material`
  passes;
- `--source gt`: the true meshes (W/hang_TAG_SEED/gt) with isotropic Gaussian vertex noise σ
  (`--vertex-noise`, 0: noise-free) drawn as `sft_material.py` draws it (numpy
  default_rng(seed)), the flat template as `rest`.
Prints one row per run: B ± s.e., error against the truth, |error| / s.e., D, rms misfit, the
fitted corners' offsets from the reconstruction and their distance to the true corners before
and after [mm], CPU and wall seconds of the estimate (benchmarks/RESULTS.md, Material from
video).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch

import taichi_ndf
from inverse.sft.hanging_synth import HangingConfig, template_grid
from inverse.sft.material_from_video import MaterialFromVideoConfig, estimate_material
from taichi_ndf.io import read_mesh


def meshes(folder: Path) -> list[np.ndarray]:
    return [np.asarray(read_mesh(p).vertices, dtype=np.float64)
            for p in sorted(folder.glob("*.obj"))]


def truth(data: Path) -> HangingConfig:
    settings = json.loads((data / "synth.json").read_text())["config"]
    return HangingConfig(**{k: tuple(v) if isinstance(v, list) else v
                            for k, v in settings.items()
                            if k in ("frames", "sheet_size", "cells", "bending_length",
                                     "areal_density", "membrane_stiffness", "poisson_ratio",
                                     "band", "spans", "degree")})


def row(label: str, material: dict, b_true: float, gt: list[np.ndarray],
        vertices: list[np.ndarray], held) -> str:
    b = material["bending_stiffness"]
    d = material["membrane_stiffness"]
    fit = material["goodness_of_fit"]
    corners = []
    for entry in material["corners"]["frames"]:
        f = entry["frame"]
        before = 1e3 * np.linalg.norm(vertices[f][list(held)] - gt[f][list(held)], axis=1)
        if entry["fitted"]:
            after = 1e3 * np.linalg.norm(vertices[f][list(held)] + np.array(entry["offset_m"])
                                         - gt[f][list(held)], axis=1)
            se = 1e3 * np.array(entry["standard_error_m"]).max()
            corners.append(f"{f}: {before[0]:.2f}, {before[1]:.2f} -> {after[0]:.2f}, "
                           f"{after[1]:.2f} (s.e. ≤ {se:.2f})")
        else:
            corners.append(f"{f}: {before[0]:.2f}, {before[1]:.2f} held")
    if b["value"] is None:
        head = "undetermined | | "
    else:
        err = b["value"] / b_true - 1
        head = (f"{b['value']:.4g} ± {b['standard_error']:.2g} | {100 * err:+.2f} % | "
                f"{abs(b['value'] - b_true) / b['standard_error']:.2f}")
    grids = " / ".join(f"{g['bending_stiffness']:.4g}" for g in material["grids"])
    check = material["corners"].get("coarse_grid_at_fitted_corners")
    if check:  # the coarse grid refitted with the corners where the fine grid put them
        grids += f" (coarse at the fitted corners {check['values'][0]:.4g})"
    dd = "" if d["value"] is None else f"{d['value']:.4g}"
    return (f"| {label} | {head} | {dd} | {grids} | {1e3 * fit['rms_m']:.2f} | "
            f"{'; '.join(corners)} | {material['cpu_seconds']:.0f} | "
            f"{material['seconds']:.0f} |")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--work", type=Path, required=True)
    p.add_argument("--tag", required=True, help="the sequences: W/hang_TAG_SEED")
    p.add_argument("--source", choices=("sft", "gt"), default="sft")
    p.add_argument("--sft-suffix", default="_template_wmisfit",
                   help="the reconstruction: W/sft_TAG_SEED<suffix>/meshes")
    p.add_argument("--vertex-noise", type=float, default=0.0)
    p.add_argument("--seeds", type=int, nargs="+", default=[0])
    p.add_argument("--corners", nargs="+", choices=("held", "fitted"),
                   default=["held", "fitted"])
    p.add_argument("--frames", type=int, default=0, help="frames used (0: all)")
    args = p.parse_args()
    torch.set_num_threads(1)
    taichi_ndf.init(arch="cpu", precision="f64")
    print("| run | B [N·m] ± s.e. | B error | abs(err)/s.e. | D [N/m] | B per grid | "
          "rms misfit [mm] | corners' distance to the truth [mm], frame: reconstructed -> "
          "fitted | CPU s | wall s |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for seed in args.seeds:
        data = args.work / f"hang_{args.tag}_{seed}"
        config = truth(data)
        grid, _, held = template_grid(config)
        gt = meshes(data / "gt")
        b_true = config.material.bending_stiffness
        if args.source == "sft":
            vertices = meshes(args.work / f"sft_{args.tag}_{seed}{args.sft_suffix}" / "meshes")
            rest = np.asarray(read_mesh(data / "template.obj").vertices, dtype=np.float64)
        else:
            rng = np.random.default_rng(seed)
            vertices = [v + args.vertex_noise * rng.standard_normal(v.shape) for v in gt]
            rest = np.column_stack([grid.xi, np.zeros(len(grid.xi))])
        for corners in args.corners:
            estimate = MaterialFromVideoConfig(areal_density=config.areal_density,
                                               frames=args.frames, corners=corners)
            material = estimate_material(vertices, grid.faces, held, estimate, rest=rest)
            label = f"{args.source} {args.tag}_{seed}, σ {args.vertex_noise:g} m, {corners}"
            print(row(label, material, b_true, gt, vertices, held), flush=True)
            name = f"fitted_corners_{args.source}_{args.tag}_{seed}_{args.vertex_noise:g}_" \
                   f"{corners}.json"
            (args.work / name).write_text(json.dumps(material, indent=2))

if __name__ == "__main__":
    main()
