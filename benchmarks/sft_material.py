"""Material from video on the synthetic hanging sheet: truth vs estimate, per noise draw.

    python benchmarks/sft_material.py --work DIR [--seeds 0 1 2] [--frames 12] [--source sft]
        [--degree 4] [--spans 6 6] [--rest flat|frame0] [--estimate-membrane]

For each seed: a hanging-sheet sequence (`inverse.sft.hanging_synth`, true bending length
2 cm, ρ_A = 0.2 kg/m²; the seed sets texture, background and image noise) is rendered, then
either reconstructed by `ndf-sft` (default spline prior; --source sft) or taken as the ground
truth with Gaussian vertex noise (--source gt --vertex-noise σ), and the material is estimated
from the meshes (`material_from_video.estimate_material`, stated ρ_A = 0.2; the flat sheet's
size from the known flat template, `--rest flat`, or from the reconstructed frame 0, which
gravity has stretched, `--rest frame0`). Prints one row per
seed: estimated c and B with standard error, error against the truth, |error| / s.e., rms
misfit, CPU and wall seconds of the estimate. Figures: benchmarks/RESULTS.md.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch

import taichi_ndf
from inverse.cli.sft import main as ndf_sft
from inverse.sft.degradations import Degradations
from inverse.sft.hanging_synth import HangingConfig, template_grid, write
from inverse.sft.material_from_video import MaterialFromVideoConfig, estimate_material
from taichi_ndf.io import read_mesh


def meshes(folder: Path) -> list[np.ndarray]:
    return [np.asarray(read_mesh(p).vertices, dtype=np.float64)
            for p in sorted(folder.glob("*.obj"))]


def one(seed: int, args) -> dict:
    truth = HangingConfig(frames=args.frames, seed=seed, degradations=Degradations(jpeg_quality=80))
    data = args.work / f"hang_{seed}"
    if not (data / "hanging.json").exists():
        write(truth, data, overwrite=True)
    if args.source == "sft":
        out = args.work / f"sft_{seed}"
        if not (out / "result.json").exists():
            ndf_sft(["--frames", str(data / "frames"), "--camera", str(data / "camera.json"),
                     "--template", str(data / "template.obj"), "--texture",
                     str(data / "texture.png"), "--masks", str(data / "masks"), "--gt",
                     str(data / "gt"), "--out", str(out), "--overwrite"])
        vertices = meshes(out / "meshes")
    else:
        rng = np.random.default_rng(seed)
        vertices = [v + args.vertex_noise * rng.standard_normal(v.shape)
                    for v in meshes(data / "gt")]
    grid, _, held = template_grid(truth)
    config = MaterialFromVideoConfig(areal_density=truth.areal_density, frames=args.used,
                                     spans=tuple(args.spans), degree=args.degree,
                                     estimate_membrane=args.estimate_membrane)
    rest = np.column_stack([grid.xi, np.zeros(len(grid.xi))]) if args.rest == "flat" else None
    cpu, wall = time.process_time(), time.perf_counter()
    material = estimate_material(vertices, grid.faces, held, config, rest=rest)
    cpu, wall = time.process_time() - cpu, time.perf_counter() - wall
    c, b = material["bending_length"], material["bending_stiffness"]
    row = {"seed": seed, "c": c and c["value"], "c_se": c and c["standard_error"],
           "B": b["value"], "B_se": b["standard_error"],
           "B_true": truth.material.bending_stiffness,
           "rms_mm": 1e3 * material["goodness_of_fit"]["rms_m"], "cpu_s": cpu, "wall_s": wall}
    if b["value"] is not None:
        row["B_error"] = b["value"] / row["B_true"] - 1
        row["z"] = abs(b["value"] - row["B_true"]) / b["standard_error"]
    (args.work / f"material_{args.source}_{seed}.json").write_text(json.dumps(material,
                                                                             indent=2))
    return row


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--work", type=Path, required=True)
    p.add_argument("--seeds", type=int, nargs="+", default=[0])
    p.add_argument("--frames", type=int, default=12)
    p.add_argument("--used", type=int, default=6, help="frames used by the estimate")
    p.add_argument("--spans", type=int, nargs=2, default=(6, 6))
    p.add_argument("--degree", type=int, choices=(3, 4), default=4)
    p.add_argument("--rest", choices=("flat", "frame0"), default="flat",
                   help="the flat sheet's size: the flat template's or the reconstructed frame 0's")
    p.add_argument("--estimate-membrane", action="store_true", help="fit D beside B")
    p.add_argument("--source", choices=("sft", "gt"), default="sft")
    p.add_argument("--vertex-noise", type=float, default=1e-3, help="gt: σ per coordinate [m]")
    args = p.parse_args()
    torch.set_num_threads(1)
    taichi_ndf.init(arch="cpu", precision="f64")
    print("| seed | c [cm] ± s.e. | B [N·m] ± s.e. | B error | abs(err)/s.e. | rms misfit [mm] "
          "| CPU s | wall s |")
    print("|---|---|---|---|---|---|---|---|")
    for seed in args.seeds:
        r = one(seed, args)
        if r["B"] is None:
            print(f"| {seed} | undetermined | | | | {r['rms_mm']:.2f} | {r['cpu_s']:.0f} | "
                  f"{r['wall_s']:.0f} |", flush=True)
            continue
        print(f"| {seed} | {100 * r['c']:.3f} ± {100 * r['c_se']:.3f} | {r['B']:.4g} ± "
              f"{r['B_se']:.2g} | {100 * r['B_error']:+.2f} % | {r['z']:.2f} | "
              f"{r['rms_mm']:.2f} | {r['cpu_s']:.0f} | {r['wall_s']:.0f} |", flush=True)


if __name__ == "__main__":
    main()
