"""The direct solves of projected Newton (`minimise.linear_solve.damped_solve`): the banded
Cholesky path against SuperLU, its definiteness answer and its fallbacks."""

import numpy as np
import pytest
import scipy.sparse as sp

from taichi_ndf.minimise import linear_solve
from taichi_ndf.minimise.linear_solve import damped_solve, lower_band


def _grid_matrix(side: int, shift: float | None, seed: int = 0) -> sp.csr_matrix:
    """A symmetric matrix with a spline grid's pattern (3 unknowns per coefficient, a 7 × 7
    coefficient stencil on a side × side grid numbered row by row), made diagonally dominant
    and shifted by `shift` (positive definite, its least eigenvalue ≥ shift); None: random."""
    rng = np.random.default_rng(seed)
    n = side * side
    i, j = np.divmod(np.arange(n), side)
    near = (np.abs(i[:, None] - i[None]) <= 3) & (np.abs(j[:, None] - j[None]) <= 3)
    pattern = sp.kron(sp.csr_matrix(near.astype(float)), np.ones((3, 3)), format="csr")
    values = pattern.multiply(rng.standard_normal(pattern.shape))
    symmetric = (values + values.T).tocsr()
    if shift is None:
        return symmetric
    dominance = np.abs(symmetric).sum(axis=1).A1 + shift
    return (symmetric + sp.diags(dominance)).tocsr()


def _superlu(monkeypatch, *args, **kwargs):
    with monkeypatch.context() as m:
        m.setattr(linear_solve, "BAND_LIMIT", 0.0)
        return damped_solve(*args, **kwargs)


def test_the_band_of_a_grid_numbered_row_by_row_is_narrow_and_a_dense_row_is_not():
    matrix = _grid_matrix(12, 1.0)
    band = lower_band(matrix)
    assert band is not None and band.shape == (3 * (3 * 12 + 3) + 3, 3 * 144)
    dense = matrix.tolil()
    dense[0, :] = dense[:, 0] = 1.0
    assert lower_band(dense.tocsr()) is None


def test_banded_cholesky_matches_superlu_with_held_unknowns_and_damping(monkeypatch):
    matrix = _grid_matrix(12, 1e-2)
    rhs = np.random.default_rng(1).standard_normal(matrix.shape[0])
    fixed = np.array([0, 5, 200])
    for damping in (0.0, 1e-3):
        band, mu_band = damped_solve(matrix, rhs, damping, fixed, require_definite=True)
        lu, mu_lu = _superlu(monkeypatch, matrix, rhs, damping, fixed, require_definite=True)
        assert mu_band == mu_lu == damping
        assert np.all(band[fixed] == 0)
        assert np.allclose(band, lu, rtol=1e-9, atol=1e-12 * np.abs(lu).max())


def test_an_indefinite_system_is_not_definite_and_is_still_solved_by_superlu(monkeypatch):
    matrix = _grid_matrix(10, None)
    eigenvalues = np.linalg.eigvalsh(matrix.toarray())
    # shifted between two eigenvalues: regular and indefinite
    shift = -0.5 * (eigenvalues[40] + eigenvalues[41])
    indefinite = (matrix + shift * sp.identity(matrix.shape[0])).tocsr()
    rhs = np.random.default_rng(2).standard_normal(matrix.shape[0])
    assert lower_band(indefinite) is not None
    assert damped_solve(indefinite, rhs, 0.0, require_definite=True) is None
    assert _superlu(monkeypatch, indefinite, rhs, 0.0, require_definite=True) is None
    x, mu = damped_solve(indefinite, rhs, 0.0)  # the band fails, SuperLU's LDLᵀ does not
    assert mu == 0.0
    assert np.linalg.norm(indefinite @ x - rhs) <= 1e-8 * np.linalg.norm(rhs)


@pytest.mark.parametrize("band_limit", [0.0, linear_solve.BAND_LIMIT])
def test_a_singular_system_is_damped_until_solvable(monkeypatch, band_limit):
    monkeypatch.setattr(linear_solve, "BAND_LIMIT", band_limit)
    matrix = sp.block_diag((_grid_matrix(6, 1.0), sp.csr_matrix((3, 3)))).tocsr()
    rhs = np.zeros(matrix.shape[0])
    rhs[0] = 1.0
    x, mu = damped_solve(matrix, rhs, 0.0)
    assert mu > 0 and np.all(np.isfinite(x))
