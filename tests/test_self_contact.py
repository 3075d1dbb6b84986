"""Self-contact (issue 30): the barrier between points of the sheet itself
(`taichi_ndf.objective.self_contact`), its step test (`taichi_ndf.contact.self_step`), the
`[self_contact]` table, and the independent triangle-intersection test used on outputs."""

import math

import numpy as np
import pytest
import torch

from taichi_ndf import jets
from taichi_ndf.contact.barrier import barrier
from taichi_ndf.contact.self_pairs import (
    SelfContactConfig,
    candidate_pairs,
    default_stiffness,
    hole_radius,
)
from taichi_ndf.contact.self_step import closest_along_step, self_step_allowed
from taichi_ndf.geometry import Plane
from taichi_ndf.io.mesh_check import self_intersections
from taichi_ndf.objective.self_contact import SelfContactTerm
from taichi_ndf.problem.sampling import SurfaceSamples

DT = torch.float64


def _folded_samples(n=(40, 4), gap=0.0045, seed=0):
    """Samples on a 0.2 m × 0.05 m plane folded in half at ξ¹ = 0.1: the half ξ¹ > 0.1
    mirrored onto the other `gap` [m] above it and shifted by half a spacing (2.5 mm), with
    a small random wobble, so that pairs sit at various distances and directions. Returns
    the samples and u."""
    surface = Plane(bounds=((0.0, 0.2), (0.0, 0.05)))
    s1 = (torch.arange(n[0], dtype=DT) + 0.5) / n[0] * 0.2
    s2 = (torch.arange(n[1], dtype=DT) + 0.5) / n[1] * 0.05
    g1, g2 = torch.meshgrid(s1, s2, indexing="ij")
    xi = torch.stack((g1.reshape(-1), g2.reshape(-1)), dim=1)
    r = surface.jets(xi).to(DT)
    weight = torch.full((len(xi),), 0.2 * 0.05 / len(xi), dtype=DT)
    samples = SurfaceSamples(xi, r, weight, torch.zeros(len(xi), 3, dtype=DT))
    x = r[:, jets.VALUE].clone()
    upper = xi[:, 0] > 0.1
    x[upper, 0] = 0.2 - xi[upper, 0] + 0.0025
    x[upper, 2] = gap
    generator = torch.Generator().manual_seed(seed)
    x = x + 5e-4 * torch.randn(x.shape, dtype=DT, generator=generator)
    u = torch.zeros(len(xi), jets.CHANNELS, 3, dtype=DT)
    u[:, jets.VALUE] = x - r[:, jets.VALUE]
    u[:, 1:] = 1e-2 * torch.randn(u[:, 1:].shape, dtype=DT, generator=generator)
    return samples, u


CONFIG = SelfContactConfig(activation=0.004, offset=0.002, stiffness=1e9, exclusion=0.03)


def test_the_folded_samples_have_active_pairs_across_the_fold_only():
    samples, u = _folded_samples()
    pairs, separation, _ = SelfContactTerm(CONFIG).pairs(samples, u)
    assert len(pairs) > 2 * 40
    xi = samples.xi
    # every pair joins the two halves (same-half neighbours are within the exclusion or far)
    assert bool(((xi[pairs[:, 0], 0] > 0.1) != (xi[pairs[:, 1], 0] > 0.1)).all())
    assert float(separation.norm(dim=1).max()) <= CONFIG.offset + CONFIG.activation


def test_value_and_gradient_against_central_differences():
    samples, u = _folded_samples()
    term = SelfContactTerm(CONFIG)
    value, gradient = term.evaluate(samples, u)
    assert value > 0
    assert float(gradient[:, 1:].abs().max()) == 0.0  # the value channel only
    generator = torch.Generator().manual_seed(1)
    for _ in range(3):
        direction = torch.zeros_like(u)
        direction[:, jets.VALUE] = torch.randn(len(u), 3, dtype=DT, generator=generator)
        h = 1e-7
        plus, _ = term.evaluate(samples, u + h * direction, grad=False)
        minus, _ = term.evaluate(samples, u - h * direction, grad=False)
        numeric = (plus - minus) / (2 * h)
        analytic = float((gradient * direction).sum())
        assert abs(numeric - analytic) <= 1e-6 * abs(analytic), (numeric, analytic)


