"""The Newton path runs the same callbacks as the Adam path (`taichi_ndf.minimise.callbacks`): the
divergence guard, the checkpoint writer (one `State` format with a method tag), Ctrl-C with a
resumable checkpoint, exact resume."""

from __future__ import annotations

import json

import pytest
import torch

from taichi_ndf.cli import sim
from taichi_ndf.minimise.callbacks import CheckpointWriter, DivergenceError, DivergenceGuard
from taichi_ndf.minimise.checkpoint import CheckpointError, load_checkpoint
from taichi_ndf.minimise.state import State
from taichi_ndf.objective import Objective
from taichi_ndf.scene.reader import load_scene
from taichi_ndf.solve.spline_solver import solve_spline
from tests.test_spline_scene import RUNTIME, write

THREE = '[field]\ntype = "spline"\nspans = [4, 2]\nlevels = 3'


def test_the_guard_stops_projected_newton_at_a_non_finite_energy(tmp_path, monkeypatch):
    scene = load_scene(write(tmp_path, field=THREE))
    real = Objective.potential
    calls = {"n": 0}

    def poisoned(self, load_factor):  # Π turns NaN from the 4th potential on
        potential = real(self, load_factor)

        def evaluate(samples, u_jets, grad):
            result = potential(samples, u_jets, grad)
            calls["n"] += 1
            if calls["n"] > 3:
                result.total = float("nan")
            return result
        return evaluate

    monkeypatch.setattr(Objective, "potential", poisoned)
    seen = []

    class Count:
        def on_record(self, run, energy, grad_norm, load_factor):
            seen.append(energy)

    with pytest.raises(DivergenceError, match="projected Newton diverged at iteration"):
        solve_spline(scene.model, scene.field, scene.solver, callbacks=[Count(),
                                                                        DivergenceGuard()])
    assert seen and all(e == e for e in seen[:-1]) and seen[-1] != seen[-1]  # the NaN last


def test_ctrl_c_leaves_a_level_checkpoint_and_resume_is_exact(tmp_path, monkeypatch):
    scene = write(tmp_path, field=THREE)
    whole = tmp_path / "whole"
    assert sim.main([str(scene), "--out", str(whole), *RUNTIME]) == 0
    expected = json.loads((whole / "result.json").read_text())

    saved = CheckpointWriter.on_level

    def interrupt(self, run):  # Ctrl-C once level 1 is saved
        saved(self, run)
        if len(run.levels) == 2:
            raise KeyboardInterrupt
    monkeypatch.setattr(CheckpointWriter, "on_level", interrupt)
    cut = tmp_path / "cut"
    assert sim.main([str(scene), "--out", str(cut), *RUNTIME]) == 130
    monkeypatch.undo()
    staged = tmp_path / "cut.incomplete"
    stored = load_checkpoint(staged / "checkpoint.pt")
    assert stored.extra["method"] == "newton" and len(stored.extra["levels"]) == 2
    assert stored.field.config.spans == (8, 4)

    assert sim.main([str(scene), "--out", str(cut), "--resume", *RUNTIME]) == 0
    resumed = json.loads((cut / "result.json").read_text())
    # the level-end checkpoint points at level 2, which is refined from level 1's solution:
    # the same finest solution, bit for bit
    assert resumed["energy"] == expected["energy"]
    assert resumed["probes"] == expected["probes"]
    assert [lv["energy"] for lv in resumed["levels"]] == [
        lv["energy"] for lv in expected["levels"]]
    assert [{**lv, "seconds": 0} for lv in resumed["levels"][:1]] == [
        {**lv, "seconds": 0} for lv in expected["levels"][:1]]


def test_one_checkpoint_format_refuses_the_other_method(tmp_path):
    scene = load_scene(write(tmp_path))
    state = State.newton(None)
    run = solve_spline(scene.model, scene.field, scene.solver, state=state,
                       callbacks=[CheckpointWriter(tmp_path / "c.pt")])
    assert run.state is state and len(state.levels) == 2
    restored = State.newton(None)
    restored.restore(tmp_path / "c.pt")
    assert restored.iteration == len(run.history) and restored.levels == state.levels
    assert torch.equal(restored.field.coefficients, run.field.coefficients)
    adam = State(field=run.field, method="adam")
    with pytest.raises(CheckpointError, match='method = "newton" run'):
        adam.restore(tmp_path / "c.pt")
