"""Import a real capture in the φ-SfT / PGSfT layout as shape-from-template inputs.

    DIR/frames/rgb_000.png …         frames (any image names, natural order)
    DIR/masks/mask_000.png …         the sheet's masks (optional)
    DIR/ground_truth/*.npy | *.ply   point clouds per frame, camera coordinates (optional;
                                     also ``point_clouds/``)
    DIR/template/*.obj               frame 0's shape (exactly one OBJ; quads or triangles)
    DIR/camera.json                  {fx, fy, cx, cy, width, height} (docs/sft.md §1)
    DIR/pinned.json | pinned.txt     held vertex indices (optional)

Conventions are found by measurement and stated (``Capture.conventions``), not assumed:
- **axes**: of the eight sign flips of the template's (x, y, z), those that put every vertex in
  front of the camera are drawn into frame 0 and the one whose silhouette overlaps mask 0 best
  (IoU) is applied (without masks: the template as given, if it projects inside the image).
  Refused when even the best overlaps by less than ``input_checks.MIN_SILHOUETTE_IOU``;
- **UVs and texture**: the texture is frame 0 itself and the UVs are re-derived by projecting
  the template's vertices into it (docs/sft.md §1's UV convention), so whatever UVs and
  texture image the capture ships are not used;
- **held vertices**: the ``pinned`` file, else the caller's list, else none.
The ground-truth clouds are checked against the template (cloud 0 must lie on frame 0's shape).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass
from itertools import product
from pathlib import Path

import cv2
import numpy as np

from inverse.sft.camera import Camera, load_camera
from inverse.sft.chamfer import cloud_files, load_point_cloud
from inverse.sft.errors import InputError, existing_path
from inverse.sft.input_checks import (
    MIN_IN_VIEW_FRACTION,
    MIN_SILHOUETTE_IOU,
    check_cloud_in_camera_frame,
    check_template_in_view,
    in_view_fraction,
    silhouette_iou,
)
from inverse.sft.inputs import (
    SftInputs,
    Template,
    list_images,
    read_frames,
    read_masks,
    read_pinned,
    validate_inputs,
)
from inverse.sft.limits import check_image_folder_memory
from taichi_ndf.io import read_mesh
from taichi_ndf.render import texture_pixels_to_uv

log = logging.getLogger(__name__)

GROUND_TRUTH_FOLDERS = ("ground_truth", "point_clouds")
PINNED_FILES = ("pinned.json", "pinned.txt")


@dataclass(frozen=True)
class Capture:
    """A capture read as SfT inputs: the inputs (camera coordinates, texture = frame 0),
    the ground-truth cloud folder or None, the conventions applied (one sentence each) and the
    sign flip applied to the template's axes, shape (3,)."""

    inputs: SftInputs
    ground_truth: Path | None
    conventions: tuple[str, ...]
    axes: tuple[int, int, int]


def template_file(folder: Path) -> Path:
    """The capture's one template OBJ (``template/*.obj`` or ``template.obj``)."""
    candidates = sorted((folder / "template").glob("*.obj")) if (folder / "template").is_dir() \
        else []
    if not candidates and (folder / "template.obj").is_file():
        candidates = [folder / "template.obj"]
    if len(candidates) != 1:
        raise InputError(f"capture {folder}: expected exactly one template OBJ in template/ "
                         f"(found {len(candidates)})")
    return candidates[0]


def ground_truth_folder(folder: Path) -> Path | None:
    """The capture's folder of ground-truth point clouds, or None."""
    for name in GROUND_TRUTH_FOLDERS:
        if (folder / name).is_dir():
            return folder / name
    return None


def best_axes(vertices: np.ndarray, faces: np.ndarray, camera: Camera,
              mask: np.ndarray | None) -> tuple[tuple[int, int, int], float, str]:
    """The sign flip (3,) of the template's axes that fits frame 0 best, its score and what
    the score is; InputError naming the measurement when none fits."""
    if mask is None:
        share = in_view_fraction(vertices, camera)
        if share < MIN_IN_VIEW_FRACTION:
            raise InputError(
                f"template: {100 * share:.0f} % of its vertices project inside the image and "
                "there are no masks to find its axes by: give masks/ or a template in OpenCV "
                "camera axes")
        return (1, 1, 1), share, "share of vertices inside the image (no masks)"
    scores = {}
    for signs in product((1, -1), repeat=3):
        flipped = vertices * signs
        if np.all(flipped[:, 2] > 0):
            scores[signs] = silhouette_iou(flipped, faces, camera, mask)
    if not scores:
        raise InputError("template: no sign flip of its axes puts every vertex in front of the "
                         "camera (z > 0)")
    signs = max(scores, key=scores.get)
    listing = ", ".join(f"{_axes_name(s)} {v:.2f}" for s, v in scores.items())
    if scores[signs] < MIN_SILHOUETTE_IOU:
        raise InputError(f"template: no axis convention projects it onto mask 0 (silhouette IoU "
                         f"{listing}; need {MIN_SILHOUETTE_IOU})")
    return signs, scores[signs], f"silhouette IoU with mask 0 ({listing})"


