"""A projected-Newton run checkpointed inside a grid level (`State.inside`: the level's
finished load steps, the coarser level's solutions, Newton's iterate) and resumed there gives
the uninterrupted run's result bit for bit: stopped by a callback raising after Newton
iteration j, every k iterations and on Ctrl-C; a run with obstacles too, stopped inside its
first and its second contact round (`State.inside.contact`: check points, κ, the round), and
it refuses a checkpoint without contact in one line."""

from __future__ import annotations

import dataclasses
import json

import pytest
import torch

from taichi_ndf.cli import sim
from taichi_ndf.field import SplineField
from taichi_ndf.minimise.callbacks import CheckpointWriter
from taichi_ndf.minimise.checkpoint import CheckpointError
from taichi_ndf.minimise.state import InsideLevel, State
from taichi_ndf.scene.reader import load_scene
from taichi_ndf.solve.spline_solver import solve_spline
from tests.test_spline_scene import RUNTIME, write

THREE = '[field]\ntype = "spline"\nspans = [4, 2]\nlevels = 3'


class Stop(Exception):
    pass


class StopAfter:
    """Raises after Newton iteration `j` (counted over the run) has been kept."""

    def __init__(self, j: int):
        self.j = j

    def on_iteration(self, run, record) -> None:
        if run.state.iteration == self.j:
            raise Stop


def stopped_after(scene, solver, j: int, path) -> State:
    """Run until Newton iteration `j` is kept with a checkpoint written at every iteration,
    stop there, and return the state read back from the checkpoint at `path`."""
    with pytest.raises(Stop):
        solve_spline(scene.model, scene.field, solver,
                     callbacks=[CheckpointWriter(path), StopAfter(j)])
    state = State.newton(None)
    state.restore(path)
    return state


@pytest.fixture(scope="module")
def strip(tmp_path_factory):
    """The clamped strip under gravity on 3 levels × 2 load steps, solved once whole."""
    scene = load_scene(write(tmp_path_factory.mktemp("strip"), field=THREE))
    solver = dataclasses.replace(scene.solver, checkpoint_every=1)
    whole = solve_spline(scene.model, scene.field, solver)
    return scene, solver, whole


def _inside(run, fraction):
    """The first Newton iteration j ≥ fraction × all after which its load step went on."""
    h = run.history
    return next(j for j in range(max(1, int(fraction * len(h))), len(h))
                if h[j - 1].step_length > 0 and (h[j].level, h[j].load_factor) ==
                (h[j - 1].level, h[j - 1].load_factor))


@pytest.mark.parametrize("fraction", [0.2, 0.55, 0.9])
def test_resume_inside_a_level_is_bit_identical(strip, tmp_path, fraction):
    scene, solver, whole = strip
    j = _inside(whole, fraction)
    state = stopped_after(scene, solver, j, tmp_path / "c.pt")
    assert state.inside is not None and state.iteration == j
    assert state.inside.level == whole.history[j].level and state.inside.iterate is not None
    resumed = solve_spline(scene.model, scene.field, solver, state=state)
    assert resumed.energy == whole.energy
    assert len(resumed.history) == len(whole.history)
    assert [h.energy for h in resumed.history] == [h.energy for h in whole.history]
    assert [h.step_length for h in resumed.history] == [h.step_length for h in whole.history]
    assert torch.equal(resumed.field.coefficients, whole.field.coefficients)
    assert [(lv.energy, lv.iterations, lv.probes) for lv in resumed.levels] == [
        (lv.energy, lv.iterations, lv.probes) for lv in whole.levels]
    assert resumed.load_steps == whole.load_steps


def test_ctrl_c_inside_a_level_saves_the_iterate_and_resume_gives_the_same_run(tmp_path,
                                                                               monkeypatch):
    scene = write(tmp_path, field=THREE)
    whole = tmp_path / "whole"
    assert sim.main([str(scene), "--out", str(whole), *RUNTIME]) == 0
    expected = json.loads((whole / "result.json").read_text())
    j = len(expected["history"]) // 2  # inside a level, between load steps' ends
    level = expected["history"][j - 1]["level"]

    def interrupt(self, run, record):  # Ctrl-C after iteration j: the writer never saved
        if run.state.iteration == j:
            raise KeyboardInterrupt
    monkeypatch.setattr(CheckpointWriter, "on_iteration", interrupt)
    cut = tmp_path / "cut"
    assert sim.main([str(scene), "--out", str(cut), *RUNTIME]) == 130
    monkeypatch.undo()
    state = State.newton(None)
    state.restore(tmp_path / "cut.incomplete" / "checkpoint.pt")
    assert state.inside.level == level and state.inside.iterate is not None
    assert state.iteration == j and len(state.levels) == level

    assert sim.main([str(scene), "--out", str(cut), "--resume", *RUNTIME]) == 0
    resumed = json.loads((cut / "result.json").read_text())
    assert resumed["energy"] == expected["energy"]
    assert resumed["iterations"] == expected["iterations"]
    assert resumed["probes"] == expected["probes"]
    untimed = [{k: v for k, v in h.items() if not k.startswith("time_")}
               for h in expected["history"]]
    assert [{k: v for k, v in h.items() if not k.startswith("time_")}
            for h in resumed["history"]] == untimed
    assert (cut / "mesh.obj").read_bytes() == (whole / "mesh.obj").read_bytes()


