"""Adam, L-BFGS and Newton (sparse, and dense over a SIREN's output layer) behind one
interface (`minimise.minimisers.Minimiser`): the same result as the direct calls, the same
hooks, and a SIREN load step as its list of phases."""

from __future__ import annotations

import torch
from test_one_newton import LOAD_FACTOR, _strip
from test_spline_scene import write

from taichi_ndf.discretise import of_scene
from taichi_ndf.minimise.continuation import Step
from taichi_ndf.minimise.linearisation import SplineLinearisation
from taichi_ndf.minimise.minimisers import Hooks, NewtonMinimiser, Phase, run_phases
from taichi_ndf.minimise.newton import minimise
from taichi_ndf.scene.reader import load_scene
from taichi_ndf.solve.solver import Solver


def test_newton_behind_the_interface_is_the_direct_call_with_the_same_hooks():
    assembly, potential, length = _strip()
    linear = SplineLinearisation(assembly, length=length)
    start = torch.zeros(assembly.n_coefficients, 3, dtype=torch.float64)
    direct = minimise(linear, potential, start, load_factor=LOAD_FACTOR)
    records, iterates, stages = [], [], []
    phase = Phase(NewtonMinimiser(load_factor=LOAD_FACTOR), lambda: (linear, potential),
                  lambda: start, Hooks(on_iteration=records.append,
                                       on_iterate=iterates.append),
                  stage=("Newton", 100), after=lambda result: stages.append(result.steps))
    (result,) = run_phases([phase])
    assert torch.equal(result.parameters, direct.parameters)
    assert result.energy == direct.energy and result.energy_before == direct.energy_before
    assert result.converged and result.steps == direct.steps == stages[0]
    assert [r.energy for r in records] == [h.energy for h in direct.history]
    assert len(iterates) == direct.steps  # after each step it went on from


def _small_siren(tmp_path, training: str) -> Solver:
    """The clamped strip under gravity (tests/test_spline_scene.py) on a width-8 SIREN."""
    scene = load_scene(write(tmp_path, field="[field]\nwidth = 8\nhidden_layers = 2",
                             training="[training]\niterations = 4\nsamples = 64\n"
                             "monitor_every = 2\nmonitor_samples = 64\nnewton_samples = 64\n"
                             + training))
    d = of_scene(scene)
    d.start(scene.solver, seed=0)
    return d.solver


def test_a_siren_load_step_is_its_list_of_phases_and_each_runs(tmp_path):
    solver = _small_siren(tmp_path, "newton_iterations = 2\nnewton_every = 2\n"
                          "lbfgs_iterations = 2")
    step = Step(0, 0, 1.0)
    names = [type(p.minimiser).__name__ for p in solver.phases(step)]
    assert names == ["OutputLayerNewton", "AdamMinimiser", "OutputLayerNewton",
                     "LBFGSMinimiser"]
    assert [type(p.minimiser).__name__ for p in solver.phases(step, done_in_step=3)][0] == \
        "AdamMinimiser"  # a resumed step does not start with Newton again
    polished = []

    class Seen:
        def on_polish(self, run, before, after):
            polished.append((before, after))
    result = solver.run(callbacks=[Seen()])
    assert result.iterations == 4 and result.newton_steps > 0
    assert len(polished) == 1 and polished[0][1] <= polished[0][0]
    plain = _small_siren(tmp_path, "")
    assert [type(p.minimiser).__name__ for p in plain.phases(step)] == ["AdamMinimiser"]
