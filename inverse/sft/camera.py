"""The pinhole camera of shape-from-template (OpenCV convention; `inverse.sft.inputs` states the
input contract) and its JSON file: the one pinhole projection of the SfT code."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from inverse.sft.errors import InputError, existing_path

CAMERA_KEYS = {"fx", "fy", "cx", "cy", "width", "height"}
OPTIONAL_CAMERA_KEYS = {"dist", "R", "t"}


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

    def project(self, points_cam, *, min_depth: float | None = None):
        """Pixels (n, 2) of camera-frame points [m] (n, 3); ideal pinhole (no distortion):
        (fx x / z + cx, fy y / z + cy). A numpy array, or a torch tensor (differentiable)
        for a torch tensor. min_depth [m]: z clamped from below (points behind the camera,
        e.g. after a bad optimiser step, must not divide by ~0), or None."""
        if isinstance(points_cam, torch.Tensor):
            z = points_cam[:, 2]
            z = z if min_depth is None else z.clamp_min(min_depth)
            return torch.stack([self.fx * points_cam[:, 0] / z + self.cx,
                                self.fy * points_cam[:, 1] / z + self.cy], dim=1)
        points_cam = np.asarray(points_cam, dtype=float)
        z = points_cam[:, 2]
        z = z if min_depth is None else np.maximum(z, min_depth)
        return np.stack(
            [self.fx * points_cam[:, 0] / z + self.cx, self.fy * points_cam[:, 1] / z + self.cy],
            axis=1,
        )

    def projection_jacobian(self, points_cam, *, min_depth: float | None = None):
        """d(pixel)/d(point) (n, 2, 3) [px/m] of `project` at camera-frame points (n, 3): rows
        (fx/z, 0, −fx x/z²) and (0, fy/z, −fy y/z²), z clamped like `project`. numpy in,
        numpy out; torch in, torch out."""
        xp = torch if isinstance(points_cam, torch.Tensor) else np
        if xp is np:
            points_cam = np.asarray(points_cam, dtype=float)
        x, y, z = points_cam[:, 0], points_cam[:, 1], points_cam[:, 2]
        if min_depth is not None:
            z = z.clamp_min(min_depth) if xp is torch else np.maximum(z, min_depth)
        zero = xp.zeros_like(z)
        rows = (xp.stack([self.fx / z, zero, -self.fx * x / z**2], 1),
                xp.stack([zero, self.fy / z, -self.fy * y / z**2], 1))
        return xp.stack(rows, 1)

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
    path = existing_path(path, "camera file")
    try:
        data = json.loads(path.read_text())
    except json.JSONDecodeError as err:
        raise InputError(f"camera file {path}: not valid JSON ({err})") from None
    return camera_from_json(data, source=f"camera file {path}")


def write_camera(camera: Camera, path: str | Path) -> None:
    """Write the camera as the contract's JSON file."""
    Path(path).write_text(json.dumps(camera.to_json(), indent=2) + "\n")
