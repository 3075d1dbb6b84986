"""Newton's endgame on a soft mode (`newton._shifted_step`): where two points' curvatures
nearly cancel along a mode, the per-block projection drops the negative one, the projected K
overstates that mode's curvature by orders of magnitude and projected Newton creeps (full or
lengthened steps, a decrement far below the floor, Π falling for hundreds of iterations:
sleeve_twist_path's frame t = 0.565, benchmarks/RESULTS.md "Gallery 5"). Once the decrement
is below the floor, Newton takes the exact K, shifted just enough to be definite, and
converges."""

from dataclasses import dataclass

import pytest
import torch

from taichi_ndf.minimise.linearisation import DenseLinearisation
from taichi_ndf.minimise.newton import NewtonConfig, minimise

DT = torch.float64
STIFF, PULL = 1.0, 1.0  # point 0: ½ STIFF v² − PULL v along v = x − y (|Π| about ½ J)
SOFT, QUARTIC, LOAD = 1.0 + 1e-6, 1.0, 1e-5  # point 1 along w = x + y: −½ SOFT w² + ¼ w⁴ − LOAD w
SPRING = 1.0  # point 2 along w: ½ SPRING w² (with point 1: −½ 1e-6 w², a soft mode)


@dataclass
class _Energy:
    total: float
    grad_u_jets: torch.Tensor


class _Potential:
    """Per-point energies of the value channel's first component v (N = 3 points), and a
    stiff ½ v² on the other two components (else K would be singular there)."""

    def _parts(self, u):
        v = u[:, 0, 0]
        energy = torch.stack((0.5 * STIFF * v[0] ** 2 - PULL * v[0],
                              -0.5 * SOFT * v[1] ** 2 + 0.25 * QUARTIC * v[1] ** 4 - LOAD * v[1],
                              0.5 * SPRING * v[2] ** 2))
        first = torch.stack((STIFF * v[0] - PULL, -SOFT * v[1] + QUARTIC * v[1] ** 3 - LOAD,
                             SPRING * v[2]))
        second = torch.stack((torch.full_like(v[0], STIFF), -SOFT + 3 * QUARTIC * v[1] ** 2,
                              torch.full_like(v[2], SPRING)))
        return energy, first, second

    def __call__(self, samples, u, grad):
        energy, first, _ = self._parts(u)
        gradient = torch.zeros_like(u)
        gradient[:, 0, 0] = first
        gradient[:, 0, 1:] = u[:, 0, 1:]
        return _Energy(float(energy.sum() + 0.5 * (u[:, 0, 1:] ** 2).sum()), gradient)

    def hessian_blocks(self, samples, u, steps):
        _, _, second = self._parts(u)
        blocks = u.new_zeros(len(u), 6, 3, 6, 3)
        blocks[:, 0, 0, 0, 0] = second
        blocks[:, 0, 1, 0, 1] = blocks[:, 0, 2, 0, 2] = 1.0
        return blocks


def _problem():
    """Parameters (x, y) per component; point 0 sees x − y, points 1 and 2 see x + y."""
    jacobian = torch.zeros(3, 3, 6, 2, dtype=DT)
    jacobian[:, 0, 0] = torch.tensor([1.0, -1.0], dtype=DT)
    jacobian[:, 1, 0] = jacobian[:, 2, 0] = torch.tensor([1.0, 1.0], dtype=DT)
    linearisation = DenseLinearisation(list(range(3)), torch.zeros(3, 6, 3, dtype=DT), jacobian)
    start = torch.zeros(3, 2, dtype=DT)
    start[0] = torch.tensor([0.5, -0.5], dtype=DT)  # v = x − y = 1 at its minimum, w = 0
    return linearisation, _Potential(), start


def _minimum():
    """Π at the minimum: v = PULL / STIFF; w the root of (SPRING − SOFT) w + w³ = LOAD."""
    w = torch.tensor(0.02, dtype=DT)
    for _ in range(50):
        w = w - ((SPRING - SOFT) * w + QUARTIC * w ** 3 - LOAD) / (
            SPRING - SOFT + 3 * QUARTIC * w ** 2)
    return float(-0.5 * PULL ** 2 / STIFF + 0.5 * (SPRING - SOFT) * w ** 2
                 + 0.25 * QUARTIC * w ** 4 - LOAD * w), float(w)


def test_newton_converges_along_a_soft_mode_that_the_projection_stiffens():
    linearisation, potential, start = _problem()
    config = NewtonConfig(max_iterations=60)
    solution = minimise(linearisation, potential, start, config, report=False)
    energy, w = _minimum()
    history = solution.history
    # the start: a decrement below the floor, the projected K's (exact K indefinite there)
    assert history[0].projected_blocks > 0
    assert 0.5 * history[0].decrement <= config.floor_tolerance * abs(history[0].energy)
    assert energy < history[0].energy - 1e-7  # ... yet Π is 1.6e-7 J above its minimum
    # the next iteration: the exact K shifted (its damping recorded), none projected
    assert history[1].projected_blocks == 0 and history[1].damping > 0
    assert solution.converged and len(history) < 30
    assert solution.energy == pytest.approx(energy, rel=1e-12)
    # w to what Π's tolerance resolves on this flat valley (½ κ δw² ≤ 1e-12 |Π|: δw/w ≤ 1e-3)
    assert float(solution.parameters[0].sum()) == pytest.approx(w, rel=1e-3)


def test_without_the_endgame_projected_newton_creeps():
    """The same problem with the exact K never tried (as before the endgame: exact K failed,
    projected K every iteration) creeps: 60 iterations, not converged, Π still far above."""
    linearisation, potential, start = _problem()
    solve = linearisation.solve

    def never_definite(matrix, gradient, damping, *, require_definite=False):
        return None if require_definite else solve(matrix, gradient, damping)

    linearisation.solve = never_definite
    solution = minimise(linearisation, potential, start, NewtonConfig(max_iterations=60),
                        report=False)
    energy, _ = _minimum()
    assert not solution.converged and len(solution.history) == 60
    assert all(h.step_length >= 1 for h in solution.history)  # never shortened: no floor stop
    assert solution.energy - energy > 1e-9
