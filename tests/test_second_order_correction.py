"""Newton's second-order correction of a rejected full step (`minimise.line_search`): a stiff
spring (a pendulum) and a draped napkin, where plain backtracking crawls; linear problems and
accepted full steps unchanged; the membrane residual against the energy's own expansion."""

import math
from dataclasses import dataclass

import pytest
import torch

from taichi_ndf import jets
from taichi_ndf.boundary import BoundaryConditions, HingedEdge
from taichi_ndf.field.spline import SplineConfig, SplineField
from taichi_ndf.geometry import Plane
from taichi_ndf.minimise.line_search import backtrack
from taichi_ndf.minimise.newton import NewtonConfig, minimise
from taichi_ndf.minimise.refinement import solve_levels
from taichi_ndf.objective import Objective, ShellEnergyTerm
from taichi_ndf.problem.loads import Loads
from taichi_ndf.problem.quadrature import span_quadrature
from taichi_ndf.scene.reader import load_scene
from taichi_ndf.shell.energy import ShellEnergy
from taichi_ndf.shell.materials import LinearIsotropic
from taichi_ndf.shell.strain_hessian import membrane_second_order_gradient
from tests.scripts import ROOT

DT = torch.float64
LENGTH, STIFFNESS, WEIGHT = 1.0, 1e6, 1.0  # the spring: rest length L [m], k [N], m g [N]


class _OnePoint:
    def __len__(self):
        return 1


class _Pendulum:
    """A `Linearisation` of a mass at x (3,) [m] hung from the origin: the jets' tangent
    channel D1 holds x (U = J P with J the identity there), a dense K (3 × 3)."""

    samples = _OnePoint()

    def displacement(self, parameters):
        u = parameters.new_zeros(1, jets.CHANNELS, 3)
        u[0, jets.D1] = parameters
        return u

    def gradient(self, grad_u_jets):
        return grad_u_jets[0, jets.D1].clone()

    def fd_steps(self, u_jets, parameters, relative):
        return torch.ones(jets.CHANNELS, dtype=DT)

    def hessian(self, blocks, couplings=None):
        return blocks(slice(0, 1)).reshape(jets.CHANNELS, 3, jets.CHANNELS, 3)[
            jets.D1, :, jets.D1, :].clone()

    def solve(self, matrix, gradient, damping, *, require_definite=False):
        mu = damping
        while True:
            factor, info = torch.linalg.cholesky_ex(matrix + mu * torch.diag(matrix.diagonal()))
            if int(info) == 0:
                return -torch.cholesky_solve(gradient[:, None], factor)[:, 0], damping
            if require_definite:
                return None
            mu = max(10 * mu, 1e-8)


@dataclass
class _Energy:
    total: float
    grad_u_jets: torch.Tensor


class _StiffSpring:
    """Π = ½ k L ε² + m g x_z with the spring's Green strain ε = (|x|² − L²) / (2 L²): a stiff
    constraint |x| ≈ L on a curved manifold (the circle), the pendulum's Maratos effect."""

    @staticmethod
    def _strain(x):
        return (x @ x - LENGTH**2) / (2 * LENGTH**2)

    def __call__(self, samples, u_jets, grad):
        x = u_jets[0, jets.D1]
        strain = self._strain(x)
        gradient = u_jets.new_zeros(u_jets.shape)
        gradient[0, jets.D1] = STIFFNESS * strain * x / LENGTH + torch.tensor(
            [0.0, 0.0, WEIGHT], dtype=DT)
        return _Energy(float(0.5 * STIFFNESS * LENGTH * strain**2 + WEIGHT * x[2]), gradient)

    def hessian_blocks(self, samples, u_jets, *, steps, rows=None):
        x = u_jets[0, jets.D1]
        blocks = u_jets.new_zeros(1, jets.CHANNELS, 3, jets.CHANNELS, 3)
        blocks[0, jets.D1, :, jets.D1, :] = STIFFNESS / LENGTH * (
            torch.outer(x, x) / LENGTH**2 + self._strain(x) * torch.eye(3, dtype=DT))
        return blocks

    def second_order_gradient(self, samples, u_jets, step_jets):
        """The stress k L ε₂ of the step's second-order strain ε₂ = |Δx|² / (2 L²), pulled
        back through dε/dx = x / L² at x."""
        x, step = u_jets[0, jets.D1], step_jets[0, jets.D1]
        out = u_jets.new_zeros(u_jets.shape)
        out[0, jets.D1] = STIFFNESS * (step @ step) / (2 * LENGTH**2) * x / LENGTH
        return out


