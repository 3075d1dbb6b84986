"""``ndf-sft-eval``: accuracy of reconstructed meshes against ground-truth meshes or clouds.

    ndf-sft-eval --pred DIR --gt DIR [--camera C.json] [--json OUT]

Both folders hold one mesh per frame (OBJ or PLY); the prediction must keep the ground truth's
vertex order. A ground-truth folder of point clouds (``.npy`` arrays or ``.ply`` without faces,
``inverse.sft.chamfer``) is scored by the field's chamfer protocol instead: mean, worst frame
and the largest vertex-to-cloud distance. Frames are paired by their frame number, the last
group of digits of the file name (``000012.obj``, ``0012.obj`` and ``frame12.ply`` are frame
12), when every name in both folders has one and no number repeats; otherwise by identical file
names. Prints how it paired them, the means over frames and the evaluation protocol; ``--json``
also writes per-frame values and the pairs. Meshes and clouds are in camera coordinates (world
coordinates when the camera JSON has extrinsics); the camera adds the reprojection error.
The metrics (torch) are imported once the command line is read: --help stays light.
"""

from __future__ import annotations

import argparse
import json
import logging
import re
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from inverse.sft.errors import InputError
from taichi_ndf.cli.common import ArgumentParser, description, interruptible
from taichi_ndf.io import atomic_path, read_mesh

MESH_SUFFIXES = (".obj", ".ply")


def mesh_files(folder: Path, suffixes: tuple[str, ...] = MESH_SUFFIXES,
               what: str = "meshes") -> dict[str, Path]:
    """Mesh (or other) files of a folder by file stem."""
    if not folder.is_dir():
        raise InputError(f"{folder}: missing folder")
    files = {p.stem: p for p in folder.iterdir() if p.suffix.lower() in suffixes}
    if not files:
        raise InputError(f"{folder}: contains no {what} {suffixes}")
    return files


def frame_number(stem: str) -> int | None:
    """The frame number of a file stem: its last group of digits, or None."""
    digits = re.findall(r"\d+", stem)
    return int(digits[-1]) if digits else None


def _by_number(files: dict[str, Path]) -> dict[int, Path] | None:
    numbers = {frame_number(stem): path for stem, path in files.items()}
    if None in numbers or len(numbers) != len(files):
        return None
    return numbers


def _listing(keys: list) -> str:
    return f"{keys[:5]}{'…' if len(keys) > 5 else ''}"


def paired_meshes(pred_dir: Path, gt_dir: Path, *,
                  clouds: bool = False) -> tuple[list[tuple[str, Path, Path]], str]:
    """(ground-truth name, prediction, ground truth) for every frame in frame order, and how
    they were paired: "frame number" or "file name" (module docstring). With `clouds` the
    ground truth is point clouds (.npy / .ply)."""
    from inverse.sft.chamfer import CLOUD_SUFFIXES

    pred = mesh_files(pred_dir)
    gt = mesh_files(gt_dir, CLOUD_SUFFIXES, "point clouds") if clouds else mesh_files(gt_dir)
    pred_numbers, gt_numbers = _by_number(pred), _by_number(gt)
    if pred_numbers is not None and gt_numbers is not None:
        pred, gt, how = pred_numbers, gt_numbers, "frame number"
    else:
        how = "file name"
    missing = sorted(gt.keys() - pred.keys())
    extra = sorted(pred.keys() - gt.keys())
    if missing or extra:
        raise InputError(
            f"frames differ (paired by {how}): missing predictions {_listing(missing)}, "
            f"predictions without ground truth {_listing(extra)}")
    return [(gt[key].stem, pred[key], gt[key]) for key in sorted(gt)], how


def build_parser() -> argparse.ArgumentParser:
    parser = ArgumentParser(
        prog="ndf-sft-eval",
        description=description(__doc__),
    )
    parser.add_argument("--pred", required=True, type=Path, help="folder of predicted meshes")
    parser.add_argument("--gt", required=True, type=Path,
                        help="folder of ground-truth meshes, or of point clouds (.npy / .ply: "
                        "the field's chamfer protocol)")
    parser.add_argument("--camera", type=Path, help="camera JSON (adds reprojection error)")
    parser.add_argument("--json", type=Path, help="write summary and per-frame values here "
                        "(refused if it exists, unless --overwrite)")
    parser.add_argument("--overwrite", action="store_true", help="replace an existing --json file")
    return parser


