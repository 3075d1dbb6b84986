"""Per-point Hessian blocks, coefficient-space assembly and projected Newton on a spline
field."""

import math
from pathlib import Path

import numpy as np
import pytest
import torch

from taichi_ndf.boundary import BoundaryConditions, ClampedEdge, HingedEdge, PinnedPoint
from taichi_ndf.field.spline import SplineConfig, SplineField
from taichi_ndf.geometry import Plane
from taichi_ndf.minimise import assembly as assembly_module
from taichi_ndf.minimise.assembly import Assembly, local_basis_at
from taichi_ndf.minimise.line_search import longer_step
from taichi_ndf.minimise.newton import NewtonConfig
from taichi_ndf.minimise.refinement import richardson, solve_levels
from taichi_ndf.objective import Objective, ShellEnergyTerm
from taichi_ndf.problem.loads import Loads, PointLoad
from taichi_ndf.problem.operator import DisplacementOperator
from taichi_ndf.problem.quadrature import span_quadrature
from taichi_ndf.scene.reader import load_scene
from taichi_ndf.shell.energy import ShellEnergy
from taichi_ndf.shell.hessian import flat_blocks, jet_steps, project_psd, sample_hessians
from taichi_ndf.shell.materials import LinearIsotropic, OrthotropicStVK, preset
from taichi_ndf.solve.spline_solver import solve_spline
from taichi_ndf.validation import CASES, LINEARISATION, load_case_scene

DT = torch.float64
SCENES = Path(__file__).resolve().parents[1] / "scenes"


def _potential(material, loads):
    energy = ShellEnergy(material, loads)
    return lambda s, u, grad: energy.evaluate(s, u, grad=grad)


def _materials():
    return {
        "linear_isotropic": LinearIsotropic.from_young(1e6, 0.3, 0.01, 1.0),
        "orthotropic": OrthotropicStVK(a11=2e4, a12=3e3, a22=1e4, G12=4e3, thickness=0.01,
                                       areal_density=1.0),
        "clyde": preset("canvas"),
    }


@pytest.mark.parametrize("law", ["linear_isotropic", "orthotropic", "clyde"])
def test_hessian_blocks_match_directional_differences_of_the_gradient(law):
    material = _materials()[law]
    surface = Plane(bounds=((0.0, 1.0), (0.0, 1.0)))
    samples = span_quadrature(surface, SplineConfig(spans=(2, 2)), points=3, dtype=DT)
    generator = torch.Generator().manual_seed(1)
    u = 0.05 * torch.randn(len(samples), 6, 3, generator=generator, dtype=DT)
    potential = _potential(material, Loads(gravity=(0.0, 0.0, -9.81)))
    steps = jet_steps(samples.r_jets, u, 1.0, 1e-4)
    blocks = flat_blocks(sample_hessians(potential, samples, u, steps=steps))
    direction = (torch.randn(len(samples), 6, 3, generator=generator, dtype=DT)
                 * (steps / 1e-4)[:, None])
    eps = 1e-6
    plus = potential(samples, u + eps * direction, True).grad_u_jets
    minus = potential(samples, u - eps * direction, True).grad_u_jets
    expected = ((plus - minus) / (2 * eps)).reshape(len(samples), 18)
    got = torch.bmm(blocks, direction.reshape(len(samples), 18, 1))[..., 0]
    assert float((got - expected).norm() / expected.norm()) <= 1e-6


@pytest.mark.parametrize("mode", ["abs", "clamp"])
def test_projection_mirrors_or_clamps_negative_eigenvalues_and_keeps_definite_blocks(mode):
    generator = torch.Generator().manual_seed(0)
    a = torch.randn(5, 18, 18, generator=generator, dtype=DT)
    definite = a @ a.transpose(1, 2) + torch.eye(18, dtype=DT)
    indefinite = a + a.transpose(1, 2)
    blocks = torch.cat((definite, indefinite))
    projected, count = project_psd(blocks, mode=mode)
    assert count == 5
    assert torch.equal(projected[:5], definite)
    values, vectors = torch.linalg.eigh(indefinite)
    assert float(torch.linalg.eigvalsh(projected[5:]).min()) > -1e-12
    modified = values.abs() if mode == "abs" else values.clamp_min(0)
    expected = (vectors * modified[:, None]) @ vectors.transpose(1, 2)
    assert torch.allclose(projected[5:], expected, atol=1e-12)
    # Rows zero in every block (the shell's value channel) stay zero; the rest as before.
    padded = torch.nn.functional.pad(blocks, (3, 0, 3, 0))
    projected_padded, count = project_psd(padded, mode=mode)
    assert count == 5 and torch.all(projected_padded[:, :3] == 0)
    assert torch.allclose(projected_padded[:, 3:, 3:], projected, atol=1e-12)
    with pytest.raises(ValueError, match="projection"):
        project_psd(blocks, mode="flip")