def _hang(correction: bool):
    start = 1.001 * torch.tensor([math.cos(-1.2), 0.0, math.sin(-1.2)], dtype=DT)
    config = NewtonConfig(decrement_tolerance=1e-14, second_order_correction=correction)
    return minimise(_Pendulum(), _StiffSpring(), start, config, report=False)


def test_the_correction_ends_the_crawl_of_a_pendulum_on_a_stiff_spring():
    """Measured: plain backtracking 57 Newton iterations (λ² falling ~5 % per iteration), the
    corrected line search 9; the same minimum (the mass below the pivot, stretched by m g / k)."""
    plain, corrected = _hang(False), _hang(True)
    assert plain.converged and corrected.converged
    bottom = torch.tensor([0.0, 0.0, -(LENGTH + WEIGHT / STIFFNESS)], dtype=DT)
    for solution in (plain, corrected):
        assert torch.allclose(solution.parameters, bottom, atol=1e-6)
    assert corrected.energy == pytest.approx(plain.energy, rel=1e-12)
    assert not any(h.corrected for h in plain.history)
    taken = [h for h in corrected.history if h.corrected]
    assert taken and all(h.step_length == 1.0 for h in taken)  # a corrected step is full
    assert len(corrected.history) <= 12 and len(plain.history) >= 4 * len(corrected.history)
    # the last decrements above the rounding floor fall quadratically (measured 2.5e-2,
    # 3.5e-5, 4.8e-8 J: λ²_{k+1} ≤ 40 (λ²_k)²)
    tail = [h.decrement for h in corrected.history[-4:-1]]
    assert all(tail[k + 1] <= 1e2 * tail[k]**2 for k in (0, 1)), tail


def test_a_full_step_that_passes_is_taken_without_a_correction():
    """The rule around the full step: accepted as it is; a failing one replaced by its
    correction only where that passes the same test; else backtracking along d."""
    asked = []

    def correct(step):
        asked.append(step)
        return step * 0.5

    def energy_at(falls):  # Π along the step: the full step's value given, else a quadratic
        return lambda step, alpha: falls(float(step) * alpha)

    quadratic = energy_at(lambda a: -2 * a + a * a)  # λ² = 2, Π(1) = −1: passes
    assert backtrack(quadratic, 0.0, torch.tensor(1.0), 2.0, armijo=1e-4, halvings=30,
                     longer_steps=0, correct=correct)[:1] == (1.0,)
    assert asked == []
    # Π rises at the full step but falls at the corrected one (½ d): the corrected full step
    stiff = energy_at(lambda a: -2 * a + 3 * a**4)
    alpha, step, corrected = backtrack(stiff, 0.0, torch.tensor(1.0), 2.0, armijo=1e-4,
                                       halvings=30, longer_steps=4, correct=correct)
    assert (alpha, float(step), corrected) == (1.0, 0.5, True)
    # a correction that fails too: backtracking along d, the correction asked once
    asked.clear()
    alpha, step, corrected = backtrack(stiff, 0.0, torch.tensor(1.0), 2.0, armijo=1e-4,
                                       halvings=30, longer_steps=4,
                                       correct=lambda s: asked.append(s) or 5 * s)
    assert (alpha, float(step), corrected, len(asked)) == (0.5, 1.0, False, 1)
    # an infeasible corrected point (Π = inf: `feasible` rejects it, contact) is not taken
    fenced = energy_at(lambda a: math.inf if a == 0.5 else -2 * a + 3 * a**4)
    alpha, step, corrected = backtrack(fenced, 0.0, torch.tensor(1.0), 2.0, armijo=1e-4,
                                       halvings=30, longer_steps=0, correct=correct)
    assert (alpha, corrected) == (0.25, False)
    # an infeasible full step (Π = inf: contact) is not corrected
    asked.clear()
    walled = energy_at(lambda a: math.inf if a > 0.6 else -2 * a + a * a)
    assert backtrack(walled, 0.0, torch.tensor(1.0), 2.0, armijo=1e-4, halvings=30,
                     longer_steps=0, correct=correct)[0] == 0.5
    assert asked == []


def _solve(model, spans, config, levels=1):
    surface, loads = model.surface, model.loads
    field = SplineField(SplineConfig(spans=spans, domain=surface.domain.bounds), dtype=DT)
    return solve_levels(field, model.boundary,
                        lambda f: span_quadrature(surface, f.config, loads, dtype=DT),
                        Objective(ShellEnergyTerm(model.material, loads)), levels=levels,
                        config=config, probes={"free": (1.0, 1.0)},
                        length=math.sqrt(surface.domain.rectangle_area))


