"""Multigrid-preconditioned CG for projected Newton's systems (`minimise.multigrid`,
`minimise.linear_solve.LinearSolver`)."""

import logging
import math
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp
import torch

from taichi_ndf.field.spline import SplineConfig, SplineField
from taichi_ndf.minimise import linear_solve
from taichi_ndf.minimise.assembly import Assembly, local_basis_at
from taichi_ndf.minimise.linear_solve import LinearSolver, LinearSolverConfig, damped_solve
from taichi_ndf.minimise.multigrid import VCycle, active_unknowns, spline_prolongations
from taichi_ndf.minimise.refinement import held_unknowns, solve_levels
from taichi_ndf.objective import Objective
from taichi_ndf.problem.operator import DisplacementOperator
from taichi_ndf.problem.quadrature import span_quadrature
from taichi_ndf.scene.reader import load_scene
from taichi_ndf.scene.schema import SceneError
from taichi_ndf.shell.hessian import flat_blocks, indefinite_blocks, jet_steps, project_psd

DT = torch.float64
NAPKIN = Path(__file__).resolve().parents[1] / "scenes" / "napkin.toml"
MULTIGRID = LinearSolverConfig(kind="multigrid", coarsest=100, tolerance=1e-12)


def _napkin_levels(model, levels, linear=None):
    surface = model.surface
    field = SplineField(SplineConfig(spans=(2, 2), domain=surface.domain.bounds), dtype=DT)
    return field, solve_levels(
        field, model.boundary, lambda f: span_quadrature(surface, f.config, model.loads),
        Objective.of_model(model), levels=levels, probes={"free": (1.0, 1.0)},
        length=math.sqrt(surface.domain.rectangle_area), linear=linear)


@pytest.fixture(scope="module")
def napkin_system():
    """The projected Newton system of the napkin (free pin: held gauge unknowns) on 16 × 16
    spans at its 4 × 4 solution prolonged: K, −g, the held unknowns and the grid."""
    model = load_scene(NAPKIN, material="cloth").model  # as measured (docstrings)
    field, results = _napkin_levels(model, 2)
    field = field.refined()
    field.coefficients.copy_(results[-1][-1].coefficients)
    field = field.refined().refined()
    samples = span_quadrature(model.surface, field.config, model.loads)
    operator = DisplacementOperator(field, model.boundary)
    basis = local_basis_at(operator, samples.xi)
    assembly = Assembly(samples, basis, field.coefficients.shape[0]).at_load(operator, 1.0)
    fixed = held_unknowns(field, model.boundary, basis)
    potential = Objective.of_model(model).potential(1.0)
    s = assembly.samples
    u = assembly.displacement(field.coefficients)
    blocks = flat_blocks(potential.hessian_blocks(s, u, steps=jet_steps(s.r_jets, u, 1.0, 1e-5)))
    blocks, _ = project_psd(blocks, indefinite_blocks(blocks))
    rhs = -assembly.gradient(potential(s, u, True).grad_u_jets).reshape(-1).numpy()
    rhs[fixed] = 0.0
    return assembly.hessian(blocks), rhs, fixed, field.config


def test_prolongations_halve_even_grids_down_to_the_coarsest_size():
    config = SplineConfig(spans=(16, 32))
    sizes = [p.shape for p in spline_prolongations(config, 100)]
    assert sizes == [(3 * 19 * 35, 3 * 11 * 19), (3 * 11 * 19, 3 * 7 * 11)]
    assert [p.shape for p in spline_prolongations(config, 3 * 11 * 19)] == sizes[:1]
    assert spline_prolongations(config, 3 * 19 * 35) == []
    assert spline_prolongations(SplineConfig(spans=(15, 16)), 10) == []
    assert spline_prolongations(SplineConfig(spans=(6, 6)), 10) == []  # 3 spans < p + 1


@pytest.mark.parametrize("smoother", ["gauss_seidel", "jacobi"])
def test_vcycle_is_symmetric_positive_definite(napkin_system, smoother):
    matrix, _, fixed, config = napkin_system
    free = np.setdiff1d(np.arange(matrix.shape[0]), fixed)
    reduced = matrix[free][:, free]
    active = active_unknowns(reduced)
    cycle = VCycle(reduced[active][:, active].tocsr(), free[active],
                   spline_prolongations(config, 100), smoother)
    assert len(cycle.sizes) == 3  # 16² -> 8² -> 4² spans
    rng = np.random.default_rng(0)
    x, y = rng.standard_normal((2, len(active)))
    assert abs(y @ cycle(x) - x @ cycle(y)) <= 1e-10 * abs(x @ cycle(x))
    for v in rng.standard_normal((20, len(active))):
        assert v @ cycle(v) > 0


def test_multigrid_cg_matches_the_direct_solve_with_held_unknowns(napkin_system):
    matrix, rhs, fixed, config = napkin_system
    assert fixed is not None and len(fixed) == 3
    solver = LinearSolver.for_grid(config, MULTIGRID)
    x, damping = solver(matrix, rhs, 0.0, fixed)
    direct, _ = damped_solve(matrix, rhs, 0.0, fixed)
    assert solver.last is not None and solver.last.status == "converged"
    assert damping == 0.0 and np.all(x[fixed] == 0.0)
    assert np.linalg.norm(x - direct) <= 1e-8 * np.linalg.norm(direct)
    # with damping: the same damped system as the direct path
    x, _ = solver(matrix, rhs, 1e-3, fixed)
    direct, _ = damped_solve(matrix, rhs, 1e-3, fixed)
    assert np.linalg.norm(x - direct) <= 1e-8 * np.linalg.norm(direct)


