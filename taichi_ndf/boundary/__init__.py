"""Boundary conditions enforced exactly by construction: u_c = φ_c N_c + g_c."""

from taichi_ndf.boundary.conditions import BoundaryConditions
from taichi_ndf.boundary.constraints import (
    EDGES,
    PIN_ROTATIONS,
    ClampedEdge,
    Constraint,
    Handle,
    HingedEdge,
    InteriorLine,
    PinnedPoint,
    RimRotation,
    SymmetryPlane,
)

__all__ = [
    "BoundaryConditions",
    "Constraint",
    "EDGES",
    "PIN_ROTATIONS",
    "ClampedEdge",
    "HingedEdge",
    "PinnedPoint",
    "Handle",
    "InteriorLine",
    "RimRotation",
    "SymmetryPlane",
]