@pytest.mark.parametrize("pad", [0, 3])  # all rows active (a slice), or zero rows (indices)
def test_projection_in_place_is_the_copy_bit_for_bit_without_a_second_tensor(pad):
    # Newton projects its blocks in place (issue 28: one (N, 18, 18) array less at the peak).
    a = torch.randn(6, 18, 18, generator=torch.Generator().manual_seed(1), dtype=DT)
    blocks = torch.nn.functional.pad(torch.cat((a @ a.transpose(1, 2), a + a.transpose(1, 2))),
                                     (pad, 0, pad, 0))
    copied, count = project_psd(blocks, mode="clamp")
    original = blocks.clone()
    in_place, count_in_place = project_psd(blocks, mode="clamp", overwrite=True)
    assert in_place.data_ptr() == blocks.data_ptr() and count_in_place == count == 6
    assert torch.equal(in_place, copied) and not torch.equal(in_place, original)


def _case(boundary_kind):
    bounds = ((0.0, 1.0), (0.0, 1.0))
    surface = Plane(bounds=bounds)
    if boundary_kind == "free_pin":
        constraints = [PinnedPoint(xi=(0.3, 0.0), rotation="free")]
    else:
        constraints = [ClampedEdge(edge="xi1_min"), HingedEdge(edge="xi2_max")]
    boundary = BoundaryConditions(constraints, domain=surface.domain, surface=surface)
    loads = Loads(gravity=(0.0, 0.0, -9.81))
    material = LinearIsotropic.from_young(1e4, 0.3, 0.01, 1.0)
    field = SplineField(SplineConfig(spans=(2, 2), domain=bounds), dtype=DT)
    samples = span_quadrature(surface, field.config, loads, points=3, dtype=DT)
    generator = torch.Generator().manual_seed(2)
    coefficients = 0.02 * torch.randn(field.parameters[0].shape, generator=generator, dtype=DT)
    operator = DisplacementOperator(field, boundary)
    assembly = Assembly(samples, local_basis_at(operator, samples.xi),
                        coefficients.shape[0]).at_load(operator, 1.0)
    shell = _potential(material, loads)

    def potential(s, u, grad):
        """The shell plus springs ½ k |u|² per area to the reference positions: a term in the
        displacement value, which the free pin's coupling carries."""
        result = shell(s, u, grad)
        stiffness = 50.0 * s.weight
        result.total += float(0.5 * (stiffness[:, None] * u[:, 0] ** 2).sum())
        if grad:
            result.grad_u_jets = result.grad_u_jets.clone()
            result.grad_u_jets[:, 0] += stiffness[:, None] * u[:, 0]
        return result

    return field, boundary, assembly.samples, potential, assembly, coefficients


@pytest.mark.parametrize("boundary_kind", ["edges", "free_pin"])
def test_assembled_gradient_matches_the_composition_adjoint(boundary_kind):
    field, boundary, samples, potential, assembly, c = _case(boundary_kind)
    index, basis = field.local_basis(boundary.evaluation_points(samples.xi))
    raw = torch.einsum("nja,nac->njc", basis, c[index])
    u = boundary.compose(samples.xi, raw)
    assert torch.allclose(assembly.displacement(c), u, atol=1e-14)
    grad_raw = boundary.compose_adjoint(samples.xi, potential(samples, u, True).grad_u_jets)
    expected = torch.zeros_like(c).index_add_(
        0, index.reshape(-1), torch.einsum("nja,njc->nac", basis, grad_raw).reshape(-1, 3))
    got = assembly.gradient(potential(samples, u, True).grad_u_jets)
    assert torch.allclose(got, expected, rtol=1e-12, atol=1e-12 * float(expected.abs().max()))


