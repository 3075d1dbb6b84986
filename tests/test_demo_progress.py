"""The material demo's observation making (demos/fit_material.py: three projected-Newton
solves of the cantilever strip, minutes at full size) shows its progress bar on a
pseudo-terminal within 5 s of the start of its solve (issue 34: a bar for every long path)."""

from __future__ import annotations

import sys

from test_progress import ROOT, _first_progress

# Imports done before the marker: the 5 s measure the demo's own start and its first solve.
WRAPPER = """
import runpy, sys, taichi, torch
import taichi_ndf.scene.reader, inverse.cli.fit_material, inverse.material.calibration
sys.argv = ["fit_material.py", *sys.argv[1:]]
print("SOLVE STARTS", flush=True)
runpy.run_path({demo!r}, run_name="__main__")
"""

# tqdm's bar of the first load step's equilibrium ("...: 0%|  | 0/100"), not the log line
# that the same stage writes when it finishes ("...load 0.125: 12 steps, ...")
BAR = r"equilibrium [^\n]*load 0\.125:\s+\d+%\|"


def test_fit_material_demo_shows_its_observation_solves_on_a_terminal_within_5_s(tmp_path):
    command = [sys.executable, "-c", WRAPPER.format(demo=str(ROOT / "demos" / "fit_material.py")),
               "--quick", "--out", str(tmp_path / "run")]
    seconds, text = _first_progress(command, BAR, timeout=90)
    assert seconds < 5, f"first progress after {seconds:.1f} s:\n{text}"