def test_a_resume_with_other_load_steps_is_refused_in_one_line(strip, tmp_path):
    scene, solver, whole = strip
    state = stopped_after(scene, solver, _inside(whole, 0.6), tmp_path / "c.pt")
    other = dataclasses.replace(solver, load_steps=(0.4, 1.0))
    with pytest.raises(CheckpointError, match=r"^the checkpoint was written inside grid level "
                       r"1 of a run with other load steps than \[0.4, 1.0\]; resume it"):
        solve_spline(scene.model, scene.field, other, state=state)


def test_a_checkpoint_without_contact_is_refused_by_a_run_with_obstacles_in_one_line():
    scene = load_scene("scenes/tablecloth_box.toml", field="spline")
    assert scene.model.contact is not None
    state = State.newton(SplineField(scene.field.config))
    state.inside = InsideLevel(level=0, first_step=0, done=[], coarser=None, records=0)
    with pytest.raises(CheckpointError, match="^the checkpoint was written inside grid level 0"
                       r" of a run without obstacles; resume it with its own scene"):
        solve_spline(scene.model, scene.field, scene.solver, state=state)

TABLE = """
name = "tiny_table"
[geometry]
type = "plane"
bounds = [[-0.2, 0.2], [-0.15, 0.15]]
origin = [0.0, 0.0, 0.003]
[material]
preset = "polyester"
[loads]
gravity = [0.0, 0.0, -9.81]
[[boundary.constraint]]
type = "pinned_point"
xi = [0.0, 0.0]
components = "xy"
[[boundary.constraint]]
type = "interior_line"
start = [-0.2, 0.0]
end = [0.2, 0.0]
extend = true
hinged = true
components = "y"
[[obstacles]]
type = "box"
name = "table"
centre = [0.0, 0.0, -0.05]
half_extents = [0.15, 0.1, 0.05]
rounding = 0.02
friction = 0.3
[contact]
check_resolution = 24
[field]
type = "spline"
spans = [4, 4]
levels = 2
[training]
load_steps = [0.5, 1.0]
"""


class Rounds:
    """After each kept Newton iterate: (iteration, load factor, the contact round's index)."""

    def __init__(self):
        self.kept = []

    def on_iteration(self, run, record) -> None:
        within = run.contact.to_dict()["round"]
        self.kept.append((run.state.iteration, run.state.history[-1].load_factor,
                          None if within is None else within["index"]))


@pytest.fixture(scope="module")
def table(tmp_path_factory):
    """A tiny tablecloth_box: a cloth with friction on a rounded box, 2 levels × 2 load
    steps, solved once whole (its kept iterates' rounds recorded)."""
    path = tmp_path_factory.mktemp("table") / "table.toml"
    path.write_text(TABLE)
    scene = load_scene(path)
    solver = dataclasses.replace(scene.solver, checkpoint_every=1)
    rounds = Rounds()
    whole = solve_spline(scene.model, scene.field, solver, callbacks=[rounds])
    return scene, solver, whole, rounds.kept


@pytest.mark.parametrize("round_index", [0, 1])
def test_a_contact_run_resumed_inside_a_round_is_bit_identical(table, tmp_path, round_index):
    scene, solver, whole, kept = table
    # an iterate in the middle of the run's iterates inside such a round
    candidates = [j for j, _, r in kept if r == round_index]
    assert candidates, f"no kept iterate inside round {round_index}: {kept}"
    j = candidates[len(candidates) // 2]
    state = stopped_after(scene, solver, j, tmp_path / "c.pt")
    assert state.iteration == j and state.inside.iterate is not None
    assert state.inside.contact["round"]["index"] == round_index
    resumed = solve_spline(scene.model, scene.field, solver, state=state)
    assert resumed.energy == whole.energy
    assert [h.energy for h in resumed.history] == [h.energy for h in whole.history]
    assert [h.step_length for h in resumed.history] == [h.step_length for h in whole.history]
    assert resumed.contact.rounds == whole.contact.rounds
    assert torch.equal(resumed.contact.points.active, whole.contact.points.active)
    assert resumed.contact.points.term.stiffness == whole.contact.points.term.stiffness
    assert torch.equal(resumed.field.coefficients, whole.field.coefficients)
    assert [(lv.energy, lv.iterations, lv.probes) for lv in resumed.levels] == [
        (lv.energy, lv.iterations, lv.probes) for lv in whole.levels]
