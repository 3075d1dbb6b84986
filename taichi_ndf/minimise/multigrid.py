"""Geometric multigrid for the Newton systems of a spline field, and preconditioned CG.

The hierarchy is the field's own: a grid of n1 × n2 knot spans is the exact dyadic refinement
of the grid of n1/2 × n2/2 spans, so the coarse coefficients C_c map to fine ones by the
refinement matrix P (`SplineField.prolongation`), applied to each of the 3 components of a
coefficient (unknowns are coefficient × 3 + component). `spline_prolongations` halves the
grid while it has more than `coarsest` unknowns, both span counts are even and the coarser
grid keeps at least p + 1 spans per direction.

`VCycle` is a symmetric V-cycle on the free unknowns of the fine system A (N × N, symmetric
positive definite): on each level the unknowns that can move (`active`: a non-zero diagonal,
so held unknowns and coefficients no quadrature point couples drop out), Galerkin coarse
operators A_c = Pᵀ A P with P restricted to the active unknowns of both levels, a
symmetric Gauss–Seidel smoother over each coefficient's 3 × 3 block (a forward sweep before
the coarse correction, a backward sweep after: the cycle is a symmetric operator, positive
definite when A is; measured against point Gauss–Seidel and block Jacobi in
benchmarks/RESULTS.md, it needs the fewest iterations) and a direct
solve (SuperLU) on the coarsest level. `conjugate_gradients` is CG preconditioned by any
such operator; it stops on a relative residual ‖b − A x‖ ≤ tolerance ‖b‖ and reports
negative curvature (pᵀ A p ≤ 0: A is not positive definite) and a breakdown of the
preconditioner (rᵀ M⁻¹ r ≤ 0) instead of going on.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
import torch

from taichi_ndf.field.spline import SplineConfig, SplineField
from taichi_ndf.shell.hessian import COMPONENTS

log = logging.getLogger(__name__)

SMOOTHERS = ("gauss_seidel", "jacobi")
# Block-Jacobi damping ω (× the inverse of each coefficient's 3 × 3 block).
JACOBI_WEIGHT = 0.5


def spline_prolongations(config: SplineConfig, coarsest: int) -> list[sp.csr_matrix]:
    """Refinement matrices over unknowns (coefficient × 3 + component), finest first: entry l
    maps the unknowns of grid l + 1 (coarser) to those of grid l, grid 0 being `config`'s.
    Empty when the grid cannot be halved (an odd span count) or has at most `coarsest`
    unknowns (module docstring)."""
    out = []
    while True:
        spans = config.spans
        if (COMPONENTS * config.num_coefficients <= coarsest
                or any(n % 2 or n // 2 < config.degree + 1 for n in spans)):
            break
        coarse = SplineConfig(spans=(spans[0] // 2, spans[1] // 2), degree=config.degree,
                              out_dim=config.out_dim, domain=config.domain,
                              periodic=config.periodic, even_ends=config.even_ends)
        p = SplineField(coarse, dtype=torch.float64, device="cpu").prolongation()
        rows, cols = p.indices().numpy()
        coefficients = sp.csr_matrix((p.values().numpy(), (rows, cols)), shape=tuple(p.shape))
        out.append(sp.kron(coefficients, sp.identity(COMPONENTS), format="csr"))
        config = coarse
    return out


def active_unknowns(matrix: sp.csr_matrix) -> np.ndarray:
    """Indices of the unknowns with a non-zero diagonal (the others have a zero row in a
    positive semi-definite matrix: nothing couples them)."""
    return active_of_diagonal(matrix.diagonal())


def active_of_diagonal(diagonal: np.ndarray) -> np.ndarray:
    """`active_unknowns` from the matrix's diagonal."""
    diagonal = np.abs(diagonal)
    return np.flatnonzero(diagonal > 1e-14 * max(float(diagonal.max(initial=0)), 1e-300))


def _sorted_csr(matrix: sp.spmatrix) -> sp.csr_matrix:
    """The matrix as CSR with sorted column indices (a copy only where needed: the caller's
    matrix is not changed)."""
    matrix = matrix.tocsr()
    return matrix if matrix.has_sorted_indices else matrix.sorted_indices()


class _Pattern(NamedTuple):
    """A CSR matrix's pattern without its values (a released V-cycle's levels)."""

    shape: tuple[int, int]
    indptr: np.ndarray
    indices: np.ndarray


def _same_pattern(a: sp.csr_matrix | _Pattern, b: sp.csr_matrix) -> bool:
    return (a.shape == b.shape and np.array_equal(a.indptr, b.indptr)
            and np.array_equal(a.indices, b.indices))


