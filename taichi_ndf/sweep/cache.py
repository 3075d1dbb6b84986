"""A study's store of expensive set-up that its runs share: arrays under a key, built once.

A run that needs a costly input every other run of its kind needs too (the solved observation
of a calibration case) looks it up in ``OUT/cache/`` (the folder `ndf-sweep` passes the job's
tool): one ``.npz`` file per key, named ``LABEL-HASH.npz`` with HASH the SHA-256 of the key,
plain data naming everything the arrays depend on (the code among it:
`taichi_ndf.sweep.provenance.code_version`). A file is written whole to a temporary sibling
and moved into place (`taichi_ndf.io.atomic_path`), so runs that build the same entry at once
each write a complete file, the last one stays, and no run reads a half-written one. A loaded
file must hold the key it was asked for (else it is not used).
"""

from __future__ import annotations

import hashlib
import json
import logging
from pathlib import Path

import numpy as np

from taichi_ndf.io import atomic_path

log = logging.getLogger(__name__)

_KEY = "__key__"  # the array of an entry that holds its key (JSON text)


def _text(key: dict) -> str:
    return json.dumps(key, sort_keys=True, separators=(",", ":"))


def entry_path(folder: str | Path, label: str, key: dict) -> Path:
    """The file of `key` in `folder`: ``LABEL-HASH.npz`` (HASH: 16 hex digits of the key)."""
    digest = hashlib.sha256(_text(key).encode()).hexdigest()[:16]
    return Path(folder) / f"{label}-{digest}.npz"


def load(folder: str | Path, label: str, key: dict) -> dict[str, np.ndarray] | None:
    """The arrays stored under `key`, or None when there is no entry (or it holds another
    key)."""
    path = entry_path(folder, label, key)
    try:
        with np.load(path, allow_pickle=False) as stored:
            arrays = {name: stored[name] for name in stored.files}
    except FileNotFoundError:
        return None
    if str(arrays.pop(_KEY, "")) != _text(key):
        log.warning("cache entry %s holds another key; not used", path)
        return None
    log.info("loaded %s", path)
    return arrays


def store(folder: str | Path, label: str, key: dict, arrays: dict[str, np.ndarray]) -> Path:
    """Write the arrays under `key` (atomically, replacing an entry of the same key)."""
    path = entry_path(folder, label, key)
    with atomic_path(path) as temporary, open(temporary, "wb") as stream:
        np.savez(stream, **arrays, **{_KEY: np.array(_text(key))})
    log.info("stored %s", path)
    return path
