"""Smoke test: the field-step benchmark runs its quick case and prints a complete table."""

import subprocess
import sys
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "field_step.py"


def test_quick_benchmark_prints_all_contenders():
    done = subprocess.run(
        [sys.executable, str(SCRIPT), "--quick"], capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, done.stderr
    rows = [line for line in done.stdout.splitlines() if line.startswith("| N=")]
    assert [row.split("|")[2].strip() for row in rows] == [
        "taichi-ndf",
        "torch-jets",
        "torch-nested",
    ]
    for row in rows:
        agreement = float(row.split("|")[9])
        assert agreement < 1e-4, row
