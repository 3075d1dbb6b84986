"""The axes a boundary's components refer to: the world axes, or a fixed tilted frame.

A frame F (rows e_x, e_y, e_z: world directions, orthonormal, right-handed) makes a
constraint's components and a symmetry plane's normal refer to its axes. The composition then
holds per component along them, u = Fᵀ (φ ⊙ N + g): the raw field's components and the
vanishing factors are frame components, prescribed motions are turned into the frame, and the
result back to world components. F is orthogonal, so a gradient with respect to world
components turns into the frame like a vector (F g), and a Hessian block like F H Fᵀ.
"""

from __future__ import annotations

import torch

from taichi_ndf import jets
from taichi_ndf.geometry.surface import IDENTITY_FRAME, checked_frame


class ComponentFrame:
    """rows: (e_x, e_y, e_z) or None (the world axes). `rows` is None for the world axes
    given either way."""

    def __init__(self, rows=None):
        rows = None if rows is None else checked_frame(rows)
        self.rows = None if rows == IDENTITY_FRAME else rows
        self._matrix = None if self.rows is None else torch.tensor(self.rows, dtype=torch.float64)

    @property
    def tilted(self) -> bool:
        return self.rows is not None

    def to_world(self, local: torch.Tensor) -> torch.Tensor:
        """Vectors (…, 3) given along the frame's axes, in world components: Fᵀ v."""
        if self._matrix is None:
            return local
        return local @ self._matrix.to(dtype=local.dtype, device=local.device)

    def to_frame(self, world: torch.Tensor) -> torch.Tensor:
        """World vectors (…, 3) along the frame's axes, F v; also the gradient with respect
        to the frame components of a scalar from its gradient with respect to the world
        ones."""
        if self._matrix is None:
            return world
        return world @ self._matrix.to(dtype=world.dtype, device=world.device).T

    def blocks_to_frame(self, blocks: torch.Tensor) -> torch.Tensor:
        """Per-point Hessian blocks (n, 18, 18) (index channel × 3 + component) with respect to
        world components, with respect to the frame's: F H Fᵀ per pair of channels."""
        if self._matrix is None:
            return blocks
        n = blocks.shape[0]
        split = blocks.reshape(n, jets.CHANNELS, 3, jets.CHANNELS, 3)
        split = self.to_frame(split.transpose(2, 4)).transpose(2, 4)   # the left component
        return self.to_frame(split).reshape(n, 3 * jets.CHANNELS, 3 * jets.CHANNELS)
