"""The CPU savings of ndf-sft's per-frame fit and tracking (issue 27) give the same numbers bit
for bit: the shell's central-difference blocks with the perturbed copies stacked into few
evaluations (`sample_hessians(stacked_points=)`), the assembly's extra points (K to rounding:
`Assembly` sums them in batches per group, tests/test_assembly_extra_points.py), and the
tracker's pairwise distances (`matching.pairwise_distances`)."""

import numpy as np
import pytest
import scipy.sparse as sp
import torch

from inverse.sft.matching import pairwise_distances
from taichi_ndf.field.spline import SplineConfig
from taichi_ndf.geometry import Cylinder
from taichi_ndf.minimise.assembly import Assembly, LocalBasis
from taichi_ndf.minimise.jacobian import ComponentJacobian
from taichi_ndf.objective import ShellEnergyTerm
from taichi_ndf.problem.loads import Loads
from taichi_ndf.problem.quadrature import span_quadrature
from taichi_ndf.problem.sampling import SurfaceSamples
from taichi_ndf.shell.hessian import jet_steps, sample_hessians
from taichi_ndf.shell.materials import preset

DT = torch.float64


def _shell_case():
    surface = Cylinder(radius=0.5, length=1.0)
    config = SplineConfig(spans=(2, 2), domain=surface.domain.bounds,
                          periodic=surface.domain.periodic)
    samples = span_quadrature(surface, config, Loads(), points=3, dtype=DT)
    u = 0.05 * torch.randn(len(samples), 6, 3, generator=torch.Generator().manual_seed(1),
                           dtype=DT)
    return samples, u, ShellEnergyTerm(preset("canvas"), Loads())


@pytest.mark.parametrize("copies", [36, 5, 1])
def test_stacked_shell_blocks_equal_one_copy_per_call_bit_for_bit(copies):
    """All 36 perturbed copies in one call, 5 per call (a ± pair split between two calls), or
    one: the same blocks as one copy per call, in 36 / copies calls (rounded up)."""
    samples, u, term = _shell_case()
    calls = []

    def potential(s, u_jets, grad):
        calls.append(len(s))
        return term.result(s, u_jets, 1.0, grad=grad)

    steps = jet_steps(samples.r_jets, u, 1.0, 1e-5)
    expected = sample_hessians(potential, samples, u, steps=steps)
    assert calls == [len(samples)] * 36
    calls.clear()
    got = sample_hessians(potential, samples, u, steps=steps,
                          stacked_points=copies * len(samples) + len(samples) // 2)
    assert len(calls) == -(-36 // copies) and max(calls) == copies * len(samples)
    assert torch.equal(got, expected)


def test_assembly_with_extra_points_sums_each_points_stiffness():
    """Groups of 2, 3 and 1 points on a 5-coefficient field (k = 2): the regular points (one
    per group) and the extra ones (batched per group) give K = Σ_q J_qᵀ H_q J_q."""
    gen = torch.Generator().manual_seed(2)
    index = torch.tensor([[0, 1], [0, 1], [1, 2], [1, 2], [1, 2], [3, 4]])
    n, k = index.shape
    basis = torch.randn(n, 6, k, generator=gen, dtype=DT)
    samples = SurfaceSamples(torch.zeros(n, 2, dtype=DT), torch.zeros(n, 6, 3, dtype=DT),
                             torch.ones(n, dtype=DT), torch.zeros(n, 3, dtype=DT))
    assembly = Assembly(samples, LocalBasis(index, basis), 5)
    assembly.jacobian = ComponentJacobian([basis[assembly.order]], (0, 0, 0))

    class Identity:  # the world axes: no boundary frame
        def blocks_to_frame(self, blocks):
            return blocks

    assembly._operator = Identity()
    half = torch.randn(n, 18, 18, generator=gen, dtype=DT)
    blocks = half @ half.transpose(1, 2)  # symmetric, in the given points' order
    got = assembly.hessian(blocks[assembly.order]).toarray()
    expected = np.zeros((15, 15))
    for q in range(n):
        jq = np.zeros((18, 15))  # jets (channel × 3 + component) over unknowns (coef × 3 + c)
        for c in range(3):
            for a in range(k):
                jq[np.arange(6) * 3 + c, 3 * int(index[q, a]) + c] = basis[q, :, a].numpy()
        expected += jq.T @ blocks[q].numpy() @ jq
    assert assembly._extra.stop - assembly._extra.start == n - 3  # three groups, one regular each
    np.testing.assert_allclose(got, expected, rtol=1e-12, atol=1e-12)
    assert sp.issparse(assembly.hessian(blocks[assembly.order]))


def test_pairwise_distances_are_numpys_norm_bit_for_bit():
    rng = np.random.default_rng(3)
    a, b = rng.uniform(-5, 2000, (300, 2)), rng.uniform(-5, 2000, (257, 2))
    assert np.array_equal(pairwise_distances(a, b),
                          np.linalg.norm(a[:, None, :] - b[None, :, :], axis=2))
