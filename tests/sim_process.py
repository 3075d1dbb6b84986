"""`ndf-sim` in a child process, as a user runs it: for the tests of a refusal (exit code 2
and one line on stderr, before any solve)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def sim_refusal(scene: Path, out: Path) -> str:
    """Run `python -m taichi_ndf.cli.sim scene --out out`; assert it exits 2 with one line on
    stderr and return that line."""
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"}
    process = subprocess.run([sys.executable, "-m", "taichi_ndf.cli.sim", str(scene), "--out",
                              str(out)], capture_output=True, text=True, env=env, timeout=300)
    assert process.returncode == 2, process.stderr
    lines = process.stderr.strip().splitlines()
    assert len(lines) == 1, process.stderr
    return lines[0]