@pytest.mark.parametrize("boundary_kind", ["edges", "free_pin"])
def test_assembled_hessian_matches_differences_of_the_assembled_gradient(boundary_kind):
    _, _, samples, potential, assembly, c = _case(boundary_kind)

    def gradient(coefficients):
        u = assembly.displacement(coefficients)
        return assembly.gradient(potential(samples, u, True).grad_u_jets).reshape(-1)

    u = assembly.displacement(c)
    blocks = flat_blocks(sample_hessians(potential, samples, u,
                                         steps=jet_steps(samples.r_jets, u, 1.0, 1e-4)))
    matrix = assembly.hessian(blocks).toarray()
    eps = 1e-6
    dense = np.zeros_like(matrix)
    for j in range(matrix.shape[0]):
        step = torch.zeros(matrix.shape[0], dtype=DT)
        step[j] = eps
        dense[:, j] = ((gradient(c + step.reshape(c.shape))
                        - gradient(c - step.reshape(c.shape))) / (2 * eps)).numpy()
    assert np.abs(matrix - matrix.T).max() <= 1e-12 * np.abs(matrix).max()
    assert np.linalg.norm(matrix - dense) <= 1e-6 * np.linalg.norm(dense)


@pytest.mark.parametrize("boundary_kind", ["edges", "free_pin"])
def test_assembled_hessian_is_the_same_bit_for_bit_in_chunks_of_one_span(boundary_kind,
                                                                        monkeypatch):
    # K's per-span sums are taken in chunks of points (issue 28: the temporaries are a
    # chunk's): chunks of one span each give the same K as one chunk of all spans.
    _, _, samples, _, assembly, _ = _case(boundary_kind)
    a = torch.randn(len(samples), 18, 18, generator=torch.Generator().manual_seed(3), dtype=DT)
    a[:, :3], a[:, :, :3] = 0.0, 0.0  # no value channel: the shell's channels (a view)
    blocks = a + a.transpose(1, 2)
    whole = assembly.hessian(blocks)
    monkeypatch.setattr(assembly_module, "CHUNK", 9)  # 3 × 3 points per span
    chunked = assembly.hessian(blocks)
    assert np.array_equal(whole.indices, chunked.indices)
    assert np.array_equal(whole.data, chunked.data) and np.abs(whole.data).max() > 0


# -- projected Newton on the spline field ------------------------------------------------------


def _solve(scene_model, spans, load_steps, config=None, probes=None, levels=1):
    surface, boundary = scene_model.surface, scene_model.boundary
    material, loads = scene_model.material, scene_model.loads
    field = SplineField(SplineConfig(spans=spans, domain=surface.domain.bounds), dtype=DT)
    return solve_levels(field, boundary,
                        lambda f: span_quadrature(surface, f.config, loads, dtype=DT),
                        Objective(ShellEnergyTerm(material, loads)), levels=levels,
                        load_steps=load_steps, config=config,
                        probes=probes or {}, length=math.sqrt(surface.domain.rectangle_area))


def test_square_plate_within_one_percent_on_an_8_by_8_grid():
    case = CASES["square_plate"]
    _, model, _ = load_case_scene(case)
    (solution,), = _solve(model, (8, 8), (1.0,), probes={"centre": (50.0, 50.0)})
    w = float(solution.probes["centre"][2]) / LINEARISATION
    assert solution.converged
    assert abs(w - 0.4875) / 0.4875 < 0.01


def test_newton_converges_quadratically_on_a_large_deflection():
    """The large-deflection strip (`_large_deflection_strip`): the final Newton decrements
    fall quadratically."""
    (solution,), = _solve(_large_deflection_strip(), (6, 1), (0.5,), NewtonConfig(
        decrement_tolerance=1e-15), probes={"tip": (10.0, 0.5)})
    decrements = [h.decrement / abs(solution.energy) for h in solution.history]
    assert solution.converged
    assert float(solution.probes["tip"][2]) > 3.0  # large rotation
    assert decrements[-1] < 1e-12
    # The last three decrements above the rounding floor, relative to |Π| (measured: …,
    # 1.3e-5, 5.3e-8, 4.3e-12): each below C × the previous squared (C ≈ 1.5e3 measured), an
    # observed order ≥ 1.5 (1.7; the FD Hessian's ~1e-8 error limits it).
    d0, d1, d2 = [d for d in decrements if d > 1e-18][-3:]
    assert d1 <= 1e4 * d0**2 and d2 <= 1e4 * d1**2, decrements
    assert math.log(d2 / d1) / math.log(d1 / d0) > 1.5, decrements


