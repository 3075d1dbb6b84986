"""Study files, points, run names, scene-key overrides, the results table and the summary plot
of `ndf-sweep` (no runs: the engines are tests/test_sweep_engines.py)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from taichi_ndf.cli import sweep
from taichi_ndf.scene.overrides import apply_overrides, parse_assignment
from taichi_ndf.scene.reader import load_scene
from taichi_ndf.scene.schema import SceneError
from taichi_ndf.sweep.jobs import JOBS, toml_value
from taichi_ndf.sweep.naming import run_name, short_keys
from taichi_ndf.sweep.plot import summary_plot
from taichi_ndf.sweep.study import StudyError, load_study
from taichi_ndf.sweep.table import ResultsTable, read_csv

ROOT = Path(__file__).resolve().parents[1]
NAPKIN = ROOT / "scenes" / "napkin.toml"


def study_file(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "study.toml"
    path.write_text(f'job = "scene"\nbase = "{NAPKIN}"\n' + text)
    return path


def test_grid_is_every_combination_first_axis_slowest(tmp_path):
    study = load_study(study_file(tmp_path, """
[options]
quick = true
[axes]
material = ["cloth", "silk"]
loads.gravity = [[0, 0, -9.81], [0, 0, -4.9], [0, -1, -9.81]]
"""))
    assert study.axes == ("material", "loads.gravity")
    assert [p.parameters["material"] for p in study.points] == ["cloth"] * 3 + ["silk"] * 3
    assert study.points[4].name == "material-silk_gravity-0,0,-4.9"
    assert study.options == {"quick": True}


def test_list_of_points_and_its_command_line(tmp_path):
    study = load_study(study_file(tmp_path, """
