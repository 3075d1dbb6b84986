"""The objective of energy terms: the shell term is `ShellEnergy` at the load factor (one
number or one per sample), further terms add to the value, the external work and the
gradient; the end moment's gradient against central differences; the last-layer Newton's
Hessian blocks work on the whole objective."""

from types import SimpleNamespace

import pytest
import torch

from taichi_ndf.geometry import Plane
from taichi_ndf.objective import EndMomentTerm, Objective, ShellEnergyTerm
from taichi_ndf.problem.loads import Loads, PointLoad
from taichi_ndf.problem.sampling import sample_surface
from taichi_ndf.shell.energy import ShellEnergy
from taichi_ndf.shell.hessian import sample_hessians
from taichi_ndf.shell.materials import LinearIsotropic

F64 = torch.float64
STRIP = Plane(bounds=((0.0, 2.0), (0.0, 1.0)))
MATERIAL = LinearIsotropic.from_young(1.2e6, 0.3, 0.01, 0.5)
LOADS = Loads(gravity=(0.0, 0.0, -9.81), pressure=2.0,
              point_loads=(PointLoad((2.0, 0.5), (0.0, 0.0, -0.1)),))


def displacement(n, seed=3):
    return 1e-3 * torch.randn(n, 6, 3, dtype=F64, generator=torch.Generator().manual_seed(seed))


def samples_at(load_factor, n=64):
    return sample_surface(STRIP, n, LOADS.scaled(load_factor),
                          torch.Generator().manual_seed(1), dtype=F64)


def test_shell_term_is_the_shell_energy_at_the_load_factor():
    # The samples carry the unscaled point forces; the term scales them with the loads.
    unscaled = samples_at(1.0)
    u = displacement(len(unscaled))
    objective = Objective(ShellEnergyTerm(MATERIAL, LOADS))
    got = objective.evaluate(unscaled, u, 0.5)
    expected = ShellEnergy(MATERIAL, LOADS.scaled(0.5)).evaluate(samples_at(0.5), u)
    assert got.total == expected.total
    assert torch.equal(got.grad_u_jets, expected.grad_u_jets)
    # One factor per sample: the same.
    factors = torch.full((len(unscaled),), 0.5, dtype=F64)
    per_sample = objective.evaluate(unscaled, u, factors)
    assert per_sample.total == pytest.approx(expected.total, rel=1e-13)


def test_further_terms_add_to_value_external_work_and_gradient():
    samples = samples_at(1.0)
    u = displacement(len(samples))
    moment = EndMomentTerm(0.3, 1.0)
    shell = Objective(ShellEnergyTerm(MATERIAL, LOADS))
    both = shell.with_terms(moment)
    alone = shell.evaluate(samples, u, 0.7)
    together = both.evaluate(samples, u, 0.7)
    work, work_grad = moment.evaluate(samples, u, 0.7)
    assert work != 0.0
    assert together.total == alone.total + work
    assert together.external == alone.external + work
    assert together.internal == alone.internal
    assert torch.equal(together.grad_u_jets, alone.grad_u_jets + work_grad)
    assert both.evaluate(samples, u, 0.7, grad=False).grad_u_jets is None


def test_end_moment_gradient_matches_central_differences():
    samples = samples_at(1.0, n=16)
    u = displacement(len(samples), seed=4)
    u[:, 1, 0] += 1.0  # a tangent near the reference one
    moment = EndMomentTerm(0.3, 1.0)
    _, grad = moment.evaluate(samples, u, 0.8)
    step = 1e-6
    for n, c, k in ((0, 1, 0), (3, 1, 2), (5, 3, 0), (7, 3, 2), (9, 0, 1)):
        up, down = u.clone(), u.clone()
        up[n, c, k] += step
        down[n, c, k] -= step
        fd = (moment.evaluate(samples, up, 0.8, grad=False)[0]
              - moment.evaluate(samples, down, 0.8, grad=False)[0]) / (2 * step)
        assert fd == pytest.approx(float(grad[n, c, k]), rel=1e-6, abs=1e-12)


def test_newton_hessian_blocks_work_on_the_whole_objective():
    samples = samples_at(1.0, n=16)
    u = displacement(len(samples))
    u[:, 1, 0] += 1.0
    moment = EndMomentTerm(0.3, 1.0)
    shell = Objective(ShellEnergyTerm(MATERIAL, LOADS))
    steps = torch.full((6,), 1e-5, dtype=F64)
    both = sample_hessians(shell.with_terms(moment).potential(1.0), samples, u, steps=steps)
    alone = sample_hessians(shell.potential(1.0), samples, u, steps=steps)

    def moment_only(s, jets, grad):
        return SimpleNamespace(grad_u_jets=moment.evaluate(s, jets, 1.0)[1])

    of_moment = sample_hessians(moment_only, samples, u, steps=steps)
    assert of_moment.abs().max() > 0
    # Central differences of the shell's large gradients leave rounding of ~4e-12 of its scale
    # (measured); the moment's blocks are ~1e-6 of it.
    scale = float(both.abs().max())
    torch.testing.assert_close(both - alone, of_moment, rtol=0.0, atol=1e-10 * scale)


def test_objective_hessian_blocks_sum_each_terms_own_blocks_or_their_differences():
    samples = samples_at(1.0, n=16)
    u = displacement(len(samples))
    u[:, 1, 0] += 1.0
    moment = EndMomentTerm(0.3, 1.0)
    steps = torch.full((6,), 1e-5, dtype=F64)

    class Analytic:  # a term with its own blocks: a quadratic ½ k |u|² in the value channel
        def evaluate(self, s, jets_, load_factor, *, grad=True):
            value = 0.5 * 3.0 * float(jets_[:, 0].pow(2).sum())
            g = torch.zeros_like(jets_)
            g[:, 0] = 3.0 * jets_[:, 0]
            return value, g

        def hessian_blocks(self, s, jets_, load_factor, *, steps):
            blocks = jets_.new_zeros(jets_.shape[0], 6, 3, 6, 3)
            blocks[:, 0, :, 0, :] = 3.0 * torch.eye(3, dtype=jets_.dtype)
            return blocks

    objective = Objective(ShellEnergyTerm(MATERIAL, LOADS)).with_terms(moment, Analytic())
    blocks = objective.potential(1.0).hessian_blocks(samples, u, steps=steps)
    by_differences = sample_hessians(objective.potential(1.0), samples, u, steps=steps)
    scale = float(by_differences.abs().max())
    torch.testing.assert_close(blocks, by_differences, rtol=0.0, atol=1e-9 * scale)
