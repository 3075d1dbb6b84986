"""Contact with rigid obstacles: obstacles with signed distances, the IPC barrier term, the
dense check points and penetration filter, the hook every minimiser calls (docs/contact.md)."""

from taichi_ndf.contact.barrier import ContactTerm, barrier
from taichi_ndf.contact.check_points import ContactPoints
from taichi_ndf.contact.config import ContactConfig
from taichi_ndf.contact.hook import ContactHook
from taichi_ndf.contact.mesh_obstacle import MeshObstacle
from taichi_ndf.contact.obstacles import (
    Capsule,
    Cylinder,
    GroundPlane,
    Obstacle,
    RoundedBox,
    Sphere,
)

__all__ = ["Capsule", "ContactConfig", "ContactHook", "ContactPoints", "ContactTerm", "Cylinder",
           "GroundPlane", "MeshObstacle", "Obstacle", "RoundedBox", "Sphere", "barrier"]