[[points]]
material = "silk"
"material.stiffness_scale" = 0.5
seed = 3
[[points]]
material = "cloth"
"material.stiffness_scale" = 2.0
seed = 4
"""))
    assert [p.name for p in study.points] == ["material-silk_stiffness_scale-0.5_seed-3",
                                              "material-cloth_stiffness_scale-2.0_seed-4"]
    command = study.job.command(study.base, study.points[0].parameters, tmp_path / "run")
    assert command[1:4] == ["-m", "taichi_ndf.cli.sim", str(NAPKIN)]
    assert command[4:] == ["--material", "silk", "--set", "material.stiffness_scale=0.5",
                           "--seed", "3", "--out", str(tmp_path / "run")]


@pytest.mark.parametrize("text, key", [
    ("[axes]\nmaterial = \"cloth\"\n", "axes.material"),            # not a list
    ("[axes]\nmaterial = []\n", "axes.material"),                   # empty
    ("[axes]\n\"loads.gravty\" = [[0, 0, -1]]\n", "loads"),          # unknown scene key
    ("[axes]\n\"material.stiffness_scale\" = [-1.0]\n", "stiffness_scale"),  # invalid value
    ("[options]\niters = \"many\"\n[axes]\nseed = [1]\n", "options.iters"),
    ("[options]\nseed = 1\n[axes]\nseed = [1, 2]\n", "axes.seed"),  # fixed and varied
    ("colour = 1\n[axes]\nseed = [1]\n", "colour"),                 # unknown top-level key
    ("", "axes"),                                                   # no axes, no points
    ("[[points]]\nseed = 1\n[[points]]\nmaterial = \"silk\"\n", "points[0]"),
])
def test_a_bad_study_file_is_one_line_naming_the_key(tmp_path, capsys, text, key):
    path = study_file(tmp_path, text)
    with pytest.raises(StudyError, match=key.replace("[", r"\[").replace("]", r"\]")):
        load_study(path)
    assert sweep.main([str(path), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("ndf-sweep: error: ") and "\n" not in err and key in err
    assert not (tmp_path / "out").exists()


def test_several_grids_one_after_the_other(tmp_path):
    path = tmp_path / "s.toml"
    path.write_text('job = "calibration"\n[[grids]]\ncase = ["strip"]\nnoise = [0.0]\n'
                    'seed = [0]\n[[grids]]\ncase = ["strip"]\nnoise = [0.01, 0.02]\n'
                    'seed = [1, 2]\n')
    study = load_study(path)
    assert [(p.parameters["noise"], p.parameters["seed"]) for p in study.points] == [
        (0.0, 0), (0.01, 1), (0.01, 2), (0.02, 1), (0.02, 2)]
    path.write_text('job = "calibration"\n[[grids]]\ncase = ["strip"]\n[[grids]]\n'
                    'seed = [1]\n')
    with pytest.raises(StudyError, match="grids: key 'case' is missing"):
        load_study(path)


def test_a_job_without_a_base_file_and_its_unknown_options(tmp_path):
    path = tmp_path / "s.toml"
    path.write_text('job = "calibration"\n[axes]\ncase = ["strip"]\nnoise_level = [0.1]\n')
    with pytest.raises(StudyError, match="axes.noise_level: not an option of job"):
        load_study(path)
    path.write_text('job = "calibration"\nbase = "x.toml"\n[axes]\nseed = [1]\n')
    with pytest.raises(StudyError, match="base: job 'calibration' takes no base file"):
        load_study(path)


def test_scene_overrides_are_the_scene_files_own_checks():
    key, value = parse_assignment("loads.gravity=[0, 0, -4.9]")
    assert (key, value) == ("loads.gravity", [0, 0, -4.9])
    scene = load_scene(NAPKIN, overrides={key: value, "material.stiffness_scale": 0.5})
    assert scene.model.loads.gravity == (0.0, 0.0, -4.9)
    assert scene.document["material"]["stiffness_scale"] == 0.5
    with pytest.raises(SceneError, match="not a TOML value"):
        parse_assignment("material.preset=silk")
    with pytest.raises(SceneError, match="no index 3"):
        apply_overrides({"probes": [{}]}, {"probes[3].xi": [0, 0]})
    with pytest.raises(SceneError, match=r"loads: unknown key\(s\) 'gravty'"):
        load_scene(NAPKIN, overrides={"loads.gravty": [0, 0, -1]})
    document = apply_overrides({"probes": [{"xi": [0, 0]}]}, {"probes[0].xi": [1, 1]})
    assert document == {"probes": [{"xi": [1, 1]}]}


def test_run_names_round_trip_floats_and_shorten_long_ones():
    keys = short_keys(["a.scale", "b.scale", "seed"])
    assert keys == {"a.scale": "a-scale", "b.scale": "b-scale", "seed": "seed"}
    assert run_name({"seed": 0.1 + 0.2}, {"seed": "seed"}) == "seed-0.30000000000000004"
    long = run_name({"x": "y" * 300}, {"x": "x"})
    assert len(long) == 120 and long != run_name({"x": "y" * 301}, {"x": "x"})
    assert toml_value({"a": [1, "b", True]}) == '{"a" = [1, "b", true]}'


def test_table_rows_in_study_order_and_the_plot(tmp_path):
    study = load_study(study_file(tmp_path, "[axes]\nloads.gravity = [[0, 0, -1], [0, 0, -2]]\n"
                                            "\"material.stiffness_scale\" = [1.0, 2.0]\n"))
    names = [p.name for p in study.points]
    table = ResultsTable(tmp_path, study.axes, names)
    for i in (3, 0, 2):
        table.add(i, {"point": names[i], **study.points[i].parameters, "status": "ok",
                      "reason": "", "energy_J": -float(i), "seed": 0, "wall_s": 1.0})
    rows = read_csv(tmp_path / "results.csv")
    assert [r["point"] for r in rows] == [names[0], names[2], names[3]]
    assert rows[0]["loads.gravity"] == "[0, 0, -1]" and rows[2]["energy_J"] == "-3.0"
    reread = ResultsTable(tmp_path, study.axes, names)
    reread.load()
    assert sorted(reread.rows) == [0, 2, 3]
    assert json.loads((tmp_path / "rows" / f"{names[2]}.json").read_text())["energy_J"] == -2.0
    named = {"point", *study.axes, "status", "reason", "seed", "wall_s"}
    plot = summary_plot(tmp_path / "summary.png", study.axes, study.points, table.rows, named)
    assert plot is not None and plot.stat().st_size > 1000


def test_every_job_names_a_tool_module():
    import importlib.util

    for job in JOBS.values():
        assert importlib.util.find_spec(job.module) is not None, job.module


def test_ndf_sim_set_refuses_a_bad_key_in_one_line(tmp_path, capsys):
    from taichi_ndf.cli import sim

    for assignment, message in [("material.preset=silk", "not a TOML value"),
                                ("loads.gravty=[0, 0, -1]", "unknown key(s) 'gravty'")]:
        assert sim.main([str(NAPKIN), "--out", str(tmp_path / "run"), "--set",
                         assignment]) == 2
        err = capsys.readouterr().err.strip()
        assert err.startswith("ndf-sim: error: ") and message in err and "\n" not in err
    assert not (tmp_path / "run").exists()


def test_fit_outputs_of_determined_and_rejected_fits_and_their_progress_lines(tmp_path):
    """A fit whose model does not explain the data has no value (inverse.material.report):
    its row gives determined False and the best-fit value, and the progress line shows it
    (a quick-simulated observation of the cantilever strip made both crash before)."""
    run = tmp_path / "run"
    run.mkdir()
    rejected = {"parameters": {"bending_stiffness": {
        "unit": "N·m", "determined": False, "status": "the model does not explain the data",
        "best_fit_value": 180.66}}, "misfit": 1e-5, "iterations": 13}
    (run / "estimate.json").write_text(json.dumps(rejected))
    row = JOBS["fit_material"].outputs(run)
    assert row["estimate_bending_stiffness"] == "" and row["best_fit_bending_stiffness"] == 180.66
    assert row["determined_bending_stiffness"] is False
    line = sweep._line({"status": "ok", **row, "wall_s": 1.0, "cpu_s": 1.0})
    assert line.startswith("best_fit_bending_stiffness = 180.66 (")
    determined = {"parameters": {"bending_stiffness": {
        "unit": "N·m", "determined": True, "value": 7.4e-4, "standard_error": None}}}
    (run / "estimate.json").write_text(json.dumps(determined))
    row = JOBS["fit_material"].outputs(run)
    assert row["estimate_bending_stiffness"] == 7.4e-4 and row["best_fit_bending_stiffness"] == ""
    assert sweep._line({"status": "ok", **row}).startswith("estimate_bending_stiffness = ")