def _dense(couplings, n):
    """The Hessian (18 n, 18 n) the pair blocks stand for: Σ_p E_pᵀ H_p E_p."""
    matrix = torch.zeros(18 * n, 18 * n, dtype=DT)
    for (a, b), block in zip(couplings.points.tolist(), couplings.blocks, strict=True):
        index = torch.cat((torch.arange(18 * a, 18 * a + 18), torch.arange(18 * b, 18 * b + 18)))
        matrix[index[:, None], index[None, :]] += block
    return matrix


def test_coupled_hessian_against_central_differences_of_the_gradient():
    """The pair blocks (exact, indefinite) times a random direction against the change of
    the gradient; and they are indefinite (b' < 0 on the tangential part), which Newton
    projects (`Couplings.projected` leaves them PSD)."""
    samples, u = _folded_samples()
    term = SelfContactTerm(CONFIG)
    couplings = term.coupled_hessian(samples, u)
    matrix = _dense(couplings, len(u))
    assert torch.allclose(matrix, matrix.T, atol=1e-12 * float(matrix.abs().max()))
    generator = torch.Generator().manual_seed(2)
    direction = torch.zeros_like(u)
    direction[:, jets.VALUE] = torch.randn(len(u), 3, dtype=DT, generator=generator)
    h = 1e-8
    change = (term.evaluate(samples, u + h * direction)[1]
              - term.evaluate(samples, u - h * direction)[1]) / (2 * h)
    product = (matrix @ direction.reshape(-1)).reshape(u.shape)
    error = float((product - change).norm() / change.norm())
    assert error < 1e-6, error
    eigenvalues = torch.linalg.eigvalsh(couplings.blocks)
    assert float(eigenvalues.min()) < 0
    projected, count = couplings.projected()
    assert count > 0 and float(torch.linalg.eigvalsh(projected.blocks).min()) > -1e-9 * float(
        eigenvalues.max())


def test_the_stiffness_rule_carries_the_load_at_half_the_activation_distance():
    """One point g = ĝ/2 above a fine wide lattice of points (spacing ĝ/20): the barrier's
    force per unit area of the point, κ Σ_b A_b |b'| n_z, equals q for κ =
    `default_stiffness(q, ĝ, o)` (the closed form 2π κ D b(g) of the module docstring)."""
    activation, offset, q = 0.004, 0.003, 2.5
    kappa = default_stiffness(q, activation, offset)
    spacing = activation / 20
    reach = math.sqrt((offset + activation) ** 2 - (offset + 0.5 * activation) ** 2)
    s = np.arange(-reach - spacing, reach + 2 * spacing, spacing)
    lattice = np.stack(np.meshgrid(s, s, indexing="ij"), axis=-1).reshape(-1, 2)
    height = offset + 0.5 * activation
    distance = torch.from_numpy(np.sqrt((lattice ** 2).sum(axis=1) + height ** 2))
    _, db, _ = barrier(distance - offset, activation)
    pressure = float((kappa * spacing ** 2 * (-db) * height / distance).sum())
    assert pressure == pytest.approx(q, rel=2e-3)


def test_candidate_pairs_are_close_and_far_apart_at_rest():
    rest = np.array([[0.0, 0, 0], [0.01, 0, 0], [0.1, 0, 0], [0.5, 0, 0]])
    x = np.array([[0.0, 0, 0], [0.0, 0, 0.003], [0.0, 0, 0.005], [0.0, 0, 0.2]])
    pairs = candidate_pairs(x, 0.006, rest, exclusion=0.05)
    assert sorted(map(tuple, pairs.tolist())) == [(0, 2), (1, 2)]


def test_closest_along_step_is_the_minimum_over_the_path():
    generator = np.random.default_rng(3)
    p0, v = generator.normal(size=(50, 3)), generator.normal(size=(50, 3))
    alphas = np.linspace(0, 1, 20001)
    brute = np.linalg.norm(p0[:, None] + alphas[None, :, None] * v[:, None], axis=2).min(axis=1)
    assert np.allclose(closest_along_step(p0, v), brute, atol=1e-7)


def _two_layers(gap):
    """Two parallel 5 × 5 lattices of points 1 cm apart, the upper `gap` [m] above, far
    apart at rest (x ± 1 m): rest, positions."""
    s = np.arange(5) * 0.01
    g = np.stack(np.meshgrid(s, s, indexing="ij"), axis=-1).reshape(-1, 2)
    lower = np.column_stack((g, np.zeros(len(g))))
    upper = lower + np.array([0.0, 0.0, gap])
    rest = np.vstack((lower, lower + np.array([1.0, 0, 0])))
    return torch.from_numpy(rest), torch.from_numpy(np.vstack((lower, upper)))


