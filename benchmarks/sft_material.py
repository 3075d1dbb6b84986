"""Material from video on a synthetic hanging sheet: truth vs estimate, per noise draw.

    python benchmarks/sft_material.py --work DIR [--seeds 0 1 2] [--frames 12] [--used 6]
        [--cells 24 24] [--bending-length 0.02] [--truth-spans 12 12] [--source sft|gt]
        [--vertex-noise 0.001] [--rest template|flat|frame0]
        [--degree 4] [--spans 7 7] [--membrane-stiffness D] [--observed 3d|ray]
        [--noise isotropic|ray] [--sheet-size-from template|equilibrium]
        [--frame-weights equal|misfit]

For each seed: a hanging-sheet sequence (`inverse.sft.hanging_synth`: a 0.3 m sheet of the
given template cells and true bending length, ρ_A = 0.2 kg/m², D = 100 N/m, solved on
--truth-spans quartic spans; the seed sets texture, background and image noise) is rendered,
then the material is estimated with the estimate's defaults (`MaterialFromVideoConfig`) unless
--degree / --spans / --membrane-stiffness set them, at the stated ρ_A = 0.2:
- `--source sft`: the command a user runs, `ndf-sft ... --estimate-material --held-corners A B
  --areal-density 0.2` on the rendered frames (default spline prior); the template is frame
  0's true shape (hanging, stretched by gravity), so the flat size is the template's
  (`--rest template`) unless `--rest flat` states the sheet's true size (`--sheet-size`);
- `--source gt`: the true meshes with Gaussian vertex noise (`--vertex-noise σ`, 0: noise-free;
  `--noise ray`: along each vertex's camera ray only, a monocular depth error)
  given to `material_from_video.estimate_material`, the flat size from the flat template
  (`--rest flat`, default here), frame 0's truth (`--rest template`) or the noisy frame 0
  (`--rest frame0`).
Prints one row per seed: estimated c and B with standard error, error against the truth,
|error| / s.e. (in brackets: over the s.e. with the Fisher error as its noise part, before
the cluster-robust error over the frames), D, rms misfit, CPU and wall seconds of the
estimate (the estimate alone, not the reconstruction). Figures: benchmarks/RESULTS.md
("Material from video").
"""

from __future__ import annotations

import argparse
import json
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


def truth_config(seed: int, args) -> HangingConfig:
    return HangingConfig(frames=args.frames, seed=seed, cells=tuple(args.cells),
                         bending_length=args.bending_length, spans=tuple(args.truth_spans),
                         degradations=Degradations(jpeg_quality=80))


def material_options(args) -> dict:
    """The estimate's settings that the command line sets (the rest: the defaults)."""
    given = {"spans": args.spans and tuple(args.spans), "degree": args.degree,
             "membrane_stiffness": args.membrane_stiffness, "observed": args.observed,
             "sheet_size_from": args.sheet_size_from, "frame_weights": args.frame_weights}
    return {k: v for k, v in given.items() if v is not None}


def by_ndf_sft(data: Path, truth: HangingConfig, held, args, out: Path) -> dict:
    """`ndf-sft --estimate-material` on the rendered frames; its result's material."""
    extra = ["--material-frames", str(args.used)]
    if args.spans:
        extra += ["--material-spans", *map(str, args.spans)]
    if args.degree:
        extra += ["--material-degree", str(args.degree)]
    if args.membrane_stiffness:
        extra += ["--membrane-stiffness", str(args.membrane_stiffness)]
    if args.rest == "flat":
        extra += ["--sheet-size", *map(str, truth.sheet_size)]
    if args.observed:
        extra += ["--material-observed", args.observed]
    if args.sheet_size_from:
        extra += ["--sheet-size-from", args.sheet_size_from]
    if args.frame_weights:
        extra += ["--material-frame-weights", args.frame_weights]
    code = ndf_sft(["--frames", str(data / "frames"), "--camera", str(data / "camera.json"),
                    "--template", str(data / "template.obj"), "--texture",
                    str(data / "texture.png"), "--masks", str(data / "masks"), "--gt",
                    str(data / "gt"), "--out", str(out), "--overwrite", "--estimate-material",
                    "--held-corners", *map(str, held), "--areal-density",
                    str(truth.areal_density), *extra])
    if code != 0:
        raise SystemExit(f"ndf-sft failed with exit code {code}")
    return json.loads((out / "result.json").read_text())["material"]


def suffix(args) -> str:
    """Output names' tail: the observed components and the noise's kind when set."""
    return (f"_{args.observed}" if args.observed else "") + \
        (f"_{args.sheet_size_from}" if args.sheet_size_from else "") + \
        (f"_w{args.frame_weights}" if args.frame_weights else "") + \
        (f"_{args.noise}" if args.source == "gt" and args.noise != "isotropic" else "")


def noise_direction(points: np.ndarray, rng, kind: str) -> np.ndarray:
    """Unit-σ noise per vertex: isotropic (σ per coordinate) or along each vertex's camera ray
    (σ along the ray from the camera centre, the origin: a monocular depth error)."""
    if kind == "isotropic":
        return rng.standard_normal(points.shape)
    ray = points / np.linalg.norm(points, axis=1, keepdims=True)
    return ray * rng.standard_normal((len(points), 1))


