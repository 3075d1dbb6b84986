"""benchmarks/newton_iterations.py (issue 28): the counts per grid level and load step of a
Newton history and its model's share of the remaining fall, on histories made by hand, and
bad input refused with exit code 2."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

from tests.scripts import load_script

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "benchmarks" / "newton_iterations.py"


def _module():
    return load_script("benchmarks/newton_iterations.py")


def _record(level, load, energy, decrement, alpha, damping=0.0, projected=0):
    return {"level": level, "spans": [2 ** (level + 1)] * 2, "load_factor": load,
            "iteration": 0, "energy": energy, "decrement": decrement, "step_length": alpha,
            "damping": damping, "projected_blocks": projected, "gradient_norm": 1.0,
            "time_energy": 0.1, "time_hessian": 0.2, "time_assembly": 0.3, "time_solve": 0.4}


HISTORY = [
    _record(0, 1.0, 0.0, 1.0, 1.0, projected=5),
    _record(0, 1.0, -1.0, 0.5, 0.5, damping=1e-6),
    _record(0, 1.0, -1.999, 0.1, 2.0),
    _record(0, 1.0, -1.9999, 1e-9, 0.0),   # λ²/2 ≤ 1e-8 |Π|: endgame, stops
    _record(1, 1.0, -2.0, 1e-3, 1.0, projected=3),
    _record(1, 1.0, -2.0004, 1e-12, 0.0),
]


def test_counts_per_level_and_load_step():
    m = _module()
    steps = m.groups(HISTORY)
    assert list(steps) == [(0, (2, 2), 1.0), (1, (4, 4), 1.0)]
    s = m.summary(steps[(0, (2, 2), 1.0)], 1e-8)
    assert (s["iterations"], s["full"], s["shortened"], s["lengthened"], s["none"]) == (
        4, 1, 1, 1, 1)
    assert (s["projected"], s["damped"], s["endgame"]) == (1, 1, 1)
    # Π within 1e-3 of the last (-1.9999) from the third record on, within 1e-5 only the last
    assert s["until"] == [2, 3, 3]
    assert abs(s["seconds"] - 4.0) < 1e-12
    fine = m.summary(steps[(1, (4, 4), 1.0)], 1e-8)
    assert fine["until"] == [0, 1, 1] and fine["endgame"] == 1


def test_the_models_share_of_the_remaining_fall():
    """λ²/2 / (Π − Π_last) over the steps taken: the median of 0.5/1.9999, 0.25/0.9999 and
    0.05/0.0009 on level 0; 5e-4/4e-4 on level 1; a linear tail whose every model sees a
    tenth of the remaining fall reads 0.1; no step taken reads nan."""
    m = _module()
    steps = m.groups(HISTORY)
    assert abs(m.model_share(steps[(0, (2, 2), 1.0)]) - 0.25 / 0.9999) < 1e-12
    assert abs(m.model_share(steps[(1, (4, 4), 1.0)]) - 1.25) < 1e-9
    tail = [_record(0, 1.0, -1.0 + 0.8 ** k, 0.2 * 0.8 ** k, 1.0) for k in range(40)]
    tail.append(_record(0, 1.0, -1.0, 1e-20, 0.0))
    assert abs(m.model_share(tail) - 0.1) < 1e-12
    assert math.isnan(m.model_share([_record(0, 1.0, -1.0, 1e-20, 0.0)]))


def test_table_has_a_row_per_step_and_per_level():
    rows = _module().table(HISTORY, 1e-8)
    assert len(rows) == 2 + 2 + 2
    assert rows[2].startswith("| 0 | 2 × 2 | 1 | 4 | 1 / 1 / 1 / 1 | 1 | 1 | 1 | 2 / 3 / 3 | "
                              "0.25 |")
    assert rows[-1].startswith("| 1 | 4 × 4 | all 1 | 2 |")


def test_bad_input_exit_2(tmp_path):
    missing = subprocess.run([sys.executable, str(SCRIPT), str(tmp_path / "none.json")],
                             capture_output=True, text=True, timeout=60)
    assert missing.returncode == 2 and len(missing.stderr.strip().splitlines()) == 1
    siren = tmp_path / "result.json"
    siren.write_text(json.dumps({"history": [{"iteration": 0, "energy": 1.0}]}))
    no_newton = subprocess.run([sys.executable, str(SCRIPT), str(siren)],
                               capture_output=True, text=True, timeout=60)
    assert no_newton.returncode == 2 and "no Newton history" in no_newton.stderr
