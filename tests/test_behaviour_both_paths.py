"""Issue 26's "resume exact, Ctrl-C and divergence handling on both paths", through `ndf-sim`
(in-process) with the same assertions for a SIREN + Adam and a spline + Newton run:

- a real SIGINT (sent by another thread, so it lands wherever the solve is, not in a chosen
  callback) leaves exit code 130 and a checkpoint in DIR.incomplete, and `--resume` ends
  where the uninterrupted run did, bit for bit (Π, iterations, history, probes, mesh.obj);
- a Π that turns NaN after the first checkpoint (the SIREN's next Adam iterations, the spline's
  next grid level) stops the run with exit code 2 and one line naming the divergence and the
  checkpoint, and that checkpoint (the last good state) resumes to the uninterrupted run's
  result bit for bit.
"""

from __future__ import annotations

import json
import os
import signal
import threading

import pytest

from taichi_ndf.cli import sim
from taichi_ndf.minimise.state import State
from taichi_ndf.objective import Objective
from tests.test_cli import SMALL_NAPKIN
from tests.test_spline_scene import STRIP

RUNTIME = ["--precision", "f64"]

SCENES = {
    # 40 Adam iterations, a checkpoint every 5
    "siren": SMALL_NAPKIN.format(lr=1e-3).replace("iterations = 10", "iterations = 40"),
    # 3 grid levels x 2 load steps, a checkpoint after each level (and on Ctrl-C inside one)
    "spline": STRIP.format(field='[field]\ntype = "spline"\nspans = [4, 2]\nlevels = 3',
                           training="[training]\nload_steps = [0.5, 1.0]"),
}
TIMING = ("wall_time", "seconds", "time_")


def untimed(value):
    """result.json without its timings (keys wall_time, seconds, time_*)."""
    if isinstance(value, dict):
        return {k: untimed(v) for k, v in value.items() if not k.startswith(TIMING)}
    if isinstance(value, list):
        return [untimed(v) for v in value]
    return value


def run(scene, out, *args) -> int:
    return sim.main([str(scene), "--out", str(out), *args, *RUNTIME])


@pytest.fixture(params=list(SCENES))
def whole(request, tmp_path):
    """The scene of one path and its uninterrupted run's result.json."""
    scene = tmp_path / f"{request.param}.toml"
    scene.write_text(SCENES[request.param])
    assert run(scene, tmp_path / "whole") == 0
    return request.param, scene, json.loads((tmp_path / "whole" / "result.json").read_text())


def assert_same_run(tmp_path, out, expected):
    resumed = json.loads((out / "result.json").read_text())
    assert resumed["energy"] == expected["energy"]
    assert resumed["iterations"] == expected["iterations"]
    assert resumed["probes"] == expected["probes"]
    assert [h["energy"] for h in resumed["history"]] == [h["energy"] for h in expected["history"]]
    assert untimed(resumed["history"]) == untimed(expected["history"])
    assert (out / "mesh.obj").read_bytes() == (tmp_path / "whole" / "mesh.obj").read_bytes()


def test_a_sigint_leaves_a_checkpoint_and_resume_is_bit_for_bit(whole, tmp_path, monkeypatch,
                                                               capsys):
    field, scene, expected = whole
    save, sent = State.save, []

    def save_then_signal(self, path, extra=None):  # SIGINT from another thread after the
        save(self, path, extra)                    # first checkpoint: it lands mid-solve
        if not sent:
            sent.append(self.iteration)
            threading.Timer(0.0, os.kill, (os.getpid(), signal.SIGINT)).start()

    monkeypatch.setattr(State, "save", save_then_signal)
    cut = tmp_path / "cut"
    assert run(scene, cut) == 130
    monkeypatch.undo()
    staged = tmp_path / "cut.incomplete"
    assert "interrupted; the last checkpoint is in" in capsys.readouterr().err
    assert not cut.exists() and (staged / "checkpoint.pt").is_file()
    state = State.newton(None) if field == "spline" else None
    if state is not None:
        state.restore(staged / "checkpoint.pt")
        assert state.iteration >= sent[0]  # saved no earlier than the first checkpoint
    assert run(scene, cut, "--resume") == 0
    assert_same_run(tmp_path, cut, expected)


def test_divergence_stops_in_one_line_and_its_checkpoint_resumes_bit_for_bit(
        whole, tmp_path, monkeypatch, capsys):
    field, scene, expected = whole
    evaluate, save, poisoned = Objective.evaluate, State.save, []

    def nan_once_saved(self, *args, **kwargs):  # Π NaN at every point after the first
        result = evaluate(self, *args, **kwargs)  # checkpoint: the SIREN's next Adam
        if poisoned:                              # iterations, the spline's next grid level
            result.total = float("nan")
        return result

    def save_then_poison(self, path, extra=None):
        save(self, path, extra)
        poisoned.append(self.iteration)

    monkeypatch.setattr(Objective, "evaluate", nan_once_saved)
    monkeypatch.setattr(State, "save", save_then_poison)
    cut = tmp_path / "cut"
    capsys.readouterr()
    assert run(scene, cut) == 2
    monkeypatch.undo()
    err = capsys.readouterr().err.strip().splitlines()
    staged = tmp_path / "cut.incomplete"
    what = "projected Newton" if field == "spline" else "training"
    assert len(err) == 1 and f"{what} diverged at iteration" in err[0]
    assert f"(checkpoint {staged / 'checkpoint.pt'})" in err[0]
    assert len(poisoned) == 1  # the guard stopped the run before any other checkpoint
    assert not (staged / "result.json").exists() and not cut.exists()
    assert run(scene, cut, "--resume") == 0
    assert_same_run(tmp_path, cut, expected)
