"""Work done in chunks to bound memory gives the numbers of the whole batch at once: the PSD
screen and projection (`shell.hessian.project_psd`, chunks of `PROJECT_CHUNK` blocks) and K's
point-local sums scattered per chunk of groups (`Assembly._pair_sums`, chunks of `CHUNK`
points, point-load samples added into their groups' sums); and a V-cycle kept between Newton
steps for its pattern only (`VCycle.release`) lends the same parts as the whole one."""

import math

import numpy as np
import pytest
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


# --- per-point blocks built and scattered chunk by chunk (issue 28) -------------------------

class _PairSprings:
    """A quadratic term joining point pairs (a stitch's form): ½ Σ_p E_pᵀ H_p E_p over both
    endpoints' jets with random positive semi-definite value-channel pair blocks."""

    def __init__(self, points, seed):
        gen = torch.Generator().manual_seed(seed)
        root = torch.randn(len(points), 6, 6, generator=gen, dtype=F64)
        value = root @ root.transpose(1, 2)  # (P, 6, 6): (end × 3 + component)²
        self.points, self.blocks = points, torch.zeros(len(points), 36, 36, dtype=F64)
        at = torch.tensor([0, 1, 2, 18, 19, 20])
        self.blocks[:, at[:, None], at[None, :]] = value

    def _pairs(self, u_jets):
        return torch.cat((u_jets[self.points[:, 0]].reshape(-1, 18),
                          u_jets[self.points[:, 1]].reshape(-1, 18)), dim=1)

    def evaluate(self, samples, u_jets, load_factor=1.0, *, grad=True):
        pairs = self._pairs(u_jets)
        force = torch.einsum("pij,pj->pi", self.blocks, pairs)
        value = 0.5 * float((pairs * force).sum())
        if not grad:
            return value, None
        out = torch.zeros_like(u_jets).reshape(-1, 18)
        out.index_add_(0, self.points[:, 0], force[:, :18])
        out.index_add_(0, self.points[:, 1], force[:, 18:])
        return value, out.reshape(u_jets.shape)

    def coupled_hessian(self, samples, u_jets, load_factor=1.0):
        from taichi_ndf.objective.couplings import Couplings
        return Couplings(self.points, self.blocks.clone())