class _Smoother:
    """Symmetric block Gauss–Seidel or damped block Jacobi over the 3 × 3 block of each
    coefficient (`block`: the coefficient of each unknown). Gauss–Seidel sweeps with the
    block-lower part (diagonal blocks included) forward and the block-upper part backward,
    each factorised once (SuperLU on a block-triangular matrix with the natural order fills
    nothing in: a block-triangular solve); Jacobi with the block diagonal.

    The parts are taken from the symmetric `matrix` (CSR, sorted indices) without a format
    conversion: the CSR arrays of its block-upper part, read as CSC, are the block-lower part
    (its transpose), and the reverse. Which entries belong to each part depends only on the
    pattern: `reuse`, a smoother of a matrix with the same pattern and blocks, lends its
    selections."""

    def __init__(self, matrix: sp.csr_matrix, kind: str, block: np.ndarray,
                 reuse: _Smoother | None = None):
        self.matrix = matrix
        self.kind = kind
        if reuse is None:
            row = block[np.repeat(np.arange(matrix.shape[0]), np.diff(matrix.indptr))]
            col = block[matrix.indices]
            # read as CSC: the upper part gives the lower one (class docstring)
            parts = [row == col] if kind == "jacobi" else [row <= col, row >= col]
            self.parts = [_Part(matrix, keep) for keep in parts]
        else:
            self.parts = reuse.parts
        options = dict(permc_spec="NATURAL", diag_pivot_thresh=0.0,
                       options={"SymmetricMode": True})
        factors = [spla.splu(part.csc_transpose(matrix), **options) for part in self.parts]
        self.lower, self.upper = factors[0], factors[-1]

    def pre(self, rhs: np.ndarray) -> np.ndarray:
        """The smoothed solution of A x = rhs from x = 0."""
        x = self.lower.solve(rhs)
        return JACOBI_WEIGHT * x if self.kind == "jacobi" else x

    def post(self, x: np.ndarray, rhs: np.ndarray) -> np.ndarray:
        """x after one sweep, the adjoint of `pre`."""
        correction = self.upper.solve(rhs - self.matrix @ x)
        return x + (JACOBI_WEIGHT * correction if self.kind == "jacobi" else correction)


class _Part:
    """The entries `keep` (bool, in CSR order) of a CSR pattern as a CSR structure."""

    def __init__(self, matrix: sp.csr_matrix, keep: np.ndarray):
        self.select = np.flatnonzero(keep)
        rows = np.repeat(np.arange(matrix.shape[0]), np.diff(matrix.indptr))[self.select]
        self.indptr = np.concatenate(([0], np.cumsum(np.bincount(
            rows, minlength=matrix.shape[0])))).astype(matrix.indptr.dtype)
        self.indices = matrix.indices[self.select]

    def csc_transpose(self, matrix: sp.csr_matrix) -> sp.csc_matrix:
        """The part of `matrix` (this pattern), transposed, as CSC (no conversion)."""
        return sp.csc_matrix((matrix.data[self.select], self.indices, self.indptr),
                             shape=matrix.shape)


@dataclass
class _Level:
    matrix: sp.csr_matrix
    rows: np.ndarray  # this level's unknowns in the numbering of its prolongation's rows
    smoother: _Smoother | None = None
    restricted: sp.csr_matrix | None = None  # the prolongation's rows of this level's unknowns
    keep: np.ndarray | None = None  # the coarser level's active unknowns
    prolongation: sp.csr_matrix | None = None  # this level's active unknowns <- coarser ones
    restriction: sp.csr_matrix | None = None  # its transpose


