"""Rigid obstacles: signed distance [m] and its gradient (the outward unit normal) at points.

Analytic shapes (ground plane, sphere, rounded box, capsule, cylinder) compute their signed
distance in torch and its gradient by autograd; a closed triangle mesh computes the exact
point-to-triangle distance in Taichi (`taichi_ndf.contact.mesh_obstacle`). The signed
distance is negative inside, 1-Lipschitz, and smooth except on the medial axis (and, for the
mesh, across the Voronoi regions of edges and vertices, where it is C¹ only).

An obstacle may move with the load factor λ: it is translated by λ · `motion` [m] (a sphere
raised into a sheet, a box slid along), so the signed distance is d(x − λ motion).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from taichi_ndf.checks import finite_vector


def _finite(name: str, value: float, *, positive: bool = False) -> float:
    value = float(value)
    if not math.isfinite(value) or (positive and value <= 0):
        raise ValueError(f"{name} must be {'> 0' if positive else 'finite'}, got {value!r}")
    return value


class Obstacle:
    """Base of the rigid obstacles: `name`, `motion` [m per unit load factor]."""

    name: str
    motion: tuple[float, float, float]

    def signed_distance(self, x: torch.Tensor, load_factor: float = 1.0
                        ) -> tuple[torch.Tensor, torch.Tensor]:
        """Signed distance d (N,) [m] of points x (N, 3) [m] (negative inside) and its
        gradient ∂d/∂x (N, 3) (the outward unit normal at the closest surface point)."""
        local = (x - load_factor * x.new_tensor(self.motion)).detach()
        with torch.enable_grad():
            p = local.requires_grad_(True)
            d = self._sdf(p)
            (normal,) = torch.autograd.grad(d.sum(), p)
        return d.detach(), normal

    def triangles(self, load_factor: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
        """A triangle mesh of the surface (vertices (V, 3) [m], faces (F, 3)) at the load
        factor, for RUN/obstacles/*.obj."""
        vertices, faces = self._mesh()
        return vertices + load_factor * np.asarray(self.motion), faces

    def _sdf(self, p: torch.Tensor) -> torch.Tensor:
        raise NotImplementedError

    def _mesh(self) -> tuple[np.ndarray, np.ndarray]:
        raise NotImplementedError


def _motion(name: str, motion) -> tuple[float, float, float]:
    return finite_vector(f"{name}: motion", motion, 3, "m")


@dataclass(frozen=True)
class GroundPlane(Obstacle):
    """The half-space below a plane through `point` with upward `normal`; drawn as a square
    of side `size` [m] centred at `point`."""

    name: str = "ground"
    point: tuple[float, float, float] = (0.0, 0.0, 0.0)
    normal: tuple[float, float, float] = (0.0, 0.0, 1.0)
    size: float = 2.0
    motion: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self):
        object.__setattr__(self, "point", finite_vector(f"{self.name}: point", self.point, 3))
        n = np.asarray(finite_vector(f"{self.name}: normal", self.normal, 3))
        if not np.linalg.norm(n) > 0:
            raise ValueError(f"{self.name}: normal must be non-zero")
        object.__setattr__(self, "normal", tuple(float(v) for v in n / np.linalg.norm(n)))
        _finite(f"{self.name}: size", self.size, positive=True)
        object.__setattr__(self, "motion", _motion(self.name, self.motion))

    def _sdf(self, p):
        return (p - p.new_tensor(self.point)) @ p.new_tensor(self.normal)

    def _mesh(self):
        n = np.asarray(self.normal)
        e1 = np.cross(n, [1.0, 0, 0] if abs(n[0]) < 0.9 else [0, 1.0, 0])
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(n, e1)
        h = 0.5 * self.size
        corners = [np.asarray(self.point) + h * (s * e1 + t * e2)
                   for s, t in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
        return np.array(corners), np.array([[0, 1, 2], [0, 2, 3]])


@dataclass(frozen=True)
class Sphere(Obstacle):
    name: str = "sphere"
    centre: tuple[float, float, float] = (0.0, 0.0, 0.0)
    radius: float = 1.0
    motion: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self):
        object.__setattr__(self, "centre", finite_vector(f"{self.name}: centre", self.centre, 3))
        _finite(f"{self.name}: radius", self.radius, positive=True)
        object.__setattr__(self, "motion", _motion(self.name, self.motion))

    def _sdf(self, p):
        return (p - p.new_tensor(self.centre)).norm(dim=1) - self.radius

    def _mesh(self):
        import trimesh  # on first use: ~0.9 s of imports (scipy, networkx)
        mesh = trimesh.creation.icosphere(subdivisions=4, radius=self.radius)
        return np.asarray(mesh.vertices) + np.asarray(self.centre), np.asarray(mesh.faces)


@dataclass(frozen=True)
class RoundedBox(Obstacle):
    """Axis-aligned box of half side lengths `half_extents` [m] about `centre`, its edges and
    corners rounded with radius `rounding` [m] (0 ≤ rounding < the smallest half extent)."""

    name: str = "box"
    centre: tuple[float, float, float] = (0.0, 0.0, 0.0)
    half_extents: tuple[float, float, float] = (0.5, 0.5, 0.5)
    rounding: float = 0.0
    motion: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self):
        object.__setattr__(self, "centre", finite_vector(f"{self.name}: centre", self.centre, 3))
        half = finite_vector(f"{self.name}: half_extents", self.half_extents, 3, "m")
        if min(half) <= 0:
            raise ValueError(f"{self.name}: half_extents must be > 0, got {half}")
        object.__setattr__(self, "half_extents", half)
        r = _finite(f"{self.name}: rounding", self.rounding)
        if not 0 <= r < min(half):
            raise ValueError(f"{self.name}: rounding must be in [0, smallest half extent "
                             f"{min(half)}), got {r}")
        object.__setattr__(self, "motion", _motion(self.name, self.motion))

    def _sdf(self, p):
        inner = p.new_tensor(self.half_extents) - self.rounding
        q = (p - p.new_tensor(self.centre)).abs() - inner
        outside = q.clamp(min=0).norm(dim=1)
        inside = q.max(dim=1).values.clamp(max=0)
        return outside + inside - self.rounding

    def _mesh(self):
        # A sphere of the rounding radius split at its equators and moved out to the corners:
        # the stretched triangles between octants are the flat faces and the rounded edges.
        radius = max(self.rounding, 1e-6)
        import trimesh
        sphere = trimesh.creation.uv_sphere(radius=radius, count=[16, 16])
        v = np.asarray(sphere.vertices)
        inner = np.asarray(self.half_extents) - radius
        moved = v + np.sign(np.where(np.abs(v) < 1e-12, 0.0, v)) * inner
        return moved + np.asarray(self.centre), np.asarray(sphere.faces)


@dataclass(frozen=True)
class _SegmentObstacle(Obstacle):
    """A solid of `radius` [m] about the segment from `start` to `end` [m]."""

    name: str = "segment"
    start: tuple[float, float, float] = (0.0, 0.0, 0.0)
    end: tuple[float, float, float] = (1.0, 0.0, 0.0)
    radius: float = 0.1
    motion: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self):
        _check_segment(self)

    def _mesh(self):
        length = float(np.linalg.norm(np.subtract(self.end, self.start)))
        mesh = self._mesh_along_z(length)  # centred on the origin
        return _along_segment(np.asarray(mesh.vertices), self), np.asarray(mesh.faces)

    def _mesh_along_z(self, length: float):
        raise NotImplementedError

    def _axial(self, p: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Position along the axis from `start` (N,) [m], distance from the axis (N,) [m]
        and the segment's length of points p (N, 3)."""
        a = p.new_tensor(self.start)
        axis = p.new_tensor(self.end) - a
        length = axis.norm()
        axis = axis / length
        along = (p - a) @ axis
        return along, (p - a - along[:, None] * axis).norm(dim=1), length


@dataclass(frozen=True)
class Capsule(_SegmentObstacle):
    """Points within `radius` [m] of the segment from `start` to `end` (hemispherical ends)."""

    name: str = "capsule"

    def _sdf(self, p):
        along, radial, length = self._axial(p)
        beyond = along - along.clamp(min=0.0, max=float(length))
        return torch.sqrt(radial**2 + beyond**2) - self.radius

    def _mesh_along_z(self, length):
        import trimesh
        return trimesh.creation.capsule(height=length, radius=self.radius, count=[32, 32])


@dataclass(frozen=True)
class Cylinder(_SegmentObstacle):
    """Solid cylinder of `radius` [m] about the segment from `start` to `end`, flat ends."""

    name: str = "cylinder"

    def _sdf(self, p):
        along, radial, length = self._axial(p)
        axial = (along - 0.5 * length).abs() - 0.5 * length
        q = torch.stack((radial - self.radius, axial), dim=1)
        return q.clamp(min=0).norm(dim=1) + q.max(dim=1).values.clamp(max=0)

    def _mesh_along_z(self, length):
        import trimesh
        return trimesh.creation.cylinder(radius=self.radius, height=length, sections=48)


def _check_segment(obstacle) -> None:
    name = obstacle.name
    object.__setattr__(obstacle, "start", finite_vector(f"{name}: start", obstacle.start, 3))
    object.__setattr__(obstacle, "end", finite_vector(f"{name}: end", obstacle.end, 3))
    if np.linalg.norm(np.subtract(obstacle.end, obstacle.start)) == 0:
        raise ValueError(f"{name}: start and end must differ (zero length)")
    _finite(f"{name}: radius", obstacle.radius, positive=True)
    object.__setattr__(obstacle, "motion", _motion(name, obstacle.motion))


def _along_segment(vertices: np.ndarray, obstacle) -> np.ndarray:
    """Vertices of a mesh built along z, centred on the origin, moved onto the segment."""
    a, b = np.asarray(obstacle.start), np.asarray(obstacle.end)
    axis = (b - a) / np.linalg.norm(b - a)
    e1 = np.cross(axis, [1.0, 0, 0] if abs(axis[0]) < 0.9 else [0, 1.0, 0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    return 0.5 * (a + b) + vertices @ np.stack((e1, e2, axis))
