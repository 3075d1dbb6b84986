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
_CODE = ("taichi_ndf", "inverse", "scenes")  # what the code of a checkout is (code_version)


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
    """The commit of the checkout and, where the code differs from it, a hash of the
    difference (``COMMIT+dirty-HASH``, HASH of ``git diff HEAD`` over the packages and the
    shipped scenes: taichi_ndf/, inverse/, scenes/; edits elsewhere, docs say, do not count):
    two checkouts that run different code get different versions (the key of the study
    cache, `taichi_ndf.sweep.cache`). ``taichi-ndf VERSION`` outside git."""
    commit = package_commit().removesuffix("+dirty")
    if commit.startswith("taichi-ndf "):
        return commit
    diff = subprocess.run(["git", "-C", str(_PACKAGE.parent), "diff", "HEAD", "--",
                           *_CODE], capture_output=True, check=True).stdout
    return f"{commit}+dirty-{hashlib.sha256(diff).hexdigest()[:12]}" if diff else commit


@functools.cache
def machine() -> str:
    """``host (N CPUs, processor)``."""
    processor = platform.processor() or platform.machine()
    return f"{platform.node()} ({os.cpu_count()} CPUs, {processor})"
