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

Malformed inputs raise :class:`InputError` with a message naming the problem.
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

from taichi_ndf.io import read_mesh

log = logging.getLogger(__name__)

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")
CAMERA_KEYS = {"fx", "fy", "cx", "cy", "width", "height"}
OPTIONAL_CAMERA_KEYS = {"dist", "R", "t"}


class InputError(ValueError):
    """A shape-from-template input is missing or malformed."""


@dataclass(frozen=True)
class Camera:
    """Pinhole camera, OpenCV convention.

    fx, fy: focal lengths [px]; cx, cy: principal point [px] (pixel centres at integers);
    width, height: image size [px]; dist: OpenCV distortion (k1, k2, p1, p2, k3) or None;
    rotation, translation: world→camera extrinsics (x_cam = R x_world + t [m]) or None.
    """

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    dist: tuple[float, ...] | None = None
    rotation: tuple[tuple[float, float, float], ...] | None = None
    translation: tuple[float, float, float] | None = None

    def __post_init__(self):
        for name in ("fx", "fy", "cx", "cy"):
            value = getattr(self, name)
            if not np.isfinite(value) or (name in ("fx", "fy") and value <= 0):
                raise InputError(f"camera {name} must be a finite (focal: positive) number, "
                                 f"got {value}")
        for name in ("width", "height"):
            value = getattr(self, name)
            if int(value) != value or value <= 0:
                raise InputError(f"camera {name} must be a positive integer, got {value}")
        if self.dist is not None and len(self.dist) != 5:
            raise InputError(
                f"camera dist must have 5 coefficients (k1, k2, p1, p2, k3), got {len(self.dist)}"
            )
        if (self.rotation is None) != (self.translation is None):
            raise InputError("camera extrinsics need both R and t (or neither)")
        if self.rotation is not None:
            R = np.asarray(self.rotation, dtype=float)
            if R.shape != (3, 3):
                raise InputError(f"camera R must be 3x3, got shape {R.shape}")
            if not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
                raise InputError("camera R must be a rotation matrix (orthonormal, det +1)")
            if np.asarray(self.translation, dtype=float).shape != (3,):
                raise InputError("camera t must have 3 components")

    @property
    def K(self) -> np.ndarray:
        """Intrinsic matrix, shape (3, 3)."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) [px]."""
        return int(self.width), int(self.height)

    def project(self, points_cam: np.ndarray) -> np.ndarray:
        """Pixels (n, 2) of camera-frame points [m], shape (n, 3); ideal pinhole (no distortion)."""
        points_cam = np.asarray(points_cam, dtype=float)
        z = points_cam[:, 2]
        return np.stack(
            [self.fx * points_cam[:, 0] / z + self.cx, self.fy * points_cam[:, 1] / z + self.cy],
            axis=1,
        )

    def to_camera(self, points_world: np.ndarray) -> np.ndarray:
        """World points [m], shape (n, 3), in camera coordinates (identity without extrinsics)."""
        points_world = np.asarray(points_world, dtype=float)
        if self.rotation is None:
            return points_world.copy()
        return points_world @ np.asarray(self.rotation).T + np.asarray(self.translation)

    def to_world(self, points_cam: np.ndarray) -> np.ndarray:
        """Camera points [m], shape (n, 3), in world coordinates (identity without extrinsics)."""
        points_cam = np.asarray(points_cam, dtype=float)
        if self.rotation is None:
            return points_cam.copy()
        return (points_cam - np.asarray(self.translation)) @ np.asarray(self.rotation)

    def to_json(self) -> dict:
        """The camera JSON object of the input contract."""
        data = {
            "fx": self.fx, "fy": self.fy, "cx": self.cx, "cy": self.cy,
            "width": int(self.width), "height": int(self.height),
        }
        if self.dist is not None:
            data["dist"] = list(self.dist)
        if self.rotation is not None:
            data["R"] = [list(row) for row in self.rotation]
            data["t"] = list(self.translation)
        return data


