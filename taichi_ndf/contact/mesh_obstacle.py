"""A closed triangle mesh as a rigid obstacle: exact point-to-triangle distance in Taichi.

For every query point the kernel visits every triangle (brute force, parallel over points):
the closest point on each triangle (Ericson, Real-Time Collision Detection §5.1.5) gives the
unsigned distance and the nearest point q; the generalised winding number (sum of the
triangles' solid angles / 4π, Van Oosterom–Strackee) gives the sign: a point is inside where
its magnitude exceeds 1/2, exact for a closed, consistently oriented mesh (outward or
inward). The gradient of the signed distance is sign · (x − q)/|x − q|, the exact one wherever
the closest point is unique.

Cost: points × triangles. Measured (tests/test_contact_obstacles.py prints it with -s): see
docs/contact.md; a uniform grid of triangle lists would cut it for large meshes but is not
built.
"""


import functools
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from taichi_ndf.contact.obstacles import Obstacle, _motion
from taichi_ndf.runtime import ti


@ti.func
def _closest_on_triangle(p, a, b, c):
    """The point of triangle abc closest to p (Ericson's Voronoi-region tests)."""
    ab = b - a
    ac = c - a
    ap = p - a
    d1 = ab.dot(ap)
    d2 = ac.dot(ap)
    bp = p - b
    d3 = ab.dot(bp)
    d4 = ac.dot(bp)
    cp = p - c
    d5 = ab.dot(cp)
    d6 = ac.dot(cp)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    result = a
    if d1 <= 0 and d2 <= 0:
        result = a
    elif d3 >= 0 and d4 <= d3:
        result = b
    elif vc <= 0 and d1 >= 0 and d3 <= 0:
        result = a + d1 / (d1 - d3) * ab
    elif d6 >= 0 and d5 <= d6:
        result = c
    elif vb <= 0 and d2 >= 0 and d6 <= 0:
        result = a + d2 / (d2 - d6) * ac
    elif va <= 0 and (d4 - d3) >= 0 and (d5 - d6) >= 0:
        result = b + (d4 - d3) / ((d4 - d3) + (d5 - d6)) * (c - b)
    else:
        denom = 1.0 / (va + vb + vc)
        result = a + ab * (vb * denom) + ac * (vc * denom)
    return result


@ti.func
def _solid_angle(a, b, c):
    """Signed solid angle of triangle abc seen from the origin."""
    la, lb, lc = a.norm(), b.norm(), c.norm()
    numerator = a.dot(b.cross(c))
    denominator = la * lb * lc + a.dot(b) * lc + a.dot(c) * lb + b.dot(c) * la
    return 2.0 * ti.atan2(numerator, denominator)


@functools.cache
def _distance_kernel():
    @ti.kernel
    def distance(points: ti.types.ndarray(), vertices: ti.types.ndarray(),
                 faces: ti.types.ndarray(), out_distance: ti.types.ndarray(),
                 out_normal: ti.types.ndarray()):
        for i in range(points.shape[0]):
            p = ti.Vector([points[i, 0], points[i, 1], points[i, 2]])
            best = p.norm_sqr() * 0 + 1e300  # in the points' dtype
            nearest = p
            winding = p[0] * 0
            for f in range(faces.shape[0]):
                ia, ib, ic = faces[f, 0], faces[f, 1], faces[f, 2]
                a = ti.Vector([vertices[ia, 0], vertices[ia, 1], vertices[ia, 2]])
                b = ti.Vector([vertices[ib, 0], vertices[ib, 1], vertices[ib, 2]])
                c = ti.Vector([vertices[ic, 0], vertices[ic, 1], vertices[ic, 2]])
                q = _closest_on_triangle(p, a, b, c)
                d2 = (p - q).norm_sqr()
                if d2 < best:
                    best = d2
                    nearest = q
                winding += _solid_angle(a - p, b - p, c - p)
            sign = 1.0
            if ti.abs(winding) > 2.0 * math.pi:  # |winding number| > 1/2: inside
                sign = -1.0
            dist = ti.sqrt(best)
            out_distance[i] = sign * dist
            offset = p - nearest
            if dist > 0:
                offset = offset / dist
            for k in ti.static(range(3)):
                out_normal[i, k] = sign * offset[k]

    return distance


@dataclass(frozen=True)
class MeshObstacle(Obstacle):
    """A closed (watertight) triangle mesh; `vertices` (V, 3) [m], `faces` (F, 3)."""

    name: str = "mesh"
    vertices: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    faces: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), dtype=np.int64))
    motion: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self):
        vertices = np.asarray(self.vertices, dtype=np.float64)
        faces = np.asarray(self.faces, dtype=np.int64)
        if vertices.ndim != 2 or vertices.shape[1] != 3 or faces.ndim != 2 \
                or faces.shape[1] != 3 or len(faces) == 0:
            raise ValueError(f"{self.name}: a mesh obstacle needs vertices (V, 3) and faces "
                             f"(F, 3), got {vertices.shape} and {faces.shape}")
        if not np.isfinite(vertices).all():
            raise ValueError(f"{self.name}: non-finite vertex coordinates")
        import trimesh  # on first use: ~0.9 s of imports (scipy, networkx)
        mesh = trimesh.Trimesh(vertices, faces, process=True)
        if not mesh.is_watertight:
            raise ValueError(f"{self.name}: the mesh is not closed (it has boundary edges or "
                             f"non-manifold edges), so inside and outside are undefined")
        object.__setattr__(self, "vertices", np.asarray(mesh.vertices))
        object.__setattr__(self, "faces", np.asarray(mesh.faces, dtype=np.int32))
        object.__setattr__(self, "motion", _motion(self.name, self.motion))

    @classmethod
    def from_file(cls, path: str | Path, *, name: str | None = None, scale: float = 1.0,
                  offset=(0.0, 0.0, 0.0), motion=(0.0, 0.0, 0.0)) -> "MeshObstacle":
        """Read an OBJ/PLY/STL file (trimesh), scale it by `scale` and move it by `offset`
        [m]."""
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"obstacle mesh not found: {path}")
        if not (math.isfinite(scale) and scale > 0):
            raise ValueError(f"{name or path.stem}: scale must be > 0, got {scale!r}")
        import trimesh
        mesh = trimesh.load(path, force="mesh", process=False)
        vertices = np.asarray(mesh.vertices) * scale + np.asarray(offset, dtype=np.float64)
        return cls(name=name or path.stem, vertices=vertices, faces=np.asarray(mesh.faces),
                   motion=motion)

    def signed_distance(self, x: torch.Tensor, load_factor: float = 1.0
                        ) -> tuple[torch.Tensor, torch.Tensor]:
        local = (x - load_factor * x.new_tensor(self.motion)).detach().contiguous()
        vertices = torch.as_tensor(self.vertices, dtype=x.dtype, device=x.device)
        faces = torch.as_tensor(self.faces, dtype=torch.int32, device=x.device)
        distance = x.new_empty(x.shape[0])
        normal = x.new_empty(x.shape[0], 3)
        if x.shape[0]:
            _distance_kernel()(local, vertices, faces, distance, normal)
        return distance, normal

    def _mesh(self):
        return np.asarray(self.vertices), np.asarray(self.faces)
