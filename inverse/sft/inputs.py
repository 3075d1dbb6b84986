"""Input contract of shape-from-template: frames, camera, template, texture, masks, pins.

Conventions (also in ``docs/sft.md``):
- Camera axes are OpenCV's: x right, y down, z forward (into the scene). A point (x, y, z) in
  camera coordinates projects to pixel (u, v) = (fx x / z + cx, fy y / z + cy).
- Pixel coordinates: the centre of the pixel in column i, row j is at (i, j), so an image of
  width W spans u ∈ [-0.5, W - 0.5]. This is what OpenCV's feature detectors, optical flow and
  ``projectPoints`` use.
- Texture coordinates follow OBJ: (u, v) = (0, 0) is the bottom-left corner of the texture
  image, v points up. Texel (col, row) of a W×H texture has its centre at
  ((col + 0.5) / W, 1 - (row + 0.5) / H).
- The template is given in camera coordinates for frame 0; if the camera has extrinsics
  (R, t, world→camera), the template is given in world coordinates and is moved into camera
  coordinates on load. Everything downstream works in camera coordinates, metres.
- With distortion coefficients, frames and masks are undistorted on load (same K), so the rest of
  the pipeline sees an ideal pinhole camera.

Malformed inputs raise :class:`InputError` with a message naming the problem. The camera and
its JSON file: `inverse.sft.camera`.
"""

from __future__ import annotations

import json
import logging
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from inverse.sft.camera import Camera, load_camera
from inverse.sft.errors import InputError, existing_path
from taichi_ndf.io import read_mesh

log = logging.getLogger(__name__)

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")


@dataclass(frozen=True)
class Template:
    """Template mesh for frame 0, camera coordinates.

    vertices: positions [m], shape (n, 3); faces: vertex indices, shape (m, 3);
    uvs: texture coordinates (OBJ convention), shape (n, 2). Vertex order is the correspondence
    between the template and every output mesh.
    """

    vertices: np.ndarray
    faces: np.ndarray
    uvs: np.ndarray

    def __post_init__(self):
        n = len(self.vertices)
        if self.vertices.ndim != 2 or self.vertices.shape[1] != 3:
            raise InputError(
                f"template vertices must have shape (n, 3), got {self.vertices.shape}")
        if self.faces.ndim != 2 or self.faces.shape[1] != 3:
            raise InputError(
                f"template faces must be triangles, shape (m, 3), got {self.faces.shape}")
        if self.uvs.shape != (n, 2):
            raise InputError(f"template UVs must have shape ({n}, 2), got {self.uvs.shape}")
        if len(self.faces) == 0 or self.faces.min() < 0 or self.faces.max() >= n:
            raise InputError("template faces are empty or index a vertex that does not exist")


def mesh_edges(faces: np.ndarray) -> np.ndarray:
    """Unique undirected edges of a triangle mesh, shape (e, 2), int64."""
    pairs = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    return np.unique(np.sort(pairs, axis=1), axis=0)


def mean_edge_length(vertices: np.ndarray, faces: np.ndarray) -> float:
    """Mean length [m] of the mesh's unique edges (each edge counted once)."""
    edges = mesh_edges(faces)
    return float(np.linalg.norm(vertices[edges[:, 0]] - vertices[edges[:, 1]], axis=1).mean())