def projected_uvs(vertices: np.ndarray, camera: Camera) -> np.ndarray:
    """UVs (V, 2) of vertices (V, 3) [m] in a texture that is the camera's own image: pixel
    (x, y) (centres at integers) is UV ((x + ½) / W, 1 − (y + ½) / H) (docs/sft.md §1)."""
    return texture_pixels_to_uv(camera.project(vertices), camera.width, camera.height)


def load_capture(folder: str | Path, *, pinned: Sequence[int] | None = None) -> Capture:
    """Read a capture (module docstring); InputError with one line for anything that does
    not fit. ``pinned`` overrides the capture's pinned file."""
    folder = existing_path(folder, "capture folder")
    camera = load_camera(existing_path(folder / "camera.json", "capture camera"))
    frames_dir = existing_path(folder / "frames", "capture frames")
    masks_dir = folder / "masks" if (folder / "masks").is_dir() else None
    for images in (frames_dir, masks_dir):
        if images is not None:
            check_image_folder_memory(images)
    path = template_file(folder)
    try:
        mesh = read_mesh(path)
    except (OSError, ValueError) as err:
        raise InputError(f"template {path}: cannot be read ({err})") from None
    conventions = [f"camera: {folder / 'camera.json'}, OpenCV axes (x right, y down, z "
                   "forward), pixel centres at integers"]
    if not np.all(np.isfinite(mesh.vertices)):
        check_template_in_view(mesh.vertices, mesh.faces, camera, None, what=f"template {path}")
    # The template is checked against mask 0 before the whole sequence is read.
    mask0 = None if masks_dir is None else _first_mask(masks_dir, camera)
    signs, score, how = best_axes(mesh.vertices, mesh.faces, camera, mask0)
    vertices = mesh.vertices * signs
    conventions.append(f"template axes: {_axes_name(signs)} applied to {path.name} (best "
                       f"{how}; chosen {score:.2f})")
    check_template_in_view(vertices, mesh.faces, camera, mask0, what=f"template {path}")
    frames = read_frames(frames_dir)
    masks = read_masks(masks_dir) if masks_dir is not None else None
    uvs = projected_uvs(vertices, camera)
    conventions.append("texture: frame 0; UVs re-derived by projecting the template's vertices "
                       "into frame 0 (the file's UVs and texture images are not used)")
    template = Template(vertices=vertices, faces=mesh.faces, uvs=uvs)
    pins, source = _pinned(folder, pinned)
    conventions.append(f"held vertices: {'none' if pins is None else pins.tolist()} ({source})")
    inputs = SftInputs(frames=frames, camera=camera, template=template, texture=frames[0],
                       masks=masks, pinned=pins)
    validate_inputs(inputs)
    gt = ground_truth_folder(folder)
    if gt is not None:
        first = cloud_files(gt)[0]
        median = check_cloud_in_camera_frame(vertices, load_point_cloud(first),
                                             what=f"point cloud {first.name}")
        conventions.append(f"ground truth: point clouds in {gt.name}/, camera coordinates "
                           f"(template {1000 * median:.1f} mm from {first.name}, median)")
    for line in conventions:
        log.info("capture: %s", line)
    return Capture(inputs=inputs, ground_truth=gt, conventions=tuple(conventions), axes=signs)


def _first_mask(folder: Path, camera: Camera) -> np.ndarray | None:
    """Mask 0 (bool (h, w)), or None when the folder has no image (refused later)."""
    files = list_images(folder)
    if not files:
        return None
    image = cv2.imread(str(files[0]), cv2.IMREAD_GRAYSCALE)
    if image is None:
        raise InputError(f"mask {files[0]}: unreadable image")
    if (image.shape[1], image.shape[0]) != camera.size:
        raise InputError(f"mask {files[0]}: size {image.shape[1]}x{image.shape[0]} differs from "
                         f"the camera size {camera.width}x{camera.height}")
    return image > 127


def _pinned(folder: Path, pinned: Sequence[int] | None) -> tuple[np.ndarray | None, str]:
    if pinned is not None:
        return np.asarray(pinned, dtype=np.int64).reshape(-1), "given as an option"
    for name in PINNED_FILES:
        if (folder / name).is_file():
            return read_pinned(folder / name), f"from {name}"
    return None, "no pinned file, none given"


def _axes_name(signs: Sequence[int]) -> str:
    flips = [axis for axis, s in zip("xyz", signs, strict=True) if s < 0]
    return "negate " + " and ".join(flips) if flips else "as given"
