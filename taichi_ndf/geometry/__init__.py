"""Reference surfaces and their parameter domains."""

from taichi_ndf.geometry.analytic import Annulus, Cone, Cylinder, CylindricalRoof, Plane
from taichi_ndf.geometry.domain import ParameterDomain
from taichi_ndf.geometry.mesh_surface import MeshSurface
from taichi_ndf.geometry.sphere import Hemisphere
from taichi_ndf.geometry.surface import PlacedSurface, ReferenceSurface

__all__ = [
    "ParameterDomain",
    "ReferenceSurface",
    "PlacedSurface",
    "Plane",
    "Annulus",
    "Cylinder",
    "Cone",
    "CylindricalRoof",
    "Hemisphere",
    "MeshSurface",
]
