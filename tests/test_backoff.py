"""The learning-rate backoff (`taichi_ndf.minimise.backoff`): when Adam's monitored Π climbs an
order of magnitude above anything recorded, the best state comes back and the learning rate
halves."""

from __future__ import annotations

import json
import math

import pytest
from test_cli import SMALL_NAPKIN, interrupt_after_saving, run_sim, write_scene

from taichi_ndf.minimise.backoff import CLIMB_FACTOR, climbed


def test_a_climb_is_an_order_of_magnitude_above_anything_recorded():
    recorded = [0.5, -0.2, -0.4]
    best = -0.4
    assert CLIMB_FACTOR == 10
    assert not climbed(-0.1, best, recorded)  # noise: 0.3 J above the best
    assert not climbed(best + 4.99, best, recorded)
    assert climbed(best + 5.01, best, recorded)  # 10 × 0.5 J above the best
    assert climbed(math.nan, best, recorded) and climbed(math.inf, best, recorded)


def scene(tmp_path, lr, iterations):
    text = SMALL_NAPKIN.format(lr=lr).replace("iterations = 10", f"iterations = {iterations}")
    return write_scene(tmp_path, text)


def test_a_too_long_adam_step_backs_off_and_the_run_ends_lower(tmp_path, caplog):
    # lr 0.1 on the small napkin: Π climbs from ~1e-3 J to ~1e10 J in five iterations. Without
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
    # Every record holds the state kept (a restored one after a backoff): none has climbed.
    assert max(h["energy"] for h in history) < 1.0


def test_a_short_enough_step_never_backs_off(tmp_path, caplog):
    assert run_sim(scene(tmp_path, 1e-3, 20), "--out", tmp_path / "run") == 0
    result = json.loads((tmp_path / "run" / "result.json").read_text())
    assert result["backoffs"] == 0 and "climbed" not in caplog.text


def test_a_resumed_run_backs_off_as_the_uninterrupted_one(tmp_path, monkeypatch):
    path = scene(tmp_path, 0.1, 30)
    assert run_sim(path, "--out", tmp_path / "whole") == 0
    whole = json.loads((tmp_path / "whole" / "result.json").read_text())
    assert whole["backoffs"] >= 2

    interrupt_after_saving(monkeypatch, 10)
    assert run_sim(path, "--out", tmp_path / "cut") == 130
    monkeypatch.undo()
    assert run_sim(path, "--out", tmp_path / "cut", "--resume") == 0
    resumed = json.loads((tmp_path / "cut" / "result.json").read_text())
    assert resumed["backoffs"] == whole["backoffs"]
    assert resumed["energy"] == pytest.approx(whole["energy"], rel=1e-9)
    assert ([h["learning_rate"] for h in resumed["history"]]
            == [h["learning_rate"] for h in whole["history"]])
