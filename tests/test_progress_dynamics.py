"""ndf-sim's dynamic path ([dynamics]: implicit time steps) on a pseudo-terminal: its bar
appears within 5 s of the start of the solve and counts the time steps (issue 34's acceptance:
each long-running path; the static paths are in test_progress.py and test_progress_tools.py)."""

from __future__ import annotations

import sys

from test_progress import WRAPPER, _progress_times

SCENE = """
name = "progress_pendulum"
[geometry]
type = "plane"
bounds = [[-0.15, 0.15], [-0.15, 0.15]]
[material]
preset = "cotton_polyester"
[loads]
gravity = [0.0, 0.0, -9.81]
[[boundary.constraint]]
type = "pinned_point"
xi = [-0.15, -0.15]
rotation = "free"
[field]
type = "spline"
spans = [4, 4]
[training]
method = "newton"
[dynamics]
integrator = "implicit_euler"
dt = 0.01
duration = 0.5
frame_rate = 10
[[probes]]
name = "far_corner"
xi = [0.15, 0.15]
[output]
resolution = [8, 8]
"""


def test_ndf_sim_dynamics_shows_its_time_steps_within_5_s(tmp_path):
    scene = tmp_path / "scene.toml"
    scene.write_text(SCENE)
    command = [sys.executable, "-c", WRAPPER.format(module="taichi_ndf.cli.sim"), str(scene),
               "--out", str(tmp_path / "run")]
    (first, counted), text = _progress_times(
        command, [r"dynamics \(implicit_euler", r"\| *[1-9]\d*/50"], timeout=90)
    assert first < 5, f"first progress after {first:.1f} s:\n{text}"
    assert counted >= first
