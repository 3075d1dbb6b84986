"""Reference mid-surface r(ξ) of a shell: the abstract interface, and the rigid placement
(origin and orientation) shared by the analytic surfaces."""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass

import torch

from taichi_ndf.geometry.domain import ParameterDomain

Vector3 = tuple[float, float, float]
IDENTITY_FRAME = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))


class ReferenceSurface(ABC):
    """A smooth (C²) map r: Ω → R³ from surface coordinates ξ to the undeformed mid-surface.

    Subclasses provide `domain` and implement `jets`.
    """

    domain: ParameterDomain

    @abstractmethod
    def jets(self, xi: torch.Tensor) -> torch.Tensor:
        """Jets of r at ξ (N, 2): shape (N, 6, 3), channels r, r_,1, r_,2, r_,11, r_,12, r_,22
        [m per unit of ξ to the power of the derivative order], dtype and device of ξ."""

    def positions(self, xi: torch.Tensor) -> torch.Tensor:
        """Reference positions r(ξ) [m], shape (N, 3)."""
        return self.jets(xi)[:, 0]


@dataclass(frozen=True, kw_only=True)
class PlacedSurface(ReferenceSurface):
    """A surface defined in its own local axes, then rigidly placed in the world.

    origin: world position [m] of the local origin.
    frame: (e_x, e_y, e_z), the world directions of the local axes; orthonormal and
        right-handed. World point = origin + x e_x + y e_y + z e_z.
    """

    origin: Vector3 = (0.0, 0.0, 0.0)
    frame: tuple[Vector3, Vector3, Vector3] = IDENTITY_FRAME

    def __post_init__(self):
        origin = tuple(float(v) for v in self.origin)
        if len(origin) != 3 or not all(math.isfinite(v) for v in origin):
            raise ValueError(f"origin must be 3 finite numbers [m], got {self.origin!r}")
        object.__setattr__(self, "origin", origin)
        object.__setattr__(self, "frame", checked_frame(self.frame))

    @abstractmethod
    def local_jets(self, xi: torch.Tensor) -> torch.Tensor:
        """Jets of r in the local axes, shape (N, 6, 3) [m]."""

    def jets(self, xi: torch.Tensor) -> torch.Tensor:
        local = self.local_jets(xi)
        frame = torch.tensor(self.frame, dtype=local.dtype, device=local.device)
        world = local @ frame
        world[:, 0] += torch.tensor(self.origin, dtype=local.dtype, device=local.device)
        return world


def checked_frame(frame) -> tuple[Vector3, Vector3, Vector3]:
    """A frame (e_x, e_y, e_z), the world directions of local axes, as a tuple of float rows;
    ValueError unless three finite 3-vectors, orthonormal and right-handed."""
    matrix = torch.tensor(frame, dtype=torch.float64)
    if matrix.shape != (3, 3) or not torch.isfinite(matrix).all():
        raise ValueError(f"frame must be three 3-vectors (e_x, e_y, e_z), got {frame!r}")
    if not torch.allclose(matrix @ matrix.T, torch.eye(3, dtype=torch.float64), atol=1e-9):
        raise ValueError("frame must be orthonormal (unit, mutually orthogonal e_x, e_y, e_z)")
    if torch.linalg.det(matrix) < 0:
        raise ValueError("frame must be right-handed (e_x × e_y = e_z)")
    return tuple(tuple(float(v) for v in row) for row in frame)


def require_positive(surface: ReferenceSurface, name: str, unit: str) -> float:
    """Check that the attribute `name` of a frozen surface is a finite number > 0 and store it
    as a float; ValueError naming the parameter otherwise."""
    value = float(getattr(surface, name))
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be a finite positive number [{unit}], got {value}")
    object.__setattr__(surface, name, value)
    return value


def require_turn(surface: ReferenceSurface, name: str) -> bool:
    """Check that the attribute `name` of a frozen surface is an angle in (0, 2π] [rad] and
    store it as a float; returns whether it is a whole turn (a periodic coordinate). A part of a
    turn has two edges, on which symmetry planes can cut a closed shell (quarter and octant
    models)."""
    angle = require_positive(surface, name, "rad")
    if angle > 2 * math.pi * (1 + 1e-12):
        raise ValueError(f"{name} must be at most 2π (one turn) [rad], got {angle}")
    return angle >= 2 * math.pi * (1 - 1e-12)
