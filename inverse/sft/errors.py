"""The error of malformed shape-from-template inputs, and the check that an input exists."""

from __future__ import annotations

from pathlib import Path


class InputError(ValueError):
    """A shape-from-template input is missing or malformed."""


def existing_path(path: str | Path, what: str) -> Path:
    """`path` as a Path; InputError naming `what` if nothing is there."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"{what} {path}: missing file or folder")
    return path