def _large_deflection_strip():
    """A cantilever strip under an end shear that deflects it by a third of its length."""
    bounds = ((0.0, 10.0), (0.0, 1.0))
    surface = Plane(bounds=bounds)
    boundary = BoundaryConditions([ClampedEdge(edge="xi1_min")], domain=surface.domain,
                                  surface=surface, length=2.0)
    loads = Loads(point_loads=[PointLoad(xi=(10.0, y), force=(0.0, 0.0, 1.0))
                               for y in (0.25, 0.5, 0.75)])
    material = LinearIsotropic.from_young(1.2e6, 0.0, 0.1, 1.0)
    return type("Model", (), {"surface": surface, "boundary": boundary,
                              "material": material, "loads": loads})


def test_a_solve_stopped_by_a_loose_decrement_tolerance_is_converged():
    """A decrement tolerance (a run's newton_tolerance) far above the rounding floor ends the
    solve before the step, converged."""
    tolerance = 1e-4
    (solution,), = _solve(_large_deflection_strip(), (6, 1), (0.5,), NewtonConfig(
        decrement_tolerance=tolerance, floor_tolerance=1e-14))
    last = solution.history[-1]
    assert last.step_length == 0.0
    assert 1e-14 < 0.5 * last.decrement / abs(last.energy) <= tolerance
    assert solution.converged


def test_a_full_step_is_lengthened_only_where_the_quadratic_model_underestimates_the_fall():
    """λ² = 2 (the model: Π(α) = Π(0) − 2α + α², so Π(1) = Π(0) − 1)."""
    calls = []

    def along(energy):
        def at(alpha):
            calls.append(alpha)
            return energy(alpha)
        return at

    # Π falls as the model says (a quadratic with its minimum at α = 1): no extra trial.
    assert longer_step(along(lambda a: -2 * a + a * a), 0.0, -1.0, 2.0, 4) == 1.0
    assert calls == []
    # A direction without curvature (Π(α) = −2α, e.g. along a clamped negative eigenvalue):
    # doubled up to the cap.
    assert longer_step(along(lambda a: -2 * a), 0.0, -2.0, 2.0, 4) == 16.0
    assert longer_step(along(lambda a: -2 * a), 0.0, -2.0, 2.0, 2) == 4.0
    # Curvature a quarter of the model's (minimum at α = 4): the best power of two.
    assert longer_step(along(lambda a: -2 * a + a * a / 4), 0.0, -1.75, 2.0, 4) == 4.0
    # A rejected (infeasible) longer trial keeps the step accepted so far.
    assert longer_step(lambda a: -2 * a if a < 4 else math.inf, 0.0, -2.0, 2.0, 4) == 2.0
    with pytest.raises(ValueError, match="longer_steps"):
        NewtonConfig(longer_steps=-1)


def test_longer_steps_take_fewer_newton_steps_on_the_draped_napkin():
    """The napkin on 8 × 8 spans from the flat sheet (projected K, cloth folds): measured 67
    Newton steps with longer steps against 69 without, to the same minimum."""
    model = load_scene(SCENES / "napkin.toml", material="cloth").model  # as measured
    steps, energies = {}, {}
    for longer in (0, 4):
        config = NewtonConfig(decrement_tolerance=1e-10, longer_steps=longer)
        (solution,), = _solve(model, (8, 8), (1.0,), config, probes={"free": (1.0, 1.0)})
        assert solution.converged
        longer_taken = sum(h.step_length > 1 for h in solution.history)
        assert longer_taken > 0 if longer else longer_taken == 0
        steps[longer], energies[longer] = len(solution.history), solution.energy
    assert energies[4] == pytest.approx(energies[0], rel=1e-8)
    assert steps[4] < steps[0], steps


def test_free_pin_hangs_and_holds_the_pinned_point():
    scene = load_scene(SCENES / "napkin.toml", material="cloth")  # the numbers below
    (coarse,), (fine,) = _solve(scene.model, (2, 2), (1.0,), levels=2,
                                probes={"pin": (0.0, 0.0), "free": (1.0, 1.0)})
    for solution in (coarse, fine):
        assert solution.converged
        assert np.abs(solution.probes["pin"]).max() < 1e-12
        assert solution.probes["free"][2] < -0.5  # the free corner hangs below the pin
    assert fine.energy < coarse.energy  # the finer grid contains the coarser one
    # From the flat sheet, K is singular along the rigid rotations about the pin: a negative
    # decrement must raise the damping, not end the solve at Π = 0 as "converged".
    assert coarse.energy < -1.25


