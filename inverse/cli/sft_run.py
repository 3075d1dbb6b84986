"""The work of ``ndf-sft`` (``inverse.cli.sft``): inputs, tracking, baseline, reconstruction
by the chosen method and field, outputs (meshes, overlay video, result.json)."""

from __future__ import annotations

import argparse
import dataclasses
import math
import time

import cv2
import numpy as np

from inverse.cli.sft_inputs import (
    ground_truth_metrics,
    load_run_inputs,
)
from inverse.cli.sft_material import check_held_corners, material_config
from inverse.cli.sft_options import BORDER_OPTIONS
from inverse.material.field_types import INVERSE_FIELD_TYPES
from inverse.sft.baseline import mesh_edges, reconstruct_baseline
from inverse.sft.correspondences import FrameCorrespondences, track_gaps
from inverse.sft.crop import cropped_to_sheet
from inverse.sft.flow import DenseFlow
from inverse.sft.frame_fits import reconstruct_sequence
from inverse.sft.guided import GuidedSearch
from inverse.sft.inputs import Camera, InputError, Template, mean_edge_length
from inverse.sft.material_from_video import estimate_material
from inverse.sft.photometric import photometric_evidence
from inverse.sft.settings import ReconstructionConfig, SplinePriorConfig
from inverse.sft.tracking import track_sequence
from taichi_ndf.cli.common import machine_description, start
from taichi_ndf.io import OutputDir, write_obj
from taichi_ndf.render import write_video

OVERLAY_COLOUR = (60, 230, 60)  # BGR


def run(args: argparse.Namespace) -> dict:
    """The whole pipeline; returns the summary written to result.json."""
    seconds: dict[str, float] = {}
    clock = time.perf_counter()
    config = method_config(args)  # the options are checked before any work
    if not 0 < args.fps < math.inf:
        raise InputError(f"--fps must be finite and positive, got {args.fps}")
    material = material_config(args)
    loaded = load_run_inputs(args)
    inputs = loaded.inputs
    held = None if material is None else check_held_corners(args, inputs.template,
                                                             inputs.pinned)
    for line in loaded.conventions:
        print(f"capture: {line}")
    out = OutputDir(args.out, overwrite=args.overwrite)
    runtime = start(args)
    seconds["load"] = time.perf_counter() - clock

    # Tracking and fit on the part of the frames where the sheet is (exact, faster).
    work = cropped_to_sheet(inputs)
    clock = time.perf_counter()
    correspondences, _ = track_sequence(work.frames, work.template, work.texture,
                                        work.camera, masks=work.masks)
    seconds["tracking"] = time.perf_counter() - clock

    baseline = None
    field = INVERSE_FIELD_TYPES[args.field]
    if args.method == "baseline" or (field.initial_guesses and args.init == "baseline"):
        clock = time.perf_counter()
        baseline = reconstruct_baseline(work.template, work.camera, correspondences,
                                        pinned=work.pinned)
        seconds["baseline"] = time.perf_counter() - clock

    clock = time.perf_counter()
    guided = None
    if args.method == "baseline":
        vertices, losses, per_frame = baseline.vertices, None, baseline.seconds
    else:
        if args.guided:
            guided = GuidedSearch(work.frames, work.camera, work.template, work.texture,
                                  masks=work.masks)
        result = reconstruct_sequence(
            work.template, work.camera, correspondences, config, masks=work.masks,
            pinned=work.pinned, initial=None if baseline is None else baseline.vertices,
            flow=None if not args.flow else DenseFlow(work.frames, work.camera,
                                                      work.template.faces, masks=work.masks),
            guided=guided, photometric=photometric_evidence(
                config, work.frames, work.camera, work.template, work.texture,
                masks=work.masks))
        vertices, losses, per_frame = result.vertices, result.losses, result.seconds
    if args.method != "baseline":
        seconds["reconstruction"] = time.perf_counter() - clock

    clock = time.perf_counter()
    template = inputs.template
    for i, frame_vertices in enumerate(vertices):
        write_obj(out.file(f"meshes/{i:06d}.obj"), frame_vertices, template.faces,
                  uvs=template.uvs)
    write_video(out.file("overlay.mp4"),
                overlay_frames(inputs.frames, vertices, template.faces, inputs.camera),
                args.fps)
    seconds["output"] = time.perf_counter() - clock

    n = len(inputs.frames)
    summary = {
        "frames": n,
        "vertices": len(template.vertices),
        "inputs": {name: None if getattr(args, name) is None else str(getattr(args, name))
                   for name in ("capture", "frames", "camera", "template", "texture", "masks",
                                "pinned")},
        "conventions": list(loaded.conventions),
        "pinned": None if inputs.pinned is None else inputs.pinned.tolist(),
        "method": args.method,
        "field": None if args.method == "baseline" else args.field,
        "init": args.init if field.initial_guesses and args.method != "baseline" else None,
        "config": None if config is None else dataclasses.asdict(config),
        "correspondences_per_frame": [len(c) for c in correspondences],
        "guided": None if guided is None else {str(t): v for t, v in guided.stats.items()},
        "confidence": track_coverage(work.template, correspondences),
        "final_loss_terms": losses,
        "timings": {
            "total": seconds,
            "per_frame": {name: value / n for name, value in seconds.items()},
            "method_per_frame": per_frame,
        },
        "machine": machine_description(runtime),
        "threads": args.threads,
    }
    if loaded.gt is not None:
        summary["metrics"], summary["metrics_per_frame"] = ground_truth_metrics(
            loaded, vertices, template.faces, inputs.camera)
    if material is not None:
        clock = time.perf_counter()
        summary["material"] = estimate_material(vertices, template.faces, held, material,
                                                rest=template.vertices)
        seconds["material"] = time.perf_counter() - clock
        summary["timings"]["per_frame"]["material"] = seconds["material"] / n
    out.write_json("result.json", summary)
    return summary


