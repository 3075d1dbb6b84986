"""K's sparse pattern in `minimise.assembly` (the per-step scatter of projected Newton)."""

import numpy as np
import pytest
import scipy.sparse as sp

from taichi_ndf.minimise.assembly import _csr_pattern


@pytest.mark.parametrize("periodic", [False, True])
def test_csr_pattern_scatters_group_sums_as_a_coordinate_matrix_does(periodic):
    """Groups of 4 × 4 coefficients on a 9 × 7 coefficient grid (one per span of a cubic
    spline; periodic: wrapped in the second direction, so row-coupled coefficients are far
    apart in number); the data of random sums (3, 3, G, k, k) scattered by the pattern equal
    scipy's COO → CSR sum of the same entries."""
    rng = np.random.default_rng(0)
    rows, cols = 9, 7
    spans = [(i, j) for i in range(rows - 3) for j in range(cols if periodic else cols - 3)]
    groups = np.array([[(i + a) * cols + (j + b) % cols for a in range(4) for b in range(4)]
                       for i, j in spans])
    n, k = rows * cols, groups.shape[1]
    values = rng.standard_normal((3, 3, len(groups), k, k))
    scatter, columns, row_starts = _csr_pattern(groups, n)
    assert scatter.dtype == np.int32  # few entries: the positions in int32 (half the memory)
    data = np.zeros(len(columns))
    np.add.at(data, scatter, values.ravel())  # as `Assembly._point_hessian` sums them
    ours = sp.csr_matrix((data, columns, row_starts), shape=(3 * n, 3 * n))
    comps = np.arange(3)
    row = 3 * groups[None, None, :, :, None] + comps[:, None, None, None, None]
    col = 3 * groups[None, None, :, None, :] + comps[None, :, None, None, None]
    row, col = np.broadcast_arrays(row, col, values)[:2]
    reference = sp.coo_matrix((values.ravel(), (row.ravel(), col.ravel())),
                              shape=(3 * n, 3 * n)).tocsr()
    reference.sum_duplicates()
    assert ours.has_sorted_indices
    assert np.array_equal(ours.indptr, reference.indptr)
    assert np.array_equal(ours.indices, reference.indices)
    assert np.allclose(ours.data, reference.data, rtol=1e-14, atol=1e-14)