def _scene(case):
    """A case of test_jacobian (the cylinder: a point-load sample; the plate: a free pin) on
    its grid, with the shell, a stiffness damping of random PSD blocks and pair springs."""
    from test_jacobian import CASES

    from taichi_ndf.minimise.linearisation import GridLinearisation
    from taichi_ndf.objective import Objective, ShellEnergyTerm
    from taichi_ndf.objective.damping import StiffnessDampingTerm
    from taichi_ndf.shell.materials import LinearIsotropic

    surface, config, boundary, loads = CASES[case]()
    grid = GridLinearisation(SplineField(config, dtype=F64), boundary, length=1.0)
    samples = GridLinearisation.quadrature(surface, config, loads, dtype=F64)
    linear = grid.linearisation(1.0, samples)
    n = len(linear.samples)
    gen = torch.Generator().manual_seed(2)
    root = torch.randn(n, 18, 18, generator=gen, dtype=F64)
    damping = StiffnessDampingTerm(
        (1e3 * root @ root.transpose(1, 2)).reshape(n, 6, 3, 6, 3), 0.3,
        1e-3 * torch.randn(n, 6, 3, generator=gen, dtype=F64))
    pairs = torch.randint(0, n, (2 * n // 3, 2), generator=gen)
    material = LinearIsotropic.from_young(2e8, 0.3, 0.01, 1.0)
    objective = Objective(ShellEnergyTerm(material, loads), (damping, _PairSprings(pairs, 4)))
    return linear, objective


@pytest.mark.parametrize("case", ["cylinder_xy_diaphragms", "free_pin_xz"])
def test_blocks_by_rows_and_k_by_chunks_equal_all_at_once(case, monkeypatch):
    """The objective's blocks asked by rows (shell, damping by its rows, pair springs none)
    are those rows of all points' blocks bit for bit, exact and psd; K assembled from blocks
    asked per chunk of 5 points (`PointBlocks`) equals K from all blocks at once to 1e-14
    relative, on the point-load sample's chunk and through a free pin."""
    from taichi_ndf.minimise.point_blocks import PointBlocks

    linear, objective = _scene(case)
    potential = objective.potential(1.0)
    c = 1e-3 * torch.randn(linear.assembly.n_coefficients, 3, dtype=F64,
                           generator=torch.Generator().manual_seed(5))
    u = linear.displacement(c)
    steps = linear.fd_steps(u, c, 1e-4)
    n = len(linear.samples)
    for psd in (False, True):
        whole = objective.hessian_blocks(linear.samples, u, 1.0, steps=steps, psd=psd)
        for rows in (slice(0, 7), slice(7, n - 1), slice(n - 1, n)):
            part = objective.hessian_blocks(linear.samples, u, 1.0, steps=steps, psd=psd,
                                            rows=rows)
            assert torch.equal(part, whole[rows])
    for psd, project in ((False, None), (True, None), (False, "clamp")):
        blocks = PointBlocks(linear, potential, c, u, 1e-4, psd, project)
        full = linear.hessian(blocks(slice(0, n)))
        monkeypatch.setattr(assembly_module, "POINT_CHUNK", 5)
        chunked_blocks = PointBlocks(linear, potential, c, u, 1e-4, psd, project)
        chunked = linear.hessian(chunked_blocks)
        monkeypatch.undo()
        assert chunked_blocks.projected == blocks.projected
        if project:
            assert blocks.projected > 0
        assert abs(full).max() > 0
        assert abs(chunked - full).max() <= 1e-14 * abs(full).max()


@pytest.mark.parametrize("hessian", ["strain", "clamp"])
def test_newton_with_blocks_in_chunks_takes_the_same_iterations(hessian, monkeypatch):
    """Projected Newton on the cylinder with damping and pair springs (couplings): blocks in
    chunks of 5 points give the same iterations (Π, λ², α, projected counts) and the same
    coefficients to 1e-12 relative as one chunk of all points."""
    from taichi_ndf.minimise.newton import NewtonConfig, minimise

    runs = []
    for chunk in (10 ** 7, 5):
        monkeypatch.setattr(assembly_module, "POINT_CHUNK", chunk)
        linear, objective = _scene("cylinder_xy_diaphragms")
        start = torch.zeros(linear.assembly.n_coefficients, 3, dtype=F64)
        runs.append(minimise(linear, objective.potential(1.0), start,
                             NewtonConfig(hessian=hessian, max_iterations=6), report=False))
    one, chunked = runs
    assert len(one.history) == len(chunked.history) >= 2
    for a, b in zip(one.history, chunked.history, strict=True):
        assert a.projected_blocks == b.projected_blocks and a.step_length == b.step_length
        assert math.isclose(a.energy, b.energy, rel_tol=1e-12)
        assert math.isclose(a.decrement, b.decrement, rel_tol=1e-10)
    scale = float(one.parameters.abs().max())
    assert scale > 0
    assert float((one.parameters - chunked.parameters).abs().max()) <= 1e-12 * scale


def test_pair_blocks_over_their_channels_equal_all_six():
    """Pair blocks mapped onto the coefficients over the channels they touch equal the
    products over all six channels to 1e-14 relative: a transmitted seam's stitches (value
    and slope channels) on a plate, and value-only pair springs through a free pin."""
    from test_seam import _plane_seam, _samples

    from taichi_ndf.minimise.linearisation import GridLinearisation
    from taichi_ndf.minimise.pair_hessian import coupled_hessian, touched_channels

    plane, term = _plane_seam("transmitted", "reversed")
    config = SplineConfig(spans=(4, 2), domain=plane.domain.bounds)
    grid = GridLinearisation(SplineField(config, dtype=F64), None)
    linear = grid.linearisation(1.0, _samples(plane, term))
    c = 1e-2 * torch.randn(config.num_coefficients, 3, dtype=F64,
                           generator=torch.Generator().manual_seed(6))
    seam = term.coupled_hessian(linear.samples, linear.displacement(c))
    springs_linear, objective = _scene("free_pin_xz")
    springs = objective.extra[1].coupled_hessian(springs_linear.samples, None)
    for assembly, couplings, channels in ((linear.assembly, seam, None),
                                          (springs_linear.assembly, springs, [0])):
        ends = couplings.endpoint_blocks().permute(0, 1, 4, 2, 3, 5, 6).reshape(-1, 6, 3, 6, 3)
        used = touched_channels(ends).tolist()
        assert len(used) < 6 and (channels is None or used == channels)
        every = coupled_hessian(assembly, couplings, all_channels=True)
        touched = coupled_hessian(assembly, couplings)
        assert abs(every).max() > 0
        assert abs(touched - every).max() <= 1e-14 * abs(every).max()


def _dense_pair_sum(assembly, couplings) -> np.ndarray:
    """Σ_p A_pᵀ H_p A_p written out pair by pair (dense, all six channels): A_p's row
    (end, channel, component) holds the end's Jacobian at its unknowns (and the pin's)."""
    from taichi_ndf.minimise.pair_hessian import dofs

    total = np.zeros((assembly.size, assembly.size))
    blocks = couplings.blocks.double().numpy()
    for p, ends in enumerate(couplings.points.tolist()):
        a_p = np.zeros((36, assembly.size))
        for end, point in enumerate(ends):
            rows = torch.tensor([point])
            jacobian = assembly.jacobian.rows(rows).dense()[:, 0]  # (3, 6, k)
            index = dofs(assembly.basis.index[rows])[0].reshape(-1, 3)  # (k, 3)
            if assembly.pin_jacobian is not None:
                jacobian = torch.cat((jacobian, assembly.pin_jacobian[:, point]), dim=2)
                index = np.concatenate((index, assembly.pin_dofs.reshape(-1, 3)))
            for c in range(3):
                for i in range(6):
                    np.add.at(a_p[18 * end + 3 * i + c], index[:, c],
                              jacobian[c, i].double().numpy())
        total += a_p.T @ blocks[p] @ a_p
    return total


def test_pair_blocks_scattered_at_once_equal_the_pair_by_pair_sum():
    """The pair blocks' K (`coupled_hessian`: all pairs in one sparse product) equals
    Σ_p A_pᵀ H_p A_p summed pair by pair to 1e-14 relative: value-only pair springs through
    a free pin (every pair also acts on the pin's unknowns) and on the cylinder."""
    from taichi_ndf.minimise.pair_hessian import coupled_hessian

    for case in ("free_pin_xz", "cylinder_xy_diaphragms"):
        linear, objective = _scene(case)
        couplings = objective.extra[1].coupled_hessian(linear.samples, None)
        couplings = type(couplings)(couplings.points[:40], couplings.blocks[:40])
        reference = _dense_pair_sum(linear.assembly, couplings)
        matrix = coupled_hessian(linear.assembly, couplings).toarray()
        assert np.abs(reference).max() > 0
        assert np.abs(matrix - reference).max() <= 1e-14 * np.abs(reference).max()


def test_inertia_and_wind_blocks_by_rows_are_those_rows_of_all_blocks():
    """InertiaTerm's and WindTerm's blocks asked by rows (chunks of 5 points, the last one
    short; the wind acting on the first 9 of 14 points, a chunk across that end) are those
    rows of all points' blocks bit for bit."""
    from taichi_ndf.objective.inertia import InertiaTerm
    from taichi_ndf.objective.wind import wind_term
    from taichi_ndf.problem.wind import Wind

    linear, _ = _scene("free_pin_xz")
    samples = linear.samples
    gen = torch.Generator().manual_seed(8)
    u = 0.05 * torch.randn(len(samples), 6, 3, generator=gen, dtype=F64)
    inertia = InertiaTerm(1.2, 4e4, torch.randn(len(samples), 6, 3, generator=gen, dtype=F64))
    head = type(samples)(samples.xi[:9], samples.r_jets[:9], samples.weight[:9],
                         samples.point_force[:9])
    wind = wind_term(Wind(velocity=(0.0, 1.0, 2.0)), 0.1, head, u[:9],
                     torch.randn(9, 3, generator=gen, dtype=F64), 20.0, u[:14])
    for term, points in ((inertia, len(samples)), (wind, 14)):
        every = term.hessian_blocks(samples, u[:points])
        assert float(every.abs().max()) > 0
        chunks = [term.hessian_blocks(samples, u[:points], rows=slice(s, s + 5))
                  for s in range(0, points, 5)]
        assert torch.equal(torch.cat(chunks), every)