def one(seed: int, args) -> dict:
    truth = truth_config(seed, args)
    tag = f"c{args.bending_length:g}_cells{args.cells[0]}x{args.cells[1]}_f{args.frames}_{seed}"
    data = args.work / f"hang_{tag}"
    if not (data / "hanging.json").exists():
        write(truth, data, overwrite=True)
    grid, _, held = template_grid(truth)
    if args.source == "sft":
        out = args.work / f"sft_{tag}_{args.rest}{suffix(args)}"
        material = by_ndf_sft(data, truth, held, args, out)
    else:
        rng = np.random.default_rng(seed)
        truth_meshes = meshes(data / "gt")
        vertices = [v + args.vertex_noise * noise_direction(v, rng, args.noise)
                    for v in truth_meshes]
        config = MaterialFromVideoConfig(areal_density=truth.areal_density, frames=args.used,
                                         **material_options(args))
        rest = {"flat": np.column_stack([grid.xi, np.zeros(len(grid.xi))]),
                "template": truth_meshes[0], "frame0": None}[args.rest]
        material = estimate_material(vertices, grid.faces, held, config, rest=rest)
    c, b, d = (material["bending_length"], material["bending_stiffness"],
               material["membrane_stiffness"])
    row = {"seed": seed, "c": c and c["value"], "c_se": c and c["standard_error"],
           "B": b["value"], "B_se": b["standard_error"],
           "B_true": truth.material.bending_stiffness, "D": d["value"],
           "D_se": d["standard_error"],
           "rms_mm": 1e3 * material["goodness_of_fit"]["rms_m"],
           "cpu_s": material["cpu_seconds"], "wall_s": material["seconds"],
           "grids": material["grids"]}
    if b["value"] is not None:
        row["B_error"] = b["value"] / row["B_true"] - 1
        row["z"] = abs(b["value"] - row["B_true"]) / b["standard_error"]
        parts = b.get("standard_error_parts")
        if parts:  # the s.e. before the cluster-robust part: Fisher and grids in quadrature
            row["z_fisher"] = abs(b["value"] - row["B_true"]) / np.hypot(
                parts["fisher"], parts["discretisation"])
    (args.work / f"material_{args.source}_{tag}_{args.rest}{suffix(args)}.json").write_text(
        json.dumps(material, indent=2))
    return row


def line(r: dict) -> str:
    d = "" if r["D"] is None else (f"{r['D']:.4g}" if r["D_se"] is None else
                                   f"{r['D']:.4g} ± {r['D_se']:.2g}")
    grids = " / ".join(f"{g['bending_stiffness']:.4g}" for g in r["grids"])
    tail = f"{d} | {grids} | {r['rms_mm']:.2f} | {r['cpu_s']:.0f} | {r['wall_s']:.0f} |"
    if r["B"] is None:
        return f"| {r['seed']} | undetermined | | | | {tail}"
    z_fisher = f" ({r['z_fisher']:.2f})" if "z_fisher" in r else ""
    return (f"| {r['seed']} | {100 * r['c']:.3f} ± {100 * r['c_se']:.3f} | {r['B']:.4g} ± "
            f"{r['B_se']:.2g} | {100 * r['B_error']:+.2f} % | {r['z']:.2f}{z_fisher} | {tail}")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--work", type=Path, required=True)
    p.add_argument("--seeds", type=int, nargs="+", default=[0])
    p.add_argument("--frames", type=int, default=12)
    p.add_argument("--used", type=int, default=6, help="frames used by the estimate (0: all)")
    p.add_argument("--cells", type=int, nargs=2, default=(24, 24), help="template cells")
    p.add_argument("--bending-length", type=float, default=0.02, help="true c [m]")
    p.add_argument("--truth-spans", type=int, nargs=2, default=(12, 12),
                   help="the truth's quartic spline grid")
    p.add_argument("--spans", type=int, nargs=2, help="estimate's coarse grid (default: the "
                   "estimate's)")
    p.add_argument("--degree", type=int, choices=(3, 4), help="(default: the estimate's)")
    p.add_argument("--membrane-stiffness", type=float,
                   help="hold D [N/m] (default: estimated beside B)")
    p.add_argument("--rest", choices=("template", "flat", "frame0"),
                   help="the flat sheet's size (module docstring; default: gt flat, "
                   "sft template)")
    p.add_argument("--observed", choices=("3d", "ray"),
                   help="what the fit compares of each vertex (default: the estimate's)")
    p.add_argument("--sheet-size-from", choices=("template", "equilibrium"),
                   help="the flat size without a stated one (default: the estimate's)")
    p.add_argument("--frame-weights", choices=("equal", "misfit"),
                   help="how the frames count in the fit (default: the estimate's)")
    p.add_argument("--noise", choices=("isotropic", "ray"), default="isotropic",
                   help="gt: vertex noise isotropic (σ per coordinate) or along the camera "
                   "rays (σ along each ray)")
    p.add_argument("--source", choices=("sft", "gt"), default="sft")
    p.add_argument("--vertex-noise", type=float, default=1e-3, help="gt: σ per coordinate [m]")
    args = p.parse_args()
    args.rest = args.rest or ("flat" if args.source == "gt" else "template")
    if args.source == "sft" and args.rest == "frame0":
        p.error("--source sft: the flat size is the template's or the stated (flat) one")
    args.work.mkdir(parents=True, exist_ok=True)
    torch.set_num_threads(1)
    taichi_ndf.init(arch="cpu", precision="f64")
    print(f"source {args.source}, rest {args.rest}, observed {args.observed or 'default'}, "
          f"noise {args.noise}, truth c = {args.bending_length} m, cells "
          f"{tuple(args.cells)}, {args.frames} frames, used {args.used}, settings "
          f"{material_options(args) or 'the defaults'}")
    print("| seed | c [cm] ± s.e. | B [N·m] ± s.e. | B error | abs(err)/s.e. (Fisher) | D [N/m] "
          "| B per grid | rms misfit [mm] | CPU s | wall s |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for seed in args.seeds:
        print(line(one(seed, args)), flush=True)


if __name__ == "__main__":
    main()
