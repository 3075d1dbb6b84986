"""What a results row records about where it ran: the package's commit and the machine."""

from __future__ import annotations

import functools
import hashlib
import os
import platform
import subprocess
from pathlib import Path

import taichi_ndf

_PACKAGE = Path(taichi_ndf.__file__).resolve().parent


@functools.cache
def package_commit() -> str:
    """The git commit of the taichi_ndf checkout that runs (12 hex digits, ``+dirty`` with
    uncommitted changes to tracked files), or ``taichi-ndf VERSION`` for an installed copy
    outside git."""
    try:
        commit = subprocess.run(["git", "-C", str(_PACKAGE), "rev-parse", "--short=12", "HEAD"],
                                capture_output=True, text=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(_PACKAGE), "status", "--porcelain",
                                "--untracked-files=no"], capture_output=True, text=True,
                               check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return f"taichi-ndf {taichi_ndf.__version__}"
    return f"{commit}+dirty" if dirty else commit


@functools.cache
def code_version() -> str:
    """`package_commit`, and for a checkout with uncommitted changes to tracked files a hash
    of them (``COMMIT+dirty-HASH`` of ``git diff HEAD``): two checkouts that run different
    code get different versions (the key of the study cache, `taichi_ndf.sweep.cache`)."""
    commit = package_commit()
    if not commit.endswith("+dirty"):
        return commit
    diff = subprocess.run(["git", "-C", str(_PACKAGE), "diff", "HEAD"], capture_output=True,
                          check=True).stdout
    return f"{commit}-{hashlib.sha256(diff).hexdigest()[:12]}"


@functools.cache
def machine() -> str:
    """``host (N CPUs, processor)``."""
    processor = platform.processor() or platform.machine()
    return f"{platform.node()} ({os.cpu_count()} CPUs, {processor})"