@interruptible("ndf-sft-eval")
def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    from inverse.sft.chamfer import is_cloud_folder
    from inverse.sft.inputs import load_camera
    from inverse.sft.metrics import evaluate_sequence

    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    try:
        if args.json is not None and args.json.exists() and not args.overwrite:
            raise InputError(f"{args.json} exists; pass --overwrite to replace it")
        camera = load_camera(args.camera) if args.camera else None
        if is_cloud_folder(args.gt):
            return _against_clouds(args, camera)
        pairs, how = paired_meshes(args.pred, args.gt)
        pred, gt = [], []
        faces = gt_faces = None
        to_camera = camera.to_camera if camera is not None else np.asarray
        for name, pred_path, gt_path in pairs:
            p, g = read_mesh(pred_path), read_mesh(gt_path)
            faces = p.faces if faces is None else faces
            gt_faces = g.faces if gt_faces is None else gt_faces
            if not np.array_equal(p.faces, faces) or not np.array_equal(g.faces, gt_faces):
                raise InputError(f"{name}: connectivity differs from the first frame's")
            if p.vertices.shape != g.vertices.shape:
                raise InputError(
                    f"{name}: prediction has {len(p.vertices)} vertices, ground truth "
                    f"{len(g.vertices)}; the prediction must keep the template's vertex order"
                )
            pred.append(to_camera(p.vertices))
            gt.append(to_camera(g.vertices))
    except (InputError, ValueError, OSError) as err:
        print(f"ndf-sft-eval: error: {err}", file=sys.stderr)
        return 2
    metrics = evaluate_sequence(pred, gt, faces, camera=camera, gt_faces=gt_faces)
    _report(args, pairs, how, metrics, ("frames", "e3d", "e3d_procrustes", "chamfer_x1e4",
                                        "normal_deg", "reprojection_px"))
    return 0


def _against_clouds(args: argparse.Namespace, camera) -> int:
    """Predicted meshes against point clouds: the field's chamfer protocol."""
    from inverse.sft.chamfer import evaluate_against_clouds, load_point_cloud
    from taichi_ndf import progress

    pairs, how = paired_meshes(args.pred, args.gt, clouds=True)
    to_camera = camera.to_camera if camera is not None else np.asarray
    pred, clouds, faces = [], [], None
    with progress.stage(f"read {len(pairs)} meshes and clouds", len(pairs)):
        for i, (name, pred_path, gt_path) in enumerate(pairs):
            mesh = read_mesh(pred_path)
            faces = mesh.faces if faces is None else faces
            if not np.array_equal(mesh.faces, faces):
                raise InputError(f"{name}: connectivity differs from the first frame's")
            pred.append(to_camera(mesh.vertices))
            clouds.append(to_camera(load_point_cloud(gt_path)))
            progress.report(i + 1)
    metrics = evaluate_against_clouds(pred, faces, clouds)
    _report(args, pairs, how, metrics, ("frames", "chamfer_x1e4", "chamfer_x1e4_worst",
                                        "worst_frame", "max_vertex_distance_m",
                                        "max_vertex_distance_frame"))
    return 0


def _report(args, pairs, how, metrics, keys) -> None:
    first, last = pairs[0], pairs[-1]
    print(f"paired {len(pairs)} frames by {how}: {first[1].name} <-> {first[2].name}"
          + (f" ... {last[1].name} <-> {last[2].name}" if len(pairs) > 1 else ""))
    summary = metrics.summary()
    for key in keys:
        value = summary[key]
        if value is not None:
            print(f"{key:>26}: {value:.6g}" if isinstance(value, float)
                  else f"{key:>26}: {value}")
    print(f"protocol: {summary['protocol']}")
    if args.json:
        report = {"summary": summary, "per_frame": metrics.per_frame(),
                  "frames": [name for name, _, _ in pairs], "paired_by": how,
                  "pairs": [[p.name, g.name] for _, p, g in pairs]}
        with atomic_path(args.json) as temporary:  # never a half-written file
            temporary.write_text(json.dumps(report, indent=2) + "\n")


if __name__ == "__main__":
    raise SystemExit(main())