def load_template(path: str | Path, *, camera: Camera | None = None) -> Template:
    """Template from an OBJ (one UV per vertex) or a PLY with per-vertex texture coordinates.

    Read with ``taichi_ndf.io.read_mesh`` (trimesh, ``process=False``), so vertex order is kept.
    An OBJ whose faces use texture indices that differ from the vertex indices (UV seams) cannot
    keep one UV per vertex: it is refused. With camera extrinsics the file is in world
    coordinates and is moved into camera coordinates.
    """
    path = existing_path(path, "template mesh")
    if path.suffix.lower() == ".obj":
        _check_obj_uv_indices(path)
    try:
        mesh = read_mesh(path)
    except Exception as err:  # trimesh raises many types for unreadable files
        raise InputError(f"template mesh {path}: cannot be read ({err})") from None
    if mesh.uvs is None:
        raise InputError(f"template mesh {path}: has no UV (texture) coordinates")
    vertices = mesh.vertices
    if camera is not None:
        vertices = camera.to_camera(vertices)
    template = Template(vertices=vertices, faces=mesh.faces, uvs=np.asarray(mesh.uvs, float))
    if np.any(template.vertices[:, 2] <= 0):
        raise InputError(
            f"template mesh {path}: some vertices have z <= 0, i.e. are not in front of the camera "
            "(the template must be in camera coordinates, z forward)"
        )
    return template


def _check_obj_uv_indices(path: Path) -> None:
    """Refuse OBJ faces whose texture index differs from the vertex index (UV seams)."""
    for number, line in enumerate(path.read_text().splitlines(), start=1):
        if not line.startswith("f "):
            continue
        for corner in line.split()[1:]:
            parts = corner.split("/")
            if len(parts) > 1 and parts[1] and parts[1] != parts[0]:
                raise InputError(
                    f"template mesh {path}: line {number} uses texture index {parts[1]} for "
                    f"vertex {parts[0]} (UV seam); give exactly one UV per vertex (f i/i j/j k/k)"
                )


def load_texture(path: str | Path) -> np.ndarray:
    """Texture image, BGR uint8, shape (h, w, 3)."""
    return _read_image(existing_path(path, "texture image"), "texture image", cv2.IMREAD_COLOR)


def list_images(folder: Path) -> list[Path]:
    """Image files of a folder, in natural sort order (frame2 before frame10)."""
    def natural(p: Path):
        return [int(s) if s.isdigit() else s for s in re.split(r"(\d+)", p.name)]

    return sorted((p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES), key=natural)


def read_frames(path: str | Path) -> list[np.ndarray]:
    """Frames of a video file or an image folder (natural sort order), BGR uint8 (h, w, 3)."""
    path = existing_path(path, "frames")
    if path.is_dir():
        files = list_images(path)
        if not files:
            raise InputError(f"frames folder {path}: zero frames (no {IMAGE_SUFFIXES} images)")
        return [_read_image(f, "frame", cv2.IMREAD_COLOR) for f in files]
    capture = cv2.VideoCapture(str(path))
    frames = []
    try:
        if not capture.isOpened():
            raise InputError(f"frames video {path}: unreadable video (OpenCV cannot open it)")
        while True:
            ok, frame = capture.read()
            if not ok:
                break
            frames.append(frame)
    finally:
        capture.release()
    if not frames:
        raise InputError(f"frames video {path}: unreadable video or zero frames")
    return frames


def read_masks(path: str | Path) -> list[np.ndarray]:
    """Masks from an image folder (natural sort order): bool (h, w), True on the sheet."""
    path = existing_path(path, "masks folder")
    if not path.is_dir():
        raise InputError(f"masks {path}: expected a folder of images")
    files = list_images(path)
    if not files:
        raise InputError(f"masks folder {path}: contains no images {IMAGE_SUFFIXES}")
    return [_read_image(f, "mask", cv2.IMREAD_GRAYSCALE) > 127 for f in files]


def read_pinned(path: str | Path) -> np.ndarray:
    """Pinned vertex indices from a JSON list or a whitespace-separated text file, shape (k,)."""
    path = existing_path(path, "pinned vertices file")
    text = path.read_text()
    try:
        values = json.loads(text) if path.suffix.lower() == ".json" else text.split()
        return np.array([int(v) for v in values], dtype=np.int64)
    except (json.JSONDecodeError, TypeError, ValueError) as err:
        raise InputError(
            f"pinned vertices file {path}: expected a list of integers ({err})") from None