def test_richardson_recovers_the_limit_and_order_of_a_power_law():
    values = [2.0 + 0.5 * h**3 for h in (1.0, 0.5, 0.25)]
    result = richardson(values)
    assert result.order == pytest.approx(3.0, rel=1e-9)
    assert result.value == pytest.approx(2.0, rel=1e-12)
    assert result.error == pytest.approx(1.25 * 0.5 * 0.25**3, rel=1e-9)  # Roache's Fs 1.25
    stalled = richardson([1.0, 1.1, 1.05])  # differences not falling: no extrapolation
    assert stalled.order is None and stalled.value == 1.05 and stalled.unreliable
    assert stalled.error == pytest.approx(0.3)  # 3 × the range of the three values
    assert richardson([1.0, 1.5], order=1.0).value == pytest.approx(2.0)
    with pytest.raises(ValueError, match="assumed order"):
        richardson([1.0, 1.5])


def _power_sums(limit: float, terms: list[tuple[float, float]]) -> list[float]:
    """limit + Σ c h^q on the grids h = 1, 1/2, 1/4: a sequence whose limit and asymptotic
    order (the smallest q) are known."""
    return [limit + sum(c * h**q for c, q in terms) for h in (1.0, 0.5, 0.25)]


@pytest.mark.parametrize("order", [0.6, 1.0, 2.0, 3.0, 4.0])
def test_a_power_law_of_a_reasonable_order_is_extrapolated_and_covered(order):
    values = _power_sums(-1.3, [(0.2, order)])
    result = richardson(values, order=4.0)
    assert result.basis == "observed" and result.order == pytest.approx(order, rel=1e-6)
    assert abs(result.value - (-1.3)) <= result.error
    assert result.error == pytest.approx(1.25 * abs(result.value - values[-1]), rel=1e-9)


def test_a_near_zero_change_between_the_last_grids_is_not_read_as_a_high_order():
    """Issue 35 (cantilever_shear: 6.5e-6 then 6.4e-9, observed order 10, bar 76 000× too
    small): order 0.7 with a pre-asymptotic h⁴ term of the opposite sign that makes the last
    two grids agree. main's rule extrapolated at order 10.5 and its bar missed the limit by
    5 orders of magnitude; the guarded rule calls the order unreliable and the bar covers."""
    a = 0.01
    b = -a * (0.5**0.7 - 0.25**0.7) / (0.5**4 - 0.25**4) * (1 + 1e-2)
    values = _power_sums(2.0, [(a, 0.7), (b, 4.0)])
    assert abs(values[2] - values[1]) < 1e-3 * abs(values[1] - values[0])  # near-zero change
    result = richardson(values, order=4.0)
    assert abs(result.value - 2.0) <= result.error  # main: 3.6e-3 away, bar 1.7e-8
    assert result.unreliable and "above the expected 4" in result.reason
    assert "order unreliable" in result.describe() and "order unreliable" in result.warning
    assert result.value == values[-1]
    assert result.error == pytest.approx(3 * abs(values[2] - values[0]), rel=1e-9)
    assert result.to_dict()["order_basis"] == "unreliable"


def test_growing_differences_are_bounded_by_the_range_not_the_last_change():
    """Issue 35 (the napkin in cotton_polyester on 2/4/8 spans: changes −0.017, −0.030, bar
    0.8× short): order 0.5 with a pre-asymptotic h² term, so the changes grow. main's bar, the
    larger of the two changes, misses the limit; 3 × the range covers."""
    values = _power_sums(-1.65, [(0.117, 0.5), (-0.023, 2.0)])
    d1, d2 = np.diff(values)
    assert d1 * d2 > 0 and abs(d2) > abs(d1)  # same sign, growing
    assert abs(values[-1] - (-1.65)) > max(abs(d1), abs(d2))  # main's bar falls short
    result = richardson(values, order=4.0)
    assert abs(result.value - (-1.65)) <= result.error
    assert result.unreliable and result.reason == "changes not falling monotonically"


@pytest.mark.parametrize("values, reason", [
    # cantilever_shear at t = 0.1 (its last change at the rounding level) has the bound
    # "floor": tests/test_extrapolation.py
    ([1.0 + 0.3 * h**0.3 for h in (1.0, 0.5, 0.25)], "below 0.5"),
    ([1.0, 1.2, 1.1], "not falling"),  # oscillating
])
def test_unreliable_orders_say_why_and_fall_back_to_three_times_the_range(values, reason):
    result = richardson(values, order=4.0)
    assert result.unreliable and reason in result.reason and result.value == values[-1]
    assert result.error == pytest.approx(3 * (max(values) - min(values)), rel=1e-12)
    assert f"({result.reason})" in result.describe()


