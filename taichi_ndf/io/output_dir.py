"""Run directories that are never silently reused, and atomic file writes."""

import json
import logging
import os
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

__all__ = ["OutputDir", "atomic_path"]

logger = logging.getLogger(__name__)


@contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary sibling of ``path`` to write; on success it replaces ``path`` at once.

    The temporary name keeps the suffix, so writers that pick a format from the extension
    (OpenCV) work. Readers never see a half-written file; on error the temporary is removed and
    ``path`` is left as it was.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_name(f".{path.stem}.{uuid.uuid4().hex[:8]}.partial{path.suffix}")
    try:
        yield temporary
        if not temporary.exists():
            raise FileNotFoundError(f"nothing was written to {temporary} for {path}")
        os.replace(temporary, path)
    finally:
        temporary.unlink(missing_ok=True)


class OutputDir:
    """A run's output directory: created if missing, refused if it already holds files.

    path: the directory; its parents are created.
    overwrite: allow a non-empty directory (files written again are replaced, others are kept;
        this is also how a run is resumed in place).
    """

    def __init__(self, path: str | os.PathLike, *, overwrite: bool = False):
        self.path = Path(path)
        if self.path.exists() and not self.path.is_dir():
            raise FileExistsError(f"output path {self.path} exists and is not a directory")
        if self.path.is_dir() and any(self.path.iterdir()):
            if not overwrite:
                raise FileExistsError(
                    f"output directory {self.path} is not empty; choose a new directory or "
                    "allow overwriting (overwrite=True, --overwrite)"
                )
            logger.warning("writing into non-empty output directory %s", self.path)
        self.path.mkdir(parents=True, exist_ok=True)

    def file(self, name: str) -> Path:
        """Path of the file ``name`` (may contain sub-folders, which are created) in the run."""
        relative = Path(name)
        if relative.is_absolute() or ".." in relative.parts:
            raise ValueError(f"output file name must be relative and inside the run: {name!r}")
        target = self.path / relative
        target.parent.mkdir(parents=True, exist_ok=True)
        return target

    def write_text(self, name: str, text: str) -> Path:
        """Write a text file atomically; returns its path."""
        target = self.file(name)
        with atomic_path(target) as temporary:
            temporary.write_text(text, encoding="utf-8")
        return target

    def write_json(self, name: str, data) -> Path:
        """Write strict JSON (NaN and infinity are refused: they are not JSON) atomically."""
        return self.write_text(name, json.dumps(data, indent=2, allow_nan=False) + "\n")

    def __repr__(self) -> str:
        return f"OutputDir({str(self.path)!r})"