def test_the_correction_cuts_the_napkins_newton_iterations_to_the_same_minimum():
    """The README demo's napkin (cotton/polyester, free pin) on 4 × 4 spans from the flat sheet,
    then 8 × 8 from the prolonged solution, to the default tolerance: measured 115 + 59 Newton
    iterations plain, 86 + 26 corrected (28 and 13 steps corrected), Π equal to 1e-12."""
    model = load_scene(ROOT / "scenes" / "napkin.toml").model
    runs = {}
    for correction in (False, True):
        config = NewtonConfig(max_iterations=400, discretisation_fraction=0.0,
                              second_order_correction=correction)
        runs[correction] = [level[0] for level in _solve(model, (4, 4), config, levels=2)]
    for plain, corrected in zip(runs[False], runs[True], strict=True):
        assert plain.converged and corrected.converged
        assert corrected.energy == pytest.approx(plain.energy, rel=1e-7)
        assert corrected.probes["free"][2] == pytest.approx(plain.probes["free"][2], abs=1e-5)
        assert any(h.corrected for h in corrected.history)
    counts = [(len(p.history), len(c.history))
              for p, c in zip(runs[False], runs[True], strict=True)]
    assert sum(c for _, c in counts) < 0.8 * sum(p for p, _ in counts), counts


def test_a_linear_problem_is_unchanged_bit_for_bit():
    """A hinged plate under a small pressure (the linear regime): every full step passes, so
    the correction is never computed and the iterations are the same to the last bit."""
    surface = Plane(bounds=((0.0, 1.0), (0.0, 1.0)))
    boundary = BoundaryConditions(
        [HingedEdge(edge=e) for e in ("xi1_min", "xi1_max", "xi2_min", "xi2_max")],
        domain=surface.domain, surface=surface)
    loads = Loads(pressure=1e-3)
    material = LinearIsotropic.from_young(1e9, 0.3, 0.01, 1.0)
    solutions = []
    for correction in (False, True):
        field = SplineField(SplineConfig(spans=(4, 4), domain=surface.domain.bounds), dtype=DT)
        (solution,), = solve_levels(
            field, boundary, lambda f: span_quadrature(surface, f.config, loads, dtype=DT),
            Objective(ShellEnergyTerm(material, loads)), levels=1,
            config=NewtonConfig(second_order_correction=correction))
        solutions.append(solution)
    plain, corrected = solutions
    assert plain.converged and not any(h.corrected for h in corrected.history)
    assert torch.equal(plain.coefficients, corrected.coefficients)
    assert [h.energy for h in plain.history] == [h.energy for h in corrected.history]


@pytest.mark.parametrize("seed", [0, 1])
def test_the_membrane_residual_is_the_third_order_coefficient_of_the_membrane_energy(seed):
    """For a membrane (bending negligible: h = 1e-6 m) the strain energy along U + tΔ is the
    quartic ½ (s + t AΔ + t² ε₂)ᵀ C (…) in t, whose t³ coefficient is (AΔ)ᵀ C ε₂ = ⟨r, Δ⟩ with
    r = `membrane_second_order_gradient`(U, Δ): checked by the five-point third difference,
    exact on a quartic."""
    surface = Plane(bounds=((0.0, 1.0), (0.0, 1.0)))
    field = SplineField(SplineConfig(spans=(2, 2), domain=surface.domain.bounds), dtype=DT)
    samples = span_quadrature(surface, field.config, Loads(), dtype=DT)
    material = LinearIsotropic.from_young(1e6, 0.3, 1e-6, 1.0)
    generator = torch.Generator().manual_seed(seed)
    u = 0.05 * torch.randn(samples.r_jets.shape, generator=generator, dtype=DT)
    step = 0.05 * torch.randn(samples.r_jets.shape, generator=generator, dtype=DT)
    energy = ShellEnergy(material, Loads())

    def along(t):
        return energy.evaluate(samples, u + t * step, grad=False).internal

    h = 0.5
    third = (along(2 * h) - 2 * along(h) + 2 * along(-h) - along(-2 * h)) / (2 * h**3)
    residual = membrane_second_order_gradient(material, samples, u, step)
    assert float((residual * step).sum()) == pytest.approx(third / 6, rel=1e-6)
    assert float((membrane_second_order_gradient(material, samples, u, 2 * step) * step).sum()
                 ) == pytest.approx(4 * third / 6, rel=1e-6)  # ε₂ is quadratic in Δ
    assert torch.equal(membrane_second_order_gradient(material, samples, u, 0 * step),
                       torch.zeros_like(u))
