"""docs/make_gallery.py draws a scene's pictures, energy plot and video from its run files."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
import torch
from test_render_figure import fake_run

import taichi_ndf.render.trajectory as trajectory
from taichi_ndf.render.video import video_info
from tests.scripts import load_script


def gallery():
    return load_script("docs/make_gallery.py")


def test_pictures_energy_plot_video_and_overview_of_a_run(tmp_path, monkeypatch):
    module = gallery()
    monkeypatch.setattr(module, "PICTURES", tmp_path / "pictures")
    (tmp_path / "pictures").mkdir()
    run = fake_run(tmp_path / "run", frames=3, obstacle=True)
    made = module.pictures("sheet", run)
    assert made["video"] == "sheet.mp4" and made["colour"] == "displacement"
    picture = cv2.imread(str(tmp_path / "pictures" / "sheet.png"))
    energy = cv2.imread(str(tmp_path / "pictures" / "sheet_energy.png"))
    assert picture.shape[0] == 480 and picture.std() > 0 and energy.std() > 0
    info = video_info(tmp_path / "pictures" / "sheet.mp4")
    assert info["codec"].startswith("h264") and info["size"] == module.VIDEO_SIZE
    tile = made["tile"]
    assert tile.shape == (module.TILE[1], module.TILE[0], 3)
    # four tiles, one row; five: two rows with the rest blank
    assert module.overview([tile] * 4).shape == (module.TILE[1], 4 * module.TILE[0], 3)
    two_rows = module.overview([tile] * 5)
    assert two_rows.shape[0] == 2 * module.TILE[1]
    assert np.all(two_rows[module.TILE[1]:, module.TILE[0]:] == 235)


def test_add_folds_perturbs_the_periodic_direction_radially(tmp_path):
    module = gallery()
    m1, m2 = 8, 5
    payload = {"field_type": "spline",
               "architecture": {"spans": [m1, 2], "periodic": [True, False]},
               "parameters": {"coefficients": torch.zeros(m1 * m2, 3, dtype=torch.float64)}}
    torch.save(payload, tmp_path / "checkpoint.pt")
    module.add_folds(tmp_path / "checkpoint.pt", 2)
    grid = torch.load(tmp_path / "checkpoint.pt")["parameters"]["coefficients"].view(m1, m2, 3)
    radial = grid[..., 0] * torch.cos(2 * torch.pi * torch.arange(m1) / m1)[:, None] \
        + grid[..., 1] * torch.sin(2 * torch.pi * torch.arange(m1) / m1)[:, None]
    # two folds: out at θ = 0 and π, in at π/2 and 3π/2; largest at ξ₂ = 0, none at the far end
    assert radial[0, 0] == pytest.approx(module.FOLD_AMPLITUDE)
    assert radial[2, 0] == pytest.approx(-module.FOLD_AMPLITUDE)
    assert radial[4, 0] == pytest.approx(module.FOLD_AMPLITUDE)
    assert torch.all(radial[:, -1] == 0) and torch.all(grid[..., 2] == 0)
    payload["architecture"]["periodic"] = [False, False]
    torch.save(payload, tmp_path / "open.pt")
    with pytest.raises(SystemExit, match="periodic"):
        module.add_folds(tmp_path / "open.pt", 2)


def test_unconverged_and_left_out_runs_get_reasons_not_pictures():
    module = gallery()
    run = {"status": "ok", "energy": 0.1, "iterations": 3, "converged": True, "spans": [4, 4],
           "wall": 1.0, "cpu": 1.0, "load": [1.0, 1.0], "date": "d", "commit": "c"}
    records = {"a": run, "b": {**run, "converged": False, "newton_tail": [[0.1, 2e-9, 1.0, 0]]},
               "c": run, "d": {"status": "failed", "message": "boom"}}
    reasons = module.left_out_reasons(records, {"c": "a saddle"})
    assert set(reasons) == {"b", "c", "d"}
    assert reasons["b"].startswith("not converged") and "2e-09" in reasons["b"]
    assert reasons["c"] == "a saddle" and "boom" in reasons["d"]


def test_a_garment_gets_a_picture_of_its_panels_with_their_legend(tmp_path, monkeypatch):
    import json

    from taichi_ndf.io import read_mesh, write_ply
    from taichi_ndf.render.legend import PALETTE_BGR

    module = gallery()
    monkeypatch.setattr(module, "PICTURES", tmp_path / "pictures")
    (tmp_path / "pictures").mkdir()
    run = fake_run(tmp_path / "run")
    assert module.pictures("sheet", run)["panels"] is None  # not a garment: no panel picture
    mesh = read_mesh(run / "mesh.ply")
    panel = (mesh.vertices[:, 0] > 0.5).astype(np.float64)  # two panels, left and right
    write_ply(run / "mesh.ply", mesh.vertices, mesh.faces, uvs=mesh.uvs,
              vertex_scalars={**mesh.vertex_scalars, "panel": panel})
    result = json.loads((run / "result.json").read_text())
    result["resolved"]["scene_file"]["panels"] = [{"name": "front"}, {"name": "back"}]
    (run / "result.json").write_text(json.dumps(result))
    made = module.pictures("skirt", run)
    assert made["panels"] == "skirt_panels.png" and made["colour"] == "displacement"
    image = cv2.imread(str(tmp_path / "pictures" / "skirt_panels.png"))
    assert image.shape[0] == 480
    # both panels' palette colours appear (shaded: within a few levels of them somewhere)
    pixels = image.reshape(-1, 3).astype(float)
    for colour in PALETTE_BGR[:2]:
        assert np.abs(pixels - colour).max(axis=1).min() < 12


def test_a_left_out_scene_without_a_stored_run_is_not_run(tmp_path, monkeypatch):
    module = gallery()
    ran = []
    monkeypatch.setattr(module, "run_scene",
                        lambda name, runs, quick, spans: ran.append(name) or {})
    module.main(["--runs", str(tmp_path), "--scenes", "napkin,bowl", "--runs-only",
                 "--leave-out", "bowl=grid-limited"])
    assert ran == ["napkin"]
    (tmp_path / "bowl.json").write_text("{}")  # stored: run (read back) again
    module.main(["--runs", str(tmp_path), "--scenes", "napkin,bowl", "--runs-only",
                 "--leave-out", "bowl=grid-limited"])
    assert ran == ["napkin", "napkin", "bowl"]
    assert module.left_out_reasons({}, {"bowl": "grid-limited"}) == {"bowl": "grid-limited"}


def test_spans_solve_a_scene_on_the_grid_given_and_refuse_a_run_on_another(tmp_path,
                                                                          monkeypatch):
    module = gallery()
    calls = []

    def run_one(name, field, out, precision, quick, extra=()):
        calls.append((name, extra))
        out.mkdir(parents=True)
        (out / "result.json").write_text("{}")
        return {"status": "ok", "energy": -0.1, "iterations": 5, "converged": True,
                "spans": [20, 10], "wall": 1.0, "cpu": 1.0, "load": [1.0, 1.0]}

    monkeypatch.setattr(module.comparison, "run_one", run_one)
    module.main(["--runs", str(tmp_path), "--scenes", "napkin,bowl", "--runs-only",
                 "--spans", "napkin=20x10"])
    assert calls == [("napkin", ("--set", "field.spans=[20,10]")), ("bowl", ())]
    with pytest.raises(SystemExit, match=r"\[20, 10\] spans, not \[40, 40\]"):
        module.main(["--runs", str(tmp_path), "--scenes", "napkin", "--runs-only",
                     "--spans", "napkin=40x40"])
    for bad in ("napkin=20", "napkin=0x4", "bowl=4x4", "napkin=ax4"):  # bowl: not in --scenes
        with pytest.raises(SystemExit) as refused:
            module.main(["--runs", str(tmp_path), "--scenes", "napkin", "--runs-only",
                         "--spans", bad])
        assert refused.value.code == 2
    assert len(calls) == 2


def test_kept_sections_give_each_scene_its_text_and_overview_tile():
    module = gallery()
    width, height = module.TILE
    tiles = [np.full((height, width, 3), 10 * (k + 1), np.uint8) for k in range(5)]
    page = "# Gallery\n\nintro\n\n" + "".join(
        f"### s{k}\n\nsection {k}\n\n" for k in range(5)) + \
        "### Not in this gallery\n\n- **late**: not converged: 3 iterations\n"
    sections, reasons = module.kept_sections(page, module.overview(tiles))
    assert list(sections) == [f"s{k}" for k in range(5)]
    assert sections["s3"][0] == "### s3\n\nsection 3\n"
    for k in range(5):  # the fifth tile from the second row, not the blank beside it
        assert np.all(sections[f"s{k}"][1] == 10 * (k + 1))
    assert reasons == {"late": "not converged: 3 iterations"}
    with pytest.raises(SystemExit, match="no tile"):
        module.kept_sections(page, module.overview(tiles[:4]))


def test_a_garment_or_dynamic_run_has_its_convergence_from_its_result():
    module = gallery()
    steps = [{"load_factor": 0.5, "converged": True}, {"load_factor": 1.0, "converged": True}]
    assert module.run_convergence({"load_steps": steps})["converged"] is True
    steps[1]["converged"] = False
    assert module.run_convergence({"load_steps": steps})["converged"] is False
    assert module.run_convergence({})["converged"] is False  # nothing says it converged
    dynamic = module.run_convergence({"dynamics": {"spans": [6, 6], "steps": 120}})
    assert dynamic == {"converged": True, "spans": [6, 6], "dynamic": True}
    record = {"status": "ok", "energy": -0.03, "iterations": 725, "wall": 1.0, "cpu": 1.0,
              "load": [1.0, 1.0], "date": "d", "commit": "c", **dynamic}
    assert "every time step converged (6 × 6 spans)" in module.describe(record)


def test_a_dynamic_run_gets_its_energies_over_time_plotted():
    module = gallery()
    times = np.linspace(0.0, 1.0, 11)
    result = {"dynamics": {"times": times.tolist(), "kinetic": np.sin(3 * times).tolist(),
                           "potential": (-np.sin(3 * times)).tolist(),
                           "total": np.zeros(11).tolist(), "integrator": "implicit_euler",
                           "dt": 0.01}}
    image = module.energy_picture(result)  # no "history": energy_figure would raise
    assert image.shape == (500, 820, 3) and image.std() > 0
    with pytest.raises(KeyError):
        module.energy_picture({})


def test_a_dynamic_runs_video_plays_in_real_time_labelled_by_time(tmp_path, monkeypatch):
    module = gallery()
    monkeypatch.setattr(module, "PICTURES", tmp_path / "pictures")
    (tmp_path / "pictures").mkdir()
    run = fake_run(tmp_path / "run", frames=11)  # states at 1/11 … 1: times [s] in a dynamic run
    result = json.loads((run / "result.json").read_text())
    times = result["trajectory"]["load_factors"]
    result["dynamics"] = {"times": times, "kinetic": times, "potential": times,
                          "total": times, "integrator": "implicit_euler", "dt": 0.01}
    (run / "result.json").write_text(json.dumps(result))
    labels = []
    monkeypatch.setattr(trajectory, "put_label", lambda image, text, **_: labels.append(text))
    made = module.pictures("swing", run)
    info = video_info(tmp_path / "pictures" / made["video"])
    assert info["fps"] == pytest.approx(11.0, rel=1e-3)  # 10 intervals in 10/11 s: real time
    assert labels[0].startswith("t = 0.09 s") and labels[-1].startswith("t = 1.00 s")
    assert info["frames"] == 11 + 11  # one video frame per state, the last held one second