@dataclass(frozen=True)
class SftInputs:
    """Everything a shape-from-template run consumes, validated and in camera coordinates.

    frames: BGR uint8 images (h, w, 3), undistorted; masks: bool (h, w) per frame or None;
    pinned: vertex indices held at their template positions, shape (k,), or None.
    """

    frames: list[np.ndarray]
    camera: Camera
    template: Template
    texture: np.ndarray
    masks: list[np.ndarray] | None = None
    pinned: np.ndarray | None = None


def validate_inputs(inputs: SftInputs) -> None:
    """Raise InputError if frames, masks or pins disagree with the camera or the template."""
    if not inputs.frames:
        raise InputError("frames: zero frames")
    size = inputs.camera.size
    for i, frame in enumerate(inputs.frames):
        if (frame.shape[1], frame.shape[0]) != size:
            raise InputError(
                f"frame {i}: image size {frame.shape[1]}x{frame.shape[0]} differs from the camera "
                f"size {size[0]}x{size[1]}"
            )
    if inputs.masks is not None:
        if len(inputs.masks) != len(inputs.frames):
            raise InputError(
                f"masks: {len(inputs.masks)} masks for {len(inputs.frames)} frames "
                "(counts must match)"
            )
        for i, mask in enumerate(inputs.masks):
            if (mask.shape[1], mask.shape[0]) != size:
                raise InputError(
                    f"mask {i}: size {mask.shape[1]}x{mask.shape[0]} differs from the camera size "
                    f"{size[0]}x{size[1]}"
                )
    if inputs.pinned is not None:
        n = len(inputs.template.vertices)
        bad = inputs.pinned[(inputs.pinned < 0) | (inputs.pinned >= n)]
        if bad.size:
            raise InputError(f"pinned vertices: indices {bad.tolist()} out of range [0, {n})")


def load_inputs(
    *,
    frames: str | Path,
    camera: str | Path,
    template: str | Path,
    texture: str | Path,
    masks: str | Path | None = None,
    pinned: str | Path | Sequence[int] | None = None,
) -> SftInputs:
    """Load and validate all inputs of the contract; undistort frames and masks if needed."""
    cam = load_camera(camera)
    tmpl = load_template(template, camera=cam)
    tex = load_texture(texture)
    images = read_frames(frames)
    mask_list = read_masks(masks) if masks is not None else None
    if pinned is None:
        pins = None
    elif isinstance(pinned, (str, Path)):
        pins = read_pinned(pinned)
    else:
        pins = np.asarray(pinned, dtype=np.int64).reshape(-1)
    inputs = SftInputs(frames=images, camera=cam, template=tmpl, texture=tex, masks=mask_list,
                       pinned=pins)
    validate_inputs(inputs)
    if cam.dist is not None:
        inputs = _undistorted(inputs)
    log.info(
        "loaded %d frames %dx%d, template %d vertices / %d faces, texture %dx%d%s",
        len(images), cam.width, cam.height, len(tmpl.vertices), len(tmpl.faces),
        tex.shape[1], tex.shape[0], ", with masks" if mask_list is not None else "",
    )
    return inputs


def _undistorted(inputs: SftInputs) -> SftInputs:
    cam = inputs.camera
    K = cam.K
    dist = np.asarray(cam.dist)
    map1, map2 = cv2.initUndistortRectifyMap(K, dist, None, K, cam.size, cv2.CV_32FC1)
    frames = [cv2.remap(f, map1, map2, cv2.INTER_LINEAR) for f in inputs.frames]
    masks = None
    if inputs.masks is not None:
        masks = [
            cv2.remap(m.astype(np.uint8), map1, map2, cv2.INTER_NEAREST) > 0 for m in inputs.masks
        ]
    return SftInputs(frames=frames, camera=cam, template=inputs.template, texture=inputs.texture,
                     masks=masks, pinned=inputs.pinned)


def _read_image(path: Path, what: str, flags: int) -> np.ndarray:
    image = cv2.imread(str(path), flags)
    if image is None:
        raise InputError(f"{what} {path}: unreadable image")
    return image