class VCycle:
    """The symmetric V-cycle M⁻¹ (module docstring) of a symmetric positive definite `matrix`
    (N × N) over unknowns numbered as the finest prolongation's rows restricted to `unknowns`
    (N indices; the fine system's free unknowns, coefficient × 3 + component).

    prolongations: `spline_prolongations`, finest first. smoother: one of SMOOTHERS.
    reuse: the V-cycle of the previous Newton step: on each level where the matrix's pattern
    and unknowns are the same, its restricted prolongations and the smoother's selections
    are kept (only the Galerkin products and the factorisations are redone).
    Raises RuntimeError when the coarsest factorisation fails (singular)."""

    def __init__(self, matrix: sp.csr_matrix, unknowns: np.ndarray,
                 prolongations: list[sp.csr_matrix], smoother: str = "gauss_seidel",
                 reuse: VCycle | None = None):
        if smoother not in SMOOTHERS:
            raise ValueError(f"smoother must be one of {SMOOTHERS}, got {smoother!r}")
        self.smoother = smoother
        self.levels: list[_Level] = []
        rows = np.asarray(unknowns)
        matrix = _sorted_csr(matrix)
        old_levels = reuse.levels if reuse is not None and reuse.smoother == smoother else []
        for depth, full in enumerate(prolongations):
            old = old_levels[depth] if depth < len(old_levels) else None
            same = (old is not None and np.array_equal(old.rows, rows)
                    and _same_pattern(old.matrix, matrix))
            level = _Level(matrix, rows, _Smoother(matrix, smoother, rows // COMPONENTS,
                                                   old.smoother if same else None))
            level.restricted = old.restricted if same else full[rows].tocsr()
            coarse = (level.restricted.T @ (matrix @ level.restricted)).tocsr()
            level.keep = active_unknowns(coarse)
            if same and np.array_equal(level.keep, old.keep):
                level.prolongation, level.restriction = old.prolongation, old.restriction
            else:
                level.prolongation = level.restricted[:, level.keep].tocsr()
                level.restriction = level.prolongation.T.tocsr()
            self.levels.append(level)
            matrix = _sorted_csr(coarse[level.keep][:, level.keep])
            rows = level.keep
        self.coarsest = spla.splu(matrix.tocsc(), permc_spec="MMD_AT_PLUS_A",
                                  diag_pivot_thresh=0.0, options={"SymmetricMode": True})
        self.sizes = [lv.matrix.shape[0] for lv in self.levels] + [matrix.shape[0]]

    def __call__(self, residual: np.ndarray) -> np.ndarray:
        return self._cycle(0, residual)

    def release(self) -> VCycle:
        """Keep only what `reuse` reads (each level's pattern, unknowns and prolongations, the
        smoothers' selections) and let the matrices' values and the factorisations go (a
        copy of K and more, held between Newton steps otherwise); not applicable after."""
        for level in self.levels:
            level.matrix = _Pattern(level.matrix.shape, level.matrix.indptr,
                                    level.matrix.indices)
            level.smoother.matrix = level.smoother.lower = level.smoother.upper = None
        self.coarsest = None
        return self

    def _cycle(self, depth: int, rhs: np.ndarray) -> np.ndarray:
        if depth == len(self.levels):
            return self.coarsest.solve(rhs)
        level = self.levels[depth]
        x = level.smoother.pre(rhs)
        coarse_rhs = level.restriction @ (rhs - level.matrix @ x)
        x = x + level.prolongation @ self._cycle(depth + 1, coarse_rhs)
        return level.smoother.post(x, rhs)


@dataclass
class CGResult:
    """x, the iterations taken, the final relative residual ‖b − A x‖/‖b‖ and the status:
    "converged", "not converged" (max_iterations reached), "negative curvature" (pᵀ A p ≤ 0)
    or "preconditioner" (rᵀ M⁻¹ r ≤ 0: M is not positive definite); seconds of the
    preconditioner's setup and of the iterations where the caller timed them."""

    x: np.ndarray
    iterations: int
    residual: float
    status: str
    setup_seconds: float = 0.0
    solve_seconds: float = 0.0


def conjugate_gradients(matrix: sp.csr_matrix, rhs: np.ndarray, precondition,
                        tolerance: float, max_iterations: int) -> CGResult:
    """Preconditioned CG for A x = b from x = 0 (module docstring); precondition(r) = M⁻¹ r."""
    x = np.zeros_like(rhs)
    norm = float(np.linalg.norm(rhs))
    if norm == 0.0:
        return CGResult(x, 0, 0.0, "converged")
    r = rhs.copy()
    z = precondition(r)
    rz = float(r @ z)
    if not rz > 0:
        return CGResult(x, 0, 1.0, "preconditioner")
    p = z
    for iteration in range(1, max_iterations + 1):
        q = matrix @ p
        curvature = float(p @ q)
        if not curvature > 0:
            return CGResult(x, iteration, float(np.linalg.norm(r)) / norm,
                            "negative curvature")
        alpha = rz / curvature
        x += alpha * p
        r -= alpha * q
        residual = float(np.linalg.norm(r)) / norm
        if residual <= tolerance:
            return CGResult(x, iteration, residual, "converged")
        z = precondition(r)
        rz_next = float(r @ z)
        if not rz_next > 0:
            return CGResult(x, iteration, residual, "preconditioner")
        p = z + (rz_next / rz) * p
        rz = rz_next
    return CGResult(x, max_iterations, residual, "not converged")