def test_two_grid_richardson_says_order_assumed_and_widens_the_bar_to_the_change():
    """Issue 35: the napkin's two-grid bar at the assumed order 4 (−1.31609 ± 0.00078 J) was
    15× smaller than the change between its grids and missed the 32² value. With two grids
    the bar is the whole change and the value says its order was assumed."""
    two = richardson([-1.30426, -1.31535], order=4.0)
    assert two.assumed and two.grids == 2
    assert two.value == pytest.approx(-1.31535 - 0.01109 / 15, rel=1e-9)
    assert two.error == pytest.approx(0.01109, rel=1e-9)
    assert "order 4 assumed" in two.describe("J")
    assert two.to_dict()["order_basis"] == "assumed"
    assert two.value - two.error < -1.32216  # the 32 x 32 value lies inside


def test_richardson_warns_where_the_observed_order_is_far_from_the_expected(caplog):
    """The napkin's 8/16/32 grids observe order 0.77 against the expected 4: the estimate
    rests on the observed order, with a warning that names both."""
    slow = [1.0 + h**0.77 for h in (1.0, 0.5, 0.25)]
    with caplog.at_level("WARNING"):
        result = richardson(slow, order=4.0)
    assert result.basis == "observed" and result.order == pytest.approx(0.77)
    assert result.warning is not None and "0.77" in result.warning and "4" in result.warning
    assert result.value == pytest.approx(1.0, abs=1e-9)
    assert "observed order 0.77" in result.describe()
    assert any("far below the expected" in r.message for r in caplog.records)
    assert richardson([2.0 + h**4 for h in (1.0, 0.5, 0.25)], order=4.0).warning is None


def test_clamped_projection_needs_fewer_newton_steps_than_mirrored_on_a_draped_flag():
    """The default projection (negative eigenvalues clamped to 0) against the mirrored one
    (|λ|) on a coarse flag that drapes from its hoist under gravity and wind from the flat
    state: many blocks are indefinite (compression folds). Measured: 40 against 48 Newton
    steps to the same minimum (napkin 32 × 32 spans from 16 × 16: 9 against 11), with the
    `cloth` preset the flag had then."""
    model = load_scene(SCENES / "flag.toml", material="cloth").model
    steps, energies = {}, {}
    for mode in ("clamp", "abs"):
        config = NewtonConfig(hessian=mode, decrement_tolerance=1e-10,
                                       max_iterations=200)
        (solution,), = _solve(model, (4, 3), (1.0,), config)
        assert solution.converged
        assert any(h.projected_blocks for h in solution.history)
        steps[mode], energies[mode] = len(solution.history), solution.energy
    assert energies["clamp"] == pytest.approx(energies["abs"], rel=1e-8)
    assert steps["clamp"] < steps["abs"], steps


@pytest.mark.slow
def test_the_flag_converges_with_the_default_spline_settings():
    """`ndf-sim scenes/flag.toml --field spline` in float64: the draped flag's damped phase
    (an exact, definite K far from the quadratic region) is long; measured 106 Newton
    iterations, beyond the former 100-iteration cap (about 1 min), with the `cloth` preset
    the flag had then (in its measured `polyester`: 405 iterations, Π −0.965153 J)."""
    scene = load_scene(SCENES / "flag.toml", field="spline", material="cloth")
    run = solve_spline(scene.model, scene.field, scene.solver)
    level, = run.levels
    assert level.converged, (level.iterations, level.energy)
    assert level.energy == pytest.approx(-1.466637, rel=1e-5)


def test_the_strain_treatment_reaches_the_clamped_minimum_on_the_draped_flag():
    """`hessian="strain"` (every block positive semi-definite through the strains, no screen)
    against the default clamp on the coarse draped flag: the same minimum, and as few Newton
    steps give or take 10 % (measured: 39 each, benchmarks/RESULTS.md); where it projects,
    every block is replaced."""
    model = load_scene(SCENES / "flag.toml", material="cloth").model
    solutions = {}
    for mode in ("clamp", "strain"):
        config = NewtonConfig(hessian=mode, decrement_tolerance=1e-10, max_iterations=200)
        (solutions[mode],), = _solve(model, (4, 3), (1.0,), config)
        assert solutions[mode].converged
    strain, clamp = solutions["strain"], solutions["clamp"]
    assert strain.energy == pytest.approx(clamp.energy, rel=1e-8)
    assert len(strain.history) <= 1.1 * len(clamp.history)
    points = {h.projected_blocks for h in strain.history} - {0}
    assert len(points) == 1  # all blocks, every time it projects
