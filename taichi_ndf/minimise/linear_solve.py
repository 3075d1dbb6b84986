"""Sparse symmetric positive (semi-)definite solves K d = −g of projected Newton.

One direct method, chosen by measurement on this project's machine (benchmarks/RESULTS.md):
scipy's SuperLU with a minimum-degree ordering on Kᵀ + K and no pivoting (K is symmetric
positive definite after projection and damping, so the diagonal is a stable pivot). Unknowns
listed in `fixed` (gauge freedoms, e.g. the constant shift of a free-pinned field) are held
at zero. Levenberg–Marquardt damping μ · diag(K) keeps near-singular systems (zero-energy
motions, a flat sheet under a transverse load) solvable; it is raised tenfold while the
factorisation fails.
"""

from __future__ import annotations

import logging

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

log = logging.getLogger(__name__)

MAX_DAMPING_RAISES = 12


def damped_solve(matrix: sp.csr_matrix, rhs: np.ndarray, damping: float,
                 fixed: np.ndarray | None = None, *, require_definite: bool = False
                 ) -> tuple[np.ndarray, float] | None:
    """Solve (K + μ D) x = rhs over the free unknowns (x = 0 at `fixed`), D = diag(K) (the
    mean diagonal where an entry of it is 0), μ = damping (raised ×10 from at least 1e-12
    while the factorisation fails). Returns x and the μ used.

    require_definite: return None unless K + μ D is positive definite (all pivots of the
    symmetric-mode factorisation positive: its inertia), without raising μ."""
    size = matrix.shape[0]
    free = np.ones(size, dtype=bool)
    if fixed is not None:
        free[fixed] = False
    reduced = matrix[free][:, free].tocsc()
    diag = reduced.diagonal().copy()
    mean = float(np.abs(diag).mean()) or 1.0
    diag[diag <= 0] = mean
    mu = damping
    for _ in range(MAX_DAMPING_RAISES):
        system = reduced + sp.diags(mu * diag, format="csc") if mu > 0 else reduced
        try:
            factor = spla.splu(system, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                               options={"SymmetricMode": True})
            solution = factor.solve(rhs[free])
        except RuntimeError as err:  # exactly singular
            if require_definite:
                return None
            log.debug("factorisation failed at damping %g: %s", mu, err)
            mu = max(10 * mu, 1e-12)
            continue
        if require_definite and not _positive_pivots(factor):
            return None
        if np.all(np.isfinite(solution)):
            out = np.zeros(size)
            out[free] = solution
            return out, mu
        mu = max(10 * mu, 1e-12)
    raise RuntimeError(f"the Newton system stayed singular up to damping {mu:g}")


def _positive_pivots(factor) -> bool:
    """Whether a symmetric-mode LU of a symmetric matrix has only positive pivots (then it is
    LDLᵀ with D > 0 under one symmetric permutation: the matrix is positive definite)."""
    if not np.array_equal(factor.perm_r, factor.perm_c):
        return False
    return bool(np.all(factor.U.diagonal() > 0))
