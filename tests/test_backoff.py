"""The learning-rate backoff (`taichi_ndf.backoff`): when Adam's monitored Π climbs an order of
magnitude above anything recorded, the best state comes back and the learning rate halves."""

from __future__ import annotations

import itertools
import json
import math

import pytest
import torch
from test_cli import SMALL_NAPKIN, run_sim, write_scene

from taichi_ndf.backoff import CLIMB_FACTOR, DIVERGED_FACTOR, BestState, climbed, should_back_off
from taichi_ndf.state import State


def test_a_climb_is_an_order_of_magnitude_that_persists_for_two_records():
    best = BestState(iteration=100, load_factor=1.0, energy=-0.4, magnitude=0.5,
                     parameters=torch.zeros(3), optimiser={})
    assert CLIMB_FACTOR == 10
    assert not climbed(-0.1, best)  # noise: 0.3 J above the best
    assert not climbed(best.energy + 4.99, best)
    assert climbed(best.energy + 5.01, best)  # 10 × 0.5 J above the best
    assert climbed(math.nan, best) and climbed(math.inf, best)
    # One order of magnitude at one record is an overshoot that may come back down; at two in
    # a row, or two orders at one, the run backs off.
    assert DIVERGED_FACTOR == 100
    assert not should_back_off(6.0, None, best)
    assert not should_back_off(6.0, -0.3, best)
    assert not should_back_off(-0.3, 6.0, best)
    assert should_back_off(6.0, 7.0, best)
    assert not should_back_off(best.energy + 49.9, None, best)
    assert should_back_off(best.energy + 50.1, None, best)  # 100 × 0.5 J above the best
    assert should_back_off(math.nan, None, best)  # nothing to wait for


def scene(tmp_path, lr, iterations):
    text = SMALL_NAPKIN.format(lr=lr).replace("iterations = 10", f"iterations = {iterations}")
    return write_scene(tmp_path, text)


def test_a_too_long_adam_step_backs_off_and_the_run_ends_lower(tmp_path, caplog):
    # lr 0.1 on the small napkin: Π climbs from ~1e-3 J to ~1e11 J in ten iterations. Without
    # the backoff it ended at +1.5e7 J (f32, 100 iterations); with it, on the cloth's way down.
    path = scene(tmp_path, 0.1, 40)
    assert run_sim(path, "--out", tmp_path / "run") == 0
    result = json.loads((tmp_path / "run" / "result.json").read_text())
    history = result["history"]
    assert result["backoffs"] >= 1
    assert "climbed" in caplog.text and "learning rate halved" in caplog.text
    assert result["energy"] < 0  # the cloth hangs: Π below the flat sheet's
    rates = [h["learning_rate"] for h in history]
    assert rates[-1] < 0.1 * 0.5 ** result["backoffs"] * 1.0001
    # A record that climbed by less than two orders of magnitude is kept once (an overshoot may
    # come back down); at the second in a row the record holds the restored state: never two
    # climbed records in a row.
    climbed_records = [h["energy"] > 1.0 for h in history]
    assert not any(a and b for a, b in itertools.pairwise(climbed_records))


def test_a_short_enough_step_never_backs_off(tmp_path, caplog):
    assert run_sim(scene(tmp_path, 1e-3, 20), "--out", tmp_path / "run") == 0
    result = json.loads((tmp_path / "run" / "result.json").read_text())
    assert result["backoffs"] == 0 and "climbed" not in caplog.text


def test_a_resumed_run_backs_off_as_the_uninterrupted_one(tmp_path, monkeypatch):
    path = scene(tmp_path, 0.1, 30)
    assert run_sim(path, "--out", tmp_path / "whole") == 0
    whole = json.loads((tmp_path / "whole" / "result.json").read_text())
    assert whole["backoffs"] >= 2

    save = State.save

    def save_then_crash(self, path, extra=None):
        save(self, path, extra)
        if self.iteration == 10:
            raise KeyboardInterrupt

    monkeypatch.setattr(State, "save", save_then_crash)
    assert run_sim(path, "--out", tmp_path / "cut") == 130
    monkeypatch.undo()
    assert run_sim(path, "--out", tmp_path / "cut", "--resume") == 0
    resumed = json.loads((tmp_path / "cut" / "result.json").read_text())
    assert resumed["backoffs"] == whole["backoffs"]
    assert resumed["energy"] == pytest.approx(whole["energy"], rel=1e-9)
    assert ([h["learning_rate"] for h in resumed["history"]]
            == [h["learning_rate"] for h in whole["history"]])
