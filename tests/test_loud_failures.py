"""Inputs that used to be accepted silently or gave a number that is not a result: a line
load on a periodic "edge", a spline grid on which projected Newton takes no step."""

from __future__ import annotations

from test_cli import run_sim, write_scene
from test_run_size import spline_scene

CYLINDER_LINE_LOAD = """
name = "sleeve_line_load"
[geometry]
type = "cylinder"
radius = 0.1
length = 0.4
[material]
preset = "cloth"
[[boundary.constraint]]
type = "clamped_edge"
edge = "xi2_min"
[[loads.line]]
edge = "{edge}"
force = [0.0, 0.0, -1.0]
[field]
width = 16
[training]
iterations = 1
samples = 256
[output]
resolution = [8, 8]
"""


def test_a_line_load_on_a_periodic_edge_is_refused_in_one_line(tmp_path, capsys):
    scene = write_scene(tmp_path, CYLINDER_LINE_LOAD.format(edge="xi1_min"))
    assert run_sim(scene, "--out", tmp_path / "run") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "loads.line" in err[0] and "ξ1 is periodic" in err[0], err
    assert not (tmp_path / "run").exists()


def test_a_spline_run_that_takes_no_newton_step_is_an_error_not_pi_0(tmp_path, capsys):
    """The free-pinned napkin on 1 × 1 spans (`SplineDiscretisation.check_solution`)."""
    scene = spline_scene(tmp_path, "spans = [1, 1]").read_text().replace(
        'xi = [0.0, 0.0]\n', 'xi = [0.0, 0.0]\nrotation = "free"\n', 1)
    scene = write_scene(tmp_path, scene, "one_span.toml")
    assert run_sim(scene, "--out", tmp_path / "run") == 2
    captured = capsys.readouterr()
    err = captured.err.strip().splitlines()
    assert len(err) == 1 and "took no step on any grid (finest 1 × 1 spans" in err[0], err
    assert "Π = 0 J after" not in captured.out
    assert not (tmp_path / "run").exists()
