"""Work done in chunks to bound memory gives the numbers of the whole batch at once: the PSD
screen and projection (`shell.hessian.project_psd`, chunks of `PROJECT_CHUNK` blocks) and K's
point-local sums scattered per chunk of groups (`Assembly._pair_sums`, chunks of `CHUNK`
points, point-load samples added into their groups' sums); and a V-cycle kept between Newton
steps for its pattern only (`VCycle.release`) lends the same parts as the whole one."""

import numpy as np
import scipy.sparse as sp
import torch
from test_jacobian import _cylinder
from test_multigrid import napkin_system  # noqa: F401  (the fixture)

from taichi_ndf.field.spline import SplineConfig, SplineField
from taichi_ndf.minimise import assembly as assembly_module
from taichi_ndf.minimise.assembly import Assembly, local_basis_at
from taichi_ndf.minimise.multigrid import VCycle, spline_prolongations
from taichi_ndf.problem.operator import DisplacementOperator
from taichi_ndf.problem.quadrature import span_quadrature
from taichi_ndf.shell import hessian as hessian_module
from taichi_ndf.shell.hessian import project_psd

F64 = torch.float64


def test_project_psd_in_chunks_equals_all_at_once(monkeypatch):
    """Random symmetric blocks (half indefinite; the value channel's rows zero, as the shell's
    blocks): projected in chunks of 7 blocks, the same blocks bit for bit and the same count,
    in both modes and with and without overwriting."""
    gen = torch.Generator().manual_seed(0)
    blocks = torch.randn(200, 18, 18, generator=gen, dtype=F64)
    blocks = blocks @ blocks.transpose(1, 2)
    blocks[::2] -= 40 * torch.eye(18, dtype=F64)  # indefinite
    blocks[:, :3] = 0.0
    blocks[:, :, :3] = 0.0
    for mode in ("clamp", "abs"):
        whole, count = project_psd(blocks, mode=mode)
        monkeypatch.setattr(hessian_module, "PROJECT_CHUNK", 64)
        chunked, chunked_count = project_psd(blocks.clone(), mode=mode, overwrite=True)
        monkeypatch.undo()
        assert count == chunked_count == 100
        assert torch.equal(whole, chunked)
        assert float(torch.linalg.eigvalsh(chunked).min()) > -1e-12


def test_hessian_scattered_per_chunk_equals_the_whole_batch(monkeypatch):
    """The cylinder of test_jacobian (a point-load sample: added into its group's sums) on
    4 × 3 spans: K with one group per chunk equals K with all groups in one chunk, bit for
    bit."""
    surface, _, boundary, loads = _cylinder()
    config = SplineConfig(spans=(4, 3), domain=surface.domain.bounds, periodic=(True, False))
    field = SplineField(config, dtype=F64)
    samples = span_quadrature(surface, config, loads, dtype=F64)
    operator = DisplacementOperator(field, boundary)
    assembly = Assembly(samples, local_basis_at(operator, samples.xi),
                        field.coefficients.shape[0]).at_load(operator, 1.0)
    assert assembly._extra.stop - assembly._extra.start == 1  # the point load's sample
    gen = torch.Generator().manual_seed(1)
    blocks = torch.randn(len(assembly.samples), 18, 18, generator=gen, dtype=F64)
    blocks = blocks + blocks.transpose(1, 2)
    monkeypatch.setattr(assembly_module, "CHUNK", 10 ** 6)
    whole = assembly.hessian(blocks)
    monkeypatch.setattr(assembly_module, "CHUNK", 1)
    chunked = assembly.hessian(blocks)
    assert np.array_equal(whole.indptr, chunked.indptr)
    assert np.array_equal(whole.indices, chunked.indices)
    assert np.array_equal(whole.data, chunked.data)


def test_a_vcycle_reused_after_release_equals_a_fresh_one(napkin_system):  # noqa: F811
    """A released V-cycle (`VCycle.release`: its values and factorisations let go between
    Newton steps) holds no matrix values, and a V-cycle built on it for a changed matrix
    applies the same operator as one built from scratch."""
    matrix, _, fixed, config = napkin_system
    prolongations = spline_prolongations(config, 100)
    unknowns = np.setdiff1d(np.arange(matrix.shape[0]), fixed)
    system = matrix[unknowns][:, unknowns].tocsr()
    first = VCycle(system, unknowns, prolongations).release()
    assert first.coarsest is None and not hasattr(first.levels[0].matrix, "data")
    assert first.levels[0].smoother.lower is None
    changed = (system + sp.diags(0.3 * system.diagonal())).tocsr()
    reused = VCycle(changed, unknowns, prolongations, reuse=first)
    fresh = VCycle(changed, unknowns, prolongations)
    assert reused.levels[0].smoother.parts is first.levels[0].smoother.parts
    r = np.random.default_rng(0).standard_normal(len(unknowns))
    assert np.array_equal(reused(r), fresh(r))