@pytest.mark.parametrize("drop, allowed", [
    (0.5, True),    # half the gap (o + ĝ − o) closed: allowed
    (0.9, False),   # 90 % of the gap closed (more than the step fraction 0.8)
    (2.0, False),   # through the lower layer, ending as far below it
    (40.0, False),  # tunnelling: the end far below, every end distance large
])
def test_the_step_test_refuses_steps_that_close_or_cross_a_gap(drop, allowed):
    config = SelfContactConfig(activation=0.004, offset=0.003, stiffness=1.0)
    rest, x = _two_layers(0.006)
    end = x.clone()
    end[25:, 2] -= drop * (0.006 - config.offset)
    assert self_step_allowed(config, rest, x, end) is allowed


def test_the_step_test_allows_sliding_and_ignores_neighbours():
    config = SelfContactConfig(activation=0.004, offset=0.003, stiffness=1.0)
    rest, x = _two_layers(0.006)
    sliding = x.clone()
    sliding[25:, 0] += 0.3  # the upper layer slides sideways: gaps never close
    assert self_step_allowed(config, rest, x, sliding)
    lower = x[:25]
    crossing = lower.clone()
    crossing[:5, 1] += 0.02  # points of one layer pass each other: excluded neighbours
    assert self_step_allowed(config, rest[:25], lower, crossing)


def test_the_settings_are_validated():
    with pytest.raises(ValueError, match="activation"):
        SelfContactConfig(activation=0.0, offset=0.001, stiffness=1.0)
    with pytest.raises(ValueError, match="exclusion"):
        SelfContactConfig(activation=0.004, offset=0.003, stiffness=1.0, exclusion=0.006)
    assert SelfContactConfig(0.004, 0.003, 1.0).exclusion == pytest.approx(0.014)


def test_hole_radius_of_a_gauss_lattice():
    """Four Gauss points per span: the widest gap is between the two middle nodes (0.3400 of
    a span); the hole radius is half the diagonal of that cell."""
    nodes = np.polynomial.legendre.leggauss(4)[0] * 0.5 + 0.5
    widest = nodes[2] - nodes[1]
    assert widest == pytest.approx(0.33999, abs=1e-5)
    assert hole_radius((0.02, 0.01), 4) == pytest.approx(0.5 * widest * math.hypot(0.02, 0.01))


def test_the_independent_intersection_test():
    """Two crossing triangles are found, parallel ones are not; a flat grid has none; a grid
    folded through itself (upper half below the lower one at its end) has some."""
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0],
                  [0.2, 0.2, -0.5], [0.2, 0.2, 0.5], [0.8, 0.8, 0.0]], dtype=float)
    assert len(self_intersections(v, np.array([[0, 1, 2], [3, 4, 5]]))) == 1
    v[3:, 2] = 0.1
    v[5, 2] = 0.1
    assert len(self_intersections(v, np.array([[0, 1, 2], [3, 4, 5]]))) == 0
    n = 11
    s = np.linspace(0, 1, n)
    g = np.stack(np.meshgrid(s, s, indexing="ij"), axis=-1).reshape(-1, 2)
    quads = [(i * n + j, (i + 1) * n + j, (i + 1) * n + j + 1, i * n + j + 1)
             for i in range(n - 1) for j in range(n - 1)]
    faces = np.array([f for a, b, c, d in quads for f in ((a, b, c), (a, c, d))])
    flat = np.column_stack((g, np.zeros(len(g))))
    assert len(self_intersections(flat, faces)) == 0
    folded = flat.copy()
    upper = g[:, 0] > 0.5
    folded[upper, 0] = 1.0 - g[upper, 0]
    folded[upper, 2] = 0.05 - 0.2 * (g[upper, 0] - 0.5)  # the upper half dips through
    assert len(self_intersections(folded, faces)) > 0
    folded[upper, 2] = 0.05 + 0.0 * g[upper, 0]
    assert len(self_intersections(folded, faces)) == 0