def camera_from_json(data: dict, *, source: str = "camera JSON") -> Camera:
    """Camera from the contract's JSON object {fx, fy, cx, cy, width, height[, dist, R, t]}."""
    if not isinstance(data, dict):
        raise InputError(f"{source}: expected a JSON object, got {type(data).__name__}")
    missing = CAMERA_KEYS - data.keys()
    if missing:
        raise InputError(f"{source}: missing key(s) {sorted(missing)}")
    unknown = data.keys() - CAMERA_KEYS - OPTIONAL_CAMERA_KEYS
    if unknown:
        raise InputError(
            f"{source}: unknown key(s) {sorted(unknown)}; allowed: "
            f"{sorted(CAMERA_KEYS | OPTIONAL_CAMERA_KEYS)}"
        )
    for name in ("fx", "fy", "cx", "cy", "width", "height"):
        if not _is_number(data[name]):
            raise InputError(f"{source}: {name} must be a number, got {data[name]!r}")
    for name in ("dist", "t"):
        value = data.get(name)
        if value is not None and not (isinstance(value, list)
                                      and all(_is_number(x) for x in value)):
            raise InputError(f"{source}: {name} must be a list of numbers, got {value!r}")
    rows = data.get("R")
    if rows is not None and not (isinstance(rows, list) and all(
            isinstance(row, list) and all(_is_number(x) for x in row) for row in rows)):
        raise InputError(f"{source}: R must be a list of rows of numbers, got {rows!r}")
    try:
        dist = None if data.get("dist") is None else tuple(float(x) for x in data["dist"])
        rotation = None
        translation = None
        if data.get("R") is not None:
            rotation = tuple(tuple(float(x) for x in row) for row in data["R"])
        if data.get("t") is not None:
            translation = tuple(float(x) for x in data["t"])
        return Camera(
            fx=float(data["fx"]), fy=float(data["fy"]), cx=float(data["cx"]), cy=float(data["cy"]),
            width=data["width"], height=data["height"], dist=dist,
            rotation=rotation, translation=translation,
        )
    except (TypeError, ValueError) as err:
        if isinstance(err, InputError):
            raise InputError(f"{source}: {err}") from None
        raise InputError(f"{source}: malformed value ({err})") from None


def _is_number(value) -> bool:
    """A JSON number: int or float, not a boolean nor a numeric string."""
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def load_camera(path: str | Path) -> Camera:
    """Camera from a JSON file of the input contract."""
    path = _existing(path, "camera file")
    try:
        data = json.loads(path.read_text())
    except json.JSONDecodeError as err:
        raise InputError(f"camera file {path}: not valid JSON ({err})") from None
    return camera_from_json(data, source=f"camera file {path}")


def write_camera(camera: Camera, path: str | Path) -> None:
    """Write the camera as the contract's JSON file."""
    Path(path).write_text(json.dumps(camera.to_json(), indent=2) + "\n")


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


def load_template(path: str | Path, *, camera: Camera | None = None) -> Template:
    """Template from an OBJ (one UV per vertex) or a PLY with per-vertex texture coordinates.

    Read with ``taichi_ndf.io.read_mesh`` (trimesh, ``process=False``), so vertex order is kept.
    An OBJ whose faces use texture indices that differ from the vertex indices (UV seams) cannot
    keep one UV per vertex: it is refused. With camera extrinsics the file is in world
    coordinates and is moved into camera coordinates.
    """
    path = _existing(path, "template mesh")
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
    return _read_image(_existing(path, "texture image"), "texture image", cv2.IMREAD_COLOR)


def list_images(folder: Path) -> list[Path]:
    """Image files of a folder, in natural sort order (frame2 before frame10)."""
    def natural(p: Path):
        return [int(s) if s.isdigit() else s for s in re.split(r"(\d+)", p.name)]

    return sorted((p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES), key=natural)


def read_frames(path: str | Path) -> list[np.ndarray]:
    """Frames of a video file or an image folder (natural sort order), BGR uint8 (h, w, 3)."""
    path = _existing(path, "frames")
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
    path = _existing(path, "masks folder")
    if not path.is_dir():
        raise InputError(f"masks {path}: expected a folder of images")
    files = list_images(path)
    if not files:
        raise InputError(f"masks folder {path}: contains no images {IMAGE_SUFFIXES}")
    return [_read_image(f, "mask", cv2.IMREAD_GRAYSCALE) > 127 for f in files]


def read_pinned(path: str | Path) -> np.ndarray:
    """Pinned vertex indices from a JSON list or a whitespace-separated text file, shape (k,)."""
    path = _existing(path, "pinned vertices file")
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


def _existing(path: str | Path, what: str) -> Path:
    path = Path(path)
    if not path.exists():
        raise InputError(f"{what} {path}: missing file or folder")
    return path


def _read_image(path: Path, what: str, flags: int) -> np.ndarray:
    image = cv2.imread(str(path), flags)
    if image is None:
        raise InputError(f"{what} {path}: unreadable image")
    return image
