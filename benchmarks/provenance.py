"""Where a benchmark's figures come from: the commit they were measured on, printed at the top
of each benchmark's tables (with the machine's load, which each script states its own way)."""

from __future__ import annotations

import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def commit() -> str:
    """The repository's HEAD as a short hash; "unknown" outside a git checkout or without git."""
    try:
        return subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"],
                              capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
