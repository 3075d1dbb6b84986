"""`ndf-sft`: monocular shape-from-template reconstruction with the Kirchhoff–Love prior.

    ndf-sft --frames F --camera C.json --template T.obj --texture X.png [--masks M]
            [--pinned P] [--gt G] --out DIR

Stages (each timed in ``result.json``): load inputs, tracking (``inverse.sft.tracking``),
baseline (``inverse.sft.baseline``; the initial guess of every frame unless ``--init previous``),
reconstruction (``inverse.sft.reconstruct``), output. Writes ``DIR/meshes/000000.obj`` … (the
template's connectivity, vertex order and UVs), ``DIR/overlay.mp4`` (the reconstructed mesh's
projected wireframe drawn over the frames) and ``DIR/result.json``; with ``--gt`` (a folder of
ground-truth meshes, template vertex order) also the metrics of ``inverse.sft.metrics``.
Input conventions: ``docs/sft.md``.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from inverse.sft.baseline import mesh_edges, reconstruct_baseline
from inverse.sft.inputs import Camera, InputError, load_inputs
from inverse.sft.metrics import evaluate_sequence
from inverse.sft.reconstruct import ReconstructionConfig, reconstruct
from inverse.sft.tracking import track_sequence
from taichi_ndf.cli.common import (
    ArgumentParser,
    add_runtime_options,
    finite_float,
    interruptible,
    machine_description,
    start,
)
from taichi_ndf.io import OutputDir, read_mesh, write_obj
from taichi_ndf.render import write_video

OVERLAY_COLOUR = (60, 230, 60)  # BGR


def build_parser() -> argparse.ArgumentParser:
    p = ArgumentParser(prog="ndf-sft", description=__doc__.split("\n")[0].strip("`"))
    p.add_argument("--frames", type=Path, required=True, help="video file or folder of images")
    p.add_argument("--camera", type=Path, required=True, help="camera JSON (docs/sft.md)")
    p.add_argument("--template", type=Path, required=True,
                   help="template mesh with UVs, camera coordinates of frame 0 (OBJ or PLY)")
    p.add_argument("--texture", type=Path, required=True, help="texture image of the template")
    p.add_argument("--masks", type=Path, help="folder of per-frame masks (white = sheet)")
    p.add_argument("--pinned", type=Path, help="pinned vertex indices (JSON list or text)")
    p.add_argument("--gt", type=Path, help="folder of ground-truth meshes, one per frame in name "
                   "order, for metrics")
    p.add_argument("--out", type=Path, required=True, help="output directory (new or empty "
                   "unless --overwrite)")
    p.add_argument("--physics-weight", type=finite_float,
                   default=ReconstructionConfig.physics_weight,
                   help="w_phys of the Kirchhoff–Love prior; 0 switches it off "
                   "(default: %(default)s)")
    p.add_argument("--steps", type=int, default=ReconstructionConfig.steps,
                   help="Adam steps per frame (default: %(default)s)")
    p.add_argument("--init", choices=("baseline", "previous"), default="baseline",
                   help="initial guess of each frame: the baseline's mesh or the previous "
                   "frame (default: %(default)s)")
    p.add_argument("--fps", type=finite_float, default=30.0, help="overlay video frame rate")
    p.add_argument("--overwrite", action="store_true",
                   help="allow writing into a non-empty output directory")
    add_runtime_options(p)
    return p


@interruptible("ndf-sft")
def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        summary = run(args)
    except (InputError, FileExistsError, ValueError, RuntimeError) as err:
        print(f"ndf-sft: error: {err}", file=sys.stderr)
        return 2
    timings = summary["timings"]
    print(f"reconstructed {summary['frames']} frames; seconds per frame: " + ", ".join(
        f"{name} {value:.2f}" for name, value in timings["per_frame"].items()))
    if "metrics" in summary:
        m = summary["metrics"]
        print(f"e3D {m['e3d']:.4f}, chamfer x1e4 {m['chamfer_x1e4']:.3f}, normal error "
              f"{m['normal_deg']:.2f} deg, reprojection {m['reprojection_px']:.3f} px")
    print(f"outputs in {args.out}")
    return 0


def run(args: argparse.Namespace) -> dict:
    """The whole pipeline; returns the summary written to result.json."""
    seconds: dict[str, float] = {}
    clock = time.perf_counter()
    config = ReconstructionConfig(physics_weight=args.physics_weight, steps=args.steps,
                                  seed=args.seed)  # the options are checked before any work
    if not 0 < args.fps < math.inf:
        raise InputError(f"--fps must be finite and positive, got {args.fps}")
    inputs = load_inputs(frames=args.frames, camera=args.camera, template=args.template,
                         texture=args.texture, masks=args.masks, pinned=args.pinned)
    gt = _read_ground_truth(args.gt, len(inputs.frames)) if args.gt is not None else None
    out = OutputDir(args.out, overwrite=args.overwrite)
    runtime = start(args)
    seconds["load"] = time.perf_counter() - clock

    clock = time.perf_counter()
    correspondences, _ = track_sequence(inputs.frames, inputs.template, inputs.texture,
                                        inputs.camera, masks=inputs.masks)
    seconds["tracking"] = time.perf_counter() - clock

    initial = None
    if args.init == "baseline":
        clock = time.perf_counter()
        initial = reconstruct_baseline(inputs.template, inputs.camera, correspondences,
                                       pinned=inputs.pinned).vertices
        seconds["baseline"] = time.perf_counter() - clock

    clock = time.perf_counter()
    result = reconstruct(inputs.template, inputs.camera, correspondences, masks=inputs.masks,
                         pinned=inputs.pinned, initial=initial, config=config)
    seconds["reconstruction"] = time.perf_counter() - clock

    clock = time.perf_counter()
    template = inputs.template
    for i, vertices in enumerate(result.vertices):
        write_obj(out.file(f"meshes/{i:06d}.obj"), vertices, template.faces, uvs=template.uvs)
    write_video(out.file("overlay.mp4"),
                overlay_frames(inputs.frames, result.vertices, template.faces, inputs.camera),
                args.fps)
    seconds["output"] = time.perf_counter() - clock

    n = len(inputs.frames)
    summary = {
        "frames": n,
        "vertices": len(template.vertices),
        "inputs": {name: None if getattr(args, name) is None else str(getattr(args, name))
                   for name in ("frames", "camera", "template", "texture", "masks", "pinned")},
        "init": args.init,
        "config": dataclasses.asdict(config),
        "correspondences_per_frame": [len(c) for c in correspondences],
        "final_loss_terms": result.losses,
        "timings": {
            "total": seconds,
            "per_frame": {name: value / n for name, value in seconds.items()},
            "reconstruction_per_frame": result.seconds,
        },
        "machine": machine_description(runtime),
        "threads": args.threads,
    }
    if gt is not None:
        metrics = evaluate_sequence(result.vertices, gt, template.faces, camera=inputs.camera)
        summary["metrics"] = metrics.summary()
        summary["metrics_per_frame"] = metrics.per_frame()
    out.write_json("result.json", summary)
    return summary


def overlay_frames(
    frames: list[np.ndarray], vertices: list[np.ndarray], faces: np.ndarray, camera: Camera
) -> list[np.ndarray]:
    """Frames (BGR uint8) with the projected wireframe of each frame's mesh drawn over them."""
    edges = mesh_edges(faces)
    shift = 4  # sub-pixel line positions, 1/16 px
    out = []
    for frame, v in zip(frames, vertices, strict=True):
        image = frame.copy()
        # Pixel centres are at integers (docs/sft.md), as in OpenCV's drawing functions.
        pixels = np.rint(camera.project(v) * (1 << shift)).astype(np.int32)
        lines = pixels[edges]
        cv2.polylines(image, list(lines), False, OVERLAY_COLOUR, 1, cv2.LINE_AA, shift)
        out.append(image)
    return out


def _read_ground_truth(folder: Path, frames: int) -> list[np.ndarray]:
    if not folder.is_dir():
        raise InputError(f"ground truth {folder}: expected a folder of meshes")
    files = [p for p in sorted(folder.iterdir()) if p.suffix.lower() in (".obj", ".ply")]
    if len(files) != frames:
        raise InputError(f"ground truth {folder}: {len(files)} meshes for {frames} frames")
    return [read_mesh(p).vertices for p in files]


if __name__ == "__main__":
    sys.exit(main())
