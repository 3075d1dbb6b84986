"""Sparse symmetric positive (semi-)definite solves K d = −g of projected Newton.

Two direct methods, chosen by measurement on this project's machine (benchmarks/RESULTS.md):
a banded Cholesky factorisation (LAPACK dpbtrf) where K's half-bandwidth b in the given
order is at most `BAND_LIMIT` × √N (N unknowns: a spline grid's coefficients numbered row by
row, b ≈ 3 p × its coefficients per row ≈ 5.2 √N for cubics; 7.5× faster than SuperLU on the
napkin's 28² system), else scipy's SuperLU with a minimum-degree ordering on Kᵀ + K and no
pivoting (K is symmetric positive definite after projection and damping, so the diagonal is a
stable pivot; a dense row, e.g. a free pin's couplings, or a periodic wrap across rows makes
the band too wide). A system that the Cholesky factorisation finds not positive definite is
refactorised by SuperLU at the same damping (which also solves a regular indefinite K, e.g.
unprojected Newton), unless the caller only wants a definite one. Unknowns
listed in `fixed` (gauge freedoms, e.g. the constant shift of a free-pinned field) are held
at zero. Levenberg–Marquardt damping μ · diag(K) keeps near-singular systems (zero-energy
motions, a flat sheet under a transverse load) solvable; it is raised tenfold while the
factorisation fails.

`LinearSolver` chooses between that direct solve and conjugate gradients preconditioned by a
geometric multigrid V-cycle over the spline grid's own dyadic hierarchy
(`taichi_ndf.minimise.multigrid`): "direct", "multigrid", or "auto" (multigrid, where the
grid can be coarsened, from `band_threshold` unknowns, or from `threshold` unknowns when the
band is too wide for the banded factorisation). The multigrid path keeps
`damped_solve`'s contract (held unknowns stay 0, the same damping, require_definite) and
falls back to the direct solve, with a logged note, when CG meets negative curvature or does
not converge — except under require_definite, where either answers "not definite" (None)
without a factorisation (projected Newton then projects the blocks, as after failed pivots).
Converging without meeting negative curvature is taken as definite there (CG does not prove
it: a Newton step on an indefinite K that CG happens to solve is still checked by the line
search and the decrement's sign).
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from scipy.linalg import lapack

from taichi_ndf.minimise.multigrid import (
    SMOOTHERS,
    CGResult,
    VCycle,
    active_of_diagonal,
    conjugate_gradients,
    spline_prolongations,
)
from taichi_ndf.problem.training import LINEAR_SOLVERS
from taichi_ndf.shell.hessian import COMPONENTS

log = logging.getLogger(__name__)

MAX_DAMPING_RAISES = 12
# The banded Cholesky factorisation is used when K's half-bandwidth is at most this × √N.
BAND_LIMIT = 8.0


def damped_solve(matrix: sp.csr_matrix, rhs: np.ndarray, damping: float,
                 fixed: np.ndarray | None = None, *, require_definite: bool = False
                 ) -> tuple[np.ndarray, float] | None:
    """Solve (K + μ D) x = rhs over the free unknowns (x = 0 at `fixed`), D = diag(K) (the
    mean diagonal where an entry of it is 0), μ = damping (raised ×10 from at least 1e-12
    while the factorisation fails). Returns x and the μ used. Banded Cholesky where the band
    is narrow, else SuperLU (module docstring).

    require_definite: return None unless K + μ D is positive definite (the Cholesky
    factorisation succeeds, or all pivots of the symmetric-mode LU are positive: its
    inertia), without raising μ."""
    size = matrix.shape[0]
    free = np.ones(size, dtype=bool)
    if fixed is not None:
        free[fixed] = False
    reduced = matrix[free][:, free].tocsc()
    diag = reduced.diagonal().copy()
    mean = float(np.abs(diag).mean()) or 1.0
    diag[diag <= 0] = mean
    band = lower_band(reduced)
    mu = damping
    for _ in range(MAX_DAMPING_RAISES):
        solution = None
        if band is not None:
            solution = _band_solve(band, mu * diag, rhs[free])
            if solution is None and require_definite:
                return None
        if solution is None:
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


def half_bandwidth(matrix: sp.spmatrix) -> int:
    """The largest i − j of a stored entry A[i, j] below the diagonal (the half-bandwidth of a
    symmetric matrix), from the first column of each CSR row."""
    csr = matrix.tocsr()
    if not csr.has_sorted_indices:
        csr = csr.sorted_indices()
    rows = np.flatnonzero(np.diff(csr.indptr))
    return int(np.max(rows - csr.indices[csr.indptr[rows]], initial=0))


def narrow_band(matrix: sp.spmatrix) -> bool:
    """Whether the banded Cholesky factorisation applies (`_band_fits`)."""
    return _band_fits(half_bandwidth(matrix), matrix.shape[0])


def _band_fits(width: int, size: int) -> bool:
    """A half-bandwidth `width` of an N × N matrix (N = `size`) is narrow enough for the
    banded factorisation: width ≤ BAND_LIMIT × √N."""
    return width <= BAND_LIMIT * math.sqrt(size)


def lower_band(matrix: sp.spmatrix) -> np.ndarray | None:
    """The lower band of a symmetric matrix (N × N) in LAPACK's layout, shape (b + 1, N):
    band[i − j, j] = A[i, j] for j ≤ i ≤ j + b, b its half-bandwidth; None when b exceeds
    BAND_LIMIT × √N (module docstring)."""
    coo = matrix.tocoo()
    lower = coo.row >= coo.col
    row, col = coo.row[lower], coo.col[lower]
    offset = row - col
    width = int(offset.max(initial=0))  # the half-bandwidth (`half_bandwidth`)
    size = matrix.shape[0]
    if not _band_fits(width, size):
        return None
    # bincount sums duplicate entries, as the sparse matrix does
    return np.bincount(offset * size + col, weights=coo.data[lower],
                       minlength=(width + 1) * size).reshape(width + 1, size)


def _band_solve(band: np.ndarray, shift: np.ndarray, rhs: np.ndarray) -> np.ndarray | None:
    """x with (A + diag(shift)) x = rhs by a banded Cholesky factorisation of the lower band
    of A (`lower_band`); None when A + diag(shift) is not positive definite."""
    if np.any(shift):
        band = band.copy()
        band[0] += shift
    factor, info = lapack.dpbtrf(band, lower=1)
    if info != 0:  # info > 0: a leading minor is not positive definite
        return None
    solution, info = lapack.dpbtrs(factor, rhs, lower=1)
    return solution if info == 0 else None


def _positive_pivots(factor) -> bool:
    """Whether a symmetric-mode LU of a symmetric matrix has only positive pivots (then it is
    LDLᵀ with D > 0 under one symmetric permutation: the matrix is positive definite)."""
    if not np.array_equal(factor.perm_r, factor.perm_c):
        return False
    return bool(np.all(factor.U.diagonal() > 0))


@dataclass(frozen=True)
class LinearSolverConfig:
    """How projected Newton solves K d = −g.

    kind: "direct" (`damped_solve`), "multigrid" (MG-preconditioned CG) or "auto"
        (multigrid from `threshold` or `band_threshold` unknowns where the grid has a
        coarser level).
    threshold: unknowns (3 × coefficients) from which "auto" uses multigrid when K's band is
        too wide for the banded Cholesky factorisation (`narrow_band`: SuperLU would
        factorise): measured on the napkin's Newton systems (benchmarks/RESULTS.md, one core
        under load), SuperLU 0.52 / 4.4 / 25 s and MG-PCG 0.95 / 4.4 / 9.2 s at 32² / 64² /
        128² spans (3.7 k / 13.5 k / 51 k unknowns): they tie at 64².
    band_threshold: unknowns from which "auto" uses multigrid also when the band is narrow:
        the banded Cholesky factorisation took 0.22 / 2.6 s CPU at 64² / 128² spans and MG-PCG
        0.80 / 2.9 s (setup reused), so the direct solve (exact, with its definiteness check)
        keeps up to 128² spans (51 k unknowns; its band then takes ~0.5 GB).
    tolerance: CG's relative residual ‖K d + g‖ ≤ tolerance ‖g‖ (an inexact Newton step:
        on the napkin at 64² spans 1e-8, 1e-6 and 1e-4 all kept the direct solve's 17 Newton
        iterations, Π within 1e-10, 4e-9 and 2e-7 relative; benchmarks/RESULTS.md).
    max_iterations: most CG iterations before the direct fallback.
    smoother: "gauss_seidel" (symmetric) or "jacobi" (damped, on 3 × 3 coefficient blocks).
    coarsest: the hierarchy stops at a grid of at most this many unknowns (direct solve).
    """

    kind: str = "auto"
    threshold: int = 20_000
    band_threshold: int = 60_000
    tolerance: float = 1e-6
    max_iterations: int = 300
    smoother: str = "gauss_seidel"
    coarsest: int = 1500

    def __post_init__(self):
        if self.kind not in LINEAR_SOLVERS:
            raise ValueError(f"kind must be one of {LINEAR_SOLVERS}, got {self.kind!r}")
        if self.smoother not in SMOOTHERS:
            raise ValueError(f"smoother must be one of {SMOOTHERS}, got {self.smoother!r}")
        if not (math.isfinite(self.tolerance) and 0 < self.tolerance < 1):
            raise ValueError(f"tolerance must be in (0, 1), got {self.tolerance!r}")
        for name in ("threshold", "band_threshold", "max_iterations", "coarsest"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} must be a positive integer, got {value!r}")


class LinearSolver:
    """`damped_solve`'s call (matrix, rhs, damping, fixed, require_definite=) by the method
    the config chooses for a grid (module docstring). `prolongations`: the grid's hierarchy
    (`spline_prolongations`; empty: direct only). After each call `last` holds the CG result
    of a multigrid solve (None after a direct one)."""

    def __init__(self, config: LinearSolverConfig | None = None,
                 prolongations: list[sp.csr_matrix] | None = None):
        self.config = config or LinearSolverConfig()
        self.prolongations = list(prolongations or [])
        self.last = None
        self._cycle = None  # the last V-cycle: its pattern-only parts are reused

    @classmethod
    def for_grid(cls, spline_config, config: LinearSolverConfig | None = None
                 ) -> LinearSolver:
        """The solver of a spline grid (`SplineConfig`): its hierarchy when multigrid may be
        used."""
        config = config or LinearSolverConfig()
        size = COMPONENTS * spline_config.num_coefficients
        wanted = config.kind == "multigrid" or (
            config.kind == "auto" and size >= min(config.threshold, config.band_threshold))
        hierarchy = spline_prolongations(spline_config, config.coarsest) if wanted else []
        if wanted and not hierarchy:
            log.info("no multigrid hierarchy for %s spans (odd or too few): direct solves",
                     spline_config.spans)
        return cls(config, hierarchy)

    @property
    def multigrid(self) -> bool:
        return bool(self.prolongations) and self.config.kind != "direct"

    def __call__(self, matrix: sp.csr_matrix, rhs: np.ndarray, damping: float,
                 fixed: np.ndarray | None = None, *, require_definite: bool = False
                 ) -> tuple[np.ndarray, float] | None:
        self.last = None
        if self.multigrid and (self.config.kind == "multigrid"
                               or matrix.shape[0] >= self.config.band_threshold
                               or not narrow_band(matrix)):
            result = self._multigrid(matrix, rhs, damping, fixed)
            if result is not None:
                self.last = result
                if result.status == "converged":
                    return result.x, damping
                if require_definite:  # not shown definite: the caller projects instead
                    log.debug("multigrid CG under require_definite: %s", result.status)
                    return None
                log.info("multigrid CG stopped (%s after %d iterations, residual %.2e): "
                         "direct solve", result.status, result.iterations, result.residual)
        return damped_solve(matrix, rhs, damping, fixed, require_definite=require_definite)

    def _multigrid(self, matrix, rhs, damping, fixed):
        """MG-preconditioned CG on the free, coupled unknowns; None where it cannot apply
        (a right-hand side on an uncoupled unknown, a singular coarsest level)."""
        size = matrix.shape[0]
        free = np.ones(size, dtype=bool)
        if fixed is not None:
            free[fixed] = False
        unknowns = np.flatnonzero(free)
        matrix = matrix.tocsr()
        active = active_of_diagonal(matrix.diagonal()[unknowns])
        idle = np.ones(len(unknowns), dtype=bool)
        idle[active] = False
        if np.any(rhs[unknowns[idle]] != 0):
            log.info("multigrid: a force on an unknown with no stiffness: direct solve")
            return None
        system = matrix[unknowns[active]][:, unknowns[active]]
        if np.any(system.diagonal() < 0):  # e_iᵀ K e_i < 0
            return CGResult(np.zeros(size), 0, 1.0, "negative curvature")
        if damping > 0:
            system = system + sp.diags(damping * system.diagonal(), format="csr")
        started = time.perf_counter()
        try:
            cycle = VCycle(system, unknowns[active], self.prolongations, self.config.smoother,
                           reuse=self._cycle)
            self._cycle = cycle
        except RuntimeError as err:
            log.info("multigrid: coarsest factorisation failed (%s): direct solve", err)
            return None
        setup = time.perf_counter() - started
        result = conjugate_gradients(system, rhs[unknowns[active]], cycle,
                                     self.config.tolerance, self.config.max_iterations)
        cycle.release()  # kept for its pattern-only parts only
        solve = time.perf_counter() - started - setup
        log.debug("multigrid CG: %s in %d iterations, residual %.2e, levels %s, setup %.3f "
                  "s, iterations %.3f s", result.status, result.iterations, result.residual,
                  cycle.sizes, setup, solve)
        x = np.zeros(size)
        x[unknowns[active]] = result.x
        return CGResult(x, result.iterations, result.residual, result.status, setup, solve)
