"""Look-at pinhole cameras and automatic framing of a mesh."""

from dataclasses import dataclass

import numpy as np

from taichi_ndf.render.raster import rasterize

__all__ = ["Camera", "frame_mesh", "ground_axes", "visible_cover", "widest_azimuth",
           "widest_azimuth_over"]


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


PREFERRED_AZIMUTH_DEG = -45.0  # a diagonal in front and to the side, as in Blender's default view
AZIMUTH_STEP_DEG = 15.0  # candidates of `widest_azimuth_over`
AREA_TOLERANCE = 0.1  # `widest_azimuth_over`: views this close to the widest count as wide


def ground_axes(up: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """East and north unit vectors completing the unit vector `up` to a right-handed frame
    (east: the world axis least aligned with up, made normal to it)."""
    reference = np.eye(3)[np.argmin(np.abs(up))]
    east = _unit(reference - (reference @ up) * up, "east")
    return east, np.cross(up, east)


def _toward_eye(up: np.ndarray, elevation_deg, azimuth_deg) -> np.ndarray:
    """Unit vectors (..., 3) from the target towards the eye: `elevation_deg` above the ground
    plane, `azimuth_deg` around `up` from east."""
    east, north = ground_axes(up)
    el, az = np.radians(elevation_deg), np.radians(azimuth_deg)
    horizontal = np.cos(az)[..., None] * east + np.sin(az)[..., None] * north
    return np.cos(el)[..., None] * horizontal + np.sin(el)[..., None] * up


def visible_cover(
    states,
    faces: np.ndarray,
    obstacles=None,
    *,
    up=(0.0, 0.0, 1.0),
    elevation_deg: float = 30.0,
    azimuths_deg=(PREFERRED_AZIMUTH_DEG,),
) -> np.ndarray:
    """The fraction of a 64 x 64 image that the surface covers in front of the obstacles, per
    azimuth of `azimuths_deg` [deg] (shape (A,)), summed over `states` (positions (V, 3) [m]
    on `faces`, with `obstacles[k]` (meshes with `vertices`, `faces`; None: none) at state k):
    a camera at `elevation_deg` above the plane normal to `up`, distant (10° field of view)
    and at one distance from the centre of every state and obstacle, so nearly a parallel
    projection. A surface pixel behind an obstacle does not count, nor does a layer behind
    another (folded layers count once, as the eye sees them)."""
    up = _unit(up, "up")
    faces = np.asarray(faces, dtype=np.int64)
    obstacles = [()] * len(states) if obstacles is None else obstacles
    soups = []
    for state, group in zip(states, obstacles, strict=True):
        parts = [np.asarray(state, dtype=np.float64)] + [np.asarray(o.vertices, np.float64)
                                                          for o in group]
        offsets = np.cumsum([0] + [len(p) for p in parts])
        tris = [faces] + [np.asarray(o.faces, np.int64) for o in group]
        soups.append((np.concatenate(parts),
                      np.concatenate([t + o for t, o in zip(tris, offsets, strict=False)])))
    points = np.concatenate([soup[0] for soup in soups])
    points = points[np.all(np.isfinite(points), axis=1)]
    centre = 0.5 * (points.min(axis=0) + points.max(axis=0))
    radius = max(float(np.linalg.norm(points - centre, axis=1).max()), 1e-9)
    fov_deg, side = 10.0, 64
    distance = radius / np.sin(np.radians(fov_deg) / 2.0)
    cover = np.zeros(len(azimuths_deg))
    for a, azimuth in enumerate(np.asarray(azimuths_deg, dtype=np.float64)):
        toward_eye = _toward_eye(up, np.float64(elevation_deg), azimuth)
        camera = Camera(eye=tuple(centre + distance * toward_eye), target=tuple(centre),
                        up=tuple(up), fov_y_deg=fov_deg)
        for points_k, faces_k in soups:
            raster = rasterize(camera.to_camera(points_k), faces_k,
                               camera.intrinsics(side, side), side, side)
            cover[a] += np.mean((raster.face_id >= 0) & (raster.face_id < len(faces)))
    return cover


def widest_azimuth(
    vertices: np.ndarray,
    faces: np.ndarray,
    *,
    up=(0.0, 0.0, 1.0),
    elevation_deg: float = 30.0,
    preferred_deg: float = PREFERRED_AZIMUTH_DEG,
) -> float:
    """The azimuth [deg] from which a camera at `elevation_deg` sees the surface (vertices
    (V, 3) [m], faces (F, 3)) largest: `widest_azimuth_over` its one state.

    The silhouette (pixels covered), not the summed face areas: folded layers count once, as
    the eye sees them. A level sheet or a cylinder about `up` looks alike from everywhere and
    keeps the preferred view; a sheet hanging in a vertical plane is seen from its face
    instead of edge-on.
    """
    return widest_azimuth_over([vertices], faces, up=up, elevation_deg=elevation_deg,
                               preferred_deg=preferred_deg)


def widest_azimuth_over(
    states,
    faces: np.ndarray,
    obstacles=None,
    *,
    up=(0.0, 0.0, 1.0),
    elevation_deg: float = 30.0,
    preferred_deg: float = PREFERRED_AZIMUTH_DEG,
) -> float:
    """The azimuth [deg] from which a camera at `elevation_deg` sees the surface largest over
    `states` (positions (V, 3) [m] on `faces`, `obstacles` per state hiding what lies behind
    them, None: none): of the candidates every AZIMUTH_STEP_DEG, those whose summed
    `visible_cover` is within AREA_TOLERANCE (relative) of the largest, the one nearest
    `preferred_deg` (the preferred view where no state has a finite vertex or there are no
    faces)."""
    if not len(faces) or not any(np.isfinite(np.asarray(s, np.float64)).all(axis=1).any()
                                 for s in states):
        return float(preferred_deg)
    candidates = preferred_deg + np.arange(0.0, 360.0, AZIMUTH_STEP_DEG)
    cover = visible_cover(states, faces, obstacles, up=up, elevation_deg=elevation_deg,
                          azimuths_deg=candidates)
    if cover.max() <= 0:
        return float(preferred_deg)
    wide = cover >= (1.0 - AREA_TOLERANCE) * cover.max()
    away = np.abs((candidates - preferred_deg + 180.0) % 360.0 - 180.0)
    return float(candidates[wide][np.argmin(away[wide])])


def frame_mesh(
    vertices: np.ndarray,
    *,
    width: int,
    height: int,
    up=(0.0, 0.0, 1.0),
    elevation_deg: float = 30.0,
    azimuth_deg: float = PREFERRED_AZIMUTH_DEG,
    fov_y_deg: float = 30.0,
    margin: float = 0.08,
) -> Camera:
    """A camera that looks down on the points from an oblique direction and just fits them.

    The viewing direction comes down at ``elevation_deg`` above the plane normal to ``up``, from
    ``azimuth_deg`` around ``up`` (0 = the world axis least aligned with up, -45 = a diagonal
    in front and to the side, as in Blender's default view; `widest_azimuth` picks the one that
    shows a surface largest). The distance and a sideways shift are chosen so that all points
    fill the image, leaving ``margin`` (fraction of the half field of view) free on the tighter
    side.
    """
    points = np.asarray(vertices, dtype=np.float64)
    points = points[np.all(np.isfinite(points), axis=1)]
    if not len(points):
        raise ValueError("no finite vertices to frame")
    up = _unit(up, "up")
    toward_eye = _toward_eye(up, np.float64(elevation_deg), np.float64(azimuth_deg))

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