def test_an_indefinite_system_falls_back_to_the_direct_solve(napkin_system, caplog):
    matrix, rhs, fixed, config = napkin_system
    shift = 0.5 * float(np.mean(matrix.diagonal()))
    indefinite = (matrix - shift * sp.identity(matrix.shape[0], format="csr")).tocsr()
    solver = LinearSolver.for_grid(config, MULTIGRID)
    assert solver(indefinite, rhs, 0.0, fixed, require_definite=True) is None
    assert solver.last.status in ("negative curvature", "preconditioner")
    with caplog.at_level(logging.INFO, logger="taichi_ndf.minimise.linear_solve"):
        x, _ = solver(indefinite, rhs, 0.0, fixed)
    assert "direct solve" in caplog.text
    direct, _ = damped_solve(indefinite, rhs, 0.0, fixed)
    assert np.allclose(x, direct, rtol=0, atol=1e-12 * np.abs(direct).max())


def test_newton_with_multigrid_matches_the_direct_solve(caplog):
    model = load_scene(NAPKIN, material="cloth").model
    _, direct = _napkin_levels(model, 3)
    with caplog.at_level(logging.DEBUG, logger="taichi_ndf.minimise.linear_solve"):
        _, multigrid = _napkin_levels(model, 3, LinearSolverConfig(kind="multigrid",
                                                                   coarsest=100))
    assert "multigrid CG: converged" in caplog.text  # the 8 × 8 level used it
    a, b = direct[-1][-1], multigrid[-1][-1]
    assert a.converged and b.converged
    assert abs(a.energy - b.energy) <= 1e-9 * abs(a.energy)
    assert np.allclose(a.probes["free"], b.probes["free"], rtol=1e-6)


def test_a_reused_vcycle_equals_a_fresh_one(napkin_system):
    """The V-cycle built with the previous one's pattern-only parts (another matrix with the
    same pattern: a Newton step later) applies the same operator as one built from scratch."""
    matrix, rhs, fixed, config = napkin_system
    prolongations = spline_prolongations(config, 100)
    unknowns = np.setdiff1d(np.arange(matrix.shape[0]), fixed)
    system = matrix[unknowns][:, unknowns].tocsr()
    first = VCycle(system, unknowns, prolongations)
    changed = (system + sp.diags(0.3 * system.diagonal())).tocsr()
    reused = VCycle(changed, unknowns, prolongations, reuse=first)
    fresh = VCycle(changed, unknowns, prolongations)
    assert reused.levels[0].smoother.parts is first.levels[0].smoother.parts
    r = np.random.default_rng(0).standard_normal(len(unknowns))
    assert np.allclose(reused(r), fresh(r), rtol=1e-12, atol=1e-12 * np.abs(fresh(r)).max())
    assert not np.allclose(first(r), fresh(r), rtol=1e-3)


def test_auto_solves_directly_while_the_band_is_narrow(napkin_system, monkeypatch):
    """"auto" above `threshold` unknowns: the banded direct solve while K's band is narrow and
    it is below `band_threshold`, multigrid when the band is too wide or from
    `band_threshold`."""
    matrix, rhs, fixed, config = napkin_system
    for band_threshold, band_limit, multigrid in ((10**6, linear_solve.BAND_LIMIT, False),
                                                  (10**6, 0.0, True),
                                                  (100, linear_solve.BAND_LIMIT, True)):
        monkeypatch.setattr(linear_solve, "BAND_LIMIT", band_limit)
        solver = LinearSolver.for_grid(config, LinearSolverConfig(
            threshold=100, band_threshold=band_threshold, coarsest=100))
        solver(matrix, rhs, 0.0, fixed)
        assert (solver.last is not None) == multigrid


def test_linear_solver_settings_are_checked():
    with pytest.raises(ValueError, match="kind"):
        LinearSolverConfig(kind="cholesky")
    with pytest.raises(ValueError, match="smoother"):
        LinearSolverConfig(smoother="sor")
    with pytest.raises(ValueError, match="tolerance"):
        LinearSolverConfig(tolerance=0.0)
    with pytest.raises(ValueError, match="band_threshold"):
        LinearSolverConfig(band_threshold=0)


def test_scene_key_linear_solver(tmp_path):
    text = NAPKIN.read_text()
    text = text[:text.index("[field]")] + '[field]\ntype = "spline"\n\n[training]\n' \
        'method = "newton"\nlinear_solver = "{}"\n'
    path = tmp_path / "napkin.toml"
    path.write_text(text.format("multigrid"))
    assert load_scene(path).solver.linear_solver == "multigrid"
    path.write_text(text.format("amg"))
    with pytest.raises(SceneError, match=r"training\.linear_solver"):
        load_scene(path)
