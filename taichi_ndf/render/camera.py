"""Look-at pinhole cameras and automatic framing of a mesh."""

from dataclasses import dataclass

import numpy as np

__all__ = ["Camera", "frame_mesh"]


def _unit(vector, name: str) -> np.ndarray:
    vector = np.asarray(vector, dtype=np.float64)
    length = np.linalg.norm(vector)
    if vector.shape != (3,) or not np.isfinite(length) or length == 0:
        raise ValueError(f"{name} must be a finite non-zero 3-vector, got {vector}")
    return vector / length


@dataclass(frozen=True)
class Camera:
    """A pinhole camera at ``eye`` looking at ``target``; OpenCV axes (x right, y down, z forward).

    eye, target: world positions [m]; up: world direction shown upwards in the image;
    fov_y_deg: vertical field of view [degrees]; pixels are square.
    """

    eye: tuple[float, float, float]
    target: tuple[float, float, float]
    up: tuple[float, float, float] = (0.0, 0.0, 1.0)
    fov_y_deg: float = 30.0

    def __post_init__(self):
        if not 0.0 < self.fov_y_deg < 180.0:
            raise ValueError(f"fov_y_deg must be in (0, 180), got {self.fov_y_deg}")
        forward = _unit(np.subtract(self.target, self.eye), "target - eye")
        up = _unit(self.up, "up")
        if np.linalg.norm(np.cross(forward, up)) < 1e-6:
            raise ValueError(f"up {self.up} is parallel to the viewing direction")

    @property
    def rotation(self) -> np.ndarray:
        """World-to-camera rotation, shape (3, 3); its rows are the camera axes in world axes."""
        forward = _unit(np.subtract(self.target, self.eye), "target - eye")
        right = _unit(np.cross(forward, self.up), "right")
        down = np.cross(forward, right)
        return np.stack([right, down, forward])

    def to_camera(self, points: np.ndarray) -> np.ndarray:
        """Camera coordinates of world points, shape (N, 3)."""
        return (np.asarray(points, dtype=np.float64) - np.asarray(self.eye)) @ self.rotation.T

    def intrinsics(self, width: int, height: int) -> np.ndarray:
        """K (3, 3) for an image of this size, principal point at the image centre."""
        focal = 0.5 * height / np.tan(np.radians(self.fov_y_deg) / 2.0)
        return np.array(
            [[focal, 0.0, (width - 1) / 2.0], [0.0, focal, (height - 1) / 2.0], [0.0, 0.0, 1.0]]
        )


def frame_mesh(
    vertices: np.ndarray,
    *,
    width: int,
    height: int,
    up=(0.0, 0.0, 1.0),
    elevation_deg: float = 30.0,
    azimuth_deg: float = -45.0,
    fov_y_deg: float = 30.0,
    margin: float = 0.08,
) -> Camera:
    """A camera that looks down on the points from an oblique direction and just fits them.

    The viewing direction comes down at ``elevation_deg`` above the plane normal to ``up``, from
    ``azimuth_deg`` around ``up`` (0 = the world axis least aligned with up, -45 = a diagonal
    in front and to the side, as in Blender's default view). The distance and a sideways shift
    are chosen so that all points fill the image, leaving ``margin`` (fraction of the half
    field of view) free on the tighter side.
    """
    points = np.asarray(vertices, dtype=np.float64)
    points = points[np.all(np.isfinite(points), axis=1)]
    if not len(points):
        raise ValueError("no finite vertices to frame")
    up = _unit(up, "up")
    reference = np.eye(3)[np.argmin(np.abs(up))]
    east = _unit(reference - (reference @ up) * up, "east")
    north = np.cross(up, east)
    el, az = np.radians(elevation_deg), np.radians(azimuth_deg)
    toward_eye = np.cos(el) * (np.cos(az) * east + np.sin(az) * north) + np.sin(el) * up

    centre = 0.5 * (points.min(axis=0) + points.max(axis=0))
    probe = Camera(eye=tuple(centre + toward_eye), target=tuple(centre), up=tuple(up))
    rotation = probe.rotation
    relative = (points - centre) @ rotation.T  # camera axes, origin at the centre
    size = max(float(np.ptp(relative[:, :2], axis=0).max()), 1e-9)
    tan_y = np.tan(np.radians(fov_y_deg) / 2.0) * (1.0 - margin)
    tan_x = tan_y * width / height

    def fitting_distance(shift):
        lateral = relative[:, :2] - shift
        return max(
            np.max(np.abs(lateral[:, 0]) / tan_x - relative[:, 2]),
            np.max(np.abs(lateral[:, 1]) / tan_y - relative[:, 2]),
            size * 1e-3 - relative[:, 2].min(),
        )

    # Fit the distance, centre the projected extent by a sideways shift, and refit: perspective
    # couples the two; two rounds centre the mesh to within about a pixel.
    shift = np.zeros(2)
    distance = fitting_distance(shift)
    for _ in range(2):
        projected = (relative[:, :2] - shift) / (relative[:, 2:3] + distance)
        shift = shift + 0.5 * (projected.min(axis=0) + projected.max(axis=0)) * distance
        distance = fitting_distance(shift)
    offset = shift @ rotation[:2]
    eye = centre + offset + distance * toward_eye
    return Camera(eye=tuple(eye), target=tuple(centre + offset), up=tuple(up), fov_y_deg=fov_y_deg)
