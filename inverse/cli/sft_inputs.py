"""The input side of ``ndf-sft``: loading and checking the inputs (or a capture folder,
``inverse.sft.capture``) before any expensive work, and the ground truth (meshes or point
clouds) with its metrics. Its options are ``inverse.cli.sft_options`` (light, for --help)."""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from inverse.cli.sft_options import CONTRACT_OPTIONS
from inverse.sft.capture import load_capture
from inverse.sft.chamfer import (
    cloud_files,
    evaluate_against_clouds,
    is_cloud_folder,
    load_point_cloud,
)
from inverse.sft.input_checks import (
    check_cloud_in_camera_frame,
    check_template_in_view,
    check_uvs_match_texture,
)
from inverse.sft.inputs import (
    Camera,
    InputError,
    SftInputs,
    list_images,
    load_inputs,
    read_pinned,
)
from inverse.sft.limits import check_frames_memory, check_texture_memory
from inverse.sft.metrics import evaluate_sequence
from taichi_ndf.io import read_mesh


@dataclass(frozen=True)
class RunInputs:
    """Checked inputs of a run, the ground truth (meshes or clouds, per frame) or None, and
    the conventions the capture importer applied (empty for the contract's files)."""

    inputs: SftInputs
    gt: list[np.ndarray] | None
    gt_kind: str | None  # "meshes" or "clouds"
    gt_folder: Path | None
    conventions: tuple[str, ...]


def load_run_inputs(args: argparse.Namespace) -> RunInputs:
    """Inputs from --capture or the contract's options; every check before expensive work.
    InputError (one line) for anything that does not fit."""
    given = [f"--{name}" for name in (*CONTRACT_OPTIONS, "masks")
             if getattr(args, name) is not None]
    if args.capture is not None:
        if given:
            raise InputError(f"--capture replaces {', '.join(given)}: give one or the other")
        pins = args.pinned
        if isinstance(pins, Path):
            pins = read_pinned(pins).tolist()
        capture = load_capture(args.capture, pinned=pins)
        inputs, conventions = capture.inputs, capture.conventions
        gt_folder = args.gt if args.gt is not None else capture.ground_truth
    else:
        missing = [f"--{name}" for name in CONTRACT_OPTIONS if getattr(args, name) is None]
        if missing:
            raise InputError(f"missing {', '.join(missing)} (or give --capture DIR)")
        _check_sizes(args)
        inputs = load_inputs(frames=args.frames, camera=args.camera, template=args.template,
                             texture=args.texture, masks=args.masks, pinned=args.pinned)
        mask0 = None if inputs.masks is None else inputs.masks[0]
        t = inputs.template
        check_template_in_view(t.vertices, t.faces, inputs.camera, mask0,
                               what=f"template {args.template}")
        check_uvs_match_texture(t.vertices, t.faces, t.uvs, inputs.texture, inputs.frames[0],
                                inputs.camera, mask0, what=f"template {args.template} UVs")
        conventions, gt_folder = (), args.gt
    gt, kind = (None, None) if gt_folder is None else read_ground_truth(
        gt_folder, len(inputs.frames), inputs.template.vertices)
    return RunInputs(inputs=inputs, gt=gt, gt_kind=kind, gt_folder=gt_folder,
                     conventions=tuple(conventions))


def read_ground_truth(folder: Path, frames: int,
                      template: np.ndarray) -> tuple[list[np.ndarray], str]:
    """Per-frame ground truth of a folder: meshes' vertices or point clouds [m], and which
    ("meshes" or "clouds"); clouds are checked to be in the camera's frame (cloud 0 on the
    template)."""
    if not folder.is_dir():
        raise InputError(f"ground truth {folder}: expected a folder of meshes or point clouds")
    if is_cloud_folder(folder):
        files = cloud_files(folder)
        if len(files) != frames:
            raise InputError(f"ground truth {folder}: {len(files)} point clouds for {frames} "
                             "frames")
        first = load_point_cloud(files[0])
        check_cloud_in_camera_frame(template, first, what=f"point cloud {files[0]}")
        return [first] + [load_point_cloud(p) for p in files[1:]], "clouds"
    files = [p for p in sorted(folder.iterdir()) if p.suffix.lower() in (".obj", ".ply")]
    if len(files) != frames:
        raise InputError(f"ground truth {folder}: {len(files)} meshes for {frames} frames")
    return [read_mesh(p).vertices for p in files], "meshes"


def ground_truth_metrics(run: RunInputs, vertices: list[np.ndarray], faces: np.ndarray,
                         camera: Camera) -> tuple[dict, dict]:
    """Summary and per-frame metrics of the reconstruction against the run's ground truth."""
    if run.gt_kind == "clouds":
        metrics = evaluate_against_clouds(vertices, faces, run.gt)
    else:
        metrics = evaluate_sequence(vertices, run.gt, faces, camera=camera)
    summary = metrics.summary()
    summary["ground_truth"] = f"{run.gt_kind} in {run.gt_folder}"
    return summary, metrics.per_frame()


def metrics_line(m: dict) -> str:
    """One printed line of a run's metrics (meshes or clouds)."""
    if "e3d" in m:
        return (f"e3D {m['e3d']:.4f}, chamfer x1e4 {m['chamfer_x1e4']:.3f}, normal error "
                f"{m['normal_deg']:.2f} deg, reprojection {m['reprojection_px']:.3f} px")
    return (f"chamfer x1e4 (field protocol) mean {m['chamfer_x1e4']:.3f}, worst frame "
            f"{m['worst_frame']} {m['chamfer_x1e4_worst']:.3f}; largest vertex-to-cloud "
            f"distance {1000 * m['max_vertex_distance_m']:.1f} mm (frame "
            f"{m['max_vertex_distance_frame']})")


def _check_sizes(args: argparse.Namespace) -> None:
    """Textures and frames refused from their headers when they need too much memory."""
    if args.texture.is_file():
        check_texture_memory(args.texture)
    for folder, what in ((args.frames, "frames"), (args.masks, "masks")):
        if folder is not None and folder.is_dir():
            check_frames_memory(list_images(folder), what)
