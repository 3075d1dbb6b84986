"""The divergence guard on a Newton grid level's closing Π (issue 26): the Π a load step ends
with is evaluated after its last recorded Newton iteration, so `on_record` never sees it. A NaN
there must stop `ndf-sim` with exit code 2 and the guard's one line, before that level is
checkpointed (it used to be kept as "Π = nan" and a later write failed on JSON's NaN)."""

from __future__ import annotations

import dataclasses

from taichi_ndf.minimise import minimisers
from taichi_ndf.minimise.state import State
from tests.test_behaviour_both_paths import SCENES, run


def test_a_nan_closing_a_level_stops_the_run_before_its_checkpoint(tmp_path, monkeypatch,
                                                                   capsys):
    scene = tmp_path / "spline.toml"
    scene.write_text(SCENES["spline"])  # 3 grid levels x load steps [0.5, 1.0]
    minimise, save, calls, saved = minimisers.minimise, State.save, [], []

    def nan_closing_level_0(*args, **kwargs):  # level 0's last load step ends at Π NaN
        solution = minimise(*args, **kwargs)
        calls.append(solution.energy)
        return dataclasses.replace(solution, energy=float("nan")) if len(calls) == 2 \
            else solution

    def save_counted(self, path, extra=None):
        saved.append(list(self.levels))
        save(self, path, extra)

    monkeypatch.setattr(minimisers, "minimise", nan_closing_level_0)
    monkeypatch.setattr(State, "save", save_counted)
    cut = tmp_path / "cut"
    capsys.readouterr()
    assert run(scene, cut) == 2
    monkeypatch.undo()
    err = capsys.readouterr().err.strip().splitlines()
    assert len(calls) == 2  # stopped at the end of level 0, not after more load steps
    assert len(err) == 1 and "projected Newton diverged at iteration" in err[0], err
    assert "Π = nan" in err[0]
    assert all(not levels for levels in saved)  # level 0 (Π NaN) was never checkpointed
    assert not cut.exists() and not (tmp_path / "cut.incomplete" / "result.json").exists()
