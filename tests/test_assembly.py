"""K's sparse pattern and the Jacobian products in `minimise.assembly` (projected Newton)."""

import numpy as np
import pytest
import scipy.sparse as sp
import torch

from taichi_ndf.minimise.group_pattern import csr_pattern
from taichi_ndf.minimise.jacobian import ComponentJacobian


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
    scatter, columns, row_starts = csr_pattern(groups, n)
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


def _apply_one_bmm(jacobian, local):
    """U = J C as one batched GEMV over all components of a dense J (3, N, 6, k) (the form
    before J could be stored per distinct component): the reference the per-component form
    must equal bit for bit."""
    comps, count, channels, k = jacobian.shape
    out = torch.bmm(jacobian.reshape(comps * count, channels, k),
                    local.permute(2, 0, 1).reshape(comps * count, k, 1))
    return out.reshape(comps, count, channels).permute(1, 2, 0)


def _apply_transpose_one_bmm(jacobian, grad):
    comps, count, channels, k = jacobian.shape
    out = torch.bmm(grad.permute(2, 0, 1).reshape(comps * count, 1, channels),
                    jacobian.reshape(comps * count, channels, k))
    return out.reshape(comps, count, k).permute(1, 2, 0)


def test_apply_of_a_component_jacobian_equals_the_one_bmm_form_bit_for_bit():
    """U = J C and Jᵀ g per component, with J (3, N, 6, 16) stored once, as two arrays (x and
    y alike) or three, give exactly the one-GEMM results of the dense J (no rounding
    changed)."""
    gen = torch.Generator().manual_seed(0)
    arrays = [torch.randn(500, 6, 16, generator=gen, dtype=torch.float64) for _ in range(3)]
    local = torch.randn(500, 16, 3, generator=gen, dtype=torch.float64)
    grad = torch.randn(500, 6, 3, generator=gen, dtype=torch.float64)
    for jacobian in (ComponentJacobian(arrays[:1], (0, 0, 0)),
                     ComponentJacobian(arrays[:2], (0, 0, 1)),
                     ComponentJacobian(arrays, (0, 1, 2))):
        full = jacobian.dense().contiguous()
        assert torch.equal(jacobian.apply(local), _apply_one_bmm(full, local))
        assert torch.equal(jacobian.apply_transpose(grad), _apply_transpose_one_bmm(full, grad))
        assert ComponentJacobian.of(full).slots == jacobian.slots


def test_a_jacobian_equal_in_the_three_components_is_stored_once():
    """The strip clamped in all components (`test_one_newton._strip`): J is one array for the
    three components, and U, g and K equal those of the same assembly with J written out per
    component (and int64 unknown numbers) to rounding (one product per span or point over all
    components against one per component: the BLAS may sum in another order)."""
    from test_one_newton import _strip

    assembly, _, _ = _strip()
    assert len(assembly.jacobian.arrays) == 1 and assembly.jacobian.slots == (0, 0, 0)
    assert assembly.point_dofs.dtype == torch.int32  # the gradient's scatter: half of int64
    coefficients = torch.randn(assembly.n_coefficients, 3, dtype=torch.float64,
                               generator=torch.Generator().manual_seed(1)) * 1e-3
    grad_u = torch.randn(len(assembly.samples), 6, 3, dtype=torch.float64,
                         generator=torch.Generator().manual_seed(2))
    blocks = torch.randn(len(assembly.samples), 18, 18, dtype=torch.float64,
                         generator=torch.Generator().manual_seed(3))
    blocks = blocks + blocks.transpose(1, 2)
    once = (assembly.displacement(coefficients), assembly.gradient(grad_u),
            assembly.hessian(blocks))
    one = assembly.jacobian.component(0)
    assembly.jacobian = ComponentJacobian([one.clone() for _ in range(3)], (0, 1, 2))
    assembly.point_dofs = assembly.point_dofs.long()
    per_component = (assembly.displacement(coefficients), assembly.gradient(grad_u),
                     assembly.hessian(blocks))
    for a, b in zip(once[:2], per_component[:2], strict=True):
        torch.testing.assert_close(a, b, rtol=1e-14, atol=1e-14 * float(b.abs().max()))
    k_once, k_per = once[2].toarray(), per_component[2].toarray()
    np.testing.assert_allclose(k_once, k_per, rtol=1e-14, atol=1e-14 * np.abs(k_per).max())