def test_the_contact_hook_refuses_a_crossing_step_only_with_self_contact():
    """The hook's `feasible(P, P_trial)` (what projected Newton's line search asks) on two
    layers 0.5 m above a table: the upper layer moved through the lower one passes the obstacle
    test (nothing nears the table) but not the self-contact one; without self-contact the hook
    allows it."""
    from dataclasses import replace

    from taichi_ndf.boundary import BoundaryConditions
    from taichi_ndf.contact import ContactConfig, ContactHook, GroundPlane
    from taichi_ndf.problem.loads import Loads
    from taichi_ndf.problem.model import ShellModel
    from taichi_ndf.shell.materials import preset

    surface = Plane(bounds=((0.0, 0.05), (0.0, 0.05)))
    model = ShellModel(surface, preset("cotton_polyester"), Loads(),
                       BoundaryConditions([], domain=surface.domain))
    config = SelfContactConfig(activation=0.004, offset=0.003, stiffness=1.0)
    contact = ContactConfig((GroundPlane(name="table", point=(0.0, 0.0, -0.5)),), 3e-4,
                            activation=1e-3, stiffness=1.0, check_resolution=4)
    rest, x = _two_layers(0.006)
    crossed = x.clone()
    crossed[25:, 2] -= 0.012
    for self_contact, allowed in ((config, False), (None, True)):
        hook = ContactHook.of_model(replace(model, contact=replace(contact,
                                                                    self_contact=self_contact)),
                                    DT, both_ends=False)
        grid = hook.points.grid_r
        positions = lambda p, grid=grid: torch.cat((p, grid))  # noqa: E731
        feasible = hook.feasible(positions, 1.0, self_rest=rest)
        assert feasible(x, crossed) is allowed
        assert feasible(x, x + 1e-4)


def test_self_contact_alone_refuses_a_crossing_step_and_has_no_obstacle_energy():
    """`ContactConfig.self_only` (no obstacle): the hook still refuses the upper layer moved
    through the lower one and allows a small step; the obstacle barrier is zero, every point's
    obstacle gap +inf, and result.json's obstacle distances are None."""
    from dataclasses import replace

    from taichi_ndf.boundary import BoundaryConditions
    from taichi_ndf.contact import ContactConfig, ContactHook
    from taichi_ndf.contact.config import contact_summary
    from taichi_ndf.problem.loads import Loads
    from taichi_ndf.problem.model import ShellModel
    from taichi_ndf.shell.materials import preset

    surface = Plane(bounds=((0.0, 0.05), (0.0, 0.05)))
    model = ShellModel(surface, preset("cotton_polyester"), Loads(),
                       BoundaryConditions([], domain=surface.domain))
    config = SelfContactConfig(activation=0.004, offset=0.003, stiffness=1.0)
    contact = ContactConfig.self_only(model, config)
    with pytest.raises(ValueError, match="at least one obstacle"):
        replace(contact, self_contact=None)
    hook = ContactHook.of_model(replace(model, contact=contact), DT, both_ends=False)
    rest, x = _two_layers(0.006)
    crossed = x.clone()
    crossed[25:, 2] -= 0.012
    grid = hook.points.grid_r
    assert len(grid) == 4
    feasible = hook.feasible(lambda p: torch.cat((p, grid)), 1.0, self_rest=rest)
    assert not feasible(x, crossed)
    assert feasible(x, x + 1e-4)
    assert torch.isinf(hook.points.point_gaps(x, 1.0)).all()
    samples, u = _folded_samples()
    assert contact.term().evaluate(samples, u)[0] == 0.0
    summary = contact_summary(contact, x)
    assert summary["min_signed_distance"] is None and summary["min_gap"] is None


def test_the_contact_potential_passes_the_pair_blocks_on():
    """`ContactPotential` (the spline contact rounds' potential) gives the self-contact term's
    pair blocks to Newton (`coupled_blocks`) and skips it among the per-point blocks."""
    from taichi_ndf.contact.newton_contact import ContactPotential
    from taichi_ndf.objective import Objective, ShellEnergyTerm
    from taichi_ndf.problem.loads import Loads
    from taichi_ndf.shell.materials import preset

    samples, u = _folded_samples()
    term = SelfContactTerm(CONFIG)
    potential = ContactPotential(Objective(ShellEnergyTerm(preset("cotton_polyester"),
                                                           Loads())), (term,), 1.0)
    couplings = potential.coupled_blocks(samples, u)
    own = term.coupled_hessian(samples, u)
    assert torch.equal(couplings.points, own.points)
    assert torch.allclose(couplings.blocks, own.blocks)
    value = potential(samples, u, True)
    assert value.total == pytest.approx(
        term.evaluate(samples, u)[0] + Objective(ShellEnergyTerm(
            preset("cotton_polyester"), Loads())).evaluate(samples, u).total)