def track_coverage(template: Template, correspondences: list[FrameCorrespondences], *,
                   reach: float = SplinePriorConfig.span_edges) -> dict:
    """The per-frame confidence of result.json: per frame the vertices farther than `reach`
    template mean edge lengths (one knot span of the spline field) from every tracked point,
    whose shape is the prior's continuation rather than measured, and the largest such
    distance; the frames that have any."""
    mean_edge = mean_edge_length(template.vertices, template.faces)
    gaps = [track_gaps(template.vertices, template.faces, c, mean_edge)
            for c in correspondences]
    unobserved = [int((g > reach).sum()) for g in gaps]
    return {"reach_mean_edges": reach,
            "unobserved_vertices": unobserved,
            "largest_gap_mean_edges": [float(g.max()) for g in gaps],
            "frames_with_unobserved_parts": [i for i, n in enumerate(unobserved) if n]}


def method_config(args: argparse.Namespace) -> SplinePriorConfig | ReconstructionConfig | None:
    """The reconstruction settings of the chosen method and field (None for the baseline);
    raises ValueError for options that do not fit them."""
    if args.method == "baseline":
        return None
    field = INVERSE_FIELD_TYPES[args.field]
    if field.float64_only and args.precision != "f64":
        raise ValueError(f"--field {args.field} needs --precision f64 (its Hessian blocks are "
                         "central differences)")
    kind = field.frame_settings
    weight = kind.physics_weight if args.physics_weight is None else args.physics_weight
    if args.method == "no-prior":
        weight = 0.0
    options = {"steps": args.iterations, "seed": args.seed}  # where the settings have them
    if args.photometric_weight is not None:
        if not field.photometric:
            takes = [n for n, f in INVERSE_FIELD_TYPES.items() if f.photometric]
            raise ValueError(f"--photometric-weight is an option of --field "
                             f"{' or '.join(takes)}")
        options["photometric_weight"] = args.photometric_weight
    names = {f.name for f in dataclasses.fields(kind)}
    # given only where the settings have them
    for option in ("silhouette_border_gap", "extrapolate", "silhouette_allowance",
                   "allowance_reach", "frame_interval") + BORDER_OPTIONS:
        if getattr(args, option) is None or getattr(args, option) is False:
            continue  # not given (0 is given: e.g. --allowance-fade 0 is refused)
        if option not in names:
            raise ValueError(f"--{option.replace('_', '-')} is not an option of "
                             f"--field {args.field}")
        options[option] = getattr(args, option)
    return kind(physics_weight=weight, **{k: v for k, v in options.items() if k in names})


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
