"""One consistent command line: the same flag names across the tools (old names kept as
aliases), clean --help descriptions, the scene positional, ndf-export of a run directory by
the output's extension, ndf-render --time and the final summary of a solve."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from inverse.cli import fit_material, sft, sft_eval
from taichi_ndf.cli import common, export, render, sim, validate, view

PARSERS = {"ndf-sim": sim.build_parser, "ndf-export": export.build_parser,
           "ndf-render": render.build_parser, "ndf-view": view.build_parser,
           "ndf-validate": validate.build_parser, "ndf-fit-material": fit_material.build_parser,
           "ndf-sft": sft.build_parser, "ndf-sft-eval": sft_eval.build_parser}


@pytest.mark.parametrize("tool", PARSERS)
def test_help_description_is_one_clean_sentence(tool):
    text = PARSERS[tool]().description
    assert "`" not in text and text[0].isupper() and text.endswith("."), text
    assert "  " not in text and "\n" not in text


def test_description_drops_the_synopsis_and_joins_the_paragraph():
    doc = "`ndf-x A --out B`: do a thing over\ntwo lines.\n\nMore detail."
    assert common.description(doc) == "Do a thing over two lines."


@pytest.mark.parametrize("tool, old, new", [
    ("ndf-sim", "--iters", "--iterations"), ("ndf-validate", "--iters", "--iterations"),
    ("ndf-sft", "--steps", "--iterations")])
def test_iterations_is_the_name_and_the_old_one_still_works(tool, old, new):
    parser = PARSERS[tool]()
    required = {"ndf-sim": ["s.toml", "--out", "o"], "ndf-validate": ["--out", "o"],
                "ndf-sft": ["--frames", "f", "--camera", "c", "--template", "t", "--texture",
                            "x", "--out", "o"]}[tool]
    assert parser.parse_args([*required, new, "7"]).iterations == 7
    assert parser.parse_args([*required, old, "7"]).iterations == 7


def test_fit_material_takes_the_scene_positional_or_as_option(capsys):
    common_args = ["--observed", "o.obj", "--estimate", "bending", "--out", "d"]
    assert fit_material.parse_args(["s.toml", *common_args]).scene == Path("s.toml")
    assert fit_material.parse_args(["--scene", "s.toml", *common_args]).scene == Path("s.toml")
    for argv in (common_args, ["a.toml", "--scene", "b.toml", *common_args]):
        with pytest.raises(SystemExit) as exit_:
            fit_material.parse_args(argv)
        assert exit_.value.code == 2
    assert "overwrite" in fit_material.build_parser().format_help()


def test_every_solving_tool_has_overwrite_and_precision():
    for tool in ("ndf-sim", "ndf-export", "ndf-validate", "ndf-fit-material", "ndf-sft"):
        text = PARSERS[tool]().format_help()
        assert "--overwrite" in text and "--precision" in text, tool
    assert "--overwrite" in PARSERS["ndf-sft-eval"]().format_help()


def test_one_precision_default_across_the_tools():
    required = {"ndf-sim": ["s.toml", "--out", "o"], "ndf-export": ["r", "--out", "m.obj"],
                "ndf-validate": ["--out", "o"],
                "ndf-fit-material": ["s.toml", "--observed", "o.obj", "--estimate", "bending",
                                     "--out", "d"],
                "ndf-sft": ["--frames", "f", "--camera", "c", "--template", "t", "--texture",
                            "x", "--out", "o"]}
    for tool, argv in required.items():
        parser = PARSERS[tool]()
        assert parser.parse_args(argv).precision == common.DEFAULT_PRECISION == "f64", tool
        assert f"(default: {common.DEFAULT_PRECISION}" in " ".join(parser.format_help().split())


def test_the_summary_gives_the_extrapolated_values_with_their_errors():
    from taichi_ndf.minimise.refinement import richardson, richardson_point

    def study(values):
        return {"values": values, **richardson(values, order=4.0).to_dict()}

    result = {"energy": -1.6, "iterations": 12, "wall_time": 3.0,
              "probes": {"corner": [0.1, 0.2, -1.4]},
              "refinement": {"energy": study([-1.5, -1.6]),
                             "probes": {"corner": [study([0.12, 0.11]), study([0.22, 0.21]),
                                                   study([-1.42, -1.43])]}}}
    lines = sim.summary_lines("napkin", result)
    energy = result["refinement"]["energy"]
    assert lines[1] == f"  refinement over 2 grids: Π → {energy['text']} J"
    assert "assumed" in lines[1] and "± 0.1" in lines[1]  # two grids: the whole change
    # order 4 assumed: v + (v - v_coarse) / 15, error = the whole change
    assert "extrapolated (0.10933 ± 0.01, 0.20933 ± 0.01, -1.4307 ± 0.01) m (order assumed)" \
        in lines[2]
    assert len(sim.summary_lines("napkin", {**result, "refinement": None})) == 2
    # three grids whose changes do not fall: "order unreliable" on the Π line and the probe's
    three = {**result, "refinement": {
        "energy": study([-1.5, -1.6, -1.4]),
        "probes": {"corner": [study([0.1, 0.2, 0.15]), study([0.2, 0.21, 0.215]),
                              study([-1.4, -1.3, -1.45])]}}}
    lines = sim.summary_lines("napkin", three)
    assert "order unreliable" in lines[1] and "± 0.6" in lines[1]  # 3 × the range 0.2
    assert "warning: refinement order unreliable" in lines[2]
    assert lines[3].endswith("(order unreliable)")
    # a component bounded by its point's bar (`richardson_point`): said on the probe's line
    values = [[1e-3 * h**3, 2e-4 * h**3, 1e-3 * h**4.5] for h in (1.0, 0.5, 0.25)]
    point = [{"values": [u[c] for u in values], **e.to_dict()}
             for c, e in enumerate(richardson_point(values, order=4.0))]
    lines = sim.summary_lines("napkin", {**three, "refinement": {**three["refinement"],
                                                                 "probes": {"corner": point}}})
    assert lines[3].endswith("(order unreliable; component 2 within the point's bar)")


SCENE = """
name = "small_spline"
[geometry]
type = "plane"
bounds = [[0.0, 1.0], [0.0, 1.0]]
[material]
preset = "cloth"
[loads]
gravity = [0.0, 0.0, -9.81]
[[boundary.constraint]]
type = "clamped_edge"
edge = "xi1_min"
[field]
type = "spline"
spans = [4, 2]
[training]
load_steps = [0.5, 1.0]
[[probes]]
name = "tip"
xi = [1.0, 0.5]
[output]
resolution = [8, 4]
"""


@pytest.fixture(scope="module")
def spline_run(tmp_path_factory):
    root = tmp_path_factory.mktemp("cli")
    scene = root / "scene.toml"
    scene.write_text(SCENE)
    assert sim.main([str(scene), "--out", str(root / "run"), "--precision", "f64"]) == 0
    return root / "run"


def test_export_of_a_run_directory_by_the_extension(spline_run, tmp_path, capsys):
    out = tmp_path / "x.obj"
    assert export.main([str(spline_run), "--out", str(out), "--resolution", "4",
                        "--precision", "f64"]) == 0
    assert out.read_text().count("\nv ") == 25 or out.read_text().startswith("v ")
    assert export.main([str(spline_run), "--out", str(out), "--precision", "f64"]) == 2
    assert "--overwrite" in capsys.readouterr().err


def test_render_time_draws_a_trajectory_frame(spline_run, tmp_path, capsys):
    out = tmp_path / "half.png"
    assert render.main([str(spline_run), "--time", "0.5", "--colour", "displacement",
                        "--size", "320x240", "--out", str(out)]) == 0
    assert out.is_file()
    assert render.main([str(spline_run), "--time", "0.3", "--colour", "displacement",
                        "--out", str(tmp_path / "no.png")]) == 2
    assert "frames at 0.5, 1" in capsys.readouterr().err
    assert render.main([str(spline_run), "--time", "0.5", "--out",
                        str(tmp_path / "no.png")]) == 2  # strains: the final state only
    result = json.loads((spline_run / "result.json").read_text())
    assert [s["load_factor"] for s in result["load_steps"]] == [0.5, 1.0]
    tip = [s["probes"]["tip"] for s in result["load_steps"]]
    assert abs(tip[1][2]) > abs(tip[0][2]) > 0  # the tip sags further at the full load


def test_help_of_every_tool_imports_neither_torch_nor_taichi():
    """`--help` of every [project.scripts] entry point, in a fresh interpreter: the parsed
    command line leaves torch, Taichi (or quadrants) and scipy unimported (they cost 2-5 s)."""
    import subprocess
    import sys
    import tomllib

    root = Path(__file__).resolve().parents[1]
    scripts = tomllib.loads((root / "pyproject.toml").read_text())["project"]["scripts"]
    heavy = ("torch", "taichi", "quadrants", "scipy")
    for tool, target in scripts.items():
        module, function = target.split(":")
        code = (f"import sys, contextlib, io\nfrom {module} import {function}\n"
                "with contextlib.redirect_stdout(io.StringIO()):\n"
                f"    try:\n        {function}(['--help'])\n    except SystemExit:\n        pass\n"
                f"print(sorted(m for m in {heavy!r} if m in sys.modules))")
        done = subprocess.run([sys.executable, "-c", code], cwd=root, capture_output=True,
                              text=True, timeout=120)
        assert done.returncode == 0, (tool, done.stderr)
        assert done.stdout.strip() == "[]", (tool, done.stdout)
