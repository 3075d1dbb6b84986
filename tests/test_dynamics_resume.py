"""Resuming a dynamic run mid-trajectory (`solve.dynamics_trajectory` checkpoints, `ndf-sim
--resume`): the final state equals the uninterrupted run's bit for bit."""

from __future__ import annotations

import json

import pytest
import torch

from taichi_ndf.app import dynamics as app_dynamics
from taichi_ndf.cli import sim
from taichi_ndf.problem.dynamics import AdaptiveStep, DynamicsConfig
from taichi_ndf.solve.dynamics import TimeStepper
from taichi_ndf.solve.dynamics_trajectory import read_checkpoint, write_checkpoint
from tests.test_dynamics_scene import RUNTIME, SCENE
from tests.test_dynamics_scene import parse as parse_document


def strip():
    import tomllib

    return parse_document(tomllib.loads(SCENE))


@pytest.mark.parametrize("integrator, adaptive", [("implicit_euler", None),
                                                 ("newmark", None),
                                                 ("implicit_euler", AdaptiveStep(0.02, 6, 1))])
def test_a_resumed_run_ends_in_the_same_state_bit_for_bit(tmp_path, integrator, adaptive):
    s = strip()
    config = DynamicsConfig(dt=0.005, duration=0.03, frame_rate=100, integrator=integrator,
                            mass_damping=0.5, adaptive=adaptive)
    whole = TimeStepper(s.model, s.field, config).run()
    saved = []
    first = TimeStepper(s.model, s.field, config)

    def keep(checkpoint):
        if checkpoint.step == 2:
            write_checkpoint(tmp_path / "c.pt", checkpoint, {"note": "step 2"})
            saved.append(checkpoint.step)
            raise KeyboardInterrupt  # the run stops here

    with pytest.raises(KeyboardInterrupt):
        first.run(on_checkpoint=keep)
    assert saved == [2]
    checkpoint, extra = read_checkpoint(tmp_path / "c.pt", config)
    assert extra == {"note": "step 2"} and checkpoint.state.time == pytest.approx(0.01)
    resumed = TimeStepper(s.model, s.field, config).run(resume=checkpoint)
    assert torch.equal(resumed.field.coefficients, whole.field.coefficients)
    assert resumed.times == whole.times
    assert [r.total for r in resumed.records] == [r.total for r in whole.records]
    assert resumed.probes == whole.probes
    assert [t for t, _ in resumed.frames] == [t for t, _ in whole.frames]
    assert [r.size for r in resumed.records] == [r.size for r in whole.records]
    if adaptive is not None:  # the step grew before the checkpoint and after it
        assert checkpoint.step_size > 0.005
        assert max(r.size for r in whole.records) == pytest.approx(0.01)
    with pytest.raises(ValueError, match="other \\[dynamics\\] settings"):
        read_checkpoint(tmp_path / "c.pt", DynamicsConfig(dt=0.005, duration=0.04))


def test_ndf_sim_resume_continues_an_interrupted_dynamic_run(tmp_path, monkeypatch):
    scene = tmp_path / "drop.toml"
    scene.write_text(SCENE.replace("duration = 0.02", "duration = 0.03"))
    whole, cut = tmp_path / "whole", tmp_path / "cut"
    assert sim.main([str(scene), "--out", str(whole), "--no-pictures", *RUNTIME]) == 0
    real = app_dynamics.write_checkpoint

    def interrupted(path, checkpoint, extra):
        real(path, checkpoint, extra)
        if checkpoint.step == 4:
            raise KeyboardInterrupt

    monkeypatch.setattr(app_dynamics, "write_checkpoint", interrupted)
    assert sim.main([str(scene), "--out", str(cut), "--no-pictures", *RUNTIME]) == 130
    monkeypatch.setattr(app_dynamics, "write_checkpoint", real)
    assert sim.main([str(scene), "--out", str(cut), "--no-pictures", "--resume",
                     *RUNTIME]) == 0
    a = json.loads((whole / "result.json").read_text())
    b = json.loads((cut / "result.json").read_text())
    for key in ("times", "kinetic", "potential", "total", "newton_iterations", "probes",
                "frame_times"):
        assert a["dynamics"][key] == b["dynamics"][key], key
    assert a["trajectory"] == b["trajectory"] and a["probes"] == b["probes"]
    assert (whole / "mesh.obj").read_bytes() == (cut / "mesh.obj").read_bytes()
    for k in range(4):
        name = f"trajectory/step_{k:03d}.obj"
        assert (whole / name).read_bytes() == (cut / name).read_bytes()
    # another scene is refused in one line
    scene.write_text(SCENE.replace("duration = 0.02", "duration = 0.03").replace(
        "mass_damping = 0.5", "mass_damping = 0.6"))
    (cut / "result.json").unlink()
    assert sim.main([str(scene), "--out", str(cut), "--no-pictures", "--resume",
                     *RUNTIME]) == 2


def test_a_resumed_contact_run_ends_in_the_same_state_bit_for_bit(tmp_path):
    """With obstacles: a plate dropped 1 cm onto the ground, interrupted at 0.1 s (on the
    barrier) and resumed, ends as the uninterrupted run, bit for bit, with the same gaps.
    (The checkpoint also carries the check points flagged so far and the barrier stiffness;
    here the test passes without restoring them too: the resumed step's first contact round
    flags the same points and κ was not raised.)"""
    from tests.test_dynamics_contact import PLATE
    from tests.test_dynamics_contact import scene as contact_scene

    s = contact_scene(PLATE)
    config = DynamicsConfig(dt=0.02, duration=0.2, mass_damping=20.0, frame_rate=50.0)
    whole = TimeStepper(s.model, s.field, config).run()

    def stop(checkpoint):
        if checkpoint.step == 5:
            write_checkpoint(tmp_path / "c.pt", checkpoint, {})
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        TimeStepper(s.model, s.field, config).run(on_checkpoint=stop)
    checkpoint, _ = read_checkpoint(tmp_path / "c.pt", config)
    resumed = TimeStepper(s.model, s.field, config).run(resume=checkpoint)
    assert torch.equal(resumed.field.coefficients, whole.field.coefficients)
    assert [r.gap for r in resumed.records] == [r.gap for r in whole.records]
    assert [r.total for r in resumed.records] == [r.total for r in whole.records]
    assert min(r.gap for r in whole.records[5:]) < s.model.contact.activation  # it landed