def test_edge_points_lie_on_the_free_edges_and_share_the_area():
    """The outermost Gauss rows projected onto the free edges (and corners): 3 × 2 spans of
    4² points have 2 (8 + 12) edge points plus 4 corners; a periodic direction none; the
    Gauss points and edge points together keep the area."""
    from taichi_ndf.contact.self_pairs import edge_points
    from taichi_ndf.field import SplineConfig
    from taichi_ndf.problem.quadrature import span_points

    config = SplineConfig((3, 2), domain=((0.0, 0.3), (0.0, 0.15)))
    xi, weight = span_points(config)
    edges = edge_points(xi, weight, config.domain, (False, False))
    assert len(edges.xi) == 2 * (8 + 12) + 4
    on_edge = ((edges.xi[:, 0] == 0.0) | (edges.xi[:, 0] == 0.3)
               | (edges.xi[:, 1] == 0.0) | (edges.xi[:, 1] == 0.15))
    assert bool(on_edge.all())
    total = float((weight / edges.shares(xi)).sum() + edges.weight.sum())
    assert total == pytest.approx(0.3 * 0.15, rel=1e-12)
    tube = edge_points(xi, weight, config.domain, (True, False))
    assert len(tube.xi) == 2 * 12 and bool(((tube.xi[:, 1] == 0.0)
                                           | (tube.xi[:, 1] == 0.15)).all())


def test_edge_points_carry_the_barrier_at_a_free_edge():
    """A layer's free edge over another layer, closer than the barrier's reach only at its
    edge: the Gauss points alone feel nothing; with the edge points (samples of weight 0 at
    their ξ) the energy is positive and its gradient pushes the edge up."""
    from taichi_ndf.contact.self_pairs import edge_points
    from taichi_ndf.field import SplineConfig
    from taichi_ndf.problem.quadrature import span_points

    config = SplineConfig((4, 2), domain=((0.0, 0.2), (0.0, 0.05)))
    xi, weight = span_points(config)
    edges = edge_points(xi, weight, config.domain, (False, False))
    surface = Plane(bounds=config.domain)
    all_xi = torch.cat((xi, edges.xi))
    w = torch.cat((weight, torch.zeros(len(edges.xi), dtype=DT)))
    samples = SurfaceSamples(all_xi, surface.jets(all_xi).to(DT), w,
                             torch.zeros(len(all_xi), 3, dtype=DT))
    # the half ξ¹ > 0.1 folded over the other: x¹ = 0.25 − ξ¹, tilted so that its free edge
    # ξ¹ = 0.2 sits 3 mm over the lower layer's ξ¹ = 0.05 (4.6 mm from its nearest Gauss
    # points, 3.5 mm of ξ¹ away), rising 1 m per metre of ξ¹ away from it (its outer Gauss
    # row, 3.5 mm of ξ¹ in, 6.5 mm up: beyond o + ĝ = 5.5 mm of every lower point)
    r = samples.r_jets[:, jets.VALUE]
    x = r.clone()
    upper = all_xi[:, 0] > 0.1
    x[upper, 0] = 0.25 - all_xi[upper, 0]
    x[upper, 2] = 0.003 + (0.2 - all_xi[upper, 0])
    u = torch.zeros(len(all_xi), jets.CHANNELS, 3, dtype=DT)
    u[:, jets.VALUE] = x - r
    config_s = SelfContactConfig(activation=0.002, offset=0.0035, stiffness=1e9,
                                 exclusion=0.03)
    alone = SelfContactTerm(config_s).evaluate(samples, u)[0]
    term = SelfContactTerm(config_s, edges)
    value, gradient = term.evaluate(samples, u)
    assert alone == 0.0 and value > 0
    rows, area = term.points(samples)
    assert len(rows) == len(xi) + len(edges.xi)
    assert float(area.sum()) == pytest.approx(0.2 * 0.05, rel=1e-12)
    edge_rows = torch.nonzero(all_xi[:, 0] == 0.2).reshape(-1)
    assert float(gradient[edge_rows, jets.VALUE, 2].sum()) < 0  # Π falls as the edge rises
