"""The assembly's extra points (beyond each span's Gauss points: contact's check points, SfT's
data points) are summed per span in batches before they reach K's fixed pattern
(`Assembly._extra_batches`, `batch_slots`), not scattered point by point: the same K to
rounding, with points whose blocks touch the value channel only beside full ones and through a
free pin."""

import numpy as np
import torch

from taichi_ndf.minimise.assembly import Assembly, LocalBasis
from taichi_ndf.minimise.group_pattern import batch_slots
from taichi_ndf.minimise.jacobian import ComponentJacobian
from taichi_ndf.problem.sampling import SurfaceSamples

DT = torch.float64


def test_batch_slots_lay_each_groups_points_out_in_batches_of_one_size():
    """6 points in 3 groups: batches of ⌈6 / 3⌉ = 2 slots, a group's last batch short."""
    slots, groups, size = batch_slots(torch.tensor([0, 0, 0, 2, 2, 5]))
    assert size == 2
    assert slots.tolist() == [0, 1, 2, 4, 5, 6]  # slot 3: group 0's second batch, short
    assert groups.tolist() == [0, 0, 2, 5]


class _Identity:  # the world axes: no boundary frame
    def blocks_to_frame(self, blocks):
        return blocks


def _case(seed: int, pin: bool, slots: tuple[int, int, int] = (0, 0, 0)):
    """Spans of a 3 × 2-span cubic grid (k = 16), 4 Gauss points each, and 0–12 extra points in
    half of the spans: value-only blocks (a barrier's) and blocks without the value channel (a
    shell's), in a shuffled order; with a free pin at the first span's coefficients. J per
    component: the basis jets times a per-point factor of the component's array (`slots`:
    which components share one; array 0 is the basis itself)."""
    gen = torch.Generator().manual_seed(seed)
    columns = 2 + 3
    spans = torch.tensor([[(i + a) * columns + j + b for a in range(4) for b in range(4)]
                          for i in range(3) for j in range(2)])
    extra = torch.randint(0, 13, (len(spans),), generator=gen) * (torch.arange(len(spans)) % 2)
    group = torch.cat((torch.arange(len(spans)).repeat_interleave(4),
                       torch.arange(len(spans)).repeat_interleave(extra)))
    shuffle = torch.randperm(len(group), generator=gen)
    group, gauss = group[shuffle], shuffle < 4 * len(spans)
    index, n, k = spans[group], len(group), spans.shape[1]
    basis = torch.randn(n, 6, k, generator=gen, dtype=DT)
    factors = torch.cat((torch.ones(1, n), 1 + torch.rand(max(slots), n, generator=gen,
                                                          dtype=DT)))
    per_component = [basis * factors[s][:, None, None] for s in slots]  # (n, 6, k) each
    half = torch.randn(n, 18, 18, generator=gen, dtype=DT)
    blocks = half @ half.transpose(1, 2)
    value_only = ~gauss & (torch.rand(n, generator=gen) < 0.5)
    blocks[value_only, 3:] = 0
    blocks[value_only, :, 3:] = 0
    blocks[~gauss & ~value_only, :3] = 0
    blocks[~gauss & ~value_only, :, :3] = 0
    pin_at = (spans[0], torch.randn(6, k, generator=gen, dtype=DT)) if pin else (None, None)
    samples = SurfaceSamples(torch.zeros(n, 2, dtype=DT), torch.zeros(n, 6, 3, dtype=DT),
                             torch.ones(n, dtype=DT), torch.zeros(n, 3, dtype=DT))
    assembly = Assembly(samples, LocalBasis(index, basis, *pin_at), int(spans.max()) + 1)
    assembly.jacobian = ComponentJacobian(
        [(basis * f[:, None, None])[assembly.order] for f in factors], slots)
    assembly._operator = _Identity()
    pin_jets = None
    if pin:  # u = N(ξ) − N(ξ₀): the pin's Jacobian on the value channel
        pin_jets = torch.zeros(6, k, dtype=DT)
        pin_jets[0] = -pin_at[1][0]
        assembly.pin_jacobian = pin_jets[None, None].expand(3, n, -1, -1)
        assembly._pin_channels = torch.tensor([0])
    # K = Σ_q J_qᵀ H_q J_q with J_q (18 × 3n) dense, point by point
    expected = np.zeros((assembly.size, assembly.size))
    for q in range(n):
        jq = np.zeros((18, assembly.size))
        for c in range(3):
            for a in range(k):
                jq[np.arange(6) * 3 + c, 3 * int(index[q, a]) + c] += (
                    per_component[c][q, :, a].numpy())
                if pin:
                    jq[np.arange(6) * 3 + c, 3 * int(pin_at[0][a]) + c] += pin_jets[:, a].numpy()
        expected += jq.T @ blocks[q].numpy() @ jq
    return assembly, blocks[assembly.order], expected, int(extra.sum()), int((extra > 0).sum())


