"""`ndf-sim` and the demos, in-process: resume, NaN guard, invalid scenes, output protection,
`ndf-export`."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from taichi_ndf.cli import export, sim
from taichi_ndf.minimise.checkpoint import load_checkpoint
from taichi_ndf.minimise.state import State
from tests.scripts import load_script

RUNTIME = ["--precision", "f64"]  # the test session's runtime (tests/conftest.py)

# A small napkin: pinned corner, gravity, a 16-wide field, checkpoints every 5 iterations.
SMALL_NAPKIN = """
name = "small_napkin"
[geometry]
type = "plane"
bounds = [[0.0, 1.0], [0.0, 1.0]]
[material]
preset = "cloth"
[loads]
gravity = [0.0, 0.0, -9.81]
[[boundary.constraint]]
type = "pinned_point"
xi = [0.0, 0.0]
[field]
width = 16
[training]
iterations = 10
samples = 256
learning_rate = {lr}
monitor_every = 5
monitor_samples = 512
checkpoint_every = 5
[[probes]]
name = "free_corner"
xi = [1.0, 1.0]
[output]
resolution = [16, 16]
"""


def write_scene(tmp_path: Path, text: str, name: str = "scene.toml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def small_napkin(tmp_path: Path, *, lr: float = 1e-3, name: str = "scene.toml") -> Path:
    return write_scene(tmp_path, SMALL_NAPKIN.format(lr=lr), name)


def run_sim(*args) -> int:
    return sim.main([str(a) for a in args] + RUNTIME)


def interrupt_after_saving(monkeypatch, iteration: int | None = None) -> None:
    """Ctrl-C right after the checkpoint of `iteration` is written (None: the first one)."""
    save = State.save

    def save_then_interrupt(self, path, extra=None):
        save(self, path, extra)
        if iteration is None or self.iteration == iteration:
            raise KeyboardInterrupt

    monkeypatch.setattr(State, "save", save_then_interrupt)


def load_demo(name: str):
    return load_script(f"demos/{name}.py", f"demo_{name}")


def test_napkin_demo_quick_on_the_spline_path(tmp_path, capsys):
    out = tmp_path / "napkin"
    assert load_demo("napkin").main(["--quick", "--out", str(out), *RUNTIME]) == 0
    printed = capsys.readouterr().out
    assert str(out) in printed and "render.png" in printed
    result = json.loads((out / "result.json").read_text())
    assert result["scene"] == "napkin" and len(result["levels"]) == 1  # one spline grid level
    assert np.isfinite(result["energy"]) and result["energy"] < 0
    for name in ("mesh.obj", "mesh.ply", "render.png", "energy.png", "checkpoint.pt"):
        assert (out / name).is_file()


def test_napkin_demo_quick_with_the_siren(tmp_path, capsys):
    out = tmp_path / "napkin"
    assert load_demo("napkin").main(["--quick", "--siren", "--out", str(out), "--iters", "3",
                                     *RUNTIME]) == 0
    printed = capsys.readouterr().out
    assert str(out) in printed and "render.png" in printed
    result = json.loads((out / "result.json").read_text())
    assert result["scene"] == "napkin" and result["iterations"] == 3
    for name in ("mesh.obj", "mesh.ply", "render.png", "energy.png", "checkpoint.pt"):
        assert (out / name).is_file()


def test_run_scene_demo_lists_and_runs_with_a_fabric(tmp_path, capsys):
    demo = load_demo("run_scene")
    assert demo.main(["--list"]) == 0
    assert "sleeve_twist" in capsys.readouterr().out.split()
    out = tmp_path / "run"
    status = demo.main([str(small_napkin(tmp_path)), "--quick", "--material", "silk", "--iters",
                        "2", "--out", str(out), *RUNTIME])
    assert status == 0
    result = json.loads((out / "result.json").read_text())
    assert result["iterations"] == 2
    assert result["resolved"]["scene_file"]["material"] == {"preset": "silk"}


def test_resume_continues_an_interrupted_run(tmp_path, monkeypatch):
    scene = small_napkin(tmp_path)
    assert run_sim(scene, "--out", tmp_path / "whole") == 0
    whole = json.loads((tmp_path / "whole" / "result.json").read_text())

    interrupt_after_saving(monkeypatch, 5)
    assert run_sim(scene, "--out", tmp_path / "cut") == 130  # Ctrl-C
    monkeypatch.undo()
    # The attempt lies beside the (never completed) run directory, ready to resume.
    assert not (tmp_path / "cut").exists()
    staged = tmp_path / "cut.incomplete"
    assert not (staged / "result.json").exists()
    assert load_checkpoint(staged / "checkpoint.pt").extra["iteration"] == 5

    assert run_sim(scene, "--out", tmp_path / "cut", "--resume") == 0
    resumed = json.loads((tmp_path / "cut" / "result.json").read_text())
    assert resumed["iterations"] == whole["iterations"] == 10
    # The first five iterations are the interrupted run's own, kept in the checkpoint.
    assert resumed["history"][0] == {**whole["history"][0], "wall_time":
                                     resumed["history"][0]["wall_time"]}
    assert [h["iteration"] for h in resumed["history"]] == [5, 10]
    # Adam's moments and the sampling generator are in the checkpoint: the resumed run draws
    # the same samples and ends where the uninterrupted one did.
    assert resumed["energy"] == pytest.approx(whole["energy"], rel=1e-9)

    # Resuming with more iterations goes on from the end of the previous run.
    assert run_sim(scene, "--out", tmp_path / "cut", "--resume", "--iters", "15") == 0
    longer = json.loads((tmp_path / "cut" / "result.json").read_text())
    assert [h["iteration"] for h in longer["history"]] == [5, 10, 15]


def test_resume_needs_a_checkpoint(tmp_path, capsys):
    assert run_sim(small_napkin(tmp_path), "--out", tmp_path / "none", "--resume") == 2
    assert "no checkpoint" in capsys.readouterr().err


def test_nan_guard_stops_with_a_clear_message(tmp_path, capsys):
    out = tmp_path / "run"
    assert run_sim(small_napkin(tmp_path, lr=1e30), "--out", out) == 2
    err = capsys.readouterr().err
    assert "diverged at iteration 1" in err and "Lower the learning rate" in err
    assert not (out / "result.json").exists()


def test_nan_guard_keeps_the_last_good_checkpoint(tmp_path, capsys):
    out = tmp_path / "run"
    assert run_sim(small_napkin(tmp_path), "--out", out) == 0
    good = (out / "checkpoint.pt").read_bytes()
    result = (out / "result.json").read_bytes()
    # The same scene with an absurd learning rate, resumed from the good run, blows up.
    bad = small_napkin(tmp_path, lr=1e30, name="bad.toml")
    assert run_sim(bad, "--out", out, "--resume", "--iters", "20") == 2
    err = capsys.readouterr().err
    # The resumed attempt runs in run.incomplete; its checkpoint is the good one.
    staged = tmp_path / "run.incomplete" / "checkpoint.pt"
    assert "diverged at iteration 11" in err and str(staged) in err
    assert staged.read_bytes() == good
    assert (out / "checkpoint.pt").read_bytes() == good
    assert (out / "result.json").read_bytes() == result
    weights = load_checkpoint(out / "checkpoint.pt").field.get_flat()
    assert torch.isfinite(weights).all()


@pytest.mark.parametrize(
    ("edit", "key"),
    [
        (("[material]\npreset = \"cloth\"", "[material]\npreset = \"cloth\"\ncolour = \"red\""),
         "material: unknown key(s) 'colour'"),
        (("iterations = 10", "iterations = \"many\""),
         "training.iterations: expected an integer"),
        (("xi = [0.0, 0.0]", "xi = [2.0, 0.5]"), "boundary"),
        (("xi = [1.0, 1.0]", "xi = [1.0, 1.5]"), "probes"),
        (("preset = \"cloth\"", "preset = \"velvet\""), "material.preset: must be one of"),
        (("width = 16", "width = 16.5"), "field.width: expected an integer"),
    ],
    ids=["unknown-key", "wrong-type", "pin-outside", "probe-outside", "bad-preset", "float-width"],
)
def test_invalid_scene_errors_name_the_key(tmp_path, capsys, edit, key):
    text = SMALL_NAPKIN.format(lr=1e-3)
    assert edit[0] in text
    scene = write_scene(tmp_path, text.replace(edit[0], edit[1], 1))
    assert run_sim(scene, "--out", tmp_path / "run") == 2
    err = capsys.readouterr().err
    assert err.startswith("ndf-sim: error: ") and key in err, err
    assert not (tmp_path / "run").exists()


def test_bad_material_option_names_the_preset(tmp_path, capsys):
    assert run_sim(small_napkin(tmp_path), "--out", tmp_path / "run", "--material", "tweed") == 2
    err = capsys.readouterr().err
    assert "material.preset" in err and "tweed" in err


def test_non_empty_output_directory_is_refused(tmp_path, capsys):
    out = tmp_path / "run"
    out.mkdir()
    notes = out / "notes.txt"
    notes.write_text("keep me")
    before = notes.stat().st_mtime_ns
    assert run_sim(small_napkin(tmp_path), "--out", out) == 2
    assert "not empty" in capsys.readouterr().err
    assert sorted(p.name for p in out.iterdir()) == ["notes.txt"]
    assert notes.read_text() == "keep me" and notes.stat().st_mtime_ns == before

    assert run_sim(small_napkin(tmp_path), "--out", out, "--overwrite") == 0
    assert notes.read_text() == "keep me" and (out / "result.json").is_file()


def test_export_reproduces_the_run_mesh_at_any_resolution(tmp_path):
    out = tmp_path / "run"
    assert run_sim(small_napkin(tmp_path), "--out", out) == 0
    same = tmp_path / "same.obj"
    assert export.main([str(out / "checkpoint.pt"), "--resolution", "16", "--out", str(same),
                        *RUNTIME]) == 0
    run_mesh = np.loadtxt([ln for ln in (out / "mesh.obj").read_text().splitlines()
                           if ln.startswith("v ")], usecols=(1, 2, 3))
    exported = np.loadtxt([ln for ln in same.read_text().splitlines() if ln.startswith("v ")],
                          usecols=(1, 2, 3))
    np.testing.assert_allclose(exported, run_mesh, rtol=0, atol=1e-9)
    fine = tmp_path / "fine.ply"
    assert export.main([str(out / "checkpoint.pt"), "--resolution", "64", "--out", str(fine),
                        *RUNTIME]) == 0
    assert fine.read_bytes().startswith(b"ply")
    assert export.main([str(out / "checkpoint.pt"), "--resolution", "64", "--out", str(fine),
                        *RUNTIME]) == 2  # exists, no --overwrite


def test_resume_keeps_the_trajectory_of_load_steps_finished_before_the_interruption(
        tmp_path, monkeypatch):
    text = SMALL_NAPKIN.format(lr=1e-3).replace("checkpoint_every = 5",
                                                 "checkpoint_every = 5\nload_steps = [0.5, 1.0]")
    scene = write_scene(tmp_path, text)
    assert run_sim(scene, "--out", tmp_path / "whole") == 0
    whole = json.loads((tmp_path / "whole" / "result.json").read_text())
    assert whole["trajectory"]["load_factors"] == [0.5, 1.0]

    interrupt_after_saving(monkeypatch, 15)  # in the second load step
    assert run_sim(scene, "--out", tmp_path / "cut") == 130  # Ctrl-C
    monkeypatch.undo()
    # the first step's frame is on disk at once (in the incomplete attempt)
    written_before = (tmp_path / "cut.incomplete" / "trajectory" / "step_000.obj").read_bytes()
    first = tmp_path / "cut" / "trajectory" / "step_000.obj"

    assert run_sim(scene, "--out", tmp_path / "cut", "--resume") == 0
    resumed = json.loads((tmp_path / "cut" / "result.json").read_text())
    assert resumed["trajectory"]["load_factors"] == [0.5, 1.0]
    assert resumed["trajectory"]["energy"] == pytest.approx(whole["trajectory"]["energy"],
                                                            rel=1e-9)
    assert first.read_bytes() == written_before
    assert first.read_bytes() == (tmp_path / "whole" / "trajectory" / "step_000.obj").read_bytes()
    # the resumed run's video shows both load steps, in H.264, each for a while
    from taichi_ndf.render.trajectory import FPS, HOLD_SECONDS, frame_repeats
    from taichi_ndf.render.video import video_info

    info = video_info(tmp_path / "cut" / "trajectory.mp4")
    assert info["codec"].startswith("h264")
    assert info["frames"] == 2 * frame_repeats(2) + round(HOLD_SECONDS * FPS)


def test_threads_option_sets_torch_threads_and_refuses_zero(tmp_path, capsys):
    scene = small_napkin(tmp_path)
    with pytest.raises(SystemExit) as stop:
        run_sim(scene, "--out", tmp_path / "zero", "--threads", "0")
    assert stop.value.code == 2 and "--threads: must be >= 1" in capsys.readouterr().err
    try:
        assert run_sim(scene, "--out", tmp_path / "two", "--iters", "1", "--threads", "2") == 0
        assert torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(1)  # the test session's setting (tests/conftest.py)


def test_export_evaluates_a_pseudo_time_field_at_any_time(tmp_path, capsys):
    text = SMALL_NAPKIN.format(lr=1e-3).replace(
        "checkpoint_every = 5", "checkpoint_every = 5\npseudo_time = true").replace(
        "resolution = [16, 16]", "resolution = [16, 16]\nframes = 3")
    out = tmp_path / "run"
    assert run_sim(write_scene(tmp_path, text), "--out", out) == 0
    frames = sorted((out / "trajectory").glob("step_*.obj"))
    assert len(frames) == 3 and (out / "trajectory.mp4").stat().st_size > 0

    def vertices(path):
        return np.loadtxt([ln for ln in path.read_text().splitlines() if ln.startswith("v ")],
                          usecols=(1, 2, 3))

    for time, frame in (("1", out / "mesh.obj"), ("0.5", frames[1])):
        mesh = tmp_path / f"t{time}.obj"
        assert export.main([str(out / "checkpoint.pt"), "--resolution", "16", "--out",
                            str(mesh), "--time", time, *RUNTIME]) == 0
        np.testing.assert_allclose(vertices(mesh), vertices(frame), rtol=0, atol=1e-9)
    assert export.main([str(out / "checkpoint.pt"), "--resolution", "16", "--out",
                        str(tmp_path / "bad.obj"), "--time", "1.5", *RUNTIME]) == 2
    assert "--time must be in [0, 1]" in capsys.readouterr().err


def test_export_refuses_a_time_for_an_ordinary_field(tmp_path, capsys):
    out = tmp_path / "run"
    assert run_sim(small_napkin(tmp_path), "--out", out, "--iters", "1") == 0
    assert export.main([str(out / "checkpoint.pt"), "--resolution", "16", "--out",
                        str(tmp_path / "t.obj"), "--time", "0.5", *RUNTIME]) == 2
    assert "--time needs a checkpoint of a pseudo-time field" in capsys.readouterr().err
