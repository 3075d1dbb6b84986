"""Held edges of flat-cut garment panels (`problem.multipatch.Patch.held`): the joined
linearisation with the held edges clamped where the start put them (`HeldEdges`), and the
path of the held rows towards a held target over the load steps (`held_moves`: a gathered
waist).

A clamp holds an edge's position and its derivative across the edge, nothing more (the
single-patch clamp, u = φ N with φ vanishing quadratically at the edge, holds the same). On
the uniform unclamped splines (`taichi_ndf.field.bspline`) both depend on the p rows of
coefficients nearest the edge, through a 2 × p matrix A per row of the edge (cubic, at
ξ = lo: value (c₀ + 4 c₁ + c₂)/6, slope (c₂ − c₀)/2h), so a clamp leaves p − 2 combinations of
those rows free (cubic: c ← c + a (1, −½, 1), the edge's curvature). The held steps are
C = T z: T the identity except that the two rows of an edge farthest from it follow its p − 2
nearest ones (their columns of A solved for), and the two followers held (no own step):
gradient Tᵀ g, Hessian Tᵀ K T, step T z. Holding all p rows instead held the edge's
curvature too: stiffer than a clamp, and more so on coarse grids."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import torch

from taichi_ndf.field.bspline import piece_coefficients
from taichi_ndf.minimise.multipatch import MultiPatchLinearisation
from taichi_ndf.problem.multipatch import COMPONENTS


def edge_constraint(degree: int, side: str) -> np.ndarray:
    """A (2, p): the value and the derivative (per span, d/dt) of an open direction's field
    at its edge `side` ("min": ξ = lo, rows 0 … p − 1; "max": ξ = hi, rows m − p … m − 1) as
    combinations of the p rows nearest it."""
    pieces = [[float(c) for c in piece] for piece in piece_coefficients(degree)]
    if side == "min":  # span 0 at u = 0: coefficient a weighs piece a's constant term
        return np.array([[piece[0] for piece in pieces[:degree]],
                         [piece[1] for piece in pieces[:degree]]])
    return np.array([[sum(pieces[a]) for a in range(1, degree + 1)],  # last span at u = 1
                     [sum(k * c for k, c in enumerate(pieces[a])) for a in range(1, degree + 1)]])


def direction_map(count: int, degree: int, sides: tuple[str, ...]
                  ) -> tuple[np.ndarray, np.ndarray]:
    """(T (count, count), followers): the step map of one open direction of `count`
    coefficients with its edges `sides` ("min", "max") clamped (module docstring), and the
    rows that follow (held: no step of their own)."""
    if len(sides) == 2 and count < 2 * degree:
        raise ValueError(f"both edges of a direction of {count} coefficients held: they "
                         f"share rows (at least {degree} spans needed)")
    t = np.eye(count)
    followers = []
    for side in sides:
        rows = np.arange(degree) if side == "min" else np.arange(count - degree, count)
        lead, follow = ((rows[:degree - 2], rows[degree - 2:]) if side == "min"
                        else (rows[2:], rows[:2]))
        a = edge_constraint(degree, side)
        at = {int(r): k for k, r in enumerate(rows)}
        coupling = np.linalg.solve(a[:, [at[int(r)] for r in follow]],
                                   -a[:, [at[int(r)] for r in lead]])
        t[np.ix_(follow, lead)] = coupling
        t[follow, follow] = 0.0
        followers.extend(int(r) for r in follow)
    return t, np.array(sorted(followers), dtype=np.int64)


def patch_map(patch) -> tuple[sp.csr_matrix, np.ndarray]:
    """(T, held): the step map of a `Patch`'s unknowns (3 per coefficient, coefficient
    i₁ m₂ + i₂) with its `held` edges clamped, and its held unknowns (the followers')."""
    (m1, m2), p = patch.config.coefficient_counts, patch.config.degree
    maps = [direction_map(m, p, tuple(side for side in ("min", "max")
                                      if f"xi{d + 1}_{side}" in patch.held))
            for d, m in enumerate((m1, m2))]
    (t1, f1), (t2, f2) = maps
    t = sp.kron(sp.kron(sp.csr_matrix(t1), sp.csr_matrix(t2)), sp.identity(COMPONENTS))
    held = np.zeros((m1, m2), dtype=bool)
    held[f1, :] = True
    held[:, f2] = True
    coefficients = np.flatnonzero(held.reshape(-1))
    unknowns = (coefficients[:, None] * COMPONENTS + np.arange(COMPONENTS)).reshape(-1)
    return t.tocsr(), unknowns


class HeldEdges(MultiPatchLinearisation):
    """`MultiPatchLinearisation` of `grids` with the held edges of `patches` (`Patch.held`)
    clamped where the current coefficients put them (module docstring): gradient, Hessian
    and step through the step map T. held: the held (follower) unknowns, sorted, into the
    joint unknowns (None: no patch has held edges)."""

    def __init__(self, grids, load_factor: float, patches):
        super().__init__(grids, load_factor)
        maps, held = [], []
        for patch, offset, size in zip(patches, self.unknown_offsets(), self._sizes(),
                                       strict=True):
            if patch.held:
                t, h = patch_map(patch)
                maps.append(t)
                held.append(h + offset)
            else:
                maps.append(sp.identity(size, format="csr"))
        self.held = np.concatenate(held) if held else None
        self.map = sp.block_diag(maps, format="csr") if held else None
        if self.held is not None:
            self.fixed = self.held if self.fixed is None else np.union1d(self.fixed, self.held)

    def unknown_offsets(self) -> list[int]:
        """Each patch's first joint unknown (3 per coefficient, in the plan's order)."""
        return [COMPONENTS * o for o in self.coefficient_offsets[:-1]]

    def _sizes(self) -> list[int]:
        offsets = self.coefficient_offsets
        return [COMPONENTS * (b - a) for a, b in zip(offsets[:-1], offsets[1:], strict=True)]

    def gradient(self, grad_u_jets: torch.Tensor) -> torch.Tensor:
        """Tᵀ g, 0 at the held unknowns: the gradient over the clamp's free directions."""
        gradient = super().gradient(grad_u_jets)
        if self.map is None:
            return gradient
        g = self.map.T @ gradient.reshape(-1).double().cpu().numpy()
        g[self.held] = 0.0
        return torch.from_numpy(g).to(gradient).reshape(gradient.shape)

    def hessian(self, blocks, couplings=None) -> sp.csr_matrix:
        """Tᵀ K T (K: `MultiPatchLinearisation.hessian`)."""
        matrix = super().hessian(blocks, couplings)
        if self.map is None:
            return matrix
        return (self.map.T @ matrix @ self.map).tocsr()

    def solve(self, matrix: sp.csr_matrix, gradient: torch.Tensor, damping: float, *,
              require_definite: bool = False) -> tuple[torch.Tensor, float] | None:
        """The step T z, z from the reduced system (`MultiPatchLinearisation.solve`)."""
        result = super().solve(matrix, gradient, damping, require_definite=require_definite)
        if result is None or self.map is None:
            return result
        step, damping = result
        full = self.map @ step.reshape(-1).double().cpu().numpy()
        return torch.from_numpy(full).to(step).reshape(step.shape), damping


def held_moves(patches, targets, linear: HeldEdges, start: torch.Tensor):
    """(unknowns, start values, target values) of the p rows at the held edges
    (`Patch.held_unknowns`) of the patches that have a held target (`targets`: per patch
    the fitted target field or None), numbered as `linear`'s joint unknowns, the start
    values from the joint start coefficients `start` (the fitted placement); None: none.
    Rows set between the two hold the edge's position and slope between the start's and
    the target's (their curvature combination is then free again: `HeldEdges`)."""
    index, target = [], []
    for patch, field, offset in zip(patches, targets, linear.unknown_offsets(), strict=False):
        if field is not None:
            held = patch.held_unknowns()
            index.append(torch.from_numpy(held + offset))
            target.append(field.coefficients.detach().reshape(-1)[held])
    if not index:
        return None
    index = torch.cat(index)
    return index, start.reshape(-1)[index].clone(), torch.cat(target).to(start)