def test_extra_points_give_each_points_stiffness_summed_in_batches_per_span(monkeypatch):
    for seed, pin in ((0, False), (1, True)):
        assembly, blocks, expected, count, present = _case(seed, pin)
        calls = []
        pair_sums = Assembly._pair_sums

        def spy(self, data, jacobian, blocks, used, groups, m, calls=calls,
                pair_sums=pair_sums):
            calls.append((len(groups), m))
            return pair_sums(self, data, jacobian, blocks, used, groups, m)

        monkeypatch.setattr(Assembly, "_pair_sums", spy)
        got = assembly.hessian(blocks, chunk=8).toarray()
        np.testing.assert_allclose(got, expected, rtol=1e-12, atol=1e-12 * np.abs(expected).max())
        # the regular points: one call per chunk of 2 spans (8 points); then the extra points,
        # value-only and the others apart, each in < 2 × (its points / its spans) batches
        assert calls[:3] == [(2, 4)] * 3
        extra = calls[3:]
        assert len(extra) == 2
        assert sum(b * m for b, m in extra) < 2 * count
        assert sum(b for b, _ in extra) <= 2 * present


def test_k_u_and_g_of_a_jacobian_stored_per_component_are_the_dense_sums():
    """All component pairs summed per span in one product per stored array of J
    (`Assembly._pair_sums`) and U, g one product per span (`Assembly.displacement`,
    `.gradient`): K = Σ_q J_qᵀ H_q J_q, U_q = J_q C and g = Σ_q J_qᵀ ∂Π/∂U_q written out point by
    point, to rounding, with J one array for all components, two (x, y alike: a cylinder's
    diaphragms) or three, extra points beside the Gauss points and a free pin."""
    for seed, pin, slots in ((2, False, (0, 0, 0)), (3, False, (0, 0, 1)), (4, True, (1, 0, 1)),
                             (5, True, (0, 1, 2))):
        assembly, blocks, expected, _, _ = _case(seed, pin, slots)
        got = assembly.hessian(blocks, chunk=8).toarray()
        np.testing.assert_allclose(got, expected, rtol=1e-12, atol=1e-12 * np.abs(expected).max())
        gen = torch.Generator().manual_seed(seed)
        coefficients = torch.randn(assembly.n_coefficients, 3, generator=gen, dtype=DT)
        grad_u = torch.randn(len(assembly.order), 6, 3, generator=gen, dtype=DT)
        assembly.offset = torch.zeros(len(assembly.order), 6, 3, dtype=DT)
        assembly._operator.to_world = assembly._operator.to_frame = lambda u: u
        dense = assembly.jacobian.dense()  # (3, N, 6, k), the assembly's order
        index = assembly.basis.index
        u = torch.einsum("cnja,nac->njc", dense, coefficients[index])
        g = torch.zeros_like(coefficients)
        g.index_put_((index[..., None], torch.arange(3)),
                     torch.einsum("cnja,njc->nac", dense, grad_u), accumulate=True)
        if pin:
            pin_jacobian = assembly.pin_jacobian[:, 0]  # (3, 6, k)
            u = u + torch.einsum("cja,ac->jc", pin_jacobian,
                                 coefficients[assembly.basis.pin_index])
            g[assembly.basis.pin_index] += torch.einsum("cja,jc->ac", pin_jacobian,
                                                        grad_u.sum(0))
        torch.testing.assert_close(assembly.displacement(coefficients), u, rtol=1e-13,
                                   atol=1e-13 * float(u.abs().max()))
        torch.testing.assert_close(assembly.gradient(grad_u), g, rtol=1e-13,
                                   atol=1e-13 * float(g.abs().max()))
