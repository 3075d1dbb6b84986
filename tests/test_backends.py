"""Both Taichi backends (taichi, quadrants; `taichi_ndf.runtime`) give the same Π in float64:
the napkin on the spline path (8 × 8 spans, projected Newton to the rounding floor), a few
SIREN Adam steps on the napkin, and the square-plate and pinched-hemisphere validation cases
(the hemisphere's membrane strains are small differences of metrics: with the compiler's fast
math on, the backends' Π differed there by 1.1e-12), each backend in its own process
(benchmarks/backends.py --child energies)."""

import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from taichi_ndf.runtime import BACKEND_VARIABLE, BACKENDS

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "benchmarks" / "backends.py"
MISSING = [name for name in BACKENDS if importlib.util.find_spec(name) is None]


def energies(backend: str) -> dict[str, float]:
    env = {**os.environ, BACKEND_VARIABLE: backend, "OMP_NUM_THREADS": "1",
           "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))}
    done = subprocess.run([sys.executable, str(SCRIPT), "--child", "energies", "--cases",
                           "square_plate", "pinched_hemisphere", "--siren-steps", "3"], env=env,
                          capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stderr[-3000:]
    result = json.loads(done.stdout.strip().splitlines()[-1])
    assert result["backend"].startswith(backend + " ")
    return result["energy"]


@pytest.mark.skipif(bool(MISSING), reason=f"{' and '.join(MISSING)} not installed (both "
                    "backends: pip install -e '.[quadrants]')")
def test_both_backends_give_the_same_energy():
    taichi, quadrants = (energies(name) for name in BACKENDS)
    assert taichi.keys() == quadrants.keys() and len(taichi) == 4
    for name, value in taichi.items():
        assert quadrants[name] == pytest.approx(value, rel=1e-12, abs=0), name
